//! `tip-sliding`: sliding-mode surge control through the magnetic thrust bearing, which moves
//! the impeller axially and so modulates the tip clearance (seed 004, Sanadgol & Maslen).
//!
//! # Model (seed 004 eq. 4, in the pressure ratio p = P/P01)
//!
//! ```text
//! ṗ = c_p (m − m_th(p)),   c_p = a01²/(Vp P01)                    (4a)
//! ṁ = c_m (ψ − p),         c_m = A P01/Lc                         (4b)
//! ψ^k − 1 = (ψss(m)^k − 1)(1 − u/(4 b2)),   k = (γ−1)/γ           (3), sign corrected
//! ```
//!
//! Correction (ERRATA 004, eq. 3): the seed divides by (1 − u/(4b2)), so a larger clearance
//! would *raise* the pressure ratio, against Senoo's efficiency loss (eq. 2). We use the
//! multiplicative form of `physics::tip_clearance` (u > 0 opens the clearance and lowers ψ) and
//! invert it for the command, u = 4 b2 (1 − (ψ_d^k − 1)/(ψss^k − 1)). The seed's u_eq of eq. 10,
//! 4b2 (1 − (ψ^k − 1)/(ψ_eq^k − 1)), is the inverse of the printed eq. 3, with the roles of
//! demanded and steady ratio swapped; the unit test `reaching_law_holds_with_an_instantaneous_servo` pins ours.
//!
//! # Sliding surface (deviation from seed 004 eq. 7 and 9)
//!
//! The seed slides on the steady characteristic, s = ψ − ψss (eq. 7), or its polar form
//! (eq. 9), which has the same zero set. On that surface p = ψss(m) and the motion is
//! ṁ = c_p (m − m_th(ψss(m)))/ψss'(m), whose linearisation c_p (1 − g σ)/σ (σ = ψss',
//! g = ∂m_th/∂p) is *positive* wherever σ > 0: the flow runs away from every equilibrium left of
//! the peak, the very region the law is meant to open (ERRATA 004; pinned by the unit test
//! `equivalent_dynamics_bare_surface_unstable_tilted_stable`). The polar form also keeps the
//! singularity at the peak: eq. 10's factor r_ss(m − α) + ∂r_ss/∂θ (P − β) vanishes where the
//! characteristic is horizontal. We slide instead on a surface tilted by a washed-out flow:
//!
//! ```text
//! s = p − ψss(m) + kv (m − m_f),     ṁ_f = (m − m_f)/τf,     kv > sup ψss'  (left of the peak)
//! ```
//!
//! *Why it is stable left of the peak.* On s = 0 with m_f frozen, p = ψss(m) − kv (m − m_f) is a
//! line of slope ψss' − kv = −D < 0 in the (m, p) plane: the compressor is made to look like one
//! with a falling characteristic. With ṗ = −D ṁ + kv ṁ_f and (4a), the equivalent dynamics on
//! s = 0 in (m, m_f), linearised at an equilibrium, have
//!
//! ```text
//! trace = −c_p (1 + g D)/D + σ/(D τf),        det = c_p (1 − g σ)/(D τf)
//! ```
//!
//! so they are stable whenever D > 0, g σ < 1 (true at every equilibrium where the throttle line
//! is steeper than the characteristic, i.e. the static-stability condition) and
//! τf > σ/(c_p (1 + g D)) (checked conservatively as τf > sup σ/c_p). At rest m_f = m, so s = 0
//! gives p = ψss(m), and ṁ = 0 gives ψ = p = ψss: u = 0, no steady offset of the impeller, as
//! the seed wants. Because D ≥ kv − sup ψss' > 0 everywhere (σ is clipped at its sup), the law
//! never divides by ψss' and the peak is not singular.
//!
//! # Reaching law (seed 004 eq. 12 and 15 on this surface)
//!
//! ṡ = ṗ + D ṁ − kv ṁ_f = ṗ + D c_m (ψ − p) − kv ṁ_f. Asking ṡ = −k sat(s/φ) (eq. 15) gives
//!
//! ```text
//! ψ_d = p + (−k sat(s/φ) − ṗ + kv ṁ_f)/(c_m D)      (ψ_eq of eq. 10/12: the same without k)
//! ```
//!
//! with ṗ from eq. 4a (throttle flow at the measured stem position) or from the filtered
//! derivative of the discharge pressure. Inside the boundary layer ṡ = −λ s, λ = k/φ.
//!
//! # Servo (the seed's analysis assumed an instantaneous servo)
//!
//! The thrust bearing follows its setpoint through a 3rd-order Butterworth low-pass,
//! H(s) = ωc³/(s³ + 2ωc s² + 2ωc² s + ωc³), ωc = 2π·70 Hz: at low frequency a delay of
//! 2/ωc ≈ 4.5 ms (16° at the 10 Hz Helmholtz frequency), plus half a control period for the
//! hold. Left of the peak the open-loop plant has real unstable poles near 100 s⁻¹, so the lag
//! is not negligible (pole × delay ≈ 0.5). Two measures:
//! 1. *prediction*: the law is evaluated at the state predicted h = f·2/ωc + dt/2 ahead with the
//!    model, p̂ = p + h ṗ, m̂ = m + h c_m (ψ(ψss(m), u_servo) − p), where u_servo is the clearance
//!    the servo delivers now (the measured rotor position, or an internal copy of the servo if
//!    it is not measured);
//! 2. λ = k/φ is kept below a third of ωc (checked when the law is built).
//!
//! A linearised discrete-time analysis (plant + servo + law at 1 ms, 0.08–0.85 kg/s) with the
//! tuned values of `config/plants/sanadgol2006_tip.toml` gives stability for a clearance
//! effectiveness (b2) error between −25 % and +20 % and one extra period of delay; simulation
//! agrees on the error range. Without the prediction the stairs between 0.04 and 0.16 kg/s
//! oscillate (test `servo_prediction_matters`). A phase lead (1 + 2s/ωc)/(1 + 2s/(α ωc)) was
//! tried first and narrowed the margins (it raises the loop gain near ωc), so it is not used.
//!
//! # Measurement noise
//!
//! The law feeds the duct pressure difference back almost directly, so pressure noise would
//! reach the clearance with gain 1/(∂ψ/∂u). The plenum pressure goes through a complementary
//! filter (eq. 4a integrated with the measured flow, pulled toward the measurement at rate L),
//! the suction pressure P01 through a slow low-pass, and the orifice flow's density correction
//! (m ∝ √p1) is re-referenced to the filtered P01.
//!
//! The command is limited to the bearing's modulation rating (auxiliary bearings: 50 % of the
//! nominal clearance) times `modulation_limit_fraction`. There is no integrator that could wind
//! up: the washout and the filters act on bounded measurements.

