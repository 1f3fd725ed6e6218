//! Mass-flow observer (seed 000 eq. 14–17): estimates the compressor mass flow from pressures
//! and speed only, so a law can run without a flow transmitter or fall back to it when the
//! transmitter fails.
//!
//! Eq. 14 copies the duct equation and injects the estimation error:
//!
//! ```text
//! dm̂/dt = A/L (Ψ̂c p_in − p) + A/L c2 (m − m̂),   Ψ̂c = Ψc(m̂, ω)
//! ```
//!
//! It needs the unmeasured m. With z = m̂ − K_z p, K_z = (V/a²)(A/L) c2 and the volume's mass
//! balance dp/dt = a²/V (m − m_out) (eq. 1a) we have dm̂/dt = ż + (A/L) c2 (m − m_out), so
//!
//! ```text
//! ż = A/L (Ψ̂c p_in − p − c2 m̂ + c2 m_out),   m̂ = z + K_z p        (derived form of eq. 15)
//! ```
//!
//! Correction: the seed prints "− c2 m_t" in eq. 15a. Derived as above the sign is "+"; with the
//! printed sign the error equation keeps a forcing term 2 (A/L) c2 m_out and the estimate
//! converges to a wrong value (tests/control/observer.rs shows both). The z-form uses only the
//! pressures, the speed and the outflow m_out, which the controller computes from the outlet
//! valves' position feedback and the valve equations.
//!
//! Gain: the error dynamics (eq. 16) are dm̃/dt = A/L (Ψ̃c p_in − c2 m̃); by the mean-value
//! theorem they are exponentially stable if c2 > p_in · sup ∂Ψc/∂m (eq. 17 prints a spurious
//! factor 2, ERRATA.md), with rate at least (A/L)(c2 − p_in sup ∂Ψc/∂m).
//!
//! Discretisation: implicit Euler on the whole z equation, z₊ = z + h f(m̂₊) with
//! m̂₊ = z₊ + K_z p, solved for m̂₊ by Newton's method from the last estimate (at most
//! [`NEWTON_ITERATIONS`] steps, each z₊ = z + h f / (1 + h (A/L)(c2 − p_in ∂Ψ̂/∂m)) linearised
//! at the current iterate). Under the gain condition the denominator is > 1 wherever
//! ∂Ψ̂/∂m > 0, and a falling characteristic only makes it larger, so the update is stable at
//! any cycle time. (Implicit only in −c2 m̂ is not enough: in deep surge the estimate visits
//! the steep choke side, where an explicit Ψ̂ term oscillates and diverges.)
//!
//! Why Newton from the last estimate, not one linearised step: with a large gain the explicit
//! part K_z Δp of each cycle is large (kvangardsnes2009, c2 = 1.5e6 Pa·s/kg: K_z = 0.047 kg/s
//! per Pa, and a throttle closure raises the discharge pressure 160 Pa per 1 ms cycle, so
//! z + K_z p moves 7.5 kg/s a cycle). One step linearised there, 7.5 kg/s away on the steep
//! choke side, fell short every cycle: the estimate ran 2.5 kg/s above the true 10.3 kg/s within
//! 1 s of the closure and then jumped to the negative branch (−0.5 kg/s), so a frozen-Δp
//! fallback opened the recycle valve fully for nothing.

use serde::{Deserialize, Serialize};

/// Newton steps per cycle at most (the implicit Euler update); 1–2 suffice near a steady
/// state, the rest is for a large pressure step on a steep characteristic.
pub const NEWTON_ITERATIONS: usize = 4;

/// Observer settings (`[controller.observer]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObserverConfig {
    /// Observer gain c2 of eq. 14, Pa per kg/s (K_m̃ = (A/L) c2). Seed 000 §6.2: 40 000.
    pub c2_pa_s_kg: f64,
    /// First-order low-pass on the pressures fed to the observer, Hz (0: off). The estimate
    /// m̂ = z + K_z p passes pressure noise with gain K_z (ERRATA.md): filtering trades noise for
    /// lag.
    pub pressure_filter_hz: f64,
}

impl Default for ObserverConfig {
    fn default() -> Self {
        ObserverConfig {
            c2_pa_s_kg: 40_000.0,
            pressure_filter_hz: 0.0,
        }
    }
}

/// The volume/duct pair the observer copies: the outlet volume whose pressure it measures and
/// the compressor duct.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObserverPlant {
    /// A/L of the compressor duct, m.
    pub area_over_length_m: f64,
    /// V/a² of the outlet volume, kg/Pa (s²·m).
    pub volume_over_sonic2: f64,
}

/// First-order low-pass filter (bypassed when the cut-off is 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LowPass {
    cutoff_hz: f64,
    y: f64,
    started: bool,
}

