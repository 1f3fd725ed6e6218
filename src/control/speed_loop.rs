//! The drive's speed loop: PI on the speed error with feed-forward, torque limits and
//! anti-windup (seed 002 eq. 3.7; seed 001 §4.3.1: Kp = 2, Ki = 10). Every law runs on top of it;
//! in fail-safe the active laws hand control back to it.

/// Speed PI state and gains.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpeedLoop {
    /// Proportional gain, N·m per rad/s.
    pub kp_nm_s_rad: f64,
    /// Integral gain, N·m per rad.
    pub ki_nm_rad: f64,
    /// Torque limits (min, max), N·m.
    pub limits_nm: (f64, f64),
    /// Integral part (includes the feed-forward it converged to), N·m.
    pub integral_nm: f64,
}

impl SpeedLoop {
    /// New loop with the integral preset to `initial_torque_nm` (bumpless start).
    pub fn new(kp: f64, ki: f64, limits_nm: (f64, f64), initial_torque_nm: f64) -> Self {
        SpeedLoop {
            kp_nm_s_rad: kp,
            ki_nm_rad: ki,
            limits_nm,
            integral_nm: initial_torque_nm,
        }
    }

    /// Re-initialise the integral so that the output equals `torque_nm` now (bumpless transfer).
    pub fn track(&mut self, torque_nm: f64, setpoint_rad_s: f64, omega_rad_s: f64) {
        let e = setpoint_rad_s - omega_rad_s;
        self.integral_nm = torque_nm - self.kp_nm_s_rad * e;
    }

    /// Torque command for the speed error plus an additional torque `extra_nm` from a surge law,
    /// clamped to the limits. The integral stops when the total output saturates (anti-windup
    /// by conditional integration).
    pub fn update(
        &mut self,
        setpoint_rad_s: f64,
        omega_rad_s: f64,
        extra_nm: f64,
        dt_s: f64,
    ) -> f64 {
        let e = setpoint_rad_s - omega_rad_s;
        let (lo, hi) = self.limits_nm;
        let unclamped = self.integral_nm + self.kp_nm_s_rad * e + extra_nm;
        let out = unclamped.clamp(lo, hi);
        let pushing_out = (unclamped > hi && e > 0.0) || (unclamped < lo && e < 0.0);
        if !pushing_out {
            self.integral_nm += self.ki_nm_rad * e * dt_s;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integrates_error_and_stops_at_limit() {
        let mut s = SpeedLoop::new(2.0, 10.0, (0.0, 50.0), 20.0);
        let t = s.update(100.0, 99.0, 0.0, 0.1);
        assert!((t - 22.0).abs() < 1e-12);
        assert!((s.integral_nm - 21.0).abs() < 1e-12);
        // saturated: integral frozen
        let before = s.integral_nm;
        let t = s.update(200.0, 100.0, 0.0, 0.1);
        assert_eq!(t, 50.0);
        assert_eq!(s.integral_nm, before);
    }

    #[test]
    fn track_is_bumpless() {
        let mut s = SpeedLoop::new(2.0, 10.0, (0.0, 50.0), 0.0);
        s.track(33.0, 100.0, 98.0);
        let t = s.update(100.0, 98.0, 0.0, 0.0);
        assert!((t - 33.0).abs() < 1e-12);
    }
}
