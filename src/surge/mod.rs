//! Surge detection from the compressor flow: flow reversal and sustained limit cycles, with
//! the cycle frequency. One online detector, allocation-free, used by the simulation summary
//! and by the daemon's control cycle.
//!
//! Method: the flow is split into a slow mean (first-order low-pass) and a deviation. A cycle
//! is a full down-and-up excursion of the deviation through a hysteresis band of
//! ± `amplitude_threshold` (relative to the mean flow, with an absolute floor). A cycle
//! *qualifies* when its period lies in the surge band (seeds: 1–10 Hz; the band is wider to
//! catch slow deep surge and fast mild surge) and its half peak-to-peak amplitude exceeds the
//! threshold. A limit cycle is declared after `confirm_cycles` consecutive qualifying cycles
//! whose amplitude does not decay by more than `decay_tolerance` per cycle: a damped transient
//! after a disturbance is not surge. Every flow-reversal episode (flow below −reversal
//! threshold) also counts as a surge cycle unless it is already part of a counted limit cycle.

use serde::{Deserialize, Serialize};

/// Detector settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorConfig {
    /// Time constant of the mean-flow low-pass, s.
    #[serde(default = "d_mean_tau")]
    pub mean_time_constant_s: f64,
    /// Oscillation threshold as a fraction of the mean flow.
    #[serde(default = "d_amp_rel")]
    pub amplitude_threshold_rel: f64,
    /// Floor of the oscillation threshold, kg/s.
    #[serde(default = "d_amp_abs")]
    pub amplitude_threshold_abs_kg_s: f64,
    /// Flow below −this counts as reversal, kg/s (a small positive number).
    #[serde(default = "d_rev")]
    pub reversal_threshold_kg_s: f64,
    /// Lowest surge frequency accepted, Hz.
    #[serde(default = "d_fmin")]
    pub min_frequency_hz: f64,
    /// Highest surge frequency accepted, Hz.
    #[serde(default = "d_fmax")]
    pub max_frequency_hz: f64,
    /// Consecutive qualifying cycles that confirm a limit cycle.
    #[serde(default = "d_confirm")]
    pub confirm_cycles: u32,
    /// Largest per-cycle amplitude decay (fraction) still considered sustained.
    #[serde(default = "d_decay")]
    pub decay_tolerance: f64,
}

fn d_mean_tau() -> f64 {
    1.0
}
fn d_amp_rel() -> f64 {
    0.05
}
fn d_amp_abs() -> f64 {
    1e-3
}
fn d_rev() -> f64 {
    1e-3
}
fn d_fmin() -> f64 {
    0.3
}
fn d_fmax() -> f64 {
    30.0
}
fn d_confirm() -> u32 {
    3
}
fn d_decay() -> f64 {
    0.2
}

impl Default for DetectorConfig {
    fn default() -> Self {
        DetectorConfig {
            mean_time_constant_s: d_mean_tau(),
            amplitude_threshold_rel: d_amp_rel(),
            amplitude_threshold_abs_kg_s: d_amp_abs(),
            reversal_threshold_kg_s: d_rev(),
            min_frequency_hz: d_fmin(),
            max_frequency_hz: d_fmax(),
            confirm_cycles: d_confirm(),
            decay_tolerance: d_decay(),
        }
    }
}

/// What the detector reports for one update.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Detection {
    /// Nothing new.
    None,
    /// A limit cycle was just confirmed (first surge of an episode).
    SurgeStarted,
    /// One more surge cycle counted.
    SurgeCycle,
    /// Flow reversal began.
    ReversalStarted,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Band {
    Inside,
    Above,
    Below,
}

/// The oscillation threshold is at least this many times the flow signal's measured noise
/// (standard deviation per new sample): a noisy flow transmitter swings across a threshold
/// of 5 % of the mean flow at every poll (hemchi2016 at 10 % of surge-line flow, 2 % of
/// span of Δp noise: ±5 % of flow), which read as a 30 Hz limit cycle and moved the
/// control line right by a safety-on step for nothing. Four standard deviations: a real
/// surge cycle's swing is tens of percent of the flow, noise three cycles in a row that far
/// out is improbable.
pub const NOISE_THRESHOLD_FACTOR: f64 = 4.0;

