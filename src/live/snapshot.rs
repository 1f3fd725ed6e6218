//! The live state snapshot: what the operator sees, written by the control thread once per
//! cycle into a [`SeqLock`] (the lock-free hand-off of `runtime::handoff`: plain atomic
//! stores, no allocation, lock or syscall) and read by the status socket, the metrics
//! endpoint, the Modbus block and the persistence task at their own pace.

use serde::{Deserialize, Serialize};

use crate::control::core::MarginShift;
use crate::control::vote::{TransmitterState, VoteRule, VoteStatus, MAX_TRANSMITTERS, VOTABLE};
use crate::control::LawId;
use crate::events::cause::{Cause, CauseKind};
use crate::events::FallbackReason;
use crate::runtime::handoff::SeqLock;
use crate::vocab::signals::SensorId;
use crate::vocab::Mode;

/// Where the flow the law uses comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FlowSourceNow {
    /// No flow (inputs lost).
    None,
    /// The flow element (orifice Δp).
    Orifice,
    /// The observer (configured as the source).
    Observer,
    /// The observer standing in for a failed flow element.
    ObserverFallback,
    /// The speed line's flow standing in for a failed flow element (no observer).
    SpeedLineFallback,
}

impl FlowSourceNow {
    const ALL: [FlowSourceNow; 5] = [
        FlowSourceNow::None,
        FlowSourceNow::Orifice,
        FlowSourceNow::Observer,
        FlowSourceNow::ObserverFallback,
        FlowSourceNow::SpeedLineFallback,
    ];
    /// Numeric code (Modbus block).
    pub fn code(self) -> u8 {
        self as u8
    }

    /// snake_case name, as in `antisurge status --json`.
    pub const fn name(self) -> &'static str {
        match self {
            FlowSourceNow::None => "none",
            FlowSourceNow::Orifice => "orifice",
            FlowSourceNow::Observer => "observer",
            FlowSourceNow::ObserverFallback => "observer_fallback",
            FlowSourceNow::SpeedLineFallback => "speed_line_fallback",
        }
    }
}

/// One cycle's operator view. All flows in the map's flow coordinate unless the name says
/// kg/s; NaN where unknown.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiveSnapshot {
    /// Control cycle number.
    pub cycle: u64,
    /// Monotonic time of the cycle, ns.
    pub t_ns: u64,
    /// Mode.
    pub mode: Mode,
    /// Active law.
    pub law: LawId,
    /// Flow source.
    pub flow_source: FlowSourceNow,
    /// Bit i set when sensor i is not usable.
    pub fault_bits: u32,
    /// The field links' fault word this cycle ([`crate::io::link::FieldFaults::word`]).
    pub field_faults: u32,
    /// Cause of the last mode change (None before the first).
    pub cause: Option<Cause>,
    /// Operating point: flow in map coordinates.
    pub flow_map: f64,
    /// Operating point: pressure ratio.
    pub pressure_ratio: f64,
    /// Mass flow the law uses, kg/s.
    pub m_kg_s: f64,
    /// Shaft speed, rad/s.
    pub omega_rad_s: f64,
    /// Suction pressure the cycle used, Pa (NaN: not usable or not bound).
    pub p_suction_pa: f64,
    /// Discharge pressure the cycle used, Pa (NaN: not usable or not bound).
    pub p_discharge_pa: f64,
    /// Flow element's Δp the cycle used (the vote's value where redundant), Pa (NaN: no
    /// usable flow element, e.g. a skid without one or a frozen transmitter).
    pub orifice_dp_pa: f64,
    /// Suction temperature the cycle measured, K (NaN where the skid has no usable
    /// transmitter: the cycle then uses the machine's nominal temperature, which is no
    /// measurement and is not shown as one).
    pub t_suction_k: f64,
    /// Surge-line flow at the current ratio.
    pub surge_line_flow: f64,
    /// Control-line flow at the current ratio (with the safety-on shift).
    pub control_line_flow: f64,
    /// Trip-line flow at the current ratio.
    pub trip_line_flow: f64,
    /// Deviation from the control line, % of the control-line flow (positive = safe side).
    pub deviation_pct: f64,
    /// Surge margin (q − j(R))/j(R), %.
    pub surge_margin_pct: f64,
    /// Safety-on shift of the control line, % of surge-line flow.
    pub safety_on_shift_pct: f64,
    /// Safety-on steps in force.
    pub safety_on_count: u32,
    /// Surge counter.
    pub surge_count: u64,
    /// Recycle trips since start.
    pub trip_count: u64,
    /// Recycle valve output commanded, fraction.
    pub valve_output: f64,
    /// Recycle valve position measured, fraction.
    pub valve_position: f64,
    /// Manual-station output, fraction (NaN: not set).
    pub manual_output: f64,
    /// Whether automatic mode is requested (false: the manual station).
    pub auto_requested: bool,
    /// The votes of redundant transmitters and the degraded margin shift.
    pub votes: VoteLamps,
}

