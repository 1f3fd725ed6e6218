//! The distinct samples of one measured quantity, as the bus delivers them: the recycle trip
//! keeps the surge margin's, the throttle watch the throttle position's. One ring, one noise
//! estimate and one slope for both, so the margin and the throttle are judged alike.
//!
//! A sample is *new* when it comes at a later measurement time *and* with a different value: a
//! value held by a slower poll is one sample, whether or not the bus tells its age, and a value
//! that truly stands still carries no rate. Its noise (σ) comes from the second difference of
//! the distinct samples (≈ σ for white noise, ≈ 0 on a clean ramp), averaged over
//! [`NOISE_TAU_S`].

/// Length of the ring of distinct samples: a 20 ms window at 1 kHz needs 21.
pub const RING: usize = 48;

/// Time constant of the noise estimate, s: long against a surge period (≤ 1 s), so a surge's
/// own swing, whose second difference is small at the sample rates used, hardly moves it.
pub const NOISE_TAU_S: f64 = 1.0;

/// Second differences in the noise estimate before a prediction may use it: a plain mean of 8
/// half second differences is within ±35 % of σ (two standard errors), which the 3σ
/// allowance absorbs; fewer let a lucky low estimate fire a prediction on noise.
pub const PREDICTION_ARMS_AFTER: u32 = 8;

/// Or a prediction arms after this much loop time with a usable value, s: one noise time
/// constant. Transmitters that read the same value poll after poll for that long show no noise
/// at their resolution (a steady, noise-free skid sends no distinct samples to count), and
/// their first motion is the disturbance itself.
pub const PREDICTION_ARMS_AFTER_S: f64 = NOISE_TAU_S;

/// The ring (fixed size, no allocation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DistinctSamples {
    values: [f64; RING],
    times_s: [f64; RING],
    /// The last sample time at which each sample's value was read again (a value that stood
    /// still over several polls was still there at its last poll: a motion that follows
    /// began after it).
    seen_s: [f64; RING],
    at: usize,
    len: usize,
    /// Noise of the value (σ), and the second differences in it so far.
    noise: f64,
    noise_n: u32,
    /// Loop time with a usable value so far, s.
    watched_s: f64,
    /// Mean interval between samples as the bus delivers them (a repeated value included),
    /// s (NaN: unknown).
    sample_dt_s: f64,
}

impl Default for DistinctSamples {
    fn default() -> Self {
        Self::new()
    }
}

impl DistinctSamples {
    /// An empty ring.
    pub const fn new() -> Self {
        DistinctSamples {
            values: [f64::NAN; RING],
            times_s: [f64::NAN; RING],
            seen_s: [f64::NAN; RING],
            at: 0,
            len: 0,
            noise: 0.0,
            noise_n: 0,
            watched_s: 0.0,
            sample_dt_s: f64::NAN,
        }
    }

    /// Forget the samples (the noise estimate, the watched time and the sample period are
    /// kept: the transmitters are the same).
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// Distinct samples held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Measurement time from the oldest sample held to the newest, s (0 with fewer than two).
    pub fn span_s(&self) -> f64 {
        if self.len < 2 {
            return 0.0;
        }
        self.sample(0).1 - self.sample(self.len - 1).1
    }

    /// Whether no sample is held.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The measured noise (σ, in the value's unit).
    pub fn noise(&self) -> f64 {
        self.noise
    }

    /// Mean interval between samples as the bus delivers them, a repeated value included, s
    /// (NaN: unknown).
    pub fn sample_dt_s(&self) -> f64 {
        self.sample_dt_s
    }

    /// Whether a prediction may use the noise estimate (see [`PREDICTION_ARMS_AFTER`] and
    /// [`PREDICTION_ARMS_AFTER_S`]).
    pub fn armed(&self) -> bool {
        self.noise_n >= PREDICTION_ARMS_AFTER || self.watched_s >= PREDICTION_ARMS_AFTER_S
    }

    /// Sample `back` places before the newest: (value, measurement time).
    pub fn sample(&self, back: usize) -> (f64, f64) {
        let i = (self.at + RING - back) % RING;
        (self.values[i], self.times_s[i])
    }

    /// The last time sample `back` was read again.
    fn seen(&self, back: usize) -> f64 {
        self.seen_s[(self.at + RING - back) % RING]
    }

    /// Count loop time with a usable value (arms predictions).
    pub fn watch(&mut self, value: f64, dt_s: f64) {
        if value.is_finite() {
            self.watched_s += dt_s.max(0.0);
        }
    }

    /// Loop time with a usable value so far, s.
    pub fn watched_s(&self) -> f64 {
        self.watched_s
    }

    /// Record `value` measured at `t_s` when it is new; returns whether it was.
    pub fn push(&mut self, value: f64, t_s: f64) -> bool {
        self.push_spaced(value, t_s, 0.0)
    }

