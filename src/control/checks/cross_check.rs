//! Transmitter cross-check: a flow element's Δp that stops changing while the pressures around
//! it move is frozen (a transmitter or gateway repeating its last value with a fresh
//! timestamp), even though every sample arrives on time and in range. Freshness and range
//! supervision cannot see it; this check can, and the control core then treats the Δp as
//! unusable ([`InputFault::Frozen`](crate::control::supervisor::InputFault::Frozen)): the flow falls
//! back to the conservative estimate (the lower of the observer's flow and the frozen
//! reading's), or to fail-safe when there is no observer.
//!
//! Physics behind "related signals": the orifice Δp is ∝ ṁ²/ρ with ρ ∝ p_suction, and on a
//! speed line the mass flow moves with the pressure ratio. A suction or discharge pressure
//! that moves by more than its noise floor therefore moves the Δp too, unless two effects
//! cancel exactly, which they do not for long. The check needs the Δp to stay within
//! [`DP_STILL`] of its reading for at least [`MIN_QUIET_S`] *and* a pressure to move beyond
//! [`PRESSURE_MOVE`] of its reading (or 4 × its measured sample-to-sample noise, whichever is
//! larger) meanwhile. A Δp reading of exactly zero (a transmitter's low-flow cut-off) is not
//! checked.
//!
//! A second criterion catches a frozen *noisy* transmitter at bus rates, where the pressures'
//! trend takes too long to clear their noise: a live Δp whose reading has visibly changed
//! (by more than [`NOISY_DP_REL`] of the reading, on average) on a fraction `f` of the
//! pressure samples repeats itself over `n` consecutive pressure samples with probability
//! `(1 − f)^n`; when that falls below [`REPEAT_PROBABILITY`] (and the repeat has lasted
//! [`MIN_QUIET_S`]) the reading is frozen. Counted in pressure *samples* (new values, not
//! cycles), so the same rule holds at 1 kHz and at a 50 Hz poll: with `f` ≈ 1 it fires after
//! [`MIN_REPEATS`] repeats and [`MIN_QUIET_S`], i.e. ≈ 0.1 s at 100 Hz and ≈ 0.12 s at 50 Hz
//! after the freeze (a Δp polled separately from the pressures, `f` ≈ ½: 20 samples). A smooth
//! noise-free reading (a simulation) never qualifies: its changes shrink gradually before it
//! stands still, so its average change is far below [`NOISY_DP_REL`].
//!
//! Pure and allocation-free: a few numbers of state, one call per cycle.

/// Shortest time the Δp must stay unchanged before it can be called frozen, s.
pub const MIN_QUIET_S: f64 = 0.1;
/// Relative pressure change that must happen meanwhile (of the reading; noise raises it).
pub const PRESSURE_MOVE: f64 = 2e-3;
/// Relative Δp change below which the Δp counts as unchanged (of the reading): a frozen
/// value repeats itself to the bit (an f32 register re-read, a gateway's cached answer); a
/// live transmitter's noise and the process move it far beyond this (one f32 rounding step
/// is 6e-8, a 16-bit register's step ≥ 1.5e-5 of its span). Smooth noise-free signals (a
/// simulation) at a flow extremum stay within it only for a few milliseconds.
pub const DP_STILL: f64 = 1e-6;
/// Weight of one new sample in the running sample-to-sample noise estimates.
const NOISE_WEIGHT: f64 = 0.01;
/// Average |sample-to-sample change| of the Δp, relative to the reading, from which a
/// reading counts as noisy (a live transmitter: 1e-3–1e-2; one 16-bit step of a
/// 0–100 kPa range at 5 kPa: 3e-4; a smooth simulated signal near standstill: < 1e-6).
pub const NOISY_DP_REL: f64 = 1e-4;
/// Probability below which a noisy reading's run of repeats is not chance (one false find in
/// a million runs of the check's length).
pub const REPEAT_PROBABILITY: f64 = 1e-6;
/// Fewest repeats (pressure samples) before a noisy reading can be called frozen.
pub const MIN_REPEATS: u32 = 3;
/// Pressure samples before the change fraction `f` is trusted.
const RATE_ARMS_AFTER: u32 = 20;
/// Weight of one pressure sample in the change fraction `f` (≈ 50 samples: 0.5 s at 100 Hz).
const RATE_WEIGHT: f64 = 0.02;

/// Running mean of |sample-to-sample change| of one signal (its noise and ripple), counted
/// on new values only (a repeated value is not a sample).
#[derive(Debug, Clone, Copy)]
struct Increment {
    last: f64,
    mean_abs: f64,
}

