//! The one fault vocabulary: the categories `config/skid.dbc` documents for the heartbeat's
//! `Faults` signal (and its `VAL_` table), used alike by the CAN heartbeat, the Modbus
//! watchdog's `faults` register, the event log and status.
//!
//! A fault word is a bit set, bit `n` = [`FaultCategory`] with code `n`; `0` means healthy.
//! The categories are about *kinds* of trouble, not sensor indices, so a PLC built to the DBC
//! reads them without knowing the controller's internals.

use crate::control::supervisor::{InputFault, Supervisor, Validity};
use crate::signals::SensorId;
use serde::{Deserialize, Serialize};

/// A fault category (bit number = [`code`](Self::code)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultCategory {
    /// A sensor value missed its deadline (stale).
    SensorTimeout,
    /// A sender's alive counter skipped or repeated.
    SensorAliveError,
    /// A frame failed its CRC.
    SensorCrcError,
    /// A sensor value is NaN or outside its plausible range.
    SensorImplausible,
    /// A surge cycle was detected.
    SurgeDetected,
    /// An actuator command was saturated.
    ActuatorSaturated,
    /// The control step missed its deadline.
    CycleOverrun,
    /// The configuration is inconsistent.
    ConfigError,
    /// An actuator's measured position (or delivered torque) differs from its command for
    /// longer than the configured time.
    ActuatorFeedbackMismatch,
    /// A field device refused or did not answer writes (exception or timeout).
    FieldWriteFailed,
    /// A field link (CAN interface, Modbus connection) is down.
    FieldLinkDown,
    /// A field link answers, but slower than its configured rate or than its inputs'
    /// freshness allows (achieved poll period, answer latency).
    FieldLinkSlow,
    /// An actuator's command register, read back, holds a value this controller did not
    /// write: another master writes it (latched until acknowledged).
    AnotherWriter,
    /// Redundant transmitters of one measurement disagree: one stays further from the vote
    /// than its deviation threshold for the confirmation time ([`crate::control::vote`]).
    TransmitterDeviation,
    /// A redundant measurement's vote runs on fewer transmitters than bound (or fewer than
    /// two that agree): the control line is shifted by the degraded margin.
    VoteDegraded,
}

impl FaultCategory {
    /// Every category, in bit order.
    pub const ALL: [FaultCategory; 15] = [
        FaultCategory::SensorTimeout,
        FaultCategory::SensorAliveError,
        FaultCategory::SensorCrcError,
        FaultCategory::SensorImplausible,
        FaultCategory::SurgeDetected,
        FaultCategory::ActuatorSaturated,
        FaultCategory::CycleOverrun,
        FaultCategory::ConfigError,
        FaultCategory::ActuatorFeedbackMismatch,
        FaultCategory::FieldWriteFailed,
        FaultCategory::FieldLinkDown,
        FaultCategory::FieldLinkSlow,
        FaultCategory::AnotherWriter,
        FaultCategory::TransmitterDeviation,
        FaultCategory::VoteDegraded,
    ];

    /// Bit number on the wire (the DBC's `Faults` documentation).
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The bit of this category in a fault word.
    pub const fn bit(self) -> u32 {
        1 << self.code()
    }

