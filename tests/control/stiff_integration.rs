//! Issue 2 acceptance: the stiff recycle model (seed 002 §5; ERRATA: line inertias near
//! 10⁴–10⁵ s⁻¹) integrated at the daemon's real-time step of 1 ms. The test shows which method
//! and step it needs: RK4 at 1 ms diverges; ROS2 (L-stable) at 1 ms stays stable and accurate;
//! RK4 needs sub-steps below 2.8/|λ_max|. All against a tight-tolerance Dormand–Prince reference.

use crate::common;

use antisurge::plant::recycle_system::{RecyclePlant, N};
use antisurge::plant::SimPlant;
use antisurge::solver::{dormand_prince, rk4, rosenbrock, AdaptiveStats, Tolerance};
use nalgebra::SVector;

const T_END: f64 = 0.5;
const H: f64 = 1e-3;

fn setup() -> (RecyclePlant, SVector<f64, N>) {
    let desc = common::plant("kvangardsnes2009_recycle");
    let init = desc.file.initial;
    let SimPlant::Recycle(mut p) = common::node::plant_at_initial_point(&desc).0 else {
        panic!("recycle plant expected")
    };
    let x0 = p.x;
    // excite the dynamics: throttle command steps 60 % → 50 % at t = 0, valve held
    let torque = p.shaft.load_torque_nm(x0[2], x0[5]);
    p.hold_inputs(torque, init.recycle_valve, 0.5, init.feed);
    (p, x0)
}

/// Largest component error relative to typical magnitudes (Pa ~ 1 MPa, kg/s ~ 10, rad/s ~ 1000).
fn err(a: &SVector<f64, N>, b: &SVector<f64, N>) -> f64 {
    let scale = [1e6, 1e6, 10.0, 10.0, 10.0, 1000.0, 1.0, 1.0, 1.0];
    (0..N)
        .map(|i| {
            let e = (a[i] - b[i]).abs() / scale[i];
            if e.is_finite() {
                e
            } else {
                f64::INFINITY
            }
        })
        .fold(0.0, f64::max)
}

fn reference(p: &RecyclePlant, x0: &SVector<f64, N>) -> Vec<SVector<f64, N>> {
    let tol = Tolerance {
        rtol: 1e-10,
        atol: [1e-3, 1e-3, 1e-8, 1e-8, 1e-8, 1e-7, 1e-10, 1e-10, 1e-10],
    };
    let mut x = *x0;
    let mut h = 1e-7;
    let mut stats = AdaptiveStats::default();
    let n = (T_END / H).round() as usize;
    let mut out = vec![x];
    for k in 0..n {
        dormand_prince::integrate(
            p,
            k as f64 * H,
            &mut x,
            (k + 1) as f64 * H,
            &tol,
            &mut h,
            &mut stats,
        );
        out.push(x);
    }
    out
}

fn max_err_fixed(
    p: &RecyclePlant,
    x0: &SVector<f64, N>,
    r: &[SVector<f64, N>],
    substeps: usize,
    step: impl Fn(&RecyclePlant, f64, &SVector<f64, N>, f64) -> SVector<f64, N>,
) -> f64 {
    use antisurge::solver::OdeSystem;
    let mut x = *x0;
    let mut worst: f64 = 0.0;
    let h = H / substeps as f64;
    for k in 0..r.len() - 1 {
        for j in 0..substeps {
            x = step(p, k as f64 * H + j as f64 * h, &x, h);
            p.project(&mut x);
        }
        worst = worst.max(err(&x, &r[k + 1]));
        if !worst.is_finite() || worst > 1e6 {
            return f64::INFINITY;
        }
    }
    worst
}

#[test]
fn ros2_is_stable_at_one_millisecond_where_rk4_diverges() {
    let (p, x0) = setup();
    let lam = antisurge::plant::analysis::eigenvalues(&p, &x0)
        .iter()
        .map(|c| c.norm())
        .fold(0.0, f64::max);
    assert!(lam * H > 2.8, "not stiff at 1 ms: |λ|max = {lam} s⁻¹");
    let r = reference(&p, &x0);
    assert!(
        err(&r[r.len() - 1], &x0) > 1e-3,
        "the step must excite the dynamics"
    );

    let rk4_1ms = max_err_fixed(&p, &x0, &r, 1, rk4::step);
    let ros2_1ms = max_err_fixed(&p, &x0, &r, 1, |s, t, x, h| rosenbrock::step(s, t, x, h).0);
    // RK4's real stability limit is |hλ| ≈ 2.785: sub-steps so that |hλ| ≤ 2.5
    let sub = (lam * H / 2.5).ceil() as usize;
    let rk4_sub = max_err_fixed(&p, &x0, &r, sub, rk4::step);
    // the plant file's setting: ROS2 with error-controlled sub-steps inside each period
    let mut x = x0;
    let mut h = H;
    let tol = Tolerance {
        rtol: 1e-4,
        atol: antisurge::solver::OdeSystem::abs_tolerance(&p),
    };
    let mut ros2_adaptive: f64 = 0.0;
    let mut steps = 0u32;
    for k in 0..r.len() - 1 {
        steps += rosenbrock::integrate_bounded(
            &p,
            k as f64 * H,
            &mut x,
            (k + 1) as f64 * H,
            &tol,
            &mut h,
            200,
        );
        ros2_adaptive = ros2_adaptive.max(err(&x, &r[k + 1]));
    }
    eprintln!("|λ|max = {lam:.0} s⁻¹ (|hλ| = {:.1} at 1 ms)", lam * H);
    eprintln!("RK4  1 ms:            max error {rk4_1ms:.3e}");
    eprintln!("RK4  1 ms / {sub:>3} sub-steps: max error {rk4_sub:.3e}");
    eprintln!("ROS2 1 ms:            max error {ros2_1ms:.3e}");
    eprintln!(
        "ROS2 adaptive (rtol 1e-4): max error {ros2_adaptive:.3e}, {steps} steps for {} periods",
        r.len() - 1
    );

    assert!(
        rk4_1ms.is_infinite() || rk4_1ms > 1.0,
        "RK4 at 1 ms should diverge: {rk4_1ms}"
    );
    assert!(ros2_1ms < 2e-2, "ROS2 at 1 ms: {ros2_1ms}");
    assert!(rk4_sub < 1e-3, "RK4 with {sub} sub-steps: {rk4_sub}");
    assert!(ros2_adaptive < 5e-3, "adaptive ROS2: {ros2_adaptive}");
    // error control never does worse than the fixed step (it only subdivides)
    assert!(
        ros2_adaptive <= ros2_1ms * (1.0 + 1e-9),
        "{ros2_adaptive} vs {ros2_1ms}"
    );
}
