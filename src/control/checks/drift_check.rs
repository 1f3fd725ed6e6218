//! Transmitter cross-check, second part: a flow element's Δp that is fresh, in range and
//! moving, but **drifting or biased** (a zero shift, a span error, an impulse line filling
//! up). The frozen check ([`super::cross_check`]) cannot see it; this one compares the flow
//! the transmitter gives with two estimates that do not use it:
//!
//! - the observer's flow (seed 000 eq. 14–15, [`crate::control::observer`]), which integrates the duct
//!   and outlet-volume dynamics from the pressures, the speed and the valve positions;
//! - the *speed-line flow*: the flow at which the compressor map's speed line at the measured
//!   speed gives the measured pressure ratio, Ψc(q, ω) = p_d/p_s (the steady state of the duct
//!   equation, seed 000 eq. 1b / seed 001 eq. 2.1b: L/A dm/dt = Ψc p_s − p_d). The inversion is
//!   well-defined only **right of the peak** of the speed line, where Ψc falls with the flow;
//!   there one ratio gives one flow. Left of the peak, and near it where the line is flat
//!   (one ratio, a wide range of flows), it is not used: its uncertainty (below) grows as
//!   1/|∂Ψc/∂q| and rules it out by itself.
//!
//! Residuals are in fractions of the surge-line flow at the measured ratio (the unit of the
//! control margin): r = (q_transmitter − q_estimate)/q_SL(R). Each is low-passed (time
//! constant `filter_s`). A leg disagrees when its filtered residual exceeds its combined
//! uncertainty: `threshold_pct` (model and transmitter accuracy) + `noise_factor` × the
//! filtered residual's noise, measured online from its sample-to-sample increments (blind to
//! a bias or a slow drift, which do not change from one sample to the next) + for the
//! speed-line leg the map's uncertainty `map_uncertainty_pct` carried through the inversion
//! (ε (q + (R − 1)/|∂Ψc/∂q|)). The transmitter is declared drifting when every available leg
//! disagrees, in the same direction, for `persistence_s` without a break; it is trusted again
//! when every leg is back within half its threshold for `clear_s` without a break.
//!
//! The observer is a reference only while the speed-line flow confirms it (both within the
//! speed line's uncertainty of each other); then both legs must disagree, and the speed-line
//! leg's map allowance has gone into the confirmation. An observer the speed line does not
//! confirm (converging, or off in a transient: its outflow is the valve equations, without the
//! outlet lines' inertia) leaves the speed-line flow alone to decide, with its whole allowance.
//!
//! Time scale: a step bias must be found faster than a law believing it closes the machine
//! into surge (≈ 150 ms from the control line on kvangardsnes2009's recycle system, README),
//! hence 30 ms of filter and 30 ms of persistence by default; noise is kept out by the
//! measured-noise term of the threshold, which grows as the filter shortens, not by the
//! filter's length. Trusting the transmitter again takes `clear_s` (1 s): a bias does not go
//! away by itself.
//!
//! Pure and allocation-free: a few numbers of state, one call per new sample.

use serde::{Deserialize, Serialize};

/// Settings of the drift/bias cross-check (`[controller.drift_check]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriftCheckConfig {
    /// Whether the check runs.
    pub enabled: bool,
    /// Disagreement always tolerated (model and transmitter accuracy), % of the surge-line
    /// flow at the measured pressure ratio.
    pub threshold_pct: f64,
    /// Multiples of the filtered residual's measured noise (1 σ) added to the threshold.
    pub noise_factor: f64,
    /// Uncertainty of the compressor map, % (of its flow and of its pressure rise R − 1),
    /// carried through the speed-line inversion.
    pub map_uncertainty_pct: f64,
    /// Time constant of the residual filter, s.
    pub filter_s: f64,
    /// How long every check must disagree without a break before the transmitter is
    /// declared drifting, s.
    pub persistence_s: f64,
    /// How long every check must agree again without a break before a transmitter declared
    /// drifting is trusted again, s (a bias does not go away by itself: longer than
    /// `persistence_s`).
    pub clear_s: f64,
}