impl Increment {
    const NEW: Increment = Increment {
        last: f64::NAN,
        mean_abs: 0.0,
    };
    fn update(&mut self, x: f64) {
        if self.last.is_finite() && x != self.last {
            self.mean_abs += NOISE_WEIGHT * ((x - self.last).abs() - self.mean_abs);
        }
        self.last = x;
    }
}

/// The frozen-Δp check (see the module doc).
#[derive(Debug, Clone, Copy)]
pub struct FrozenDpCheck {
    /// Δp and pressures when the Δp last changed beyond its floor, and when.
    anchor_t_s: f64,
    anchor_dp_pa: f64,
    anchor_ps_pa: f64,
    anchor_pd_pa: f64,
    ps: Increment,
    pd: Increment,
    frozen: bool,
    /// When the Δp last changed before the current verdict, s (NaN: no anchor).
    frozen_since_s: f64,
    /// The repeat criterion: the Δp's own sample-to-sample change, the fraction of
    /// pressure samples on which it changed (and how many were counted), the Δp at the last
    /// pressure sample, the current run of repeats, when it began and `f` then.
    dp: Increment,
    change_rate: f64,
    rate_n: u32,
    dp_at_sample: f64,
    run: u32,
    run_since_s: f64,
    run_rate: f64,
    /// Whether the repeat criterion is on (always, but for the test that shows what it adds).
    repeat_criterion: bool,
}

impl Default for FrozenDpCheck {
    fn default() -> Self {
        Self::new()
    }
}

impl FrozenDpCheck {
    /// A check with no history.
    pub const fn new() -> FrozenDpCheck {
        FrozenDpCheck {
            anchor_t_s: f64::NAN,
            anchor_dp_pa: f64::NAN,
            anchor_ps_pa: f64::NAN,
            anchor_pd_pa: f64::NAN,
            ps: Increment::NEW,
            pd: Increment::NEW,
            frozen: false,
            frozen_since_s: f64::NAN,
            dp: Increment::NEW,
            change_rate: 0.0,
            rate_n: 0,
            dp_at_sample: f64::NAN,
            run: 0,
            run_since_s: f64::NAN,
            run_rate: 0.0,
            repeat_criterion: true,
        }
    }

    /// Whether the Δp is judged frozen now.
    pub fn frozen(&self) -> bool {
        self.frozen
    }

    /// Since when the frozen Δp has not changed, s (NaN unless frozen).
    pub fn frozen_since_s(&self) -> f64 {
        if self.frozen {
            self.frozen_since_s
        } else {
            f64::NAN
        }
    }

    fn anchor(&mut self, t_s: f64, dp: f64, ps: f64, pd: f64) {
        self.anchor_t_s = t_s;
        self.anchor_dp_pa = dp;
        self.anchor_ps_pa = ps;
        self.anchor_pd_pa = pd;
        self.frozen = false;
    }

    /// One cycle with the (supervised, usable) Δp, suction and discharge pressure readings,
    /// Pa; NaN for an unusable one (the check then starts over). Returns whether the Δp is
    /// frozen.
    pub fn update(&mut self, t_s: f64, dp_pa: f64, ps_pa: f64, pd_pa: f64) -> bool {
        if !(dp_pa.is_finite() && ps_pa.is_finite() && pd_pa.is_finite()) || dp_pa == 0.0 {
            *self = FrozenDpCheck {
                ps: self.ps,
                pd: self.pd,
                dp: self.dp,
                change_rate: self.change_rate,
                rate_n: self.rate_n,
                repeat_criterion: self.repeat_criterion,
                ..FrozenDpCheck::new()
            };
            return false;
        }
        let new_pressure_sample = ps_pa != self.ps.last || pd_pa != self.pd.last;
        self.ps.update(ps_pa);
        self.pd.update(pd_pa);
        self.dp.update(dp_pa);
        if new_pressure_sample && self.repeats(t_s, dp_pa) && self.repeat_criterion {
            if !self.frozen {
                self.frozen = true;
                self.frozen_since_s = self.run_since_s;
            }
            return true;
        }
        if !self.anchor_t_s.is_finite() {
            self.anchor(t_s, dp_pa, ps_pa, pd_pa);
            return false;
        }
        // a live transmitter's reading changes (noise, ripple, the process); a frozen one
        // repeats itself: "unchanged" is within DP_STILL of the reading
        if (dp_pa - self.anchor_dp_pa).abs() > DP_STILL * self.anchor_dp_pa.abs() {
            self.anchor(t_s, dp_pa, ps_pa, pd_pa);
            return false;
        }
        if self.run > 0 && self.frozen && self.frozen_since_s == self.run_since_s {
            // found by the repeat criterion and still repeating
            return true;
        }
        if !self.frozen {
            let moved = |x: f64, anchor: f64, noise: &Increment| {
                (x - anchor).abs() > (4.0 * noise.mean_abs).max(PRESSURE_MOVE * anchor.abs())
            };
            if t_s - self.anchor_t_s >= MIN_QUIET_S
                && (moved(ps_pa, self.anchor_ps_pa, &self.ps)
                    || moved(pd_pa, self.anchor_pd_pa, &self.pd))
            {
                self.frozen = true;
                self.frozen_since_s = self.anchor_t_s;
            }
        }
        self.frozen
    }
}

