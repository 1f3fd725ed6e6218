//! Shaft dynamics (seed 000 eq. 1c; seed 002 eq. 3.6, 3.9).

use serde::{Deserialize, Serialize};

/// Rotor and impeller data for the torque balance J ω̇ = τ_d − τ_c.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Shaft {
    /// Inertia of all rotating parts, kg·m².
    pub inertia_kg_m2: f64,
    /// Impeller exit radius r₂, m (seed 000 calls it a diameter; it is a radius, ERRATA.md).
    pub impeller_radius_m: f64,
    /// Slip factor σ (1 for radial vanes, seed 002 eq. 3.9).
    pub slip_factor: f64,
}

impl Shaft {
    /// Compressor load torque τ_c = |m| r₂² σ ω, N·m (seed 000 eq. 1c).
    #[inline]
    pub fn load_torque_nm(&self, m_kg_s: f64, omega_rad_s: f64) -> f64 {
        m_kg_s.abs()
            * self.impeller_radius_m
            * self.impeller_radius_m
            * self.slip_factor
            * omega_rad_s
    }

    /// Angular acceleration ω̇ = (τ_d − τ_c)/J, rad/s² (seed 000 eq. 1c).
    #[inline]
    pub fn acceleration_rad_s2(&self, drive_torque_nm: f64, m_kg_s: f64, omega_rad_s: f64) -> f64 {
        (drive_torque_nm - self.load_torque_nm(m_kg_s, omega_rad_s)) / self.inertia_kg_m2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equilibrium_where_drive_equals_load() {
        let s = Shaft {
            inertia_kg_m2: 0.5,
            impeller_radius_m: 0.1,
            slip_factor: 0.9,
        };
        let tau = s.load_torque_nm(8.0, 2500.0);
        assert!((tau - 8.0 * 0.01 * 0.9 * 2500.0).abs() < 1e-9);
        assert_eq!(s.acceleration_rad_s2(tau, 8.0, 2500.0), 0.0);
        // reverse flow also loads the shaft (|m|)
        assert_eq!(s.load_torque_nm(-8.0, 2500.0), tau);
    }
}
