//! Plenum/duct plant with tip-clearance actuation at constant speed (seed 004 eq. 4):
//!
//! ```text
//! Ṗ = a01²/Vp (m − m_th)                              (4a)
//! ṁ = A/Lc (ψ(ψ_ss(m), u) P01 − P)                    (4b), ψ from eq. 3 (sign corrected)
//! u = clearance change delivered by the thrust-bearing servo (3rd-order Butterworth)
//! ```
//! The speed is held by the drive's speed controller (seed 004: "effects of rotor speed
//! variations are ignored"). State x = (P, m, servo position, velocity, acceleration, throttle).

use super::file::{PlantDescription, ThrustRating, TipClearanceParams};
use super::{sensor_snapshot, PlantError, PlantInputs, PlantTruth};
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;
use crate::physics::shaft::Shaft;
use crate::solver::{self, OdeSystem, StepSettings};
use crate::vocab::signals::{ActuatorId, SensorSnapshot};
use nalgebra::SVector;

/// State dimension.
pub const N: usize = 6;

/// Throttle flow to ambient: see [`TipClearanceParams::throttle_flow_kg_s`], kg/s.
#[inline]
pub fn throttle_flow_kg_s(pp: &TipClearanceParams, gas: &Gas, p_pa: f64, position: f64) -> f64 {
    pp.throttle_flow_kg_s(gas, p_pa, position)
}

/// Seed 004 plant.
#[derive(Debug, Clone)]
pub struct TipClearancePlant {
    /// Parameters.
    pub params: TipClearanceParams,
    /// Thrust bearing rating.
    pub rating: ThrustRating,
    /// Compressor map (steady-state characteristic ψ_ss).
    pub map: CompressorMap,
    /// Gas.
    pub gas: Gas,
    /// Orifice.
    pub orifice: Orifice,
    /// Shaft (for the load-torque figure only).
    pub shaft: Shaft,
    /// Constant speed, rad/s.
    pub omega_rad_s: f64,
    /// Integration settings.
    pub settings: StepSettings,
    /// State.
    pub x: SVector<f64, N>,
    /// Time, s.
    pub t_s: f64,
    /// Step size carried between periods by adaptive integration, s.
    pub h_state_s: f64,
    clearance_cmd_m: f64,
    throttle_cmd: f64,
}

