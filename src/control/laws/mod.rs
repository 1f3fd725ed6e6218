//! The surge laws, one file each, behind the interface of [`crate::control::law::api`]. Which
//! laws exist is the one list [`crate::control::law::list`]: a new law is one file here plus
//! one line there.

use crate::control::law::list::laws;

/// One `pub mod` per law of the list that lives here (`laws::<file>::<Type>`): a new law's file
/// needs no line of its own in this file.
macro_rules! law_modules {
    (@mods) => {};
    (@mods $id:ident $code:literal $name:literal $scope:ident laws :: $file:ident :: $ty:ident,
        $settings:tt; $($rest:tt)*) => {
        pub mod $file;
        law_modules!(@mods $($rest)*);
    };
    (@mods $id:ident $code:literal $name:literal $scope:ident $($seg:ident)::+, $settings:tt;
        $($rest:tt)*) => {
        law_modules!(@mods $($rest)*);
    };
    ($($list:tt)*) => {
        law_modules!(@mods $($list)*);
    };
}

laws!(law_modules);

/// What the seed 003 spool laws share (not a law itself).
pub mod spool;

use crate::control::law::api::{LawError, LawNeeds, LawSpec};
use crate::control::laws::recycle_pi::{ControlVariable, RecyclePi, RecyclePiConfig};
use crate::control::model::ControlModel;
// recycle_pi/mod.rs names `super::measurements` in a signature
use crate::control::measurements;
use crate::machine::MachineData;
use crate::vocab::signals::{ActuatorId, ActuatorSet, SensorId};

// recycle-pi's `LawSpec` lives here while its own files are being rebuilt (another change
// edits them); it moves into `recycle_pi/mod.rs` with that change.
impl LawSpec for RecyclePi {
    type Settings = RecyclePiConfig;
    const NEEDS: LawNeeds = LawNeeds {
        summary:
            "PI on the recycle valve around a surge control line (seed 001 ch. 3, seed 002 ch. 4)",
        actuators: ActuatorSet::of(&[ActuatorId::RecycleValve]),
        sensors: &[SensorId::RecycleValvePosition],
        needs_flow: true,
        machine_data: &[MachineData::SurgeLine, MachineData::RecycleValve],
        model_family: None,
    };
    fn build(settings: &Self::Settings, model: &ControlModel) -> Result<Self, LawError> {
        RecyclePi::new(settings, model)
    }

    fn carry_over(&mut self, running: &Self) -> bool {
        self.take_over_from(running)
    }

    fn settings_problems(settings: &RecyclePiConfig) -> Vec<(String, String)> {
        let pi = &settings.pi;
        let (kp, ki, key) = match pi.control_variable {
            ControlVariable::Deviation => (pi.kp, pi.ki_per_s, "recycle_pi.pi.kp"),
            _ => (
                pi.kp_per_map_flow,
                pi.ki_per_map_flow_s,
                "recycle_pi.pi.kp_per_map_flow",
            ),
        };
        if kp == 0.0 && ki == 0.0 {
            vec![(
                key.into(),
                "kp and ki are both 0: recycle-pi would never move the valve".into(),
            )]
        } else {
            Vec::new()
        }
    }
}
