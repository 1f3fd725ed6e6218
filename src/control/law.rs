//! Surge laws behind one interface, selectable by name.
//!
//! A law is a small state machine: [`SurgeLaw::start`] initialises its integrators from the
//! outputs currently applied (bumpless transfer from another law or from manual), and
//! [`SurgeLaw::update`] turns one measurement snapshot into actuator commands. Laws are pure,
//! deterministic and allocation-free. The drive's speed loop always runs: a law's drive-torque
//! command is *added* to the speed loop's output.

use super::config::ControllerConfig;
use super::measurements::{Measurements, OperatorInputs};
use super::model::ControlModel;
use crate::machine::params::ModelKind;
use crate::machine::MachineData;
use crate::vocab::signals::{ActuatorCommands, ActuatorId, ActuatorSet, SensorId};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The selectable laws.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LawId {
    /// No surge control: speed loop only, valves from their manual stations (open loop).
    None,
    /// Industrial surge avoidance: PI on the recycle valve around a surge control line
    /// (seed 001 ch. 3, seed 002 ch. 4).
    RecyclePi,
    /// Active surge control of the recycle valve by input–output feedback linearization
    /// (seed 001 ch. 4).
    RecycleFl,
    /// Active surge control with the drive torque (seed 000 eq. 7, 22).
    DriveTorque,
    /// Close-coupled valve (seed 003 Theorem 1, eq. 25/48).
    Ccv,
    /// Throttle backstepping (seed 003 Theorem 2, eq. 30–37/52).
    ThrottleBackstep,
    /// Robust torque + close-coupled valve (seed 003 Theorem 3, eq. 44, 46, 47).
    Robust,
    /// Sliding mode on the tip clearance via the magnetic thrust bearing (seed 004).
    TipSliding,
    /// The yardstick: textbook symmetric PI on the normalised deviation (simulation and
    /// benchmarks only, never offered to the daemon: not in [`LawId::ALL`]).
    BaselinePi,
}

/// What a law is and what it needs: one registry line per law ([`REGISTRY`]). The config
/// check asks for exactly these bindings and machine data; the CAN heartbeat's `ActiveLaw`
/// code and the DBC value table come from here (tests/config_corpus.rs checks
/// `config/skid.dbc` against [`dbc_value_table`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LawDescriptor {
    /// Which law.
    pub id: LawId,
    /// Name in config files, on the command line, in the event log and the DBC value table.
    pub name: &'static str,
    /// Numeric code (heartbeat `ActiveLaw`, trace, DBC value table).
    pub code: u8,
    /// One line for humans.
    pub summary: &'static str,
    /// Actuators the law itself commands (the drive's speed loop comes on top when the
    /// controller owns the drive).
    pub actuators: ActuatorSet,
    /// Sensors the law reads besides the suction and discharge pressures and the flow (the
    /// flow source adds the flow element's Δp).
    pub sensors: &'static [SensorId],
    /// Whether the law needs the compressor flow (then the flow source's sensors are needed).
    pub needs_flow: bool,
    /// Machine data the law needs from the machine description.
    pub machine_data: &'static [MachineData],
    /// Model family of a model-based law (its equations are written for this model).
    pub model_family: Option<ModelKind>,
}

use ActuatorId as A;
use SensorId as S;

