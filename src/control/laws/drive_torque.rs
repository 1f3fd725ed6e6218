//! `drive-torque`: active surge control with the drive torque and mass-flow observer feedback
//! (seed 000, Bøhagen & Gravdahl).
//!
//! # The law
//!
//! Seed 000 eq. 7 with the observer estimate of Theorem 3 (eq. 22):
//!
//! ```text
//! τ̄d = −K1 (ω − ω0) − K2 (m̂ − m0),   K2 = K1 c1                            (eq. 7, 9, 22)
//! c1 > sup (∂Ψc/∂m)/(∂Ψc/∂ω)  on the operating region                    (eq. 8)
//! ```
//!
//! τ̄d is added to the output of the drive's speed loop (the core's `SpeedLoop`), whose integral
//! supplies the equilibrium torque τd0 = τc0; ω0 is the operator's speed setpoint. Eq. 7 is the
//! velocity loop τ̄d = K1 (ωd − ω) around the desired speed ωd = ω0 − c1 m̄ (seed 000 eq. 4): the
//! speed is raised when the flow falls below its equilibrium, which raises the pressure rise and
//! accelerates the flow back. Eq. 8 is the condition that the *effective* characteristic
//! Ψc(m, ω0 − c1 m̄) has a negative slope, ∂Ψc/∂m − c1 ∂Ψc/∂ω < 0.
//!
//! K2 is not a separate setting: eq. 9 fixes it. (Seed 000 §6.2 simulated K2 = 500 with
//! K1 c1 = 10⁶, which violates eq. 9 and leaves deep surge untouched, ERRATA.md.)
//!
//! # Equilibrium flow m0 (not in the seed)
//!
//! The proof takes m0 as the known equilibrium; after a throttle change it is unknown. At any
//! equilibrium m0 = m_t0, the throttle flow (seed 000, text below eq. 3). The law uses
//!
//! ```text
//! m0 = m_out(p, throttle position) + b,    b = LP_τb(m̂ − m_out)
//! m̄ = m̂ − m0 = HP_τb(m̂ − m_out)
//! ```
//!
//! where m_out is the outflow of the plenum computed from the measured pressure and the valve
//! position feedback with the valve equation (the same m_t the observer of eq. 15 already
//! needs), and b is a slow low-pass that absorbs any steady model error of m_out. By the mass
//! balance (eq. 1a) m − m_out = (Vp/a01²) ṗ, so m̄ vanishes at *every* steady state, whatever
//! the throttle: the law is then zero and the speed loop holds the mean speed at ω0.
//!
//! Why this keeps the local stability argument (linearise eq. 3 with the law and ω tracking ωd,
//! write ψ' = p01 ∂Ψc/∂m, β = p01 c1 ∂Ψc/∂ω, g = ∂m_t/∂p):
//!
//! ```text
//! d m̄/dt = A1/Lc [(ψ' − β) m̄ + (β g − 1) p̄]
//! d p̄/dt = a01²/Vp (m̄ − g p̄)
//! trace = A1/Lc (ψ' − β) − a01²/Vp g,   det = A1/Lc · a01²/Vp · (1 − ψ' g)
//! ```
//!
//! The trace is negative under eq. 8 (ψ' < β) exactly as for eq. 7 with a constant m0; the
//! determinant is the open-loop one and is positive wherever the throttle line is steeper than
//! the characteristic (ψ' g < 1: a unique, statically stable intersection, true for every
//! throttle opening of the benchmark plants). The slow bias b (time constant τb ≫ the closed-loop
//! time constants) only removes the DC part: by time-scale separation it adds one slow stable
//! pole near −1/τb. A plain washout of m̂ (`equilibrium_flow = "washout"`, m0 = LP(m̂)) is the
//! fallback when no valve position is available (and what the law uses until one appears).
//! Linearised, its slow subsystem is stable under the same static condition if the washout is
//! slower than the closed-loop modes, but during a large throttle move m̂ − LP(m̂) is of the
//! order of the ramp rate × τb, the law asks for a speed change c1 times that, and the torque
//! saturates: on bohagen2007 the 60 → 20 % closure surges with the washout for every τb tried
//! (0.3–5 s), while small steps (the 5 %-point sweep with τb = 0.3 s) are held. Hence the
//! outflow construction is the default.
//!
//! # Flow source and noise
//!
//! The flow is the observer estimate by default (Theorem 3; `flow = "observer"`), or the flow
//! the core selected (`"selected"`), or the orifice (`"measured"`); a missing value falls back
//! to the core's selection. The estimate m̂ = z + K_z p passes pressure noise with gain K_z
//! (ERRATA.md); the law low-passes m̂ − m_out with `flow_filter_order` first-order sections at
//! `flow_filter_hz`. The cut-off must stay above the closed-loop bandwidth, which eq. 8 forces
//! up to ≈ A1/Lc · p01 · c1 ∂Ψc/∂ω (the unstable duct pole of the bohagen2007 plant is
//! ≈ 143 rad/s at 20 % throttle), so filtering buys little. With c2 = 40 000 the estimate's
//! high-frequency noise gain is K_z = 7.8·10⁻³ kg/s per Pa, i.e. K2 K_z ≈ 200 N·m of torque per
//! Pa before the filter; below the speed bandwidth the torque needed to follow the noise is
//! J c1 s m̂, a double derivative of the pressure noise. Measured on bohagen2007 (uniform white
//! noise on both transmitters, 1 kHz): the loop stays out of surge up to ≈ 25 Pa (torque then
//! chatters at the ±1000 N·m rating about a quarter of the time); it holds the torque inside
//! the rating without clipping only up to ≈ 5 Pa; 100 Pa and the seed's 5000 Pa (§6.3) surge.
//! The seed's noise claim held only with its ineffective K2 = 500 (ERRATA.md).
//!
//! # Limits and bumpless transfer
//!
//! The law's extra torque is clamped to ±`torque_limit_nm` (default: the drive's whole range);
//! the speed loop clamps the sum to the drive rating and stops integrating while the sum
//! saturates in the direction of its error (conditional integration). The law has no integrator
//! of its own, so nothing in it winds up. `start` sets the filters so that m̄ = 0 and stores the
//! difference between the applied extra torque and −K1 (ω − ω0) as an offset that decays with
//! `transfer_time_constant_s`: the first output equals the applied one.