/// Redundant transmitters: each vote (in [`VOTABLE`] order; `bound` 0 where none) and the
/// degraded policy's margin shift.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoteLamps {
    /// The votes.
    pub votes: [VoteStatus; VOTABLE.len()],
    /// The control-line shift in force and its causes.
    pub shift: MarginShift,
}

impl Default for VoteLamps {
    fn default() -> Self {
        VoteLamps {
            votes: VOTABLE.map(VoteStatus::none),
            shift: MarginShift::default(),
        }
    }
}

fn rule_code(r: VoteRule) -> u64 {
    match r {
        VoteRule::None => 0,
        VoteRule::Median => 1,
        VoteRule::Conservative => 2,
        VoteRule::HoldLast => 3,
    }
}

fn rule_of(c: u64) -> VoteRule {
    match c & 3 {
        1 => VoteRule::Median,
        2 => VoteRule::Conservative,
        3 => VoteRule::HoldLast,
        _ => VoteRule::None,
    }
}

impl Default for LiveSnapshot {
    fn default() -> Self {
        LiveSnapshot {
            cycle: 0,
            t_ns: 0,
            mode: Mode::Init,
            law: LawId::None,
            flow_source: FlowSourceNow::None,
            fault_bits: 0,
            field_faults: 0,
            cause: None,
            flow_map: f64::NAN,
            pressure_ratio: f64::NAN,
            m_kg_s: f64::NAN,
            omega_rad_s: f64::NAN,
            p_suction_pa: f64::NAN,
            p_discharge_pa: f64::NAN,
            orifice_dp_pa: f64::NAN,
            t_suction_k: f64::NAN,
            surge_line_flow: f64::NAN,
            control_line_flow: f64::NAN,
            trip_line_flow: f64::NAN,
            deviation_pct: f64::NAN,
            surge_margin_pct: f64::NAN,
            safety_on_shift_pct: 0.0,
            safety_on_count: 0,
            surge_count: 0,
            trip_count: 0,
            valve_output: f64::NAN,
            valve_position: f64::NAN,
            manual_output: f64::NAN,
            auto_requested: true,
            votes: VoteLamps::default(),
        }
    }
}

/// Words of the scalar snapshot, then the votes: per measurement its value and three
/// transmitter readings, two words of codes, four of the margin shift.
const VOTE_AT: usize = 29;
const WORDS: usize = VOTE_AT + 4 * VOTABLE.len() + 2 + 4;

fn mode_of(code: u8) -> Mode {
    match code {
        1 => Mode::Manual,
        2 => Mode::Auto,
        3 => Mode::FailSafe,
        _ => Mode::Init,
    }
}

fn law_of(code: u8) -> LawId {
    LawId::ALL
        .into_iter()
        .find(|l| l.code() == code)
        .unwrap_or(LawId::None)
}

fn fault_code(f: Option<FallbackReason>) -> u8 {
    match f {
        None => 0,
        Some(FallbackReason::Stale) => 1,
        Some(FallbackReason::OutOfRange) => 2,
        Some(FallbackReason::Nan) => 3,
        Some(FallbackReason::AliveCounter) => 4,
        Some(FallbackReason::BusOff) => 5,
        Some(FallbackReason::Frozen) => 6,
        Some(FallbackReason::Drift) => 7,
    }
}

fn fault_of(c: u8) -> Option<FallbackReason> {
    Some(match c {
        1 => FallbackReason::Stale,
        2 => FallbackReason::OutOfRange,
        3 => FallbackReason::Nan,
        4 => FallbackReason::AliveCounter,
        5 => FallbackReason::BusOff,
        6 => FallbackReason::Frozen,
        7 => FallbackReason::Drift,
        _ => return None,
    })
}

fn opt(x: Option<f64>) -> u64 {
    x.unwrap_or(f64::NAN).to_bits()
}

fn unopt(w: u64) -> Option<f64> {
    let x = f64::from_bits(w);
    x.is_finite().then_some(x)
}

/// The snapshot board: one writer (the control thread), any number of readers.
#[derive(Debug, Default)]
pub struct LiveBoard {
    lock: SeqLock<WORDS>,
}