/// The law registry: a new law is one file plus one line here.
pub const REGISTRY: [LawDescriptor; 8] = [
    LawDescriptor {
        id: LawId::None,
        name: "none",
        code: 0,
        summary: "no surge control (valves from their manual stations)",
        actuators: ActuatorSet::of(&[]),
        sensors: &[],
        needs_flow: false,
        machine_data: &[],
        model_family: None,
    },
    LawDescriptor {
        id: LawId::RecyclePi,
        name: "recycle-pi",
        code: 1,
        summary:
            "PI on the recycle valve around a surge control line (seed 001 ch. 3, seed 002 ch. 4)",
        actuators: ActuatorSet::of(&[A::RecycleValve]),
        sensors: &[S::RecycleValvePosition],
        needs_flow: true,
        machine_data: &[MachineData::SurgeLine, MachineData::RecycleValve],
        model_family: None,
    },
    LawDescriptor {
        id: LawId::RecycleFl,
        name: "recycle-fl",
        code: 2,
        summary: "feedback linearization on the recycle valve (seed 001 ch. 4)",
        actuators: ActuatorSet::of(&[A::RecycleValve]),
        sensors: &[S::ShaftSpeed, S::RecycleValvePosition, S::ThrottlePosition],
        needs_flow: true,
        machine_data: &[
            MachineData::SpeedLineMap,
            MachineData::RecycleValve,
            MachineData::Model(ModelKind::RecycleSystem),
        ],
        model_family: Some(ModelKind::RecycleSystem),
    },
    LawDescriptor {
        id: LawId::DriveTorque,
        name: "drive-torque",
        code: 3,
        summary: "active surge control with the drive torque (seed 000 eq. 7, 22)",
        actuators: ActuatorSet::of(&[A::DriveTorque]),
        sensors: &[S::ShaftSpeed],
        needs_flow: true,
        machine_data: &[
            MachineData::SpeedLineMap,
            MachineData::OwnedDrive,
            MachineData::Model(ModelKind::PlenumDuct),
        ],
        model_family: Some(ModelKind::PlenumDuct),
    },
    LawDescriptor {
        id: LawId::Ccv,
        name: "ccv",
        code: 4,
        summary: "close-coupled valve (seed 003 Theorem 1)",
        actuators: ActuatorSet::of(&[A::CloseCoupledValve]),
        sensors: &[S::ShaftSpeed],
        needs_flow: true,
        machine_data: &[
            MachineData::SpeedLineMap,
            MachineData::Model(ModelKind::Spool),
        ],
        model_family: Some(ModelKind::Spool),
    },
    LawDescriptor {
        id: LawId::ThrottleBackstep,
        name: "throttle-backstep",
        code: 5,
        summary: "throttle backstepping (seed 003 Theorem 2)",
        actuators: ActuatorSet::of(&[A::Throttle]),
        sensors: &[S::ShaftSpeed],
        needs_flow: true,
        machine_data: &[
            MachineData::SpeedLineMap,
            MachineData::Model(ModelKind::Spool),
        ],
        model_family: Some(ModelKind::Spool),
    },
    LawDescriptor {
        id: LawId::Robust,
        name: "robust",
        code: 6,
        summary: "robust torque + close-coupled valve (seed 003 Theorem 3)",
        actuators: ActuatorSet::of(&[A::DriveTorque, A::CloseCoupledValve]),
        sensors: &[S::ShaftSpeed],
        needs_flow: true,
        machine_data: &[
            MachineData::SpeedLineMap,
            MachineData::OwnedDrive,
            MachineData::Model(ModelKind::Spool),
        ],
        model_family: Some(ModelKind::Spool),
    },
    LawDescriptor {
        id: LawId::TipSliding,
        name: "tip-sliding",
        code: 7,
        summary: "sliding mode on the tip clearance via the magnetic thrust bearing (seed 004)",
        actuators: ActuatorSet::of(&[A::TipClearance]),
        sensors: &[S::ShaftSpeed, S::ThrustPosition],
        needs_flow: true,
        machine_data: &[
            MachineData::SpeedLineMap,
            MachineData::Model(ModelKind::TipClearance),
        ],
        model_family: Some(ModelKind::TipClearance),
    },
];

