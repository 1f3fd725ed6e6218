//! Nondimensional spool model (seed 003 eq. 4–6):
//!
//! ```text
//! dω̃/dτ = ā (τ_t − Γ(φ, ω̃)),     Γ = σ φ ω̃          (4)
//! dφ/dτ = b̄ (ψc(φ, ω̃) − ψ + u₂)                       (5), u₂ = close-coupled valve
//! dψ/dτ = c̄ (φ − F(γ, ψ)),        F = γ √ψ             (6)
//! ```
//! τ is nondimensional time (τ = t / time_scale_s). ψc is the Moore–Greitzer cubic with the
//! speed scaling of the other plants, in pressure-rise form. The plant reports SI values
//! through its scales: p_d = p01 + ψ·pressure_scale, m = φ·flow_scale, ω = ω̃·speed_scale,
//! torque = τ·torque_scale; its SI compressor map is the exact image of ψc.
//! State x = (ω̃, φ, ψ, throttle position).
//!
//! Optional matched uncertainty (seed 003 eq. 38, 41–42, 53; off unless
//! `spool.uncertainty_amplitude` ≠ 0): Δf = ΔCss = A sin(k x₂) is added to eq. 4 as ā Δf and to
//! eq. 5 as b̄ ΔCss. x₂ = φ − φ⁰, where φ⁰ is the steady state of the *nominal* model at the
//! plant's current throttle position and nominal speed (rightmost root, recomputed at the start
//! of each step when the throttle moved): the uncertainty vanishes at the nominal equilibrium,
//! as eq. 53 does at x = 0, and the plant does not need to know any controller's x⁰.

use super::file::{MapSpec, PlantDescription, SpoolParams};
use super::{sensor_snapshot, PlantError, PlantInputs, PlantTruth};
use crate::physics::characteristic::{MapPoint, MooreGreitzerCubic};
use crate::physics::compressor_map::CompressorMap;
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;
use crate::physics::spool_throttle::throttle_function;
use crate::solver::{self, OdeSystem, StepSettings};
use crate::vocab::signals::{ActuatorId, SensorSnapshot};
use nalgebra::SVector;

/// State dimension.
pub const N: usize = 4;

/// Seed 003 plant.
#[derive(Debug, Clone)]
pub struct SpoolPlant {
    /// Parameters and scales.
    pub params: SpoolParams,
    /// Nondimensional characteristic ψc(φ, ω̃) (pressure-rise form).
    pub cubic: MooreGreitzerCubic,
    /// The SI image of ψc (pressure ratio versus kg/s and rad/s).
    pub map: CompressorMap,
    /// Gas (for the orifice reading).
    pub gas: Gas,
    /// Orifice.
    pub orifice: Orifice,
    /// Torque limits, nondimensional (min, max).
    pub torque_limits: (f64, f64),
    /// Integration settings.
    pub settings: StepSettings,
    /// State (ω̃, φ, ψ, throttle position).
    pub x: SVector<f64, N>,
    /// Time, s.
    pub t_s: f64,
    /// Step size carried between periods by adaptive integration, s.
    pub h_state_s: f64,
    torque: f64,
    ccv: f64,
    throttle_cmd: f64,
    /// Nominal speed, units of speed_scale.
    omega_nominal: f64,
    /// φ⁰ of the uncertainty term (nominal steady state at `phi_ref_throttle`).
    phi_ref: f64,
    /// Throttle position `phi_ref` was computed for.
    phi_ref_throttle: f64,
}

/// Steady-state speed of the spool model: the nominal drive speed in units of speed_scale.
fn nominal_speed(desc: &PlantDescription, p: &SpoolParams) -> f64 {
    desc.file.drive.nominal_speed_rad_s / p.speed_scale_rad_s
}

impl SpoolPlant {
    /// Build at the steady state for `inputs` at nominal speed.
    pub fn new(desc: &PlantDescription, inputs: &PlantInputs) -> Result<Self, PlantError> {
        let f = &desc.file;
        let params = f.spool.expect("validated: spool present");
        let cubic = match f.map {
            MapSpec::Cubic {
                psi_c0,
                semi_height,
                semi_width,
                omega_ref_rad_s,
                ..
            } => MooreGreitzerCubic {
                psi_c0,
                semi_height,
                semi_width,
                omega_ref: omega_ref_rad_s,
            },
            MapSpec::Table { .. } => return Err(PlantError::NoEquilibrium {
                plant: f.name.clone(),
                what: "a tabulated map (the spool model needs [map.cubic] in nondimensional units)"
                    .into(),
            }),
        };
        let map = si_map(&cubic, &params).map_err(|m| PlantError::NoEquilibrium {
            plant: f.name.clone(),
            what: m,
        })?;
        let ts = params.torque_scale_nm;
        let mut plant = SpoolPlant {
            params,
            cubic,
            map,
            gas: f.gas,
            orifice: f.orifice,
            torque_limits: (f.drive.min_torque_nm / ts, f.drive.rated_torque_nm / ts),
            settings: f.integration,
            x: SVector::zeros(),
            t_s: 0.0,
            h_state_s: 0.0,
            torque: 0.0,
            ccv: 0.0,
            throttle_cmd: inputs.throttle_target(),
            omega_nominal: nominal_speed(desc, &params),
            phi_ref: 0.0,
            phi_ref_throttle: f64::NAN,
        };
        let w0 = plant.omega_nominal;
        let eq = plant
            .equilibria(inputs.throttle_target(), w0)
            .into_iter()
            .last()
            .ok_or_else(|| PlantError::NoEquilibrium {
                plant: f.name.clone(),
                what: format!("throttle {:.3}", inputs.throttle_target()),
            })?;
        plant.x = eq;
        plant.torque = plant.params.torque_coefficient * eq[1] * eq[0];
        plant.update_uncertainty_reference();
        Ok(plant)
    }

