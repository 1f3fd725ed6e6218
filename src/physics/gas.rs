//! Ideal-gas relations used throughout (seed 002 eq. 2.12, 2.1–2.3).

use serde::{Deserialize, Serialize};

/// Universal gas constant, J/(mol·K) (value of seed 002 Table A.1).
pub const R_UNIVERSAL_J_MOL_K: f64 = 8.314472;

/// Properties of the compressed gas.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Gas {
    /// Molar mass, kg/mol (air 0.02897; natural gas ≈ 0.022 in seed 002).
    pub molar_mass_kg_mol: f64,
    /// Ratio of specific heats cp/cv (air 1.4).
    pub heat_capacity_ratio: f64,
    /// Compressibility factor Z (1 = ideal gas).
    #[serde(default = "one")]
    pub compressibility: f64,
    /// Polytropic exponent σ = (n−1)/n of seed 002 eq. 2.2, used for the polytropic head.
    pub polytropic_exponent: f64,
}

fn one() -> f64 {
    1.0
}

impl Gas {
    /// Air at ordinary conditions.
    pub const AIR: Gas = Gas {
        molar_mass_kg_mol: 0.028_97,
        heat_capacity_ratio: 1.4,
        compressibility: 1.0,
        polytropic_exponent: 0.3,
    };

    /// Specific gas constant Z·R/M, J/(kg·K).
    #[inline]
    pub fn specific_constant_j_kg_k(&self) -> f64 {
        self.compressibility * R_UNIVERSAL_J_MOL_K / self.molar_mass_kg_mol
    }

    /// Density ρ = p M /(Z R T), kg/m³ (seed 002 eq. 2.12).
    #[inline]
    pub fn density_kg_m3(&self, p_pa: f64, t_k: f64) -> f64 {
        p_pa / (self.specific_constant_j_kg_k() * t_k)
    }

    /// Speed of sound √(γ Z R T / M), m/s.
    #[inline]
    pub fn sonic_velocity_m_s(&self, t_k: f64) -> f64 {
        (self.heat_capacity_ratio * self.specific_constant_j_kg_k() * t_k).sqrt()
    }

    /// Polytropic head h = (Z R T_s / M) (R_p^σ − 1)/σ, J/kg: seed 002 eq. 2.2 (reduced head
    /// h_r = (R_p^σ−1)/σ) times the inlet's Z R T/M. Used for the recycle energy figure.
    #[inline]
    pub fn polytropic_head_j_kg(&self, t_suction_k: f64, pressure_ratio: f64) -> f64 {
        let s = self.polytropic_exponent;
        let rp = pressure_ratio.max(1e-9);
        self.specific_constant_j_kg_k() * t_suction_k * (rp.powf(s) - 1.0) / s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn air_density_and_sound_speed() {
        let rho = Gas::AIR.density_kg_m3(101_325.0, 288.15);
        assert!((rho - 1.225).abs() < 0.002, "{rho}");
        let a = Gas::AIR.sonic_velocity_m_s(288.15);
        assert!((a - 340.3).abs() < 0.5, "{a}");
    }

    #[test]
    fn polytropic_head_is_zero_at_unity_ratio_and_grows() {
        let g = Gas::AIR;
        assert!(g.polytropic_head_j_kg(300.0, 1.0).abs() < 1e-9);
        let h = g.polytropic_head_j_kg(300.0, 2.0);
        // (2^0.3 - 1)/0.3 = 0.7707; R_air*300 = 86 097 J/kg
        assert!((h - 86_097.0 * 0.7707).abs() < 200.0, "{h}");
    }
}
