//! What the seed 003 (Liaw, Song & Huang) laws on the nondimensional spool model share: the
//! nondimensional machine, the equilibrium, the torque schedule and the bumpless offsets of
//! `ccv` ([`super::ccv`]), `throttle-backstep` ([`super::throttle_backstep`]) and `robust`
//! ([`super::robust`]).
//!
//! The model (seed 003 eq. 4–6, `src/plant/spool.rs`), with Γ = σ φ ω̃ and F = γ √ψ:
//!
//! ```text
//! dω̃/dτ = ā (τ_t − Γ(φ, ω̃))      dφ/dτ = b̄ (ψc(φ, ω̃) − ψ + u₂)      dψ/dτ = c̄ (φ − F(γ, ψ))
//! ```
//!
//! In deviation coordinates x₁ = ω̃ − ω̃⁰, x₂ = φ − φ⁰, x₃ = ψ − ψ⁰ (eq. 10–14):
//! ẋ₁ = ā (f(x₁, x₂) + u₁), ẋ₂ = b̄ (Css − x₃ + u₂), ẋ₃ = c̄ (x₂ + F(γ⁰, ψ⁰) − F(γ⁰ + u₃, ψ)),
//! with Css = ψc(φ, ω̃) − ψc(φ⁰, ω̃⁰) and f = Γ(φ⁰, ω̃⁰) − Γ(φ, ω̃). For Γ = σ φ ω̃ the
//! decomposition eq. 21 is f = f(x₁, 0) + x₂ f̃ with f(x₁, 0) = −σ φ⁰ x₁ and
//! f̃ = −σ (x₁ + ω̃⁰).
//!
//! * `ccv` (Theorem 1, eq. 25, instance eq. 48): u₂ = −x₁ f̃ − Css − k x₂
//!   = σ x₁ (x₁ + ω̃⁰) − Css − k x₂, which gives V̇ = x₁ f(x₁, 0) − k x₂² + x₃ (F⁰ − F) ≤ 0 for
//!   V = ½ (x₁²/ā + x₂²/b̄ + x₃²/c̄) (eq. 22 with the bars ERRATA restores).
//! * `throttle-backstep` (Theorem 2): virtual control x₃d = x₁ f̃ + Css + k x₂ (eq. 30, 52),
//!   ξ = x₃ − x₃d, and eq. 37 with a gain k_ξ: u₃ = [γ⁰ (√ψ⁰ − √ψ) − ẋ₃d/c̄ + k_ξ ξ]/√ψ, so that
//!   ξ̇ = c̄ (x₂ − k_ξ ξ) (eq. 51). ẋ₃d is computed from the model (eq. 26–27), not by numerical
//!   differentiation.
//! * `robust` (Theorem 3): inner loop ū₂ = −x₁ f̃ − C̄ss − k x₂ (eq. 44 with f̃, not the printed
//!   f̄: only f̃ gives eq. 45, ERRATA), outer loop Δu₁ = −δ₁ sat(x₁/ε₁), Δu₂ = −δ₂ sat(x₂/ε₂)
//!   (eq. 46–47 with the boundary layer of Remark 2 instead of sign()).
//!
//! Every command is saturated to the plant file's ratings: |u₂| ≤ `spool.ccv_max`, throttle
//! opening in [0, 1], extra drive torque within ±(rated − min) (the speed loop and the drive clamp
//! the total torque to [min, rated]).
//!
//! **Equilibrium.** x⁰ follows the operator at the speed setpoint: ω̃⁰ = setpoint / speed_scale,
//! γ⁰ = gamma_max · opening, and (φ⁰, ψ⁰) solve eq. 8–9, F(γ⁰, ψc(φ⁰, ω̃⁰)) = φ⁰ (rightmost root,
//! fixed-iteration scan and bisection, allocation-free, recomputed only when γ⁰ or ω̃⁰ change).
//! The throttle law takes the opening from the operator's demand (it modulates around it,
//! γ = γ⁰ + u₃); `ccv` and `robust` do not drive the throttle, so for them γ = γ⁰ is the
//! throttle's actual opening (position feedback, which follows the demand through the
//! positioner; the demand if the feedback is missing). ψc is read from the controller's SI map,
//! of which the nondimensional characteristic is the exact image:
//! ψc(φ, ω̃) = (Ψ_SI(φ·flow_scale, ω̃·speed_scale) − 1) · p01 / pressure_scale.
//!
//! **Drive torque (additions to the seed).** Seed 003 holds τ_t = τ⁰ = Γ(φ⁰, ω̃⁰) (eq. 7) and
//! u₁ = τ_t − τ⁰. When x⁰ moves with the throttle, τ⁰ moves with it, so every law schedules the
//! drive torque by eq. 7 (`torque_schedule`), added to the speed loop, which on this plant has
//! zero gains and holds a constant torque. That held torque is not a law input: the law takes it
//! as τ⁰ of the operating point in force when it starts (exact when it starts from a steady
//! state) and an optional PI speed trim, v = −k_p x₁ − k_i ∫x₁, corrects a mismatch e.
//! Derivation: the P part adds −k_p x₁² to V̇; for the I part, V + (e + v_I)²/(2 k_i) has the
//! same derivative as V, so the Lyapunov arguments of Theorems 1–3 are unchanged and LaSalle
//! gives x → 0, e + v_I → 0. The trim defaults to 0 (the seed's u₁ = 0); the plant file tunes it.
//!
//! **Bumpless start.** The laws are static state feedback apart from the trim. At start, the
//! difference between the outputs applied now and the law's outputs is held as an offset that
//! decays with `bumpless_time_constant_s`: the first output equals the current one.
//!
//! **Units of the settings.** The laws work in the seed's nondimensional units: keys ending in
//! `_psi` are in units of ψ (pressure_scale_pa), `_phi` of φ (flow_scale_kg_s), `_omega` of ω̃
//! (speed_scale_rad_s), `_tau` of the model torque (torque_scale_nm); `_nd` is a pure number.