    /// [`DistinctSamples::push`], taking a new sample only `spacing_s` or more after the
    /// newest (a ring that spans a longer window at a fast poll).
    pub fn push_spaced(&mut self, value: f64, t_s: f64, spacing_s: f64) -> bool {
        if !(value.is_finite() && t_s.is_finite()) {
            return false;
        }
        if self.len > 0 {
            let (v0, t0) = self.sample(0);
            if t_s <= t0 + 1e-9 {
                return false;
            }
            if t_s < t0 + spacing_s - 1e-9 {
                return false;
            }
            // the sample period is the bus's, counted from the last time the newest value was
            // read, whether or not the value moved: a noise-free transmitter at a standstill
            // still answers every poll, and a disturbance's first sample comes one poll after
            // the last (counting only distinct values left the period unknown until the
            // disturbance, and the trip's horizon one period short on its first sample)
            let read_dt = t_s - self.seen_s[self.at];
            if read_dt > 1e-9 {
                // (an outage is no sample period: at most 0.1 s counts)
                let dt_c = read_dt.min(0.1);
                self.sample_dt_s = if self.sample_dt_s.is_finite() {
                    self.sample_dt_s + (dt_c / NOISE_TAU_S).min(1.0) * (dt_c - self.sample_dt_s)
                } else {
                    dt_c
                };
            }
            if value == v0 {
                // the same value at a later poll: still there then
                self.seen_s[self.at] = self.seen_s[self.at].max(t_s);
                return false;
            }
            let dt = t_s - t0;
            if self.len > 1 {
                let (v1, _) = self.sample(1);
                // σ ≈ |v_k − 2 v_k−1 + v_k−2|/2 for white noise (E|·| = 1.95 σ), ≈ 0 on a ramp
                let d2 = 0.5 * (value - 2.0 * v0 + v1).abs();
                self.noise_n = self.noise_n.saturating_add(1);
                // a 1-s average, but a plain mean over its first samples (from zero a 1-s
                // average reads no noise during the first second after a start); once the
                // value was watched for a noise time constant the estimate stands, zero
                // included: a disturbance's first samples after a standstill are no noise
                // to average in at full weight
                let w = (dt / NOISE_TAU_S).clamp(0.0, 1.0);
                let w = if self.watched_s >= NOISE_TAU_S {
                    w
                } else {
                    w.max(1.0 / f64::from(self.noise_n))
                };
                self.noise += w * (d2 - self.noise);
            }
        }
        self.at = (self.at + 1) % RING;
        self.values[self.at] = value;
        self.times_s[self.at] = t_s;
        self.seen_s[self.at] = t_s;
        self.len = (self.len + 1).min(RING);
        true
    }

    /// The value the quantity had at measurement time `tau_s` (the newest sample taken at or
    /// before it; the oldest held when all are newer) and the last time it was read: the
    /// motion since `tau_s` began after then. `None` when the ring is empty.
    pub fn value_at(&self, tau_s: f64) -> Option<(f64, f64)> {
        if self.len == 0 {
            return None;
        }
        let mut k = 0;
        while k + 1 < self.len && self.sample(k).1 > tau_s + 1e-9 {
            k += 1;
        }
        Some((self.sample(k).0, self.seen(k)))
    }

    /// Least-squares slope of the samples taken within the last `window_s` before the newest
    /// (at least three), per second, and its standard deviation per unit of sample noise
    /// (1/√Σ(t − t̄)²: times σ it is the slope's own noise). NaN without three samples.
    pub fn fitted_slope(&self, window_s: f64) -> (f64, f64) {
        let (slope, per_sigma, _) = self.fitted_line(window_s);
        (slope, per_sigma)
    }

    /// [`DistinctSamples::fitted_slope`], and the fitted line's value at the newest sample's
    /// time (the level with the samples' noise averaged out).
    pub fn fitted_line(&self, window_s: f64) -> (f64, f64, f64) {
        if self.len < 3 {
            return (f64::NAN, f64::NAN, f64::NAN);
        }
        let (_, t0) = self.sample(0);
        let mut n = 0usize;
        while n < self.len && (n < 3 || t0 - self.sample(n).1 <= window_s + 1e-9) {
            n += 1;
        }
        let nf = n as f64;
        let (mut st, mut sv) = (0.0, 0.0);
        for k in 0..n {
            let (v, t) = self.sample(k);
            st += t - t0;
            sv += v;
        }
        let (tm, vm) = (st / nf, sv / nf);
        let (mut stt, mut stv) = (0.0, 0.0);
        for k in 0..n {
            let (v, t) = self.sample(k);
            let dt = t - t0 - tm;
            stt += dt * dt;
            stv += dt * (v - vm);
        }
        if stt <= 0.0 {
            return (f64::NAN, f64::NAN, f64::NAN);
        }
        let slope = stv / stt;
        (slope, 1.0 / stt.sqrt(), vm - slope * tm)
    }

