//! The closing limiter (seed 002 §2.2.2, application note [15]: "the closing rate is
//! limited. This allows the PID controller to be tuned for fast response, while at the same
//! time avoiding that the valve is closed equally fast").
//!
//! Purpose: the valve opens as fast as any part asks, and closes
//! - never faster than `rate_per_s`, and
//! - never below the opening the operating point needs to stay on the control line, estimated
//!   from the measured point and the measured valve position: closing the valve from u_pos to
//!   u takes at most the recycle flow w_r(u_pos)(1 − f(u)/f(u_pos)) from the compressor
//!   (f the valve's characteristic, the pressures held), and w_r(u_pos) is at most the
//!   compressor flow q itself. So q stays at or right of the control-line flow c for every u
//!   with f(u) ≥ f(u_pos) · c/q: a conservative floor that needs no valve capacity, only the
//!   characteristic. At or left of the line (q ≤ c) it forbids any closing.
//!
//! After a trip, a fail-safe resume or a link restart the PI's demand may lie far below the
//! valve; the limiter then closes the valve at its rate and stops it where the point reaches
//! the control line, where the PI takes over (it follows the held output, see
//! [`super::pi`]).
//!
//! One exception to the rate: a trip held on the observer's flow estimate and ended by the
//! flow transmitter's return (the transmitter shows the point right of the control line)
//! closes at the return rate, the distance to the line over one answer time of the pressures
//! ([`ClosingLimiter::return_rate_per_s`]), until the PI's own demand is selected again.

use crate::physics::valve::Characteristic;
use serde::{Deserialize, Serialize};

/// Settings of the closing limiter (`[controller.recycle_pi.closing]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClosingConfig {
    /// Whether the limiter acts. Default true.
    pub enabled: bool,
    /// Largest closing speed of the valve command, opening fraction per second. Default
    /// 0.1/s: a full closing takes 10 s, five times the slowest stroke of the campaign's
    /// valves (3 s) plus margin, and one control margin's worth of opening (≈ 0.1) takes
    /// about one second, the period of the slowest surge: the pressures settle to each
    /// closing step before the next is taken.
    pub rate_per_s: f64,
    /// Stop the closing at the opening the point needs to stay on the control line (see
    /// the module doc). Default true.
    pub stop_at_control_line: bool,
}

impl Default for ClosingConfig {
    fn default() -> Self {
        ClosingConfig {
            enabled: true,
            rate_per_s: 0.1,
            stop_at_control_line: true,
        }
    }
}

/// The closing limiter (stateless beyond its settings).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClosingLimiter {
    enabled: bool,
    rate_per_s: f64,
    stop_at_line: bool,
    characteristic: Characteristic,
}

impl ClosingLimiter {
    /// A limiter for a valve of this characteristic.
    pub fn new(cfg: &ClosingConfig, characteristic: Characteristic) -> Self {
        ClosingLimiter {
            enabled: cfg.enabled,
            rate_per_s: cfg.rate_per_s,
            stop_at_line: cfg.stop_at_control_line,
            characteristic,
        }
    }

    /// The lowest opening the output may take this cycle, given the last output `u_last`,
    /// the measured position `u_pos` (NaN: not measured, the last output stands in), the
    /// compressor flow `q` and the control-line flow `c` (map units); `approach_cap_per_s`
    /// a further cap on the closing rate from the recycle trip (see
    /// [`ClosingLimiter::approach_cap_per_s`]; ∞: none); `return_rate_per_s` a faster rate
    /// allowed in place of `rate_per_s` (see [`ClosingLimiter::return_rate_per_s`]; NaN or
    /// 0: none), itself under the approach cap. −∞ when off. Never above `u_last`: the
    /// limiter only holds a closing back, it never opens.
    #[allow(clippy::too_many_arguments)] // one cycle's inputs, each a named quantity
    pub fn floor(
        &self,
        u_last: f64,
        u_pos: f64,
        q: f64,
        c: f64,
        approach_cap_per_s: f64,
        return_rate_per_s: f64,
        dt_s: f64,
    ) -> f64 {
        if !self.enabled || !u_last.is_finite() {
            return f64::NEG_INFINITY;
        }
        let base = if return_rate_per_s > self.rate_per_s {
            return_rate_per_s
        } else {
            self.rate_per_s
        };
        let rate = if approach_cap_per_s >= 0.0 {
            base.min(approach_cap_per_s)
        } else {
            base
        };
        let by_rate = u_last - rate * dt_s.max(0.0);
        let by_line = if self.stop_at_line {
            self.line_opening(if u_pos.is_finite() { u_pos } else { u_last }, q, c)
        } else {
            f64::NEG_INFINITY
        };
        by_rate.max(by_line).min(u_last)
    }

