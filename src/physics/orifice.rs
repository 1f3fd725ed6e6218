//! Orifice flow element: differential pressure ↔ mass and volume flow with density correction
//! (seed 002 eq. 2.10, 2.13, 2.14, 3.19).

use super::gas::Gas;
use serde::{Deserialize, Serialize};

/// An orifice (or other Bernoulli flow element) at the compressor suction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Orifice {
    /// Flow coefficient c_f including the discharge coefficient and 1/√(1−β⁴) (seed 002 eq. 2.10).
    pub flow_coefficient: f64,
    /// Bore diameter d₂, m.
    pub bore_diameter_m: f64,
}

impl Orifice {
    /// Bore area A₂, m².
    #[inline]
    pub fn bore_area_m2(&self) -> f64 {
        std::f64::consts::PI * 0.25 * self.bore_diameter_m * self.bore_diameter_m
    }

    /// c_w = c_f A₂ √(2M/(ZRT)) of seed 002 eq. 2.13 at suction temperature `t_k`.
    #[inline]
    pub fn c_w(&self, gas: &Gas, t_k: f64) -> f64 {
        self.flow_coefficient
            * self.bore_area_m2()
            * (2.0 / (gas.specific_constant_j_kg_k() * t_k)).sqrt()
    }

    /// Mass flow from Δp with density correction: w = c_w √(p₁ Δp) (seed 002 eq. 2.13), kg/s.
    /// A negative Δp (reverse flow through a symmetric element) gives a negative flow.
    #[inline]
    pub fn mass_flow_kg_s(&self, gas: &Gas, dp_pa: f64, p1_pa: f64, t_k: f64) -> f64 {
        self.c_w(gas, t_k) * (p1_pa.max(0.0) * dp_pa.abs()).sqrt() * dp_pa.signum()
    }

    /// Volume flow at suction conditions: q = c_q √(Δp / p₁), c_q = c_f A₂ √(2RT/M)
    /// (seed 002 eq. 2.14), m³/s.
    #[inline]
    pub fn volume_flow_m3_s(&self, gas: &Gas, dp_pa: f64, p1_pa: f64, t_k: f64) -> f64 {
        let c_q = self.flow_coefficient
            * self.bore_area_m2()
            * (2.0 * gas.specific_constant_j_kg_k() * t_k).sqrt();
        c_q * (dp_pa.abs() / p1_pa.max(1.0)).sqrt() * dp_pa.signum()
    }

    /// Differential pressure produced by a mass flow: Δp = w|w| /(c_w² p₁) (seed 002 eq. 3.19), Pa.
    #[inline]
    pub fn dp_pa(&self, gas: &Gas, w_kg_s: f64, p1_pa: f64, t_k: f64) -> f64 {
        let cw = self.c_w(gas, t_k);
        w_kg_s * w_kg_s.abs() / (cw * cw * p1_pa.max(1.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ORIFICE: Orifice = Orifice {
        flow_coefficient: 0.62,
        bore_diameter_m: 0.2,
    };

    #[test]
    fn round_trip_mass_and_volume() {
        let gas = Gas::AIR;
        for &(w, p1, t) in &[
            (3.2, 1.0e5, 293.0),
            (-0.4, 2.0e6, 310.0),
            (11.0, 4.0e6, 295.0),
        ] {
            let dp = ORIFICE.dp_pa(&gas, w, p1, t);
            let back = ORIFICE.mass_flow_kg_s(&gas, dp, p1, t);
            assert!(
                (back - w).abs() < 1e-12 * w.abs().max(1.0),
                "{w} -> {dp} -> {back}"
            );
            let q = ORIFICE.volume_flow_m3_s(&gas, dp, p1, t);
            let rho = gas.density_kg_m3(p1, t);
            assert!((q - w / rho).abs() < 1e-9 * (w / rho).abs().max(1.0));
        }
    }

    #[test]
    fn density_correction_matters() {
        // same Δp at twice the suction pressure: mass flow × √2, volume flow ÷ √2
        let g = Gas::AIR;
        let w1 = ORIFICE.mass_flow_kg_s(&g, 1000.0, 1e5, 300.0);
        let w2 = ORIFICE.mass_flow_kg_s(&g, 1000.0, 2e5, 300.0);
        assert!((w2 / w1 - 2f64.sqrt()).abs() < 1e-12);
        let q1 = ORIFICE.volume_flow_m3_s(&g, 1000.0, 1e5, 300.0);
        let q2 = ORIFICE.volume_flow_m3_s(&g, 1000.0, 2e5, 300.0);
        assert!((q1 / q2 - 2f64.sqrt()).abs() < 1e-12);
    }
}
