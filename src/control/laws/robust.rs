//! `robust`: robust drive torque + close-coupled valve of seed 003 (Theorem 3, eq. 44, 46,
//! 47), on the nondimensional spool model of [`super::spool`].

use super::spool::*;
use crate::control::law::api::{
    LawError, LawId, LawInputs, LawNeeds, LawOutput, LawSpec, SurgeLaw,
};
use crate::control::model::ControlModel;
use crate::machine::params::ModelKind;
use crate::machine::MachineData;
use crate::vocab::signals::{ActuatorCommands, ActuatorId, ActuatorSet, SensorId};
use serde::{Deserialize, Serialize};

/// Settings of `robust` (`[controller.robust]`): seed 003 Theorem 3, eq. 44, 46, 47 with the
/// boundary layer of Remark 2.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RobustConfig {
    /// k of the inner loop's damping term (eq. 44 uses k = 1).
    pub x2_gain_nd: f64,
    /// δ₁: bound on the torque uncertainty |Δf| (eq. 39), units of the model torque; seed 003
    /// §IV: 0.1 for eq. 53.
    pub delta1_tau: f64,
    /// δ₂: bound on the characteristic uncertainty |ΔCss| (eq. 40), units of ψ; seed 003 §IV:
    /// 0.1 for eq. 53.
    pub delta2_psi: f64,
    /// Boundary layer of Δu₁ = −δ₁ sat(x₁/ε₁) replacing sign() (Remark 2), units of ω̃.
    pub boundary_layer_x1_omega: f64,
    /// Boundary layer of Δu₂ = −δ₂ sat(x₂/ε₂) (Remark 2), units of φ.
    pub boundary_layer_x2_phi: f64,
    /// Schedule the drive torque with the equilibrium (eq. 7), see [`CcvConfig`].
    pub torque_schedule: bool,
    /// Proportional speed trim, N·m per rad/s (not in the seed; 0 disables it).
    pub speed_trim_kp_nm_s_per_rad: f64,
    /// Integral speed trim, N·m per rad (not in the seed; 0 disables it).
    pub speed_trim_ki_nm_per_rad: f64,
    /// Decay time of the bumpless-transfer offset, s.
    pub bumpless_time_constant_s: f64,
}