impl LiveBoard {
    /// Publish (control thread only). Allocation-free.
    #[inline]
    pub fn publish(&self, s: &LiveSnapshot) {
        let c = s.cause;
        let kind = c.map(|c| c.kind.code()).unwrap_or(0);
        let input = c
            .and_then(|c| c.input)
            .map(|i| i.index() as u8 + 1)
            .unwrap_or(0);
        let fault = fault_code(c.and_then(|c| c.fault));
        let codes = u64::from(s.mode.code())
            | u64::from(s.law.code()) << 8
            | u64::from(s.flow_source.code()) << 16
            | u64::from(kind) << 24
            | u64::from(input) << 32
            | u64::from(fault) << 40
            | u64::from(s.auto_requested) << 48
            | u64::from(c.and_then(|c| c.link).map_or(0, |l| l.code())) << 56;
        let w = [
            s.cycle,
            s.t_ns,
            codes,
            u64::from(s.fault_bits) | u64::from(s.safety_on_count) << 32,
            s.surge_count,
            s.trip_count,
            s.flow_map.to_bits(),
            s.pressure_ratio.to_bits(),
            s.m_kg_s.to_bits(),
            s.omega_rad_s.to_bits(),
            s.surge_line_flow.to_bits(),
            s.control_line_flow.to_bits(),
            s.trip_line_flow.to_bits(),
            s.deviation_pct.to_bits(),
            s.surge_margin_pct.to_bits(),
            s.safety_on_shift_pct.to_bits(),
            s.valve_output.to_bits(),
            s.valve_position.to_bits(),
            s.manual_output.to_bits(),
            opt(c.and_then(|c| c.value)),
            opt(c.and_then(|c| c.min)),
            opt(c.and_then(|c| c.max)),
            opt(c.and_then(|c| c.age_ms)),
            opt(c.and_then(|c| c.timeout_ms)),
            s.p_suction_pa.to_bits(),
            s.p_discharge_pa.to_bits(),
            s.orifice_dp_pa.to_bits(),
            s.t_suction_k.to_bits(),
            u64::from(s.field_faults),
        ];
        let mut w = {
            let mut all = [0u64; WORDS];
            all[..VOTE_AT].copy_from_slice(&w);
            all
        };
        // states: 3 bits per transmitter (12 × 3 = 36 bits); rule 2, valid 2, bound 2,
        // degraded 1 bit per measurement (7 × 4 = 28 bits)
        let (mut states, mut meta) = (0u64, 0u64);
        for (k, v) in s.votes.votes.iter().enumerate() {
            let at = VOTE_AT + 4 * k;
            w[at] = v.value.to_bits();
            for t in 0..MAX_TRANSMITTERS {
                w[at + 1 + t] = v.values[t].to_bits();
                states |= u64::from(v.states[t].code() & 7) << (3 * (MAX_TRANSMITTERS * k + t));
            }
            meta |= (rule_code(v.rule)
                | u64::from(v.valid & 3) << 2
                | u64::from(v.bound & 3) << 4
                | u64::from(v.degraded) << 6)
                << (7 * k);
        }
        let at = VOTE_AT + 4 * VOTABLE.len();
        w[at] = states;
        w[at + 1] = meta;
        let sh = &s.votes.shift;
        w[at + 2] = sh.now.to_bits();
        w[at + 3] = sh.target.to_bits();
        w[at + 4] = sh.vote.to_bits();
        w[at + 5] = sh.slow_link.to_bits();
        self.lock.write(&w);
    }

