//! The PI on the deviation from the surge control line (seed 001 eq. 3.7 with K_d = 0, seed
//! 002 §2.2.2 and eq. 4.6): u = K_p z + K_i ∫z dt, z > 0 left of the line (opens the valve).
//!
//! Purpose: the valve opening that holds the operating point on the control line in steady
//! operation and against slow disturbances. It is the only part that *closes* the valve.
//!
//! Anti-windup by conditional integration, as in the textbook: the integrator stops while the
//! output is saturated at a limit and the error drives it further into that limit. With every
//! other part of recycle-pi off this *is* a textbook PI (`tests/control/law_recycle_pi.rs` compares it
//! with an independent implementation on seed 002's plant).
//!
//! When another part holds the valve above the PI's demand (a trip, the closing limiter,
//! the ESD opening: the high-select of [`super::RecyclePi`]), the PI follows the selected
//! output the way selector control does (external reset): while it asks for more opening
//! (z ≥ 0) its integrator is re-based so that its demand starts from the valve's opening, and
//! while it asks for less (z < 0) its integrator does not integrate further down. So the PI
//! takes over bumplessly the moment it needs more than the other parts give, and its demand
//! never dives far below the valve while a limiter holds it.

use serde::{Deserialize, Serialize};

/// Which control variable the PI acts on (seed 002 ch. 4, or the normalised deviation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ControlVariable {
    /// Strategy 1: z = c(R)² − q̄ (seed 002 eq. 4.19), in map flow units squared.
    Strategy1,
    /// Strategy 2: z = 1 − q̄/c(R)² (seed 002 eq. 4.38), dimensionless. Its steady-state gain
    /// varies less with speed (seed 002 Fig. 4.11 vs 4.7).
    Strategy2,
    /// The normalised deviation d = (q − c(R))/c(R): distance to the control line as a
    /// fraction of the control-line flow, positive = safe; the PI acts on z = −d. Gains
    /// `kp`, `ki_per_s` are per unit of d, so one set of defaults fits every machine (the
    /// map's flow unit and the machine's size drop out).
    #[default]
    Deviation,
}

impl ControlVariable {
    /// z for a flow `q` (map units, signed) and control-line flow `c` at the measured ratio.
    /// q̄ = q|q| keeps the sign of the orifice Δp. NaN if c ≤ 0 for strategy 2.
    #[inline]
    pub fn z(self, q: f64, c: f64) -> f64 {
        let q_bar = q * q.abs();
        match self {
            // seed 002 eq. 4.19 with eq. 4.15, K_f/c_q² = 1
            ControlVariable::Strategy1 => c * c - q_bar,
            // seed 002 eq. 4.38 with eq. 4.33, p_ref/c_q² = 1
            ControlVariable::Strategy2 => {
                if c > 0.0 {
                    1.0 - q_bar / (c * c)
                } else {
                    f64::NAN
                }
            }
            // z = −d = (c − q)/c (signed q: a reversal reads as far left)
            ControlVariable::Deviation => {
                if c > 0.0 {
                    (c - q) / c
                } else {
                    f64::NAN
                }
            }
        }
    }

    /// ∂z/∂q on the line (q = c): the factor that turns a linear flow error into z.
    #[inline]
    pub fn slope_on_line(self, q_line: f64) -> f64 {
        match self {
            ControlVariable::Strategy1 => 2.0 * q_line,
            ControlVariable::Strategy2 => 2.0 / q_line,
            ControlVariable::Deviation => 1.0 / q_line,
        }
    }
}

/// Settings of the PI (`[controller.recycle_pi.pi]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PiConfig {
    /// Control variable: `deviation` (default), `strategy1` (seed 002 eq. 4.19) or
    /// `strategy2` (eq. 4.38).
    pub control_variable: ControlVariable,
    /// Proportional gain of `deviation`: valve opening (fraction) per unit of normalised
    /// deviation. Default 1.0: 1 % of the line's flow moves the valve 1 %; a valve sized to
    /// pass the surge-line flow (the usual sizing) then returns about the flow it lost.
    pub kp: f64,
    /// Integral gain of `deviation`, per second. Default 2.0/s: integral time 0.5 s, half
    /// the period of the slowest surge (1 Hz), so the integral acts within one surge period
    /// and stays slower than the fastest valve stroke (0.5 s) it drives.
    pub ki_per_s: f64,
    /// Proportional gain of `strategy1`/`strategy2`: valve opening (fraction) per map flow
    /// unit (kg/s or m³/s at suction) of equivalent linear flow error at the design point.
    /// Seed 001 §3.4: 35.5 (per kg/s). Not used by `deviation`.
    pub kp_per_map_flow: f64,
    /// Integral gain of `strategy1`/`strategy2`, per map flow unit and second. Seed 001
    /// §3.4: 85. Not used by `deviation`.
    pub ki_per_map_flow_s: f64,
    /// Cut-off of a first-order low-pass on z before the PI, Hz (0: none). Default 1 Hz:
    /// the usual damping of a flow signal, below the slowest surge frequency (1 Hz) so
    /// that Δp noise is damped, fast events are left to the trip.
    pub z_filter_hz: f64,
}

