//! Compressor-system physics from the seed papers: pure functions and small structs, SI units,
//! no I/O and no heap allocation per evaluation.
//!
//! Each formula carries a comment naming its seed and equation. Seeds are numbered as in
//! docs/science.md (titles there): 000 Bøhagen & Gravdahl, 001 Hemchi & Tebba, 002 Kvangardsnes,
//! 003 Liaw, Song & Huang, 004 Sanadgol & Maslen.

pub mod characteristic;
pub mod compressor_map;
pub mod gas;
pub mod orifice;
pub mod shaft;
pub mod spool_throttle;
pub mod thrust_bearing;
pub mod tip_clearance;
pub mod valve;

/// Smooth sign of `x` with transition width ~1/`xi` (seed 001 eq. 2.7: sgn(x) ≈ tanh(ξx)).
#[inline]
pub fn smooth_sign(x: f64, xi: f64) -> f64 {
    (xi * x).tanh()
}

/// Smooth signed square root: sgn(x)·√|x| with the sign and absolute value of seed 001
/// eq. 2.8–2.9, i.e. tanh(ξx)·√(x·tanh(ξx)). Continuously differentiable through zero, which
/// keeps implicit integrators and Newton solvers well-behaved when a flow reverses.
#[inline]
pub fn smooth_signed_sqrt(x: f64, xi: f64) -> f64 {
    let t = (xi * x).tanh();
    t * (x * t).max(0.0).sqrt()
}
