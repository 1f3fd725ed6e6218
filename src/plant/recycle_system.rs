//! Two-volume recycle system: seed 002 eq. 3.18 with the feed valve of seed 001 eq. 2.27 and a
//! throttle in the discharge line (seed 001 eq. 2.26's throttle).
//!
//! ```text
//! ṗ1 = c1²/V1 (w_f + w_r − w_c)                               (002 eq. 3.18, line 1)
//! ṗ2 = c2²/V2 (w_c − w_r − w_t)                               (line 2)
//! ẇc = Ac/Lc (Ψc(q_c, ω) p1 − p2),  q_c = w_c/ρ1 (= c_qw w_c/p1) (line 3)
//! ẇr = Ar/Lr (p2 − p1 − |w_r| w_r /(2 ρ_up C_r*(l_r)²))        (line 4, eq. 3.16)
//! ẇt = At/Lt (p2 − p_a − |w_t| w_t /(2 ρ2 C_t*(l_t)²)),  w_t ≥ 0 (eq. 3.17 + throttle)
//! ω̇  = (τd − r² σ |w_c| ω)/J                                  (eq. 3.6, 3.9)
//! ```
//!
//! Conventions (ERRATA.md: eq. 3.16 and 3.18 disagree): the recycle flow w_r is positive from
//! the discharge volume V2 back to the suction volume V1, and the density in its friction term
//! is the density on the side the flow comes from (ρ2 for w_r ≥ 0). With the ideal gas law
//! 1/(p2 C_r²) of eq. 3.18 equals 1/(2ρ2 C_r*²) with C_r = C_r*√(2M/RT) (eq. 3.14).
//! The speed controller of eq. 3.18's last line is not part of the plant: the drive is a torque
//! actuator and the speed loop runs in the controller (that line's "(Kp + r² wc) e_ω" is a
//! misprint for ė_ω anyway, ERRATA.md).
//!
//! Extension, stated: seed 002's discharge line has only a check valve into a large volume at
//! p_a; we add the throttle valve of seed 001 (eq. 2.26) as a friction term in that line so
//! the throttle-closure scenario applies to this plant too.
//!
//! The line inertias make this model stiff near valve closure (ERRATA.md: eigenvalues near
//! 10⁵ s⁻¹): its plant files select the Rosenbrock integrator.
//!
//! State x = (p1, p2, w_c, w_r, w_t, ω, recycle position, throttle position, feed position).

use super::file::{FeedSpec, PlantDescription, RecycleParams};
use super::{sensor_snapshot, PlantError, PlantInputs, PlantTruth};
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;
use crate::physics::shaft::Shaft;
use crate::physics::valve;
use crate::solver::{self, OdeSystem, StepSettings};
use crate::vocab::signals::SensorSnapshot;
use nalgebra::SVector;

/// State dimension.
pub const N: usize = 9;

/// Quasi-steady recycle flow (V2 → V1): see [`RecycleParams::recycle_flow_steady_kg_s`], kg/s.
pub fn recycle_flow_steady_kg_s(pp: &RecycleParams, gas: &Gas, p1: f64, p2: f64, lr: f64) -> f64 {
    pp.recycle_flow_steady_kg_s(gas, p1, p2, lr)
}

/// Quasi-steady throttle flow: see [`RecycleParams::throttle_flow_steady_kg_s`], kg/s.
pub fn throttle_flow_steady_kg_s(
    pp: &RecycleParams,
    gas: &Gas,
    p2: f64,
    p_a_pa: f64,
    lt: f64,
) -> f64 {
    pp.throttle_flow_steady_kg_s(gas, p2, p_a_pa, lt)
}

/// Indices into the state vector.
pub mod ix {
    /// Suction pressure p1, Pa.
    pub const P1: usize = 0;
    /// Discharge pressure p2, Pa.
    pub const P2: usize = 1;
    /// Compressor mass flow w_c, kg/s.
    pub const WC: usize = 2;
    /// Recycle flow w_r, kg/s.
    pub const WR: usize = 3;
    /// Discharge (throttle) flow w_t, kg/s.
    pub const WT: usize = 4;
    /// Speed ω, rad/s.
    pub const OMEGA: usize = 5;
    /// Recycle valve position.
    pub const LR: usize = 6;
    /// Throttle position.
    pub const LT: usize = 7;
    /// Feed valve position (or feed scale for a mass-flow feed).
    pub const LF: usize = 8;
}