use crate::control::law::api::{LawError, LawId, LawInputs};
use crate::control::model::ControlModel;
use crate::physics::compressor_map::CompressorMap;
use crate::physics::spool_throttle::throttle_function;
use crate::vocab::signals::{ActuatorCommands, ActuatorId};

// ---------------------------------------------------------------------------------------------
// Settings
// ---------------------------------------------------------------------------------------------

// Defaults: the seed's values where it gives them (k = 1 of eq. 48/52, k_ξ = 1 of eq. 37,
// δ₁ = δ₂ = 0.1 for eq. 53, u₁ = 0 i.e. no speed trim); chosen otherwise (boundary layers,
// bumpless decay, the √ψ guard).
pub(super) fn default_true() -> bool {
    true
}
pub(super) fn default_one() -> f64 {
    1.0
}
pub(super) fn default_bumpless_s() -> f64 {
    0.1
}
pub(super) fn default_trim_kp() -> f64 {
    0.0
}
pub(super) fn default_trim_ki() -> f64 {
    0.0
}
pub(super) fn default_min_psi() -> f64 {
    0.02
}
pub(super) fn default_delta() -> f64 {
    0.1
}
pub(super) fn default_layer_x1() -> f64 {
    0.01
}
pub(super) fn default_layer_x2() -> f64 {
    0.01
}

pub(super) fn check(law: LawId, key: &str, ok: bool, message: &str) -> Result<(), LawError> {
    if ok {
        Ok(())
    } else {
        Err(LawError::Setting {
            law,
            key: key.to_string(),
            message: message.to_string(),
        })
    }
}

pub(super) fn check_common(
    law: LawId,
    section: &str,
    x2_gain: f64,
    (kp, trim): (f64, f64),
    bumpless: f64,
) -> Result<(), LawError> {
    check(
        law,
        &format!("{section}.speed_trim_kp_nm_s_per_rad"),
        kp.is_finite() && kp >= 0.0,
        "must be ≥ 0",
    )?;
    check(
        law,
        &format!("{section}.x2_gain_nd"),
        x2_gain.is_finite() && x2_gain > 0.0,
        "must be > 0 (x₂ u(x₂) must be positive definite, seed 003 eq. 25)",
    )?;
    check(
        law,
        &format!("{section}.speed_trim_ki_nm_per_rad"),
        trim.is_finite() && trim >= 0.0,
        "must be ≥ 0",
    )?;
    check(
        law,
        &format!("{section}.bumpless_time_constant_s"),
        bumpless.is_finite() && bumpless > 0.0,
        "must be > 0",
    )
}

// ---------------------------------------------------------------------------------------------
// The nondimensional machine and the equilibrium
// ---------------------------------------------------------------------------------------------

/// ψc and its partial derivatives in nondimensional units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct PsiC {
    pub(super) value: f64,
    pub(super) d_dphi: f64,
    pub(super) d_domega: f64,
}

/// The controller's nondimensional view of the machine (seed 003 eq. 4–6), from the plant file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Spool {
    pub(super) a_bar: f64,
    pub(super) b_bar: f64,
    pub(super) c_bar: f64,
    pub(super) sigma: f64,
    pub(super) gamma_max: f64,
    pub(super) time_scale_s: f64,
    pub(super) pressure_scale_pa: f64,
    pub(super) flow_scale_kg_s: f64,
    pub(super) speed_scale_rad_s: f64,
    pub(super) torque_scale_nm: f64,
    /// p01 / pressure_scale: converts pressure-ratio rise to ψ.
    pub(super) ratio_to_psi: f64,
    pub(super) ccv_max: f64,
    pub(super) torque_min_nm: f64,
    pub(super) torque_max_nm: f64,
}

impl Spool {
    pub(super) fn from_model(law: LawId, model: &ControlModel) -> Result<Spool, LawError> {
        let s = model.spool.ok_or_else(|| LawError::NotApplicable {
            law,
            plant: model.name.clone(),
            kind: model.kind,
        })?;
        Ok(Spool {
            a_bar: s.a_bar,
            b_bar: s.b_bar,
            c_bar: s.c_bar,
            sigma: s.torque_coefficient,
            gamma_max: s.gamma_max,
            time_scale_s: s.time_scale_s,
            pressure_scale_pa: s.pressure_scale_pa,
            flow_scale_kg_s: s.flow_scale_kg_s,
            speed_scale_rad_s: s.speed_scale_rad_s,
            torque_scale_nm: s.torque_scale_nm,
            ratio_to_psi: s.ambient_pressure_pa / s.pressure_scale_pa,
            ccv_max: s.ccv_max,
            torque_min_nm: model.drive.min_torque_nm,
            torque_max_nm: model.drive.rated_torque_nm,
        })
    }

