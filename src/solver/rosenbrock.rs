//! ROS2: a two-stage, second-order, L-stable linearly implicit Rosenbrock(-W) method
//! (Verwer, Spee, Blom & Hundsdorfer 1999), γ = 1 + 1/√2:
//!
//! ```text
//! W = I − γ h J
//! W k₁ = f(tₙ, yₙ)
//! W k₂ = f(tₙ + h, yₙ + h k₁) − 2 k₁
//! yₙ₊₁ = yₙ + h (3/2 k₁ + 1/2 k₂)
//! ```
//! Its stability function is R(z) = (1 + (1−2γ) z)/(1 − γz)², so R(∞) = 0: stiff modes such as
//! the nearly closed recycle valve line (λ ≈ −10⁵ s⁻¹) are damped at any step size.
//! The embedded first-order solution ŷ = yₙ + h k₁ (linearly implicit Euler) gives the local
//! error estimate h (k₁ + k₂)/2 for step-size control. Order 2 holds for any approximation of J
//! (W-method), so a finite-difference Jacobian is sufficient.

use super::linalg::Lu;
use super::{error_norm, jacobian, AdaptiveStats, OdeSystem, Tolerance};
use nalgebra::{SMatrix, SVector};

/// γ = 1 + 1/√2 (L-stability).
pub const GAMMA: f64 = 1.0 + std::f64::consts::FRAC_1_SQRT_2;

/// One fixed ROS2 step. Returns the new state and the local error estimate vector.
/// If the iteration matrix is singular (should not happen for h > 0 with physical Jacobians)
/// falls back to an explicit Euler step so the caller never sees NaN from a solve.
pub fn step<const N: usize, S: OdeSystem<N>>(
    sys: &S,
    t_s: f64,
    x: &SVector<f64, N>,
    h_s: f64,
) -> (SVector<f64, N>, SVector<f64, N>) {
    let f0 = sys.rhs(t_s, x);
    let jac = jacobian(sys, t_s, x, &f0);
    step_with_jacobian(sys, t_s, x, h_s, &f0, &jac)
}

/// One ROS2 step with a given Jacobian and f(tₙ, yₙ) (lets callers reuse a Jacobian).
pub fn step_with_jacobian<const N: usize, S: OdeSystem<N>>(
    sys: &S,
    t_s: f64,
    x: &SVector<f64, N>,
    h_s: f64,
    f0: &SVector<f64, N>,
    jac: &SMatrix<f64, N, N>,
) -> (SVector<f64, N>, SVector<f64, N>) {
    let w = SMatrix::<f64, N, N>::identity() - jac * (GAMMA * h_s);
    let lu = match Lu::new(w) {
        Some(lu) => lu,
        None => return (x + f0 * h_s, SVector::<f64, N>::zeros()),
    };
    let k1 = lu.solve(f0);
    let mut x1 = x + k1 * h_s;
    sys.project(&mut x1);
    let f1 = sys.rhs(t_s + h_s, &x1);
    let k2 = lu.solve(&(f1 - k1 * 2.0));
    let x_new = x + (k1 * 1.5 + k2 * 0.5) * h_s;
    let err = (k1 + k2) * (0.5 * h_s);
    (x_new, err)
}