impl Default for PiConfig {
    fn default() -> Self {
        PiConfig {
            control_variable: ControlVariable::default(),
            kp: 1.0,
            ki_per_s: 2.0,
            kp_per_map_flow: 35.5,
            ki_per_map_flow_s: 85.0,
            z_filter_hz: 1.0,
        }
    }
}

impl PiConfig {
    /// Gains on z (K_p, K_i): the normalised deviation's directly; a seed gain on the linear
    /// flow error divided by ∂z/∂q on the line at the design flow `q_ref`.
    pub fn z_gains(&self, q_ref: f64) -> (f64, f64) {
        match self.control_variable {
            ControlVariable::Deviation => (self.kp, self.ki_per_s),
            cv => {
                let s = cv.slope_on_line(q_ref);
                (self.kp_per_map_flow / s, self.ki_per_map_flow_s / s)
            }
        }
    }
}

/// The PI's state (fixed size).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pi {
    /// Gains on z.
    pub kp: f64,
    /// Integral gain on z, per second.
    pub ki_per_s: f64,
    filter_hz: f64,
    /// z through the low-pass (NaN before the first sample).
    z_f: f64,
    /// Integrator, valve fraction.
    integ: f64,
    /// What the last [`Pi::step`] added to the integrator.
    last_inc: f64,
}

impl Pi {
    /// A PI with gains on z and the z low-pass.
    pub fn new(kp: f64, ki_per_s: f64, filter_hz: f64) -> Self {
        Pi {
            kp,
            ki_per_s,
            filter_hz,
            z_f: f64::NAN,
            integ: 0.0,
            last_inc: 0.0,
        }
    }

    /// Bumpless start: the first demand at `z0` equals the applied opening `u0`.
    pub fn start(&mut self, u0: f64, z0: f64) {
        self.z_f = z0;
        self.integ = if z0.is_finite() {
            u0 - self.kp * z0
        } else {
            u0
        };
    }

    /// Restart the z filter at `z` (the flow source switched between the transmitter and the
    /// observer: the jump between two sources is no change of the flow, and the filter, whose
    /// purpose is the transmitter's noise, must not carry one source's value over to the
    /// other for its time constant; on campaign case 155 the filter carried the fallback's
    /// reversed flow into the returned Δp's and held the PI's demand up for a second).
    pub fn restart_filter(&mut self, z: f64) {
        if z.is_finite() {
            self.z_f = z;
        }
    }

    /// The filtered z of the last step.
    pub fn z_filtered(&self) -> f64 {
        self.z_f
    }

    /// Integrator state, valve fraction.
    pub fn integrator(&self) -> f64 {
        self.integ
    }

    /// Take over another PI's state so that the unclamped demand at its last z is unchanged
    /// (a bumpless change of gains).
    pub fn take_over(&mut self, old: &Pi) {
        self.z_f = old.z_f;
        self.integ = if old.z_f.is_finite() {
            old.integ + (old.kp - self.kp) * old.z_f
        } else {
            old.integ
        };
    }

    /// Filter z (first order at `filter_hz`; none at 0) and return the filtered value.
    pub fn filter(&mut self, z: f64, dt_s: f64) -> f64 {
        if self.filter_hz > 0.0 && self.z_f.is_finite() {
            let a = 1.0 - (-2.0 * std::f64::consts::PI * self.filter_hz * dt_s.max(0.0)).exp();
            self.z_f += a * (z - self.z_f);
        } else {
            self.z_f = z;
        }
        self.z_f
    }

