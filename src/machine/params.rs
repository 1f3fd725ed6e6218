//! Model parameters of the machine that model-based laws use and the simulator shares: the
//! model family, the drive, the thrust-bearing rating and the per-family plant data (volumes,
//! ducts, valves). They describe *the machine*; the simulator's plant models (`plant/`) and the
//! controller (`control/`) both read them from here, so neither depends on the other.

use crate::physics::characteristic::MooreGreitzerCubic;
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use crate::physics::gas::Gas;
use crate::physics::thrust_bearing::ThrustBearingServo;
use crate::physics::tip_clearance::TipClearanceEffect;
use crate::physics::valve::{self, ValveSpec};
use serde::{Deserialize, Serialize};

/// Which dynamic model the plant uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelKind {
    /// Plenum/duct/shaft model (seed 000 eq. 1).
    PlenumDuct,
    /// Two-volume recycle system (seed 002 eq. 3.18, seed 001 eq. 2.26–2.27).
    RecycleSystem,
    /// Plenum/duct with tip-clearance actuation (seed 004 eq. 4).
    TipClearance,
    /// Nondimensional spool model (seed 003 eq. 4–6).
    Spool,
}

/// The compressor drive (motor) as an actuator.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveSpec {
    /// Largest motoring torque the drive delivers, N·m (its rating).
    pub rated_torque_nm: f64,
    /// Most negative (braking) torque, N·m; 0 for a drive without braking.
    #[serde(default)]
    pub min_torque_nm: f64,
    /// Nominal speed, rad/s: the speed setpoint at start.
    pub nominal_speed_rad_s: f64,
    /// Proportional gain of the drive's speed loop, N·m per rad/s (seed 002 eq. 3.7).
    pub speed_kp_nm_s_rad: f64,
    /// Integral gain of the speed loop, N·m per rad.
    pub speed_ki_nm_rad: f64,
}

/// Ratings of the actuators, so that laws are judged within real limits.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct ThrustRating {
    /// Peak force of the magnetic thrust bearing, N.
    pub force_max_n: f64,
    /// Force slew-rate limit, N/s.
    pub slew_max_n_s: f64,
    /// Nominal tip clearance, m.
    pub nominal_clearance_m: f64,
    /// Largest clearance modulation the auxiliary bearings allow, m (seed 004: 50 % of nominal).
    pub modulation_max_m: f64,
}

/// Plenum/duct/shaft plant (seed 000 eq. 1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlenumDuctParams {
    /// Ambient (suction) stagnation pressure p01, Pa.
    pub ambient_pressure_pa: f64,
    /// Ambient temperature, K.
    pub ambient_temperature_k: f64,
    /// Speed of sound a01, m/s.
    pub sonic_velocity_m_s: f64,
    /// Plenum volume Vp, m³.
    pub plenum_volume_m3: f64,
    /// Duct through-flow area A1, m².
    pub duct_area_m2: f64,
    /// Duct length Lc, m.
    pub duct_length_m: f64,
    /// Throttle valve to ambient.
    pub throttle: ValveSpec,
    /// If set, the throttle flow uses this constant density (seed 000: m_t = k_t √(p − p01));
    /// otherwise the plenum density from the gas law.
    #[serde(default)]
    pub throttle_density_kg_m3: Option<f64>,
    /// Width of the smooth zero crossing of valve flows, Pa (1/ξ of seed 001 eq. 2.9).
    #[serde(default = "default_smoothing")]
    pub valve_smoothing_pa: f64,
}

/// Feed into the suction volume of the recycle system.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum FeedSpec {
    /// A mass-flow source (seed 002: w_f is a disturbance), kg/s at scale 1.
    MassFlow {
        /// Nominal feed, kg/s.
        nominal_kg_s: f64,
    },
    /// A feed valve from an upstream header (seed 001 eq. 2.27).
    Valve {
        /// Upstream header pressure, Pa.
        upstream_pressure_pa: f64,
        /// The feed valve.
        valve: ValveSpec,
        /// Constant density for the valve equation (seed 001 uses w = A √Δp), kg/m³;
        /// otherwise the upstream density from the gas law.
        #[serde(default)]
        density_kg_m3: Option<f64>,
    },
}