    /// The latest snapshot, or `None` before the first cycle.
    pub fn latest(&self) -> Option<LiveSnapshot> {
        let (w, n) = self.lock.read();
        if n == 0 {
            return None;
        }
        let f = |i: usize| f64::from_bits(w[i]);
        let codes = w[2];
        let byte = |k: u32| ((codes >> k) & 0xff) as u8;
        let cause = CauseKind::from_code(byte(24)).map(|kind| Cause {
            kind,
            input: match byte(32) {
                0 => None,
                i => SensorId::ALL.get(usize::from(i) - 1).copied(),
            },
            fault: fault_of(byte(40)),
            value: unopt(w[19]),
            min: unopt(w[20]),
            max: unopt(w[21]),
            age_ms: unopt(w[22]),
            timeout_ms: unopt(w[23]),
            link: crate::vocab::faults::FieldLinkKind::from_code(byte(56)),
        });
        Some(LiveSnapshot {
            cycle: w[0],
            t_ns: w[1],
            mode: mode_of(byte(0)),
            law: law_of(byte(8)),
            flow_source: FlowSourceNow::ALL
                .get(usize::from(byte(16)))
                .copied()
                .unwrap_or(FlowSourceNow::None),
            fault_bits: w[3] as u32,
            field_faults: w[28] as u32,
            safety_on_count: (w[3] >> 32) as u32,
            cause,
            surge_count: w[4],
            trip_count: w[5],
            flow_map: f(6),
            pressure_ratio: f(7),
            m_kg_s: f(8),
            omega_rad_s: f(9),
            p_suction_pa: f(24),
            p_discharge_pa: f(25),
            orifice_dp_pa: f(26),
            t_suction_k: f(27),
            surge_line_flow: f(10),
            control_line_flow: f(11),
            trip_line_flow: f(12),
            deviation_pct: f(13),
            surge_margin_pct: f(14),
            safety_on_shift_pct: f(15),
            valve_output: f(16),
            valve_position: f(17),
            manual_output: f(18),
            auto_requested: byte(48) != 0,
            votes: {
                let at = VOTE_AT + 4 * VOTABLE.len();
                let (states, meta) = (w[at], w[at + 1]);
                let mut votes = VoteLamps::default();
                for (k, v) in votes.votes.iter_mut().enumerate() {
                    let base = VOTE_AT + 4 * k;
                    v.value = f(base);
                    for t in 0..MAX_TRANSMITTERS {
                        v.values[t] = f(base + 1 + t);
                        v.states[t] = TransmitterState::from_code(
                            ((states >> (3 * (MAX_TRANSMITTERS * k + t))) & 7) as u8,
                        );
                    }
                    let m = meta >> (7 * k);
                    v.rule = rule_of(m);
                    v.valid = ((m >> 2) & 3) as u8;
                    v.bound = ((m >> 4) & 3) as u8;
                    v.degraded = (m >> 6) & 1 != 0;
                }
                votes.shift = MarginShift {
                    now: f(at + 2),
                    target: f(at + 3),
                    vote: f(at + 4),
                    slow_link: f(at + 5),
                };
                votes
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_every_field() {
        let b = LiveBoard::default();
        assert!(b.latest().is_none());
        let s = LiveSnapshot {
            cycle: 12,
            t_ns: 34,
            mode: Mode::FailSafe,
            law: LawId::RecyclePi,
            flow_source: FlowSourceNow::ObserverFallback,
            fault_bits: 0b1010,
            field_faults: 0x0300,
            cause: Some(Cause {
                kind: CauseKind::InputFault,
                input: Some(SensorId::PDischarge),
                fault: Some(FallbackReason::OutOfRange),
                value: Some(2.1e7),
                min: Some(1e4),
                max: Some(1.2e7),
                age_ms: Some(1.0),
                timeout_ms: Some(50.0),
                link: Some(crate::vocab::faults::FieldLinkKind::Modbus),
            }),
            flow_map: 1.5,
            pressure_ratio: 2.5,
            m_kg_s: 1.6,
            omega_rad_s: 900.0,
            p_suction_pa: 1.01e5,
            p_discharge_pa: 2.5e5,
            orifice_dp_pa: 1.2e4,
            t_suction_k: 293.15,
            surge_line_flow: 1.0,
            control_line_flow: 1.1,
            trip_line_flow: 1.05,
            deviation_pct: 36.0,
            surge_margin_pct: 50.0,
            safety_on_shift_pct: 5.0,
            safety_on_count: 1,
            surge_count: 3,
            trip_count: 2,
            valve_output: 0.2,
            valve_position: 0.21,
            manual_output: f64::NAN,
            auto_requested: false,
            votes: {
                let mut v = VoteLamps::default();
                v.votes[3] = VoteStatus {
                    input: SensorId::OrificeDp,
                    bound: 3,
                    valid: 2,
                    rule: VoteRule::Conservative,
                    value: 1000.0,
                    values: [1000.0, 1200.0, 1001.0],
                    states: [
                        TransmitterState::Healthy,
                        TransmitterState::Deviating,
                        TransmitterState::VotedOut(crate::control::vote::TransmitterCheck::Frozen),
                    ],
                    degraded: true,
                };
                v.shift = MarginShift {
                    now: 0.02,
                    target: 0.05,
                    vote: 0.05,
                    slow_link: 0.0,
                };
                v
            },
        };
        b.publish(&s);
        let r = b.latest().expect("published");
        assert_eq!(format!("{r:?}"), format!("{s:?}"));
        let mut none = s;
        none.cause = None;
        b.publish(&none);
        assert_eq!(b.latest().expect("published").cause, None);
    }
}