use crate::control::law::api::{LawError, LawId, LawInputs, LawOutput, SurgeLaw};
use crate::control::law::api::{LawNeeds, LawSpec};
use crate::control::model::ControlModel;
use crate::machine::params::ModelKind;
use crate::machine::MachineData;
use crate::physics::compressor_map::FlowCoordinate;
use crate::physics::thrust_bearing::ThrustBearingServo;
use crate::physics::tip_clearance::TipClearanceEffect;
use crate::vocab::signals::{ActuatorCommands, ActuatorId};
use crate::vocab::signals::{ActuatorSet, SensorId};
use serde::{Deserialize, Serialize};

/// Where the law takes the plenum pressure rate ṗ from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PressureRateSource {
    /// Seed 004 eq. 4a with the measured flow and the throttle flow at the measured stem
    /// position (falls back to `measured` when the throttle position is missing).
    #[default]
    Model,
    /// The filtered derivative of the discharge pressure (`controller.derivative_filter_hz`).
    Measured,
}

/// Settings (`[controller.tip_sliding]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TipSlidingConfig {
    /// Tilt of the sliding surface kv as a multiple of sup ψss' (the steepest positive slope
    /// of the characteristic left of the peak, per kg/s): must be > 1 (ERRATA 004: kv > sup
    /// ψss'). Not in the seed (its surface eq. 7 has no tilt); default 1.5.
    pub tilt_over_max_slope: f64,
    /// Washout time constant τf of the filtered flow m_f, s. Must exceed
    /// sup ψss'·Vp·P01/a01² (stability of the equivalent dynamics); the tilt's offset during a
    /// flow ramp ṁ is kv·τf·ṁ, so short is better. Not in the seed; default 0.07 s.
    pub washout_time_s: f64,
    /// Reaching gain k of eq. 12/15, pressure ratio per second (seed 004 eq. 13–14 give only a
    /// lower bound in terms of a reaching time, no number); default 1.4 /s.
    pub reaching_gain_per_s: f64,
    /// Boundary-layer thickness φ of eq. 15, pressure-ratio units (seed: no number); with k
    /// it sets the s-loop bandwidth λ = k/φ, which must stay below ωc/3. Default 0.02
    /// (≈ the ratio change of the full modulation), i.e. λ = 70 /s.
    pub boundary_layer: f64,
    /// Prediction horizon against the servo lag, as a fraction of the Butterworth's
    /// low-frequency delay 2/ωc (plus half a control period for the hold); 0 = evaluate the law
    /// at the measured state. Not in the seed (it assumed an instantaneous servo); default 0.5.
    pub servo_prediction_fraction: f64,
    /// Fraction of the bearing's modulation rating (`thrust_rating.modulation_max_m`) the
    /// law may command, in (0, 1] (seed 004: the auxiliary bearings allow 50 % of the
    /// clearance, i.e. the full rating); default 1.
    pub modulation_limit_fraction: f64,
    /// Source of the plenum pressure rate ṗ; default `model`.
    pub pressure_rate_source: PressureRateSource,
    /// Time constant with which the bumpless-transfer offset decays, s; default 0.1 s.
    pub bumpless_time_s: f64,
    /// Bandwidth L of the complementary filter for the plenum pressure, 1/s: p̂ integrates
    /// eq. 4a with the measured flow and is pulled toward the measured pressure at rate L, so
    /// pressure noise reaches the law low-pass filtered while the model supplies the fast part
    /// without lag. 0 = use the measured pressure directly. Not in the seed; default 3 /s.
    pub pressure_filter_per_s: f64,
    /// Cut-off of the low-pass on the suction pressure P01 (a boundary condition that moves
    /// slowly; its noise would enter p = P/P01 unfiltered), Hz. Not in the seed; default 0.5 Hz.
    pub suction_filter_hz: f64,
}