impl LowPass {
    /// A filter with cut-off `cutoff_hz` (0: pass-through).
    pub fn new(cutoff_hz: f64) -> Self {
        LowPass {
            cutoff_hz,
            y: 0.0,
            started: false,
        }
    }

    /// Filter one sample taken `dt_s` after the previous one.
    #[inline]
    pub fn update(&mut self, x: f64, dt_s: f64) -> f64 {
        if self.cutoff_hz <= 0.0 || !self.started || !x.is_finite() {
            self.y = x;
            self.started = x.is_finite();
            return x;
        }
        let a = 1.0 - (-2.0 * std::f64::consts::PI * self.cutoff_hz * dt_s).exp();
        self.y += a * (x - self.y);
        self.y
    }

    /// The same filter state with another cut-off (hot reload: no jump in the output).
    pub fn with_cutoff(&self, cutoff_hz: f64) -> Self {
        LowPass { cutoff_hz, ..*self }
    }

    /// Restart from `x`.
    pub fn reset(&mut self, x: f64) {
        self.y = x;
        self.started = x.is_finite();
    }
}

/// The observer state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MassFlowObserver {
    c2: f64,
    a_over_l: f64,
    k_z: f64,
    z: f64,
    /// The last estimate m̂, kg/s (where the next cycle's Newton iteration starts).
    m_hat_last: f64,
    started: bool,
    p_filter: LowPass,
    p_in_filter: LowPass,
}

impl MassFlowObserver {
    /// Observer for a volume/duct pair.
    pub fn new(cfg: &ObserverConfig, plant: ObserverPlant) -> Self {
        let a_over_l = plant.area_over_length_m;
        MassFlowObserver {
            c2: cfg.c2_pa_s_kg,
            a_over_l,
            k_z: plant.volume_over_sonic2 * a_over_l * cfg.c2_pa_s_kg,
            z: 0.0,
            m_hat_last: f64::NAN,
            started: false,
            p_filter: LowPass::new(cfg.pressure_filter_hz),
            p_in_filter: LowPass::new(cfg.pressure_filter_hz),
        }
    }

    /// This observer with new settings (hot reload), carrying the current estimate over: the
    /// filtered pressures keep their values and z is re-based on the new K_z, so m̂ does not
    /// jump and a running flow-transmitter fallback is not interrupted.
    pub fn retuned(&self, cfg: &ObserverConfig, plant: ObserverPlant) -> Self {
        let mut next = MassFlowObserver::new(cfg, plant);
        if self.started {
            let p = self.p_filter.y;
            let m_hat = self.estimate(p);
            next.p_filter = self.p_filter.with_cutoff(cfg.pressure_filter_hz);
            next.p_in_filter = self.p_in_filter.with_cutoff(cfg.pressure_filter_hz);
            next.z = m_hat - next.k_z * p;
            next.m_hat_last = m_hat;
            next.started = m_hat.is_finite();
        }
        next
    }

    /// K_z = (V/a²)(A/L) c2, s: the gain from measured pressure to the estimate.
    pub fn k_z(&self) -> f64 {
        self.k_z
    }

    /// c2, Pa per kg/s.
    pub fn c2(&self) -> f64 {
        self.c2
    }

    /// A/L, m.
    pub fn area_over_length(&self) -> f64 {
        self.a_over_l
    }

    /// Whether the observer has been initialised.
    pub fn started(&self) -> bool {
        self.started
    }

    /// Initialise so that the estimate equals `m_kg_s` at outlet pressure `p_pa`.
    pub fn reset(&mut self, m_kg_s: f64, p_pa: f64, p_in_pa: f64) {
        self.p_filter.reset(p_pa);
        self.p_in_filter.reset(p_in_pa);
        self.z = m_kg_s - self.k_z * p_pa;
        self.m_hat_last = m_kg_s;
        self.started = true;
    }

    /// The estimate m̂ = z + K_z p for outlet pressure `p_pa` (eq. 15b).
    #[inline]
    pub fn estimate(&self, p_pa: f64) -> f64 {
        self.z + self.k_z * p_pa
    }

    /// ż of the derived eq. 15a: A/L (Ψ̂ p_in − p − c2 m̂ + c2 m_out), with Ψ̂ given.
    #[inline]
    pub fn z_rate(&self, z: f64, p_in_pa: f64, p_pa: f64, m_out_kg_s: f64, psi_hat: f64) -> f64 {
        let m_hat = z + self.k_z * p_pa;
        self.a_over_l * (psi_hat * p_in_pa - p_pa - self.c2 * m_hat + self.c2 * m_out_kg_s)
    }

