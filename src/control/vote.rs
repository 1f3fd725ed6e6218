//! Redundant transmitters and their vote (issue 23, item 5).
//!
//! A measurement may be read by two or three transmitters: `a` is the signal map's
//! `[sensors.<sensor>]` binding, `b` and `c` its `[vote.<sensor>]` bindings. Each cycle every
//! transmitter is checked by the same rules as a single input (the supervisor's freshness,
//! NaN and range check, [`Supervisor::check_one`]; for the flow element's Δp also the frozen
//! check, [`FrozenDpCheck`], one per transmitter), and the valid ones are voted into the one
//! value the control core sees:
//!
//! | valid | rule | value |
//! |---|---|---|
//! | 3 of 3 | `median` | the median |
//! | 2 (of 2 or 3) | `conservative` | the one showing less surge margin |
//! | 1 (of 2 or 3) | `hold_last` | the last value two transmitters agreed on, or the survivor where it shows less margin |
//! | 0 | `none` | transmitter `a` as read, with its fault: the core's fallback or fail-safe as for a single input |
//!
//! **The conservative side** (less surge margin) per measurement ([`Conservative`]):
//! - `orifice_dp`: the *lower* Δp (less flow, m ∝ √Δp);
//! - `p_suction`: the *lower* pressure (a higher pressure ratio, a lower gas density: less
//!   flow from the same Δp);
//! - `p_discharge`: the *higher* pressure (a higher pressure ratio: the surge line's flow is
//!   higher there);
//! - `t_suction`: the *higher* temperature (a lower gas density: less flow from the same Δp).
//!
//! Other measurements (speed, positions, torque, contacts) take no vote: their "less margin"
//! side is not defined by the surge line alone, and the map check refuses a `[vote]` for them.
//!
//! **Hold-last** (one valid transmitter left): the survivor cannot be checked against anything,
//! so it may not take margin away. The vote holds the last value that at least two
//! transmitters agreed on, and follows the survivor only on the conservative side of it: a
//! survivor seeing the flow fall is followed; one failing towards more margin is not. With a
//! `vote_degraded` fault and the degraded margin shift in force.
//!
//! **Deviation alarm**: while at least two transmitters are valid, a transmitter that passes
//! the supervisor's checks (frozen ones included) and stays further than `deviation_pct` of the
//! vote from it for `deviation_s` is *deviating* (`transmitter_deviation` fault, an event
//! naming it). When two other valid transmitters agree meanwhile, the deviation is the
//! transmitter's: it is voted out (check `deviation`) until it has been back within the
//! threshold for `deviation_s`, so a later failure of one of the two leaves the healthy one,
//! not the biased one, in the vote. Of two, the alarm cannot tell which one is wrong: it names
//! the one the vote left aside, both stay in, and the vote keeps the conservative one.
//!
//! **Degraded**: fewer valid transmitters than bound, or fewer than two valid ones that agree.
//! While any vote is degraded the core shifts the control line right by the measurement's
//! `degraded_margin_pct` (see [`crate::control::core`]).
//!
//! Pure and allocation-free: fixed arrays, one call per cycle.

use super::checks::cross_check::FrozenDpCheck;
use super::measurements::RawSensors;
use super::supervisor::{InputFault, Supervisor};
use crate::vocab::faults::{FaultCategory, FaultSet};
use crate::vocab::signals::SensorId;

// The vote's settings and the conservative side of each measurement are words the signal map
// (which binds the transmitters) and the vote share: they live in the vocabulary.
pub use crate::vocab::vote::{
    votable_index, Conservative, VoteLimits, VoteSettings, DEFAULT_DEGRADED_MARGIN_PCT,
    DEFAULT_DEVIATION_PCT, DEFAULT_DEVIATION_S, MAX_TRANSMITTERS, TRANSMITTER_NAMES, VOTABLE,
};

/// Why a transmitter is voted out or alarmed (the check that found it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TransmitterCheck {
    /// No fresh value within the input's timeout.
    Stale,
    /// No value (NaN, a failed read).
    Nan,
    /// Outside the input's plausible range.
    OutOfRange,
    /// Repeating itself while the pressures move (the frozen-Δp check).
    Frozen,
    /// Further from the vote than the deviation threshold for the confirmation time.
    Deviation,
}