/// The simulation-only yardstick (`baseline-pi`): not in [`REGISTRY`], so neither the
/// daemon's config, the bus nor the DBC value table offer it.
pub const BASELINE_PI: LawDescriptor = LawDescriptor {
    id: LawId::BaselinePi,
    name: "baseline-pi",
    code: 255,
    summary: "textbook symmetric PI on the normalised deviation (simulation and benchmarks only)",
    actuators: ActuatorSet::of(&[A::RecycleValve]),
    sensors: &[],
    needs_flow: true,
    machine_data: &[MachineData::SurgeLine, MachineData::RecycleValve],
    model_family: None,
};

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
    /// Every law, in registry order.
    pub const ALL: [LawId; 8] = {
        let mut out = [LawId::None; 8];
        let mut i = 0;
        while i < REGISTRY.len() {
            out[i] = REGISTRY[i].id;
            i += 1;
        }
        out
    };

    /// The law's registry entry.
    pub const fn descriptor(self) -> &'static LawDescriptor {
        let mut i = 0;
        while i < REGISTRY.len() {
            if REGISTRY[i].id as u8 == self as u8 {
                return &REGISTRY[i];
            }
            i += 1;
        }
        if self as u8 == LawId::BaselinePi as u8 {
            return &BASELINE_PI;
        }
        panic!("every law has a registry line")
    }

    /// Laws of the simulation and benchmarks only (not in [`LawId::ALL`], so the daemon's
    /// config and the bus never offer them).
    pub const SIM_ONLY: [LawId; 1] = [LawId::BaselinePi];

    /// Parse a law name for `antisurge sim` and the benchmarks: every daemon law and the
    /// simulation-only ones.
    pub fn parse_sim(s: &str) -> Result<LawId, UnknownLaw> {
        s.parse::<LawId>().or_else(|e| {
            LawId::SIM_ONLY
                .iter()
                .copied()
                .find(|l| l.name() == s)
                .ok_or(e)
        })
    }

    /// Name used in config files, on the command line and in the event log.
    pub const fn name(self) -> &'static str {
        self.descriptor().name
    }

    /// Numeric code (heartbeat frame `ActiveLaw`, trace).
    pub const fn code(self) -> u8 {
        self.descriptor().code
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

impl fmt::Display for LawId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Error for an unknown law name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown law `{0}`; known laws: {list}", list = LawId::ALL.iter().map(|l| l.name()).collect::<Vec<_>>().join(", "))]
pub struct UnknownLaw(pub String);

impl FromStr for LawId {
    type Err = UnknownLaw;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        LawId::ALL
            .iter()
            .copied()
            .find(|l| l.name() == s)
            .ok_or_else(|| UnknownLaw(s.to_string()))
    }
}

/// Why a law cannot run on a machine.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LawError {
    /// The law is written for another plant model.
    #[error("law `{law}` is not applicable to plant `{plant}` (model {kind:?})")]
    NotApplicable {
        /// Law.
        law: LawId,
        /// Plant name.
        plant: String,
        /// Plant model (`None`: the description has no model).
        kind: Option<ModelKind>,
    },
    /// The machine description lacks data the law needs.
    #[error("law `{law}` needs {what}, which the machine description of `{machine}` does not give", what = .missing.describe().0)]
    MachineData {
        /// Law.
        law: LawId,
        /// Machine name.
        machine: String,
        /// What is missing.
        missing: MachineData,
    },
    /// A setting is invalid for this machine.
    #[error("law `{law}`: {key}: {message}")]
    Setting {
        /// Law.
        law: LawId,
        /// Config key (below `controller.`).
        key: String,
        /// What is wrong.
        message: String,
    },
}

/// What a law sees in one cycle.
#[derive(Debug, Clone, Copy)]
pub struct LawInputs<'a> {
    /// Validated measurements and derived quantities.
    pub m: &'a Measurements,
    /// Operator inputs (setpoints, manual station).
    pub op: &'a OperatorInputs,
    /// The machine model.
    pub model: &'a ControlModel,
    /// Loop timing: the drive torques of the last cycles (still in flight when the loop has a
    /// delay) and the age of this cycle's sample.
    pub history: &'a LoopHistory,
}

/// What a delay-compensating law needs to know about the loop: the total drive torque
/// commands of the last cycles, newest first, N·m (NaN: none yet), and how old the pressure
/// and speed sample of this cycle is. With a loop delay, the commands of the last cycles act
/// before the one computed now does; a law predicts the machine through them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopHistory {
    /// `newest_first_nm[0]` is the previous cycle's command.
    pub newest_first_nm: [f64; LoopHistory::LEN],
    /// Age of the oldest of the pressure and speed inputs this cycle runs on, s (time since
    /// it arrived; 0 in the simulation).
    pub sample_age_s: f64,
}

impl LoopHistory {
    /// How many cycles are kept.
    pub const LEN: usize = 16;
    /// No commands yet.
    pub const EMPTY: LoopHistory = LoopHistory {
        newest_first_nm: [f64::NAN; LoopHistory::LEN],
        sample_age_s: 0.0,
    };

