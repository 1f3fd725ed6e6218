//! One control cycle: supervise inputs, derive measurements, run the active law on top of the
//! speed loop, decide the fail-safe state. Pure and allocation-free; the simulation and the
//! daemon call [`ControlCore::cycle`] once per period.

use super::law::LawId;
use super::measurements::{Measurements, OperatorInputs, RawSensors};
use super::model::ControlModel;
use super::speed_loop::SpeedLoop;
use super::supervisor::{InputLimits, Supervisor, Validity};
use crate::signals::{ActuatorCommands, ActuatorId, SensorId};

/// Controller mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Mode {
    /// Starting: no valid inputs yet.
    Init,
    /// Manual: recycle valve from the manual station, speed loop only.
    Manual,
    /// Automatic: the selected law runs.
    Auto,
    /// Inputs lost: safe state.
    FailSafe,
}

impl Mode {
    /// Name for traces and the event log.
    pub const fn name(self) -> &'static str {
        match self {
            Mode::Init => "init",
            Mode::Manual => "manual",
            Mode::Auto => "auto",
            Mode::FailSafe => "fail_safe",
        }
    }
    /// Numeric code (trace column, heartbeat frame).
    pub const fn code(self) -> u8 {
        match self {
            Mode::Init => 0,
            Mode::Manual => 1,
            Mode::Auto => 2,
            Mode::FailSafe => 3,
        }
    }
}

/// Settings of the control core that are not law gains.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoreSettings {
    /// Recycle valve opening commanded in fail-safe, fraction.
    pub failsafe_recycle_opening: f64,
    /// Input limits.
    pub supervisor: Supervisor,
}

impl CoreSettings {
    /// Defaults derived from the machine model: generous plausibility ranges around the
    /// machine's operating region and a 50 ms freshness timeout.
    pub fn defaults_for(model: &ControlModel) -> CoreSettings {
        let timeout_s = 0.05;
        let w_max = 2.0 * model.drive.nominal_speed_rad_s;
        let p_hi = match (model.recycle, model.plenum_duct, model.tip, model.spool) {
            (Some(r), ..) => 3.0 * r.downstream_pressure_pa,
            (_, Some(p), ..) => 5.0 * p.ambient_pressure_pa,
            (_, _, Some(t), _) => 5.0 * t.ambient_pressure_pa,
            (_, _, _, Some(s)) => 5.0 * s.ambient_pressure_pa,
            _ => 1e7,
        };
        let lim = |min: f64, max: f64| {
            Some(InputLimits {
                min,
                max,
                timeout_s,
            })
        };
        let mut limits = [None; SensorId::COUNT];
        limits[SensorId::PSuction.index()] = lim(1e3, p_hi);
        limits[SensorId::PDischarge.index()] = lim(1e3, p_hi);
        limits[SensorId::ShaftSpeed.index()] = lim(0.0, w_max);
        limits[SensorId::OrificeDp.index()] = lim(-1e5, 1e6);
        limits[SensorId::TSuction.index()] = lim(200.0, 500.0);
        limits[SensorId::RecycleValvePosition.index()] = lim(-0.05, 1.05);
        limits[SensorId::ThrottlePosition.index()] = lim(-0.05, 1.05);
        limits[SensorId::ThrustPosition.index()] = lim(-5e-3, 5e-3);
        CoreSettings {
            failsafe_recycle_opening: if model.recycle.is_some() { 1.0 } else { 0.0 },
            supervisor: Supervisor { limits },
        }
    }
}

/// What one cycle produced (for traces, the event log and the I/O layer).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleOutput {
    /// Setpoints to send (NaN: not driven).
    pub commands: ActuatorCommands,
    /// Measurements the laws saw.
    pub measurements: Measurements,
    /// Mode after the cycle.
    pub mode: Mode,
    /// Input validity.
    pub validity: Validity,
    /// A law-specific diagnostic (e.g. the control variable z), NaN if none.
    pub law_diagnostic: f64,
}

/// The control core.
#[derive(Debug, Clone)]
pub struct ControlCore {
    model: ControlModel,
    settings: CoreSettings,
    speed: SpeedLoop,
    law: LawId,
    mode: Mode,
    auto_requested: bool,
    last: ActuatorCommands,
    last_t_s: f64,
}

impl ControlCore {
    /// A core for a machine, starting in automatic mode with `law` once inputs are valid.
    /// `initial_torque_nm` presets the speed loop (bumpless start on a running machine).
    pub fn new(
        model: ControlModel,
        settings: CoreSettings,
        law: LawId,
        initial_torque_nm: f64,
    ) -> Self {
        let d = model.drive;
        ControlCore {
            speed: SpeedLoop::new(
                d.speed_kp_nm_s_rad,
                d.speed_ki_nm_rad,
                (d.min_torque_nm, d.rated_torque_nm),
                initial_torque_nm,
            ),
            model,
            settings,
            law,
            mode: Mode::Init,
            auto_requested: true,
            last: ActuatorCommands::default(),
            last_t_s: f64::NAN,
        }
    }