impl TransmitterCheck {
    /// snake_case name (events, status, metrics).
    pub const fn name(self) -> &'static str {
        match self {
            TransmitterCheck::Stale => "stale",
            TransmitterCheck::Nan => "nan",
            TransmitterCheck::OutOfRange => "out_of_range",
            TransmitterCheck::Frozen => "frozen",
            TransmitterCheck::Deviation => "deviation",
        }
    }

    fn of(f: InputFault) -> Option<TransmitterCheck> {
        match f {
            InputFault::None | InputFault::Drift => None,
            InputFault::Nan => Some(TransmitterCheck::Nan),
            InputFault::Stale => Some(TransmitterCheck::Stale),
            InputFault::OutOfRange => Some(TransmitterCheck::OutOfRange),
            InputFault::Frozen => Some(TransmitterCheck::Frozen),
        }
    }

    const ALL: [TransmitterCheck; 5] = [
        TransmitterCheck::Stale,
        TransmitterCheck::Nan,
        TransmitterCheck::OutOfRange,
        TransmitterCheck::Frozen,
        TransmitterCheck::Deviation,
    ];

    /// Code 1..=5 (0: none), for the live snapshot.
    pub fn code(c: Option<TransmitterCheck>) -> u8 {
        c.map_or(0, |c| c as u8 + 1)
    }

    /// Inverse of [`code`](Self::code).
    pub fn from_code(code: u8) -> Option<TransmitterCheck> {
        Self::ALL.get(usize::from(code).checked_sub(1)?).copied()
    }
}

/// The state of one transmitter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum TransmitterState {
    /// Not bound.
    #[default]
    Unbound,
    /// Valid and agreeing with the vote.
    Healthy,
    /// Valid, but further from the vote than the deviation threshold (confirmed).
    Deviating,
    /// Not counted in the vote, and why.
    VotedOut(TransmitterCheck),
}

impl TransmitterState {
    /// snake_case name (status, events).
    pub const fn name(self) -> &'static str {
        match self {
            TransmitterState::Unbound => "unbound",
            TransmitterState::Healthy => "healthy",
            TransmitterState::Deviating => "deviating",
            TransmitterState::VotedOut(_) => "voted_out",
        }
    }

    /// The check behind a deviating or voted-out state.
    pub const fn reason(self) -> Option<TransmitterCheck> {
        match self {
            TransmitterState::Deviating => Some(TransmitterCheck::Deviation),
            TransmitterState::VotedOut(c) => Some(c),
            _ => None,
        }
    }

    /// Code (live snapshot): 0 unbound, 1 healthy, 2 deviating, 3 + check code voted out.
    pub fn code(self) -> u8 {
        match self {
            TransmitterState::Unbound => 0,
            TransmitterState::Healthy => 1,
            TransmitterState::Deviating => 2,
            TransmitterState::VotedOut(c) => 2 + TransmitterCheck::code(Some(c)),
        }
    }

    /// Inverse of [`code`](Self::code).
    pub fn from_code(code: u8) -> TransmitterState {
        match code {
            1 => TransmitterState::Healthy,
            2 => TransmitterState::Deviating,
            c if c >= 3 => TransmitterCheck::from_code(c - 2)
                .map_or(TransmitterState::Unbound, TransmitterState::VotedOut),
            _ => TransmitterState::Unbound,
        }
    }
}

/// The rule a vote used this cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum VoteRule {
    /// No transmitter valid (or no vote): transmitter `a` as read.
    #[default]
    None,
    /// Median of three.
    Median,
    /// The conservative one of two.
    Conservative,
    /// One valid transmitter: the last agreed value, or the survivor on its conservative side.
    HoldLast,
}

impl VoteRule {
    /// snake_case name.
    pub const fn name(self) -> &'static str {
        match self {
            VoteRule::None => "none",
            VoteRule::Median => "median",
            VoteRule::Conservative => "conservative",
            VoteRule::HoldLast => "hold_last",
        }
    }
}

