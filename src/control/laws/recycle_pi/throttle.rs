//! The throttle watch: the recycle trip's view of the process valve downstream of the
//! compressor (seed 002 §2.2.2: the recycle valve is there to pass the flow the process no
//! longer takes; the industrial practice of decoupling the anti-surge loop from the
//! performance loop by a feedforward of the process valve's motion).
//!
//! Purpose: a throttle that slams shut removes its flow from the compressor *before* any
//! pressure or Δp transmitter can show it: the compressor flow follows the throttle only as
//! the discharge volume fills (40–400 ms to flow reversal on the campaign's machines), while
//! the throttle's position transmitter shows the closing on the first poll after it began.
//! At a 50 or 100 Hz poll the first Δp sample after a slam shows the flow barely moved (under
//! the transmitters' noise), and the margin's own prediction fires one sample later, one
//! sample period plus a bus round trip too late for a fast machine. The watch turns the
//! throttle's closing into a predicted margin for the trip:
//!
//! - the throttle passes a flow proportional to its opening θ at the pressures of the moment
//!   (linear characteristic: the process's own valve is not in the machine data, and the
//!   linear form is the one that needs no data);
//! - the opening it is heading for is θ extrapolated over the trip's horizon at its closing
//!   rate over the trip's rate window (the window ending *now*: a throttle that has stopped
//!   has no rate), the rate moved by the trip's noise factor times the noise the throttle's
//!   own σ leaves in it (√2 σ/T);
//! - relative to the opening at the window's start, that is the fraction `ratio` of its flow
//!   the throttle will still pass; the compressor flow q (1 + m) heads for q (1 + m) · ratio,
//!   and the trip fires when that margin lies past the trip line (`TripKind::Throttle`),
//!   sized on its depth like any predicted crossing.
//!
//! The windows and the horizon are the trip's (seconds of measurement time, valid from 20 Hz
//! to 1 kHz); nothing here has a time of its own. A slow closing by the performance controller
//! moves `ratio` by its rate times the horizon only, which the PI answers; a slam moves it to
//! the end of its travel. Without a throttle position transmitter (or with it stale) the watch
//! says nothing, and the trip works on the margin alone.

use super::samples::DistinctSamples;
use serde::{Deserialize, Serialize};

/// Settings of the throttle watch (`[controller.recycle_pi.throttle]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ThrottleConfig {
    /// Whether the throttle's closing feeds the recycle trip (only where a
    /// `throttle_position` transmitter is bound). Default true.
    pub enabled: bool,
}

impl Default for ThrottleConfig {
    fn default() -> Self {
        ThrottleConfig { enabled: true }
    }
}

/// An opening below which the throttle's flow is no reference (a nearly shut throttle has no
/// flow left to remove; its position transmitter's resolution dominates the ratio).
const MIN_REFERENCE_OPENING: f64 = 0.02;

/// What the watch tells the trip for one cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThrottlePrediction {
    /// The flow the throttle will still pass at the end of the horizon, relative to what it
    /// passed at the start of the rate window (NaN: no prediction).
    pub flow_ratio: f64,
    /// Whether this cycle brought a new throttle sample.
    pub new_sample: bool,
}

impl ThrottlePrediction {
    /// No throttle watched.
    pub const NONE: ThrottlePrediction = ThrottlePrediction {
        flow_ratio: f64::NAN,
        new_sample: false,
    };
}

/// The throttle watch's state (fixed size).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThrottleWatch {
    enabled: bool,
    samples: DistinctSamples,
    /// The opening the last prediction headed for (NaN: none).
    heading: f64,
    /// The opening the trip's last throttle step covered: a further step is due only for a
    /// closing predicted beyond it (NaN: none while the trip holds no throttle step).
    covered: f64,
}

impl ThrottleWatch {
    /// A watch with these settings.
    pub fn new(cfg: &ThrottleConfig) -> Self {
        ThrottleWatch {
            enabled: cfg.enabled,
            samples: DistinctSamples::new(),
            heading: f64::NAN,
            covered: f64::NAN,
        }
    }