    /// The closing rate at which the law's own closing cannot make the recycle trip predict a
    /// crossing, 1/s: closing at r takes at most the fraction r/u_pos of the compressor flow
    /// per second (the same bound as the line opening: the recycle share is at most 1), so the
    /// surge margin m falls at most at (1 + m)·r/u_pos; over the trip's horizon that must stay
    /// within half the distance to the trip line. Without it the law's closing after a trip
    /// ran the point towards the line at 0.35/s of margin on a large valve, the prediction
    /// fired the trip again, and the two made a 0.4 Hz cycle (kvangardsnes2009, 5 % margin).
    /// ∞ without a usable point.
    pub fn approach_cap_per_s(u_pos: f64, margin: f64, trip_line: f64, horizon_s: f64) -> f64 {
        if !(u_pos.is_finite() && margin.is_finite() && horizon_s > 0.0 && margin > -1.0) {
            return f64::INFINITY;
        }
        u_pos.max(0.0) * (margin - trip_line).max(0.0) / (2.0 * (1.0 + margin) * horizon_s)
    }

    /// The closing rate after a trip taken on the observer's flow estimate is released by the
    /// flow transmitter's return, 1/s: the rate at which the conservative bound of the line
    /// opening (closing at r takes at most the fraction r/u_pos of the compressor flow per
    /// second, so the margin m falls at most at (1 + m)·r/u_pos) carries the point from its
    /// measured margin to the control line `line` in no less than `answer_s`, the time the
    /// pressures take to answer a valve move (the trip's hold time, one period of the slowest
    /// surge): u_pos (m − line)/((1 + m) answer_s). The opening was taken on an estimate the
    /// trusted transmitter now contradicts, not on an approach it saw; the closing that
    /// brings it back is paced by the distance the transmitter shows, not by the 0.1/s meant
    /// for settling after a measured approach (campaign cases 155 and 120: a frozen Δp under
    /// a feed drop, the valve fully open on the fallback, 0.1/s took 9 s back to the line).
    /// 0 at or left of the line; 0 without a usable point.
    pub fn return_rate_per_s(u_pos: f64, margin: f64, line: f64, answer_s: f64) -> f64 {
        if !(u_pos.is_finite() && margin.is_finite() && line.is_finite() && answer_s > 0.0)
            || margin <= -1.0
        {
            return 0.0;
        }
        u_pos.max(0.0) * (margin - line).max(0.0) / ((1.0 + margin) * answer_s)
    }

