//! Classical fixed-step 4th-order Runge–Kutta.

use super::OdeSystem;
use nalgebra::SVector;

/// One RK4 step of size `h_s` from (`t_s`, `x`). Four right-hand-side evaluations.
#[inline]
pub fn step<const N: usize, S: OdeSystem<N>>(
    sys: &S,
    t_s: f64,
    x: &SVector<f64, N>,
    h_s: f64,
) -> SVector<f64, N> {
    let half = 0.5 * h_s;
    let k1 = sys.rhs(t_s, x);
    let k2 = sys.rhs(t_s + half, &(x + k1 * half));
    let k3 = sys.rhs(t_s + half, &(x + k2 * half));
    let k4 = sys.rhs(t_s + h_s, &(x + k3 * h_s));
    x + (k1 + (k2 + k3) * 2.0 + k4) * (h_s / 6.0)
}

#[cfg(test)]
mod tests {
    use super::super::test_systems::*;
    use super::*;

    #[test]
    fn fourth_order_convergence_on_decay() {
        let sys = Decay { lambda: 2.0 };
        let err = |n: usize| {
            let h = 1.0 / n as f64;
            let mut x = SVector::<f64, 1>::new(1.0);
            for k in 0..n {
                x = step(&sys, k as f64 * h, &x, h);
            }
            (x[0] - (-2.0f64).exp()).abs()
        };
        let ratio = err(20) / err(40);
        // 2^4 = 16 for a 4th-order method
        assert!((ratio - 16.0).abs() < 1.0, "ratio {ratio}");
    }

    #[test]
    fn unstable_beyond_its_stability_limit() {
        // RK4's real stability interval is about |hλ| < 2.785: beyond it the numerical
        // solution of a decaying ODE grows. This is why the stiff recycle plant needs ROS2.
        let sys = Decay { lambda: 1e5 };
        let mut x = SVector::<f64, 1>::new(1.0);
        for k in 0..20 {
            x = step(&sys, k as f64 * 1e-3, &x, 1e-3);
        }
        assert!(
            x[0].abs() > 1e10,
            "RK4 at hλ = 100 should blow up, got {}",
            x[0]
        );
    }
}
