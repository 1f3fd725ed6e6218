//! Simulated compressor plants: the four dynamic models of the seeds behind one interface.
//!
//! A plant is stepped with inputs held over the step (zero-order hold, as a sampled controller
//! sees it), reports its true state ([`PlantTruth`]) and what its field instruments would read
//! ([`crate::vocab::signals::SensorSnapshot`]). The same plant code runs inside `antisurge sim` and as
//! the HIL plant node on a bus.

pub mod analysis;
pub mod file;
pub mod plenum_duct;
pub mod recycle_system;
pub mod spool;
pub mod tip_clearance;

use crate::physics::compressor_map::CompressorMap;
use crate::vocab::signals::{ActuatorCommands, ActuatorId, SensorSnapshot};
use file::{ModelKind, PlantDescription};

/// Inputs held constant over one plant step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlantInputs {
    /// Controller setpoints; NaN means "this actuator is not driven by the controller".
    pub commands: ActuatorCommands,
    /// Throttle opening demanded by the process (scenario/operator) when the controller does
    /// not drive the throttle, fraction.
    pub throttle_process: f64,
    /// Recycle valve opening from the manual station when the controller does not drive it.
    pub recycle_manual: f64,
    /// Feed as a fraction of nominal (mass-flow source) or feed-valve opening.
    pub feed: f64,
    /// Downstream header pressure as a fraction of nominal (recycle plants).
    pub downstream: f64,
    /// Drive tripped (emergency shutdown): no torque regardless of command.
    pub drive_tripped: bool,
}

impl Default for PlantInputs {
    fn default() -> Self {
        PlantInputs {
            commands: ActuatorCommands::default(),
            throttle_process: 1.0,
            recycle_manual: 0.0,
            feed: 1.0,
            downstream: 1.0,
            drive_tripped: false,
        }
    }
}

impl PlantInputs {
    /// The throttle opening the plant's positioner is driven to.
    #[inline]
    pub fn throttle_target(&self) -> f64 {
        let c = self.commands.get(ActuatorId::Throttle);
        if c.is_nan() {
            self.throttle_process
        } else {
            c
        }
    }
    /// The recycle valve opening the positioner is driven to.
    #[inline]
    pub fn recycle_target(&self) -> f64 {
        let c = self.commands.get(ActuatorId::RecycleValve);
        if c.is_nan() {
            self.recycle_manual
        } else {
            c
        }
    }
    /// Torque the drive delivers: command clamped to the rating, zero when tripped.
    #[inline]
    pub fn drive_torque(&self, min_nm: f64, max_nm: f64, hold_nm: f64) -> f64 {
        if self.drive_tripped {
            return 0.0;
        }
        let c = self.commands.get(ActuatorId::DriveTorque);
        if c.is_nan() {
            hold_nm
        } else {
            c.clamp(min_nm, max_nm)
        }
    }
    /// A command or a default when not commanded.
    #[inline]
    pub fn command_or(&self, id: ActuatorId, default: f64) -> f64 {
        let c = self.commands.get(id);
        if c.is_nan() {
            default
        } else {
            c
        }
    }
}

/// True plant state in SI units, for traces, surge detection and scoring. Fields a plant does
/// not have are NaN.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlantTruth {
    /// Compressor mass flow, kg/s.
    pub m_kg_s: f64,
    /// Compressor flow in the map's coordinate (kg/s or m³/s at suction).
    pub flow_map: f64,
    /// Suction pressure, Pa.
    pub p_suction_pa: f64,
    /// Discharge (plenum) pressure, Pa.
    pub p_discharge_pa: f64,
    /// Shaft speed, rad/s.
    pub omega_rad_s: f64,
    /// Suction temperature, K.
    pub t_suction_k: f64,
    /// Recycle flow (discharge → suction), kg/s.
    pub recycle_flow_kg_s: f64,
    /// Throttle/discharge flow, kg/s.
    pub throttle_flow_kg_s: f64,
    /// Feed flow, kg/s.
    pub feed_flow_kg_s: f64,
    /// Recycle valve stem position, fraction.
    pub recycle_valve_position: f64,
    /// Throttle stem position, fraction.
    pub throttle_position: f64,
    /// Torque the drive delivers, N·m.
    pub drive_torque_nm: f64,
    /// Compressor load torque, N·m.
    pub load_torque_nm: f64,
    /// Close-coupled valve pressure-rise reduction applied (plant units).
    pub ccv: f64,
    /// Tip-clearance change (actual rotor position), m.
    pub tip_clearance_m: f64,
    /// Thrust-bearing force, N.
    pub thrust_force_n: f64,
    /// Thrust-bearing force slew rate, N/s.
    pub thrust_slew_n_s: f64,
}

