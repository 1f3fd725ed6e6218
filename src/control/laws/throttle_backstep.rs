//! `throttle-backstep`: the throttle backstepping law of seed 003 (Theorem 2, eq. 30–37/52),
//! on the nondimensional spool model of [`super::spool`].

use super::spool::*;
use crate::control::law::api::{
    LawError, LawId, LawInputs, LawNeeds, LawOutput, LawSpec, SurgeLaw,
};
use crate::control::model::ControlModel;
use crate::machine::params::ModelKind;
use crate::machine::MachineData;
use crate::vocab::signals::{ActuatorCommands, ActuatorId, ActuatorSet, SensorId};
use serde::{Deserialize, Serialize};

/// Settings of `throttle-backstep` (`[controller.throttle_backstep]`): seed 003 Theorem 2,
/// eq. 30–37 with the instance eq. 52.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ThrottleBackstepConfig {
    /// k of the virtual control x₃d = x₁ f̃ + Css + k·x₂ (eq. 30, 52 use k = 1).
    pub x2_gain_nd: f64,
    /// k_ξ of the error feedback: V₃ = −k_ξ ξ² (eq. 37 uses k_ξ = 1, giving ξ̇ = c̄ (x₂ − ξ),
    /// eq. 51).
    pub xi_gain_nd: f64,
    /// Smallest pressure rise used in the division by √ψ of eq. 37 (units of ψ).
    pub min_pressure_rise_psi: f64,
    /// Schedule the drive torque with the equilibrium (eq. 7), see [`CcvConfig`].
    pub torque_schedule: bool,
    /// Proportional speed trim, N·m per rad/s (not in the seed; 0 disables it).
    pub speed_trim_kp_nm_s_per_rad: f64,
    /// Integral speed trim, N·m per rad (not in the seed; 0 disables it).
    pub speed_trim_ki_nm_per_rad: f64,
    /// Decay time of the bumpless-transfer offset, s.
    pub bumpless_time_constant_s: f64,
}