    /// ψc(φ, ω̃) from the SI map (its exact image, see the module doc).
    #[inline]
    pub(super) fn psi_c(&self, map: &CompressorMap, phi: f64, omega: f64) -> PsiC {
        let p = map.eval(phi * self.flow_scale_kg_s, omega * self.speed_scale_rad_s);
        PsiC {
            value: (p.value - 1.0) * self.ratio_to_psi,
            d_dphi: p.d_dflow * self.flow_scale_kg_s * self.ratio_to_psi,
            d_domega: p.d_domega * self.speed_scale_rad_s * self.ratio_to_psi,
        }
    }

    /// Steady state (φ⁰, ψ⁰) of eq. 8–9 at throttle gain γ⁰ and speed ω̃⁰: the rightmost root of
    /// F(γ⁰, ψc(φ, ω̃⁰)) − φ (scan down from four times the peak flow in 200 steps, then 50
    /// bisections; fixed work, no allocation).
    pub(super) fn equilibrium(&self, map: &CompressorMap, gamma0: f64, omega0: f64) -> (f64, f64) {
        let r = |phi: f64| throttle_function(gamma0, self.psi_c(map, phi, omega0).value) - phi;
        let peak = map
            .peak(omega0 * self.speed_scale_rad_s)
            .map_or(1.0, |(q, _)| q / self.flow_scale_kg_s);
        let hi = 4.0 * peak.max(1e-3);
        const N: usize = 200;
        let (mut a, mut b) = (0.0, hi);
        for i in (0..N).rev() {
            let phi = hi * i as f64 / N as f64;
            if r(phi) >= 0.0 {
                a = phi;
                b = hi * (i + 1) as f64 / N as f64;
                break;
            }
        }
        for _ in 0..50 {
            let m = 0.5 * (a + b);
            if r(m) >= 0.0 {
                a = m;
            } else {
                b = m;
            }
        }
        let phi0 = 0.5 * (a + b);
        (phi0, self.psi_c(map, phi0, omega0).value)
    }

    /// The same root as [`Spool::equilibrium`] by at most 8 Newton steps from `guess` (the
    /// previous φ⁰). Accepted only if it converges to a root where the residual is falling,
    /// i.e. the rightmost branch it started on; `None` otherwise (the caller scans).
    pub(super) fn equilibrium_newton(
        &self,
        map: &CompressorMap,
        gamma0: f64,
        omega0: f64,
        guess: f64,
    ) -> Option<(f64, f64)> {
        let mut phi = guess;
        for _ in 0..8 {
            let pc = self.psi_c(map, phi, omega0);
            if pc.value <= 0.0 {
                return None;
            }
            let sq = pc.value.sqrt();
            let r = gamma0 * sq - phi;
            let dr = gamma0 * pc.d_dphi / (2.0 * sq) - 1.0;
            if dr >= 0.0 {
                return None;
            }
            let step = r / dr;
            phi -= step;
            if step.abs() <= 1e-13 * phi.abs().max(1e-6) {
                let psi0 = self.psi_c(map, phi, omega0).value;
                return (phi > 0.0 && psi0 > 0.0).then_some((phi, psi0));
            }
        }
        None
    }

    /// Γ(φ, ω̃) = σ φ ω̃ (seed 003 eq. 48, after its ref. [3]).
    #[inline]
    pub(super) fn gamma_torque(&self, phi: f64, omega: f64) -> f64 {
        self.sigma * phi * omega
    }
}

/// One cycle's state in the seed's coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Frame {
    pub(super) omega0: f64,
    pub(super) phi0: f64,
    pub(super) psi0: f64,
    pub(super) gamma0: f64,
    /// τ⁰ = Γ(φ⁰, ω̃⁰) (eq. 7).
    pub(super) tau0: f64,
    pub(super) x1: f64,
    pub(super) x2: f64,
    pub(super) x3: f64,
    /// ψc and its slopes at the measured (φ, ω̃).
    pub(super) pc: PsiC,
    /// Css(x₁, x₂) (eq. 13).
    pub(super) css: f64,
}

impl Frame {
    /// f̃(x₁, x₂) of the decomposition eq. 21 for Γ = σ φ ω̃: f̃ = −σ (x₁ + ω̃⁰).
    #[inline]
    pub(super) fn f_tilde(&self, sp: &Spool) -> f64 {
        -sp.sigma * (self.x1 + self.omega0)
    }

    /// V of eq. 22 (with the bars ERRATA restores): ½ (x₁²/ā + x₂²/b̄ + x₃²/c̄).
    #[inline]
    pub(super) fn lyapunov(&self, sp: &Spool, x3: f64) -> f64 {
        0.5 * (self.x1 * self.x1 / sp.a_bar + self.x2 * self.x2 / sp.b_bar + x3 * x3 / sp.c_bar)
    }
}

