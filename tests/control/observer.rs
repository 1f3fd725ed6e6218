//! Issue 3 acceptance for the mass-flow observer (seed 000 eq. 14–17):
//! - in the z-form (eq. 15, derived sign) it matches eq. 14 to 1e-6 relative;
//! - from an initial estimate 50 % off the error decays at least exponentially, at no less than
//!   the rate the gain condition guarantees (fitted);
//! - the printed sign of eq. 15a gives a biased estimate, the derived one does not;
//! - every plant's configured gain c2 satisfies eq. 17 (without its spurious factor 2).

use crate::common;

use antisurge::control::observer::{MassFlowObserver, ObserverConfig};
use antisurge::plant::plenum_duct::PlenumDuctPlant;
use antisurge::plant::{PlantInputs, SimPlant};
use antisurge::solver::{dormand_prince, AdaptiveStats, OdeSystem, Tolerance};
use antisurge::vocab::signals::SensorId;
use nalgebra::SVector;

/// Which form of the observer's z equation.
#[derive(Clone, Copy, PartialEq)]
enum ZSign {
    Derived,
    Printed,
}

/// Plant (p, m, ω, throttle) + eq. 14 estimate m̂ + z-form state z, integrated together so the
/// comparison is free of discretisation effects.
struct Combined {
    plant: PlenumDuctPlant,
    obs: MassFlowObserver,
    sign: ZSign,
}

impl Combined {
    fn psi(&self, m: f64, omega: f64) -> f64 {
        self.plant.map.eval(m, omega).value
    }
}

impl OdeSystem<6> for Combined {
    fn rhs(&self, t: f64, x: &SVector<f64, 6>) -> SVector<f64, 6> {
        let xp = SVector::<f64, 4>::new(x[0], x[1], x[2], x[3]);
        let dp = self.plant.rhs(t, &xp);
        let p01 = self.plant.params.ambient_pressure_pa;
        let (p, m, omega) = (x[0], x[1], x[2]);
        let m_t = self.plant.throttle_flow(p, x[3]);
        // eq. 14 with the true m
        let m_hat = x[4];
        let d14 = self.obs.eq14_rate(m_hat, m, p01, p, self.psi(m_hat, omega));
        // eq. 15: derived (+ c2 m_t) or printed (− c2 m_t)
        let z = x[5];
        let m_hat_z = z + self.obs.k_z() * p;
        let dz = match self.sign {
            ZSign::Derived => self.obs.z_rate(z, p01, p, m_t, self.psi(m_hat_z, omega)),
            ZSign::Printed => {
                self.obs.z_rate(z, p01, p, m_t, self.psi(m_hat_z, omega))
                    - 2.0 * self.obs.area_over_length() * self.obs.c2() * m_t
            }
        };
        SVector::<f64, 6>::from_column_slice(&[dp[0], dp[1], dp[2], dp[3], d14, dz])
    }
}

fn combined(sign: ZSign, throttle_target: f64) -> (Combined, SVector<f64, 6>) {
    let desc = common::plant("bohagen2007_plenum");
    let inputs = PlantInputs {
        throttle_process: 0.6,
        ..PlantInputs::default()
    };
    let SimPlant::PlenumDuct(mut plant) = SimPlant::new(&desc, &inputs).expect("plant") else {
        panic!()
    };
    let x0 = plant.x;
    // constant drive torque at its initial value; the throttle moves to `throttle_target`
    plant.hold_inputs(plant.shaft.load_torque_nm(x0[1], x0[2]), throttle_target);
    let model = antisurge::sim::control_model(&desc);
    let obs = MassFlowObserver::new(
        &desc.controller.observer,
        model.observer_plant().expect("observer"),
    );
    let m_hat0 = 0.5 * x0[1]; // 50 % off
    let z0 = m_hat0 - obs.k_z() * x0[0];
    let x = SVector::<f64, 6>::from_column_slice(&[x0[0], x0[1], x0[2], x0[3], m_hat0, z0]);
    (Combined { plant, obs, sign }, x)
}

fn integrate(sys: &Combined, x: &mut SVector<f64, 6>, t0: f64, t1: f64, h: &mut f64) {
    let tol = Tolerance {
        rtol: 1e-11,
        atol: [1e-6, 1e-10, 1e-8, 1e-12, 1e-10, 1e-10],
    };
    let mut stats = AdaptiveStats::default();
    dormand_prince::integrate(sys, t0, x, t1, &tol, h, &mut stats);
}

#[test]
fn z_form_matches_eq14_to_one_part_per_million() {
    // a transient: the throttle moves 60 % → 45 % while the estimate converges from 50 % off
    let (sys, mut x) = combined(ZSign::Derived, 0.45);
    let mut h = 1e-6;
    let mut worst: f64 = 0.0;
    for k in 0..300 {
        integrate(&sys, &mut x, k as f64 * 1e-2, (k + 1) as f64 * 1e-2, &mut h);
        let m14 = x[4];
        let mz = x[5] + sys.obs.k_z() * x[0];
        worst = worst.max((m14 - mz).abs() / x[1].abs().max(1e-3));
    }
    assert!(
        worst < 1e-6,
        "z-form differs from eq. 14 by {worst:e} (relative)"
    );
}