impl PlantTruth {
    /// All NaN.
    pub const NAN: PlantTruth = PlantTruth {
        m_kg_s: f64::NAN,
        flow_map: f64::NAN,
        p_suction_pa: f64::NAN,
        p_discharge_pa: f64::NAN,
        omega_rad_s: f64::NAN,
        t_suction_k: f64::NAN,
        recycle_flow_kg_s: f64::NAN,
        throttle_flow_kg_s: f64::NAN,
        feed_flow_kg_s: f64::NAN,
        recycle_valve_position: f64::NAN,
        throttle_position: f64::NAN,
        drive_torque_nm: f64::NAN,
        load_torque_nm: f64::NAN,
        ccv: f64::NAN,
        tip_clearance_m: f64::NAN,
        thrust_force_n: f64::NAN,
        thrust_slew_n_s: f64::NAN,
    };

    /// Pressure ratio p_d/p_s.
    #[inline]
    pub fn pressure_ratio(&self) -> f64 {
        self.p_discharge_pa / self.p_suction_pa
    }
}

/// Errors constructing or initialising a plant.
#[derive(Debug, thiserror::Error)]
pub enum PlantError {
    /// No steady state exists for the requested inputs.
    #[error("plant `{plant}`: no steady operating point for {what}")]
    NoEquilibrium {
        /// Plant name.
        plant: String,
        /// Which inputs.
        what: String,
    },
}

/// Any of the four plant models.
#[derive(Debug, Clone)]
#[allow(clippy::large_enum_variant)]
pub enum SimPlant {
    /// Seed 000.
    PlenumDuct(plenum_duct::PlenumDuctPlant),
    /// Seeds 001/002.
    Recycle(recycle_system::RecyclePlant),
    /// Seed 004.
    TipClearance(tip_clearance::TipClearancePlant),
    /// Seed 003.
    Spool(spool::SpoolPlant),
}

macro_rules! dispatch {
    ($self:expr, $p:ident => $e:expr) => {
        match $self {
            SimPlant::PlenumDuct($p) => $e,
            SimPlant::Recycle($p) => $e,
            SimPlant::TipClearance($p) => $e,
            SimPlant::Spool($p) => $e,
        }
    };
}

impl SimPlant {
    /// Build the plant of a description, at its steady state for `inputs` (the drive torque
    /// command in `inputs` is ignored: the steady state is at the nominal speed).
    pub fn new(desc: &PlantDescription, inputs: &PlantInputs) -> Result<SimPlant, PlantError> {
        Ok(match desc.file.model {
            ModelKind::PlenumDuct => {
                SimPlant::PlenumDuct(plenum_duct::PlenumDuctPlant::new(desc, inputs)?)
            }
            ModelKind::RecycleSystem => {
                SimPlant::Recycle(recycle_system::RecyclePlant::new(desc, inputs)?)
            }
            ModelKind::TipClearance => {
                SimPlant::TipClearance(tip_clearance::TipClearancePlant::new(desc, inputs)?)
            }
            ModelKind::Spool => SimPlant::Spool(spool::SpoolPlant::new(desc, inputs)?),
        })
    }

    /// Advance by `dt_s` with `inputs` held.
    #[inline]
    pub fn step(&mut self, inputs: &PlantInputs, dt_s: f64) {
        dispatch!(self, p => p.step(inputs, dt_s))
    }

    /// True state in SI units.
    #[inline]
    pub fn truth(&self) -> PlantTruth {
        dispatch!(self, p => p.truth())
    }

    /// Noise-free field instrument readings.
    #[inline]
    pub fn sensors(&self) -> SensorSnapshot {
        dispatch!(self, p => p.sensors())
    }

    /// Simulation time, s.
    #[inline]
    pub fn time_s(&self) -> f64 {
        dispatch!(self, p => p.t_s)
    }

    /// The compressor map in SI units (for the spool plant: the SI image of its
    /// nondimensional characteristic).
    pub fn map(&self) -> &CompressorMap {
        dispatch!(self, p => &p.map)
    }

    /// Drive torque that holds the current state at constant speed (the load torque), N·m.
    pub fn equilibrium_torque_nm(&self) -> f64 {
        self.truth().load_torque_nm
    }
}

/// Sensor snapshot helper shared by the models.
pub(crate) fn sensor_snapshot(truth: &PlantTruth, orifice_dp_pa: f64) -> SensorSnapshot {
    use crate::vocab::signals::SensorId as S;
    let mut s = SensorSnapshot::default();
    s.set(S::PSuction, truth.p_suction_pa);
    s.set(S::PDischarge, truth.p_discharge_pa);
    s.set(S::ShaftSpeed, truth.omega_rad_s);
    s.set(S::OrificeDp, orifice_dp_pa);
    s.set(S::TSuction, truth.t_suction_k);
    s.set(S::RecycleValvePosition, truth.recycle_valve_position);
    s.set(S::ThrottlePosition, truth.throttle_position);
    s.set(S::ThrustPosition, truth.tip_clearance_m);
    s.set(S::DriveTorque, truth.drive_torque_nm);
    s
}