    /// The machine model.
    pub fn model(&self) -> &ControlModel {
        &self.model
    }

    /// Active law.
    pub fn law(&self) -> LawId {
        self.law
    }

    /// Current mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Select another law (bumpless: it starts from the current outputs).
    pub fn select_law(&mut self, law: LawId) {
        self.law = law;
    }

    /// Request automatic (true) or manual (false) mode.
    pub fn request_auto(&mut self, auto: bool) {
        self.auto_requested = auto;
    }

    /// Derived measurements from validated inputs.
    fn measurements(&self, t_s: f64, raw: &RawSensors, v: &Validity) -> Measurements {
        let get = |id: SensorId| {
            if v.ok(id) {
                raw.values.get(id)
            } else {
                f64::NAN
            }
        };
        let p_s = get(SensorId::PSuction);
        let p_d = get(SensorId::PDischarge);
        let t_s_k = if v.ok(SensorId::TSuction) {
            raw.values.get(SensorId::TSuction)
        } else {
            self.model.nominal_suction_temperature_k
        };
        let dp = get(SensorId::OrificeDp);
        let m_meas = self
            .model
            .orifice
            .mass_flow_kg_s(&self.model.gas, dp, p_s, t_s_k);
        let m = m_meas;
        Measurements {
            t_s,
            p_suction_pa: p_s,
            p_discharge_pa: p_d,
            omega_rad_s: get(SensorId::ShaftSpeed),
            t_suction_k: t_s_k,
            m_kg_s: m,
            m_measured_kg_s: m_meas,
            m_observer_kg_s: f64::NAN,
            flow_map: self.model.map_flow(m, p_s, t_s_k),
            pressure_ratio: p_d / p_s,
            recycle_position: get(SensorId::RecycleValvePosition),
            throttle_position: get(SensorId::ThrottlePosition),
            thrust_position_m: get(SensorId::ThrustPosition),
        }
    }

    /// Run one cycle at time `t_s`.
    pub fn cycle(&mut self, t_s: f64, raw: &RawSensors, op: &OperatorInputs) -> CycleOutput {
        let dt = if self.last_t_s.is_finite() {
            (t_s - self.last_t_s).max(0.0)
        } else {
            0.0
        };
        self.last_t_s = t_s;
        let validity = self.settings.supervisor.check(raw);
        let meas = self.measurements(t_s, raw, &validity);
        let essentials_ok = validity.ok(SensorId::PSuction)
            && validity.ok(SensorId::PDischarge)
            && validity.ok(SensorId::ShaftSpeed);
        let mut cmd = ActuatorCommands::default();
        if !essentials_ok {
            // fail-safe: recycle valve to its safe opening, thrust to centre, torque held
            self.mode = Mode::FailSafe;
            if self.model.recycle.is_some() {
                cmd.set(
                    ActuatorId::RecycleValve,
                    self.settings.failsafe_recycle_opening,
                );
            }
            if self.model.tip.is_some() {
                cmd.set(ActuatorId::TipClearance, 0.0);
            }
            if self.model.spool.is_some() {
                cmd.set(ActuatorId::CloseCoupledValve, 0.0);
            }
            let held = self.last.get(ActuatorId::DriveTorque);
            cmd.set(ActuatorId::DriveTorque, held);
            self.last = cmd;
            return CycleOutput {
                commands: cmd,
                measurements: meas,
                mode: self.mode,
                validity,
                law_diagnostic: f64::NAN,
            };
        }
        let from_failsafe = matches!(self.mode, Mode::FailSafe | Mode::Init);
        self.mode = if self.auto_requested {
            Mode::Auto
        } else {
            Mode::Manual
        };
        if from_failsafe {
            let held = self.last.get(ActuatorId::DriveTorque);
            if held.is_finite() {
                self.speed
                    .track(held, op.speed_setpoint_rad_s, meas.omega_rad_s);
            }
        }
        let extra_torque = 0.0;
        if self.mode == Mode::Manual && self.model.recycle.is_some() {
            cmd.set(ActuatorId::RecycleValve, op.recycle_manual);
        }
        let torque = self
            .speed
            .update(op.speed_setpoint_rad_s, meas.omega_rad_s, extra_torque, dt);
        cmd.set(ActuatorId::DriveTorque, torque);
        self.last = cmd;
        CycleOutput {
            commands: cmd,
            measurements: meas,
            mode: self.mode,
            validity,
            law_diagnostic: f64::NAN,
        }
    }
}
