//! Emergency-shutdown detection on the shaft speed (seed 002 §2.2.2: ESD events).
//!
//! Purpose: a drive trip runs the machine down the speed lines towards the surge line faster
//! than any flow-based part can follow; a shaft deceleration beyond any speed ramp opens the
//! valve fully at once, held until the speed has risen again for `release_s`.

use serde::{Deserialize, Serialize};

/// Settings of the ESD detection (`[controller.recycle_pi.esd]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EsdConfig {
    /// Deceleration that means a drive trip, percent of nominal speed per second (0
    /// disables). Default 20 %/s: speed ramps of process drives are a few %/s; a tripped
    /// drive loses 20 % of speed within the first second.
    pub decel_pct_per_s: f64,
    /// Cut-off of the speed filter before differentiation, Hz. Default 2 Hz: above the
    /// slowest surge (1 Hz) so a trip is seen within ≈ 0.1 s, below the speed pickup's noise.
    pub filter_hz: f64,
    /// The opening is held until the speed has risen this long, s. Default 1 s: one period
    /// of the slowest surge.
    pub release_s: f64,
}

impl Default for EsdConfig {
    fn default() -> Self {
        EsdConfig {
            decel_pct_per_s: 20.0,
            filter_hz: 2.0,
            release_s: 1.0,
        }
    }
}

/// ESD detection state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EsdDetector {
    cfg_decel: f64,
    filter_hz: f64,
    release_s: f64,
    omega_f: f64,
    active: bool,
    rising_s: f64,
}

impl EsdDetector {
    /// With these settings.
    pub fn new(cfg: &EsdConfig) -> Self {
        EsdDetector {
            cfg_decel: cfg.decel_pct_per_s.max(0.0),
            filter_hz: cfg.filter_hz,
            release_s: cfg.release_s.max(0.0),
            omega_f: f64::NAN,
            active: false,
            rising_s: 0.0,
        }
    }

    /// Forget the filtered speed (after an outage it is old: the difference is no
    /// deceleration).
    pub fn restart(&mut self) {
        self.omega_f = f64::NAN;
        self.active = false;
        self.rising_s = 0.0;
    }

    /// Whether an ESD holds the valve open.
    pub fn active(&self) -> bool {
        self.active
    }

    /// One cycle; returns true when an ESD starts.
    pub fn update(&mut self, omega_rad_s: f64, nominal_rad_s: f64, dt_s: f64) -> bool {
        if self.cfg_decel <= 0.0 || !omega_rad_s.is_finite() || dt_s <= 0.0 {
            return false;
        }
        if !self.omega_f.is_finite() {
            self.omega_f = omega_rad_s;
            return false;
        }
        let a = 1.0 - (-2.0 * std::f64::consts::PI * self.filter_hz * dt_s).exp();
        let last = self.omega_f;
        self.omega_f += a * (omega_rad_s - self.omega_f);
        let rate = (self.omega_f - last) / dt_s;
        let limit = -0.01 * self.cfg_decel * nominal_rad_s.abs();
        if self.active {
            self.rising_s = if rate > 0.0 {
                self.rising_s + dt_s
            } else {
                0.0
            };
            if self.rising_s >= self.release_s {
                self.active = false;
            }
            false
        } else if rate < limit {
            self.active = true;
            self.rising_s = 0.0;
            true
        } else {
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_drive_trip_is_found_and_a_ramp_is_not() {
        let mut d = EsdDetector::new(&EsdConfig::default());
        let dt = 0.01;
        // a 5 %/s ramp down for 3 s: no ESD
        for k in 0..300 {
            assert!(!d.update(1000.0 - 50.0 * k as f64 * dt, 1000.0, dt));
        }
        // then a coast-down at 40 %/s: found within 0.3 s
        let w0 = 850.0;
        let mut found = None;
        for k in 0..100 {
            if d.update(w0 - 400.0 * k as f64 * dt, 1000.0, dt) {
                found = Some(k as f64 * dt);
                break;
            }
        }
        assert!(found.is_some_and(|t| t < 0.3), "{found:?}");
        // released after the speed rose for 1 s
        for k in 0..150 {
            d.update(500.0 + 10.0 * k as f64 * dt, 1000.0, dt);
        }
        assert!(!d.active());
    }
}
