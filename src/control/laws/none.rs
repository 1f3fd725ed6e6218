//! `none`: no surge control. The speed loop runs; the valves stay with their manual stations
//! (open loop).

use crate::control::law::api::{LawError, LawInputs, LawNeeds, LawOutput, LawSpec, SurgeLaw};
use crate::control::model::ControlModel;
use crate::vocab::signals::{ActuatorCommands, ActuatorSet};

/// The law that commands nothing.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct NoLaw;

impl SurgeLaw for NoLaw {
    fn start(&mut self, _inputs: &LawInputs<'_>, _current: &ActuatorCommands) {}

    fn update(&mut self, _inputs: &LawInputs<'_>, _dt_s: f64) -> LawOutput {
        LawOutput::idle()
    }
}

impl LawSpec for NoLaw {
    type Settings = ();
    const NEEDS: LawNeeds = LawNeeds {
        summary: "no surge control (valves from their manual stations)",
        actuators: ActuatorSet::of(&[]),
        sensors: &[],
        needs_flow: false,
        machine_data: &[],
        model_family: None,
    };

    fn build(_settings: &(), _model: &ControlModel) -> Result<Self, LawError> {
        Ok(NoLaw)
    }
}
