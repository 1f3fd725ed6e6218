//! Dormand–Prince 5(4) adaptive explicit Runge–Kutta: the tight-tolerance reference against
//! which the real-time integrators are checked.

use super::{error_norm, AdaptiveStats, OdeSystem, Tolerance};
use nalgebra::SVector;

const C2: f64 = 1.0 / 5.0;
const C3: f64 = 3.0 / 10.0;
const C4: f64 = 4.0 / 5.0;
const C5: f64 = 8.0 / 9.0;
const A21: f64 = 1.0 / 5.0;
const A31: f64 = 3.0 / 40.0;
const A32: f64 = 9.0 / 40.0;
const A41: f64 = 44.0 / 45.0;
const A42: f64 = -56.0 / 15.0;
const A43: f64 = 32.0 / 9.0;
const A51: f64 = 19372.0 / 6561.0;
const A52: f64 = -25360.0 / 2187.0;
const A53: f64 = 64448.0 / 6561.0;
const A54: f64 = -212.0 / 729.0;
const A61: f64 = 9017.0 / 3168.0;
const A62: f64 = -355.0 / 33.0;
const A63: f64 = 46732.0 / 5247.0;
const A64: f64 = 49.0 / 176.0;
const A65: f64 = -5103.0 / 18656.0;
const B1: f64 = 35.0 / 384.0;
const B3: f64 = 500.0 / 1113.0;
const B4: f64 = 125.0 / 192.0;
const B5: f64 = -2187.0 / 6784.0;
const B6: f64 = 11.0 / 84.0;
// difference between the 5th- and 4th-order weights
const E1: f64 = B1 - 5179.0 / 57600.0;
const E3: f64 = B3 - 7571.0 / 16695.0;
const E4: f64 = B4 - 393.0 / 640.0;
const E5: f64 = B5 - -92097.0 / 339200.0;
const E6: f64 = B6 - 187.0 / 2100.0;
const E7: f64 = -1.0 / 40.0;

/// One Dormand–Prince step: returns (5th-order solution, error estimate).
pub fn step<const N: usize, S: OdeSystem<N>>(
    sys: &S,
    t: f64,
    x: &SVector<f64, N>,
    h: f64,
) -> (SVector<f64, N>, SVector<f64, N>) {
    let k1 = sys.rhs(t, x);
    let k2 = sys.rhs(t + C2 * h, &(x + k1 * (A21 * h)));
    let k3 = sys.rhs(t + C3 * h, &(x + (k1 * A31 + k2 * A32) * h));
    let k4 = sys.rhs(t + C4 * h, &(x + (k1 * A41 + k2 * A42 + k3 * A43) * h));
    let k5 = sys.rhs(
        t + C5 * h,
        &(x + (k1 * A51 + k2 * A52 + k3 * A53 + k4 * A54) * h),
    );
    let k6 = sys.rhs(
        t + h,
        &(x + (k1 * A61 + k2 * A62 + k3 * A63 + k4 * A64 + k5 * A65) * h),
    );
    let x_new = x + (k1 * B1 + k3 * B3 + k4 * B4 + k5 * B5 + k6 * B6) * h;
    let k7 = sys.rhs(t + h, &x_new);
    let err = (k1 * E1 + k3 * E3 + k4 * E4 + k5 * E5 + k6 * E6 + k7 * E7) * h;
    (x_new, err)
}

/// Adaptive Dormand–Prince from `t0_s` to `t1_s`, landing exactly on `t1_s`.
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
        stats.rhs_evals += 7;
        sys.project(&mut x_new);
        let en = error_norm(&err, x, &x_new, tol);
        if en <= 1.0 || h <= h_min {
            t = if last { t1_s } else { t + h };
            *x = x_new;
            stats.accepted += 1;
            let fac = if en == 0.0 {
                5.0
            } else {
                (0.9 * en.powf(-0.2)).clamp(0.2, 5.0)
            };
            if !last || fac < 1.0 {
                *h_s = h * fac;
            }
        } else {
            stats.rejected += 1;
            *h_s = h * (0.9 * en.powf(-0.2)).clamp(0.1, 0.9);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_systems::*;
    use super::*;

    #[test]
    fn fifth_order_step() {
        let sys = Decay { lambda: 1.0 };
        let err = |h: f64| {
            let (x, _) = step(&sys, 0.0, &SVector::<f64, 1>::new(1.0), h);
            (x[0] - (-h).exp()).abs()
        };
        // local error O(h^6)
        let ratio = err(0.2) / err(0.1);
        assert!(ratio > 50.0 && ratio < 80.0, "ratio {ratio}");
    }

    #[test]
    fn adaptive_hits_tight_tolerance() {
        let sys = VanDerPol { mu: 1.0 };
        let tol = Tolerance {
            rtol: 1e-11,
            atol: [1e-12; 2],
        };
        let mut x = SVector::<f64, 2>::new(2.0, 0.0);
        let mut h = 1e-3;
        let mut stats = AdaptiveStats::default();
        integrate(&sys, 0.0, &mut x, 3.0, &tol, &mut h, &mut stats);
        let mut r = SVector::<f64, 2>::new(2.0, 0.0);
        let n = 30_000;
        for k in 0..n {
            r = crate::solver::rk4::step(&sys, k as f64 * 3.0 / n as f64, &r, 3.0 / n as f64);
        }
        assert!((x - r).norm() < 1e-9, "{x:?} vs {r:?}");
    }
}
