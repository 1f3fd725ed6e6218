//! Transmitter cross-check: a flow element's Δp that stops changing while the pressures around
//! it move is frozen (a transmitter or gateway repeating its last value with a fresh
//! timestamp), even though every sample arrives on time and in range. Freshness and range
//! supervision cannot see it; this check can, and the control core then treats the Δp as
//! unusable ([`InputFault::Frozen`](super::supervisor::InputFault::Frozen)): the flow falls
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
                ..FrozenDpCheck::new()
            };
            return false;
        }
        self.ps.update(ps_pa);
        self.pd.update(pd_pa);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A closure-like ramp: pressures rise 2 %/s, the Δp 1.5 %/s; the Δp repeats its value
    /// from t = 1 s to 2 s.
    fn run(freeze: bool, noise: f64) -> (Option<f64>, Option<f64>) {
        let mut c = FrozenDpCheck::new();
        let mut seed = 7u64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
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
