//! Verdicts that cannot lie: a run that sits in fail-safe, saturates its drive or leaves the
//! plausible state space is not "stable", whatever the surge detector saw.

use crate::common;

use antisurge::control::LawId;

/// Seed 000 Proposition 1 gains with a sampled speed loop that is unstable at 1 kHz:
/// K1·h/J = 1000 · 1e-3 / 0.5 = 2 (the pole 1 − K1 h/J = −1 sits on the unit circle, and with
/// the speed loop on top, outside). Before the verdict was fixed this run reported
/// "STABLE — no surge" while the controller sat in fail-safe and the speed ran away.
#[test]
fn drive_torque_with_k1_h_over_j_of_2_is_reported_unstable() {
    let mut plant = common::plant("bohagen2007_plenum");
    let j = plant.file.shaft.inertia_kg_m2;
    let h = 1e-3;
    plant.controller.drive_torque.k1_nm_s_rad = 2.0 * j / h;
    let s = common::simulate(
        &plant,
        &common::scenario("throttle_closure"),
        LawId::DriveTorque,
    )
    .summary;
    assert!(!s.stable, "{s:#?}");
    assert!(
        s.verdict.starts_with("UNSTABLE") || s.verdict.starts_with("SURGE"),
        "{}",
        s.verdict
    );
    assert!(
        s.failsafe_fraction >= 0.01
            || s.torque_saturation_fraction >= 0.2
            || !s.implausible.is_empty(),
        "{s:#?}"
    );
}

/// The seed's continuous-time K1 = 10 000 N·m·s/rad at 1 kHz (K1·h/J = 50): the torque
/// chatters between the drive's limits.
#[test]
fn drive_torque_with_the_seed_k1_is_reported_unstable() {
    let mut plant = common::plant("bohagen2007_plenum");
    plant.controller.drive_torque.k1_nm_s_rad = 10_000.0;
    let s = common::simulate(
        &plant,
        &common::scenario("throttle_closure"),
        LawId::DriveTorque,
    )
    .summary;
    assert!(!s.stable, "{s:#?}");
    assert!(!s.verdict.starts_with("STABLE"), "{}", s.verdict);
}

/// The shipped tuning is stable and says so, with the closest approach taken during the
/// closure (not the t = 0 point) and the law's own torque peak, not the load torque.
#[test]
fn shipped_drive_torque_closure_is_stable_and_its_figures_come_from_the_event() {
    let plant = common::plant("bohagen2007_plenum");
    let s = common::simulate(
        &plant,
        &common::scenario("throttle_closure"),
        LawId::DriveTorque,
    )
    .summary;
    assert!(s.stable, "{s:#?}");
    assert_eq!(s.verdict, "STABLE — no surge");
    assert_eq!(s.failsafe_fraction, 0.0);
    assert!(s.torque_saturation_fraction < 0.01, "{s:#?}");
    let a = s.closest_approach;
    assert!(a.min_flow_at_s >= a.from_s && a.from_s > 0.0, "{a:?}");
    // the t = 0 flow is ≈ 8.8 kg/s; the closure takes it far lower
    assert!(a.min_flow_kg_s < 4.0, "{a:?}");
    let p = s.actuator_peaks;
    assert!(p.law_drive_torque_nm > 0.0 && p.law_drive_torque_nm < p.drive_torque_rating_nm);
}

/// A transmitter failure is reported with its time and cause, and the observer's error.
#[test]
fn flow_transmitter_failure_names_the_fallback_and_its_time() {
    let plant = common::plant("kvangardsnes2009_recycle");
    let s = common::simulate(
        &plant,
        &common::scenario("flow_transmitter_failure"),
        LawId::RecyclePi,
    )
    .summary;
    assert_eq!(s.flow_source.configured, "orifice_with_observer_fallback");
    let f = s.flow_source.fallbacks.first().expect("a fallback");
    assert!((4.0..4.2).contains(&f.from_s), "{f:?}");
    assert_eq!(f.cause, "flow transmitter stale");
    assert!(f.observer_max_error_kg_s.is_finite());
    let plain = common::simulate(
        &plant,
        &common::scenario("throttle_closure"),
        LawId::RecyclePi,
    )
    .summary;
    assert!(plain.flow_source.fallbacks.is_empty());
}