#[cfg(doc)]
use crate::control::law::api::LoopHistory;
use crate::control::law::api::{
    LawError, LawId, LawInputs, LawNeeds, LawOutput, LawSpec, SurgeLaw,
};
use crate::control::measurements::Measurements;
use crate::control::model::ControlModel;
use crate::machine::params::ModelKind;
use crate::machine::plenum_duct::{PlenumDuctModel, N as PLENUM_N};
use crate::machine::MachineData;
use crate::physics::compressor_map::FlowCoordinate;
use crate::vocab::signals::{ActuatorCommands, ActuatorId};
use crate::vocab::signals::{ActuatorSet, SensorId};
use nalgebra::SVector;
use serde::{Deserialize, Serialize};

/// Where the law takes the mass flow from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FlowInput {
    /// The mass-flow observer (seed 000 eq. 15, Theorem 3): pressures and speed only.
    #[default]
    Observer,
    /// The flow the core selected with `[controller] flow_source`.
    Selected,
    /// The orifice transmitter.
    Measured,
}

/// How the law obtains the equilibrium flow m0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum EquilibriumFlow {
    /// m0 = m_out(p, valve positions) + slow bias: exact at every steady state (module docs).
    #[default]
    Outflow,
    /// m0 = low-pass of the flow (washout); no valve positions needed.
    Washout,
}

/// Settings (`[controller.drive_torque]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriveTorqueConfig {
    /// c1 of eq. 4/8/9, rad/s of speed change per kg/s of flow deviation. Must exceed the eq. 8
    /// bound ([`eq8_bound`]). Seed 000 §6.2: 100.
    pub c1_rad_s_per_kg_s: f64,
    /// K1 of eq. 7, N·m per rad/s. K1/J is the bandwidth of the speed tracking; with a control
    /// period h it needs K1 h/J < 1. Seed 000 §6.2: 10 000 (continuous time).
    pub k1_nm_s_rad: f64,
    /// Flow the law feeds back. Seed 000 Theorem 3: the observer.
    pub flow: FlowInput,
    /// Construction of the equilibrium flow m0 (not in the seed; module docs).
    pub equilibrium_flow: EquilibriumFlow,
    /// Time constant of the low-pass that gives the bias of m0 (or m0 itself for `washout`), s.
    /// Not in the seed.
    pub equilibrium_time_constant_s: f64,
    /// Cut-off of each low-pass section on the flow deviation, Hz (0: no filter). Not in the
    /// seed (§6.3 uses the raw estimate).
    pub flow_filter_hz: f64,
    /// Number of first-order sections of that filter (1–4).
    pub flow_filter_order: u32,
    /// Bound on the law's extra torque, N·m (0: the drive's whole range, rated − min).
    pub torque_limit_nm: f64,
    /// Decay time of the bumpless-transfer offset, s.
    pub transfer_time_constant_s: f64,
    /// Loop delay the law compensates, ms: from the control cycle to the moment its torque
    /// acts (command transfer, the drive's torque loop, plus the sensor transfer before the
    /// sample reached the controller). The law predicts speed and flow from the sample over
    /// this delay plus the sample's measured age, in whole control periods, with the machine
    /// model (seed 000 eq. 1) and the torques already commanded (module docs). 0: no
    /// prediction, for a loop whose command acts within the period (`antisurge sim`). Not in
    /// the seed.
    pub delay_compensation_ms: f64,
}