/// Adaptive ROS2 from `t0_s` to `t1_s`, landing exactly on `t1_s`. `h_s` carries the step size
/// between calls (pass the previous value back in; start with a small guess).
pub fn integrate<const N: usize, S: OdeSystem<N>>(
    sys: &S,
    t0_s: f64,
    x: &mut SVector<f64, N>,
    t1_s: f64,
    tol: &Tolerance<N>,
    h_s: &mut f64,
    stats: &mut AdaptiveStats,
) {
    let mut t = t0_s;
    let span = t1_s - t0_s;
    if span <= 0.0 {
        return;
    }
    let h_min = span * 1e-14;
    while t < t1_s {
        let mut h = h_s.min(t1_s - t).max(h_min);
        let last = t + h >= t1_s * (1.0 - 1e-15);
        if last {
            h = t1_s - t;
        }
        let (mut x_new, err) = step(sys, t, x, h);
        stats.rhs_evals += 2 + N as u64;
        sys.project(&mut x_new);
        let en = error_norm(&err, x, &x_new, tol);
        if en <= 1.0 || h <= h_min {
            t = if last { t1_s } else { t + h };
            *x = x_new;
            stats.accepted += 1;
            let fac = if en == 0.0 {
                4.0
            } else {
                (0.9 / en.sqrt()).clamp(0.2, 4.0)
            };
            if !last || fac < 1.0 {
                *h_s = h * fac;
            }
        } else {
            stats.rejected += 1;
            *h_s = h * (0.9 / en.sqrt()).clamp(0.1, 0.9);
        }
    }
}

/// Adaptive ROS2 over [t0, t1] with at most `max_steps` attempted steps. If the budget runs
/// out, the remaining interval is covered in one step without error control, so the work per
/// call is bounded (real-time use). Returns the number of steps taken.
///
/// The Jacobian is evaluated once per call and reused for every sub-step (ROS2 keeps order 2
/// with any Jacobian approximation: it is a W-method); it is re-evaluated only after a rejected
/// step. This cuts the cost of a sub-step from N + 2 to 2 right-hand-side evaluations.
pub fn integrate_bounded<const N: usize, S: OdeSystem<N>>(
    sys: &S,
    t0_s: f64,
    x: &mut SVector<f64, N>,
    t1_s: f64,
    tol: &Tolerance<N>,
    h_s: &mut f64,
    max_steps: u32,
) -> u32 {
    let span = t1_s - t0_s;
    if span <= 0.0 {
        return 0;
    }
    let mut t = t0_s;
    let mut steps = 0u32;
    let budget = max_steps.max(2);
    let f0 = sys.rhs(t, x);
    let mut jac = jacobian(sys, t, x, &f0);
    let mut fresh = true;
    let mut f = f0;
    while t < t1_s {
        if steps + 1 >= budget {
            // out of budget: finish in one step of what remains
            let (mut xn, _) = step_with_jacobian(sys, t, x, t1_s - t, &f, &jac);
            sys.project(&mut xn);
            *x = xn;
            return steps + 1;
        }
        let mut h = h_s.min(t1_s - t).max(span * 1e-9);
        let last = t + h >= t1_s - span * 1e-12;
        if last {
            h = t1_s - t;
        }
        let (mut x_new, err) = step_with_jacobian(sys, t, x, h, &f, &jac);
        steps += 1;
        sys.project(&mut x_new);
        let en = error_norm(&err, x, &x_new, tol);
        if en <= 1.0 && x_new.iter().all(|v| v.is_finite()) {
            t = if last { t1_s } else { t + h };
            *x = x_new;
            if t < t1_s {
                f = sys.rhs(t, x);
            }
            fresh = false;
            let fac = if en == 0.0 {
                4.0
            } else {
                (0.9 / en.sqrt()).clamp(0.2, 4.0)
            };
            *h_s = (h * fac).min(span);
        } else {
            if !fresh {
                // the reused Jacobian may be stale: evaluate it where we are
                jac = jacobian(sys, t, x, &f);
                fresh = true;
            }
            let fac = if en.is_finite() {
                (0.9 / en.sqrt()).clamp(0.1, 0.9)
            } else {
                0.1
            };
            *h_s = h * fac;
        }
    }
    steps
}

#[cfg(test)]
mod tests {
    use super::super::test_systems::*;
    use super::*;

    #[test]
    fn second_order_convergence_on_nonlinear_problem() {
        let sys = VanDerPol { mu: 1.0 };
        let run = |n: usize| {
            let h = 2.0 / n as f64;
            let mut x = SVector::<f64, 2>::new(2.0, 0.0);
            for k in 0..n {
                x = step(&sys, k as f64 * h, &x, h).0;
            }
            x
        };
        let reference = run(64_000);
        let e1 = (run(200) - reference).norm();
        let e2 = (run(400) - reference).norm();
        let ratio = e1 / e2;
        assert!((ratio - 4.0).abs() < 0.4, "observed order ratio {ratio}");
    }

