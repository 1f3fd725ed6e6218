//! Steady states and linear stability of the plants.

use crate::solver::{jacobian_central, OdeSystem};
use nalgebra::{Complex, DMatrix, SVector};

/// All roots of a scalar function on [lo, hi]: scan `n` intervals for sign changes, refine by
/// bisection. NaN values are treated as gaps. Roots are returned in increasing order.
pub fn roots_1d(f: impl Fn(f64) -> f64, lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let mut out = Vec::new();
    let mut x0 = lo;
    let mut f0 = f(x0);
    for k in 1..=n {
        let x1 = lo + (hi - lo) * k as f64 / n as f64;
        let f1 = f(x1);
        if f0.is_finite() && f1.is_finite() && f0 * f1 <= 0.0 && !(f0 == 0.0 && k > 1) {
            let (mut a, mut b, mut fa) = (x0, x1, f0);
            for _ in 0..200 {
                let m = 0.5 * (a + b);
                let fm = f(m);
                if !fm.is_finite() {
                    break;
                }
                if fa * fm <= 0.0 {
                    b = m;
                } else {
                    a = m;
                    fa = fm;
                }
                if (b - a).abs() <= 1e-14 * (1.0 + a.abs()) {
                    break;
                }
            }
            out.push(0.5 * (a + b));
        }
        x0 = x1;
        f0 = f1;
    }
    out
}

/// Eigenvalues of the Jacobian of `sys` at `x` (central differences).
pub fn eigenvalues<const N: usize, S: OdeSystem<N>>(
    sys: &S,
    x: &SVector<f64, N>,
) -> Vec<Complex<f64>> {
    let j = jacobian_central(sys, 0.0, x);
    let d = DMatrix::from_fn(N, N, |r, c| j[(r, c)]);
    d.complex_eigenvalues().iter().copied().collect()
}

/// Largest real part of the Jacobian's eigenvalues: < 0 means locally asymptotically stable.
pub fn spectral_abscissa<const N: usize, S: OdeSystem<N>>(sys: &S, x: &SVector<f64, N>) -> f64 {
    eigenvalues(sys, x)
        .iter()
        .map(|c| c.re)
        .fold(f64::NEG_INFINITY, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_all_roots_of_cubic() {
        let r = roots_1d(|x| (x - 1.0) * (x - 2.0) * (x + 0.5), -3.0, 3.0, 600);
        assert_eq!(r.len(), 3);
        for (a, b) in r.iter().zip([-0.5, 1.0, 2.0]) {
            assert!((a - b).abs() < 1e-10, "{a} {b}");
        }
    }
}
