//! The plenum/duct/shaft model of seed 000 eq. 1, one copy shared by the simulated plant
//! (`plant::plenum_duct`, which integrates it) and the controller (the drive-torque law's
//! delay predictor, which steps it ahead over the loop delay):
//!
//! ```text
//! ṗ = a01²/Vp (m − m_t)                 (1a)
//! ṁ = A1/Lc (Ψc(m, ω) p01 − p)          (1b)
//! ω̇ = (τd − τc)/J,  τc = |m| r2² σ ω    (1c)
//! m_t = k_t √(p − p01)                   throttle, with k_t ∝ opening
//! ```
//! plus the throttle positioner. State x = (p Pa, m kg/s, ω rad/s, throttle position).

use super::params::PlenumDuctParams;
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;
use crate::physics::shaft::Shaft;
use crate::solver::{self, OdeSystem};
use nalgebra::SVector;

/// State dimension.
pub const N: usize = 4;

/// Seed 000 eq. 1 with its parameters and the inputs held over a step.
#[derive(Debug, Clone)]
pub struct PlenumDuctModel {
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
    /// Drive torque held over the current step, N·m.
    pub torque_nm: f64,
    /// Throttle target held over the current step (0–1).
    pub throttle_cmd: f64,
}

impl PlenumDuctModel {
    /// The model with no input applied yet.
    pub fn new(
        params: PlenumDuctParams,
        map: CompressorMap,
        shaft: Shaft,
        gas: Gas,
        orifice: Orifice,
        torque_limits_nm: (f64, f64),
    ) -> Self {
        PlenumDuctModel {
            params,
            map,
            shaft,
            gas,
            orifice,
            torque_limits_nm,
            torque_nm: 0.0,
            throttle_cmd: 0.0,
        }
    }

    /// The map's flow coordinate of a mass flow m (kg/s, or m³/s at the inlet conditions).
    #[inline]
    pub fn map_flow(&self, m: f64) -> f64 {
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

    /// Throttle flow m_t at plenum pressure p and stem position l, kg/s.
    #[inline]
    pub fn throttle_flow(&self, p_pa: f64, position: f64) -> f64 {
        self.params.throttle_flow_kg_s(&self.gas, p_pa, position)
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
}

impl OdeSystem<N> for PlenumDuctModel {
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