#[test]
fn printed_sign_is_biased_derived_sign_is_not() {
    let t_end = 2.0;
    let mut out = Vec::new();
    for sign in [ZSign::Derived, ZSign::Printed] {
        let (sys, mut x) = combined(sign, 0.6);
        let mut h = 1e-6;
        integrate(&sys, &mut x, 0.0, t_end, &mut h);
        let m = x[1];
        let m_hat = x[5] + sys.obs.k_z() * x[0];
        out.push((m, m_hat));
    }
    let (m, m_derived) = out[0];
    let (_, m_printed) = out[1];
    assert!(
        (m_derived - m).abs() < 1e-6 * m,
        "derived: {m_derived} vs true {m}"
    );
    // the printed sign leaves a forcing 2 (A/L) c2 m_t in the error equation: the estimate
    // settles far from the truth (ERRATA.md: −7.8 kg/s for a true 11 kg/s in another plant)
    assert!(
        (m_printed - m).abs() > 0.5 * m,
        "printed: {m_printed} vs true {m}"
    );
    eprintln!("true {m:.3} kg/s, derived {m_derived:.6}, printed {m_printed:.3}");
}

#[test]
fn error_decays_at_least_exponentially_at_the_guaranteed_rate() {
    // continuous-time: fit ln|m̃| against t and compare with the rate the gain condition
    // guarantees, (A/L)(c2 − p01 sup ∂Ψc/∂m)
    let (sys, mut x) = combined(ZSign::Derived, 0.6);
    let desc = common::plant("bohagen2007_plenum");
    let model = antisurge::sim::control_model(&desc);
    let c2_min = model.observer_min_gain().expect("bound");
    let lambda_bound = sys.obs.area_over_length() * (sys.obs.c2() - c2_min);
    assert!(lambda_bound > 0.0);
    let e0 = (x[1] - (x[5] + sys.obs.k_z() * x[0])).abs();
    let mut h = 1e-6;
    let (mut ts, mut ls) = (Vec::new(), Vec::new());
    let dt = 2e-4;
    for k in 0..200 {
        let t1 = (k + 1) as f64 * dt;
        integrate(&sys, &mut x, k as f64 * dt, t1, &mut h);
        let e = (x[1] - (x[5] + sys.obs.k_z() * x[0])).abs();
        // at least exponential: below the guaranteed envelope at every sample
        assert!(
            e <= e0 * (-lambda_bound * t1).exp() * (1.0 + 1e-6) + 1e-12,
            "t {t1}: {e} above the envelope"
        );
        if e > 1e-9 * x[1] {
            ts.push(t1);
            ls.push(e.ln());
        }
    }
    // least-squares slope of ln|m̃|(t)
    let n = ts.len() as f64;
    let (mt, ml) = (ts.iter().sum::<f64>() / n, ls.iter().sum::<f64>() / n);
    let num: f64 = ts.iter().zip(&ls).map(|(t, l)| (t - mt) * (l - ml)).sum();
    let den: f64 = ts.iter().map(|t| (t - mt).powi(2)).sum();
    let rate = -num / den;
    eprintln!(
        "fitted decay rate {rate:.1} 1/s, guaranteed {lambda_bound:.1} 1/s, {} samples",
        ts.len()
    );
    assert!(ts.len() > 20, "too few samples to fit");
    assert!(
        rate >= lambda_bound,
        "fitted rate {rate} below the bound {lambda_bound}"
    );
}

#[test]
fn discrete_observer_in_the_control_cycle_converges_from_fifty_percent_off() {
    // the observer as the core runs it: 1 kHz, Rosenbrock–Euler update, fed by sensor readings
    let desc = common::plant("bohagen2007_plenum");
    let model = antisurge::sim::control_model(&desc);
    let inputs = PlantInputs {
        throttle_process: 0.6,
        ..PlantInputs::default()
    };
    let mut plant = SimPlant::new(&desc, &inputs).expect("plant");
    let mut obs = MassFlowObserver::new(
        &desc.controller.observer,
        model.observer_plant().expect("obs"),
    );
    let s = plant.sensors();
    let m0 = plant.truth().m_kg_s;
    obs.reset(
        0.5 * m0,
        s.get(SensorId::PDischarge),
        s.get(SensorId::PSuction),
    );
    let c2_min = model.observer_min_gain().expect("bound");
    let lambda_bound = obs.area_over_length() * (obs.c2() - c2_min);
    let dt = 1e-3;
    let mut errors = Vec::new();
    for k in 0..200 {
        let s = plant.sensors();
        let (ps, pd, w) = (
            s.get(SensorId::PSuction),
            s.get(SensorId::PDischarge),
            s.get(SensorId::ShaftSpeed),
        );
        let out = model.outflow_kg_s(ps, pd, f64::NAN, s.get(SensorId::ThrottlePosition));
        let m_hat = obs.update(ps, pd, out, dt, |m| {
            model.pressure_ratio_at(m, ps, 293.15, w, f64::NAN)
        });
        errors.push(((plant.truth().m_kg_s - m_hat).abs(), k as f64 * dt));
        plant.step(&inputs, dt);
    }
    // the implicit Euler factor 1/(1 + hλ) per step bounds the decay from below
    let per_step = 1.0 / (1.0 + dt * lambda_bound);
    let e0 = errors[0].0;
    for (k, (e, t)) in errors.iter().enumerate().skip(1) {
        assert!(
            *e <= e0 * per_step.powi(k as i32) * 1.001 + 1e-9,
            "t {t}: {e}"
        );
    }
    assert!(errors.last().expect("errors").0 < 1e-6 * m0);
}

#[test]
fn every_plant_gain_satisfies_eq17() {
    for stem in common::PLANTS {
        let desc = common::plant(stem);
        let model = antisurge::sim::control_model(&desc);
        if let Some(c2_min) = model.observer_min_gain() {
            let c2 = desc.controller.observer.c2_pa_s_kg;
            assert!(c2 > c2_min, "{stem}: c2 = {c2} ≤ {c2_min} (eq. 17)");
        }
    }
    // and the bound catches a gain that is too small
    let desc = common::plant("kvangardsnes2009_recycle");
    let model = antisurge::sim::control_model(&desc);
    assert!(ObserverConfig::default().c2_pa_s_kg < model.observer_min_gain().expect("bound"));
}
