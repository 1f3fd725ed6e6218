//! Valves: inherent characteristics, flow through a valve, valve lines with duct dynamics,
//! check valves and the positioner (stroke-rate limit and lag).

use super::smooth_signed_sqrt;
use serde::{Deserialize, Serialize};

/// Inherent valve characteristic: C_v*(l)/C_v,max* as a function of opening l ∈ [0, 1]
/// (seed 002 §2.3.5).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Characteristic {
    /// C* = C*max · l.
    Linear,
    /// C* = C*max · l^(1/μ), μ > 1.
    QuickOpening {
        /// μ > 1.
        mu: f64,
    },
    /// C* = C*max · φ^(l−1), φ ≈ 50 (the rangeability).
    EqualPercentage {
        /// φ > 1.
        rangeability: f64,
    },
}

impl Characteristic {
    /// Fraction of the full capacity at opening `l` (clamped to [0, 1]).
    #[inline]
    pub fn fraction(&self, l: f64) -> f64 {
        let l = l.clamp(0.0, 1.0);
        match *self {
            Characteristic::Linear => l,
            Characteristic::QuickOpening { mu } => l.powf(1.0 / mu),
            Characteristic::EqualPercentage { rangeability } => rangeability.powf(l - 1.0),
        }
    }

    /// Opening that gives a capacity fraction (inverse of [`Self::fraction`]), clamped to [0,1].
    pub fn opening_for_fraction(&self, f: f64) -> f64 {
        let f = f.clamp(0.0, 1.0);
        match *self {
            Characteristic::Linear => f,
            Characteristic::QuickOpening { mu } => f.powf(mu),
            Characteristic::EqualPercentage { rangeability } => {
                if f <= 0.0 {
                    0.0
                } else {
                    (1.0 + f.ln() / rangeability.ln()).clamp(0.0, 1.0)
                }
            }
        }
    }
}

/// A control valve with its positioner.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValveSpec {
    /// Full-open flow coefficient C_v,max* as an effective area, m²: w = C_v*(l)·√(2ρΔp)
    /// (seed 002 eq. 2.15).
    pub cv_max_m2: f64,
    /// Inherent characteristic.
    pub characteristic: Characteristic,
    /// Smallest effective opening ε_l > 0: leakage of a closed valve (seed 002 §3.5 keeps
    /// l ∈ [ε_l, 1] to avoid division by zero in the line equation).
    #[serde(default = "default_min_opening")]
    pub min_opening: f64,
    /// Full-stroke time of the actuator, s: the positioner moves at most 1/stroke_time_s per s.
    pub stroke_time_s: f64,
    /// First-order positioner lag, s.
    #[serde(default = "default_positioner_lag")]
    pub positioner_lag_s: f64,
}

fn default_min_opening() -> f64 {
    1e-3
}
fn default_positioner_lag() -> f64 {
    0.05
}

impl ValveSpec {
    /// Effective flow coefficient C_v*(l), m², never below the leakage value.
    #[inline]
    pub fn cv_m2(&self, opening: f64) -> f64 {
        let l = opening.clamp(self.min_opening, 1.0);
        self.cv_max_m2 * self.characteristic.fraction(l)
    }

    /// Positioner: rate of change of the stem position toward the command, 1/s.
    /// First-order lag limited to the stroke rate.
    #[inline]
    pub fn positioner_rate(&self, command: f64, position: f64) -> f64 {
        let target = command.clamp(0.0, 1.0);
        let max_rate = 1.0 / self.stroke_time_s.max(1e-6);
        ((target - position) / self.positioner_lag_s.max(1e-6)).clamp(-max_rate, max_rate)
    }
}

/// Quasi-steady mass flow through a valve, kg/s, from upstream to downstream:
/// w = C_v*·√(2ρ_up·Δp) (seed 002 eq. 2.15) with the smooth sign handling of seed 001 eq. 2.9,
/// so that it passes through zero differentiably when the pressure difference reverses.
/// `rho_up_kg_m3` is the density on the high-pressure side; `smoothing_pa` the width of the
/// transition region (1/ξ of seed 001 eq. 2.9).
#[inline]
pub fn flow_kg_s(cv_m2: f64, rho_up_kg_m3: f64, dp_pa: f64, smoothing_pa: f64) -> f64 {
    cv_m2 * (2.0 * rho_up_kg_m3).sqrt() * smooth_signed_sqrt(dp_pa, 1.0 / smoothing_pa)
}