impl Default for DriftCheckConfig {
    fn default() -> Self {
        DriftCheckConfig {
            enabled: true,
            threshold_pct: 5.0,
            noise_factor: 4.0,
            map_uncertainty_pct: 3.0,
            filter_s: 0.03,
            persistence_s: 0.03,
            clear_s: 1.0,
        }
    }
}

impl DriftCheckConfig {
    /// Problems with the settings as `(key relative to [controller], message)`.
    pub fn problems(&self) -> Vec<(String, String)> {
        let mut out = Vec::new();
        let mut check = |key: &str, v: f64, lo: f64, hi: f64, what: &str| {
            if !(v.is_finite() && v >= lo && v <= hi) {
                out.push((
                    format!("drift_check.{key}"),
                    format!("{v} is outside {lo} … {hi} ({what})"),
                ));
            }
        };
        check(
            "threshold_pct",
            self.threshold_pct,
            0.5,
            50.0,
            "% of surge-line flow; below the map's accuracy it false-alarms, above the control margin it is useless",
        );
        check(
            "noise_factor",
            self.noise_factor,
            0.0,
            20.0,
            "multiples of σ",
        );
        check(
            "map_uncertainty_pct",
            self.map_uncertainty_pct,
            0.0,
            50.0,
            "% of the map's flow and pressure rise",
        );
        check("filter_s", self.filter_s, 0.01, 60.0, "s");
        check("persistence_s", self.persistence_s, 0.0, 60.0, "s");
        check("clear_s", self.clear_s, 0.0, 600.0, "s");
        out
    }
}

/// Weight of one new sample in the running increment (noise) estimates.
const NOISE_WEIGHT: f64 = 0.01;
/// Largest sample noise (1 σ, fraction of surge-line flow) of an estimate that is judged.
const MAX_NOISE: f64 = 0.25;
/// Samples a leg must have seen before its noise estimate is trusted.
const MIN_SAMPLES: u32 = 200;

/// One comparison (transmitter against one estimate).
#[derive(Debug, Clone, Copy)]
struct Leg {
    /// Filtered residual, fraction of surge-line flow (NaN: none yet).
    e: f64,
    /// Raw residual at its last new sample, and when (NaN: none).
    r_at_change: f64,
    t_at_change: f64,
    /// Running mean |increment| of the raw residual from one new sample to the next.
    inc: f64,
    /// Running mean time between new samples, s (inputs polled slower than the cycle repeat
    /// their values: a repeated value is not a sample of the noise).
    interval_s: f64,
    /// Filtered extra uncertainty (the map's, for the speed-line leg), fraction.
    unc: f64,
    last_valid_t_s: f64,
    first_t_s: f64,
    n: u32,
}

impl Leg {
    const NEW: Leg = Leg {
        e: f64::NAN,
        r_at_change: f64::NAN,
        t_at_change: f64::NAN,
        inc: 0.0,
        interval_s: 0.0,
        unc: 0.0,
        last_valid_t_s: f64::NAN,
        first_t_s: f64::NAN,
        n: 0,
    };

    /// One call per cycle; `new_sample`: an input of this residual changed since the last.
    fn update(&mut self, t_s: f64, r: f64, unc: f64, a: f64, new_sample: bool) {
        if !(r.is_finite() && unc.is_finite()) {
            self.r_at_change = f64::NAN;
            return;
        }
        if self.e.is_finite() {
            self.e += a * (r - self.e);
            self.unc += a * (unc - self.unc);
        } else {
            self.e = r;
            self.unc = unc;
            self.first_t_s = t_s;
        }
        if self.r_at_change.is_finite() {
            self.n = self.n.saturating_add(1);
        }
        if new_sample || !self.r_at_change.is_finite() {
            if self.r_at_change.is_finite() {
                let gap = t_s - self.t_at_change;
                self.inc += NOISE_WEIGHT * ((r - self.r_at_change).abs() - self.inc);
                self.interval_s = if self.interval_s > 0.0 {
                    self.interval_s + NOISE_WEIGHT * (gap - self.interval_s)
                } else {
                    gap
                };
            }
            self.r_at_change = r;
            self.t_at_change = t_s;
        }
        self.last_valid_t_s = t_s;
    }

