//! `tip-sliding` (stub: to be implemented).

use super::law::{LawError, LawInputs, LawOutput, SurgeLaw};
use super::model::ControlModel;
use crate::signals::ActuatorCommands;
use serde::{Deserialize, Serialize};

/// Settings (`[controller.tip_sliding]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct TipSlidingConfig {}

/// Law state.
#[derive(Debug, Clone)]
pub struct TipSliding {}

impl TipSliding {
    /// Build for a machine.
    pub fn new(_cfg: &TipSlidingConfig, _model: &ControlModel) -> Result<Self, LawError> {
        Ok(TipSliding {})
    }
}

impl SurgeLaw for TipSliding {
    fn start(&mut self, _inputs: &LawInputs<'_>, _current: &ActuatorCommands) {}
    fn update(&mut self, _inputs: &LawInputs<'_>, _dt_s: f64) -> LawOutput {
        LawOutput::idle()
    }
}