    #[test]
    fn l_stable_on_very_stiff_decay() {
        // hλ = -100: RK4 explodes here (see rk4 tests); ROS2 must damp it by its stability
        // function R(z) = (1 + (1-2γ)z)/(1-γz)² ≈ 0.0082 at z = -100.
        let sys = Decay { lambda: 1e5 };
        let z = -100.0;
        let r = (1.0 + (1.0 - 2.0 * GAMMA) * z) / (1.0 - GAMMA * z).powi(2);
        let mut x = SVector::<f64, 1>::new(1.0);
        for k in 0..5 {
            let before = x[0];
            x = step(&sys, k as f64 * 1e-3, &x, 1e-3).0;
            assert!(
                (x[0] / before - r).abs() < 1e-6,
                "step {k}: factor {}",
                x[0] / before
            );
        }
        assert!(x[0].abs() < 1e-9);
    }

    #[test]
    fn stiff_prothero_robinson_tracks_smooth_solution() {
        let sys = ProtheroRobinson { lambda: 1e6 };
        let mut x = SVector::<f64, 1>::new(0.0);
        let h = 1e-2;
        for k in 0..100 {
            x = step(&sys, k as f64 * h, &x, h).0;
        }
        // ROS2 shows order reduction on this problem (a known property of W-methods), but the
        // numerical solution stays on the smooth manifold instead of exploding.
        assert!((x[0] - 1.0f64.sin()).abs() < 1e-2, "got {}", x[0]);
    }

    #[test]
    fn bounded_integration_respects_budget_and_accuracy() {
        let sys = VanDerPol { mu: 5.0 };
        let tol = Tolerance {
            rtol: 1e-6,
            atol: [1e-8; 2],
        };
        let mut x = SVector::<f64, 2>::new(2.0, 0.0);
        let mut h = 1e-3;
        let mut total = 0;
        for k in 0..1000 {
            total += integrate_bounded(
                &sys,
                k as f64 * 1e-3,
                &mut x,
                (k + 1) as f64 * 1e-3,
                &tol,
                &mut h,
                50,
            );
        }
        let mut r = SVector::<f64, 2>::new(2.0, 0.0);
        let n = 100_000;
        for k in 0..n {
            r = crate::solver::rk4::step(&sys, k as f64 * 1.0 / n as f64, &r, 1.0 / n as f64);
        }
        assert!((x - r).norm() < 1e-4, "{x:?} {r:?}");
        assert!((1000..=50_000).contains(&total));
        // a tiny budget still finishes the interval
        let mut y = SVector::<f64, 2>::new(2.0, 0.0);
        let mut h2 = 1e-9;
        let n = integrate_bounded(&sys, 0.0, &mut y, 0.5, &tol, &mut h2, 3);
        assert_eq!(n, 3);
        assert!(y.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn adaptive_meets_tolerance() {
        let sys = VanDerPol { mu: 5.0 };
        let tol = Tolerance {
            rtol: 1e-7,
            atol: [1e-9; 2],
        };
        let mut x = SVector::<f64, 2>::new(2.0, 0.0);
        let mut h = 1e-4;
        let mut stats = AdaptiveStats::default();
        integrate(&sys, 0.0, &mut x, 5.0, &tol, &mut h, &mut stats);
        // reference by very fine fixed steps
        let mut r = SVector::<f64, 2>::new(2.0, 0.0);
        let n = 200_000;
        for k in 0..n {
            r = crate::solver::rk4::step(&sys, k as f64 * 5.0 / n as f64, &r, 5.0 / n as f64);
        }
        assert!((x - r).norm() < 1e-4, "adaptive {x:?} reference {r:?}");
        assert!(stats.accepted > 10);
    }
}