impl Default for ThrottleBackstepConfig {
    fn default() -> Self {
        ThrottleBackstepConfig {
            x2_gain_nd: default_one(),
            xi_gain_nd: default_one(),
            min_pressure_rise_psi: default_min_psi(),
            torque_schedule: default_true(),
            speed_trim_kp_nm_s_per_rad: default_trim_kp(),
            speed_trim_ki_nm_per_rad: default_trim_ki(),
            bumpless_time_constant_s: default_bumpless_s(),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// throttle-backstep
// ---------------------------------------------------------------------------------------------

/// `throttle-backstep`: throttle only (seed 003 Theorem 2, eq. 30–37 with eq. 52), with the
/// eq. 7 torque schedule.
#[derive(Debug, Clone)]
pub struct ThrottleBackstep {
    pub(super) k2: f64,
    pub(super) k_xi: f64,
    pub(super) min_psi: f64,
    pub(super) c: Common,
}

/// What the backstepping law computes in one cycle.
#[derive(Debug, Clone, Copy)]
pub(super) struct Backstep {
    /// Throttle opening command (before offset and limits).
    pub(super) opening: f64,
    /// ξ = x₃ − x₃d.
    pub(super) xi: f64,
}

impl ThrottleBackstep {
    /// A reload of the running law: take over its torque reference, trim and equilibrium
    /// cache (see `Common::take_over`); the core still starts it bumplessly.
    pub(crate) fn take_over_from(&mut self, running: &ThrottleBackstep) {
        self.c.take_over(&running.c);
    }

    /// Build for a machine.
    pub fn new(cfg: &ThrottleBackstepConfig, model: &ControlModel) -> Result<Self, LawError> {
        let law = LawId::ThrottleBackstep;
        let sp = Spool::from_model(law, model)?;
        check_common(
            law,
            "throttle_backstep",
            cfg.x2_gain_nd,
            (cfg.speed_trim_kp_nm_s_per_rad, cfg.speed_trim_ki_nm_per_rad),
            cfg.bumpless_time_constant_s,
        )?;
        check(
            law,
            "throttle_backstep.xi_gain_nd",
            cfg.xi_gain_nd.is_finite() && cfg.xi_gain_nd > 0.0,
            "must be > 0 (V₃ must be negative definite, seed 003 eq. 36)",
        )?;
        check(
            law,
            "throttle_backstep.min_pressure_rise_psi",
            cfg.min_pressure_rise_psi.is_finite() && cfg.min_pressure_rise_psi > 0.0,
            "must be > 0",
        )?;
        let mut c = Common::new(
            sp,
            cfg.torque_schedule,
            (cfg.speed_trim_kp_nm_s_per_rad, cfg.speed_trim_ki_nm_per_rad),
            cfg.bumpless_time_constant_s,
        );
        c.gamma_from_position = false;
        Ok(ThrottleBackstep {
            k2: cfg.x2_gain_nd,
            k_xi: cfg.xi_gain_nd,
            min_psi: cfg.min_pressure_rise_psi,
            c,
        })
    }

    pub(super) fn law(&self, fr: &Frame) -> Backstep {
        let sp = &self.c.sp;
        let k = self.k2;
        // virtual control, eq. 30 / 52: x₃d = x₁ f̃ + Css + k x₂ = −σ x₁ (x₁ + ω̃⁰) + Css + k x₂
        let x3d = fr.x1 * fr.f_tilde(sp) + fr.css + k * fr.x2;
        let xi = fr.x3 - x3d;
        // ẋ₃d from the model (analytic, no numerical differentiation):
        // ∂x₃d/∂x₁ = −σ (2x₁ + ω̃⁰) + ∂ψc/∂ω̃,  ∂x₃d/∂x₂ = ∂ψc/∂φ + k,
        // ẋ₁ = ā f(x₁, x₂) (eq. 26, u₁ = 0: the drive holds τ⁰), ẋ₂ = b̄ (Css − x₃) (eq. 27)
        let omega = fr.x1 + fr.omega0;
        let phi = fr.x2 + fr.phi0;
        let f = sp.gamma_torque(fr.phi0, fr.omega0) - sp.gamma_torque(phi, omega); // eq. 14
        let x1_dot = sp.a_bar * f;
        let x2_dot = sp.b_bar * (fr.css - fr.x3);
        let x3d_dot = (-sp.sigma * (2.0 * fr.x1 + fr.omega0) + fr.pc.d_domega) * x1_dot
            + (fr.pc.d_dphi + k) * x2_dot;
        // eq. 37 (with gain k_ξ on ξ): F(γ, ψ) = F(γ⁰, ψ⁰) − ẋ₃d/c̄ + k_ξ ξ makes
        // V₃ = −k_ξ ξ² (eq. 36) and ξ̇ = c̄ (x₂ − k_ξ ξ) (eq. 51); with F = γ √ψ:
        // u₃ = [γ⁰ (√ψ⁰ − √ψ) − ẋ₃d/c̄ + k_ξ ξ] / √ψ
        let sq = (fr.x3 + fr.psi0).max(self.min_psi).sqrt();
        let sq0 = fr.psi0.max(0.0).sqrt();
        let u3 = (fr.gamma0 * (sq0 - sq) - x3d_dot / sp.c_bar + self.k_xi * xi) / sq;
        Backstep {
            opening: (fr.gamma0 + u3) / sp.gamma_max,
            xi,
        }
    }
}

impl SurgeLaw for ThrottleBackstep {
    fn start(&mut self, inputs: &LawInputs<'_>, current: &ActuatorCommands) {
        if let Some(fr) = self.c.frame(inputs) {
            let raw = self.law(&fr).opening;
            let cur = current.get(ActuatorId::Throttle);
            let cur = if cur.is_finite() { cur } else { raw };
            self.c.start(&fr, 0.0, raw, cur, current_torque(current));
        }
    }

    fn update(&mut self, inputs: &LawInputs<'_>, dt_s: f64) -> LawOutput {
        let Some(fr) = self.c.frame(inputs) else {
            return LawOutput::idle();
        };
        let b = self.law(&fr);
        if !self.c.tau_ref.is_finite() {
            let cur = inputs.m.throttle_position;
            let cur = if cur.is_finite() { cur } else { b.opening };
            self.c.start(&fr, 0.0, b.opening, cur, 0.0);
        }
        let opening = (b.opening + self.c.offset_valve).clamp(0.0, 1.0);
        let torque = self.c.torque_out(&fr, 0.0, dt_s); // u₁ = 0 (Theorem 2)
        self.c.decay(dt_s);
        let mut commands = ActuatorCommands::default();
        commands.set(ActuatorId::DriveTorque, torque);
        commands.set(ActuatorId::Throttle, opening);
        LawOutput {
            commands,
            // V of eq. 34 (in x₁, x₂, ξ)
            diagnostic: fr.lyapunov(&self.c.sp, b.xi),
            event: None,
        }
    }
}

impl LawSpec for ThrottleBackstep {
    type Settings = ThrottleBackstepConfig;
    const NEEDS: LawNeeds = LawNeeds {
        summary: "throttle backstepping (seed 003 Theorem 2)",
        actuators: ActuatorSet::of(&[ActuatorId::Throttle]),
        sensors: &[SensorId::ShaftSpeed],
        needs_flow: true,
        machine_data: &[
            MachineData::SpeedLineMap,
            MachineData::Model(ModelKind::Spool),
        ],
        model_family: Some(ModelKind::Spool),
    };
    fn build(settings: &Self::Settings, model: &ControlModel) -> Result<Self, LawError> {
        ThrottleBackstep::new(settings, model)
    }

    fn carry_over(&mut self, running: &Self) -> bool {
        // the torque reference and trim carry over; the core still starts it bumplessly
        self.take_over_from(running);
        false
    }
}