    /// snake_case name, as in the DBC's value table and the event log.
    pub const fn name(self) -> &'static str {
        match self {
            FaultCategory::SensorTimeout => "sensor_timeout",
            FaultCategory::SensorAliveError => "sensor_alive_error",
            FaultCategory::SensorCrcError => "sensor_crc_error",
            FaultCategory::SensorImplausible => "sensor_implausible",
            FaultCategory::SurgeDetected => "surge_detected",
            FaultCategory::ActuatorSaturated => "actuator_saturated",
            FaultCategory::CycleOverrun => "cycle_overrun",
            FaultCategory::ConfigError => "config_error",
            FaultCategory::ActuatorFeedbackMismatch => "actuator_feedback_mismatch",
            FaultCategory::FieldWriteFailed => "field_write_failed",
            FaultCategory::FieldLinkDown => "field_link_down",
            FaultCategory::FieldLinkSlow => "field_link_slow",
            FaultCategory::AnotherWriter => "another_writer",
            FaultCategory::TransmitterDeviation => "transmitter_deviation",
            FaultCategory::VoteDegraded => "vote_degraded",
        }
    }

    /// Words an operator understands.
    pub const fn describe(self) -> &'static str {
        match self {
            FaultCategory::SensorTimeout => "a sensor stopped updating",
            FaultCategory::SensorAliveError => "a sender's alive counter skipped or repeated",
            FaultCategory::SensorCrcError => "a sensor frame failed its checksum",
            FaultCategory::SensorImplausible => "a sensor reads no value or an implausible one",
            FaultCategory::SurgeDetected => "a surge cycle was detected",
            FaultCategory::ActuatorSaturated => "an actuator command hit its limit",
            FaultCategory::CycleOverrun => "the control step missed its deadline",
            FaultCategory::ConfigError => "the configuration is inconsistent",
            FaultCategory::ActuatorFeedbackMismatch => "an actuator does not follow its command",
            FaultCategory::FieldWriteFailed => "a field device refuses or ignores writes",
            FaultCategory::FieldLinkDown => "a field link is down",
            FaultCategory::FieldLinkSlow => {
                "a field link answers slower than its rate or its inputs' freshness allows"
            }
            FaultCategory::AnotherWriter => "another master writes an actuator's command register",
            FaultCategory::TransmitterDeviation => {
                "redundant transmitters of one measurement disagree"
            }
            FaultCategory::VoteDegraded => {
                "a redundant measurement is voted on fewer transmitters than bound"
            }
        }
    }

    /// The category of a bit number, if defined.
    pub fn from_code(code: u8) -> Option<FaultCategory> {
        Self::ALL.get(usize::from(code)).copied()
    }
}

/// The kind of a field link, as a fault's root cause names it ("the Modbus link is down", not
/// the sensors it carries).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FieldLinkKind {
    /// A CAN interface (SocketCAN).
    Can,
    /// A Modbus connection (TCP or RTU).
    Modbus,
}

impl FieldLinkKind {
    /// Both kinds, in code order.
    pub const ALL: [FieldLinkKind; 2] = [FieldLinkKind::Can, FieldLinkKind::Modbus];

    /// The kind of a link by its reporter's name (`modbus:10.0.0.5:502`, `can0`).
    pub fn of_link_name(name: &str) -> FieldLinkKind {
        if name.starts_with("modbus") {
            FieldLinkKind::Modbus
        } else {
            FieldLinkKind::Can
        }
    }

    /// Code (live snapshot): 1 + position in [`Self::ALL`]; 0 is "none".
    pub const fn code(self) -> u8 {
        match self {
            FieldLinkKind::Can => 1,
            FieldLinkKind::Modbus => 2,
        }
    }

    /// Inverse of [`Self::code`].
    pub fn from_code(c: u8) -> Option<FieldLinkKind> {
        Self::ALL.get(usize::from(c).checked_sub(1)?).copied()
    }

    /// Name for an operator.
    pub const fn name(self) -> &'static str {
        match self {
            FieldLinkKind::Can => "CAN",
            FieldLinkKind::Modbus => "Modbus",
        }
    }
}

/// A fault word: bit set of [`FaultCategory`]. `FaultSet::default()` is healthy (0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub struct FaultSet(pub u32);

impl FaultSet {
    /// Healthy.
    pub const NONE: FaultSet = FaultSet(0);

    /// Add a category.
    pub fn set(&mut self, c: FaultCategory) {
        self.0 |= c.bit();
    }

    /// Whether a category is active.
    pub const fn has(self, c: FaultCategory) -> bool {
        self.0 & c.bit() != 0
    }

    /// Active categories, in bit order (bits without a category are ignored).
    pub fn categories(self) -> impl Iterator<Item = FaultCategory> {
        FaultCategory::ALL.into_iter().filter(move |c| self.has(*c))
    }

    /// Input faults in categories. Sensors the supervisor does not use (no limits) are not
    /// faults: a healthy controller that reads only some sensors sends 0. Allocation-free.
    pub fn from_validity(v: &Validity, supervisor: &Supervisor) -> FaultSet {
        let mut f = FaultSet::NONE;
        for id in SensorId::ALL {
            if supervisor.limits[id.index()].is_none() {
                continue;
            }
            match v.fault[id.index()] {
                InputFault::None => {}
                InputFault::Stale => f.set(FaultCategory::SensorTimeout),
                InputFault::Nan
                | InputFault::OutOfRange
                | InputFault::Frozen
                | InputFault::Drift => f.set(FaultCategory::SensorImplausible),
            }
        }
        f
    }