/// The equilibrium and the torque schedule shared by the laws.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Common {
    pub(super) sp: Spool,
    pub(super) torque_schedule: bool,
    /// γ⁰ from the throttle position feedback (laws that do not drive the throttle) rather than
    /// the demand.
    pub(super) gamma_from_position: bool,
    pub(super) trim_kp_nm_s_per_rad: f64,
    pub(super) trim_ki_nm_per_rad: f64,
    pub(super) bumpless_tau_s: f64,
    /// Cache key of the equilibrium: (γ⁰, ω̃⁰).
    pub(super) key: (f64, f64),
    /// (φ⁰, ψ⁰) for `key`.
    pub(super) eq: (f64, f64),
    /// τ⁰ the speed loop is taken to hold (set at start), model torque units.
    pub(super) tau_ref: f64,
    /// Integral speed trim, N·m.
    pub(super) trim_nm: f64,
    /// Bumpless offsets: drive torque (N·m), the law's valve (CCV ψ units or throttle opening).
    pub(super) offset_torque_nm: f64,
    pub(super) offset_valve: f64,
    /// τ_ref and the trim were taken over from the running law (a reload): `start` keeps them.
    pub(super) taken_over: bool,
}

impl Common {
    pub(super) fn new(
        sp: Spool,
        torque_schedule: bool,
        (kp, ki): (f64, f64),
        bumpless_s: f64,
    ) -> Common {
        Common {
            sp,
            torque_schedule,
            gamma_from_position: true,
            trim_kp_nm_s_per_rad: kp,
            trim_ki_nm_per_rad: ki,
            bumpless_tau_s: bumpless_s,
            key: (f64::NAN, f64::NAN),
            eq: (f64::NAN, f64::NAN),
            tau_ref: f64::NAN,
            trim_nm: 0.0,
            offset_torque_nm: 0.0,
            offset_valve: 0.0,
            taken_over: false,
        }
    }

    /// The cycle's frame, or None without a usable measurement or throttle demand.
    pub(super) fn frame(&mut self, inputs: &LawInputs<'_>) -> Option<Frame> {
        let sp = self.sp;
        let m = inputs.m;
        // γ⁰: a law that does not drive the throttle sees γ = γ⁰ (u₃ = 0 in eq. 12), i.e. the
        // throttle's actual opening, which follows the operator's demand through the positioner;
        // the throttle law modulates around the demand itself (γ = γ⁰ + u₃)
        let (first, second) = if self.gamma_from_position {
            (m.throttle_position, inputs.op.throttle_demand)
        } else {
            (inputs.op.throttle_demand, m.throttle_position)
        };
        let demand = if first.is_finite() { first } else { second };
        let mut omega0 = inputs.op.speed_setpoint_rad_s / sp.speed_scale_rad_s;
        if !omega0.is_finite() {
            omega0 = self.key.1;
        }
        let gamma0 = if demand.is_finite() {
            sp.gamma_max * demand.clamp(0.0, 1.0)
        } else {
            self.key.0
        };
        if !(gamma0.is_finite() && omega0.is_finite()) {
            return None;
        }
        if (gamma0, omega0) != self.key {
            let had = self.key.0.is_finite() && self.eq.0.is_finite() && self.eq.0 > 0.0;
            self.key = (gamma0, omega0);
            // warm start from the previous steady state while the throttle moves (a few Newton
            // steps), the full scan otherwise or when Newton does not land on the same branch
            self.eq = match had
                .then(|| sp.equilibrium_newton(inputs.model.speed_map(), gamma0, omega0, self.eq.0))
            {
                Some(Some(e)) => e,
                _ => sp.equilibrium(inputs.model.speed_map(), gamma0, omega0),
            };
        }
        let (phi0, psi0) = self.eq;
        let omega = m.omega_rad_s / sp.speed_scale_rad_s;
        let phi = m.m_kg_s / sp.flow_scale_kg_s;
        let psi = (m.p_discharge_pa - m.p_suction_pa) / sp.pressure_scale_pa;
        if !(omega.is_finite() && phi.is_finite() && psi.is_finite()) {
            return None;
        }
        let pc = sp.psi_c(inputs.model.speed_map(), phi, omega);
        Some(Frame {
            omega0,
            phi0,
            psi0,
            gamma0,
            tau0: sp.gamma_torque(phi0, omega0), // eq. 7
            x1: omega - omega0,
            x2: phi - phi0,
            x3: psi - psi0,
            pc,
            css: pc.value - psi0, // eq. 13 (ψc(φ⁰, ω̃⁰) = ψ⁰ by eq. 9)
        })
    }

    /// Drive-torque command (N·m, added to the speed loop) for the extra torque u₁ (model
    /// units) before the bumpless offset and the limits: the eq. 7 schedule τ⁰ − τ_ref, the
    /// PI speed trim and u₁.
    pub(super) fn raw_torque_nm(&self, fr: &Frame, u1: f64) -> f64 {
        let schedule = if self.torque_schedule {
            fr.tau0 - self.tau_ref
        } else {
            0.0
        };
        let e = -fr.x1 * self.sp.speed_scale_rad_s; // ω_set − ω, rad/s
        (schedule + u1) * self.sp.torque_scale_nm + self.trim_kp_nm_s_per_rad * e + self.trim_nm
    }

