//! The throttle of the nondimensional spool model of seed 003 (shared by the simulated spool
//! plant and the spool laws' equilibrium and feedforward terms).

use super::smooth_signed_sqrt;

/// Throttle function F(γ, ψ) = γ √ψ (seed 003 §III-B, after its refs. [3], [11]), with the
/// square root smoothed through 0 (seed 001 eq. 2.8–2.9) so a pressure reversal stays
/// differentiable. γ: throttle gain, ψ: nondimensional pressure rise; returns the
/// nondimensional throttle flow.
#[inline]
pub fn throttle_function(gamma: f64, psi: f64) -> f64 {
    gamma * smooth_signed_sqrt(psi, 1e4)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_root_law_and_smooth_through_zero() {
        assert!((throttle_function(0.5, 0.04) - 0.1).abs() < 1e-12);
        assert!(throttle_function(0.5, -0.04) < 0.0);
        assert!(throttle_function(0.5, 0.0).abs() < 1e-12);
    }
}
