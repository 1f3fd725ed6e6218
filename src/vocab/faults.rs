//! The one fault vocabulary: the categories `config/skid.dbc` documents for the heartbeat's
//! `Faults` signal (and its `VAL_` table), used alike by the CAN heartbeat, the Modbus
//! watchdog's `faults` register, the event log and status.
//!
//! A fault word is a bit set, bit `n` = [`FaultCategory`] with code `n`; `0` means healthy.
//! The categories are about *kinds* of trouble, not sensor indices, so a PLC built to the DBC
//! reads them without knowing the controller's internals.

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
    /// than its deviation threshold for the confirmation time (the control core's vote).
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
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
