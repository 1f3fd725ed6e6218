//! `recycle-fl` (stub: to be implemented).

use super::law::{LawError, LawInputs, LawOutput, SurgeLaw};
use super::model::ControlModel;
use crate::signals::ActuatorCommands;
use serde::{Deserialize, Serialize};

/// Settings (`[controller.recycle_fl]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct RecycleFlConfig {}

/// Law state.
#[derive(Debug, Clone)]
pub struct RecycleFl {}

impl RecycleFl {
    /// Build for a machine.
    pub fn new(_cfg: &RecycleFlConfig, _model: &ControlModel) -> Result<Self, LawError> {
        Ok(RecycleFl {})
    }
}

impl SurgeLaw for RecycleFl {
    fn start(&mut self, _inputs: &LawInputs<'_>, _current: &ActuatorCommands) {}
    fn update(&mut self, _inputs: &LawInputs<'_>, _dt_s: f64) -> LawOutput {
        LawOutput::idle()
    }
}