/// Online surge detector.
#[derive(Debug, Clone)]
pub struct SurgeDetector {
    cfg: DetectorConfig,
    /// Noise of the flow per new sample, kg/s (running mean of half the absolute second
    /// difference of distinct samples, ≈ σ for white noise, ≈ 0 for a ramp).
    noise_kg_s: f64,
    /// The last two distinct flow samples, newest first, and when the newest came, s.
    distinct: [f64; 2],
    distinct_t_s: f64,
    initialised: bool,
    mean: f64,
    band: Band,
    went_below: bool,
    last_up_t: f64,
    cycle_max: f64,
    cycle_min: f64,
    run: u32,
    last_amp: f64,
    in_limit_cycle: bool,
    reversing: bool,
    // reversals already counted as surge cycles during the current run of qualifying cycles
    run_reversals: u32,
    /// Surge cycles counted (limit-cycle periods plus isolated reversal episodes).
    pub surge_cycles: u32,
    /// Flow-reversal episodes.
    pub reversals: u32,
    /// Frequency of the last qualifying cycle, Hz (NaN if none yet).
    pub frequency_hz: f64,
    /// Largest qualifying-cycle amplitude seen, kg/s.
    pub max_amplitude_kg_s: f64,
    /// Time of the last counted surge cycle or reversal, s (NaN if none).
    pub last_surge_t_s: f64,
}

impl SurgeDetector {
    /// New detector.
    pub fn new(cfg: DetectorConfig) -> Self {
        SurgeDetector {
            cfg,
            noise_kg_s: 0.0,
            distinct: [f64::NAN; 2],
            distinct_t_s: f64::NAN,
            initialised: false,
            mean: 0.0,
            band: Band::Inside,
            went_below: false,
            last_up_t: f64::NAN,
            cycle_max: f64::NEG_INFINITY,
            cycle_min: f64::INFINITY,
            run: 0,
            last_amp: 0.0,
            in_limit_cycle: false,
            reversing: false,
            run_reversals: 0,
            surge_cycles: 0,
            reversals: 0,
            frequency_hz: f64::NAN,
            max_amplitude_kg_s: 0.0,
            last_surge_t_s: f64::NAN,
        }
    }

    /// Whether a limit cycle is in progress.
    pub fn in_surge(&self) -> bool {
        self.in_limit_cycle || self.reversing
    }

    /// Slow mean flow, kg/s.
    pub fn mean_flow(&self) -> f64 {
        self.mean
    }

    /// Measured noise of the flow signal per new sample, kg/s.
    pub fn noise_kg_s(&self) -> f64 {
        self.noise_kg_s
    }

    /// Update the noise estimate with a sample: only a value that differs from the last
    /// counts (a slow bus under a fast cycle repeats each value), weighted by the time since
    /// the last new one (≈ 1 s average).
    fn track_noise(&mut self, t_s: f64, m_kg_s: f64) {
        let [p1, p2] = self.distinct;
        if m_kg_s == p1 {
            return;
        }
        if p1.is_finite() && p2.is_finite() && self.distinct_t_s.is_finite() {
            let w = (t_s - self.distinct_t_s).clamp(0.0, 1.0);
            let d2 = 0.5 * (m_kg_s - 2.0 * p1 + p2).abs();
            self.noise_kg_s += w * (d2 - self.noise_kg_s);
        }
        self.distinct = [m_kg_s, p1];
        self.distinct_t_s = t_s;
    }

