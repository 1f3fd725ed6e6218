//! `ccv`: the close-coupled valve law of seed 003 (Theorem 1, eq. 25/48), on the
//! nondimensional spool model of [`super::spool`].

use super::spool::*;
use crate::control::law::api::{
    LawError, LawId, LawInputs, LawNeeds, LawOutput, LawSpec, SurgeLaw,
};
use crate::control::model::ControlModel;
use crate::machine::params::ModelKind;
use crate::machine::MachineData;
use crate::vocab::signals::{ActuatorCommands, ActuatorId, ActuatorSet, SensorId};
use serde::{Deserialize, Serialize};

/// Settings of `ccv` (`[controller.ccv]`): seed 003 Theorem 1, eq. 25 with the instance eq. 48.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CcvConfig {
    /// k of the damping term u(x₂) = k·x₂ in eq. 25 (any u with x₂ u(x₂) > 0 is allowed);
    /// eq. 48 uses k = 1.
    pub x2_gain_nd: f64,
    /// Schedule the drive torque with the equilibrium, τ_t = Γ(φ⁰, ω̃⁰) (eq. 7), so that x⁰ is an
    /// equilibrium at the speed setpoint when the throttle demand moves.
    pub torque_schedule: bool,
    /// Proportional part of the speed trim added to the drive torque, N·m per rad/s of speed
    /// error (ω_set − ω); not in the seed (u₁ = 0 there), 0 disables it.
    pub speed_trim_kp_nm_s_per_rad: f64,
    /// Integral part of the speed trim, N·m per rad (d torque/dt = k·(ω_set − ω)); not in the
    /// seed, 0 disables it.
    pub speed_trim_ki_nm_per_rad: f64,
    /// Decay time of the bumpless-transfer offset, s.
    pub bumpless_time_constant_s: f64,
}

impl Default for CcvConfig {
    fn default() -> Self {
        CcvConfig {
            x2_gain_nd: default_one(),
            torque_schedule: default_true(),
            speed_trim_kp_nm_s_per_rad: default_trim_kp(),
            speed_trim_ki_nm_per_rad: default_trim_ki(),
            bumpless_time_constant_s: default_bumpless_s(),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// ccv
// ---------------------------------------------------------------------------------------------

/// `ccv`: close-coupled valve only (seed 003 Theorem 1, eq. 25/48), with the eq. 7 torque
/// schedule.
#[derive(Debug, Clone)]
pub struct Ccv {
    pub(super) cfg_k: f64,
    pub(super) c: Common,
}

impl Ccv {
    /// A reload of the running law: take over its torque reference, trim and equilibrium
    /// cache (see `Common::take_over`); the core still starts it bumplessly.
    pub(crate) fn take_over_from(&mut self, running: &Ccv) {
        self.c.take_over(&running.c);
    }

    /// Build for a machine.
    pub fn new(cfg: &CcvConfig, model: &ControlModel) -> Result<Self, LawError> {
        let sp = Spool::from_model(LawId::Ccv, model)?;
        check_common(
            LawId::Ccv,
            "ccv",
            cfg.x2_gain_nd,
            (cfg.speed_trim_kp_nm_s_per_rad, cfg.speed_trim_ki_nm_per_rad),
            cfg.bumpless_time_constant_s,
        )?;
        Ok(Ccv {
            cfg_k: cfg.x2_gain_nd,
            c: Common::new(
                sp,
                cfg.torque_schedule,
                (cfg.speed_trim_kp_nm_s_per_rad, cfg.speed_trim_ki_nm_per_rad),
                cfg.bumpless_time_constant_s,
            ),
        })
    }

    pub(super) fn raw_ccv(&self, fr: &Frame) -> f64 {
        ccv_nominal(&self.c.sp, fr, self.cfg_k)
    }
}

impl SurgeLaw for Ccv {
    fn start(&mut self, inputs: &LawInputs<'_>, current: &ActuatorCommands) {
        if let Some(fr) = self.c.frame(inputs) {
            let raw = self.raw_ccv(&fr);
            self.c
                .start(&fr, 0.0, raw, current_ccv(current), current_torque(current));
        }
    }

    fn update(&mut self, inputs: &LawInputs<'_>, dt_s: f64) -> LawOutput {
        let Some(fr) = self.c.frame(inputs) else {
            return LawOutput::idle();
        };
        if !self.c.tau_ref.is_finite() {
            // started without measurements: start now
            let raw = self.raw_ccv(&fr);
            self.c.start(&fr, 0.0, raw, 0.0, 0.0);
        }
        let sp = self.c.sp;
        let u2 = (self.raw_ccv(&fr) + self.c.offset_valve).clamp(-sp.ccv_max, sp.ccv_max);
        let torque = self.c.torque_out(&fr, 0.0, dt_s); // u₁ = 0 (Theorem 1)
        self.c.decay(dt_s);
        let mut commands = ActuatorCommands::default();
        commands.set(ActuatorId::DriveTorque, torque);
        commands.set(ActuatorId::CloseCoupledValve, u2);
        LawOutput {
            commands,
            diagnostic: fr.lyapunov(&sp, fr.x3),
            event: None,
        }
    }
}

impl LawSpec for Ccv {
    type Settings = CcvConfig;
    const NEEDS: LawNeeds = LawNeeds {
        summary: "close-coupled valve (seed 003 Theorem 1)",
        actuators: ActuatorSet::of(&[ActuatorId::CloseCoupledValve]),
        sensors: &[SensorId::ShaftSpeed],
        needs_flow: true,
        machine_data: &[
            MachineData::SpeedLineMap,
            MachineData::Model(ModelKind::Spool),
        ],
        model_family: Some(ModelKind::Spool),
    };
    fn build(settings: &Self::Settings, model: &ControlModel) -> Result<Self, LawError> {
        Ccv::new(settings, model)
    }

    fn carry_over(&mut self, running: &Self) -> bool {
        // the torque reference and trim carry over; the core still starts it bumplessly
        self.take_over_from(running);
        false
    }
}