impl Default for DriveTorqueConfig {
    fn default() -> Self {
        DriveTorqueConfig {
            c1_rad_s_per_kg_s: 100.0,
            k1_nm_s_rad: 10_000.0,
            flow: FlowInput::Observer,
            equilibrium_flow: EquilibriumFlow::Outflow,
            equilibrium_time_constant_s: 2.0,
            flow_filter_hz: 0.0,
            flow_filter_order: 1,
            torque_limit_nm: 0.0,
            transfer_time_constant_s: 0.5,
            delay_compensation_ms: 0.0,
        }
    }
}

impl DriveTorqueConfig {
    /// K2 = K1 c1 (eq. 9), N·m per kg/s.
    pub fn k2_nm_s_kg(&self) -> f64 {
        self.k1_nm_s_rad * self.c1_rad_s_per_kg_s
    }
}

/// Largest number of low-pass sections.
pub const MAX_FILTER_ORDER: usize = 4;

/// Longest loop delay the predictor covers, control periods.
pub const MAX_DELAY_PERIODS: usize = 8;

/// The region of the map on which eq. 8 is evaluated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Eq8Region {
    /// Speed range, rad/s.
    pub omega_rad_s: (f64, f64),
    /// Mass-flow range, kg/s.
    pub flow_kg_s: (f64, f64),
}

impl Eq8Region {
    /// The operating region used for the gain checks: flows from −q_peak (reverse flow of deep
    /// surge) to 2.5 q_peak, speeds 70–120 % of nominal, q_peak = surge flow at nominal speed
    /// (the same region as the observer bound, `ControlModel::observer_min_gain`).
    pub fn default_for(model: &ControlModel) -> Option<Eq8Region> {
        let w0 = model.drive.nominal_speed_rad_s;
        let (q_peak, _) = model.speed_map().peak(w0)?;
        let (p, t) = suction_conditions(model);
        let per_map = model.map_flow(1.0, p, t);
        let m_peak = q_peak / per_map;
        Some(Eq8Region {
            omega_rad_s: (0.7 * w0, 1.2 * w0),
            flow_kg_s: (-m_peak, 2.5 * m_peak),
        })
    }
}

/// The admissible c1 of eq. 8 on a region: c1 ∈ (c1_min, c1_max).
///
/// Eq. 8 is the condition ∂Ψc/∂m − c1 ∂Ψc/∂ω < 0 at every point. Where ∂Ψc/∂ω > 0 it reads
/// c1 > (∂Ψc/∂m)/(∂Ψc/∂ω) (the seed's sup); where ∂Ψc/∂ω < 0 it *reverses* into an upper bound
/// c1 < (∂Ψc/∂m)/(∂Ψc/∂ω); where ∂Ψc/∂ω = 0 and ∂Ψc/∂m ≥ 0 no c1 works. Over all flows the sup
/// is unbounded for maps whose ∂Ψc/∂ω changes sign at large reverse flow (ERRATA.md): the
/// condition holds on a region only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Eq8Bound {
    /// sup of (∂Ψc/∂m)/(∂Ψc/∂ω) where ∂Ψc/∂ω > 0, rad/s per kg/s (the seed's eq. 8 bound).
    pub c1_min: f64,
    /// inf of (∂Ψc/∂m)/(∂Ψc/∂ω) where ∂Ψc/∂ω < 0 (∞ if ∂Ψc/∂ω > 0 on the whole region).
    pub c1_max: f64,
    /// Flow and speed where the sup is attained, (kg/s, rad/s).
    pub argmax: (f64, f64),
    /// The region.
    pub region: Eq8Region,
}

impl Eq8Bound {
    /// Whether c1 satisfies eq. 8 on the region.
    pub fn admits(&self, c1: f64) -> bool {
        c1 > self.c1_min && c1 < self.c1_max
    }
}

fn suction_conditions(model: &ControlModel) -> (f64, f64) {
    match &model.plenum_duct {
        Some(p) => (p.ambient_pressure_pa, p.ambient_temperature_k),
        None => (1.0e5, model.nominal_suction_temperature_k),
    }
}