    /// Limits of the extra torque. The drive delivers the speed loop's held torque plus the
    /// extra, clamped to [min, rated] by the speed loop and the drive; the held torque is not a
    /// law input, so the extra is limited to the largest correction that can matter for any
    /// held torque in the rating, ±(rated − min).
    pub(super) fn torque_limits_nm(&self) -> (f64, f64) {
        let span = self.sp.torque_max_nm - self.sp.torque_min_nm;
        (-span, span)
    }

    /// Bumpless start with the law's extra torque u₁ and valve output `raw_valve` at this
    /// instant: take τ_ref = τ⁰ (the speed loop is taken to hold the eq. 7 torque of the operating
    /// point in force now), reset the trim, and set the offsets so that the first output is the
    /// current one (extra torque 0, valve `current_valve`).
    /// Bumpless start: the offsets make the first outputs equal the applied extra torque
    /// `current_torque_nm` (N·m; 0 from another law) and valve. A fresh law takes τ_ref from
    /// the operating point and starts the trim at 0; one that took over a running law's state
    /// ([`take_over`](Self::take_over)) keeps both.
    pub(super) fn start(
        &mut self,
        fr: &Frame,
        u1: f64,
        raw_valve: f64,
        current_valve: f64,
        current_torque_nm: f64,
    ) {
        if !self.taken_over {
            self.tau_ref = fr.tau0;
            self.trim_nm = 0.0;
        }
        self.taken_over = false;
        let applied = if current_torque_nm.is_finite() {
            current_torque_nm
        } else {
            0.0
        };
        self.offset_torque_nm = applied - self.raw_torque_nm(fr, u1);
        self.offset_valve = current_valve - raw_valve;
    }

    /// A reload of the running law (new settings): keep the torque reference τ_ref (the eq. 7
    /// schedule would otherwise restart from the operating point of the reload and its torque
    /// decay away with the offset), the integral trim and the equilibrium cache; `start` then
    /// re-bases the offsets, so the gain change moves no output in its first cycle.
    pub(super) fn take_over(&mut self, running: &Common) {
        if running.tau_ref.is_finite() {
            self.tau_ref = running.tau_ref;
            let (lo, hi) = self.torque_limits_nm();
            self.trim_nm = running.trim_nm.clamp(lo, hi);
            self.key = running.key;
            self.eq = running.eq;
            self.taken_over = true;
        }
    }

    /// Final torque command: raw + offset, limited; then advance the trim (anti-windup) and the
    /// offset decay.
    pub(super) fn torque_out(&mut self, fr: &Frame, u1: f64, dt_s: f64) -> f64 {
        let (lo, hi) = self.torque_limits_nm();
        let want = self.raw_torque_nm(fr, u1) + self.offset_torque_nm;
        let out = want.clamp(lo, hi);
        // integral speed trim: d trim/dt = k (ω_set − ω) = −k x₁ speed_scale; frozen while the
        // output is saturated in the direction it would push (conditional integration)
        let e = -fr.x1 * self.sp.speed_scale_rad_s;
        let pushing_out = (want >= hi && e > 0.0) || (want <= lo && e < 0.0);
        if !pushing_out {
            self.trim_nm = (self.trim_nm + self.trim_ki_nm_per_rad * e * dt_s).clamp(lo, hi);
        }
        out
    }

    /// Decay the bumpless offsets by one cycle.
    pub(super) fn decay(&mut self, dt_s: f64) {
        let k = (-dt_s / self.bumpless_tau_s).exp();
        self.offset_torque_nm *= k;
        self.offset_valve *= k;
    }
}

/// Boundary-layer saturation sat(x/ε) ∈ [−1, 1] replacing sign(x) (seed 003 Remark 2).
#[inline]
pub(super) fn sat(x: f64, eps: f64) -> f64 {
    (x / eps).clamp(-1.0, 1.0)
}

/// The CCV law of Theorem 1 (eq. 25), also the robust law's inner loop (eq. 44 with f̃):
/// u₂ = −x₁ f̃(x₁, x₂) − Css(x₁, x₂) − k x₂, i.e. for Γ = σ φ ω̃ (eq. 48):
/// u₂ = σ x₁ (x₁ + ω̃⁰) − Css − k x₂.
#[inline]
pub(super) fn ccv_nominal(sp: &Spool, fr: &Frame, k: f64) -> f64 {
    -fr.x1 * fr.f_tilde(sp) - fr.css - k * fr.x2
}

/// CCV current output: NaN (not driven) means the valve sits at its neutral 0.
#[inline]
/// The extra drive torque applied now (N·m, on top of the speed loop), 0 if none.
pub(super) fn current_torque(current: &ActuatorCommands) -> f64 {
    let t = current.get(ActuatorId::DriveTorque);
    if t.is_finite() {
        t
    } else {
        0.0
    }
}