/// One measurement's vote this cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoteStatus {
    /// The measurement.
    pub input: SensorId,
    /// Transmitters bound (0: no vote).
    pub bound: u8,
    /// Valid transmitters.
    pub valid: u8,
    /// Rule used.
    pub rule: VoteRule,
    /// The voted value (NaN: none).
    pub value: f64,
    /// Each transmitter's reading (NaN: none) and state.
    pub values: [f64; MAX_TRANSMITTERS],
    /// Each transmitter's state.
    pub states: [TransmitterState; MAX_TRANSMITTERS],
    /// Whether the vote is degraded (fewer valid than bound, or fewer than two that agree).
    pub degraded: bool,
}

impl VoteStatus {
    /// No vote of `input` (nothing bound beyond `a`).
    pub const fn none(input: SensorId) -> VoteStatus {
        VoteStatus {
            input,
            bound: 0,
            valid: 0,
            rule: VoteRule::None,
            value: f64::NAN,
            values: [f64::NAN; MAX_TRANSMITTERS],
            states: [TransmitterState::Unbound; MAX_TRANSMITTERS],
            degraded: false,
        }
    }

    /// Whether a transmitter is deviating (alarmed, or voted out for it).
    pub fn deviating(&self) -> bool {
        self.states
            .iter()
            .any(|s| s.reason() == Some(TransmitterCheck::Deviation))
    }
}

/// One measurement's vote state between cycles.
#[derive(Debug, Clone, Copy)]
struct SensorVote {
    frozen: [FrozenDpCheck; MAX_TRANSMITTERS],
    /// Since when each transmitter has been further from the vote than the threshold, s.
    off_since_s: [f64; MAX_TRANSMITTERS],
    /// Voted out for a deviation the others agreed against, and since when it has been back
    /// within the threshold (s; NaN: not).
    out_for_deviation: [bool; MAX_TRANSMITTERS],
    back_since_s: [f64; MAX_TRANSMITTERS],
    /// The last value at least two transmitters agreed on (NaN: none yet).
    held: f64,
    status: VoteStatus,
}

impl SensorVote {
    const fn new(input: SensorId) -> SensorVote {
        SensorVote {
            frozen: [FrozenDpCheck::new(); MAX_TRANSMITTERS],
            off_since_s: [f64::NAN; MAX_TRANSMITTERS],
            out_for_deviation: [false; MAX_TRANSMITTERS],
            back_since_s: [f64::NAN; MAX_TRANSMITTERS],
            held: f64::NAN,
            status: VoteStatus::none(input),
        }
    }
}

/// The votes of every measurement with redundant transmitters.
#[derive(Debug, Clone)]
pub struct Vote {
    votes: [SensorVote; VOTABLE.len()],
}

impl Default for Vote {
    fn default() -> Self {
        Self::new()
    }
}

