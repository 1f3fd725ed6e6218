//! The vote's vocabulary: how many transmitters a measurement may have, their names, the
//! side of each measurement that shows less surge margin, and the settings of a vote. The
//! signal map (which binds the transmitters and reads the settings) and the vote itself
//! ([`crate::control::vote`], which uses them each cycle) share these words.

use super::signals::SensorId;

/// Most transmitters per measurement.
pub const MAX_TRANSMITTERS: usize = 3;

/// Transmitter names, by slot.
pub const TRANSMITTER_NAMES: [&str; MAX_TRANSMITTERS] = ["a", "b", "c"];

/// Default deviation threshold, % of the vote: ten times a good transmitter's reading error
/// (accuracy class 0.1–0.5 % incl. drift), so healthy transmitters never reach it; a 20 %
/// bias is four times it. For a Δp it is 2.5 % of flow, a quarter of the default 10 % control
/// margin.
pub const DEFAULT_DEVIATION_PCT: f64 = 5.0;
/// Default confirmation of a deviation, s: five times a Δp transmitter's usual 0.1 s damping,
/// so transmitters damped differently do not part during a fast closure for that long.
pub const DEFAULT_DEVIATION_S: f64 = 0.5;
/// Default control-line shift while a vote is degraded, % of the control-line flow: the
/// error a degraded vote can no longer catch is up to the deviation threshold (5 %), which
/// moves the operating point by at most that fraction of flow (half of it for Δp and suction
/// pressure, through the square root).
pub const DEFAULT_DEGRADED_MARGIN_PCT: f64 = 5.0;

/// Which side of a measurement shows less surge margin (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Conservative {
    /// The lower reading.
    Low,
    /// The higher reading.
    High,
}

impl Conservative {
    /// The side of `id`, `None` for a measurement that takes no vote.
    pub const fn of(id: SensorId) -> Option<Conservative> {
        match id {
            SensorId::OrificeDp | SensorId::PSuction => Some(Conservative::Low),
            SensorId::PDischarge | SensorId::TSuction => Some(Conservative::High),
            _ => None,
        }
    }

    /// The conservative one of two readings.
    #[inline]
    pub fn pick(self, x: f64, y: f64) -> f64 {
        match self {
            Conservative::Low => x.min(y),
            Conservative::High => x.max(y),
        }
    }

    /// Name ("lower"/"higher") for messages.
    pub const fn name(self) -> &'static str {
        match self {
            Conservative::Low => "lower",
            Conservative::High => "higher",
        }
    }
}

/// The measurements that can take a vote, in the order they are voted (pressures before the
/// Δp, whose frozen check reads them).
pub const VOTABLE: [SensorId; 4] = [
    SensorId::PSuction,
    SensorId::PDischarge,
    SensorId::TSuction,
    SensorId::OrificeDp,
];

/// Position of `id` in [`VOTABLE`].
pub fn votable_index(id: SensorId) -> Option<usize> {
    VOTABLE.iter().position(|v| *v == id)
}

/// The vote settings of one measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoteLimits {
    /// Transmitters bound: 2 or 3.
    pub transmitters: u8,
    /// Deviation threshold, fraction of the vote.
    pub deviation: f64,
    /// Deviation confirmation, s.
    pub deviation_s: f64,
    /// Control-line shift while the vote is degraded, fraction of the control-line flow.
    pub degraded_margin: f64,
}

impl VoteLimits {
    /// `n` transmitters with the default threshold, confirmation and shift.
    pub fn defaults(n: u8) -> VoteLimits {
        VoteLimits {
            transmitters: n,
            deviation: 0.01 * DEFAULT_DEVIATION_PCT,
            deviation_s: DEFAULT_DEVIATION_S,
            degraded_margin: 0.01 * DEFAULT_DEGRADED_MARGIN_PCT,
        }
    }
}

/// Vote settings per measurement (None: one transmitter, no vote).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VoteSettings {
    /// Indexed by [`SensorId::index`].
    pub per_sensor: [Option<VoteLimits>; SensorId::COUNT],
}

impl VoteSettings {
    /// Whether any measurement is voted.
    pub fn any(&self) -> bool {
        self.per_sensor.iter().any(Option::is_some)
    }
}