    /// Rightmost steady-state flow of the nominal model at a throttle opening and speed ω̃
    /// (seed 003 eq. 8–9: F(γ, ψc(φ, ω̃)) = φ), without allocation: scan down from four times
    /// the peak flow for the first sign change, then bisect.
    pub fn operating_flow(&self, throttle: f64, omega: f64) -> f64 {
        let gamma = self.params.gamma_max * throttle.clamp(0.0, 1.0);
        let r = |phi: f64| throttle_function(gamma, self.psi_c(phi, omega).value) - phi;
        let hi = 4.0 * self.cubic.peak(omega, 0.0).0.max(1e-6);
        let n = 200;
        let (mut a, mut b) = (0.0, hi);
        for i in (0..n).rev() {
            let phi = hi * i as f64 / n as f64;
            if r(phi) >= 0.0 {
                a = phi;
                b = hi * (i + 1) as f64 / n as f64;
                break;
            }
        }
        for _ in 0..60 {
            let m = 0.5 * (a + b);
            if r(m) >= 0.0 {
                a = m;
            } else {
                b = m;
            }
        }
        0.5 * (a + b)
    }

    /// Recompute φ⁰ of the uncertainty term if the throttle moved (no-op when it is off).
    fn update_uncertainty_reference(&mut self) {
        if self.params.uncertainty_amplitude == 0.0 || self.x[3] == self.phi_ref_throttle {
            return;
        }
        self.phi_ref_throttle = self.x[3];
        self.phi_ref = self.operating_flow(self.x[3], self.omega_nominal);
    }

    /// The matched uncertainty Δf = ΔCss = A sin(k (φ − φ⁰)) of seed 003 eq. 53 (0 when off).
    #[inline]
    pub fn uncertainty(&self, phi: f64) -> f64 {
        let p = &self.params;
        if p.uncertainty_amplitude == 0.0 {
            return 0.0;
        }
        p.uncertainty_amplitude * (p.uncertainty_frequency * (phi - self.phi_ref)).sin()
    }

    /// ψc and its partial derivatives (nondimensional).
    #[inline]
    pub fn psi_c(&self, phi: f64, omega: f64) -> MapPoint {
        self.cubic.eval(phi, omega, 0.0)
    }

    /// Steady states at speed ω̃ and throttle opening, ordered by flow.
    pub fn equilibria(&self, throttle: f64, omega: f64) -> Vec<SVector<f64, N>> {
        let gamma = self.params.gamma_max * throttle;
        let resid = |phi: f64| throttle_function(gamma, self.psi_c(phi, omega).value) - phi;
        let hi = 4.0 * self.cubic.peak(omega, 0.0).0.max(1e-6);
        super::analysis::roots_1d(resid, 1e-6 * hi, hi, 4000)
            .into_iter()
            .map(|phi| SVector::<f64, N>::new(omega, phi, self.psi_c(phi, omega).value, throttle))
            .collect()
    }

    /// Steady states at constant nondimensional drive torque τ (open loop, seed 003: τ_t = τ0):
    /// speed is an unknown too, fixed by Γ(φ, ω̃) = τ. Ordered by flow.
    pub fn equilibria_at_torque(&self, throttle: f64, torque: f64) -> Vec<SVector<f64, N>> {
        let sigma = self.params.torque_coefficient;
        let n = 400;
        let grid: Vec<(f64, Vec<SVector<f64, N>>)> = (0..=n)
            .map(|k| {
                let w = 0.2 + 2.3 * k as f64 / n as f64;
                (w, self.equilibria(throttle, w))
            })
            .collect();
        let mut out = Vec::new();
        for win in grid.windows(2) {
            let ((w0, e0), (w1, e1)) = (&win[0], &win[1]);
            if e0.len() != e1.len() {
                continue;
            }
            for i in 0..e0.len() {
                let f = |x: &SVector<f64, N>| sigma * x[1] * x[0] - torque;
                if f(&e0[i]) * f(&e1[i]) > 0.0 {
                    continue;
                }
                // bisect on speed along branch i
                let (mut a, mut b) = (*w0, *w1);
                let fa0 = f(&e0[i]);
                let mut fa = fa0;
                let mut best = e0[i];
                for _ in 0..80 {
                    let m = 0.5 * (a + b);
                    let em = self.equilibria(throttle, m);
                    if em.len() != e0.len() {
                        break;
                    }
                    let fm = f(&em[i]);
                    best = em[i];
                    if fa * fm <= 0.0 {
                        b = m;
                    } else {
                        a = m;
                        fa = fm;
                    }
                    if b - a < 1e-12 {
                        break;
                    }
                }
                out.push(best);
            }
        }
        out.sort_by(|a, b| a[1].total_cmp(&b[1]));
        out.dedup_by(|a, b| (a[1] - b[1]).abs() < 1e-9);
        out
    }