/// Two-volume recycle system (seed 002 eq. 3.18 with seed 001's feed and throttle valves).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecycleParams {
    /// Suction volume V1, m³.
    pub suction_volume_m3: f64,
    /// Discharge volume V2, m³.
    pub discharge_volume_m3: f64,
    /// Speed of sound in the suction volume c1, m/s.
    pub suction_sonic_velocity_m_s: f64,
    /// Speed of sound in the discharge volume c2, m/s.
    pub discharge_sonic_velocity_m_s: f64,
    /// Suction temperature T1, K.
    pub suction_temperature_k: f64,
    /// Discharge temperature T2, K.
    pub discharge_temperature_k: f64,
    /// Compressor duct area Ac, m².
    pub compressor_duct_area_m2: f64,
    /// Compressor duct length Lc, m.
    pub compressor_duct_length_m: f64,
    /// Recycle line area Ar, m².
    pub recycle_duct_area_m2: f64,
    /// Recycle line length Lr, m.
    pub recycle_duct_length_m: f64,
    /// Discharge (check-valve) line area At, m².
    pub discharge_duct_area_m2: f64,
    /// Discharge line length Lt, m.
    pub discharge_duct_length_m: f64,
    /// Downstream header pressure p_a, Pa.
    pub downstream_pressure_pa: f64,
    /// Whether the discharge line has a check valve (seed 002 eq. 3.17).
    pub check_valve: bool,
    /// The feed.
    pub feed: FeedSpec,
    /// The recycle (anti-surge) valve.
    pub recycle_valve: ValveSpec,
    /// The throttle/discharge valve in the discharge line.
    pub throttle: ValveSpec,
    /// Width of the smooth zero crossing of the feed valve flow, Pa.
    #[serde(default = "default_smoothing")]
    pub valve_smoothing_pa: f64,
}

fn default_smoothing() -> f64 {
    50.0
}

/// Plenum/duct plant with tip-clearance actuation at constant speed (seed 004 eq. 4).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TipClearanceParams {
    /// Ambient pressure P01, Pa.
    pub ambient_pressure_pa: f64,
    /// Ambient temperature, K.
    pub ambient_temperature_k: f64,
    /// Speed of sound a01, m/s.
    pub sonic_velocity_m_s: f64,
    /// Plenum volume Vp, m³.
    pub plenum_volume_m3: f64,
    /// Duct area A, m².
    pub duct_area_m2: f64,
    /// Duct length Lc, m.
    pub duct_length_m: f64,
    /// Throttle valve to ambient.
    pub throttle: ValveSpec,
    /// Constant density for the throttle equation (seed 004: m_th = k_th √(P − P01)), kg/m³.
    #[serde(default)]
    pub throttle_density_kg_m3: Option<f64>,
    /// Tip-clearance effect (seed 004 eq. 2–3).
    pub effect: TipClearanceEffect,
    /// Thrust-bearing servo (seed 004: 3rd-order Butterworth, 70 Hz).
    pub servo: ThrustBearingServo,
    /// Width of the smooth zero crossing of the throttle flow, Pa.
    #[serde(default = "default_smoothing")]
    pub valve_smoothing_pa: f64,
}

/// Nondimensional spool model (seed 003 eq. 4–6) with the scales that map it to SI units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpoolParams {
    /// ā of eq. 4 (spool inertia parameter).
    pub a_bar: f64,
    /// b̄ of eq. 5 (Greitzer B).
    pub b_bar: f64,
    /// c̄ of eq. 6 (1/B).
    pub c_bar: f64,
    /// Torque coefficient σ: Γ(φ, ω̃) = σ φ ω̃ (seed 003 eq. 48, after [3]).
    pub torque_coefficient: f64,
    /// Throttle gain at full opening: F(γ, ψ) = γ √ψ with γ = gamma_max · opening.
    pub gamma_max: f64,
    /// Time unit of the nondimensional model (1/ω_H), s.
    pub time_scale_s: f64,
    /// Pressure per unit ψ, Pa.
    pub pressure_scale_pa: f64,
    /// Mass flow per unit φ, kg/s.
    pub flow_scale_kg_s: f64,
    /// Shaft speed per unit ω̃, rad/s.
    pub speed_scale_rad_s: f64,
    /// Torque per unit τ, N·m.
    pub torque_scale_nm: f64,
    /// Ambient (suction) pressure, Pa.
    pub ambient_pressure_pa: f64,
    /// Ambient temperature, K.
    pub ambient_temperature_k: f64,
    /// The throttle valve's positioner (its capacity is gamma_max).
    pub throttle: ValveSpec,
    /// Close-coupled valve authority: |u₂| ≤ this (seed 003 §IV uses 0.1 and 0.2).
    pub ccv_max: f64,
    /// Matched model uncertainty of seed 003 eq. 53 in the plant, off by default: amplitude A
    /// of Δf = ΔCss = A sin(k x₂), which enters eq. 4 as ā Δf and eq. 5 as b̄ ΔCss (seed 003
    /// eq. 38, 41–42; §IV uses A = 0.1). x₂ = φ − φ⁰ with φ⁰ the nominal steady state of the
    /// plant's current throttle position at nominal speed, so the equilibrium is unchanged.
    #[serde(default)]
    pub uncertainty_amplitude: f64,
    /// k of eq. 53 (per unit φ; seed 003 §IV: 10).
    #[serde(default = "default_uncertainty_frequency")]
    pub uncertainty_frequency: f64,
}

