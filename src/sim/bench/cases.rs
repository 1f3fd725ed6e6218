//! The matrix's cases and what the field does to the signals in each.

use crate::control::LawId;

/// What the field does to the signals in a case.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FieldFault {
    /// Clean signals.
    None,
    /// White noise: uniform ±1 % of span on each pressure, ±2 % of span on Δp (spans: 1.5× the
    /// initial pressure readings, 2× the initial Δp, i.e. design flow at ≈ 70 % of the flow
    /// range). Fixed seed.
    Noise {
        /// Seed of the noise sequence.
        seed: u64,
    },
    /// The Δp transmitter repeats its value (fresh age) from `at_s` for `for_s`.
    DpFrozen {
        /// Start, s.
        at_s: f64,
        /// Duration, s.
        for_s: f64,
    },
    /// The Δp transmitter drifts: from `at_s` it reads `rate_pct_per_s` % of its span more
    /// per second, up to `max_pct` % of span (a bias that makes it read more flow than
    /// true: the dangerous direction).
    DpDrift {
        /// Start, s.
        at_s: f64,
        /// Drift rate, % of span per s.
        rate_pct_per_s: f64,
        /// Largest offset, % of span.
        max_pct: f64,
    },
    /// Every input arrives `len_s` late, `count` times, every `every_s` from `at_s`.
    Blips {
        /// First blip, s.
        at_s: f64,
        /// Period, s.
        every_s: f64,
        /// Length of each blip, s.
        len_s: f64,
        /// How many.
        count: u32,
    },
    /// No input arrives and no command reaches the plant from `at_s` for `for_s`.
    LinkOutage {
        /// Start, s.
        at_s: f64,
        /// Duration, s.
        for_s: f64,
    },
    /// Not a fault, the field's wiring: the drive's trip contact is wired to the controller
    /// as `esd_input` (bound and supervised like the daemon binds a contact its signal map
    /// names) and reaches it `delay_s` after the plant closes it (a bus poll, a relay). The
    /// other cases leave the contact unwired: the controller sees a drive trip only in the
    /// speed decay.
    EsdContact {
        /// Latency from the drive trip to the controller reading the contact, s.
        delay_s: f64,
    },
}

/// One case of the matrix: a scenario file and what the field does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Case {
    /// Name in the table.
    pub name: &'static str,
    /// Scenario name in `config/scenarios`.
    pub scenario: &'static str,
    /// Field behaviour.
    pub fault: FieldFault,
}

/// The emergency shutdown as the matrix runs it: the trip contact not wired, so the
/// controller sees the drive trip in the speed decay alone ([`TripSignal`] for the other
/// situation).
pub const ESD_CASE: Case = Case {
    name: "ESD rundown",
    scenario: "emergency-shutdown",
    fault: FieldFault::None,
};

/// The cases, in table order.
pub const CASES: [Case; 10] = [
    Case {
        name: "throttle closure",
        scenario: "throttle-closure",
        fault: FieldFault::None,
    },
    Case {
        name: "throttle step",
        scenario: "throttle-step",
        fault: FieldFault::None,
    },
    Case {
        name: "feed drop",
        scenario: "feed-drop",
        fault: FieldFault::None,
    },
    Case {
        name: "speed ramp",
        scenario: "speed-ramp",
        fault: FieldFault::None,
    },
    ESD_CASE,
    Case {
        name: "closure + noise",
        scenario: "throttle-closure",
        fault: FieldFault::Noise { seed: 20261125 },
    },
    Case {
        name: "closure + Δp frozen 1 s",
        scenario: "throttle-closure",
        fault: FieldFault::DpFrozen {
            at_s: 5.5,
            for_s: 1.0,
        },
    },
    Case {
        name: "closure + Δp drift",
        scenario: "throttle-closure",
        fault: FieldFault::DpDrift {
            at_s: 1.0,
            rate_pct_per_s: 1000.0,
            max_pct: 30.0,
        },
    },
    Case {
        name: "closure + 100 ms blips",
        scenario: "throttle-closure",
        fault: FieldFault::Blips {
            at_s: 4.0,
            every_s: 1.0,
            len_s: 0.1,
            count: 10,
        },
    },
    Case {
        name: "closure + 3 s link outage",
        scenario: "throttle-closure",
        fault: FieldFault::LinkOutage {
            at_s: 12.0,
            for_s: 3.0,
        },
    },
];

/// The laws compared.
pub const LAWS: [LawId; 2] = [LawId::RecyclePi, LawId::BaselinePi];
/// The control-line margins, percent of surge-line flow.
pub const MARGINS_PCT: [f64; 2] = [10.0, 5.0];