    /// Feed one flow sample taken at `t_s` (`dt_s` since the previous one).
    pub fn update(&mut self, t_s: f64, dt_s: f64, m_kg_s: f64) -> Detection {
        if !m_kg_s.is_finite() {
            return Detection::None;
        }
        if !self.initialised {
            self.mean = m_kg_s;
            self.initialised = true;
        }
        let a = (dt_s / self.cfg.mean_time_constant_s).min(1.0);
        self.mean += a * (m_kg_s - self.mean);
        self.track_noise(t_s, m_kg_s);
        let mut result = Detection::None;

        // flow reversal episodes (with hysteresis)
        let rev = self.cfg.reversal_threshold_kg_s;
        if !self.reversing && m_kg_s < -rev {
            self.reversing = true;
            self.reversals += 1;
            if !self.in_limit_cycle {
                self.surge_cycles += 1;
                self.run_reversals += 1;
                self.last_surge_t_s = t_s;
            }
            result = Detection::ReversalStarted;
        } else if self.reversing && m_kg_s > rev {
            self.reversing = false;
        }

        // oscillation cycles around the mean
        let dev = m_kg_s - self.mean;
        self.cycle_max = self.cycle_max.max(dev);
        self.cycle_min = self.cycle_min.min(dev);
        let h = (self.cfg.amplitude_threshold_rel * self.mean.abs())
            .max(self.cfg.amplitude_threshold_abs_kg_s)
            .max(NOISE_THRESHOLD_FACTOR * self.noise_kg_s);
        let band = if dev > h {
            Band::Above
        } else if dev < -h {
            Band::Below
        } else {
            self.band
        };
        if band == Band::Below {
            self.went_below = true;
        }
        if band == Band::Above && self.band != Band::Above && self.went_below {
            // an upward crossing completes a cycle
            self.went_below = false;
            if self.last_up_t.is_finite() {
                let period = t_s - self.last_up_t;
                let amp = 0.5 * (self.cycle_max - self.cycle_min);
                let f = 1.0 / period;
                let qualifies =
                    f >= self.cfg.min_frequency_hz && f <= self.cfg.max_frequency_hz && amp > h;
                if qualifies {
                    let sustained =
                        self.run == 0 || amp >= (1.0 - self.cfg.decay_tolerance) * self.last_amp;
                    if !sustained {
                        self.run = 0;
                        self.run_reversals = 0;
                    }
                    self.run += 1;
                    self.last_amp = amp;
                    self.frequency_hz = f;
                    self.max_amplitude_kg_s = self.max_amplitude_kg_s.max(amp);
                    if self.in_limit_cycle {
                        self.surge_cycles += 1;
                        self.last_surge_t_s = t_s;
                        result = Detection::SurgeCycle;
                    } else if self.run >= self.cfg.confirm_cycles {
                        self.in_limit_cycle = true;
                        // the confirming cycles count; reversals already counted during them
                        // are not counted twice
                        self.surge_cycles += self.run.saturating_sub(self.run_reversals);
                        self.run_reversals = 0;
                        self.last_surge_t_s = t_s;
                        result = Detection::SurgeStarted;
                    }
                } else {
                    self.run = 0;
                    self.run_reversals = 0;
                    self.in_limit_cycle = false;
                }
            }
            self.last_up_t = t_s;
            self.cycle_max = dev;
            self.cycle_min = dev;
        }
        // an oscillation that dies out ends the limit cycle
        if self.in_limit_cycle
            && self.last_up_t.is_finite()
            && t_s - self.last_up_t > 2.0 / self.cfg.min_frequency_hz
        {
            self.in_limit_cycle = false;
            self.run = 0;
            self.run_reversals = 0;
        }
        self.band = band;
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(f: impl Fn(f64) -> f64, t_end: f64) -> SurgeDetector {
        let mut d = SurgeDetector::new(DetectorConfig::default());
        let dt = 1e-3;
        let n = (t_end / dt) as usize;
        for k in 0..n {
            let t = k as f64 * dt;
            d.update(t, dt, f(t));
        }
        d
    }

    #[test]
    fn steady_flow_is_not_surge() {
        let d = run(|_| 8.0, 10.0);
        assert_eq!(d.surge_cycles, 0);
        assert_eq!(d.reversals, 0);
        assert!(d.frequency_hz.is_nan());
    }

    #[test]
    fn sustained_oscillation_is_counted_with_frequency() {
        // 4 Hz, ±2 kg/s around 8 kg/s for 5 s: 20 periods
        let d = run(
            |t| 8.0 + 2.0 * (2.0 * std::f64::consts::PI * 4.0 * t).sin(),
            5.0,
        );
        assert!((d.frequency_hz - 4.0).abs() < 0.05, "{}", d.frequency_hz);
        assert!((17..=20).contains(&d.surge_cycles), "{}", d.surge_cycles);
        assert_eq!(d.reversals, 0);
    }

    #[test]
    fn damped_transient_is_not_surge() {
        // 3 Hz oscillation decaying by 50 % per period
        let d = run(
            |t| {
                8.0 + 3.0
                    * (-(0.5f64.ln().abs()) * 3.0 * t).exp()
                    * (2.0 * std::f64::consts::PI * 3.0 * t).sin()
            },
            5.0,
        );
        assert_eq!(d.surge_cycles, 0);
    }

    #[test]
    fn deep_surge_reversals_are_counted_once() {
        // 2 Hz between −3 and +9 kg/s: reversal every period
        let d = run(
            |t| 3.0 + 6.0 * (2.0 * std::f64::consts::PI * 2.0 * t).sin(),
            5.0,
        );
        assert_eq!(d.reversals, 10);
        assert!((9..=11).contains(&d.surge_cycles), "{}", d.surge_cycles);
        assert!((d.frequency_hz - 2.0).abs() < 0.05);
    }

    #[test]
    fn slow_ramp_is_not_surge() {
        let d = run(|t| 10.0 - 0.8 * t.min(8.0), 12.0);
        assert_eq!(d.surge_cycles, 0);
    }

    /// Uniform noise, a new value every 10 ms (a 100 Hz poll under a 1 kHz cycle), fixed seed.
    fn polled_noise(amplitude_kg_s: f64) -> impl Fn(f64) -> f64 {
        move |t: f64| {
            let k = (t / 0.01).floor() as u64;
            let mut x = k.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x5DEE_CE66;
            x ^= x >> 31;
            x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
            x ^= x >> 29;
            amplitude_kg_s * ((x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0)
        }
    }

    #[test]
    fn a_noisy_transmitter_on_a_steady_flow_is_not_surge() {
        // ±6 % of a 0.22 kg/s flow (hemchi2016 near its control line with 2 % of span of Δp
        // noise): without the noise floor this read as a limit cycle within seconds
        let noise = polled_noise(0.06 * 0.22);
        let d = run(|t| 0.22 + noise(t), 30.0);
        assert_eq!(d.surge_cycles, 0);
        assert!(d.noise_kg_s() > 0.003, "noise {}", d.noise_kg_s());
        let mut bare = SurgeDetector::new(DetectorConfig::default());
        bare.noise_kg_s = f64::NAN; // the floor off (NaN drops out of the max)
        let dt = 1e-3;
        let mut cycles = 0;
        for k in 0..30_000 {
            let t = k as f64 * dt;
            bare.update(t, dt, 0.22 + noise(t));
            bare.noise_kg_s = f64::NAN;
            cycles = bare.surge_cycles;
        }
        assert!(
            cycles > 0,
            "the fixture must fool a detector without the floor"
        );
    }

    #[test]
    fn surge_under_the_same_noise_is_still_counted() {
        // 4 Hz, ±40 % of 0.22 kg/s (a surge cycle's swing), with the noise above
        let noise = polled_noise(0.06 * 0.22);
        let d = run(
            |t| 0.22 * (1.0 + 0.4 * (2.0 * std::f64::consts::PI * 4.0 * t).sin()) + noise(t),
            5.0,
        );
        assert!((15..=20).contains(&d.surge_cycles), "{}", d.surge_cycles);
        assert!((d.frequency_hz - 4.0).abs() < 0.5, "{}", d.frequency_hz);
    }
}