/// Seed 001/002 recycle plant.
#[derive(Debug, Clone)]
pub struct RecyclePlant {
    /// Parameters.
    pub params: RecycleParams,
    /// Compressor map.
    pub map: CompressorMap,
    /// Shaft.
    pub shaft: Shaft,
    /// Gas.
    pub gas: Gas,
    /// Orifice at the compressor suction.
    pub orifice: Orifice,
    /// Drive torque limits (min, max), N·m.
    pub torque_limits_nm: (f64, f64),
    /// Integration settings.
    pub settings: StepSettings,
    /// State.
    pub x: SVector<f64, N>,
    /// Time, s.
    pub t_s: f64,
    /// Step size carried between periods by adaptive integration, s.
    pub h_state_s: f64,
    torque_nm: f64,
    recycle_cmd: f64,
    throttle_cmd: f64,
    feed_cmd: f64,
    downstream_scale: f64,
}

impl RecyclePlant {
    /// Build at the steady state for `inputs` at nominal speed.
    pub fn new(desc: &PlantDescription, inputs: &PlantInputs) -> Result<Self, PlantError> {
        let f = &desc.file;
        let params = f.recycle_system.expect("validated: recycle_system present");
        let mut plant = RecyclePlant {
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
            recycle_cmd: inputs.recycle_target(),
            throttle_cmd: inputs.throttle_target(),
            feed_cmd: inputs.feed,
            downstream_scale: inputs.downstream,
        };
        let omega = f.drive.nominal_speed_rad_s;
        let eq = plant
            .equilibria(
                inputs.recycle_target(),
                inputs.throttle_target(),
                inputs.feed,
                omega,
            )
            .into_iter()
            .last()
            .ok_or_else(|| PlantError::NoEquilibrium {
                plant: f.name.clone(),
                what: format!(
                    "recycle {:.3}, throttle {:.3}, feed {:.3} at {omega} rad/s",
                    inputs.recycle_target(),
                    inputs.throttle_target(),
                    inputs.feed
                ),
            })?;
        plant.x = eq;
        plant.torque_nm = plant.shaft.load_torque_nm(eq[ix::WC], omega);
        Ok(plant)
    }

    #[inline]
    fn rho1(&self, p1: f64) -> f64 {
        self.gas
            .density_kg_m3(p1.max(1.0), self.params.suction_temperature_k)
    }
    #[inline]
    fn rho2(&self, p2: f64) -> f64 {
        self.gas
            .density_kg_m3(p2.max(1.0), self.params.discharge_temperature_k)
    }

    /// Map flow coordinate of the compressor flow at suction pressure p1.
    #[inline]
    pub fn map_flow(&self, w_c: f64, p1: f64) -> f64 {
        match self.map.flow_coordinate {
            FlowCoordinate::MassKgS => w_c,
            // q = w/ρ1 = c_qw w/p1 (seed 002 eq. 2.14, 3.18)
            FlowCoordinate::InletVolumeM3S => w_c / self.rho1(p1),
        }
    }

    /// Feed flow into V1 at suction pressure p1 and feed position/scale `lf`, kg/s.
    #[inline]
    pub fn feed_flow(&self, p1: f64, lf: f64) -> f64 {
        match self.params.feed {
            FeedSpec::MassFlow { nominal_kg_s } => nominal_kg_s * lf.max(0.0),
            FeedSpec::Valve {
                upstream_pressure_pa,
                valve: v,
                density_kg_m3,
            } => {
                // seed 001 eq. 2.27 with the smooth sign of eq. 2.9
                let rho = density_kg_m3.unwrap_or_else(|| self.rho1(upstream_pressure_pa));
                valve::flow_kg_s(
                    v.cv_m2(lf),
                    rho,
                    upstream_pressure_pa - p1,
                    self.params.valve_smoothing_pa,
                )
            }
        }
    }

    /// Downstream header pressure with the current scale, Pa.
    #[inline]
    pub fn downstream_pa(&self) -> f64 {
        self.params.downstream_pressure_pa * self.downstream_scale
    }