    /// Faults of the votes of redundant transmitters: `transmitter_deviation` while one is
    /// deviating, `vote_degraded` while a vote is degraded. Allocation-free.
    pub fn from_vote(vote: &crate::control::vote::Vote) -> FaultSet {
        Self::from_votes(&vote.status())
    }

    /// [`from_vote`](Self::from_vote) of votes as published (the live snapshot's).
    pub fn from_votes(votes: &[crate::control::vote::VoteStatus]) -> FaultSet {
        let mut f = FaultSet::NONE;
        for s in votes.iter().filter(|s| s.bound > 0) {
            if s.deviating() {
                f.set(FaultCategory::TransmitterDeviation);
            }
            if s.degraded {
                f.set(FaultCategory::VoteDegraded);
            }
        }
        f
    }
}

/// Field faults (links, writes, actuator feedback) raised by the I/O tasks, for the fault
/// word on the wire: per category, how many sources have it active. The control thread's
/// input faults and these are OR-ed into the heartbeat's `Faults` and the Modbus watchdog's
/// `faults` register, so a PLC sees a refused write or a valve that does not follow.
pub mod field {
    use super::{FaultCategory, FaultSet};
    use std::sync::atomic::{AtomicU32, Ordering};

    #[allow(clippy::declare_interior_mutable_const)]
    const ZERO: AtomicU32 = AtomicU32::new(0);
    static ACTIVE: [AtomicU32; FaultCategory::ALL.len()] = [ZERO; FaultCategory::ALL.len()];

    /// One source raised `c` (pair with [`clear`]).
    pub fn raise(c: FaultCategory) {
        ACTIVE[usize::from(c.code())].fetch_add(1, Ordering::Relaxed);
    }

    /// One source cleared `c`.
    pub fn clear(c: FaultCategory) {
        let _ =
            ACTIVE[usize::from(c.code())]
                .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |n| n.checked_sub(1));
    }

    static LINKS_DOWN: [AtomicU32; super::FieldLinkKind::ALL.len()] = [ZERO; 2];

    /// A link of `kind` went down (`true`) or came back up (`false`; pair with a down).
    pub fn link_down(kind: super::FieldLinkKind, down: bool) {
        let n = &LINKS_DOWN[usize::from(kind.code() - 1)];
        if down {
            n.fetch_add(1, Ordering::Relaxed);
        } else {
            let _ = n.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |n| n.checked_sub(1));
        }
    }

    /// The first kind of link that is down now, if any. Allocation-free.
    pub fn down_link() -> Option<super::FieldLinkKind> {
        super::FieldLinkKind::ALL
            .into_iter()
            .find(|k| LINKS_DOWN[usize::from(k.code() - 1)].load(Ordering::Relaxed) > 0)
    }

    /// The first kind of link among `kinds` (bits of `1 << FieldLinkKind::code`) that is
    /// down now, if any. Allocation-free.
    pub fn down_link_among(kinds: u8) -> Option<super::FieldLinkKind> {
        first_down_among(kinds, |k| {
            LINKS_DOWN[usize::from(k.code() - 1)].load(Ordering::Relaxed) > 0
        })
    }

    /// The first kind among `kinds` for which `down` holds.
    pub(crate) fn first_down_among(
        kinds: u8,
        down: impl Fn(super::FieldLinkKind) -> bool,
    ) -> Option<super::FieldLinkKind> {
        super::FieldLinkKind::ALL
            .into_iter()
            .find(|k| kinds & (1 << k.code()) != 0 && down(*k))
    }

    /// The active field faults as a fault word. Allocation-free.
    pub fn word() -> u32 {
        let mut f = FaultSet::NONE;
        for c in FaultCategory::ALL {
            if ACTIVE[usize::from(c.code())].load(Ordering::Relaxed) > 0 {
                f.set(c);
            }
        }
        f.0
    }
}