    /// Threshold (fraction) if the leg can be judged now.
    fn threshold(&self, t_s: f64, cfg: &DriftCheckConfig, a: f64) -> Option<f64> {
        let ready = self.e.is_finite()
            && self.n >= MIN_SAMPLES
            && t_s - self.first_t_s >= cfg.filter_s
            && t_s - self.last_valid_t_s <= cfg.filter_s;
        // white noise of σ: E|Δ| = 2σ/√π; a first-order filter of gain a keeps σ √(a/(2 − a))
        let sigma = self.inc * std::f64::consts::PI.sqrt() / 2.0;
        // an estimate whose sample noise is of the order of the flow itself is no reference:
        // the map's curvature biases its mean (the observer passes pressure noise with gain
        // K_z, ERRATA.md)
        if !ready || sigma > MAX_NOISE {
            return None;
        }
        // held between new samples, the noise reaches the filter once per sample interval
        let a_sample = if self.interval_s > 0.0 {
            1.0 - (-self.interval_s / cfg.filter_s.max(1e-6)).exp()
        } else {
            a
        };
        let sigma_f = sigma * (a_sample / (2.0 - a_sample)).sqrt();
        Some(0.01 * cfg.threshold_pct + cfg.noise_factor * sigma_f + self.unc)
    }
}

/// What the check concluded this sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftVerdict {
    /// The transmitter is declared drifting or biased.
    pub drifting: bool,
    /// Filtered residual against the observer, fraction of surge-line flow (NaN: not judged).
    pub vs_observer: f64,
    /// Filtered residual against the speed-line flow, fraction (NaN: not judged).
    pub vs_speed_line: f64,
}

/// The drift/bias check (see the module doc).
#[derive(Debug, Clone, Copy)]
pub struct DriftCheck {
    obs: Leg,
    line: Leg,
    /// Observer against the speed-line flow (whether the observer is confirmed).
    agree: Leg,
    last_t_s: f64,
    /// The inputs' last values (a repeated value is no new sample).
    last_q_transmitter: f64,
    last_q_line: f64,
    /// Since when every leg disagrees (or, while drifting, agrees), s; NaN: not.
    since_s: f64,
    sign: f64,
    drifting: bool,
    verdict: DriftVerdict,
}

impl Default for DriftCheck {
    fn default() -> Self {
        Self::new()
    }
}

impl DriftCheck {
    /// A check with no history.
    pub const fn new() -> DriftCheck {
        DriftCheck {
            obs: Leg::NEW,
            line: Leg::NEW,
            agree: Leg::NEW,
            last_t_s: f64::NAN,
            last_q_transmitter: f64::NAN,
            last_q_line: f64::NAN,
            since_s: f64::NAN,
            sign: 0.0,
            drifting: false,
            verdict: DriftVerdict {
                drifting: false,
                vs_observer: f64::NAN,
                vs_speed_line: f64::NAN,
            },
        }
    }

    /// Whether the transmitter is declared drifting now.
    pub fn drifting(&self) -> bool {
        self.drifting
    }

    /// The last verdict (residuals for the event log and status).
    pub fn verdict(&self) -> DriftVerdict {
        self.verdict
    }