impl Default for TipSlidingConfig {
    fn default() -> Self {
        TipSlidingConfig {
            tilt_over_max_slope: 1.5,
            washout_time_s: 0.07,
            reaching_gain_per_s: 1.4,
            boundary_layer: 0.02,
            servo_prediction_fraction: 0.5,
            modulation_limit_fraction: 1.0,
            pressure_rate_source: PressureRateSource::Model,
            bumpless_time_s: 0.1,
            pressure_filter_per_s: 3.0,
            suction_filter_hz: 0.5,
        }
    }
}

/// Law state.
#[derive(Debug, Clone)]
pub struct TipSliding {
    cfg: TipSlidingConfig,
    /// kv, pressure ratio per kg/s.
    tilt: f64,
    /// sup ψss' over the region the law opens, per kg/s.
    max_slope: f64,
    /// A/Lc, m.
    area_over_length_m: f64,
    /// Vp/a01², s²·m.
    volume_over_sonic2: f64,
    effect: TipClearanceEffect,
    servo: ThrustBearingServo,
    /// Clearance command limit, m.
    u_limit_m: f64,
    /// Prediction horizon without the hold's half period, s.
    horizon_s: f64,
    // --- state ---
    /// Washed-out flow m_f, kg/s.
    m_f: f64,
    /// Filtered plenum pressure ratio p̂ (NaN: not started).
    p_hat: f64,
    /// Samples in the pressure filter so far.
    p_hat_samples: f64,
    /// Flow of the previous cycle, kg/s.
    m_prev: f64,
    /// Low-passed suction pressure P01, Pa (NaN: not started).
    p01_pa: f64,
    /// Samples in the suction filter so far.
    p01_samples: f64,
    /// Internal copy of the servo (position, velocity, acceleration), used when the rotor
    /// position is not measured.
    servo_x: [f64; 3],
    /// Last clearance command, m.
    last_u_m: f64,
    /// Bumpless-transfer offset, m.
    offset_m: f64,
    /// Output applied when the law started, m.
    current_m: f64,
    first: bool,
}

fn setting(key: &str, message: impl Into<String>) -> LawError {
    LawError::Setting {
        law: LawId::TipSliding,
        key: if key.is_empty() {
            "tip_sliding".to_string()
        } else {
            format!("tip_sliding.{key}")
        },
        message: message.into(),
    }
}

