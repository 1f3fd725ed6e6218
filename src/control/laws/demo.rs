//! `demo`: a throw-away law proving that a new law is one file plus one `laws!` line. It
//! holds the recycle valve at a fixed opening from `[controller.demo]`.

use crate::control::law::api::{LawError, LawId, LawInputs, LawNeeds, LawOutput, LawSpec, SurgeLaw};
use crate::control::model::ControlModel;
use crate::machine::MachineData;
use crate::vocab::signals::{ActuatorCommands, ActuatorId, ActuatorSet};
use serde::{Deserialize, Serialize};

/// Settings of `demo` (`[controller.demo]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DemoConfig {
    /// Recycle valve opening held, fraction.
    pub opening: f64,
}

impl Default for DemoConfig {
    fn default() -> Self {
        DemoConfig { opening: 0.5 }
    }
}

/// The law: a constant recycle valve opening.
#[derive(Debug, Clone)]
pub struct Demo {
    opening: f64,
}

impl SurgeLaw for Demo {
    fn start(&mut self, _inputs: &LawInputs<'_>, _current: &ActuatorCommands) {}

    fn update(&mut self, _inputs: &LawInputs<'_>, _dt_s: f64) -> LawOutput {
        let mut commands = ActuatorCommands::default();
        commands.set(ActuatorId::RecycleValve, self.opening);
        LawOutput {
            commands,
            diagnostic: f64::NAN,
            event: None,
        }
    }
}

impl LawSpec for Demo {
    type Settings = DemoConfig;
    const NEEDS: LawNeeds = LawNeeds {
        summary: "a constant recycle valve opening (throw-away proof)",
        actuators: ActuatorSet::of(&[ActuatorId::RecycleValve]),
        sensors: &[],
        needs_flow: false,
        machine_data: &[MachineData::RecycleValve],
        model_family: None,
    };

    fn build(settings: &DemoConfig, _model: &ControlModel) -> Result<Self, LawError> {
        if !(0.0..=1.0).contains(&settings.opening) {
            return Err(LawError::Setting {
                law: LawId::Demo,
                key: "demo.opening".into(),
                message: "must be within 0 … 1".into(),
            });
        }
        Ok(Demo {
            opening: settings.opening,
        })
    }
}
