//! Dense LU with partial pivoting on fixed-size matrices: allocation-free and usable with a
//! generic const dimension (nalgebra's own LU needs type-level dimension bounds there).

use nalgebra::{SMatrix, SVector};

/// LU factors of a square matrix (Doolittle, row pivoting), stored in place.
#[derive(Debug, Clone, Copy)]
pub struct Lu<const N: usize> {
    lu: SMatrix<f64, N, N>,
    perm: [usize; N],
}

impl<const N: usize> Lu<N> {
    /// Factor `a`. Returns `None` if a pivot is exactly zero or not finite.
    pub fn new(mut a: SMatrix<f64, N, N>) -> Option<Self> {
        let mut perm = [0usize; N];
        for (i, p) in perm.iter_mut().enumerate() {
            *p = i;
        }
        for k in 0..N {
            // pivot: largest magnitude in column k at or below row k
            let mut p = k;
            let mut best = a[(k, k)].abs();
            for i in (k + 1)..N {
                let v = a[(i, k)].abs();
                if v > best {
                    best = v;
                    p = i;
                }
            }
            if best == 0.0 || !best.is_finite() {
                return None;
            }
            if p != k {
                a.swap_rows(p, k);
                perm.swap(p, k);
            }
            let pivot = a[(k, k)];
            for i in (k + 1)..N {
                let l = a[(i, k)] / pivot;
                a[(i, k)] = l;
                for j in (k + 1)..N {
                    let u = a[(k, j)];
                    a[(i, j)] -= l * u;
                }
            }
        }
        Some(Lu { lu: a, perm })
    }

    /// Solve A x = b.
    pub fn solve(&self, b: &SVector<f64, N>) -> SVector<f64, N> {
        let mut y = SVector::<f64, N>::zeros();
        for i in 0..N {
            let mut s = b[self.perm[i]];
            for j in 0..i {
                s -= self.lu[(i, j)] * y[j];
            }
            y[i] = s;
        }
        for i in (0..N).rev() {
            let mut s = y[i];
            for j in (i + 1)..N {
                s -= self.lu[(i, j)] * y[j];
            }
            y[i] = s / self.lu[(i, i)];
        }
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_with_pivoting() {
        // a zero on the first diagonal entry forces a row swap
        let a = SMatrix::<f64, 3, 3>::new(0.0, 2.0, 1.0, 1.0, 1.0, 0.0, 3.0, 0.0, 1.0);
        let x = SVector::<f64, 3>::new(1.0, -2.0, 0.5);
        let b = a * x;
        let lu = Lu::new(a).expect("regular");
        assert!((lu.solve(&b) - x).norm() < 1e-12);
    }

    #[test]
    fn singular_is_none() {
        let a = SMatrix::<f64, 2, 2>::new(1.0, 2.0, 2.0, 4.0);
        assert!(Lu::new(a).is_none());
    }
}
