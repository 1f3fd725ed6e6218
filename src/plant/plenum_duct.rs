//! Plenum/duct/shaft plant (seed 000 eq. 1):
//!
//! ```text
//! ṗ = a01²/Vp (m − m_t)                 (1a)
//! ṁ = A1/Lc (Ψc(m, ω) p01 − p)          (1b)
//! ω̇ = (τd − τc)/J,  τc = |m| r2² σ ω    (1c)
//! m_t = k_t √(p − p01)                   throttle, with k_t ∝ opening
//! ```
//! plus the throttle positioner. State x = (p Pa, m kg/s, ω rad/s, throttle position).

use super::file::{PlantDescription, PlenumDuctParams};
use super::{sensor_snapshot, PlantError, PlantInputs, PlantTruth};
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;
use crate::physics::shaft::Shaft;
use crate::signals::SensorSnapshot;
use crate::solver::{self, OdeSystem, StepSettings};
use nalgebra::SVector;

/// State dimension.
pub const N: usize = 4;

/// Throttle flow to ambient: see [`PlenumDuctParams::throttle_flow_kg_s`], kg/s.
#[inline]
pub fn throttle_flow_kg_s(pp: &PlenumDuctParams, gas: &Gas, p_pa: f64, position: f64) -> f64 {
    pp.throttle_flow_kg_s(gas, p_pa, position)
}

/// Seed 000 plant.
#[derive(Debug, Clone)]
pub struct PlenumDuctPlant {
    /// Parameters.
    pub params: PlenumDuctParams,
    /// Compressor map.
    pub map: CompressorMap,
    /// Shaft.
    pub shaft: Shaft,
    /// Gas.
    pub gas: Gas,
    /// Orifice.
    pub orifice: Orifice,
    /// Drive torque limits (min, max), N·m.
    pub torque_limits_nm: (f64, f64),
    /// Integration settings.
    pub settings: StepSettings,
    /// State (p, m, ω, throttle position).
    pub x: SVector<f64, N>,
    /// Time, s.
    pub t_s: f64,
    /// Step size carried between periods by adaptive integration, s.
    pub h_state_s: f64,
    // inputs held over the current step
    torque_nm: f64,
    throttle_cmd: f64,
}

impl PlenumDuctPlant {
    /// Build at the steady state for `inputs` at nominal speed.
    pub fn new(desc: &PlantDescription, inputs: &PlantInputs) -> Result<Self, PlantError> {
        let f = &desc.file;
        let params = f
            .plenum_duct
            .expect("validated: plenum_duct section present");
        let mut plant = PlenumDuctPlant {
            params,
            map: desc.map,
            shaft: f.shaft,
            gas: f.gas,
            orifice: f.orifice,
            torque_limits_nm: (f.drive.min_torque_nm, f.drive.rated_torque_nm),
            settings: f.integration,
            x: SVector::zeros(),
            t_s: 0.0,
            h_state_s: 0.0,
            torque_nm: 0.0,
            throttle_cmd: inputs.throttle_target(),
        };
        let omega = f.drive.nominal_speed_rad_s;
        let eq = plant
            .equilibria(inputs.throttle_target(), omega)
            .into_iter()
            .last()
            .ok_or_else(|| PlantError::NoEquilibrium {
                plant: f.name.clone(),
                what: format!("throttle {:.3} at {omega} rad/s", inputs.throttle_target()),
            })?;
        plant.x = eq;
        plant.torque_nm = plant.shaft.load_torque_nm(eq[1], omega);
        Ok(plant)
    }

    #[inline]
    fn map_flow(&self, m: f64) -> f64 {
        match self.map.flow_coordinate {
            FlowCoordinate::MassKgS => m,
            FlowCoordinate::InletVolumeM3S => {
                m / self.gas.density_kg_m3(
                    self.params.ambient_pressure_pa,
                    self.params.ambient_temperature_k,
                )
            }
        }
    }

    /// The model without a state, for the controller's delay predictor (the same eq. 1 the
    /// simulated plant integrates, built from the controller's own plant description).
    pub fn for_prediction(
        params: PlenumDuctParams,
        map: CompressorMap,
        shaft: Shaft,
        gas: Gas,
        orifice: Orifice,
        torque_limits_nm: (f64, f64),
    ) -> Self {
        PlenumDuctPlant {
            params,
            map,
            shaft,
            gas,
            orifice,
            torque_limits_nm,
            settings: StepSettings::default(),
            x: SVector::zeros(),
            t_s: 0.0,
            h_state_s: 0.0,
            torque_nm: 0.0,
            throttle_cmd: 0.0,
        }
    }