/// The DBC `VAL_` entries of a `Faults` signal: one value per single-bit word
/// (`1 "sensor_timeout" 2 "sensor_alive_error" …`), for message `id` and `signal`.
pub fn dbc_value_table(id: u32, signal: &str) -> String {
    let mut s = format!("VAL_ {id} {signal} 0 \"healthy\"");
    for c in FaultCategory::ALL {
        s += &format!(" {} \"{}\"", c.bit(), c.name());
    }
    s + " ;"
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::supervisor::InputLimits;

    #[test]
    fn codes_follow_the_dbc_documentation() {
        assert_eq!(FaultCategory::SensorTimeout.bit(), 1);
        assert_eq!(FaultCategory::ConfigError.bit(), 128);
        assert_eq!(FaultCategory::ActuatorFeedbackMismatch.bit(), 256);
        for (i, c) in FaultCategory::ALL.iter().enumerate() {
            assert_eq!(usize::from(c.code()), i);
            assert_eq!(FaultCategory::from_code(c.code()), Some(*c));
        }
        assert_eq!(FaultCategory::from_code(31), None);
    }

    #[test]
    fn unused_sensors_are_not_faults_and_kinds_map_to_categories() {
        let lim = InputLimits {
            min: 0.0,
            max: 1.0,
            timeout_s: 0.1,
        };
        let mut limits = [None; SensorId::COUNT];
        limits[SensorId::PSuction.index()] = Some(lim);
        limits[SensorId::OrificeDp.index()] = Some(lim);
        let sup = Supervisor { limits };
        // thrust position (index 7) unused and "NaN": healthy, not 128 (config_error)
        let mut fault = [InputFault::None; SensorId::COUNT];
        fault[SensorId::ThrustPosition.index()] = InputFault::Nan;
        let v = Validity { fault };
        assert_eq!(FaultSet::from_validity(&v, &sup), FaultSet::NONE);
        fault[SensorId::PSuction.index()] = InputFault::Stale;
        fault[SensorId::OrificeDp.index()] = InputFault::OutOfRange;
        let f = FaultSet::from_validity(&Validity { fault }, &sup);
        assert_eq!(f.0, 1 | 8);
        let names: Vec<&str> = f.categories().map(|c| c.name()).collect();
        assert_eq!(names, ["sensor_timeout", "sensor_implausible"]);
    }

    #[test]
    fn shipped_dbc_documents_this_vocabulary() {
        let dbc = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/skid.dbc"),
        )
        .expect("skid.dbc");
        assert!(
            dbc.contains(&dbc_value_table(128, "Faults")),
            "config/skid.dbc must carry: {}",
            dbc_value_table(128, "Faults")
        );
        for c in FaultCategory::ALL {
            assert!(
                dbc.contains(&format!("bit {} {}", c.code(), c.name())),
                "{}",
                c.name()
            );
        }
    }

    #[test]
    fn field_faults_count_their_sources() {
        // (a category no other test raises)
        let c = FaultCategory::CycleOverrun;
        field::raise(c);
        field::raise(c);
        field::clear(c);
        assert_ne!(field::word() & c.bit(), 0, "one source still active");
        field::clear(c);
        field::clear(c);
        assert_eq!(field::word() & c.bit(), 0);
    }

    #[test]
    fn value_table_lists_every_category() {
        let t = dbc_value_table(128, "Faults");
        assert!(t.starts_with("VAL_ 128 Faults 0 \"healthy\" 1 \"sensor_timeout\""));
        assert!(t.contains("256 \"actuator_feedback_mismatch\""));
        assert!(t.ends_with(" ;"));
    }

    #[test]
    fn a_link_down_roots_only_the_inputs_of_its_kind() {
        use super::field::first_down_among;
        let can_down = |k: FieldLinkKind| k == FieldLinkKind::Can;
        let can = 1 << FieldLinkKind::Can.code();
        let modbus = 1 << FieldLinkKind::Modbus.code();
        assert_eq!(first_down_among(can, can_down), Some(FieldLinkKind::Can));
        assert_eq!(first_down_among(modbus, can_down), None, "a Modbus input");
        assert_eq!(
            first_down_among(can | modbus, can_down),
            Some(FieldLinkKind::Can)
        );
        assert_eq!(first_down_among(0, can_down), None, "on no field link");
        assert_eq!(
            first_down_among(u8::MAX, can_down),
            Some(FieldLinkKind::Can),
            "not told: any link"
        );
    }
}