    /// The opening that keeps the point at or right of the control line (see the module
    /// doc): f(u) = f(u_pos)·c/q; at or left of the line, u_pos itself. −∞ without a usable
    /// point.
    pub fn line_opening(&self, u_pos: f64, q: f64, c: f64) -> f64 {
        if !(q.is_finite() && c.is_finite() && c > 0.0 && u_pos.is_finite()) {
            return f64::NEG_INFINITY;
        }
        if q <= c {
            return u_pos;
        }
        let f = self.characteristic.fraction(u_pos) * c / q;
        self.characteristic.opening_for_fraction(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limiter() -> ClosingLimiter {
        ClosingLimiter::new(&ClosingConfig::default(), Characteristic::Linear)
    }

    #[test]
    fn closing_is_rate_limited_and_opening_is_not() {
        let l = limiter();
        // far right of the line: the rate limits (0.1/s × 0.01 s)
        let f = l.floor(0.5, 0.5, 3.0, 1.0, f64::INFINITY, f64::NAN, 0.01);
        assert!((f - 0.499).abs() < 1e-12, "{f}");
        // never above the last output: it cannot open
        assert!(l.floor(0.5, 0.9, 0.5, 1.0, f64::INFINITY, f64::NAN, 0.01) <= 0.5);
    }

    #[test]
    fn the_closing_stops_at_the_opening_the_control_line_needs() {
        let l = limiter();
        // 30 % right of the line with the valve at 0.99: the flow may fall by at most the
        // recycle share, which is at most all of it: the valve stays above 0.99/1.3
        let u_line = l.line_opening(0.99, 1.3, 1.0);
        assert!((u_line - 0.99 / 1.3).abs() < 1e-12);
        // a plant whose compressor flow is 0.5 of throughput plus the recycle, 1.3 at 0.99:
        // the line (q = 1) needs 0.619; closing at the rate, the floor stops it there
        let q = |u: f64| 0.5 + 0.8 * u / 0.99;
        let need = 0.5 * 0.99 / 0.8;
        let mut u = 0.99;
        for _ in 0..100_000 {
            u = l.floor(u, u, q(u), 1.0, f64::INFINITY, f64::NAN, 0.01).max(0.0);
        }
        assert!(u >= need - 1e-9 && u < need + 0.01, "{u} vs {need}");
        // on or left of the line: no closing at all
        assert_eq!(l.floor(0.4, 0.4, 0.95, 1.0, f64::INFINITY, f64::NAN, 0.01), 0.4);
    }

    #[test]
    fn an_equal_percentage_valve_keeps_the_capacity_not_the_stroke() {
        let l = ClosingLimiter::new(
            &ClosingConfig::default(),
            Characteristic::EqualPercentage { rangeability: 50.0 },
        );
        let u = l.line_opening(0.8, 2.0, 1.0);
        let c = Characteristic::EqualPercentage { rangeability: 50.0 };
        assert!((c.fraction(u) - 0.5 * c.fraction(0.8)).abs() < 1e-9);
    }

    #[test]
    fn the_closing_slows_so_that_its_own_approach_stays_within_the_trip_horizon() {
        // 16 % right of the surge line, trip line 2.5 %, valve at 0.2, horizon 0.33 s
        let cap = ClosingLimiter::approach_cap_per_s(0.2, 0.16, 0.025, 0.33);
        // the margin falls at most (1 + m) r/u_pos: half the distance over the horizon
        let fall = (1.0 + 0.16) * cap / 0.2 * 0.33;
        assert!((fall - 0.5 * (0.16 - 0.025)).abs() < 1e-12, "{fall}");
        assert!(cap < 0.1, "slower than the default rate: {cap}");
        // at the trip line no closing at all
        assert_eq!(
            ClosingLimiter::approach_cap_per_s(0.2, 0.02, 0.025, 0.33),
            0.0
        );
        let l = limiter();
        assert!((l.floor(0.2, 0.2, 3.0, 1.0, cap, f64::NAN, 0.01) - (0.2 - cap * 0.01)).abs() < 1e-12);
    }

    #[test]
    fn the_return_rate_carries_the_bound_to_the_line_in_one_answer_time() {
        // fully open, 120 % right of the surge line, line at 10 %, answer time 1 s
        let r = ClosingLimiter::return_rate_per_s(1.0, 1.2, 0.1, 1.0);
        // at r the margin falls at most (1 + m) r/u_pos: the distance to the line in 1 s
        assert!(((1.0 + 1.2) * r / 1.0 - (1.2 - 0.1)).abs() < 1e-12, "{r}");
        assert!(r > 0.1, "faster than the default rate: {r}");
        // at or left of the line: none
        assert_eq!(ClosingLimiter::return_rate_per_s(1.0, 0.1, 0.1, 1.0), 0.0);
        assert_eq!(ClosingLimiter::return_rate_per_s(1.0, f64::NAN, 0.1, 1.0), 0.0);
        // the floor takes it in place of the default rate, under the approach cap
        let l = limiter();
        let f = l.floor(1.0, 1.0, 2.2, 1.1, f64::INFINITY, r, 0.01);
        assert!((f - (1.0 - r * 0.01)).abs() < 1e-12, "{f}");
        let f = l.floor(1.0, 1.0, 2.2, 1.1, 0.2, r, 0.01);
        assert!((f - (1.0 - 0.2 * 0.01)).abs() < 1e-12, "{f}");
        // a return rate below the default rate changes nothing
        let f = l.floor(1.0, 1.0, 2.2, 1.1, f64::INFINITY, 0.01, 0.01);
        assert!((f - 0.999).abs() < 1e-12, "{f}");
    }

    #[test]
    fn off_means_no_floor() {
        let cfg = ClosingConfig {
            enabled: false,
            ..ClosingConfig::default()
        };
        let l = ClosingLimiter::new(&cfg, Characteristic::Linear);
        assert_eq!(
            l.floor(0.5, 0.5, 1.0, 1.0, f64::INFINITY, f64::NAN, 0.01),
            f64::NEG_INFINITY
        );
    }
}