impl FrozenDpCheck {
    /// The repeat criterion at a new pressure sample (see the module doc): whether the noisy
    /// Δp's run of repeats is now too long for chance.
    fn repeats(&mut self, t_s: f64, dp_pa: f64) -> bool {
        let changed = dp_pa != self.dp_at_sample;
        self.dp_at_sample = dp_pa;
        if changed || !self.run_since_s.is_finite() {
            self.run = 0;
            self.run_since_s = t_s;
        } else {
            if self.run == 0 {
                // f as it was before the run: the run itself is the question
                self.run_rate = self.change_rate;
            }
            self.run = self.run.saturating_add(1);
        }
        if self.run == 0 {
            self.change_rate += RATE_WEIGHT * (1.0 - self.change_rate);
        } else {
            self.change_rate += RATE_WEIGHT * (0.0 - self.change_rate);
        }
        self.rate_n = self.rate_n.saturating_add(1);
        let noisy = self.dp.mean_abs > NOISY_DP_REL * dp_pa.abs();
        if !(noisy && self.rate_n >= RATE_ARMS_AFTER && self.run >= MIN_REPEATS) {
            return false;
        }
        if t_s - self.run_since_s < MIN_QUIET_S {
            return false;
        }
        // (1 − f)^n below the probability (f capped so one sample never decides)
        let q = (1.0 - self.run_rate).clamp(1e-3, 1.0);
        f64::from(self.run) * q.ln() <= REPEAT_PROBABILITY.ln()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Uniform noise in [−1, 1) from a xorshift sequence (deterministic per seed).
    fn symmetric_noise(seed: u64) -> impl FnMut() -> f64 {
        let mut seed = seed.max(1);
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        }
    }

    /// A closure-like ramp: pressures rise 2 %/s, the Δp 1.5 %/s; the Δp repeats its value
    /// from t = 1 s to 2 s.
    fn run(freeze: bool, noise: f64) -> (Option<f64>, Option<f64>) {
        let mut c = FrozenDpCheck::new();
        let mut rnd = symmetric_noise(7);
        let (mut found, mut cleared) = (None, None);
        let mut held = f64::NAN;
        for k in 0..3000 {
            let t = k as f64 * 1e-3;
            let ps = 2e6 * (1.0 + 0.02 * t) * (1.0 + noise * rnd());
            let pd = 4.4e6 * (1.0 + 0.02 * t) * (1.0 + noise * rnd());
            let mut dp = 3e4 * (1.0 + 0.015 * t) * (1.0 + 2.0 * noise * rnd());
            if freeze && (1.0..2.0).contains(&t) {
                if held.is_nan() {
                    held = dp;
                }
                dp = held;
            }
            let f = c.update(t, dp, ps, pd);
            if f && found.is_none() {
                found = Some(t);
            }
            if !f && found.is_some() && cleared.is_none() {
                cleared = Some(t);
            }
        }
        (found, cleared)
    }

    #[test]
    fn a_repeated_dp_while_the_pressures_move_is_found_within_300_ms_and_cleared() {
        let (found, cleared) = run(true, 0.0);
        let found = found.expect("frozen Δp not found");
        assert!((1.0..1.3).contains(&found), "found at {found}");
        let cleared = cleared.expect("never cleared");
        assert!((2.0..2.01).contains(&cleared), "cleared at {cleared}");
    }

