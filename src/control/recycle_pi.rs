//! `recycle-pi` (stub: to be implemented).

use super::law::{LawError, LawInputs, LawOutput, SurgeLaw};
use super::model::ControlModel;
use crate::signals::ActuatorCommands;
use serde::{Deserialize, Serialize};

/// Settings (`[controller.recycle_pi]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct RecyclePiConfig {
    /// The surge control line.
    pub control_line: super::surge_control_line::ControlLineForm,
}

/// Law state.
#[derive(Debug, Clone)]
pub struct RecyclePi {}

impl RecyclePi {
    /// Build for a machine.
    pub fn new(_cfg: &RecyclePiConfig, _model: &ControlModel) -> Result<Self, LawError> {
        Ok(RecyclePi {})
    }
}

impl SurgeLaw for RecyclePi {
    fn start(&mut self, _inputs: &LawInputs<'_>, _current: &ActuatorCommands) {}
    fn update(&mut self, _inputs: &LawInputs<'_>, _dt_s: f64) -> LawOutput {
        LawOutput::idle()
    }
}
