//! Plenum/duct/shaft plant (seed 000 eq. 1): the model of [`crate::machine::plenum_duct`]
//! (one copy, shared with the controller's delay predictor) integrated with adaptive steps,
//! started at a steady state, with its field instruments.

use super::file::{PlantDescription, PlenumDuctParams};
use super::{sensor_snapshot, PlantError, PlantInputs, PlantTruth};
pub use crate::machine::plenum_duct::{PlenumDuctModel, N};
use crate::physics::compressor_map::FlowCoordinate;
use crate::physics::gas::Gas;
use crate::solver::{self, StepSettings};
use crate::vocab::signals::SensorSnapshot;
use nalgebra::SVector;

/// Throttle flow to ambient: see [`PlenumDuctParams::throttle_flow_kg_s`], kg/s.
#[inline]
pub fn throttle_flow_kg_s(pp: &PlenumDuctParams, gas: &Gas, p_pa: f64, position: f64) -> f64 {
    pp.throttle_flow_kg_s(gas, p_pa, position)
}

/// Seed 000 plant: the model (its fields read through `Deref`) and the integration state.
#[derive(Debug, Clone)]
pub struct PlenumDuctPlant {
    /// The model, seed 000 eq. 1.
    pub model: PlenumDuctModel,
    /// Integration settings.
    pub settings: StepSettings,
    /// State (p, m, ω, throttle position).
    pub x: SVector<f64, N>,
    /// Time, s.
    pub t_s: f64,
    /// Step size carried between periods by adaptive integration, s.
    pub h_state_s: f64,
}

impl std::ops::Deref for PlenumDuctPlant {
    type Target = PlenumDuctModel;
    fn deref(&self) -> &PlenumDuctModel {
        &self.model
    }
}

impl PlenumDuctPlant {
    /// Build at the steady state for `inputs` at nominal speed.
    pub fn new(desc: &PlantDescription, inputs: &PlantInputs) -> Result<Self, PlantError> {
        let f = &desc.file;
        let params = f
            .plenum_duct
            .expect("validated: plenum_duct section present");
        let mut model = PlenumDuctModel::new(
            params,
            desc.map,
            f.shaft,
            f.gas,
            f.orifice,
            (f.drive.min_torque_nm, f.drive.rated_torque_nm),
        );
        model.throttle_cmd = inputs.throttle_target();
        let mut plant = PlenumDuctPlant {
            model,
            settings: f.integration,
            x: SVector::zeros(),
            t_s: 0.0,
            h_state_s: 0.0,
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
        plant.model.torque_nm = plant.shaft.load_torque_nm(eq[1], omega);
        Ok(plant)
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
        self.model.torque_nm = inputs.drive_torque(lo, hi, self.model.torque_nm);
        self.model.throttle_cmd = inputs.throttle_target();
        let mut x = self.x;
        let mut h = self.h_state_s;
        solver::advance_adaptive(&self.model, self.settings, self.t_s, &mut x, dt_s, &mut h);
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
        self.model.torque_nm = torque_nm;
        self.model.throttle_cmd = throttle_cmd;
    }
}