    /// Record this cycle's command (allocation-free shift).
    #[inline]
    pub fn push(&mut self, torque_nm: f64) {
        self.newest_first_nm.copy_within(0..Self::LEN - 1, 1);
        self.newest_first_nm[0] = torque_nm;
    }

    /// The command of `age` cycles ago (1: the previous cycle), NaN if unknown.
    #[inline]
    pub fn ago(&self, age: usize) -> f64 {
        age.checked_sub(1)
            .and_then(|i| self.newest_first_nm.get(i))
            .copied()
            .unwrap_or(f64::NAN)
    }
}

impl Default for LoopHistory {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// What a law returns in one cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LawOutput {
    /// Commands for the law's actuators (NaN: not driven). `DriveTorque` is added to the speed
    /// loop's output.
    pub commands: ActuatorCommands,
    /// A law-specific diagnostic for traces (e.g. the control variable z), NaN if none.
    pub diagnostic: f64,
    /// An event worth logging (recycle trip, safety-on shift), if any.
    pub event: Option<LawEvent>,
}

impl LawOutput {
    /// Nothing driven.
    pub fn idle() -> LawOutput {
        LawOutput {
            commands: ActuatorCommands::default(),
            diagnostic: f64::NAN,
            event: None,
        }
    }
}

/// Events a law reports (the daemon logs them).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LawEvent {
    /// The recycle trip opened the valve (open-loop step).
    RecycleTrip {
        /// Opening stepped to, fraction.
        opening: f64,
        /// Which criterion fired.
        cause: TripCause,
    },
    /// Safety-on: the control line moved right after a surge.
    SafetyOnShift {
        /// Total added margin, fraction of flow.
        total_margin: f64,
        /// Shifts so far.
        count: u32,
    },
}

/// Why a law's recycle trip fired (the event log's `criterion`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TripCause {
    /// The operating point crossed the trip line.
    TripLine,
    /// The operating point was predicted to cross the trip line within the lead time.
    PredictedCrossing,
    /// The throttle's closing predicted the crossing before the flow showed it.
    ThrottleClosure,
    /// The shaft decelerated like a drive trip (emergency shutdown).
    SpeedDecay,
}

/// One law's state machine.
pub trait SurgeLaw {
    /// Initialise internal states so the first output equals the outputs applied now
    /// (`current`), from another law or manual: bumpless transfer.
    fn start(&mut self, inputs: &LawInputs<'_>, current: &ActuatorCommands);
    /// One control cycle of `dt_s` seconds.
    fn update(&mut self, inputs: &LawInputs<'_>, dt_s: f64) -> LawOutput;
    /// The control loop saw a surge (detector): laws with a safety-on feature react.
    fn surge_detected(&mut self) {}
}

/// The active law with its state (static dispatch: no allocation, no dyn).
#[derive(Debug, Clone)]
#[allow(clippy::large_enum_variant)]
pub enum Law {
    /// Open loop.
    None,
    /// Recycle PI.
    RecyclePi(super::recycle_pi::RecyclePi),
    /// Recycle feedback linearization.
    RecycleFl(super::recycle_fl::RecycleFl),
    /// Drive torque.
    DriveTorque(super::drive_torque::DriveTorque),
    /// Close-coupled valve.
    Ccv(super::spool_laws::Ccv),
    /// Throttle backstepping.
    ThrottleBackstep(super::spool_laws::ThrottleBackstep),
    /// Robust torque + CCV.
    Robust(super::spool_laws::Robust),
    /// Tip-clearance sliding mode.
    TipSliding(super::tip_sliding::TipSliding),
    /// The benchmark yardstick.
    BaselinePi(super::baseline_pi::BaselinePi),
}

impl Law {
    /// Build a law for a machine from the controller configuration.
    pub fn new(id: LawId, cfg: &ControllerConfig, model: &ControlModel) -> Result<Law, LawError> {
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
            LawId::None => Law::None,
            LawId::RecyclePi => {
                Law::RecyclePi(super::recycle_pi::RecyclePi::new(&cfg.recycle_pi, model)?)
            }
            LawId::RecycleFl => {
                Law::RecycleFl(super::recycle_fl::RecycleFl::new(&cfg.recycle_fl, model)?)
            }
            LawId::DriveTorque => Law::DriveTorque(super::drive_torque::DriveTorque::new(
                &cfg.drive_torque,
                model,
            )?),
            LawId::Ccv => Law::Ccv(super::spool_laws::Ccv::new(&cfg.ccv, model)?),
            LawId::ThrottleBackstep => Law::ThrottleBackstep(
                super::spool_laws::ThrottleBackstep::new(&cfg.throttle_backstep, model)?,
            ),
            LawId::Robust => Law::Robust(super::spool_laws::Robust::new(&cfg.robust, model)?),
            LawId::TipSliding => Law::TipSliding(super::tip_sliding::TipSliding::new(
                &cfg.tip_sliding,
                model,
            )?),
            LawId::BaselinePi => {
                // the same control line as recycle-pi (with its checks), textbook gains
                let rp = super::recycle_pi::RecyclePi::new(&cfg.recycle_pi, model)?;
                Law::BaselinePi(super::baseline_pi::BaselinePi::new(
                    *rp.control_line(),
                    cfg.recycle_pi.min_opening,
                ))
            }
        })
    }