impl TipSliding {
    /// Build for a machine.
    pub fn new(cfg: &TipSlidingConfig, model: &ControlModel) -> Result<Self, LawError> {
        let tip = model
            .tip
            .ok_or_else(|| setting("", "the machine has no tip-clearance model"))?;
        let rating = model
            .thrust
            .ok_or_else(|| setting("", "the machine has no thrust_rating"))?;
        let positive = |key: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(setting(
                    key,
                    format!("must be positive and finite, got {v}"),
                ))
            }
        };
        positive("washout_time_s", cfg.washout_time_s)?;
        positive("reaching_gain_per_s", cfg.reaching_gain_per_s)?;
        positive("boundary_layer", cfg.boundary_layer)?;
        positive("bumpless_time_s", cfg.bumpless_time_s)?;
        positive("suction_filter_hz", cfg.suction_filter_hz)?;
        if !(cfg.pressure_filter_per_s.is_finite() && cfg.pressure_filter_per_s >= 0.0) {
            return Err(setting("pressure_filter_per_s", "must be ≥ 0"));
        }
        if !(cfg.tilt_over_max_slope.is_finite() && cfg.tilt_over_max_slope > 1.0) {
            return Err(setting(
                "tilt_over_max_slope",
                format!(
                    "must exceed 1 (kv > sup ψss', ERRATA 004), got {}",
                    cfg.tilt_over_max_slope
                ),
            ));
        }
        if !(cfg.servo_prediction_fraction.is_finite()
            && (0.0..=2.0).contains(&cfg.servo_prediction_fraction))
        {
            return Err(setting(
                "servo_prediction_fraction",
                format!("must be in [0, 2], got {}", cfg.servo_prediction_fraction),
            ));
        }
        if !(cfg.modulation_limit_fraction > 0.0 && cfg.modulation_limit_fraction <= 1.0) {
            return Err(setting(
                "modulation_limit_fraction",
                format!(
                    "must be in (0, 1] of the bearing rating, got {}",
                    cfg.modulation_limit_fraction
                ),
            ));
        }
        // sup ψss' left of the peak, per kg/s, over ±10 % of nominal speed and flows from zero
        // to the surge point (the region the law opens)
        let w0 = model.drive.nominal_speed_rad_s;
        let (q_peak, _) = model
            .speed_map()
            .peak(w0)
            .ok_or_else(|| setting("", "the map has no surge point at nominal speed"))?;
        let slope_map = model
            .speed_map()
            .max_slope((0.9 * w0, 1.1 * w0), (0.0, q_peak));
        let per_kg = match model.flow_coordinate {
            FlowCoordinate::MassKgS => 1.0,
            FlowCoordinate::InletVolumeM3S => {
                1.0 / model
                    .gas
                    .density_kg_m3(tip.ambient_pressure_pa, tip.ambient_temperature_k)
            }
        };
        let max_slope = (slope_map * per_kg).max(0.0);
        let tilt = cfg.tilt_over_max_slope * max_slope.max(1e-6);
        // washout: the equivalent dynamics need τf > sup ψss'·Vp·P01/a01²
        let volume_over_sonic2 = tip.plenum_volume_m3 / tip.sonic_velocity_m_s.powi(2);
        let tau_min = max_slope * volume_over_sonic2 * tip.ambient_pressure_pa;
        if cfg.washout_time_s <= tau_min {
            return Err(setting(
                "washout_time_s",
                format!("must exceed sup ψss'·Vp·P01/a01² = {tau_min:.4} s"),
            ));
        }
        // the boundary-layer bandwidth must stay well below the servo's
        let wc = tip.servo.omega_c();
        let lambda = cfg.reaching_gain_per_s / cfg.boundary_layer;
        if lambda > wc / 3.0 {
            return Err(setting(
                "reaching_gain_per_s",
                format!(
                    "k/φ = {lambda:.0} 1/s exceeds a third of the servo bandwidth ωc = {wc:.0} rad/s"
                ),
            ));
        }
        Ok(TipSliding {
            cfg: cfg.clone(),
            tilt,
            max_slope,
            area_over_length_m: tip.duct_area_m2 / tip.duct_length_m,
            volume_over_sonic2,
            effect: tip.effect,
            servo: tip.servo,
            u_limit_m: cfg.modulation_limit_fraction * rating.modulation_max_m,
            horizon_s: cfg.servo_prediction_fraction * 2.0 / wc,
            m_f: f64::NAN,
            p_hat: f64::NAN,
            p_hat_samples: 0.0,
            m_prev: f64::NAN,
            p01_pa: f64::NAN,
            p01_samples: 0.0,
            servo_x: [0.0; 3],
            last_u_m: 0.0,
            offset_m: 0.0,
            current_m: 0.0,
            first: true,
        })
    }

    /// Surface tilt kv, pressure ratio per kg/s.
    pub fn tilt_per_kg_s(&self) -> f64 {
        self.tilt
    }

    /// sup ψss' over the region the law opens, per kg/s.
    pub fn max_slope_per_kg_s(&self) -> f64 {
        self.max_slope
    }

    /// The washed-out flow the last update used, given that update's flow and period.
    #[cfg(test)]
    fn m_f_before(&self, m: f64, dt: f64) -> f64 {
        let a = 1.0 - (-dt / self.cfg.washout_time_s).exp();
        (self.m_f - a * m) / (1.0 - a)
    }

    /// Plenum pressure ratio for the law: the complementary filter
    /// dp̂/dt = c_p (m − m_th(p̂)) + L (P/P01 − p̂) (seed 004 eq. 4a with the measured flow;
    /// started as a running mean), or the measured ratio if L = 0, the throttle flow is unknown
    /// or ṗ is taken from the measurement.
    fn filtered_pressure(
        &mut self,
        inputs: &LawInputs<'_>,
        dt: f64,
        c_p: f64,
        p01: f64,
        flow: f64,
    ) -> f64 {
        let meas = inputs.m;
        let p = meas.p_discharge_pa / p01;
        let l = self.cfg.pressure_filter_per_s;
        let outflow = |p_ratio: f64| {
            inputs.model.outflow_kg_s(
                meas.p_suction_pa,
                p_ratio * p01,
                meas.recycle_position,
                meas.throttle_position,
            )
        };
        if l <= 0.0
            || self.cfg.pressure_rate_source != PressureRateSource::Model
            || !outflow(p).is_finite()
        {
            self.p_hat = f64::NAN;
            return p;
        }
        if !(self.p_hat.is_finite() && self.m_prev.is_finite()) {
            self.p_hat = p;
            self.p_hat_samples = 1.0;
            return p;
        }
        // predict with eq. 4a over the period (midpoint flow), then correct toward the measurement
        let m_mid = 0.5 * (self.m_prev + flow);
        let m_th = outflow(self.p_hat);
        self.p_hat += dt * c_p * (m_mid - m_th);
        self.p_hat_samples += 1.0;
        let gain = (1.0 - (-l * dt).exp()).max(1.0 / self.p_hat_samples);
        self.p_hat += (p - self.p_hat) * gain;
        self.p_hat
    }

    /// Advance the internal copy of the servo by `dt` with the last command held.
    fn advance_servo(&mut self, dt: f64) {
        const N: usize = 8;
        let h = dt / N as f64;
        for _ in 0..N {
            let d = self.servo.rhs(self.servo_x, self.last_u_m);
            for (x, dx) in self.servo_x.iter_mut().zip(d) {
                *x += h * dx;
            }
        }
    }
}