/// Evaluate eq. 8 on a region of the controller's map (grid of 41 speeds × 801 flows).
pub fn eq8_bound(model: &ControlModel, region: Eq8Region) -> Eq8Bound {
    let (p, t) = suction_conditions(model);
    // flow in map units per kg/s (1 for a mass-flow map, 1/ρ for a volumetric one)
    let per_map = match model.flow_coordinate {
        FlowCoordinate::MassKgS => 1.0,
        FlowCoordinate::InletVolumeM3S => model.map_flow(1.0, p, t),
    };
    let mut c1_min = f64::NEG_INFINITY;
    let mut c1_max = f64::INFINITY;
    let mut argmax = (f64::NAN, f64::NAN);
    let (w_lo, w_hi) = region.omega_rad_s;
    let (m_lo, m_hi) = region.flow_kg_s;
    for i in 0..=40 {
        let w = w_lo + (w_hi - w_lo) * f64::from(i) / 40.0;
        for j in 0..=800 {
            let m = m_lo + (m_hi - m_lo) * f64::from(j) / 800.0;
            let pt = model.speed_map().eval(m * per_map, w);
            let dm = pt.d_dflow * per_map;
            let dw = pt.d_domega;
            if dw > 0.0 {
                let r = dm / dw;
                if r > c1_min {
                    c1_min = r;
                    argmax = (m, w);
                }
            } else if dw < 0.0 {
                c1_max = c1_max.min(dm / dw);
            } else if dm >= 0.0 {
                c1_min = f64::INFINITY;
                argmax = (m, w);
            }
        }
    }
    Eq8Bound {
        c1_min,
        c1_max,
        argmax,
        region,
    }
}

/// Check eq. 8 for a configuration on the default operating region
/// ([`Eq8Region::default_for`]); eq. 9 holds by construction (K2 = K1 c1). For config
/// validation: returns the bound, or a setting error naming `c1_rad_s_per_kg_s`.
pub fn check_eq8(cfg: &DriveTorqueConfig, model: &ControlModel) -> Result<Eq8Bound, LawError> {
    let region = Eq8Region::default_for(model).ok_or_else(|| {
        setting(
            "c1_rad_s_per_kg_s",
            "the map has no surge point at nominal speed: no region for eq. 8".to_string(),
        )
    })?;
    let bound = eq8_bound(model, region);
    let c1 = cfg.c1_rad_s_per_kg_s;
    if bound.admits(c1) {
        Ok(bound)
    } else {
        Err(setting(
            "c1_rad_s_per_kg_s",
            format!(
                "{c1} violates seed 000 eq. 8 on flows {:.2}…{:.2} kg/s, speeds {:.0}…{:.0} rad/s: \
                 need {:.1} < c1 < {:.1}",
                region.flow_kg_s.0,
                region.flow_kg_s.1,
                region.omega_rad_s.0,
                region.omega_rad_s.1,
                bound.c1_min,
                bound.c1_max
            ),
        ))
    }
}

/// The sampled speed-tracking loop of eq. 7: with the command held over a control period h,
/// ω̄ evolves as ω̄(k+1) = (1 − K1 h/J) ω̄(k) (forward Euler of eq. 1c under τ̄d = −K1 ω̄), a pole
/// that stays inside the unit circle only for K1 h/J < 2 and is free of sign-alternating
/// ringing only for K1 h/J < 1. The continuous-time proof of Proposition 1 says nothing about
/// this; an unchecked K1 (the seed's 10 000 at 1 kHz on a 0.2 kg·m² rotor: K1 h/J = 50)
/// chatters the torque between the drive's limits. Returns K1 h/J, or a setting error naming
/// `k1_nm_s_rad` when K1 h/J ≥ 1.
pub fn check_sampled_speed_loop(
    cfg: &DriveTorqueConfig,
    inertia_kg_m2: f64,
    period_s: f64,
) -> Result<f64, LawError> {
    let k1 = cfg.k1_nm_s_rad;
    let ratio = k1 * period_s / inertia_kg_m2;
    if ratio.is_finite() && ratio < 1.0 {
        return Ok(ratio);
    }
    Err(setting(
        "k1_nm_s_rad",
        format!(
            "K1·h/J = {k1} × {:.3} ms / {inertia_kg_m2} kg·m² = {ratio:.2} ≥ 1: the sampled speed loop \
             of eq. 7 rings or diverges at this control period (Proposition 1 is continuous-time); \
             need K1 < J/h = {:.1} N·m·s/rad (about 0.7 J/h is a good start)",
            1e3 * period_s,
            inertia_kg_m2 / period_s
        ),
    ))
}

/// Every gain condition of the law that config validation checks: eq. 8 on the default
/// operating region ([`check_eq8`]) and the sampled speed loop, K1·h/J < 1
/// ([`check_sampled_speed_loop`]) at the control period `period_s`. The first failure is
/// returned.
pub fn check_gains(
    cfg: &DriveTorqueConfig,
    model: &ControlModel,
    period_s: f64,
) -> Result<Eq8Bound, LawError> {
    // (a machine without a shaft model cannot run this law at all: the law registry's
    // machine-data check reports that, not this one)
    if let Some(shaft) = model.shaft {
        check_sampled_speed_loop(cfg, shaft.inertia_kg_m2, period_s)?;
    }
    check_eq8(cfg, model)
}