impl Default for RobustConfig {
    fn default() -> Self {
        RobustConfig {
            x2_gain_nd: default_one(),
            delta1_tau: default_delta(),
            delta2_psi: default_delta(),
            boundary_layer_x1_omega: default_layer_x1(),
            boundary_layer_x2_phi: default_layer_x2(),
            torque_schedule: default_true(),
            speed_trim_kp_nm_s_per_rad: default_trim_kp(),
            speed_trim_ki_nm_per_rad: default_trim_ki(),
            bumpless_time_constant_s: default_bumpless_s(),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// robust
// ---------------------------------------------------------------------------------------------

/// `robust`: drive torque and close-coupled valve (seed 003 Theorem 3): inner loop eq. 44,
/// outer loop eq. 46–47 with a boundary layer (Remark 2), on top of the eq. 7 torque schedule.
#[derive(Debug, Clone)]
pub struct Robust {
    pub(super) k2: f64,
    pub(super) delta1: f64,
    pub(super) delta2: f64,
    pub(super) eps1: f64,
    pub(super) eps2: f64,
    pub(super) c: Common,
}

impl Robust {
    /// A reload of the running law: take over its torque reference, trim and equilibrium
    /// cache (see `Common::take_over`); the core still starts it bumplessly.
    pub(crate) fn take_over_from(&mut self, running: &Robust) {
        self.c.take_over(&running.c);
    }

    /// Build for a machine.
    pub fn new(cfg: &RobustConfig, model: &ControlModel) -> Result<Self, LawError> {
        let law = LawId::Robust;
        let sp = Spool::from_model(law, model)?;
        check_common(
            law,
            "robust",
            cfg.x2_gain_nd,
            (cfg.speed_trim_kp_nm_s_per_rad, cfg.speed_trim_ki_nm_per_rad),
            cfg.bumpless_time_constant_s,
        )?;
        for (key, v) in [
            ("robust.delta1_tau", cfg.delta1_tau),
            ("robust.delta2_psi", cfg.delta2_psi),
        ] {
            check(law, key, v.is_finite() && v >= 0.0, "must be ≥ 0")?;
        }
        for (key, v) in [
            (
                "robust.boundary_layer_x1_omega",
                cfg.boundary_layer_x1_omega,
            ),
            ("robust.boundary_layer_x2_phi", cfg.boundary_layer_x2_phi),
        ] {
            check(law, key, v.is_finite() && v > 0.0, "must be > 0")?;
        }
        Ok(Robust {
            k2: cfg.x2_gain_nd,
            delta1: cfg.delta1_tau,
            delta2: cfg.delta2_psi,
            eps1: cfg.boundary_layer_x1_omega,
            eps2: cfg.boundary_layer_x2_phi,
            c: Common::new(
                sp,
                cfg.torque_schedule,
                (cfg.speed_trim_kp_nm_s_per_rad, cfg.speed_trim_ki_nm_per_rad),
                cfg.bumpless_time_constant_s,
            ),
        })
    }

    /// (u₁, u₂) before offsets and limits.
    pub(super) fn law(&self, fr: &Frame) -> (f64, f64) {
        // inner loop eq. 44 as corrected by ERRATA: ū₂ = −x₁ f̃ − C̄ss − k x₂ (the printed
        // −x₁ f̄ would not give eq. 45); the controller's model is the nominal one
        let u2_bar = ccv_nominal(&self.c.sp, fr, self.k2);
        // outer loop eq. 46–47 with the boundary layer of Remark 2 instead of sign()
        let du1 = -self.delta1 * sat(fr.x1, self.eps1);
        let du2 = -self.delta2 * sat(fr.x2, self.eps2);
        (du1, u2_bar + du2)
    }
}

impl SurgeLaw for Robust {
    fn start(&mut self, inputs: &LawInputs<'_>, current: &ActuatorCommands) {
        if let Some(fr) = self.c.frame(inputs) {
            let (u1, u2) = self.law(&fr);
            self.c
                .start(&fr, u1, u2, current_ccv(current), current_torque(current));
        }
    }

    fn update(&mut self, inputs: &LawInputs<'_>, dt_s: f64) -> LawOutput {
        let Some(fr) = self.c.frame(inputs) else {
            return LawOutput::idle();
        };
        let (u1, u2) = self.law(&fr);
        if !self.c.tau_ref.is_finite() {
            self.c.start(&fr, u1, u2, 0.0, 0.0);
        }
        let sp = self.c.sp;
        let u2 = (u2 + self.c.offset_valve).clamp(-sp.ccv_max, sp.ccv_max);
        let torque = self.c.torque_out(&fr, u1, dt_s);
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

impl LawSpec for Robust {
    type Settings = RobustConfig;
    const NEEDS: LawNeeds = LawNeeds {
        summary: "robust torque + close-coupled valve (seed 003 Theorem 3)",
        actuators: ActuatorSet::of(&[ActuatorId::DriveTorque, ActuatorId::CloseCoupledValve]),
        sensors: &[SensorId::ShaftSpeed],
        needs_flow: true,
        machine_data: &[
            MachineData::SpeedLineMap,
            MachineData::OwnedDrive,
            MachineData::Model(ModelKind::Spool),
        ],
        model_family: Some(ModelKind::Spool),
    };
    fn build(settings: &Self::Settings, model: &ControlModel) -> Result<Self, LawError> {
        Robust::new(settings, model)
    }

    fn carry_over(&mut self, running: &Self) -> bool {
        // the torque reference and trim carry over; the core still starts it bumplessly
        self.take_over_from(running);
        false
    }
}