pub(super) fn current_ccv(current: &ActuatorCommands) -> f64 {
    let c = current.get(ActuatorId::CloseCoupledValve);
    if c.is_finite() {
        c
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::law::api::SurgeLaw;
    use crate::control::laws::ccv::{Ccv, CcvConfig};
    use crate::control::laws::robust::{Robust, RobustConfig};
    use crate::control::laws::throttle_backstep::{ThrottleBackstep, ThrottleBackstepConfig};
    use crate::control::measurements::{Measurements, OperatorInputs};
    use crate::plant::spool::SpoolPlant;
    use crate::plant::{PlantInputs, SimPlant};
    use crate::sim::case::PlantCase;
    use std::path::Path;

    fn description() -> PlantCase {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/plants/liaw2004_spool.toml");
        PlantCase::load(&p).expect("plant file")
    }

    fn plant(desc: &PlantCase) -> SpoolPlant {
        let inputs = PlantInputs {
            throttle_process: 0.6,
            ..PlantInputs::default()
        };
        match SimPlant::new(desc, &inputs).expect("plant") {
            SimPlant::Spool(p) => p,
            _ => panic!("not a spool plant"),
        }
    }

    /// Measurements of a nondimensional state (ω̃, φ, ψ) at throttle opening `opening`.
    fn measurements(sp: &Spool, w: f64, phi: f64, psi: f64, opening: f64) -> Measurements {
        let p01 = sp.ratio_to_psi * sp.pressure_scale_pa;
        let pd = p01 + psi * sp.pressure_scale_pa;
        Measurements {
            t_s: 0.0,
            p_suction_pa: p01,
            p_discharge_pa: pd,
            omega_rad_s: w * sp.speed_scale_rad_s,
            t_suction_k: 293.15,
            m_kg_s: phi * sp.flow_scale_kg_s,
            m_measured_kg_s: phi * sp.flow_scale_kg_s,
            m_observer_kg_s: f64::NAN,
            flow_map: phi * sp.flow_scale_kg_s,
            pressure_ratio: pd / p01,
            recycle_position: f64::NAN,
            throttle_position: opening,
            thrust_position_m: f64::NAN,
            dp_suction_dt_pa_s: 0.0,
            dp_discharge_dt_pa_s: 0.0,
            flow_fallback: false,
        }
    }

    fn operator(sp: &Spool, opening: f64) -> OperatorInputs {
        OperatorInputs {
            speed_setpoint_rad_s: sp.speed_scale_rad_s,
            throttle_demand: opening,
            flow_setpoint_kg_s: f64::NAN,
            recycle_manual: f64::NAN,
        }
    }

    /// Deterministic pseudo-random numbers in [0, 1).
    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn nondimensional_characteristic_is_the_plants() {
        let desc = description();
        let model = crate::sim::control_model(&desc);
        let sp = Spool::from_model(LawId::Ccv, &model).unwrap();
        let p = plant(&desc);
        for &(phi, w) in &[(0.1, 1.0), (0.5, 0.9), (0.8, 1.2), (-0.2, 1.0), (1.5, 0.7)] {
            let a = sp.psi_c(model.speed_map(), phi, w);
            let b = p.psi_c(phi, w);
            assert!((a.value - b.value).abs() < 1e-12, "{phi} {w}");
            assert!((a.d_dphi - b.d_dflow).abs() < 1e-9, "{phi} {w}");
            assert!((a.d_domega - b.d_domega).abs() < 1e-9, "{phi} {w}");
        }
    }

    #[test]
    fn equilibrium_solves_eq_8_9_and_is_the_rightmost() {
        let desc = description();
        let model = crate::sim::control_model(&desc);
        let sp = Spool::from_model(LawId::Ccv, &model).unwrap();
        let p = plant(&desc);
        for &opening in &[0.05, 0.2, 0.35, 0.6, 1.0] {
            for &w in &[0.85, 1.0, 1.1] {
                let (phi0, psi0) = sp.equilibrium(model.speed_map(), sp.gamma_max * opening, w);
                let eq = p.equilibria(opening, w);
                let right = eq.last().expect("steady state");
                assert!(
                    (phi0 - right[1]).abs() < 1e-7,
                    "{opening} {w}: {phi0} vs {right}"
                );
                assert!((psi0 - right[2]).abs() < 1e-7);
                let f = throttle_function(sp.gamma_max * opening, psi0);
                assert!((f - phi0).abs() < 1e-12, "eq. 8");
            }
        }
    }

    #[test]
    fn warm_started_newton_finds_the_scans_root() {
        let desc = description();
        let model = crate::sim::control_model(&desc);
        let sp = Spool::from_model(LawId::Ccv, &model).unwrap();
        // a throttle ramp in small steps, as during the closure scenario
        let mut prev = sp.equilibrium(model.speed_map(), sp.gamma_max * 0.6, 1.0).0;
        let mut newton_used = 0;
        for k in 1..=400 {
            let opening = 0.6 - 0.001 * k as f64;
            let scan = sp.equilibrium(model.speed_map(), sp.gamma_max * opening, 1.0);
            if let Some(nw) =
                sp.equilibrium_newton(model.speed_map(), sp.gamma_max * opening, 1.0, prev)
            {
                assert!(
                    (nw.0 - scan.0).abs() < 1e-9,
                    "opening {opening}: {nw:?} vs {scan:?}"
                );
                newton_used += 1;
            }
            prev = scan.0;
        }
        assert!(
            newton_used > 350,
            "Newton should carry almost all steps: {newton_used}"
        );
        // a guess on the wrong side of the peak is refused, not misconverged
        let (phi_r, _) = sp.equilibrium(model.speed_map(), sp.gamma_max * 0.2, 1.0);
        if let Some(e) =
            sp.equilibrium_newton(model.speed_map(), sp.gamma_max * 0.2, 1.0, 3.0 * phi_r)
        {
            assert!((e.0 - phi_r).abs() < 1e-9);
        }
    }

    /// V̇ along the model (eq. 10–12, u₁ = u₃ = 0) with a CCV output u₂.
    fn v_dot(sp: &Spool, fr: &Frame, u2: f64) -> f64 {
        let (w, phi, psi) = (fr.x1 + fr.omega0, fr.x2 + fr.phi0, fr.x3 + fr.psi0);
        let x1d = sp.a_bar * (fr.tau0 - sp.gamma_torque(phi, w));
        let x2d = sp.b_bar * (fr.pc.value - psi + u2);
        let x3d = sp.c_bar * (phi - throttle_function(fr.gamma0, psi));
        fr.x1 * x1d / sp.a_bar + fr.x2 * x2d / sp.b_bar + fr.x3 * x3d / sp.c_bar
    }

    #[test]
    fn ccv_law_gives_eq_23_negative_semidefinite_and_printed_eq_44_does_not() {
        let desc = description();
        let model = crate::sim::control_model(&desc);
        let mut law = Ccv::new(&CcvConfig::default(), &model).unwrap();
        let sp = law.c.sp;
        let mut seed = 7u64;
        let mut printed_violations = 0;
        for _ in 0..2000 {
            let opening = 0.15 + 0.6 * lcg(&mut seed);
            let (w, phi, psi) = (
                0.6 + 0.8 * lcg(&mut seed),
                -0.2 + 1.2 * lcg(&mut seed),
                0.05 + 1.0 * lcg(&mut seed),
            );
            let m = measurements(&sp, w, phi, psi, opening);
            let op = operator(&sp, opening);
            let inputs = LawInputs {
                m: &m,
                op: &op,
                model: &model,
                history: &crate::control::law::api::LoopHistory::EMPTY,
            };
            let fr = law.c.frame(&inputs).unwrap();
            let u2 = law.raw_ccv(&fr);
            // eq. 23 with eq. 25: V̇ = x₁ f(x₁, 0) − k x₂² + x₃ (F(γ⁰, ψ⁰) − F(γ⁰, ψ))
            let f0 = -sp.sigma * fr.phi0 * fr.x1;
            let f_thr = throttle_function(fr.gamma0, fr.psi0) - throttle_function(fr.gamma0, psi);
            let expected = fr.x1 * f0 - fr.x2 * fr.x2 + fr.x3 * f_thr;
            let vd = v_dot(&sp, &fr, u2);
            assert!(
                (vd - expected).abs() < 1e-9 * (1.0 + expected.abs()),
                "{vd} {expected}"
            );
            assert!(vd <= 1e-12, "V̇ = {vd} > 0");
            // the printed eq. 44 uses f̄ = f (eq. 38) instead of f̃: u₂ = −x₁ f − Css − x₂
            let f = sp.gamma_torque(fr.phi0, fr.omega0) - sp.gamma_torque(phi, w);
            let u2_printed = -fr.x1 * f - fr.css - fr.x2;
            if v_dot(&sp, &fr, u2_printed) > 1e-6 {
                printed_violations += 1;
            }
        }
        assert!(printed_violations > 50, "{printed_violations}");
    }

    #[test]
    fn backstepping_error_obeys_eq_51() {
        // with an ideal throttle, ξ = x₃ − x₃d evolves as ξ̇ = c̄ (x₂ − k_ξ ξ) (eq. 51)
        let desc = description();
        let model = crate::sim::control_model(&desc);
        let cfg = ThrottleBackstepConfig {
            xi_gain_nd: 1.7,
            x2_gain_nd: 1.3,
            ..ThrottleBackstepConfig::default()
        };
        let mut law = ThrottleBackstep::new(&cfg, &model).unwrap();
        let sp = law.c.sp;
        let mut seed = 11u64;
        for _ in 0..200 {
            let opening = 0.2 + 0.4 * lcg(&mut seed);
            let x = [
                0.9 + 0.2 * lcg(&mut seed),
                0.1 + 0.5 * lcg(&mut seed),
                0.3 + 0.4 * lcg(&mut seed),
            ];
            let eval = |law: &mut ThrottleBackstep, x: [f64; 3]| {
                let m = measurements(&sp, x[0], x[1], x[2], opening);
                let op = operator(&sp, opening);
                let inputs = LawInputs {
                    m: &m,
                    op: &op,
                    model: &model,
                    history: &crate::control::law::api::LoopHistory::EMPTY,
                };
                let fr = law.c.frame(&inputs).unwrap();
                (fr, law.law(&fr))
            };
            let (fr, b) = eval(&mut law, x);
            let gamma = b.opening * sp.gamma_max; // unsaturated, applied at once
            let rhs = |x: [f64; 3]| {
                [
                    sp.a_bar * (fr.tau0 - sp.gamma_torque(x[1], x[0])),
                    sp.b_bar * (sp.psi_c(model.speed_map(), x[1], x[0]).value - x[2]),
                    sp.c_bar * (x[1] - throttle_function(gamma, x[2])),
                ]
            };
            let h = 1e-6;
            let d = rhs(x);
            let (xp, xm) = (
                [0, 1, 2].map(|i| x[i] + h * d[i]),
                [0, 1, 2].map(|i| x[i] - h * d[i]),
            );
            let xi_dot = (eval(&mut law, xp).1.xi - eval(&mut law, xm).1.xi) / (2.0 * h);
            let expected = sp.c_bar * (fr.x2 - cfg.xi_gain_nd * b.xi);
            assert!(
                (xi_dot - expected).abs() < 1e-5 * (1.0 + expected.abs()),
                "ξ̇ {xi_dot} vs {expected}"
            );
        }
    }

    #[test]
    fn robust_outer_loop_is_a_boundary_layer_sign() {
        let desc = description();
        let model = crate::sim::control_model(&desc);
        let cfg = RobustConfig::default();
        let law = Robust::new(&cfg, &model).unwrap();
        let sp = law.c.sp;
        let opening = 0.2;
        let (phi0, psi0) = sp.equilibrium(model.speed_map(), sp.gamma_max * opening, 1.0);
        let mut ccv = Ccv::new(&CcvConfig::default(), &model).unwrap();
        for &(x1, x2) in &[(0.0, 0.0), (0.005, -0.002), (0.05, 0.3), (-0.3, -0.02)] {
            let m = measurements(&sp, 1.0 + x1, phi0 + x2, psi0, opening);
            let op = operator(&sp, opening);
            let inputs = LawInputs {
                m: &m,
                op: &op,
                model: &model,
                history: &crate::control::law::api::LoopHistory::EMPTY,
            };
            let fr = ccv.c.frame(&inputs).unwrap();
            let (u1, u2) = law.law(&fr);
            let du2 = u2 - ccv.raw_ccv(&fr);
            let expect1 = -cfg.delta1_tau * (x1 / cfg.boundary_layer_x1_omega).clamp(-1.0, 1.0);
            let expect2 = -cfg.delta2_psi * (x2 / cfg.boundary_layer_x2_phi).clamp(-1.0, 1.0);
            assert!((u1 - expect1).abs() < 1e-12, "{u1} {expect1}");
            assert!((du2 - expect2).abs() < 1e-9, "{du2} {expect2}");
        }
    }

    #[test]
    fn first_output_equals_current_and_offset_decays() {
        let desc = description();
        let model = crate::sim::control_model(&desc);
        let mut law = Robust::new(&RobustConfig::default(), &model).unwrap();
        let sp = law.c.sp;
        let opening = 0.3;
        // a state well off x⁰: the law's own outputs are far from the current ones
        let m = measurements(&sp, 1.05, 0.3, 0.5, opening);
        let op = operator(&sp, opening);
        let inputs = LawInputs {
            m: &m,
            op: &op,
            model: &model,
            history: &crate::control::law::api::LoopHistory::EMPTY,
        };
        let mut current = ActuatorCommands::default();
        current.set(ActuatorId::CloseCoupledValve, 0.03);
        current.set(ActuatorId::DriveTorque, 0.0);
        law.start(&inputs, &current);
        let out = law.update(&inputs, 1e-3);
        assert!((out.commands.get(ActuatorId::CloseCoupledValve) - 0.03).abs() < 1e-12);
        assert!(out.commands.get(ActuatorId::DriveTorque).abs() < 1e-12);
        // after many time constants the law's own output is applied
        let mut last = out;
        for _ in 0..2000 {
            last = law.update(&inputs, 1e-3);
        }
        let fr = law.c.frame(&inputs).unwrap();
        let (_, u2) = law.law(&fr);
        let want = u2.clamp(-sp.ccv_max, sp.ccv_max);
        assert!((last.commands.get(ActuatorId::CloseCoupledValve) - want).abs() < 1e-6);
    }

    #[test]
    fn settings_are_validated_and_unknown_keys_rejected() {
        let desc = description();
        let model = crate::sim::control_model(&desc);
        let bad = RobustConfig {
            boundary_layer_x2_phi: 0.0,
            ..RobustConfig::default()
        };
        let e = Robust::new(&bad, &model).unwrap_err();
        assert!(e.to_string().contains("boundary_layer_x2_phi"), "{e}");
        let bad = CcvConfig {
            x2_gain_nd: -1.0,
            ..CcvConfig::default()
        };
        assert!(Ccv::new(&bad, &model).is_err());
        let bad = ThrottleBackstepConfig {
            xi_gain_nd: 0.0,
            ..ThrottleBackstepConfig::default()
        };
        assert!(ThrottleBackstep::new(&bad, &model).is_err());
        let parsed: Result<CcvConfig, _> = toml::from_str("x2_gain = 2.0");
        assert!(parsed.is_err(), "unknown key accepted");
        let parsed: CcvConfig = toml::from_str("x2_gain_nd = 2.0").unwrap();
        assert_eq!(parsed.x2_gain_nd, 2.0);
        assert_eq!(
            parsed.speed_trim_ki_nm_per_rad, 0.0,
            "seed default: no trim"
        );
        // the tuned tables of the plant file parse into these settings
        assert_eq!(model.controller.ccv.x2_gain_nd, 3.0);
        assert_eq!(model.controller.robust.delta1_tau, 0.1);
    }
}