/// The law's state.
#[derive(Debug, Clone)]
pub struct DriveTorque {
    c1: f64,
    k1: f64,
    k2: f64,
    flow: FlowInput,
    equilibrium: EquilibriumFlow,
    tau_eq_s: f64,
    filter_hz: f64,
    order: usize,
    limit_nm: f64,
    tau_transfer_s: f64,
    /// Low-pass sections on the flow deviation d = m̂ − m_out.
    lp: [f64; MAX_FILTER_ORDER],
    /// Slow bias b (m0 = m_out + b).
    bias: f64,
    /// Last valid outflow, kg/s (held while a valve position is missing).
    m_out_held: f64,
    /// Bumpless-transfer offset, N·m.
    offset_nm: f64,
    started: bool,
    /// Loop delay compensated, s (0: none).
    delay_s: f64,
    /// The machine model the predictor integrates (plenum/duct machines only).
    predictor: Option<PlenumDuctModel>,
}

fn setting(key: &str, message: String) -> LawError {
    LawError::Setting {
        law: LawId::DriveTorque,
        key: format!("drive_torque.{key}"),
        message,
    }
}

impl DriveTorque {
    /// Build for a machine. Checks that every setting is usable; eq. 8 depends on the region
    /// of operation and is checked by [`check_eq8`] (config validation).
    pub fn new(cfg: &DriveTorqueConfig, model: &ControlModel) -> Result<Self, LawError> {
        let positive = |key: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(v)
            } else {
                Err(setting(key, format!("must be a positive number, got {v}")))
            }
        };
        let non_negative = |key: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(v)
            } else {
                Err(setting(key, format!("must be ≥ 0, got {v}")))
            }
        };
        let c1 = positive("c1_rad_s_per_kg_s", cfg.c1_rad_s_per_kg_s)?;
        let k1 = positive("k1_nm_s_rad", cfg.k1_nm_s_rad)?;
        let tau_eq_s = positive(
            "equilibrium_time_constant_s",
            cfg.equilibrium_time_constant_s,
        )?;
        let filter_hz = non_negative("flow_filter_hz", cfg.flow_filter_hz)?;
        let tau_transfer_s = positive("transfer_time_constant_s", cfg.transfer_time_constant_s)?;
        let order = cfg.flow_filter_order as usize;
        if !(1..=MAX_FILTER_ORDER).contains(&order) {
            return Err(setting(
                "flow_filter_order",
                format!("must be 1..={MAX_FILTER_ORDER}, got {order}"),
            ));
        }
        let delay_s = 1e-3 * non_negative("delay_compensation_ms", cfg.delay_compensation_ms)?;
        let predictor = match (delay_s > 0.0, model.plenum_duct.zip(model.shaft)) {
            (false, _) => None,
            (true, Some((params, shaft))) => Some(PlenumDuctModel::new(
                params,
                *model.speed_map(),
                shaft,
                model.gas,
                model.orifice,
                (model.drive.min_torque_nm, model.drive.rated_torque_nm),
            )),
            (true, None) => {
                return Err(setting(
                    "delay_compensation_ms",
                    "the predictor needs the plenum/duct model (seed 000 plants); set 0".into(),
                ))
            }
        };
        let range = model.drive.rated_torque_nm - model.drive.min_torque_nm;
        let limit_nm = match non_negative("torque_limit_nm", cfg.torque_limit_nm)? {
            0.0 => range,
            v => v,
        };
        if !(limit_nm.is_finite() && limit_nm > 0.0) {
            return Err(setting(
                "torque_limit_nm",
                format!("the drive's torque range is {range} N·m: nothing to act with"),
            ));
        }
        Ok(DriveTorque {
            c1,
            k1,
            k2: k1 * c1, // eq. 9
            flow: cfg.flow,
            equilibrium: cfg.equilibrium_flow,
            tau_eq_s,
            filter_hz,
            order,
            limit_nm,
            tau_transfer_s,
            lp: [0.0; MAX_FILTER_ORDER],
            bias: 0.0,
            m_out_held: f64::NAN,
            offset_nm: 0.0,
            started: false,
            delay_s,
            predictor,
        })
    }

    /// The measurements the law acts on: as measured, or predicted over the loop delay.
    ///
    /// The sample is `sample_age_s` old and the torque computed now acts `delay_s` later: over
    /// those D = round((age + delay)/h) periods the commands of the last D cycles act (the
    /// core's [`LoopHistory`]). The
    /// predictor integrates seed 000 eq. 1 (the plant's own right-hand side, one RK4 step per
    /// period) from the measured plenum pressure and speed, the observer's flow and the
    /// measured throttle position (held: the process moves it, the controller cannot know
    /// how), and returns the measurements with the predicted pressure, speed and flow. None
    /// (use the measurements as they are) without a predictor or with an input or history
    /// missing.
    fn predicted(&mut self, inputs: &LawInputs<'_>, dt_s: f64) -> Option<Measurements> {
        let m = inputs.m;
        let model = self.predictor.as_mut()?;
        if dt_s.is_nan() || dt_s <= 0.0 {
            return None;
        }
        // from the sample to the moment the new command acts
        let horizon_s = inputs.history.sample_age_s + self.delay_s;
        let periods = ((horizon_s / dt_s).round() as usize).min(MAX_DELAY_PERIODS);
        let m_hat = match self.flow {
            FlowInput::Observer => m.m_observer_kg_s,
            FlowInput::Selected => m.m_kg_s,
            FlowInput::Measured => m.m_measured_kg_s,
        };
        let throttle = m.throttle_position;
        let mut x = SVector::<f64, PLENUM_N>::new(m.p_discharge_pa, m_hat, m.omega_rad_s, throttle);
        if periods == 0 || !x.iter().all(|v| v.is_finite()) {
            return None;
        }
        for age in (1..=periods).rev() {
            let torque = inputs.history.ago(age);
            if !torque.is_finite() {
                return None;
            }
            model.predict_step(&mut x, torque, throttle, dt_s);
        }
        if !x.iter().all(|v| v.is_finite()) {
            return None;
        }
        let mut p = *m;
        p.p_discharge_pa = x[0];
        p.omega_rad_s = x[2];
        match self.flow {
            FlowInput::Observer => p.m_observer_kg_s = x[1],
            FlowInput::Selected => p.m_kg_s = x[1],
            FlowInput::Measured => p.m_measured_kg_s = x[1],
        }
        Some(p)
    }

    /// c1, rad/s per kg/s.
    pub fn c1(&self) -> f64 {
        self.c1
    }

    /// K1, N·m per rad/s.
    pub fn k1(&self) -> f64 {
        self.k1
    }

    /// K2 = K1 c1 (eq. 9), N·m per kg/s.
    pub fn k2(&self) -> f64 {
        self.k2
    }

    /// The flow fed back, kg/s (the configured source, else the core's selection).
    fn flow_of(&self, inputs: &LawInputs<'_>) -> f64 {
        let m = inputs.m;
        let v = match self.flow {
            FlowInput::Observer => m.m_observer_kg_s,
            FlowInput::Selected => m.m_kg_s,
            FlowInput::Measured => m.m_measured_kg_s,
        };
        if v.is_finite() {
            v
        } else {
            m.m_kg_s
        }
    }

    /// The valve part of m0: m_out from the measured pressures and valve positions (held while
    /// a position is missing), or 0 for the washout construction.
    fn outflow(&mut self, inputs: &LawInputs<'_>) -> f64 {
        if self.equilibrium == EquilibriumFlow::Washout {
            return 0.0;
        }
        let m = inputs.m;
        let v = inputs.model.outflow_kg_s(
            m.p_suction_pa,
            m.p_discharge_pa,
            m.recycle_position,
            m.throttle_position,
        );
        if v.is_finite() {
            if self.started && !self.m_out_held.is_finite() {
                // the outflow appears after the start (a position was missing): shift the filter
                // states so that m̄ does not jump
                for y in self.lp.iter_mut() {
                    *y -= v;
                }
                self.bias -= v;
            }
            self.m_out_held = v;
        }
        self.m_out_held
    }

    /// Flow deviation d = m̂ − m_out before filtering, kg/s (NaN if no flow).
    fn deviation(&mut self, inputs: &LawInputs<'_>) -> f64 {
        let m_hat = self.flow_of(inputs);
        let m_out = self.outflow(inputs);
        if m_out.is_finite() {
            m_hat - m_out
        } else {
            // outflow never available: the washout construction
            m_hat
        }
    }
}