/// sat(x) = clamp(x, −1, 1) (seed 004 eq. 15).
#[inline]
fn sat(x: f64) -> f64 {
    x.clamp(-1.0, 1.0)
}

impl SurgeLaw for TipSliding {
    fn start(&mut self, inputs: &LawInputs<'_>, current: &ActuatorCommands) {
        let c = current.get(ActuatorId::TipClearance);
        // no command means the servo holds the centre position (setpoint 0)
        self.current_m = if c.is_finite() { c } else { 0.0 };
        self.m_f = inputs.m.m_kg_s;
        self.p_hat = f64::NAN;
        self.m_prev = f64::NAN;
        self.p01_pa = f64::NAN;
        let x = inputs.m.thrust_position_m;
        self.servo_x = [if x.is_finite() { x } else { self.current_m }, 0.0, 0.0];
        self.last_u_m = self.current_m;
        self.offset_m = 0.0;
        self.first = true;
    }

    fn update(&mut self, inputs: &LawInputs<'_>, dt_s: f64) -> LawOutput {
        let meas = inputs.m;
        let model = inputs.model;
        let mut out = LawOutput::idle();
        if !(meas.m_kg_s.is_finite() && meas.p_suction_pa > 0.0 && meas.p_discharge_pa.is_finite())
        {
            return out;
        }
        let dt = dt_s.max(0.0);
        // suction pressure P01: a boundary condition that moves slowly, low-passed (a running
        // mean until the low-pass has as much memory, so one noisy first sample does not linger)
        if !self.p01_pa.is_finite() {
            self.p01_pa = meas.p_suction_pa;
            self.p01_samples = 0.0;
        }
        self.p01_samples += 1.0;
        let tau_s = 1.0 / (2.0 * std::f64::consts::PI * self.cfg.suction_filter_hz);
        let gain = (1.0 - (-dt / tau_s).exp()).max(1.0 / self.p01_samples);
        self.p01_pa += (meas.p_suction_pa - self.p01_pa) * gain;
        let p01 = self.p01_pa;
        // the orifice's density correction (m ∝ √p1, seed 002 eq. 2.10–2.14) re-referenced to
        // the filtered suction pressure, so suction-pressure noise does not reach the flow
        let m_meas = if meas.m_kg_s == meas.m_measured_kg_s && !meas.flow_fallback {
            meas.m_kg_s * (p01 / meas.p_suction_pa).sqrt()
        } else {
            meas.m_kg_s
        };
        self.advance_servo(dt);
        if !self.m_f.is_finite() {
            self.m_f = m_meas;
        }
        let t_k = meas.t_suction_k;
        let dq_dm = model.map_flow(1.0, p01, t_k);
        let c_m = self.area_over_length_m * p01; // eq. 4b: ṁ = c_m (ψ − p)
        let c_p = 1.0 / (self.volume_over_sonic2 * p01); // eq. 4a: ṗ = c_p (m − m_th)
        let p_meas = self.filtered_pressure(inputs, dt, c_p, p01, m_meas);
        // ṗ at a plenum pressure ratio p and flow m
        let p_rate = |p: f64, m: f64| -> f64 {
            let measured = meas.dp_discharge_dt_pa_s / p01;
            let r = match self.cfg.pressure_rate_source {
                PressureRateSource::Model => {
                    let m_th = model.outflow_kg_s(
                        p01,
                        p * p01,
                        meas.recycle_position,
                        meas.throttle_position,
                    );
                    if m_th.is_finite() {
                        c_p * (m - m_th)
                    } else {
                        measured
                    }
                }
                PressureRateSource::Measured => measured,
            };
            if r.is_finite() {
                r
            } else {
                0.0
            }
        };
        // --- prediction over the servo lag: the state the command will act on ---
        let u_servo = if meas.thrust_position_m.is_finite() {
            meas.thrust_position_m
        } else {
            self.servo_x[0]
        };
        let h = self.horizon_s + if self.horizon_s > 0.0 { 0.5 * dt } else { 0.0 };
        let (p, flow) = if h > 0.0 {
            let q = model.map_flow(m_meas, p01, t_k);
            let psi_ss_now = model.speed_map().eval(q, meas.omega_rad_s).value;
            let psi_now = self.effect.pressure_ratio(psi_ss_now, u_servo); // eq. 3 (corrected)
            let m_dot = c_m * (psi_now - p_meas); // eq. 4b
            (p_meas + h * p_rate(p_meas, m_meas), m_meas + h * m_dot)
        } else {
            (p_meas, m_meas)
        };
        // steady characteristic ψss(m) and its slope per kg/s (map at the measured speed)
        let pt = model
            .speed_map()
            .eval(model.map_flow(flow, p01, t_k), meas.omega_rad_s);
        let psi_ss = pt.value;
        let sigma = pt.d_dflow * dq_dm;
        // D = kv − ψss' ≥ kv − sup ψss' > 0: no division by the slope, no singularity at the peak
        let d = self.tilt - sigma.min(self.max_slope);
        let p_dot = p_rate(p, flow);
        // tilted surface and the washout
        let s = p - psi_ss + self.tilt * (flow - self.m_f);
        let m_f_dot = (flow - self.m_f) / self.cfg.washout_time_s;
        // ṡ = ṗ + D c_m (ψ − p) − kv ṁ_f := −k sat(s/φ)  (seed 004 eq. 15 on our surface)
        let psi_d = p
            + (-self.cfg.reaching_gain_per_s * sat(s / self.cfg.boundary_layer) - p_dot
                + self.tilt * m_f_dot)
                / (c_m * d);
        // eq. 3 (corrected) inverted for the clearance change
        let lim = self.u_limit_m;
        let u_law = self
            .effect
            .clearance_for_ratio(psi_ss, psi_d)
            .unwrap_or(0.0)
            .clamp(-lim, lim);
        // bumpless transfer: the first output equals the one applied now, the difference decays
        if self.first {
            self.offset_m = self.current_m - u_law;
            self.first = false;
        } else {
            self.offset_m *= (-dt / self.cfg.bumpless_time_s).exp();
        }
        let u = (u_law + self.offset_m).clamp(-lim, lim);
        // washout of the measured flow
        self.m_f += (m_meas - self.m_f) * (1.0 - (-dt / self.cfg.washout_time_s).exp());
        self.last_u_m = u;
        self.m_prev = m_meas;
        out.commands.set(ActuatorId::TipClearance, u);
        out.diagnostic = s;
        out
    }
}

