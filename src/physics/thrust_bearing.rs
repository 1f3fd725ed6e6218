//! Magnetic thrust-bearing servo: the axial rotor position (tip-clearance change) follows its
//! setpoint through a 3rd-order Butterworth low-pass, 70 Hz bandwidth by default (seed 004).

use serde::{Deserialize, Serialize};

/// Servo and rotor data.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThrustBearingServo {
    /// −3 dB bandwidth, Hz (seed 004: 70 Hz).
    #[serde(default = "default_bandwidth")]
    pub bandwidth_hz: f64,
    /// Axially moving mass (rotor), kg: converts acceleration into servo force.
    pub rotor_mass_kg: f64,
}

fn default_bandwidth() -> f64 {
    70.0
}

impl ThrustBearingServo {
    /// Cut-off angular frequency ω_c = 2π f, rad/s.
    #[inline]
    pub fn omega_c(&self) -> f64 {
        2.0 * std::f64::consts::PI * self.bandwidth_hz
    }

    /// State derivative of the Butterworth filter H(s) = ω_c³ /(s³ + 2ω_c s² + 2ω_c² s + ω_c³)
    /// in controllable canonical form: x = (position m, velocity m/s, acceleration m/s²).
    #[inline]
    pub fn rhs(&self, x: [f64; 3], setpoint_m: f64) -> [f64; 3] {
        let w = self.omega_c();
        [
            x[1],
            x[2],
            w * w * w * (setpoint_m - x[0]) - 2.0 * w * w * x[1] - 2.0 * w * x[2],
        ]
    }

    /// Servo force needed for the commanded motion, N (inertial part m·ẍ).
    #[inline]
    pub fn force_n(&self, x: [f64; 3]) -> f64 {
        self.rotor_mass_kg * x[2]
    }

    /// Force slew rate m·d³x/dt³, N/s.
    #[inline]
    pub fn force_slew_n_s(&self, x: [f64; 3], setpoint_m: f64) -> f64 {
        self.rotor_mass_kg * self.rhs(x, setpoint_m)[2]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn simulate(servo: &ThrustBearingServo, f_hz: f64, t_end: f64) -> (f64, f64) {
        // returns (final position, peak |position| in last period) for a sine setpoint
        let dt = 1e-5;
        let mut x = [0.0; 3];
        let mut peak: f64 = 0.0;
        let n = (t_end / dt) as usize;
        for k in 0..n {
            let t = k as f64 * dt;
            let u = (2.0 * std::f64::consts::PI * f_hz * t).sin();
            let d = servo.rhs(x, u);
            for i in 0..3 {
                x[i] += dt * d[i];
            }
            if t > t_end - 1.0 / f_hz {
                peak = peak.max(x[0].abs());
            }
        }
        (x[0], peak)
    }

    #[test]
    fn unity_dc_gain_and_minus_3db_at_bandwidth() {
        let servo = ThrustBearingServo {
            bandwidth_hz: 70.0,
            rotor_mass_kg: 30.0,
        };
        // step response settles at the setpoint
        let mut x = [0.0; 3];
        for _ in 0..100_000 {
            let d = servo.rhs(x, 1e-4);
            for i in 0..3 {
                x[i] += 1e-6 * d[i];
            }
        }
        assert!((x[0] - 1e-4).abs() < 1e-8);
        // amplitude at the bandwidth is 1/√2
        let (_, peak) = simulate(&servo, 70.0, 0.3);
        assert!(
            (peak - std::f64::consts::FRAC_1_SQRT_2).abs() < 0.01,
            "{peak}"
        );
        // 3rd order roll-off: at 2×bandwidth, |H| = 1/√(1+2⁶) ≈ 0.124
        let (_, peak2) = simulate(&servo, 140.0, 0.2);
        assert!((peak2 - 1.0 / 65f64.sqrt()).abs() < 0.01, "{peak2}");
    }
}