/// Faults of the votes of redundant transmitters as published (the live snapshot's):
/// `transmitter_deviation` while one is deviating, `vote_degraded` while a vote is degraded.
/// Allocation-free.
pub fn fault_set(votes: &[VoteStatus]) -> FaultSet {
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

impl Vote {
    /// [`fault_set`] of these votes. Allocation-free.
    pub fn fault_set(&self) -> FaultSet {
        fault_set(&self.status())
    }

    /// No history.
    pub const fn new() -> Vote {
        Vote {
            votes: [
                SensorVote::new(VOTABLE[0]),
                SensorVote::new(VOTABLE[1]),
                SensorVote::new(VOTABLE[2]),
                SensorVote::new(VOTABLE[3]),
            ],
        }
    }

    /// This cycle's vote of every votable measurement, in [`VOTABLE`] order (`bound` 0 for
    /// those without a vote).
    pub fn status(&self) -> [VoteStatus; VOTABLE.len()] {
        [
            self.votes[0].status,
            self.votes[1].status,
            self.votes[2].status,
            self.votes[3].status,
        ]
    }

    /// The vote of `id`, if it is voted.
    pub fn of(&self, id: SensorId) -> Option<&VoteStatus> {
        let s = &self.votes[votable_index(id)?].status;
        (s.bound > 0).then_some(s)
    }

    /// The largest degraded-margin shift among the degraded votes, fraction (0: none).
    pub fn degraded_margin(&self, settings: &VoteSettings) -> f64 {
        self.votes
            .iter()
            .filter(|v| v.status.degraded)
            .filter_map(|v| settings.per_sensor[v.status.input.index()])
            .map(|l| l.degraded_margin)
            .fold(0.0, f64::max)
    }

    /// Vote at time `t_s`: `raw` with each voted measurement's value and age replaced by its
    /// vote (transmitter `a` as read where none is valid). `fault` gets, per voted
    /// measurement, the fault the core must take for it: `None` when the vote has a value,
    /// else transmitter `a`'s (the frozen check's included). Allocation-free.
    // (parallel per-slot arrays: indexing by slot reads better than zipped iterators)
    #[allow(clippy::needless_range_loop)]
    pub fn apply(
        &mut self,
        t_s: f64,
        raw: &RawSensors,
        sup: &Supervisor,
        settings: &VoteSettings,
        fault: &mut [Option<InputFault>; SensorId::COUNT],
    ) -> RawSensors {
        let mut out = *raw;
        for v in self.votes.iter_mut() {
            let id = v.status.input;
            let Some(lim) = settings.per_sensor[id.index()] else {
                *v = SensorVote::new(id);
                continue;
            };
            let side = Conservative::of(id).unwrap_or(Conservative::Low);
            let n = usize::from(lim.transmitters).clamp(1, MAX_TRANSMITTERS);
            // the pressures as voted so far (they come first in VOTABLE), for the Δp's frozen check
            let usable = |s: SensorId| {
                let x = out.values.get(s);
                if sup.check_one(s, x, out.age_s[s.index()]) == InputFault::None {
                    x
                } else {
                    f64::NAN
                }
            };
            let (ps, pd) = (usable(SensorId::PSuction), usable(SensorId::PDischarge));
            let mut values = [f64::NAN; MAX_TRANSMITTERS];
            let mut ages = [f64::INFINITY; MAX_TRANSMITTERS];
            let mut base = [InputFault::Nan; MAX_TRANSMITTERS];
            let mut check = [InputFault::Nan; MAX_TRANSMITTERS];
            for k in 0..n {
                let (x, age) = raw.transmitter(id, k);
                values[k] = x;
                ages[k] = age;
                base[k] = sup.check_one(id, x, age);
                check[k] = base[k];
                if id == SensorId::OrificeDp {
                    let dp = if base[k] == InputFault::None {
                        x
                    } else {
                        f64::NAN
                    };
                    if v.frozen[k].update(t_s, dp, ps, pd) {
                        check[k] = InputFault::Frozen;
                    }
                }
            }
            // the valid ones, in slot order (one voted out for a deviation stays out until it
            // has been back within the threshold for the confirmation time)
            let mut idx = [0usize; MAX_TRANSMITTERS];
            let mut valid = 0usize;
            for k in 0..n {
                if check[k] == InputFault::None && !v.out_for_deviation[k] {
                    idx[valid] = k;
                    valid += 1;
                }
            }
            let (rule, chosen, value) = match valid {
                0 => (VoteRule::None, 0, f64::NAN),
                1 => {
                    let s = idx[0];
                    let x = if v.held.is_finite() {
                        side.pick(values[s], v.held)
                    } else {
                        values[s]
                    };
                    (VoteRule::HoldLast, s, x)
                }
                2 => {
                    let (p, q) = (idx[0], idx[1]);
                    let k = if side.pick(values[p], values[q]) == values[p] {
                        p
                    } else {
                        q
                    };
                    (VoteRule::Conservative, k, values[k])
                }
                _ => {
                    let (p, q, r) = (idx[0], idx[1], idx[2]);
                    let (a, b, c) = (values[p], values[q], values[r]);
                    let k = if (a >= b) == (a <= c) {
                        p
                    } else if (b >= a) == (b <= c) {
                        q
                    } else {
                        r
                    };
                    (VoteRule::Median, k, values[k])
                }
            };
            if valid >= 2 {
                v.held = value;
            }
            // deviation: against a vote of at least two, every transmitter that passes the
            // supervisor's checks (a frozen one, one voted out for a deviation too)
            let mut deviating = [false; MAX_TRANSMITTERS];
            let mut off = [false; MAX_TRANSMITTERS];
            for k in 0..n {
                off[k] = valid >= 2
                    && base[k] == InputFault::None
                    && (values[k] - value).abs() > lim.deviation * value.abs();
                if !off[k] {
                    v.off_since_s[k] = f64::NAN;
                    continue;
                }
                if v.off_since_s[k].is_nan() {
                    v.off_since_s[k] = t_s;
                }
                deviating[k] = t_s - v.off_since_s[k] >= lim.deviation_s;
            }
            // a confirmed deviation against two others that agree is the transmitter's: voted
            // out (from the next cycle; of two, the alarm cannot tell, and both stay in)
            for k in 0..n {
                if v.out_for_deviation[k] {
                    // back: within the threshold of the vote (of any rule, hold-last too)
                    let near = base[k] == InputFault::None
                        && value.is_finite()
                        && (values[k] - value).abs() <= lim.deviation * value.abs();
                    if !near {
                        v.back_since_s[k] = f64::NAN;
                    } else if v.back_since_s[k].is_nan() {
                        v.back_since_s[k] = t_s;
                    }
                    if t_s - v.back_since_s[k] >= lim.deviation_s {
                        v.out_for_deviation[k] = false;
                        v.back_since_s[k] = f64::NAN;
                    }
                    continue;
                }
                let others_agree = (0..n)
                    .filter(|&j| j != k && check[j] == InputFault::None && !off[j])
                    .count();
                if deviating[k] && check[k] == InputFault::None && others_agree >= 2 {
                    v.out_for_deviation[k] = true;
                    v.back_since_s[k] = f64::NAN;
                }
            }
            let mut states = [TransmitterState::Unbound; MAX_TRANSMITTERS];
            let mut agreeing = 0u8;
            for k in 0..n {
                states[k] = match TransmitterCheck::of(check[k]) {
                    Some(c) => TransmitterState::VotedOut(c),
                    None if v.out_for_deviation[k] => {
                        TransmitterState::VotedOut(TransmitterCheck::Deviation)
                    }
                    None if deviating[k] => TransmitterState::Deviating,
                    None => {
                        agreeing += 1;
                        TransmitterState::Healthy
                    }
                };
            }
            let valid = valid as u8;
            v.status = VoteStatus {
                input: id,
                bound: n as u8,
                valid,
                rule,
                value,
                values,
                states,
                degraded: valid < n as u8 || agreeing < 2,
            };
            let i = id.index();
            if valid > 0 {
                out.values.set(id, value);
                out.age_s[i] = ages[chosen];
                fault[i] = None;
            } else {
                // none valid: `a` as read, with its fault (the frozen check's too)
                fault[i] = Some(check[0]);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::supervisor::InputLimits;
    use crate::vocab::signals::SensorSnapshot;

    fn sup() -> Supervisor {
        let lim = |min, max| {
            Some(InputLimits {
                min,
                max,
                timeout_s: 0.1,
            })
        };
        let mut limits = [None; SensorId::COUNT];
        limits[SensorId::PSuction.index()] = lim(1e4, 1e6);
        limits[SensorId::PDischarge.index()] = lim(1e4, 1e6);
        limits[SensorId::OrificeDp.index()] = lim(-1e5, 1e5);
        limits[SensorId::TSuction.index()] = lim(200.0, 500.0);
        Supervisor { limits }
    }

    fn settings(id: SensorId, n: u8) -> VoteSettings {
        let mut s = VoteSettings::default();
        s.per_sensor[id.index()] = Some(VoteLimits::defaults(n));
        s
    }

    fn raw(dp: [f64; 3]) -> RawSensors {
        let mut v = SensorSnapshot::default();
        v.set(SensorId::PSuction, 1e5);
        v.set(SensorId::PDischarge, 2e5);
        v.set(SensorId::OrificeDp, dp[0]);
        let mut r = RawSensors::fresh(v);
        r.spare.set(SensorId::OrificeDp, 1, dp[1], 0.0);
        r.spare.set(SensorId::OrificeDp, 2, dp[2], 0.0);
        r
    }

    fn run(
        vote: &mut Vote,
        t: f64,
        r: &RawSensors,
        s: &VoteSettings,
    ) -> (f64, VoteStatus, Option<InputFault>) {
        let mut fault = [None; SensorId::COUNT];
        let out = vote.apply(t, r, &sup(), s, &mut fault);
        let st = *vote.of(SensorId::OrificeDp).expect("voted");
        (
            out.values.get(SensorId::OrificeDp),
            st,
            fault[SensorId::OrificeDp.index()],
        )
    }

    #[test]
    fn median_of_three_conservative_of_two_per_measurement() {
        let s = settings(SensorId::OrificeDp, 3);
        let mut v = Vote::new();
        let (x, st, f) = run(&mut v, 0.0, &raw([1000.0, 1200.0, 1010.0]), &s);
        assert_eq!(
            (x, st.rule, st.valid, f),
            (1010.0, VoteRule::Median, 3, None)
        );
        assert!(!st.degraded);
        // b fails (NaN): of the two left, the lower Δp (less flow, less margin)
        let (x, st, _) = run(&mut v, 0.01, &raw([1000.0, f64::NAN, 1010.0]), &s);
        assert_eq!((x, st.rule, st.valid), (1000.0, VoteRule::Conservative, 2));
        assert_eq!(
            st.states[1],
            TransmitterState::VotedOut(TransmitterCheck::Nan)
        );
        assert!(st.degraded);
        // the discharge pressure's conservative side is the higher one
        assert_eq!(
            Conservative::of(SensorId::PDischarge)
                .unwrap()
                .pick(1.0, 2.0),
            2.0
        );
        assert_eq!(
            Conservative::of(SensorId::TSuction)
                .unwrap()
                .pick(300.0, 301.0),
            301.0
        );
        assert_eq!(
            Conservative::of(SensorId::PSuction).unwrap().pick(1.0, 2.0),
            1.0
        );
        assert_eq!(Conservative::of(SensorId::ShaftSpeed), None);
    }

    #[test]
    fn one_left_holds_the_last_agreed_value_and_follows_it_only_towards_less_margin() {
        let s = settings(SensorId::OrificeDp, 2);
        let mut v = Vote::new();
        let (x, ..) = run(&mut v, 0.0, &raw([1000.0, 1001.0, f64::NAN]), &s);
        assert_eq!(x, 1000.0);
        // b stale: a alone reads more flow than the pair agreed on: held
        let mut r = raw([1100.0, 1001.0, f64::NAN]);
        r.spare.age_s[SensorId::OrificeDp.index()][0] = 1.0;
        let (x, st, f) = run(&mut v, 0.01, &r, &s);
        assert_eq!(
            (x, st.rule, st.valid, f),
            (1000.0, VoteRule::HoldLast, 1, None)
        );
        assert_eq!(
            st.states[1],
            TransmitterState::VotedOut(TransmitterCheck::Stale)
        );
        assert!(st.degraded);
        // a sees the flow fall: followed
        r.values.set(SensorId::OrificeDp, 900.0);
        let (x, ..) = run(&mut v, 0.02, &r, &s);
        assert_eq!(x, 900.0);
        // none valid: a as read, with its fault for the core
        r.values.set(SensorId::OrificeDp, f64::NAN);
        let (_, st, f) = run(&mut v, 0.03, &r, &s);
        assert_eq!(
            (st.rule, st.valid, f),
            (VoteRule::None, 0, Some(InputFault::Nan))
        );
    }

    #[test]
    fn a_biased_transmitter_is_voted_out_after_the_confirmation_and_not_before() {
        let s = settings(SensorId::OrificeDp, 3);
        let mut v = Vote::new();
        let mut t = 0.0;
        while t < DEFAULT_DEVIATION_S - 0.02 {
            let (x, st, _) = run(&mut v, t, &raw([1000.0, 1001.0, 1200.0]), &s);
            assert_eq!(x, 1001.0);
            assert!(!st.deviating(), "{t}");
            t += 0.01;
        }
        let mut named = false;
        while t < DEFAULT_DEVIATION_S + 0.05 {
            let (_, st, _) = run(&mut v, t, &raw([1000.0, 1001.0, 1200.0]), &s);
            named |= st.states[2] == TransmitterState::VotedOut(TransmitterCheck::Deviation);
            assert_eq!(st.states[0], TransmitterState::Healthy);
            t += 0.01;
        }
        assert!(named);
        // out: b fails, and the vote is a's (not the conservative pick of a and c), also
        // after the confirmation time
        for _ in 0..100 {
            t += 0.01;
            let (x, st, _) = run(&mut v, t, &raw([1000.0, f64::NAN, 900.0]), &s);
            assert_eq!((x, st.rule, st.valid), (1000.0, VoteRule::HoldLast, 1));
        }
        // back within the threshold: healthy again after the confirmation time
        let mut back = f64::NAN;
        for _ in 0..100 {
            t += 0.01;
            let (_, st, _) = run(&mut v, t, &raw([1000.0, 1001.0, 1020.0]), &s);
            if st.states[2] == TransmitterState::Healthy {
                back = t;
                break;
            }
        }
        assert!(back.is_finite(), "c back in the vote");
        // of two, a deviation is named, and both stay in
        let s2 = settings(SensorId::OrificeDp, 2);
        let mut v = Vote::new();
        let mut t = 0.0;
        let mut last = None;
        while t < DEFAULT_DEVIATION_S + 0.05 {
            last = Some(run(&mut v, t, &raw([1000.0, 1200.0, f64::NAN]), &s2));
            t += 0.01;
        }
        let (x, st, _) = last.expect("ran");
        assert_eq!((x, st.valid), (1000.0, 2));
        assert_eq!(st.states[1], TransmitterState::Deviating);
        assert!(st.degraded, "two that disagree");
    }

    #[test]
    fn a_frozen_noisy_transmitter_is_voted_out_by_its_own_frozen_check() {
        let s = settings(SensorId::OrificeDp, 3);
        let mut v = Vote::new();
        let mut seed = 7u64;
        let mut noise = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut frozen_at = f64::NAN;
        let mut found = f64::NAN;
        for k in 0..200 {
            let t = k as f64 * 0.01; // 100 Hz samples
            let dp = 1000.0 - 100.0 * t;
            let mut r = raw([
                dp + 20.0 * noise(),
                dp + 20.0 * noise(),
                dp + 20.0 * noise(),
            ]);
            r.values.set(SensorId::PSuction, 1e5 + 50.0 * noise());
            r.values
                .set(SensorId::PDischarge, 2e5 - 1e3 * t + 50.0 * noise());
            if t >= 1.0 {
                if frozen_at.is_nan() {
                    frozen_at = r.spare.values[SensorId::OrificeDp.index()][0];
                }
                r.spare.values[SensorId::OrificeDp.index()][0] = frozen_at;
            }
            let (_, st, _) = run(&mut v, t, &r, &s);
            if found.is_nan()
                && st.states[1] == TransmitterState::VotedOut(TransmitterCheck::Frozen)
            {
                found = t;
            }
            if t < 1.0 {
                assert_eq!(st.states[1], TransmitterState::Healthy, "{t}");
            }
        }
        assert!((1.0..=1.3).contains(&found), "found at {found}");
    }

    #[test]
    fn codes_round_trip() {
        for s in [
            TransmitterState::Unbound,
            TransmitterState::Healthy,
            TransmitterState::Deviating,
            TransmitterState::VotedOut(TransmitterCheck::Stale),
            TransmitterState::VotedOut(TransmitterCheck::Frozen),
            TransmitterState::VotedOut(TransmitterCheck::Deviation),
        ] {
            assert_eq!(TransmitterState::from_code(s.code()), s);
        }
    }
}