fn default_uncertainty_frequency() -> f64 {
    10.0
}

impl PlenumDuctParams {
    /// Throttle flow to ambient, m_t = k_t(l) √(p − p01) (seed 000, with the smooth sign of seed 001
    /// eq. 2.9), kg/s. Shared by the plant and the controller's observer.
    #[inline]
    pub fn throttle_flow_kg_s(&self, gas: &Gas, p_pa: f64, position: f64) -> f64 {
        let rho = self.throttle_density_kg_m3.unwrap_or_else(|| {
            gas.density_kg_m3(
                p_pa.max(self.ambient_pressure_pa),
                self.ambient_temperature_k,
            )
        });
        valve::flow_kg_s(
            self.throttle.cv_m2(position),
            rho,
            p_pa - self.ambient_pressure_pa,
            self.valve_smoothing_pa,
        )
    }
}

impl RecycleParams {
    /// Quasi-steady recycle flow (V2 → V1) for pressures and stem position: the steady state of
    /// the line equation, w_r = C_r*(l)·√(2 ρ_up Δp) (seed 002 eq. 3.14, 3.16), kg/s. Shared by the
    /// plant's equilibrium solver and the controller's observer.
    pub fn recycle_flow_steady_kg_s(&self, gas: &Gas, p1: f64, p2: f64, lr: f64) -> f64 {
        let cv = self.recycle_valve.cv_m2(lr);
        let rho = if p2 >= p1 {
            gas.density_kg_m3(p2.max(1.0), self.discharge_temperature_k)
        } else {
            gas.density_kg_m3(p1.max(1.0), self.suction_temperature_k)
        };
        let dp = p2 - p1;
        cv * (2.0 * rho * dp.abs()).sqrt() * dp.signum()
    }

    /// Quasi-steady flow through the discharge line's throttle to the header at `p_a_pa`, with the
    /// check valve shut when p2 ≤ p_a (seed 002 eq. 3.17), kg/s.
    pub fn throttle_flow_steady_kg_s(&self, gas: &Gas, p2: f64, p_a_pa: f64, lt: f64) -> f64 {
        let cv = self.throttle.cv_m2(lt);
        let dp = p2 - p_a_pa;
        if dp <= 0.0 && self.check_valve {
            return 0.0;
        }
        cv * (2.0 * gas.density_kg_m3(p2.max(1.0), self.discharge_temperature_k) * dp.abs()).sqrt()
            * dp.signum()
    }
}

impl SpoolParams {
    /// The SI image of the nondimensional cubic (seed 003 eq. 4–6): pressure ratio
    /// 1 + ψ·p_scale/p01 versus m = φ·flow_scale and ω = ω̃·speed_scale.
    pub fn si_map(&self, cubic: &MooreGreitzerCubic) -> Result<CompressorMap, String> {
        let k = self.pressure_scale_pa / self.ambient_pressure_pa;
        let si = MooreGreitzerCubic {
            psi_c0: 1.0 + cubic.psi_c0 * k,
            semi_height: cubic.semi_height * k,
            semi_width: cubic.semi_width * self.flow_scale_kg_s,
            omega_ref: cubic.omega_ref * self.speed_scale_rad_s,
        };
        let w = cubic.omega_ref * self.speed_scale_rad_s;
        CompressorMap::cubic(si, FlowCoordinate::MassKgS, 0.5 * w, 1.5 * w)
    }
}

impl TipClearanceParams {
    /// Throttle flow to ambient, m_th = k_th √(P − P01) (seed 004), kg/s. Shared by the plant and
    /// the controller's observer.
    #[inline]
    pub fn throttle_flow_kg_s(&self, gas: &Gas, p_pa: f64, position: f64) -> f64 {
        let rho = self.throttle_density_kg_m3.unwrap_or_else(|| {
            gas.density_kg_m3(
                p_pa.max(self.ambient_pressure_pa),
                self.ambient_temperature_k,
            )
        });
        valve::flow_kg_s(
            self.throttle.cv_m2(position),
            rho,
            p_pa - self.ambient_pressure_pa,
            self.valve_smoothing_pa,
        )
    }
}