impl TipClearancePlant {
    /// Build at the steady state for `inputs`.
    pub fn new(desc: &PlantDescription, inputs: &PlantInputs) -> Result<Self, PlantError> {
        let f = &desc.file;
        let params = f.tip_clearance.expect("validated: tip_clearance present");
        let rating = f.thrust_rating.expect("validated: thrust_rating present");
        let mut plant = TipClearancePlant {
            params,
            rating,
            map: desc.map,
            gas: f.gas,
            orifice: f.orifice,
            shaft: f.shaft,
            omega_rad_s: f.drive.nominal_speed_rad_s,
            settings: f.integration,
            x: SVector::zeros(),
            t_s: 0.0,
            h_state_s: 0.0,
            clearance_cmd_m: 0.0,
            throttle_cmd: inputs.throttle_target(),
        };
        let eq = plant
            .equilibria(inputs.throttle_target())
            .into_iter()
            .last()
            .ok_or_else(|| PlantError::NoEquilibrium {
                plant: f.name.clone(),
                what: format!("throttle {:.3}", inputs.throttle_target()),
            })?;
        plant.x = eq;
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

    /// Throttle flow at plenum pressure P and stem position, kg/s.
    #[inline]
    pub fn throttle_flow(&self, p_pa: f64, position: f64) -> f64 {
        throttle_flow_kg_s(&self.params, &self.gas, p_pa, position)
    }

    /// Steady-state characteristic ψ_ss(m) at the plant's speed.
    #[inline]
    pub fn psi_ss(&self, m: f64) -> f64 {
        self.map.eval(self.map_flow(m), self.omega_rad_s).value
    }

    /// Steady states for a throttle opening with zero clearance change, ordered by flow.
    pub fn equilibria(&self, throttle: f64) -> Vec<SVector<f64, N>> {
        let p01 = self.params.ambient_pressure_pa;
        let resid = |m: f64| self.throttle_flow(self.psi_ss(m) * p01, throttle) - m;
        let m_hi = 4.0
            * self
                .map
                .surge_line
                .flow_at_speed(self.omega_rad_s)
                .max(1e-6);
        super::analysis::roots_1d(resid, 1e-6 * m_hi, m_hi, 2000)
            .into_iter()
            .map(|m| {
                SVector::<f64, N>::from_column_slice(&[
                    self.psi_ss(m) * p01,
                    m,
                    0.0,
                    0.0,
                    0.0,
                    throttle,
                ])
            })
            .collect()
    }

    /// Advance by `dt_s` with `inputs` held.
    pub fn step(&mut self, inputs: &PlantInputs, dt_s: f64) {
        let lim = self.rating.modulation_max_m;
        // the auxiliary bearings limit the axial excursion: the servo setpoint is clamped
        self.clearance_cmd_m = inputs
            .command_or(ActuatorId::TipClearance, 0.0)
            .clamp(-lim, lim);
        self.throttle_cmd = inputs.throttle_target();
        let mut x = self.x;
        let mut h = self.h_state_s;
        solver::advance_adaptive(self, self.settings, self.t_s, &mut x, dt_s, &mut h);
        self.h_state_s = h;
        self.x = x;
        self.t_s += dt_s;
    }

    fn servo_state(&self) -> [f64; 3] {
        [self.x[2], self.x[3], self.x[4]]
    }

    /// True state.
    pub fn truth(&self) -> PlantTruth {
        let x = &self.x;
        let servo = self.servo_state();
        PlantTruth {
            m_kg_s: x[1],
            flow_map: self.map_flow(x[1]),
            p_suction_pa: self.params.ambient_pressure_pa,
            p_discharge_pa: x[0],
            omega_rad_s: self.omega_rad_s,
            t_suction_k: self.params.ambient_temperature_k,
            throttle_flow_kg_s: self.throttle_flow(x[0], x[5]),
            throttle_position: x[5],
            load_torque_nm: self.shaft.load_torque_nm(x[1], self.omega_rad_s),
            drive_torque_nm: self.shaft.load_torque_nm(x[1], self.omega_rad_s),
            tip_clearance_m: x[2],
            thrust_force_n: self.params.servo.force_n(servo),
            thrust_slew_n_s: self
                .params
                .servo
                .force_slew_n_s(servo, self.clearance_cmd_m),
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

    /// Set held inputs without stepping (for analysis).
    pub fn hold_inputs(&mut self, clearance_cmd_m: f64, throttle_cmd: f64) {
        self.clearance_cmd_m = clearance_cmd_m;
        self.throttle_cmd = throttle_cmd;
    }
}

impl OdeSystem<N> for TipClearancePlant {
    #[inline]
    fn rhs(&self, _t: f64, x: &SVector<f64, N>) -> SVector<f64, N> {
        let pp = &self.params;
        let (p, m) = (x[0], x[1]);
        let servo = [x[2], x[3], x[4]];
        let psi = pp.effect.pressure_ratio(self.psi_ss(m), servo[0]); // seed 004 eq. 3 (corrected)
        let ds = pp.servo.rhs(servo, self.clearance_cmd_m);
        SVector::<f64, N>::from_column_slice(&[
            pp.sonic_velocity_m_s * pp.sonic_velocity_m_s / pp.plenum_volume_m3
                * (m - self.throttle_flow(p, x[5])), // eq. 4a
            pp.duct_area_m2 / pp.duct_length_m * (psi * pp.ambient_pressure_pa - p), // eq. 4b
            ds[0],
            ds[1],
            ds[2],
            pp.throttle.positioner_rate(self.throttle_cmd, x[5]),
        ])
    }

    fn project(&self, x: &mut SVector<f64, N>) {
        x[5] = x[5].clamp(0.0, 1.0);
    }
}
