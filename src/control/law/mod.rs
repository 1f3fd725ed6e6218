//! Surge laws behind one interface, selectable by name: the dispatch.
//!
//! The interface every law implements is [`api`] (it imports no law); the laws are under
//! [`crate::control::laws`]; which laws exist is [`list`], ONE list that generates the
//! [`api::LawId`], the registry ([`REGISTRY`], [`dbc_value_table`]), the dispatch ([`Law`])
//! and the `[controller.<section>]` settings ([`crate::control::ControllerConfig`]). A new law
//! is one file plus one line in [`list`].

pub mod api;
pub mod list;

use self::api::{LawDescriptor, LawError, LawId, LawInputs, LawOutput, LawSpec, SurgeLaw};
use self::list::laws;
use crate::control::config::ControllerConfig;
use crate::control::model::ControlModel;
use crate::machine::params::ModelKind;
use crate::machine::MachineData;
use crate::vocab::signals::{ActuatorCommands, ActuatorSet};

/// The descriptor of law `id` implemented by `L`.
const fn descriptor_of<L: LawSpec>(id: LawId) -> LawDescriptor {
    let n = L::NEEDS;
    LawDescriptor {
        id,
        name: id.name(),
        code: id.code(),
        summary: n.summary,
        actuators: n.actuators,
        sensors: n.sensors,
        needs_flow: n.needs_flow,
        machine_data: n.machine_data,
        model_family: n.model_family,
    }
}

/// The settings a law is built from: its `[controller.<section>]`, or nothing.
macro_rules! settings_of {
    ($cfg:ident, ()) => {
        &()
    };
    ($cfg:ident, ($section:ident $(: $($t:ident)::+)?)) => {
        &$cfg.$section
    };
}

macro_rules! define_dispatch {
    ($($id:ident $code:literal $name:literal $scope:ident $($seg:ident)::+, $settings:tt;)*) => {
        /// Every law's descriptor, in list order (the simulation-only ones included).
        const EVERY: [LawDescriptor; LawId::EVERY.len()] =
            [$(descriptor_of::<crate::control::$($seg)::+>(LawId::$id)),*];

        /// The active law with its state (static dispatch: no allocation, no heap).
        #[derive(Debug, Clone)]
        #[allow(clippy::large_enum_variant)]
        pub enum Law {
            $(
                #[doc = concat!("`", $name, "`.")]
                $id(crate::control::$($seg)::+),
            )*
        }

        impl Law {
            /// Build a law for a machine from the controller configuration.
            pub fn new(
                id: LawId,
                cfg: &ControllerConfig,
                model: &ControlModel,
            ) -> Result<Law, LawError> {
                if let Some(missing) = id.missing_machine_data(model) {
                    return Err(match (missing, model.kind) {
                        // a model-based law on another model family
                        (MachineData::Model(_), Some(_)) => LawError::NotApplicable {
                            law: id,
                            plant: model.name.clone(),
                            kind: model.kind,
                        },
                        _ => LawError::MachineData {
                            law: id,
                            machine: model.name.clone(),
                            missing,
                        },
                    });
                }
                Ok(match id {
                    $(
                        LawId::$id => Law::$id(<crate::control::$($seg)::+ as LawSpec>::build(
                            settings_of!(cfg, $settings),
                            model,
                        )?),
                    )*
                })
            }

            /// Which law this is.
            pub fn id(&self) -> LawId {
                match self {
                    $(Law::$id(_) => LawId::$id,)*
                }
            }

            fn inner(&mut self) -> &mut dyn SurgeLaw {
                match self {
                    $(Law::$id(l) => l,)*
                }
            }

            /// Hot reload of the running law with new settings: carry `running`'s dynamic
            /// state into this freshly built law so that only the settings change. Returns
            /// true when the state was carried over fully; false when this law has no such
            /// transfer (or the change needs one), and the caller starts it bumplessly from
            /// the applied outputs.
            pub fn take_over_from(&mut self, running: &Law) -> bool {
                match (self, running) {
                    $((Law::$id(new), Law::$id(old)) => new.carry_over(old),)*
                    #[allow(unreachable_patterns)]
                    _ => false,
                }
            }
        }
    };
}

laws!(define_dispatch);

const fn registry() -> [LawDescriptor; LawId::ALL.len()] {
    let mut out = [EVERY[0]; LawId::ALL.len()];
    let mut i = 0;
    while i < LawId::ALL.len() {
        out[i] = EVERY[LawId::ALL[i] as usize];
        i += 1;
    }
    out
}

/// The law registry: the laws the daemon offers, in code order, one descriptor each.
pub const REGISTRY: [LawDescriptor; LawId::ALL.len()] = registry();