    /// Which law this is.
    pub fn id(&self) -> LawId {
        match self {
            Law::None => LawId::None,
            Law::RecyclePi(_) => LawId::RecyclePi,
            Law::RecycleFl(_) => LawId::RecycleFl,
            Law::DriveTorque(_) => LawId::DriveTorque,
            Law::Ccv(_) => LawId::Ccv,
            Law::ThrottleBackstep(_) => LawId::ThrottleBackstep,
            Law::Robust(_) => LawId::Robust,
            Law::TipSliding(_) => LawId::TipSliding,
            Law::BaselinePi(_) => LawId::BaselinePi,
        }
    }

    fn inner(&mut self) -> Option<&mut dyn SurgeLaw> {
        match self {
            Law::None => None,
            Law::RecyclePi(l) => Some(l),
            Law::RecycleFl(l) => Some(l),
            Law::DriveTorque(l) => Some(l),
            Law::Ccv(l) => Some(l),
            Law::ThrottleBackstep(l) => Some(l),
            Law::Robust(l) => Some(l),
            Law::TipSliding(l) => Some(l),
            Law::BaselinePi(l) => Some(l),
        }
    }

    /// Hot reload of the running law with new settings: carry `running`'s dynamic state
    /// into this freshly built law so that only the settings change. Returns true when the
    /// state was carried over fully; false when this law has no such transfer (or the
    /// change needs one), and the caller starts it bumplessly from the applied outputs.
    pub fn take_over_from(&mut self, running: &Law) -> bool {
        match (self, running) {
            (Law::RecyclePi(new), Law::RecyclePi(old)) => new.take_over_from(old),
            // the spool laws keep their torque reference and trim, and are then started
            // bumplessly from the applied outputs (false: the caller starts them)
            (Law::Ccv(new), Law::Ccv(old)) => {
                new.take_over_from(old);
                false
            }
            (Law::ThrottleBackstep(new), Law::ThrottleBackstep(old)) => {
                new.take_over_from(old);
                false
            }
            (Law::Robust(new), Law::Robust(old)) => {
                new.take_over_from(old);
                false
            }
            _ => false,
        }
    }

    /// Bumpless start from the outputs applied now.
    pub fn start(&mut self, inputs: &LawInputs<'_>, current: &ActuatorCommands) {
        if let Some(l) = self.inner() {
            l.start(inputs, current);
        }
    }

    /// One cycle.
    pub fn update(&mut self, inputs: &LawInputs<'_>, dt_s: f64) -> LawOutput {
        match self.inner() {
            Some(l) => l.update(inputs, dt_s),
            None => LawOutput::idle(),
        }
    }

    /// Tell the law a surge was detected.
    pub fn surge_detected(&mut self) {
        if let Some(l) = self.inner() {
            l.surge_detected();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert!(line.ends_with("7 \"tip-sliding\" ;"), "{line}");
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