    /// Advance by `dt_s` (seconds) with `inputs` held.
    pub fn step(&mut self, inputs: &PlantInputs, dt_s: f64) {
        let (lo, hi) = self.torque_limits;
        let ts = self.params.torque_scale_nm;
        self.torque = inputs.drive_torque(lo * ts, hi * ts, self.torque * ts) / ts;
        let lim = self.params.ccv_max;
        self.ccv = inputs
            .command_or(ActuatorId::CloseCoupledValve, 0.0)
            .clamp(-lim, lim);
        self.throttle_cmd = inputs.throttle_target();
        self.update_uncertainty_reference();
        let mut x = self.x;
        let mut h = self.h_state_s;
        solver::advance_adaptive(self, self.settings, self.t_s, &mut x, dt_s, &mut h);
        self.h_state_s = h;
        self.x = x;
        self.t_s += dt_s;
    }

    /// True state in SI units.
    pub fn truth(&self) -> PlantTruth {
        let p = &self.params;
        let x = &self.x;
        let gamma = p.gamma_max * x[3];
        PlantTruth {
            m_kg_s: x[1] * p.flow_scale_kg_s,
            flow_map: x[1] * p.flow_scale_kg_s,
            p_suction_pa: p.ambient_pressure_pa,
            p_discharge_pa: p.ambient_pressure_pa + x[2] * p.pressure_scale_pa,
            omega_rad_s: x[0] * p.speed_scale_rad_s,
            t_suction_k: p.ambient_temperature_k,
            throttle_flow_kg_s: throttle_function(gamma, x[2]) * p.flow_scale_kg_s,
            throttle_position: x[3],
            drive_torque_nm: self.torque * p.torque_scale_nm,
            load_torque_nm: p.torque_coefficient * x[1] * x[0] * p.torque_scale_nm,
            ccv: self.ccv,
            ..PlantTruth::NAN
        }
    }

    /// Field instrument readings.
    pub fn sensors(&self) -> SensorSnapshot {
        let t = self.truth();
        let dp = self
            .orifice
            .dp_pa(&self.gas, t.m_kg_s, t.p_suction_pa, t.t_suction_k);
        sensor_snapshot(&t, dp)
    }

    /// Set held inputs without stepping (for analysis): nondimensional torque and CCV.
    pub fn hold_inputs(&mut self, torque: f64, ccv: f64, throttle_cmd: f64) {
        self.torque = torque;
        self.ccv = ccv;
        self.throttle_cmd = throttle_cmd;
    }
}

/// The SI image of the nondimensional cubic (the machine description's
/// [`SpoolParams::si_map`], kept here for the plant's callers).
pub fn si_map(cubic: &MooreGreitzerCubic, p: &SpoolParams) -> Result<CompressorMap, String> {
    p.si_map(cubic)
}

impl OdeSystem<N> for SpoolPlant {
    #[inline]
    fn rhs(&self, _t: f64, x: &SVector<f64, N>) -> SVector<f64, N> {
        let p = &self.params;
        let (w, phi, psi, l) = (x[0], x[1], x[2], x[3]);
        let inv_t = 1.0 / p.time_scale_s;
        let gamma = p.gamma_max * l;
        let delta = self.uncertainty(phi); // eq. 53 (0 unless enabled): ā Δf in (4), b̄ ΔCss in (5)
        SVector::<f64, N>::new(
            inv_t * p.a_bar * (self.torque - p.torque_coefficient * phi * w + delta), // seed 003 eq. 4
            inv_t * p.b_bar * (self.psi_c(phi, w).value - psi + self.ccv + delta),    // eq. 5
            inv_t * p.c_bar * (phi - throttle_function(gamma, psi)),                  // eq. 6
            p.throttle.positioner_rate(self.throttle_cmd, l),
        )
    }

    fn project(&self, x: &mut SVector<f64, N>) {
        x[3] = x[3].clamp(0.0, 1.0);
        x[0] = x[0].max(0.0);
    }
}