    /// One new sample. Flows in the map's coordinate: `q_transmitter` from the Δp (NaN: not
    /// usable, e.g. frozen or stale; the check then holds), `q_observer` (NaN: no observer),
    /// `observer_unc` its steady-state error from the map's uncertainty, `q_speed_line` with
    /// `speed_line_unc` its map uncertainty in the same unit (NaN: left of the peak or no
    /// map), `q_surge_line` the surge-line flow at the measured ratio.
    #[allow(clippy::too_many_arguments)]
    pub fn update(
        &mut self,
        cfg: &DriftCheckConfig,
        t_s: f64,
        q_transmitter: f64,
        q_observer: f64,
        observer_unc: f64,
        q_speed_line: f64,
        speed_line_unc: f64,
        q_surge_line: f64,
    ) -> DriftVerdict {
        if !cfg.enabled {
            *self = DriftCheck::new();
            return self.verdict;
        }
        let dt = if self.last_t_s.is_finite() {
            (t_s - self.last_t_s).max(0.0)
        } else {
            0.0
        };
        self.last_t_s = t_s;
        let a = 1.0 - (-dt / cfg.filter_s.max(1e-6)).exp();
        let scale = q_surge_line.abs();
        let usable = q_transmitter.is_finite() && scale > 1e-12 && scale.is_finite();
        let r = |q: f64| {
            if usable {
                (q_transmitter - q) / scale
            } else {
                f64::NAN
            }
        };
        // a new sample: the transmitter's or the pressures' (the speed-line flow's) value moved
        let moved = |x: f64, last: f64| x.to_bits() != last.to_bits();
        let new_line = moved(q_speed_line, self.last_q_line);
        let new_sample = moved(q_transmitter, self.last_q_transmitter) || new_line;
        self.last_q_transmitter = q_transmitter;
        self.last_q_line = q_speed_line;
        self.obs.update(
            t_s,
            r(q_observer),
            observer_unc.abs() / scale,
            a,
            new_sample,
        );
        self.line.update(
            t_s,
            r(q_speed_line),
            speed_line_unc.abs() / scale,
            a,
            new_sample,
        );

        // the observer is a reference only while the speed line confirms it: both within
        // the speed line's uncertainty of each other (an observer still converging after a
        // transient, or off on a model error the map does not share, is not)
        let both = |o: f64, l: f64| {
            if o.is_finite() && l.is_finite() && scale > 1e-12 {
                (o - l) / scale
            } else {
                f64::NAN
            }
        };
        self.agree.update(
            t_s,
            both(q_observer, q_speed_line),
            speed_line_unc.abs() / scale,
            a,
            new_line,
        );
        let thr_obs = self.obs.threshold(t_s, cfg, a);
        let thr_line = self.line.threshold(t_s, cfg, a);
        let confirmed = self
            .agree
            .threshold(t_s, cfg, a)
            .is_some_and(|thr| self.agree.e.abs() <= thr);
        // only the dangerous direction is declared: a transmitter reading MORE flow than true
        // lets the law close onto the surge line; one reading less makes it recycle more (the
        // fallback, the lower flow, would keep its reading anyway), and a map that over-states
        // the pressure rise looks just the same
        let side = |e: f64, thr: f64| if e > thr { 1.0 } else { 0.0 };
        // (judged, direction of a disagreement beyond the threshold, back within half of it)
        let judgement = if self.obs.e.is_finite() {
            // a machine with an observer: the transmitter beyond the confirmed observer's
            // uncertainty, and beyond the speed-line flow's tolerance and noise too (its map
            // allowance went into confirming the observer)
            match (thr_obs, thr_line) {
                (Some(t), Some(tl)) if confirmed => {
                    let s = side(self.obs.e, t) * side(self.line.e, tl - self.line.unc);
                    Some((s, self.obs.e < 0.5 * t && self.line.e < 0.5 * tl))
                }
                // an observer the speed line does not confirm (still converging, or off on
                // an outflow it models without the outlet lines' inertia) is no reference:
                // the speed-line flow alone, with its whole map allowance
                (_, Some(tl)) => Some((side(self.line.e, tl), self.line.e < 0.5 * tl)),
                _ => None,
            }
        } else {
            // no observer: the speed-line flow alone
            thr_line.map(|t| (side(self.line.e, t), self.line.e < 0.5 * t))
        };
        let vs = [
            if thr_obs.is_some() {
                self.obs.e
            } else {
                f64::NAN
            },
            if thr_line.is_some() {
                self.line.e
            } else {
                f64::NAN
            },
        ];
        if let (true, Some((sign, back))) = (usable, judgement) {
            if !self.drifting {
                if sign != 0.0 && sign == self.sign && self.since_s.is_finite() {
                    if t_s - self.since_s >= cfg.persistence_s {
                        self.drifting = true;
                        self.since_s = f64::NAN;
                    }
                } else if sign != 0.0 {
                    self.sign = sign;
                    self.since_s = t_s;
                } else {
                    self.since_s = f64::NAN;
                }
            } else if back {
                if !self.since_s.is_finite() {
                    self.since_s = t_s;
                }
                if t_s - self.since_s >= cfg.clear_s {
                    self.drifting = false;
                    self.since_s = f64::NAN;
                    self.sign = 0.0;
                }
            } else {
                self.since_s = f64::NAN;
            }
        } else {
            // nothing to judge: a disagreement (or an agreement again) must start over
            self.since_s = f64::NAN;
        }
        self.verdict = DriftVerdict {
            drifting: self.drifting,
            vs_observer: vs[0],
            vs_speed_line: vs[1],
        };
        self.verdict
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rnd(seed: &mut u64) -> f64 {
        *seed ^= *seed << 13;
        *seed ^= *seed >> 7;
        *seed ^= *seed << 17;
        (*seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }

    /// 20 s at 1 kHz: true flow 1.2 × the surge-line flow 10; the observer sees the truth
    /// plus `obs_off`, the speed line the truth plus `line_off` (fractions of q_SL), both with
    /// `noise`; map uncertainties 2 % of q_SL each; the transmitter reads truth + bias(t).
    /// Returns when drift was first declared and when it last cleared.
    fn run(
        bias: impl Fn(f64) -> f64,
        noise: f64,
        obs_off: f64,
        line_off: f64,
    ) -> (Option<f64>, Option<f64>) {
        let cfg = DriftCheckConfig::default();
        let mut c = DriftCheck::new();
        let mut seed = 11u64;
        let (mut found, mut cleared) = (None, None);
        for k in 0..20_000 {
            let t = k as f64 * 1e-3;
            let q = 12.0 * (1.0 + 0.05 * (0.5 * t).sin());
            let qt = q + 10.0 * bias(t) + 10.0 * noise * rnd(&mut seed);
            let qo = q + 10.0 * obs_off + 10.0 * noise * rnd(&mut seed);
            let ql = q + 10.0 * line_off + 10.0 * noise * rnd(&mut seed);
            let v = c.update(&cfg, t, qt, qo, 0.2, ql, 0.2, 10.0);
            if v.drifting && found.is_none() {
                found = Some(t);
            }
            if !v.drifting && found.is_some() && cleared.is_none() {
                cleared = Some(t);
            }
        }
        (found, cleared.filter(|_| !c.drifting()))
    }

    #[test]
    fn a_high_bias_beyond_the_combined_uncertainty_is_found_and_clears() {
        // +20 % of surge-line flow from 5 s to 10 s (reads more flow than true)
        let (found, cleared) = run(
            |t| if (5.0..10.0).contains(&t) { 0.2 } else { 0.0 },
            0.02,
            0.0,
            0.0,
        );
        // threshold ≈ 5 % + 2 % map + noise: the 30 ms filter crosses it within ≈ 20 ms,
        // then 30 ms of persistence; trusted again 1 s (clear_s) after the bias has gone
        let found = found.expect("bias not found");
        assert!((5.02..5.1).contains(&found), "found at {found}");
        assert!(
            cleared.is_some_and(|c| (11.0..11.2).contains(&c)),
            "{cleared:?}"
        );
    }

    #[test]
    fn a_drift_ramp_is_found_once_it_exceeds_the_threshold() {
        // +2 %/s from t = 4 s: 7 % (tolerance + map) + noise at ≈ 7.6 s, + filter lag and
        // persistence
        let (found, _) = run(|t| 0.02 * (t - 4.0).max(0.0), 0.01, 0.0, 0.0);
        let found = found.expect("drift not found");
        assert!((7.5..8.5).contains(&found), "found at {found}");
    }

    #[test]
    fn noise_map_errors_low_readings_and_an_unconfirmed_observer_never_fire() {
        // 4 % high, both estimates 3 % low (a map error), 3 % noise: within the uncertainty
        assert_eq!(run(|_| 0.04, 0.03, -0.03, -0.03).0, None);
        // heavy noise: the estimates are no reference
        assert_eq!(run(|_| 0.3, 0.5, 0.0, 0.0).0, None);
        // reading LESS flow than true is not declared (safe direction)
        assert_eq!(run(|_| -0.3, 0.0, 0.0, 0.0).0, None);
        // an observer off by 30 % that the speed line does not confirm is no reference
        assert_eq!(run(|_| 0.0, 0.0, -0.3, 0.0).0, None);
        // the transmitter high against the observer but right by the speed line: not declared
        assert_eq!(run(|_| 0.1, 0.0, 0.0, 0.1).0, None);
    }

    #[test]
    fn a_transmitter_polled_slower_than_the_cycle_is_judged_on_its_samples_noise() {
        // a 1 kHz cycle, the Δp and the pressures polled at 50 Hz (each value repeated 20
        // cycles), the Δp with ±10 % of q_SL of noise: counted per cycle its noise would look
        // 20× smaller and a 30 ms filter pass most of it; no find. A +30 % bias is found.
        for bias in [0.0, 0.3] {
            let cfg = DriftCheckConfig::default();
            let mut c = DriftCheck::new();
            let mut seed = 5u64;
            let mut found = None;
            let (mut qt, mut ql) = (0.0, 0.0);
            for k in 0..20_000 {
                let t = k as f64 * 1e-3;
                let q = 12.0 * (1.0 + 0.05 * (0.5 * t).sin());
                if k % 20 == 0 {
                    let b = if t >= 10.0 { bias } else { 0.0 };
                    qt = q + 10.0 * (b + 0.1 * rnd(&mut seed));
                    ql = q;
                }
                if c.update(&cfg, t, qt, ql, 0.2, ql, 0.2, 10.0).drifting && found.is_none() {
                    found = Some(t);
                }
            }
            if bias == 0.0 {
                assert_eq!(found, None);
            } else {
                let found = found.expect("bias not found");
                assert!((10.0..10.2).contains(&found), "found at {found}");
            }
        }
    }

    #[test]
    fn an_observer_the_speed_line_does_not_confirm_leaves_the_speed_line_to_decide() {
        // the observer 30 % off the other way (an outflow model without the outlet lines'
        // inertia, in a transient): the speed line alone finds a +30 % bias, 30 ms + 30 ms
        let (found, _) = run(|t| if t >= 5.0 { 0.3 } else { 0.0 }, 0.0, 0.3, 0.0);
        let found = found.expect("bias not found by the speed line alone");
        assert!((5.02..5.1).contains(&found), "found at {found}");
        // within the speed line's whole allowance (5 % + 2 % map) it is not
        assert_eq!(
            run(|t| if t >= 5.0 { 0.06 } else { 0.0 }, 0.0, 0.3, 0.0).0,
            None
        );
    }

    #[test]
    fn the_speed_line_alone_decides_without_an_observer_and_a_disabled_check_never_fires() {
        let cfg = DriftCheckConfig::default();
        let mut c = DriftCheck::new();
        let mut found = false;
        for k in 0..5000 {
            let t = k as f64 * 1e-3;
            // no observer; the speed line (map) alone, the transmitter 20 % high
            found |= c
                .update(&cfg, t, 14.0, f64::NAN, f64::NAN, 12.0, 0.1, 10.0)
                .drifting;
        }
        assert!(found);
        let off = DriftCheckConfig {
            enabled: false,
            ..cfg
        };
        let mut c = DriftCheck::new();
        for k in 0..5000 {
            let v = c.update(&off, k as f64 * 1e-3, 14.0, 12.0, 0.1, 12.0, 0.1, 10.0);
            assert!(!v.drifting && v.vs_observer.is_nan());
        }
    }

    #[test]
    fn defaults_are_valid_and_bad_values_are_named() {
        assert!(DriftCheckConfig::default().problems().is_empty());
        let bad = DriftCheckConfig {
            threshold_pct: 0.0,
            filter_s: f64::NAN,
            clear_s: -1.0,
            ..DriftCheckConfig::default()
        };
        let p = bad.problems();
        assert_eq!(p.len(), 3, "{p:?}");
        assert_eq!(p[0].0, "drift_check.threshold_pct");
        assert_eq!(p[1].0, "drift_check.filter_s");
        assert_eq!(p[2].0, "drift_check.clear_s");
    }
}