impl SurgeLaw for DriveTorque {
    fn start(&mut self, inputs: &LawInputs<'_>, current: &ActuatorCommands) {
        let d = self.deviation(inputs);
        let d = if d.is_finite() { d } else { 0.0 };
        self.lp = [d; MAX_FILTER_ORDER];
        self.bias = d; // m̄ = 0
        let w_bar = inputs.m.omega_rad_s - inputs.op.speed_setpoint_rad_s;
        let applied = current.get(ActuatorId::DriveTorque);
        let applied = if applied.is_finite() { applied } else { 0.0 };
        let speed_term = if w_bar.is_finite() {
            -self.k1 * w_bar
        } else {
            0.0
        };
        self.offset_nm = applied - speed_term;
        self.started = true;
    }

    fn update(&mut self, inputs: &LawInputs<'_>, dt_s: f64) -> LawOutput {
        if !self.started {
            self.start(inputs, &ActuatorCommands::default());
        }
        // over the loop delay, if one is compensated
        let predicted = self.predicted(inputs, dt_s);
        let inputs = &match &predicted {
            Some(m) => LawInputs { m, ..*inputs },
            None => *inputs,
        };
        let d = self.deviation(inputs);
        if d.is_finite() {
            // noise filter on d = m̂ − m_out
            let a = if self.filter_hz > 0.0 {
                1.0 - (-2.0 * std::f64::consts::PI * self.filter_hz * dt_s).exp()
            } else {
                1.0
            };
            let mut x = d;
            for y in self.lp.iter_mut().take(self.order) {
                *y += a * (x - *y);
                x = *y;
            }
            // slow bias of m0
            let b = 1.0 - (-dt_s / self.tau_eq_s).exp();
            self.bias += b * (x - self.bias);
        }
        let d_f = self.lp[self.order - 1];
        let m_bar = d_f - self.bias; // m̂ − m0
        let w_bar = inputs.m.omega_rad_s - inputs.op.speed_setpoint_rad_s;
        let speed_term = if w_bar.is_finite() {
            -self.k1 * w_bar
        } else {
            0.0
        };
        // eq. 7 / 22: τ̄d = −K1 ω̄ − K2 m̄, plus the decaying transfer offset
        let raw = speed_term - self.k2 * m_bar + self.offset_nm;
        let torque = raw.clamp(-self.limit_nm, self.limit_nm);
        self.offset_nm *= (-dt_s / self.tau_transfer_s).exp();
        let mut commands = ActuatorCommands::default();
        commands.set(ActuatorId::DriveTorque, torque);
        LawOutput {
            commands,
            diagnostic: m_bar,
            event: None,
        }
    }
}