    /// dm̂/dt of eq. 14 (needs the true flow m; for checking the z-form).
    #[inline]
    pub fn eq14_rate(&self, m_hat: f64, m_kg_s: f64, p_in_pa: f64, p_pa: f64, psi_hat: f64) -> f64 {
        self.a_over_l * (psi_hat * p_in_pa - p_pa) + self.a_over_l * self.c2 * (m_kg_s - m_hat)
    }

    /// One cycle: inlet and outlet pressures, outflow of the outlet volume, cycle time, and the
    /// characteristic Ψc as a function of the estimated mass flow. Returns m̂, kg/s.
    pub fn update(
        &mut self,
        p_in_pa: f64,
        p_pa: f64,
        m_out_kg_s: f64,
        dt_s: f64,
        psi: impl Fn(f64) -> f64,
    ) -> f64 {
        let p = self.p_filter.update(p_pa, dt_s);
        let p_in = self.p_in_filter.update(p_in_pa, dt_s);
        if !self.started {
            // start from the steady state: m̂ = m_out
            self.reset(m_out_kg_s, p, p_in);
        }
        // implicit Euler: m̂₊ = z + K_z p + h f(m̂₊), f = Ψ̂ p_in − p − c2 m̂ + c2 m_out
        let h = dt_s * self.a_over_l;
        let base = self.estimate(p);
        let residual = |m: f64, psi_m: f64| {
            m - base - h * (psi_m * p_in - p - self.c2 * m + self.c2 * m_out_kg_s)
        };
        let mut m = if self.m_hat_last.is_finite() {
            self.m_hat_last
        } else {
            base
        };
        // each pass evaluates Ψ̂ at the iterate (its residual, kept if the best so far) and
        // once more beside it (a forward difference for the slope): a step that has
        // converged costs three evaluations, as the one-step update did
        let mut best = (f64::INFINITY, base);
        let mut converged = false;
        for pass in 0..=NEWTON_ITERATIONS {
            let psi_m = psi(m);
            let g = residual(m, psi_m);
            if !g.is_finite() {
                break;
            }
            if g.abs() < best.0 {
                best = (g.abs(), m);
            }
            if converged || pass == NEWTON_ITERATIONS {
                break;
            }
            let dm = 1e-6 * m.abs().max(1e-3);
            let slope = (psi(m + dm) - psi_m) / dm;
            // ∂g/∂m = 1 + h (c2 − p_in ∂Ψ̂/∂m), kept ≥ 1 (a rising characteristic steeper
            // than the gain condition allows must not turn the step around)
            let dg = 1.0 + h * (self.c2 - p_in * slope).max(0.0);
            let step = g / dg;
            m -= step;
            converged = step.abs() <= 1e-7 * m.abs().max(1e-3);
        }
        let m_new = best.1;
        let z_new = m_new - self.k_z * p;
        if z_new.is_finite() {
            self.z = z_new;
            self.m_hat_last = m_new;
        }
        self.estimate(p)
    }
}