    /// Carry the running watch's samples over (a change of settings).
    pub fn take_over(&mut self, old: &ThrottleWatch) {
        self.samples = old.samples;
    }

    /// Forget the samples (a (re)start: the last samples are old).
    pub fn restart(&mut self) {
        self.samples.clear();
        self.heading = f64::NAN;
        self.covered = f64::NAN;
    }

    /// The trip stepped on this cycle's prediction: the step covers the closing down to the
    /// opening it headed for, and the next prediction is measured from there.
    pub fn stepped(&mut self) {
        if self.heading.is_finite() {
            self.covered = if self.covered.is_finite() {
                self.covered.min(self.heading)
            } else {
                self.heading
            };
        }
    }

    /// The trip released its hold: the closing it covered is history.
    pub fn released(&mut self) {
        self.covered = f64::NAN;
    }

    /// One cycle: the throttle position `theta` (fraction, NaN: not measured) of the sample
    /// taken at `t_s`; the trip's `horizon_s`, `rate_window_s` and `noise_factor`.
    pub fn update(
        &mut self,
        theta: f64,
        t_s: f64,
        horizon_s: f64,
        rate_window_s: f64,
        noise_factor: f64,
        dt_s: f64,
    ) -> ThrottlePrediction {
        if !self.enabled || !theta.is_finite() || !t_s.is_finite() {
            return ThrottlePrediction::NONE;
        }
        self.samples.watch(theta, dt_s);
        let new_sample = self.samples.push(theta, t_s);
        let mut out = ThrottlePrediction {
            flow_ratio: f64::NAN,
            new_sample,
        };
        self.heading = f64::NAN;
        if !self.samples.armed() {
            return out;
        }
        let (theta_now, t_newest) = self.samples.sample(0);
        let now = t_s.max(t_newest);
        let Some((theta_ref, seen_s)) = self.samples.value_at(now - rate_window_s.max(0.0)) else {
            return out;
        };
        if theta_ref < MIN_REFERENCE_OPENING {
            return out;
        }
        let span = now - seen_s;
        let (rate, rate_noise) = if span > 1e-9 {
            (
                (theta_now - theta_ref) / span,
                std::f64::consts::SQRT_2 * self.samples.noise() / span,
            )
        } else {
            (0.0, 0.0)
        };
        let closing = (rate + noise_factor.max(0.0) * rate_noise).min(0.0);
        let theta_then = (theta_now + horizon_s.max(0.0) * closing).max(0.0);
        self.heading = theta_then;
        // (after a step, relative to the opening that step covered: one step per stretch
        // of closing, not one per repeat interval while the same closing goes on)
        let from = if self.covered.is_finite() {
            theta_ref.min(self.covered)
        } else {
            theta_ref
        };
        out.flow_ratio = theta_then / from;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HORIZON_S: f64 = 0.1;
    const WINDOW_S: f64 = 0.02;

    /// Feed a throttle trajectory polled at `rate_hz` through the watch in a 1 kHz loop;
    /// returns the smallest flow ratio seen from `from_s` on, and when.
    fn smallest_ratio(
        rate_hz: f64,
        theta: impl Fn(f64) -> f64,
        from_s: f64,
        t_end: f64,
    ) -> (f64, f64) {
        let mut w = ThrottleWatch::new(&ThrottleConfig::default());
        let period = 1.0 / rate_hz;
        let mut best = (f64::INFINITY, f64::NAN);
        for k in 0..(t_end * 1e3) as usize {
            let t = k as f64 * 1e-3;
            let t_sample = (t / period).floor() * period;
            let p = w.update(theta(t_sample), t_sample, HORIZON_S, WINDOW_S, 3.0, 1e-3);
            if t >= from_s && p.flow_ratio < best.0 {
                best = (p.flow_ratio, t);
            }
        }
        best
    }

    fn slam(t: f64) -> f64 {
        // 0.6 → 0.1 in 20 ms from t = 2 s
        0.6 - 0.5 * ((t - 2.0) / 0.02).clamp(0.0, 1.0)
    }

    #[test]
    fn a_slam_is_predicted_on_its_first_sample_at_every_rate() {
        for rate in [20.0f64, 50.0, 100.0, 1000.0] {
            let period = 1.0 / rate;
            // the first poll after the slam began
            let first = ((2.0 / period).floor() + 1.0) * period;
            let (r, at) = smallest_ratio(rate, slam, 0.0, 3.0);
            // the closing seen on the first sample, extrapolated, removes most of the flow
            assert!(r < 0.5, "{rate} Hz: {r}");
            assert!(
                at <= first + 1e-3 + 1e-9,
                "{rate} Hz: at {at}, first poll {first}"
            );
        }
    }

    #[test]
    fn a_throttle_that_stopped_predicts_nothing_after_one_window() {
        let mut w = ThrottleWatch::new(&ThrottleConfig::default());
        let mut last = ThrottlePrediction::NONE;
        for k in 0..3000 {
            let t = k as f64 * 1e-3;
            last = w.update(slam(t), t, HORIZON_S, WINDOW_S, 3.0, 1e-3);
        }
        assert_eq!(last.flow_ratio, 1.0);
    }

    #[test]
    fn a_slow_ramp_moves_the_prediction_by_its_rate_over_the_horizon_only() {
        // the performance controller closing 5 %/s
        let (r, _) = smallest_ratio(100.0, |t| 0.6 - 0.05 * (t - 2.0).max(0.0), 2.5, 4.0);
        let expected = (0.6 - 0.05 * 0.5 - 0.05 * HORIZON_S) / (0.6 - 0.05 * 0.5 + 0.05 * WINDOW_S);
        assert!(r > expected - 0.02 && r < 1.0, "{r} vs {expected}");
    }

    #[test]
    fn noise_on_a_standing_throttle_predicts_no_closing() {
        let mut x: u64 = 99;
        let mut noise = move || {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut w = ThrottleWatch::new(&ThrottleConfig::default());
        let mut worst = f64::INFINITY;
        for k in 0..5000 {
            let t = k as f64 * 0.01; // 100 Hz
            let p = w.update(0.6 + 0.003 * noise(), t, 0.3, WINDOW_S, 3.0, 0.01);
            if t > 2.0 {
                worst = worst.min(p.flow_ratio);
            }
        }
        // 0.5 % of opening of noise must not look like a tenth of the flow leaving
        assert!(worst > 0.9, "{worst}");
    }

    #[test]
    fn after_a_step_only_a_closing_beyond_what_it_covered_counts() {
        let mut w = ThrottleWatch::new(&ThrottleConfig::default());
        let mut stepped = false;
        let mut after = Vec::new();
        // closing 0.6 → 0.1 at 0.25/s, 100 Hz, from t = 2 s
        for k in 0..400 {
            let t = k as f64 * 0.01;
            let theta = 0.6 - 0.25 * (t - 2.0).clamp(0.0, 2.0);
            let p = w.update(theta, t, HORIZON_S, WINDOW_S, 3.0, 0.01);
            if !stepped && p.flow_ratio < 0.95 {
                w.stepped();
                stepped = true;
            } else if stepped && t < 2.3 {
                after.push(p.flow_ratio);
            }
        }
        assert!(stepped);
        // right after the step the same closing is covered: ratios near 1, not 0.95 again
        assert!(after[..5].iter().all(|r| *r > 0.97), "{after:?}");
        // further on, the closing beyond the covered opening shows again
        assert!(after.iter().any(|r| *r < 0.95), "{after:?}");
        w.released();
        assert!(w.covered.is_nan());
    }

    #[test]
    fn without_a_transmitter_or_when_off_there_is_no_prediction() {
        let mut w = ThrottleWatch::new(&ThrottleConfig::default());
        let p = w.update(f64::NAN, 1.0, HORIZON_S, WINDOW_S, 3.0, 1e-3);
        assert!(p.flow_ratio.is_nan() && !p.new_sample);
        let mut off = ThrottleWatch::new(&ThrottleConfig { enabled: false });
        for k in 0..3000 {
            let t = k as f64 * 1e-3;
            let p = off.update(slam(t), t, HORIZON_S, WINDOW_S, 3.0, 1e-3);
            assert!(p.flow_ratio.is_nan());
        }
    }
}
