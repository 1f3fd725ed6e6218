//! The interface of a surge law: what every law implements ([`SurgeLaw`], [`LawSpec`]), what
//! it sees and returns ([`LawInputs`], [`LawOutput`]), its id ([`LawId`], from the one list
//! [`super::list`]) and its descriptor. This file imports no law.
//!
//! A law is a small state machine: [`SurgeLaw::start`] initialises its integrators from the
//! outputs currently applied (bumpless transfer from another law or from manual), and
//! [`SurgeLaw::update`] turns one measurement snapshot into actuator commands. Laws are pure,
//! deterministic and allocation-free. The drive's speed loop always runs: a law's drive-torque
//! command is *added* to the speed loop's output.

use super::list::laws;
use crate::control::measurements::{Measurements, OperatorInputs};
use crate::control::model::ControlModel;
use crate::machine::params::ModelKind;
use crate::machine::MachineData;
use crate::vocab::signals::{ActuatorCommands, ActuatorSet, SensorId};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Count the tokens given (one per law of the list).
macro_rules! count_laws {
    () => { 0usize };
    ($head:ident $($tail:ident)*) => { 1usize + count_laws!($($tail)*) };
}

/// `true` for a law the daemon offers.
macro_rules! offered_by_daemon {
    (daemon) => {
        true
    };
    (sim) => {
        false
    };
}

macro_rules! define_law_id {
    ($($id:ident $code:literal $name:literal $scope:ident $($seg:ident)::+, $settings:tt;)*) => {
        /// The selectable laws: one variant per line of the list ([`super::list`]).
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
        #[serde(rename_all = "kebab-case")]
        pub enum LawId {
            $(
                #[doc = concat!("`", $name, "`: ", stringify!($($seg)::+), ".")]
                $id,
            )*
        }

        impl LawId {
            /// Every law of the list in list order, the simulation-only ones included.
            pub const EVERY: [LawId; count_laws!($($id)*)] = [$(LawId::$id),*];

            /// Whether the daemon offers the law (by position in [`Self::EVERY`]).
            const OFFERED: [bool; count_laws!($($id)*)] = [$(offered_by_daemon!($scope)),*];

            /// Name used in config files, on the command line, in the event log and the DBC
            /// value table.
            pub const fn name(self) -> &'static str {
                match self {
                    $(LawId::$id => $name,)*
                }
            }

            /// Numeric code (heartbeat frame `ActiveLaw`, trace, DBC value table).
            pub const fn code(self) -> u8 {
                match self {
                    $(LawId::$id => $code,)*
                }
            }
        }
    };
}

laws!(define_law_id);

const fn count_offered(offered: bool) -> usize {
    let mut n = 0;
    let mut i = 0;
    while i < LawId::OFFERED.len() {
        if LawId::OFFERED[i] == offered {
            n += 1;
        }
        i += 1;
    }
    n
}

const fn laws_offered<const N: usize>(offered: bool) -> [LawId; N] {
    let mut out = [LawId::EVERY[0]; N];
    let (mut i, mut k) = (0, 0);
    while i < LawId::EVERY.len() {
        if LawId::OFFERED[i] == offered {
            out[k] = LawId::EVERY[i];
            k += 1;
        }
        i += 1;
    }
    out
}

impl LawId {
    /// Every law the daemon offers, in code order (the registry).
    pub const ALL: [LawId; count_offered(true)] = laws_offered(true);

    /// Laws of the simulation and benchmarks only (not in [`LawId::ALL`], so the daemon's
    /// config and the bus never offer them).
    pub const SIM_ONLY: [LawId; count_offered(false)] = laws_offered(false);

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
}

/// What a law is and what it needs: one registry entry per law
/// ([`REGISTRY`](super::REGISTRY), from the list and each law's [`LawSpec::NEEDS`]). The config
/// check asks for exactly these bindings and machine data; the CAN heartbeat's `ActiveLaw`
/// code and the DBC value table come from here (tests check `config/skid.dbc` against
/// [`dbc_value_table`](super::dbc_value_table)).
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

/// What a law declares about itself in its own file ([`LawSpec::NEEDS`]); the list adds the
/// id, the name and the code to make its [`LawDescriptor`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LawNeeds {
    /// One line for humans.
    pub summary: &'static str,
    /// Actuators the law itself commands (the drive's speed loop comes on top when the
    /// controller owns the drive).
    pub actuators: ActuatorSet,
    /// Sensors the law reads besides the suction and discharge pressures and the flow.
    pub sensors: &'static [SensorId],
    /// Whether the law needs the compressor flow.
    pub needs_flow: bool,
    /// Machine data the law needs from the machine description.
    pub machine_data: &'static [MachineData],
    /// Model family of a model-based law.
    pub model_family: Option<ModelKind>,
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

/// A law as the dispatch builds it: its settings, what it needs, how it is built, and how a
/// reload of its settings carries the running state over. One `impl` in the law's own file.
pub trait LawSpec: SurgeLaw + Sized {
    /// What the law is built from: its `[controller.<section>]` (`()`: nothing).
    type Settings;
    /// What the law drives and needs (its registry entry without id, name and code).
    const NEEDS: LawNeeds;
    /// Build the law for a machine (off the control thread: this may allocate).
    fn build(settings: &Self::Settings, model: &ControlModel) -> Result<Self, LawError>;
    /// Hot reload: carry `running`'s dynamic state into this freshly built law. True when the
    /// state was carried over fully; false (the default) and the core starts the law
    /// bumplessly from the applied outputs.
    fn carry_over(&mut self, _running: &Self) -> bool {
        false
    }
    /// Plausibility of the settings beyond their types, as `(key, message)` with the key
    /// relative to `[controller]`: check-config, the start and a reload refuse them. Default:
    /// none.
    fn settings_problems(_settings: &Self::Settings) -> Vec<(String, String)> {
        Vec::new()
    }
}
