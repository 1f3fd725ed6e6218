//! `drive-torque` (stub: to be implemented).

use super::law::{LawError, LawInputs, LawOutput, SurgeLaw};
use super::model::ControlModel;
use crate::signals::ActuatorCommands;
use serde::{Deserialize, Serialize};

/// Settings (`[controller.drive_torque]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct DriveTorqueConfig {}

/// Law state.
#[derive(Debug, Clone)]
pub struct DriveTorque {}

impl DriveTorque {
    /// Build for a machine.
    pub fn new(_cfg: &DriveTorqueConfig, _model: &ControlModel) -> Result<Self, LawError> {
        Ok(DriveTorque {})
    }
}

impl SurgeLaw for DriveTorque {
    fn start(&mut self, _inputs: &LawInputs<'_>, _current: &ActuatorCommands) {}
    fn update(&mut self, _inputs: &LawInputs<'_>, _dt_s: f64) -> LawOutput {
        LawOutput::idle()
    }
}