impl LawSpec for TipSliding {
    type Settings = TipSlidingConfig;
    const NEEDS: LawNeeds = LawNeeds {
        summary: "sliding mode on the tip clearance via the magnetic thrust bearing (seed 004)",
        actuators: ActuatorSet::of(&[ActuatorId::TipClearance]),
        sensors: &[SensorId::ShaftSpeed, SensorId::ThrustPosition],
        needs_flow: true,
        machine_data: &[
            MachineData::SpeedLineMap,
            MachineData::Model(ModelKind::TipClearance),
        ],
        model_family: Some(ModelKind::TipClearance),
    };
    fn build(settings: &Self::Settings, model: &ControlModel) -> Result<Self, LawError> {
        TipSliding::new(settings, model)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::measurements::{Measurements, OperatorInputs};
    use crate::plant::tip_clearance::throttle_flow_kg_s;
    use crate::sim::case::PlantCase;

    fn model() -> ControlModel {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("config/plants/sanadgol2006_tip.toml");
        let desc = PlantCase::load(&path).expect("plant file");
        crate::sim::control_model(&desc)
    }

    /// ψss(m) and ψss'(m) at nominal speed.
    fn psi_ss(model: &ControlModel, m: f64) -> (f64, f64) {
        let pt = model.speed_map().eval(m, model.drive.nominal_speed_rad_s);
        (pt.value, pt.d_dflow)
    }

    /// Equilibrium flow of the uncontrolled machine at a throttle opening (bisection).
    fn equilibrium(model: &ControlModel, throttle: f64) -> f64 {
        let tip = model.tip.unwrap();
        let p01 = tip.ambient_pressure_pa;
        let f =
            |m: f64| throttle_flow_kg_s(&tip, &model.gas, psi_ss(model, m).0 * p01, throttle) - m;
        let (mut lo, mut hi) = (1e-4, 1.5);
        assert!(f(lo) > 0.0 && f(hi) < 0.0);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if f(mid) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// Largest real part of the eigenvalues of the equivalent dynamics on s = 0, state
    /// (m, m_f): ṁ = (c_p (m − m_th(p)) − kv ṁ_f)/(ψss'(m) − kv), ṁ_f = (m − m_f)/τf, with
    /// p = ψss(m) − kv (m − m_f); numerical Jacobian at the equilibrium of `throttle`.
    fn surface_abscissa(model: &ControlModel, throttle: f64, kv: f64, tau_f: f64) -> f64 {
        let tip = model.tip.unwrap();
        let p01 = tip.ambient_pressure_pa;
        let c_p = tip.sonic_velocity_m_s.powi(2) / (tip.plenum_volume_m3 * p01);
        let rhs = |m: f64, mf: f64| -> (f64, f64) {
            let (psi, sigma) = psi_ss(model, m);
            let p = psi - kv * (m - mf);
            let m_th = throttle_flow_kg_s(&tip, &model.gas, p * p01, throttle);
            let mf_dot = (m - mf) / tau_f;
            ((c_p * (m - m_th) - kv * mf_dot) / (sigma - kv), mf_dot)
        };
        let m0 = equilibrium(model, throttle);
        let h = 1e-6;
        let (a, c) = {
            let (p, q) = rhs(m0 + h, m0);
            let (r, t) = rhs(m0 - h, m0);
            ((p - r) / (2.0 * h), (q - t) / (2.0 * h))
        };
        let (b, d) = {
            let (p, q) = rhs(m0, m0 + h);
            let (r, t) = rhs(m0, m0 - h);
            ((p - r) / (2.0 * h), (q - t) / (2.0 * h))
        };
        let (tr, det) = (a + d, a * d - b * c);
        let disc = tr * tr - 4.0 * det;
        if disc >= 0.0 {
            0.5 * (tr + disc.sqrt())
        } else {
            0.5 * tr
        }
    }

    #[test]
    fn equivalent_dynamics_bare_surface_unstable_tilted_stable() {
        // ERRATA 004: on the seed's surface s = ψ − ψss (kv = 0) the motion left of the peak grows;
        // on the tilted surface with the tuned kv, τf it decays, down to a few % of the peak flow.
        let model = model();
        let law = TipSliding::new(&model.controller.tip_sliding, &model).expect("law");
        let kv = law.tilt_per_kg_s();
        let tau_f = model.controller.tip_sliding.washout_time_s;
        assert!(
            (0.13..0.16).contains(&law.max_slope_per_kg_s()),
            "{}",
            law.max_slope_per_kg_s()
        );
        for throttle in [0.32, 0.28, 0.2, 0.14, 0.08, 0.03] {
            let m = equilibrium(&model, throttle);
            assert!(psi_ss(&model, m).1 > 0.0, "{throttle}: left of the peak");
            let bare = surface_abscissa(&model, throttle, 0.0, tau_f);
            let tilted = surface_abscissa(&model, throttle, kv, tau_f);
            assert!(bare > 0.1, "bare surface at {m:.3} kg/s: {bare}");
            assert!(tilted < -1.0, "tilted surface at {m:.3} kg/s: {tilted}");
        }
        // the washout bound: τf below sup ψss'/c_p loses the equivalent dynamics
        assert!(surface_abscissa(&model, 0.2, kv, 0.02) > 0.0);
    }

    fn meas(model: &ControlModel, m: f64, p_ratio: f64, throttle: f64) -> Measurements {
        let tip = model.tip.unwrap();
        Measurements {
            t_s: 0.0,
            p_suction_pa: tip.ambient_pressure_pa,
            p_discharge_pa: p_ratio * tip.ambient_pressure_pa,
            omega_rad_s: model.drive.nominal_speed_rad_s,
            t_suction_k: tip.ambient_temperature_k,
            m_kg_s: m,
            m_measured_kg_s: m,
            m_observer_kg_s: m,
            flow_map: m,
            pressure_ratio: p_ratio,
            recycle_position: f64::NAN,
            throttle_position: throttle,
            thrust_position_m: 0.0,
            dp_suction_dt_pa_s: 0.0,
            dp_discharge_dt_pa_s: 0.0,
            flow_fallback: false,
        }
    }

    const OP: OperatorInputs = OperatorInputs {
        speed_setpoint_rad_s: 2408.6,
        throttle_demand: 0.2,
        flow_setpoint_kg_s: f64::NAN,
        recycle_manual: f64::NAN,
    };

    #[test]
    fn reaching_law_holds_with_an_instantaneous_servo() {
        // With the servo taken as instantaneous (the seed's assumption), the command put through
        // the corrected eq. 3 and eq. 4 must give exactly ṡ = −k sat(s/φ): this pins the sign of
        // the inversion, c_m, D and the surface derivative. Points left of, at and right of the
        // peak (no singularity where ψss' = 0), pressure above and below the surface.
        let model = model();
        let mut cfg = model.controller.tip_sliding.clone();
        cfg.bumpless_time_s = 1e-9;
        cfg.servo_prediction_fraction = 0.0;
        cfg.pressure_filter_per_s = 0.0;
        let tip = model.tip.unwrap();
        let p01 = tip.ambient_pressure_pa;
        let c_p = tip.sonic_velocity_m_s.powi(2) / (tip.plenum_volume_m3 * p01);
        let c_m = tip.duct_area_m2 / tip.duct_length_m * p01;
        let (q_peak, _) = model
            .speed_map()
            .peak(model.drive.nominal_speed_rad_s)
            .unwrap();
        for (throttle, dm) in [(0.2, 0.0), (0.1, 0.01), (0.35, 0.0), (0.6, -0.02)] {
            let m_eq = equilibrium(&model, throttle);
            for dp in [0.004, -0.003, 0.0005] {
                let mut law = TipSliding::new(&cfg, &model).unwrap();
                let m = m_eq + dm;
                // m_f starts at m; the measured flow at the start is the equilibrium flow
                let at_start = meas(&model, m, psi_ss(&model, m).0, throttle);
                let inputs = LawInputs {
                    m: &at_start,
                    op: &OP,
                    model: &model,
                    history: &crate::control::law::api::LoopHistory::EMPTY,
                };
                law.start(&inputs, &ActuatorCommands::default());
                law.update(&inputs, 1e-3);
                let (psi, sigma) = psi_ss(&model, m);
                let p = psi + dp;
                let x = meas(&model, m, p, throttle);
                let out = law.update(
                    &LawInputs {
                        m: &x,
                        op: &OP,
                        model: &model,
                        history: &crate::control::law::api::LoopHistory::EMPTY,
                    },
                    1e-3,
                );
                let u = out.commands.get(ActuatorId::TipClearance);
                assert!(u.abs() < 0.9 * law.u_limit_m, "unsaturated: {u}");
                let s = out.diagnostic;
                let kv = law.tilt_per_kg_s();
                let m_f = law.m_f_before(m, 1e-3);
                assert!((s - (p - psi + kv * (m - m_f))).abs() < 1e-12, "surface");
                let m_dot = c_m * (tip.effect.pressure_ratio(psi, u) - p); // eq. 4b
                let p_dot = c_p * (m - throttle_flow_kg_s(&tip, &model.gas, p * p01, throttle));
                let s_dot = p_dot - sigma * m_dot + kv * (m_dot - (m - m_f) / cfg.washout_time_s);
                let want = -cfg.reaching_gain_per_s * (s / cfg.boundary_layer).clamp(-1.0, 1.0);
                assert!(
                    (s_dot - want).abs() < 1e-6 * cfg.reaching_gain_per_s,
                    "m {m:.3} (peak {q_peak:.3}) dp {dp}: ṡ {s_dot} want {want}"
                );
            }
        }
    }

    #[test]
    fn first_output_equals_current_then_converges_to_the_law() {
        let model = model();
        let m = equilibrium(&model, 0.2);
        let psi = psi_ss(&model, m).0;
        let rest = meas(&model, m, psi, 0.2);
        let inputs = LawInputs {
            m: &rest,
            op: &OP,
            model: &model,
            history: &crate::control::law::api::LoopHistory::EMPTY,
        };
        let mut law = TipSliding::new(&model.controller.tip_sliding, &model).unwrap();
        let mut cur = ActuatorCommands::default();
        cur.set(ActuatorId::TipClearance, 37e-6);
        law.start(&inputs, &cur);
        let first = law
            .update(&inputs, 1e-3)
            .commands
            .get(ActuatorId::TipClearance);
        assert_eq!(first, 37e-6);
        let mut last = first;
        for _ in 0..1000 {
            let u = law
                .update(&inputs, 1e-3)
                .commands
                .get(ActuatorId::TipClearance);
            assert!((u - last).abs() < 0.01 * 37e-6, "step {}", u - last);
            last = u;
        }
        assert!(last.abs() < 1e-8, "after 1 s at rest: {last}");
    }
}