    /// A slow noisy closure read by a poll at `poll_hz` (values held between polls, the check
    /// called at 1 kHz): the pressures rise 0.2 %/s with ±0.05 % noise, the Δp falls 10 %/s with
    /// ±`dp_noise` relative noise, quantised to `dp_step_pa`; frozen over [1, 2) s if `freeze`.
    /// Returns when it was found (s after the freeze) and when it cleared.
    fn polled(
        poll_hz: f64,
        freeze: bool,
        dp_noise: f64,
        dp_step_pa: f64,
        seed: u64,
        repeat_criterion: bool,
    ) -> (Option<f64>, Option<f64>) {
        let mut c = FrozenDpCheck::new();
        c.repeat_criterion = repeat_criterion;
        let mut rnd = symmetric_noise(seed);
        let (mut found, mut cleared) = (None, None);
        let (mut ps, mut pd, mut dp) = (f64::NAN, f64::NAN, f64::NAN);
        let mut held = f64::NAN;
        let period = (1000.0 / poll_hz).round() as u64;
        for k in 0..4000u64 {
            let t = k as f64 * 1e-3;
            if k % period == 0 {
                ps = 2e5 * (1.0 + 0.002 * t) * (1.0 + 5e-4 * rnd());
                pd = 4.4e5 * (1.0 + 0.002 * t) * (1.0 + 5e-4 * rnd());
                let live = 5e3 * (1.0 - 0.1 * t) * (1.0 + dp_noise * rnd());
                let live = (live / dp_step_pa).round() * dp_step_pa;
                dp = if freeze && (1.0..2.0).contains(&t) {
                    if held.is_nan() {
                        held = live;
                    }
                    held
                } else {
                    live
                };
            }
            let f = c.update(t, dp, ps, pd);
            if f && found.is_none() {
                found = Some(t - 1.0);
            }
            if !f && found.is_some() && cleared.is_none() {
                cleared = Some(t);
            }
        }
        (found, cleared)
    }

    #[test]
    fn a_frozen_noisy_dp_is_found_within_300_ms_at_50_and_100_hz_polling() {
        for poll_hz in [50.0, 100.0] {
            for seed in 1..=10 {
                let (found, cleared) = polled(poll_hz, true, 0.05, 1e-3, seed, true);
                let found = found.unwrap_or_else(|| panic!("{poll_hz} Hz seed {seed}: not found"));
                assert!(
                    (0.0..0.3).contains(&found),
                    "{poll_hz} Hz seed {seed}: found {found:.3} s after the freeze"
                );
                let cleared = cleared.expect("cleared");
                assert!(
                    (2.0..2.03).contains(&cleared),
                    "{poll_hz} Hz: cleared at {cleared}"
                );
            }
        }
    }

    #[test]
    fn the_repeat_criterion_fires_on_no_live_reading() {
        for poll_hz in [50.0, 100.0, 1000.0] {
            for seed in 1..=10 {
                // noisy, noisy and coarsely quantised (10 Pa steps: repeats are common), and
                // a noise-free reading beside noisy pressures
                for (noise, step) in [(0.05, 1e-3), (0.005, 10.0), (0.0, 1e-9)] {
                    assert_eq!(
                        polled(poll_hz, false, noise, step, seed, true).0,
                        None,
                        "{poll_hz} Hz seed {seed} noise {noise} step {step}"
                    );
                }
            }
        }
    }

    #[test]
    fn without_the_repeat_criterion_a_noisy_frozen_dp_is_found_late_or_never() {
        // the pressures' trend alone must clear their noise: at a 50 Hz poll most of the
        // same freezes are found later than 300 ms, or not at all
        let late = (1..=10)
            .filter(|&seed| {
                polled(50.0, true, 0.05, 1e-3, seed, false)
                    .0
                    .is_none_or(|f| f >= 0.3)
            })
            .count();
        assert!(late >= 5, "{late} of 10 late without the repeat criterion");
    }

    #[test]
    fn healthy_signals_clean_or_noisy_are_never_frozen() {
        assert_eq!(run(false, 0.0).0, None);
        assert_eq!(run(false, 0.01).0, None);
    }

    #[test]
    fn a_steady_dp_with_steady_pressures_is_not_frozen() {
        let mut c = FrozenDpCheck::new();
        for k in 0..5000 {
            assert!(!c.update(k as f64 * 1e-3, 3e4, 2e6, 4.4e6), "cycle {k}");
        }
        // nor a zero reading (low-flow cut-off) while the pressures move
        let mut c = FrozenDpCheck::new();
        for k in 0..5000 {
            let t = k as f64 * 1e-3;
            assert!(!c.update(t, 0.0, 2e6 * (1.0 + t), 4.4e6), "cycle {k}");
        }
    }
}
