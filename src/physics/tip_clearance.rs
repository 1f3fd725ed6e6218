//! Tip-clearance modified characteristic (seed 004 eq. 2–3, sign corrected).
//!
//! Senoo's relation (eq. 2) says the efficiency *drops* by Δη/η = Δl/(4 b₂) when the tip
//! clearance grows by Δl. With the isentropic relation ψ^k − 1 ∝ η (k = (γ−1)/γ) the physical
//! form is
//!
//! ```text
//! ψ^k − 1 = (ψ_ss^k − 1) (1 − u/(4 b₂)),   u = Δl
//! ```
//!
//! Correction: seed 004 eq. 3 prints the factor in the denominator, (ψ_ss^k−1)/(1 − 0.25u/b₂),
//! which makes a larger clearance *raise* the pressure ratio, contradicting eq. 2 (ERRATA.md).
//! We use the multiplicative form above; the control law is derived with the same convention.

use serde::{Deserialize, Serialize};

/// Impeller data for the clearance effect.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TipClearanceEffect {
    /// Blade height at impeller exit b₂, m.
    pub blade_height_m: f64,
    /// Ratio of specific heats γ.
    pub heat_capacity_ratio: f64,
}

impl TipClearanceEffect {
    #[inline]
    fn k(&self) -> f64 {
        (self.heat_capacity_ratio - 1.0) / self.heat_capacity_ratio
    }

    /// Pressure ratio with clearance change `u_m` (positive = larger clearance = lower ratio).
    #[inline]
    pub fn pressure_ratio(&self, psi_ss: f64, u_m: f64) -> f64 {
        let k = self.k();
        let factor = 1.0 - u_m / (4.0 * self.blade_height_m);
        let base = 1.0 + (psi_ss.max(1e-9).powf(k) - 1.0) * factor;
        base.max(1e-9).powf(1.0 / k)
    }

    /// ∂ψ/∂u, per m.
    #[inline]
    pub fn d_ratio_du(&self, psi_ss: f64, u_m: f64) -> f64 {
        let k = self.k();
        let factor = 1.0 - u_m / (4.0 * self.blade_height_m);
        let a = psi_ss.max(1e-9).powf(k) - 1.0;
        let base = (1.0 + a * factor).max(1e-9);
        (1.0 / k) * base.powf(1.0 / k - 1.0) * a * (-1.0 / (4.0 * self.blade_height_m))
    }

    /// The clearance change that turns ψ_ss into ψ (inverse of [`Self::pressure_ratio`]),
    /// u = 4 b₂ (1 − (ψ^k − 1)/(ψ_ss^k − 1)). `None` where ψ_ss^k − 1 ≈ 0 (ψ_ss ≈ 1: clearance
    /// has no authority there).
    #[inline]
    pub fn clearance_for_ratio(&self, psi_ss: f64, psi: f64) -> Option<f64> {
        let k = self.k();
        let a = psi_ss.max(1e-9).powf(k) - 1.0;
        if a.abs() < 1e-9 {
            return None;
        }
        Some(4.0 * self.blade_height_m * (1.0 - (psi.max(1e-9).powf(k) - 1.0) / a))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EFFECT: TipClearanceEffect = TipClearanceEffect {
        blade_height_m: 4e-3,
        heat_capacity_ratio: 1.4,
    };

    #[test]
    fn larger_clearance_lowers_pressure_ratio() {
        let psi_ss = 1.7;
        assert!((EFFECT.pressure_ratio(psi_ss, 0.0) - psi_ss).abs() < 1e-12);
        assert!(EFFECT.pressure_ratio(psi_ss, 2e-4) < psi_ss);
        assert!(EFFECT.pressure_ratio(psi_ss, -2e-4) > psi_ss);
    }

    #[test]
    fn senoo_efficiency_loss_is_linear_in_clearance() {
        // the isentropic "work" ψ^k − 1 drops by exactly u/(4 b₂) (seed 004 eq. 2)
        let k = 0.4 / 1.4;
        let psi_ss: f64 = 1.7;
        let u = 3e-4;
        let psi = EFFECT.pressure_ratio(psi_ss, u);
        let rel = (psi.powf(k) - 1.0) / (psi_ss.powf(k) - 1.0);
        assert!((rel - (1.0 - u / (4.0 * 4e-3))).abs() < 1e-12);
    }

    #[test]
    fn inverse_and_derivative() {
        let psi_ss = 1.65;
        for u in [-4e-4, -1e-4, 0.0, 2.5e-4] {
            let psi = EFFECT.pressure_ratio(psi_ss, u);
            let back = EFFECT.clearance_for_ratio(psi_ss, psi).expect("authority");
            assert!((back - u).abs() < 1e-12, "{u} {back}");
            let d = EFFECT.d_ratio_du(psi_ss, u);
            let fd = (EFFECT.pressure_ratio(psi_ss, u + 1e-8)
                - EFFECT.pressure_ratio(psi_ss, u - 1e-8))
                / 2e-8;
            assert!((d - fd).abs() < 1e-5 * fd.abs(), "{d} {fd}");
        }
        assert!(EFFECT.clearance_for_ratio(1.0, 1.0).is_none());
    }
}