/// The DBC value table line of the heartbeat's `ActiveLaw` signal (message `msg_id`), from
/// the registry: `VAL_ 128 ActiveLaw 0 "none" 1 "recycle-pi" … ;`.
pub fn dbc_value_table(msg_id: u32) -> String {
    let mut s = format!("VAL_ {msg_id} ActiveLaw");
    for d in &REGISTRY {
        s += &format!(" {} \"{}\"", d.code, d.name);
    }
    s + " ;"
}

impl LawId {
    /// The law's registry entry.
    pub const fn descriptor(self) -> &'static LawDescriptor {
        &EVERY[self as usize]
    }

    /// Actuators the law itself commands (without the drive's speed loop).
    pub const fn actuators(self) -> ActuatorSet {
        self.descriptor().actuators
    }

    /// Whether a simulation plant of model family `kind` gives the machine data the law
    /// needs (a plant file has a map and owns its drive; only the recycle system has a
    /// recycle valve; a model-based law needs its own family).
    pub fn supports(self, kind: ModelKind) -> bool {
        self.descriptor().machine_data.iter().all(|d| match d {
            MachineData::SurgeLine | MachineData::SpeedLineMap | MachineData::OwnedDrive => true,
            MachineData::RecycleValve => kind == ModelKind::RecycleSystem,
            MachineData::Model(k) => *k == kind,
        })
    }

    /// The first machine datum the law needs that the machine lacks.
    pub fn missing_machine_data(self, model: &ControlModel) -> Option<MachineData> {
        self.descriptor()
            .machine_data
            .iter()
            .copied()
            .find(|d| !model.has(*d))
    }
}

impl Law {
    /// Bumpless start from the outputs applied now.
    pub fn start(&mut self, inputs: &LawInputs<'_>, current: &ActuatorCommands) {
        self.inner().start(inputs, current);
    }

    /// One cycle.
    pub fn update(&mut self, inputs: &LawInputs<'_>, dt_s: f64) -> LawOutput {
        self.inner().update(inputs, dt_s)
    }

    /// Tell the law a surge was detected.
    pub fn surge_detected(&mut self) {
        self.inner().surge_detected();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vocab::signals::ActuatorId;

    #[test]
    fn serde_names_are_the_list_names() {
        for l in LawId::EVERY {
            let json = serde_json::to_string(&l).expect("json");
            assert_eq!(json, format!("\"{}\"", l.name()), "{l:?}");
            assert_eq!(l.descriptor().id, l);
        }
        assert_eq!(LawId::SIM_ONLY, [LawId::BaselinePi]);
        assert_eq!(LawId::parse_sim("baseline-pi"), Ok(LawId::BaselinePi));
        assert!(
            "baseline-pi".parse::<LawId>().is_err(),
            "not offered to the daemon"
        );
    }

    #[test]
    fn names_and_codes_are_unique_and_round_trip() {
        for (i, l) in LawId::ALL.iter().enumerate() {
            assert_eq!(l.name().parse::<LawId>(), Ok(*l));
            assert_eq!(l.code() as usize, i);
        }
        let e = "recycle_pi".parse::<LawId>().unwrap_err();
        assert!(e.to_string().contains("recycle-pi"), "{e}");
    }

    #[test]
    fn registry_is_in_code_order_and_the_dbc_value_table_matches_it() {
        for (i, d) in REGISTRY.iter().enumerate() {
            assert_eq!(d.code as usize, i);
            assert_eq!(d.id.descriptor(), d);
        }
        let line = dbc_value_table(128);
        assert!(
            line.starts_with("VAL_ 128 ActiveLaw 0 \"none\" 1 \"recycle-pi\""),
            "{line}"
        );
        let last = REGISTRY[REGISTRY.len() - 1];
        assert!(
            line.ends_with(&format!("{} \"{}\" ;", last.code, last.name)),
            "{line}"
        );
        assert_eq!(line.matches('"').count(), 2 * REGISTRY.len(), "{line}");
    }

    #[test]
    fn each_law_declares_its_actuators() {
        assert!(LawId::RecyclePi
            .actuators()
            .contains(ActuatorId::RecycleValve));
        assert!(LawId::TipSliding
            .actuators()
            .contains(ActuatorId::TipClearance));
        assert!(!LawId::TipSliding
            .actuators()
            .contains(ActuatorId::RecycleValve));
        assert!(LawId::Robust
            .actuators()
            .contains(ActuatorId::CloseCoupledValve));
        assert!(LawId::ThrottleBackstep
            .actuators()
            .contains(ActuatorId::Throttle));
    }
}
