//! Seed 003 laws on the spool model: `ccv`, `throttle-backstep`, `robust` (stubs: to be
//! implemented).

use super::law::{LawError, LawInputs, LawOutput, SurgeLaw};
use super::model::ControlModel;
use crate::signals::ActuatorCommands;
use serde::{Deserialize, Serialize};

macro_rules! stub_law {
    ($law:ident, $cfg:ident, $key:literal) => {
        #[doc = concat!("Settings (`[controller.", $key, "]`).")]
        #[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
        #[serde(deny_unknown_fields, default)]
        pub struct $cfg {}

        #[doc = "Law state."]
        #[derive(Debug, Clone)]
        pub struct $law {}

        impl $law {
            /// Build for a machine.
            pub fn new(_cfg: &$cfg, _model: &ControlModel) -> Result<Self, LawError> {
                Ok($law {})
            }
        }

        impl SurgeLaw for $law {
            fn start(&mut self, _inputs: &LawInputs<'_>, _current: &ActuatorCommands) {}
            fn update(&mut self, _inputs: &LawInputs<'_>, _dt_s: f64) -> LawOutput {
                LawOutput::idle()
            }
        }
    };
}

stub_law!(Ccv, CcvConfig, "ccv");
stub_law!(
    ThrottleBackstep,
    ThrottleBackstepConfig,
    "throttle_backstep"
);
stub_law!(Robust, RobustConfig, "robust");