    /// Steady recycle flow for pressures and stem position (quasi-steady eq. 3.14), kg/s.
    pub fn recycle_flow_steady(&self, p1: f64, p2: f64, lr: f64) -> f64 {
        let cv = self.params.recycle_valve.cv_m2(lr);
        let rho = if p2 >= p1 {
            self.rho2(p2)
        } else {
            self.rho1(p1)
        };
        let dp = p2 - p1;
        cv * (2.0 * rho * dp.abs()).sqrt() * dp.signum()
    }

    /// Steady throttle flow through the discharge line, kg/s (check valve shut if p2 ≤ p_a).
    pub fn throttle_flow_steady(&self, p2: f64, lt: f64) -> f64 {
        let cv = self.params.throttle.cv_m2(lt);
        let dp = p2 - self.downstream_pa();
        if dp <= 0.0 && self.params.check_valve {
            return 0.0;
        }
        cv * (2.0 * self.rho2(p2) * dp.abs()).sqrt() * dp.signum()
    }

    /// All steady states for the given valve positions, feed and speed, ordered by compressor
    /// flow (the last is the rightmost operating point). Solved in one unknown, p1: the feed
    /// gives w_t, hence p2, hence w_r, hence w_c; the residual is Ψc p1 − p2.
    pub fn equilibria(
        &self,
        recycle: f64,
        throttle: f64,
        feed: f64,
        omega: f64,
    ) -> Vec<SVector<f64, N>> {
        let pa = self.downstream_pa();
        let cv_t = self.params.throttle.cv_m2(throttle);
        let chain = |p1: f64| -> Option<(f64, f64, f64, f64, f64)> {
            let wf = self.feed_flow(p1, feed);
            let wt = wf;
            if wt < 0.0 && self.params.check_valve {
                return None;
            }
            // p2 from the throttle line: w_t = C_t*√(2ρ2 Δp) with ρ2 = ρ2(p2); solve by
            // fixed-point (ρ2 depends weakly on p2)
            let mut p2 = pa;
            for _ in 0..60 {
                let loss = valve::line_loss_pa(wt, cv_t, self.rho2(p2));
                let next = pa + loss;
                if (next - p2).abs() < 1e-9 * pa {
                    p2 = next;
                    break;
                }
                p2 = next;
            }
            let wr = self.recycle_flow_steady(p1, p2, recycle);
            let wc = wf + wr;
            Some((p2, wc, wr, wt, wf))
        };
        let resid = |p1: f64| match chain(p1) {
            Some((p2, wc, _, _, _)) => self.map.eval(self.map_flow(wc, p1), omega).value * p1 - p2,
            None => f64::NAN,
        };
        let upper = match self.params.feed {
            FeedSpec::Valve {
                upstream_pressure_pa,
                ..
            } => upstream_pressure_pa,
            FeedSpec::MassFlow { .. } => pa,
        };
        let mut out: Vec<(f64, SVector<f64, N>)> =
            super::analysis::roots_1d(resid, upper * 1e-3, upper * (1.0 - 1e-9), 4000)
                .into_iter()
                .filter_map(|p1| {
                    let (p2, wc, wr, wt, _) = chain(p1)?;
                    let q = self.map_flow(wc, p1);
                    Some((
                        q,
                        SVector::<f64, N>::from_column_slice(&[
                            p1, p2, wc, wr, wt, omega, recycle, throttle, feed,
                        ]),
                    ))
                })
                .collect();
        out.sort_by(|a, b| a.0.total_cmp(&b.0));
        out.into_iter().map(|(_, x)| x).collect()
    }