/// A steady operating point with its linear stability (open loop, inputs held, constant drive
/// torque equal to the load torque).
#[derive(Debug, Clone)]
pub struct OperatingPoint {
    /// Compressor mass flow, kg/s.
    pub m_kg_s: f64,
    /// Flow in map coordinates.
    pub flow_map: f64,
    /// Pressure ratio.
    pub pressure_ratio: f64,
    /// Slope of the compressor characteristic ∂Ψ/∂flow at the point (map units).
    pub compressor_slope: f64,
    /// Eigenvalues of the Jacobian.
    pub eigenvalues: Vec<nalgebra::Complex<f64>>,
    /// Largest real part of the eigenvalues, 1/s.
    pub spectral_abscissa: f64,
}

impl OperatingPoint {
    /// Whether the point is locally asymptotically stable.
    pub fn stable(&self) -> bool {
        self.spectral_abscissa < 0.0
    }
}

impl SimPlant {
    /// All steady states for the given inputs, ordered by flow, each with its eigenvalues
    /// (constant drive torque: the open-loop machine of seed 001 §2.3.5 and seed 003 Lemma 1).
    /// Plants with a speed loop are analysed at their current (nominal) speed; the spool model,
    /// which has no speed loop, at its current drive torque with speed as an unknown.
    pub fn operating_points(&self, inputs: &PlantInputs) -> Vec<OperatingPoint> {
        let mut out = Vec::new();
        match self {
            SimPlant::PlenumDuct(p) => {
                let omega = p.x[2];
                for x in p.equilibria(inputs.throttle_target(), omega) {
                    let mut q = p.clone();
                    q.x = x;
                    q.hold_inputs(q.shaft.load_torque_nm(x[1], omega), x[3]);
                    out.push(point(
                        &q.model,
                        &x,
                        q.truth(),
                        q.map.eval(q.truth().flow_map, omega).d_dflow,
                    ));
                }
            }
            SimPlant::Recycle(p) => {
                use recycle_system::ix;
                let omega = p.x[ix::OMEGA];
                for x in p.equilibria(
                    inputs.recycle_target(),
                    inputs.throttle_target(),
                    inputs.feed,
                    omega,
                ) {
                    let mut q = p.clone();
                    q.x = x;
                    q.hold_inputs(
                        q.shaft.load_torque_nm(x[ix::WC], omega),
                        x[ix::LR],
                        x[ix::LT],
                        x[ix::LF],
                    );
                    let t = q.truth();
                    out.push(point(&q, &x, t, q.map.eval(t.flow_map, omega).d_dflow));
                }
            }
            SimPlant::TipClearance(p) => {
                for x in p.equilibria(inputs.throttle_target()) {
                    let mut q = p.clone();
                    q.x = x;
                    q.hold_inputs(0.0, x[5]);
                    let t = q.truth();
                    out.push(point(
                        &q,
                        &x,
                        t,
                        q.map.eval(t.flow_map, q.omega_rad_s).d_dflow,
                    ));
                }
            }
            SimPlant::Spool(p) => {
                // constant drive torque (seed 003 holds τ_t = τ0): speed is part of the steady state
                let torque = p.params.torque_coefficient * p.x[1] * p.x[0];
                for x in p.equilibria_at_torque(inputs.throttle_target(), torque) {
                    let mut q = p.clone();
                    q.x = x;
                    q.hold_inputs(q.params.torque_coefficient * x[1] * x[0], 0.0, x[3]);
                    let t = q.truth();
                    out.push(point(&q, &x, t, q.psi_c(x[1], x[0]).d_dflow));
                }
            }
        }
        out
    }
}

fn point<const N: usize, S: crate::solver::OdeSystem<N>>(
    sys: &S,
    x: &nalgebra::SVector<f64, N>,
    t: PlantTruth,
    slope: f64,
) -> OperatingPoint {
    let eigenvalues = analysis::eigenvalues(sys, x);
    let spectral_abscissa = eigenvalues
        .iter()
        .map(|c| c.re)
        .fold(f64::NEG_INFINITY, f64::max);
    OperatingPoint {
        m_kg_s: t.m_kg_s,
        flow_map: t.flow_map,
        pressure_ratio: t.pressure_ratio(),
        compressor_slope: slope,
        eigenvalues,
        spectral_abscissa,
    }
}
