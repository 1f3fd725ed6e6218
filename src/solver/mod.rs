//! Integrators for the plant models.
//!
//! All of them are allocation-free and work on fixed-size state vectors (`nalgebra::SVector`).
//! - [`rk4`]: classical fixed-step Runge–Kutta, the real-time default for non-stiff plants.
//! - [`rosenbrock`]: a linearly implicit, L-stable second-order method (ROS2) for the stiff
//!   recycle model (seed 002 §5 needed a stiff solver: the recycle and check-valve line
//!   inertias reach ~10⁵ s⁻¹ when the valve is nearly closed), fixed-step or adaptive.
//! - [`dormand_prince`]: adaptive explicit 5(4) pair, used as the tight-tolerance reference.

pub mod dormand_prince;
pub mod linalg;
pub mod rk4;
pub mod rosenbrock;

use nalgebra::SVector;
use serde::{Deserialize, Serialize};

/// An autonomous-in-structure ODE ẋ = f(t, x) with inputs held inside `self` (zero-order hold).
pub trait OdeSystem<const N: usize> {
    /// Time derivative of the state at time `t_s`.
    fn rhs(&self, t_s: f64, x: &SVector<f64, N>) -> SVector<f64, N>;

    /// Enforce hard constraints after a step (e.g. a check valve's flow cannot go negative,
    /// a valve position stays in 0..1). Default: none.
    fn project(&self, _x: &mut SVector<f64, N>) {}

    /// Absolute error tolerance per state component for adaptive stepping, in that component's
    /// unit. Default: 1e-6 for every component.
    fn abs_tolerance(&self) -> [f64; N] {
        [1e-6; N]
    }
}

/// Which fixed-step method a plant uses in real time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Classical 4th-order Runge–Kutta.
    #[default]
    Rk4,
    /// Linearly implicit ROS2 (L-stable, 2nd order): for stiff plants.
    Rosenbrock,
}

/// Integration settings of a plant for one control period.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepSettings {
    /// Integration method.
    #[serde(default)]
    pub method: Method,
    /// Number of internal sub-steps per control period (≥ 1) when not adaptive.
    #[serde(default = "one")]
    pub substeps: u32,
    /// Relative tolerance for error-controlled sub-stepping inside each control period
    /// (Rosenbrock only). The step adapts between periods; `max_substeps` bounds the work so
    /// the plant keeps real time.
    #[serde(default)]
    pub rtol: Option<f64>,
    /// Upper bound on sub-steps per control period in adaptive mode.
    #[serde(default = "default_max_substeps")]
    pub max_substeps: u32,
}

fn one() -> u32 {
    1
}
fn default_max_substeps() -> u32 {
    200
}

impl Default for StepSettings {
    fn default() -> Self {
        StepSettings {
            method: Method::Rk4,
            substeps: 1,
            rtol: None,
            max_substeps: default_max_substeps(),
        }
    }
}

/// Advance `x` from `t_s` by `h_s` with the chosen method: fixed sub-steps, or (Rosenbrock
/// with `rtol`) error-controlled sub-steps carrying the step size in `h_state_s`.
pub fn advance_adaptive<const N: usize, S: OdeSystem<N>>(
    sys: &S,
    settings: StepSettings,
    t_s: f64,
    x: &mut SVector<f64, N>,
    h_s: f64,
    h_state_s: &mut f64,
) {
    match (settings.method, settings.rtol) {
        (Method::Rosenbrock, Some(rtol)) => {
            let tol = Tolerance {
                rtol,
                atol: sys.abs_tolerance(),
            };
            if h_state_s.is_nan() || *h_state_s <= 0.0 || *h_state_s > h_s {
                *h_state_s = h_s;
            }
            rosenbrock::integrate_bounded(
                sys,
                t_s,
                x,
                t_s + h_s,
                &tol,
                h_state_s,
                settings.max_substeps,
            );
        }
        _ => advance(sys, settings, t_s, x, h_s),
    }
}

/// Advance `x` from `t_s` by `h_s` with the chosen fixed-step method and sub-steps.
pub fn advance<const N: usize, S: OdeSystem<N>>(
    sys: &S,
    settings: StepSettings,
    t_s: f64,
    x: &mut SVector<f64, N>,
    h_s: f64,
) {
    let n = settings.substeps.max(1);
    let h = h_s / f64::from(n);
    let mut t = t_s;
    for _ in 0..n {
        *x = match settings.method {
            Method::Rk4 => rk4::step(sys, t, x, h),
            Method::Rosenbrock => rosenbrock::step(sys, t, x, h).0,
        };
        sys.project(x);
        t += h;
    }
}

/// Forward-difference Jacobian ∂f/∂x at (t, x); used by the Rosenbrock method and for
/// stability analysis. Relative perturbation √ε·max(|xᵢ|, scaleᵢ).
pub fn jacobian<const N: usize, S: OdeSystem<N>>(
    sys: &S,
    t_s: f64,
    x: &SVector<f64, N>,
    f0: &SVector<f64, N>,
) -> nalgebra::SMatrix<f64, N, N> {
    let mut jac = nalgebra::SMatrix::<f64, N, N>::zeros();
    let mut xp = *x;
    for j in 0..N {
        let delta = f64::EPSILON.sqrt() * x[j].abs().max(1e-6);
        xp[j] = x[j] + delta;
        let fp = sys.rhs(t_s, &xp);
        xp[j] = x[j];
        for i in 0..N {
            jac[(i, j)] = (fp[i] - f0[i]) / delta;
        }
    }
    jac
}