    /// Advance by `dt_s` with `inputs` held.
    pub fn step(&mut self, inputs: &PlantInputs, dt_s: f64) {
        let (lo, hi) = self.torque_limits_nm;
        self.torque_nm = inputs.drive_torque(lo, hi, self.torque_nm);
        self.recycle_cmd = inputs.recycle_target();
        self.throttle_cmd = inputs.throttle_target();
        self.feed_cmd = inputs.feed;
        self.downstream_scale = inputs.downstream;
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
        PlantTruth {
            m_kg_s: x[ix::WC],
            flow_map: self.map_flow(x[ix::WC], x[ix::P1]),
            p_suction_pa: x[ix::P1],
            p_discharge_pa: x[ix::P2],
            omega_rad_s: x[ix::OMEGA],
            t_suction_k: self.params.suction_temperature_k,
            recycle_flow_kg_s: x[ix::WR],
            throttle_flow_kg_s: x[ix::WT],
            feed_flow_kg_s: self.feed_flow(x[ix::P1], x[ix::LF]),
            recycle_valve_position: x[ix::LR],
            throttle_position: x[ix::LT],
            drive_torque_nm: self.torque_nm,
            load_torque_nm: self.shaft.load_torque_nm(x[ix::WC], x[ix::OMEGA]),
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
    pub fn hold_inputs(&mut self, torque_nm: f64, recycle: f64, throttle: f64, feed: f64) {
        self.torque_nm = torque_nm;
        self.recycle_cmd = recycle;
        self.throttle_cmd = throttle;
        self.feed_cmd = feed;
    }
}

impl OdeSystem<N> for RecyclePlant {
    #[inline]
    fn rhs(&self, _t: f64, x: &SVector<f64, N>) -> SVector<f64, N> {
        let pp = &self.params;
        let (p1, p2, wc, wr, wt, omega) = (x[0], x[1], x[2], x[3], x[4], x[5]);
        let (lr, lt, lf) = (x[6], x[7], x[8]);
        let wf = self.feed_flow(p1, lf);
        let psi = self.map.eval(self.map_flow(wc, p1), omega).value;
        let k1 =
            pp.suction_sonic_velocity_m_s * pp.suction_sonic_velocity_m_s / pp.suction_volume_m3;
        let k2 = pp.discharge_sonic_velocity_m_s * pp.discharge_sonic_velocity_m_s
            / pp.discharge_volume_m3;
        let rho_r = if wr >= 0.0 {
            self.rho2(p2)
        } else {
            self.rho1(p1)
        };
        let dwr = valve::line_flow_rate(
            pp.recycle_duct_area_m2 / pp.recycle_duct_length_m,
            p2,
            p1,
            wr,
            pp.recycle_valve.cv_m2(lr),
            rho_r,
        );
        let mut dwt = valve::line_flow_rate(
            pp.discharge_duct_area_m2 / pp.discharge_duct_length_m,
            p2,
            self.downstream_pa(),
            wt,
            pp.throttle.cv_m2(lt),
            self.rho2(p2),
        );
        if pp.check_valve {
            dwt = valve::check_valve_rate(wt, dwt);
        }
        let dlf = match pp.feed {
            FeedSpec::Valve { valve: v, .. } => v.positioner_rate(self.feed_cmd, lf),
            // a mass-flow feed follows its scale directly (first order, 0.1 s)
            FeedSpec::MassFlow { .. } => (self.feed_cmd - lf) / 0.1,
        };
        SVector::<f64, N>::from_column_slice(&[
            k1 * (wf + wr - wc),
            k2 * (wc - wr - wt),
            pp.compressor_duct_area_m2 / pp.compressor_duct_length_m * (psi * p1 - p2),
            dwr,
            dwt,
            self.shaft.acceleration_rad_s2(self.torque_nm, wc, omega),
            pp.recycle_valve.positioner_rate(self.recycle_cmd, lr),
            pp.throttle.positioner_rate(self.throttle_cmd, lt),
            dlf,
        ])
    }

    fn abs_tolerance(&self) -> [f64; N] {
        // Pa, Pa, kg/s, kg/s, kg/s, rad/s, positions
        [10.0, 10.0, 1e-3, 1e-3, 1e-3, 1e-2, 1e-5, 1e-5, 1e-5]
    }

    fn project(&self, x: &mut SVector<f64, N>) {
        if self.params.check_valve {
            x[ix::WT] = x[ix::WT].max(0.0);
        }
        x[ix::LR] = x[ix::LR].clamp(0.0, 1.0);
        x[ix::LT] = x[ix::LT].clamp(0.0, 1.0);
        x[ix::LF] = x[ix::LF].max(0.0);
        x[ix::OMEGA] = x[ix::OMEGA].max(0.0);
        x[ix::P1] = x[ix::P1].max(1.0);
        x[ix::P2] = x[ix::P2].max(1.0);
    }
}