    /// The PI's demand for this step, clamped to [lo, hi], with the integrator advanced by
    /// conditional integration (seed 001 eq. 3.7). `z` is the filtered control variable.
    /// Call [`Pi::follow`] afterwards with the output actually applied.
    pub fn step(&mut self, z: f64, dt_s: f64, lo: f64, hi: f64) -> f64 {
        let u_raw = self.integ + self.kp * z;
        let into_hi = u_raw >= hi && z > 0.0;
        let into_lo = u_raw <= lo && z < 0.0;
        self.last_inc = if into_hi || into_lo {
            0.0
        } else {
            self.ki_per_s * z * dt_s.max(0.0)
        };
        self.integ += self.last_inc;
        (self.integ + self.kp * z).clamp(lo, hi)
    }

    /// External reset: the output applied was `u` while the PI demanded `demand` at `z`.
    /// Above the demand (another part holds the valve) the integrator is re-based onto the
    /// output while the PI asks to open, and kept from integrating further down while it
    /// asks to close. Nothing changes when the PI's own demand was applied.
    pub fn follow(&mut self, u: f64, demand: f64, z: f64) {
        if u > demand + 1e-12 {
            if z >= 0.0 {
                self.integ = u - self.kp * z;
            } else {
                // undo this step's integration in the closing direction
                self.integ -= self.last_inc.min(0.0);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn start_is_bumpless_and_the_integral_acts_on_the_error() {
        let mut pi = Pi::new(1.0, 2.0, 0.0);
        pi.start(0.3, 0.05);
        let z = pi.filter(0.05, 0.01);
        let u = pi.step(z, 0.01, 0.0, 1.0);
        // first demand = 0.3 plus one integration step 2·0.05·0.01
        assert!((u - 0.301).abs() < 1e-12, "{u}");
        // right of the line the demand falls
        let u2 = pi.step(-0.1, 0.01, 0.0, 1.0);
        assert!(u2 < u - 0.1, "{u2}");
    }

    #[test]
    fn conditional_integration_stops_winding_into_a_limit() {
        let mut pi = Pi::new(1.0, 10.0, 0.0);
        pi.start(0.0, 0.0);
        // far right of the line for 10 s: pinned at the closed limit, integrator not wound
        for _ in 0..1000 {
            let u = pi.step(-0.2, 0.01, 0.0, 1.0);
            assert_eq!(u, 0.0);
        }
        // the integral stopped where the output saturated (u_raw ≤ 0 with z < 0): one step
        // past −Kp z at most
        assert!(pi.integrator() > -0.2 - 0.03, "{}", pi.integrator());
        // back on the left: opens within a few steps, not after unwinding 10 s of error
        let mut u = 0.0;
        for _ in 0..30 {
            u = pi.step(0.05, 0.01, 0.0, 1.0);
        }
        assert!(u > 0.0, "{u}");
    }

    #[test]
    fn external_reset_rebases_when_the_pi_wants_more_and_freezes_when_it_wants_less() {
        let mut pi = Pi::new(1.0, 2.0, 0.0);
        pi.start(0.1, 0.0);
        // a trip holds 0.4 while the point is left of the line: re-based
        let d = pi.step(0.02, 0.01, 0.0, 1.0);
        pi.follow(0.4, d, 0.02);
        assert!((pi.integrator() + 0.02 - 0.4).abs() < 1e-12);
        // right of the line while held above: no integration downwards
        let i0 = pi.integrator();
        let d = pi.step(-0.1, 0.01, 0.0, 1.0);
        pi.follow(0.4, d, -0.1);
        assert!((pi.integrator() - i0).abs() < 1e-12);
    }

    #[test]
    fn a_restarted_filter_carries_nothing_of_the_old_source() {
        let mut pi = Pi::new(1.0, 2.0, 1.0);
        pi.start(1.0, 2.0);
        // the new source reads -0.5: without the restart the 1-Hz filter would still be
        // near +2 after one step
        pi.restart_filter(-0.5);
        let z = pi.filter(-0.5, 0.001);
        assert!((z + 0.5).abs() < 1e-12, "{z}");
        // a NaN (no usable point) leaves the filter as it was
        pi.restart_filter(f64::NAN);
        assert!((pi.z_filtered() + 0.5).abs() < 1e-12);
    }

    #[test]
    fn a_gain_change_keeps_the_demand() {
        let mut a = Pi::new(1.0, 2.0, 1.0);
        a.start(0.3, 0.04);
        let _ = a.filter(0.05, 0.01);
        let mut b = Pi::new(3.0, 2.0, 1.0);
        b.take_over(&a);
        let za = a.z_filtered();
        assert!(((a.integrator() + a.kp * za) - (b.integrator() + b.kp * za)).abs() < 1e-12);
    }
}