impl LawSpec for DriveTorque {
    type Settings = DriveTorqueConfig;
    const NEEDS: LawNeeds = LawNeeds {
        summary: "active surge control with the drive torque (seed 000 eq. 7, 22)",
        actuators: ActuatorSet::of(&[ActuatorId::DriveTorque]),
        sensors: &[SensorId::ShaftSpeed],
        needs_flow: true,
        machine_data: &[
            MachineData::SpeedLineMap,
            MachineData::OwnedDrive,
            MachineData::Model(ModelKind::PlenumDuct),
        ],
        model_family: Some(ModelKind::PlenumDuct),
    };
    fn build(settings: &Self::Settings, model: &ControlModel) -> Result<Self, LawError> {
        DriveTorque::new(settings, model)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::measurements::{Measurements, OperatorInputs};

    #[test]
    fn defaults_are_the_seed_gains_and_k2_follows_eq9() {
        let c = DriveTorqueConfig::default();
        assert_eq!(c.c1_rad_s_per_kg_s, 100.0);
        assert_eq!(c.k1_nm_s_rad, 10_000.0);
        assert_eq!(c.k2_nm_s_kg(), 1.0e6);
    }

    fn bohagen() -> ControlModel {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("config/plants/bohagen2007_plenum.toml");
        let desc = crate::sim::case::PlantCase::load(&path).expect("plant");
        crate::sim::control_model(&desc)
    }

    fn measurements(m_hat: f64, throttle: f64, omega: f64) -> Measurements {
        Measurements {
            t_s: 0.0,
            p_suction_pa: 1.0e5,
            p_discharge_pa: 2.06e5,
            omega_rad_s: omega,
            t_suction_k: 293.15,
            m_kg_s: m_hat,
            m_measured_kg_s: m_hat,
            m_observer_kg_s: m_hat,
            flow_map: m_hat,
            pressure_ratio: 2.06,
            recycle_position: f64::NAN,
            throttle_position: throttle,
            thrust_position_m: f64::NAN,
            dp_suction_dt_pa_s: 0.0,
            dp_discharge_dt_pa_s: 0.0,
            flow_fallback: false,
        }
    }

    fn op(omega: f64) -> OperatorInputs {
        OperatorInputs {
            speed_setpoint_rad_s: omega,
            throttle_demand: f64::NAN,
            flow_setpoint_kg_s: f64::NAN,
            recycle_manual: f64::NAN,
        }
    }

    #[test]
    fn first_output_is_the_applied_one_and_law_is_zero_at_steady_state() {
        let model = bohagen();
        let cfg = model.controller.drive_torque.clone();
        let mut law = DriveTorque::new(&cfg, &model).expect("law");
        // speed 10 rad/s above the setpoint, 25 N·m applied by the previous law
        let m = measurements(2.66, 0.2, 2523.3);
        let o = op(2513.3);
        let inputs = LawInputs {
            m: &m,
            op: &o,
            model: &model,
            history: &crate::control::law::api::LoopHistory::EMPTY,
        };
        let mut cur = ActuatorCommands::default();
        cur.set(ActuatorId::DriveTorque, 25.0);
        law.start(&inputs, &cur);
        let t0 = law
            .update(&inputs, 1e-3)
            .commands
            .get(ActuatorId::DriveTorque);
        assert!((t0 - 25.0).abs() < 1e-9, "{t0}");
        // held at the speed setpoint with a steady flow: the output decays to zero (m̄ = 0,
        // ω̄ = 0, transfer offset gone)
        let m = measurements(2.66, 0.2, 2513.3);
        let inputs = LawInputs {
            m: &m,
            op: &o,
            model: &model,
            history: &crate::control::law::api::LoopHistory::EMPTY,
        };
        let mut t = f64::NAN;
        for _ in 0..10_000 {
            t = law
                .update(&inputs, 1e-3)
                .commands
                .get(ActuatorId::DriveTorque);
        }
        assert!(t.abs() < 1e-3, "{t}");
    }

    #[test]
    fn flow_deviation_does_not_jump_when_the_valve_position_appears() {
        let model = bohagen();
        let cfg = model.controller.drive_torque.clone();
        let mut law = DriveTorque::new(&cfg, &model).expect("law");
        let o = op(2513.3);
        let m = measurements(2.66, f64::NAN, 2513.3);
        let inputs = LawInputs {
            m: &m,
            op: &o,
            model: &model,
            history: &crate::control::law::api::LoopHistory::EMPTY,
        };
        law.start(&inputs, &ActuatorCommands::default());
        let before = law.update(&inputs, 1e-3);
        let m = measurements(2.66, 0.2, 2513.3);
        let inputs = LawInputs {
            m: &m,
            op: &o,
            model: &model,
            history: &crate::control::law::api::LoopHistory::EMPTY,
        };
        let after = law.update(&inputs, 1e-3);
        assert!(before.diagnostic.abs() < 1e-12);
        assert!(
            after.diagnostic.abs() < 1e-12,
            "m̄ jumped to {}",
            after.diagnostic
        );
        let t = after.commands.get(ActuatorId::DriveTorque);
        assert!(t.abs() < 1e-6, "{t}");
    }

    #[test]
    fn check_eq8_rejects_the_seed_c1_on_this_map() {
        let model = bohagen();
        let e = check_eq8(&DriveTorqueConfig::default(), &model).unwrap_err();
        assert!(e.to_string().contains("c1_rad_s_per_kg_s"), "{e}");
        assert!(e.to_string().contains("141"), "{e}");
        let b = check_eq8(&model.controller.drive_torque, &model).expect("tuned c1 passes");
        assert!(b.c1_min > 140.0 && b.c1_min < 142.0);
    }

    #[test]
    fn config_parses_with_units_and_rejects_unknown_keys() {
        let c: DriveTorqueConfig = toml::from_str(
            "c1_rad_s_per_kg_s = 180.0\nflow = \"selected\"\nequilibrium_flow = \"washout\"\n",
        )
        .expect("parse");
        assert_eq!(c.c1_rad_s_per_kg_s, 180.0);
        assert_eq!(c.flow, FlowInput::Selected);
        assert_eq!(c.equilibrium_flow, EquilibriumFlow::Washout);
        assert_eq!(c.k1_nm_s_rad, 10_000.0);
        assert!(toml::from_str::<DriveTorqueConfig>("k2 = 500.0\n").is_err());
    }

    #[test]
    fn sampled_speed_loop_needs_k1_h_over_j_below_one() {
        let mut c = DriveTorqueConfig {
            k1_nm_s_rad: 140.0,
            ..DriveTorqueConfig::default()
        };
        let r = check_sampled_speed_loop(&c, 0.2, 1e-3).expect("0.7 is fine");
        assert!((r - 0.7).abs() < 1e-12);
        c.k1_nm_s_rad = 200.0; // exactly 1: refused
        let e = check_sampled_speed_loop(&c, 0.2, 1e-3)
            .unwrap_err()
            .to_string();
        assert!(e.contains("k1_nm_s_rad") && e.contains("K1·h/J"), "{e}");
        c.k1_nm_s_rad = 400.0;
        assert!(check_sampled_speed_loop(&c, 0.2, 1e-3).is_err());
        // the same K1 is fine at 10 kHz
        assert!(check_sampled_speed_loop(&c, 0.2, 1e-4).is_ok());
        // the seed's K1 = 10 000
        c.k1_nm_s_rad = 10_000.0;
        assert!(check_sampled_speed_loop(&c, 0.2, 1e-3).is_err());
    }
}