/// Central-difference Jacobian: more accurate, twice the cost. Used for stability analysis.
pub fn jacobian_central<const N: usize, S: OdeSystem<N>>(
    sys: &S,
    t_s: f64,
    x: &SVector<f64, N>,
) -> nalgebra::SMatrix<f64, N, N> {
    let mut jac = nalgebra::SMatrix::<f64, N, N>::zeros();
    let mut xp = *x;
    for j in 0..N {
        let delta = f64::EPSILON.cbrt() * x[j].abs().max(1e-6);
        xp[j] = x[j] + delta;
        let fp = sys.rhs(t_s, &xp);
        xp[j] = x[j] - delta;
        let fm = sys.rhs(t_s, &xp);
        xp[j] = x[j];
        for i in 0..N {
            jac[(i, j)] = (fp[i] - fm[i]) / (2.0 * delta);
        }
    }
    jac
}

/// Weighted RMS error norm used by the adaptive methods: √(mean((eᵢ / (atol + rtol·max(|aᵢ|,|bᵢ|)))²)).
pub(crate) fn error_norm<const N: usize>(
    err: &SVector<f64, N>,
    a: &SVector<f64, N>,
    b: &SVector<f64, N>,
    tol: &Tolerance<N>,
) -> f64 {
    let mut sum = 0.0;
    for i in 0..N {
        let sc = tol.atol[i] + tol.rtol * a[i].abs().max(b[i].abs());
        let r = err[i] / sc;
        sum += r * r;
    }
    (sum / N as f64).sqrt()
}

/// Tolerances for adaptive integration: one relative tolerance, per-component absolute ones
/// (states have very different scales: Pa and kg/s).
#[derive(Debug, Clone, Copy)]
pub struct Tolerance<const N: usize> {
    /// Relative tolerance.
    pub rtol: f64,
    /// Absolute tolerance per state component, in that component's unit.
    pub atol: [f64; N],
}

/// Statistics of an adaptive integration.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AdaptiveStats {
    /// Accepted steps.
    pub accepted: u64,
    /// Rejected steps.
    pub rejected: u64,
    /// Right-hand-side evaluations.
    pub rhs_evals: u64,
}

#[cfg(test)]
pub(crate) mod test_systems {
    use super::*;

    /// Van der Pol oscillator with stiffness parameter mu.
    pub struct VanDerPol {
        pub mu: f64,
    }
    impl OdeSystem<2> for VanDerPol {
        fn rhs(&self, _t: f64, x: &SVector<f64, 2>) -> SVector<f64, 2> {
            SVector::<f64, 2>::new(x[1], self.mu * (1.0 - x[0] * x[0]) * x[1] - x[0])
        }
    }

    /// Linear decay ẋ = -λ x (exact solution x0 e^{-λt}).
    pub struct Decay {
        pub lambda: f64,
    }
    impl OdeSystem<1> for Decay {
        fn rhs(&self, _t: f64, x: &SVector<f64, 1>) -> SVector<f64, 1> {
            SVector::<f64, 1>::new(-self.lambda * x[0])
        }
    }

    /// Prothero–Robinson: ẋ = -λ (x − sin t) + cos t, exact x = sin t for x(0)=0; stiff for large λ.
    pub struct ProtheroRobinson {
        pub lambda: f64,
    }
    impl OdeSystem<1> for ProtheroRobinson {
        fn rhs(&self, t: f64, x: &SVector<f64, 1>) -> SVector<f64, 1> {
            SVector::<f64, 1>::new(-self.lambda * (x[0] - t.sin()) + t.cos())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::test_systems::*;
    use super::*;

    #[test]
    fn jacobian_matches_analytic() {
        let sys = VanDerPol { mu: 3.0 };
        let x = SVector::<f64, 2>::new(0.7, -1.3);
        let f0 = sys.rhs(0.0, &x);
        let j = jacobian(&sys, 0.0, &x, &f0);
        let jc = jacobian_central(&sys, 0.0, &x);
        // analytic: [[0, 1], [-2 mu x0 x1 - 1, mu (1 - x0²)]]
        let exact = [
            [0.0, 1.0],
            [-2.0 * 3.0 * 0.7 * -1.3 - 1.0, 3.0 * (1.0 - 0.49)],
        ];
        for i in 0..2 {
            for k in 0..2 {
                assert!((j[(i, k)] - exact[i][k]).abs() < 1e-6, "fwd {i}{k}");
                assert!((jc[(i, k)] - exact[i][k]).abs() < 1e-8, "central {i}{k}");
            }
        }
    }

    #[test]
    fn advance_with_substeps_matches_smaller_steps() {
        let sys = VanDerPol { mu: 1.0 };
        let mut a = SVector::<f64, 2>::new(2.0, 0.0);
        let mut b = a;
        let s4 = StepSettings {
            method: Method::Rk4,
            substeps: 4,
            ..StepSettings::default()
        };
        advance(&sys, s4, 0.0, &mut a, 0.1);
        for k in 0..4 {
            advance(
                &sys,
                StepSettings::default(),
                k as f64 * 0.025,
                &mut b,
                0.025,
            );
        }
        assert!((a - b).norm() < 1e-14);
    }
}
