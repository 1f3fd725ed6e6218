//! The Moore–Greitzer cubic compressor characteristic with speed scaling.
//!
//! Seed 001 eq. 2.10: ψc(Φ) = ψc0 + H [1 + 3/2 (Φ/W − 1) − 1/2 (Φ/W − 1)³].
//! Speed scaling by the fan laws (flow ∝ N, pressure rise ∝ N²): with s = ω/ω_ref,
//! Ψc(m, ω) = b + s² (ψc0 − b + H·g(m/(W s) − 1)), g(x) = 1 + 3/2 x − 1/2 x³, where b is the
//! baseline (1 for a pressure ratio, 0 for a pressure-rise coefficient). The peak of each speed
//! line (the surge point) is at m = 2 W s.
//!
//! Outside x ∈ [−3, 3] the cubic is continued linearly (C¹). Deep surge and shut-down
//! transients visit large |m|/(W s); the linear continuation keeps the pressure rise bounded
//! (it tends to the baseline as s → 0) instead of growing as m³/s.

use serde::{Deserialize, Serialize};

const X_LO: f64 = -3.0;
const X_HI: f64 = 3.0;

/// g(x) = 1 + 3/2 x − 1/2 x³ and g'(x), linearly continued outside [X_LO, X_HI].
#[inline]
pub fn cubic_shape(x: f64) -> (f64, f64) {
    let inner = |x: f64| (1.0 + 1.5 * x - 0.5 * x * x * x, 1.5 - 1.5 * x * x);
    if x < X_LO {
        let (g, dg) = inner(X_LO);
        (g + dg * (x - X_LO), dg)
    } else if x > X_HI {
        let (g, dg) = inner(X_HI);
        (g + dg * (x - X_HI), dg)
    } else {
        inner(x)
    }
}

/// Value and partial derivatives of a characteristic at one point.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MapPoint {
    /// Pressure ratio (or pressure-rise coefficient for nondimensional plants).
    pub value: f64,
    /// ∂/∂flow, per unit of the map's flow coordinate.
    pub d_dflow: f64,
    /// ∂/∂ω, per rad/s (per unit of nondimensional speed for the spool model).
    pub d_domega: f64,
}

/// Moore–Greitzer cubic with fan-law speed scaling.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MooreGreitzerCubic {
    /// ψc0: shut-off value (zero flow) at the reference speed.
    pub psi_c0: f64,
    /// H: semi-height of the cubic (peak = ψc0 + 2H).
    pub semi_height: f64,
    /// W: semi-width of the cubic in flow units (peak at 2W), at the reference speed.
    pub semi_width: f64,
    /// Reference speed at which ψc0, H, W hold, rad/s (or 1 for nondimensional speed).
    pub omega_ref: f64,
}

impl MooreGreitzerCubic {
    /// Evaluate with baseline `b` (1.0: pressure ratio; 0.0: pressure-rise coefficient).
    #[inline]
    pub fn eval(&self, flow: f64, omega: f64, baseline: f64) -> MapPoint {
        let s = omega.max(0.0) / self.omega_ref;
        if s < 1e-9 {
            return MapPoint {
                value: baseline,
                d_dflow: 0.0,
                d_domega: 0.0,
            };
        }
        let w = self.semi_width;
        let h = self.semi_height;
        let x = flow / (w * s) - 1.0;
        let (g, dg) = cubic_shape(x);
        let inner = self.psi_c0 - baseline + h * g;
        let value = baseline + s * s * inner;
        let d_dflow = s * h * dg / w;
        // d/ds [s² inner(x(s))] with dx/ds = −(x+1)/s
        let d_ds = 2.0 * s * inner - s * (x + 1.0) * h * dg;
        MapPoint {
            value,
            d_dflow,
            d_domega: d_ds / self.omega_ref,
        }
    }

    /// Surge point (peak of the speed line) at speed ω: (flow, value).
    #[inline]
    pub fn peak(&self, omega: f64, baseline: f64) -> (f64, f64) {
        let s = omega.max(0.0) / self.omega_ref;
        (
            2.0 * self.semi_width * s,
            baseline + s * s * (self.psi_c0 - baseline + 2.0 * self.semi_height),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cubic() -> MooreGreitzerCubic {
        MooreGreitzerCubic {
            psi_c0: 1.5,
            semi_height: 0.4,
            semi_width: 5.0,
            omega_ref: 2000.0,
        }
    }

    #[test]
    fn shape_matches_seed_001_eq_2_10() {
        let c = cubic();
        // Φ = 0 → ψc0; Φ = 2W → ψc0 + 2H; Φ = W → ψc0 + H.
        assert!((c.eval(0.0, 2000.0, 1.0).value - 1.5).abs() < 1e-12);
        assert!((c.eval(10.0, 2000.0, 1.0).value - 2.3).abs() < 1e-12);
        assert!((c.eval(5.0, 2000.0, 1.0).value - 1.9).abs() < 1e-12);
        let (m, v) = c.peak(2000.0, 1.0);
        assert_eq!((m, v), (10.0, 2.3));
    }

    #[test]
    fn derivatives_match_finite_differences() {
        let c = cubic();
        for &(m, w) in &[(3.0, 1800.0), (9.0, 2100.0), (-4.0, 1500.0), (40.0, 900.0)] {
            let p = c.eval(m, w, 1.0);
            let dm = (c.eval(m + 1e-6, w, 1.0).value - c.eval(m - 1e-6, w, 1.0).value) / 2e-6;
            let dw = (c.eval(m, w + 1e-3, 1.0).value - c.eval(m, w - 1e-3, 1.0).value) / 2e-3;
            assert!(
                (p.d_dflow - dm).abs() < 1e-6 * (1.0 + dm.abs()),
                "m {m} w {w}"
            );
            assert!(
                (p.d_domega - dw).abs() < 1e-6 * (1.0 + dw.abs()),
                "m {m} w {w}"
            );
        }
    }

    #[test]
    fn fan_law_scaling_of_peak() {
        let c = cubic();
        let (m1, v1) = c.peak(1000.0, 1.0);
        let (m2, v2) = c.peak(2000.0, 1.0);
        assert!((m2 / m1 - 2.0).abs() < 1e-12);
        assert!(((v2 - 1.0) / (v1 - 1.0) - 4.0).abs() < 1e-12);
    }

    #[test]
    fn bounded_at_zero_speed() {
        let c = cubic();
        let p = c.eval(20.0, 1e-3, 1.0);
        assert!((p.value - 1.0).abs() < 1e-3, "{p:?}");
        assert_eq!(c.eval(5.0, 0.0, 1.0).value, 1.0);
    }
}