/// Pressure loss over a valve carrying `w_kg_s`: Δp = |w| w /(2 ρ C_v*²), Pa. This is the
/// steady relation w = C_v*√(2ρΔp) solved for Δp; it is the friction term F of the valve-line
/// momentum equation (seed 002 eq. 3.15–3.16).
#[inline]
pub fn line_loss_pa(w_kg_s: f64, cv_m2: f64, rho_up_kg_m3: f64) -> f64 {
    w_kg_s.abs() * w_kg_s / (2.0 * rho_up_kg_m3 * cv_m2 * cv_m2)
}

/// Valve line with duct dynamics (seed 002 eq. 3.16):
/// ẇ = A/L (p_in − p_out − |w| w /(2 ρ_up C_v*²)), kg/s². Flow is positive from `p_in` to
/// `p_out`. ρ_up is the density on the side the flow comes from.
#[inline]
pub fn line_flow_rate(
    area_over_length_m: f64,
    p_in_pa: f64,
    p_out_pa: f64,
    w_kg_s: f64,
    cv_m2: f64,
    rho_up_kg_m3: f64,
) -> f64 {
    area_over_length_m * (p_in_pa - p_out_pa - line_loss_pa(w_kg_s, cv_m2, rho_up_kg_m3))
}

/// Check valve in a line (seed 002 eq. 3.17: ẇ = A/L (p₁ − p₂), w > 0): the derivative of
/// a line flow that may not go negative. At w ≤ 0 with a closing pressure difference the valve
/// is shut and the flow stays at zero.
#[inline]
pub fn check_valve_rate(w_kg_s: f64, unconstrained_rate: f64) -> f64 {
    if w_kg_s <= 0.0 && unconstrained_rate < 0.0 {
        0.0
    } else {
        unconstrained_rate
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn characteristics_at_ends_and_middle() {
        assert_eq!(Characteristic::Linear.fraction(0.5), 0.5);
        let q = Characteristic::QuickOpening { mu: 2.0 };
        assert!((q.fraction(0.25) - 0.5).abs() < 1e-12);
        let e = Characteristic::EqualPercentage { rangeability: 50.0 };
        assert!((e.fraction(1.0) - 1.0).abs() < 1e-12);
        assert!((e.fraction(0.0) - 0.02).abs() < 1e-12);
        // equal percentage: equal steps in l give equal ratios in capacity
        let r1 = e.fraction(0.6) / e.fraction(0.5);
        let r2 = e.fraction(0.3) / e.fraction(0.2);
        assert!((r1 - r2).abs() < 1e-12);
        for c in [Characteristic::Linear, q, e] {
            for l in [0.1, 0.37, 0.9] {
                assert!((c.opening_for_fraction(c.fraction(l)) - l).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn flow_is_smooth_and_antisymmetric() {
        let w1 = flow_kg_s(1e-3, 10.0, 1e5, 10.0);
        assert!((w1 - 1e-3 * (2.0 * 10.0 * 1e5f64).sqrt()).abs() < 1e-9);
        assert_eq!(flow_kg_s(1e-3, 10.0, -1e5, 10.0), -w1);
        assert_eq!(flow_kg_s(1e-3, 10.0, 0.0, 10.0), 0.0);
        // differentiable through zero: tiny slope near 0 instead of the √ singularity
        let d = (flow_kg_s(1e-3, 10.0, 1e-3, 10.0) - flow_kg_s(1e-3, 10.0, -1e-3, 10.0)) / 2e-3;
        assert!(d.abs() < 1e-3, "{d}");
    }

    #[test]
    fn line_steady_state_equals_valve_equation() {
        let (cv, rho, dp) = (2e-3, 30.0, 5e5);
        let w = flow_kg_s(cv, rho, dp, 1.0);
        let rate = line_flow_rate(0.01, 1e6 + dp, 1e6, w, cv, rho);
        assert!(rate.abs() < 1e-6 * dp * 0.01, "{rate}");
    }

    #[test]
    fn positioner_is_rate_limited() {
        let v = ValveSpec {
            cv_max_m2: 1e-3,
            characteristic: Characteristic::Linear,
            min_opening: 1e-3,
            stroke_time_s: 2.0,
            positioner_lag_s: 0.01,
        };
        assert_eq!(v.positioner_rate(1.0, 0.0), 0.5);
        assert_eq!(v.positioner_rate(0.0, 1.0), -0.5);
        assert!((v.positioner_rate(0.501, 0.5) - 0.1).abs() < 1e-9);
        assert_eq!(v.cv_m2(0.0), 1e-6);
    }

    #[test]
    fn check_valve_blocks_reverse_flow() {
        assert_eq!(check_valve_rate(0.0, -5.0), 0.0);
        assert_eq!(check_valve_rate(0.0, 5.0), 5.0);
        assert_eq!(check_valve_rate(1.0, -5.0), -5.0);
    }
}