    /// Slope of the value over the last `window_s` (at least one sample interval), per
    /// second; the window's span, s; and the value at its start (NaN without two samples).
    /// The window starts at the last poll that still read its oldest sample's value: after a
    /// value that stood still for seconds, the motion began after its last reading, not
    /// seconds ago.
    pub fn slope(&self, window_s: f64) -> (f64, f64, f64) {
        if self.len < 2 {
            return (f64::NAN, f64::NAN, f64::NAN);
        }
        let (v0, t0) = self.sample(0);
        let mut k = 1;
        while k + 1 < self.len && t0 - self.seen(k) < window_s {
            k += 1;
        }
        let (vk, _) = self.sample(k);
        let span = t0 - self.seen(k);
        ((v0 - vk) / span, span, vk)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_held_value_is_one_sample_and_a_ramp_has_no_noise() {
        let mut s = DistinctSamples::new();
        for k in 0..10 {
            let t = 0.01 * f64::from(k);
            // each value read twice (a slower poll)
            assert!(s.push(1.0 - 0.1 * t, t));
            assert!(!s.push(1.0 - 0.1 * t, t + 0.005));
        }
        assert_eq!(s.len(), 10);
        assert!(s.noise() < 1e-9, "{}", s.noise());
        let (slope, span, start) = s.slope(0.02);
        // from the last poll that still read the window's first value (0.065 s) to the newest
        // sample (0.09 s): 0.003 fell in 0.025 s
        assert!((span - 0.025).abs() < 1e-9, "{span}");
        assert!((slope + 0.12).abs() < 1e-9, "{slope}");
        assert!((start - (1.0 - 0.1 * 0.06)).abs() < 1e-12, "{start}");
    }

    #[test]
    fn the_sample_period_is_the_polls_even_while_the_value_stands_still() {
        // a noise-free transmitter read at 100 Hz for a second, then its first motion
        let mut s = DistinctSamples::new();
        s.push(0.6, 0.0);
        for k in 1..100 {
            assert!(!s.push(0.6, 0.01 * f64::from(k)));
        }
        let dt = s.sample_dt_s();
        assert!((dt - 0.01).abs() < 1e-9, "{dt}");
        assert!(s.push(0.45, 1.0));
        assert!((s.sample_dt_s() - 0.01).abs() < 1e-9);
        // an outage is no period: a 3-s gap counts at most 0.1 s
        s.push(0.40, 4.0);
        assert!(s.sample_dt_s() < 0.11, "{}", s.sample_dt_s());
    }

    #[test]
    fn white_noise_is_measured_near_its_sigma() {
        let mut s = DistinctSamples::new();
        // ±a uniform: σ = a/√3
        let mut x: u64 = 12345;
        for k in 0..2000 {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0;
            let t = 1e-3 * f64::from(k);
            s.watch(1.0, 1e-3);
            s.push(0.5 + 0.01 * u, t);
        }
        let sigma = 0.01 / 3f64.sqrt();
        // E|d2|/2 of three uniform draws: within 30 % of σ
        assert!(
            (s.noise() / sigma - 1.0).abs() < 0.3,
            "{} vs {sigma}",
            s.noise()
        );
        assert!(s.armed());
    }

    #[test]
    fn the_fitted_slope_of_a_ramp_is_its_rate_and_its_noise_falls_with_the_window() {
        let mut s = DistinctSamples::new();
        for k in 0..400 {
            let t = 1e-3 * f64::from(k);
            s.push_spaced(2.0 - 0.5 * t, t, 0.008);
        }
        // 8 ms apart: 48 samples span 0.376 s
        let (slope, per_sigma) = s.fitted_slope(0.2);
        assert!((slope + 0.5).abs() < 1e-9, "{slope}");
        let (_, _, level) = s.fitted_line(0.2);
        assert!((level - s.sample(0).0).abs() < 1e-9, "{level}");
        let (_, per_sigma_short) = s.fitted_slope(0.02);
        // 26 samples over 0.2 s against 3 over 0.016 s
        assert!(
            per_sigma < 0.1 * per_sigma_short,
            "{per_sigma} {per_sigma_short}"
        );
        assert!(s.len() == RING && s.sample(0).1 - s.sample(1).1 >= 0.008 - 1e-9);
    }

    #[test]
    fn the_value_at_a_time_is_the_newest_sample_taken_by_then() {
        let mut s = DistinctSamples::new();
        assert_eq!(s.value_at(0.0), None);
        s.push(0.6, 0.0);
        s.push(0.6, 0.02); // read again
        s.push(0.45, 0.04);
        s.push(0.1, 0.06);
        assert_eq!(s.value_at(0.03), Some((0.6, 0.02)));
        assert_eq!(s.value_at(0.04), Some((0.45, 0.04)));
        assert_eq!(s.value_at(0.1), Some((0.1, 0.06)));
        // before every sample: the oldest
        assert_eq!(s.value_at(-1.0), Some((0.6, 0.02)));
    }
}