/// Smallest observer gain for exponential convergence, c2 > p_in · sup ∂Ψc/∂m over the region
/// (seed 000 eq. 17 without its spurious factor 2, ERRATA.md), Pa per kg/s.
pub fn min_gain(p_in_pa: f64, sup_dpsi_dm_per_kg_s: f64) -> f64 {
    p_in_pa * sup_dpsi_dm_per_kg_s.max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs() -> MassFlowObserver {
        MassFlowObserver::new(
            &ObserverConfig::default(),
            ObserverPlant {
                area_over_length_m: 0.015,
                volume_over_sonic2: 1.5 / (340.0 * 340.0),
            },
        )
    }

    #[test]
    fn z_form_rate_equals_eq14_when_pressure_obeys_the_mass_balance() {
        // dm̂/dt = ż + K_z ṗ with ṗ = a²/V (m − m_out) must equal eq. 14
        let o = obs();
        let (m, m_hat, m_out, p, p_in, psi) = (8.0, 6.5, 7.2, 2.2e5, 1.0e5, 2.31);
        let z = m_hat - o.k_z() * p;
        let p_dot = (340.0 * 340.0 / 1.5) * (m - m_out);
        let lhs = o.z_rate(z, p_in, p, m_out, psi) + o.k_z() * p_dot;
        let rhs = o.eq14_rate(m_hat, m, p_in, p, psi);
        assert!(
            (lhs - rhs).abs() < 1e-9 * rhs.abs().max(1.0),
            "{lhs} vs {rhs}"
        );
    }

    #[test]
    fn semi_implicit_update_is_stable_for_huge_gain() {
        let mut o = MassFlowObserver::new(
            &ObserverConfig {
                c2_pa_s_kg: 1e9,
                pressure_filter_hz: 0.0,
            },
            ObserverPlant {
                area_over_length_m: 0.015,
                volume_over_sonic2: 1.5 / (340.0 * 340.0),
            },
        );
        o.reset(1.0, 2e5, 1e5);
        for _ in 0..1000 {
            let m = o.update(1e5, 2e5, 8.0, 1e-3, |_| 2.0);
            assert!(m.is_finite() && m.abs() < 100.0, "{m}");
        }
    }

    /// A large gain and a fast pressure ramp (kvangardsnes2009: c2 = 1.5e6 Pa·s/kg, V2 = 0.1 m³,
    /// a = 401 m/s, A/L = 0.05 m, the discharge pressure rising 160 kPa/s in a throttle
    /// closure) on a curved characteristic: the estimate must follow the true flow. One
    /// linearised step per cycle ran 2.5 kg/s high within 1 s on that plant, and 0.29 kg/s off
    /// here (one Newton step from the new base is exactly that update).
    #[test]
    fn follows_a_fast_pressure_ramp_with_a_large_gain() {
        let plant = ObserverPlant {
            area_over_length_m: 0.05,
            volume_over_sonic2: 0.1 / (401.0 * 401.0),
        };
        let mut o = MassFlowObserver::new(
            &ObserverConfig {
                c2_pa_s_kg: 1.5e6,
                pressure_filter_hz: 0.0,
            },
            plant,
        );
        // Ψ(m) falls right of its peak at 8 kg/s, steeper and steeper towards choke
        let psi = |m: f64| 2.25 - 0.004 * (m - 8.0).powi(2);
        let p_in = 2.0e6;
        // the true plant: duct L/A dm/dt = Ψ p_in − p (seed 000 eq. 1b), the outlet volume's
        // pressure ramping at 160 kPa/s for 0.6 s (eq. 1a: the outflow is m − (V/a²) dp/dt),
        // from 13 kg/s on the steep side towards the peak (96 kPa more needs Ψ = 2.198: 11.6
        // kg/s; the peak's 2.25 is never reached, so the true flow stays on the stable branch)
        let ramp_pa_s = 1.6e5;
        let ramp_s = 0.6;
        let mut m = 13.0;
        let mut p = psi(m) * p_in; // start in equilibrium
        o.reset(m, p, p_in);
        let dt = 1e-3;
        let mut worst: f64 = 0.0;
        for k in 0..2000 {
            let rate = if (k as f64) * dt < ramp_s {
                ramp_pa_s
            } else {
                0.0
            };
            for _ in 0..100 {
                let h = dt / 100.0;
                m += h * plant.area_over_length_m * (psi(m) * p_in - p);
                p += h * rate;
            }
            let m_out = m - plant.volume_over_sonic2 * rate;
            let est = o.update(p_in, p, m_out, dt, psi);
            if k > 50 {
                worst = worst.max((est - m).abs());
            }
        }
        assert!(m < 12.0 && m > 11.0, "the ramp must move the flow: {m}");
        assert!(worst < 0.05, "estimate off by {worst} kg/s");
    }

    #[test]
    fn retuning_keeps_the_estimate() {
        let mut o = obs();
        o.reset(7.5, 2.2e5, 1.0e5);
        for _ in 0..50 {
            o.update(1.0e5, 2.2e5, 7.0, 1e-3, |_| 2.2);
        }
        let before = o.estimate(2.2e5);
        let cfg = ObserverConfig {
            c2_pa_s_kg: 3.0 * ObserverConfig::default().c2_pa_s_kg,
            ..ObserverConfig::default()
        };
        let r = o.retuned(
            &cfg,
            ObserverPlant {
                area_over_length_m: o.area_over_length(),
                volume_over_sonic2: 1.5 / (340.0 * 340.0),
            },
        );
        assert!(r.started());
        assert!((r.k_z() - 3.0 * o.k_z()).abs() < 1e-12 * r.k_z());
        assert!(
            (r.estimate(2.2e5) - before).abs() < 1e-9,
            "{} vs {before}",
            r.estimate(2.2e5)
        );
        // a cold observer stays cold
        assert!(!obs()
            .retuned(
                &cfg,
                ObserverPlant {
                    area_over_length_m: 0.015,
                    volume_over_sonic2: 1e-5
                }
            )
            .started());
    }

    #[test]
    fn low_pass_converges_and_bypasses() {
        let mut f = LowPass::new(10.0);
        f.reset(0.0);
        let mut y = 0.0;
        for _ in 0..1000 {
            y = f.update(1.0, 1e-3);
        }
        assert!((y - 1.0).abs() < 1e-6);
        let mut b = LowPass::new(0.0);
        assert_eq!(b.update(3.0, 1e-3), 3.0);
        assert_eq!(b.update(5.0, 1e-3), 5.0);
    }
}