    /// Advance the state `x` (p, m, ω, throttle position) by `h_s` with the drive torque and
    /// the throttle target held: one classical RK4 step (fixed work, for the control cycle).
    #[inline]
    pub fn predict_step(
        &mut self,
        x: &mut SVector<f64, N>,
        torque_nm: f64,
        throttle_target: f64,
        h_s: f64,
    ) {
        let (lo, hi) = self.torque_limits_nm;
        self.torque_nm = torque_nm.clamp(lo, hi);
        self.throttle_cmd = throttle_target;
        *x = solver::rk4::step(self, 0.0, x, h_s);
        self.project(x);
    }

    /// Throttle flow m_t at plenum pressure p and stem position l, kg/s.
    #[inline]
    pub fn throttle_flow(&self, p_pa: f64, position: f64) -> f64 {
        throttle_flow_kg_s(&self.params, &self.gas, p_pa, position)
    }

    /// All steady states at speed ω and throttle opening `throttle`, ordered by flow (the last
    /// one is the rightmost, normally stable, operating point). State vectors include the
    /// throttle position.
    pub fn equilibria(&self, throttle: f64, omega: f64) -> Vec<SVector<f64, N>> {
        let p01 = self.params.ambient_pressure_pa;
        // residual in m: throttle flow at the compressor's pressure minus m
        let resid = |m: f64| {
            let p = self.map.eval(self.map_flow(m), omega).value * p01;
            self.throttle_flow(p, throttle) - m
        };
        let m_hi = 4.0
            * self.map.surge_line.flow_at_speed(omega).max(1e-6)
            * match self.map.flow_coordinate {
                FlowCoordinate::MassKgS => 1.0,
                FlowCoordinate::InletVolumeM3S => self
                    .gas
                    .density_kg_m3(p01, self.params.ambient_temperature_k),
            };
        super::analysis::roots_1d(resid, 1e-6 * m_hi, m_hi, 2000)
            .into_iter()
            .map(|m| {
                let p = self.map.eval(self.map_flow(m), omega).value * p01;
                SVector::<f64, N>::new(p, m, omega, throttle)
            })
            .collect()
    }

    /// Advance by `dt_s` with `inputs` held.
    pub fn step(&mut self, inputs: &PlantInputs, dt_s: f64) {
        let (lo, hi) = self.torque_limits_nm;
        self.torque_nm = inputs.drive_torque(lo, hi, self.torque_nm);
        self.throttle_cmd = inputs.throttle_target();
        let mut x = self.x;
        let mut h = self.h_state_s;
        solver::advance_adaptive(self, self.settings, self.t_s, &mut x, dt_s, &mut h);
        self.h_state_s = h;
        self.x = x;
        self.t_s += dt_s;
    }

    /// True state.
    pub fn truth(&self) -> PlantTruth {
        let x = &self.x;
        let p01 = self.params.ambient_pressure_pa;
        PlantTruth {
            m_kg_s: x[1],
            flow_map: self.map_flow(x[1]),
            p_suction_pa: p01,
            p_discharge_pa: x[0],
            omega_rad_s: x[2],
            t_suction_k: self.params.ambient_temperature_k,
            throttle_flow_kg_s: self.throttle_flow(x[0], x[3]),
            throttle_position: x[3],
            drive_torque_nm: self.torque_nm,
            load_torque_nm: self.shaft.load_torque_nm(x[1], x[2]),
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

    /// Set the held inputs without stepping (for analysis).
    pub fn hold_inputs(&mut self, torque_nm: f64, throttle_cmd: f64) {
        self.torque_nm = torque_nm;
        self.throttle_cmd = throttle_cmd;
    }
}

impl OdeSystem<N> for PlenumDuctPlant {
    #[inline]
    fn rhs(&self, _t: f64, x: &SVector<f64, N>) -> SVector<f64, N> {
        let pp = &self.params;
        let (p, m, omega, l) = (x[0], x[1], x[2], x[3]);
        let m_t = self.throttle_flow(p, l);
        let psi = self.map.eval(self.map_flow(m), omega).value;
        let a2_v = pp.sonic_velocity_m_s * pp.sonic_velocity_m_s / pp.plenum_volume_m3;
        SVector::<f64, N>::new(
            a2_v * (m - m_t), // seed 000 eq. 1a
            pp.duct_area_m2 / pp.duct_length_m * (psi * pp.ambient_pressure_pa - p), // eq. 1b
            self.shaft.acceleration_rad_s2(self.torque_nm, m, omega), // eq. 1c
            pp.throttle.positioner_rate(self.throttle_cmd, l),
        )
    }

    fn project(&self, x: &mut SVector<f64, N>) {
        x[3] = x[3].clamp(0.0, 1.0);
        x[2] = x[2].max(0.0);
    }
}
