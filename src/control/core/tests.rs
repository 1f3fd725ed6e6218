//! The control core's own tests (closed loop on the simulated plant).

use super::*;
use crate::control::supervisor::InputLimits;

use crate::scenario::Scenario;
use crate::sim::case::PlantCase;
use crate::sim::PlantRun;
use std::path::Path;

fn kvangardsnes() -> PlantCase {
    let p =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("config/plants/kvangardsnes2009_recycle.toml");
    PlantCase::load(&p).expect("plant")
}

fn hold() -> Scenario {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/scenarios/hold.toml");
    Scenario::load(&p).expect("scenario")
}

fn core_for(desc: &PlantCase, grace_s: f64) -> ControlCore {
    let model = crate::sim::control_model(desc);
    let mut settings = CoreSettings::defaults_for(&model);
    settings.startup_grace_s = grace_s;
    // these tests look at single cycles: no failure hold, no exit hysteresis
    settings.failure_hold_s = 0.0;
    settings.failsafe_exit_s = 0.0;
    let config = model.controller.clone();
    ControlCore::new(model, config, settings, LawId::RecyclePi, 0.0).expect("core")
}

fn op(core: &ControlCore) -> OperatorInputs {
    OperatorInputs {
        speed_setpoint_rad_s: core.model().drive.nominal_speed_rad_s,
        throttle_demand: f64::NAN,
        flow_setpoint_kg_s: f64::NAN,
        recycle_manual: f64::NAN,
    }
}

/// A core on kvangardsnes (start-up grace `grace_s`), the plant's healthy initial sample
/// and the operator inputs.
fn started(grace_s: f64) -> (ControlCore, RawSensors, OperatorInputs) {
    let desc = kvangardsnes();
    let sc = hold();
    let mut run = PlantRun::new(&desc, &sc).expect("run");
    let core = core_for(&desc, grace_s);
    let op = op(&core);
    let (_, raw) = run.sense(0.0);
    (core, raw, op)
}

/// Vendor data only (no map, no model, the drive on its own governor): recycle-pi runs on
/// pressures, Δp and valve position without a speed reading and never commands torque.
#[test]
fn a_drive_the_controller_does_not_own_gets_no_torque_and_speed_is_not_essential() {
    let desc = kvangardsnes();
    let mut m = desc.machine();
    m.family = None;
    m.map = None;
    m.recycle = None;
    m.owns_drive_speed_loop = false;
    let model = ControlModel::from_machine(&m, desc.controller.clone());
    let mut settings = CoreSettings::defaults_for(&model);
    settings.startup_grace_s = 0.0;
    let config = model.controller.clone();
    let mut core = ControlCore::new(model, config, settings, LawId::RecyclePi, 0.0)
        .expect("recycle-pi on vendor data");
    let sc = hold();
    let mut run = PlantRun::new(&desc, &sc).expect("run");
    let (_, mut raw) = run.sense(0.0);
    raw.values.set(SensorId::ShaftSpeed, f64::NAN);
    raw.age_s[SensorId::ShaftSpeed.index()] = f64::INFINITY;
    let op = op(&core);
    for k in 0..20 {
        let t = k as f64 * 1e-3;
        for a in raw.age_s.iter_mut().filter(|a| a.is_finite()) {
            *a = 0.0;
        }
        let out = core.cycle(t, &raw, &op);
        assert_eq!(out.mode, Mode::Auto, "cycle {k}");
        assert!(
            out.commands.get(ActuatorId::DriveTorque).is_nan(),
            "cycle {k}"
        );
        assert!(out.commands.get(ActuatorId::RecycleValve).is_finite());
        let (_, next) = run.sense(t);
        raw.values = next.values;
        raw.sample_seq = next.sample_seq;
        raw.values.set(SensorId::ShaftSpeed, f64::NAN);
    }
    // the plant-file machine owns its drive: the same sample without speed fails safe
    let mut owned = core_for(&desc, 0.0);
    let out = owned.cycle(0.0, &raw, &op);
    assert_eq!(out.mode, Mode::FailSafe);
}

/// A core whose ESD input is bound (supervised 0..1, 50 ms like the other inputs).
fn with_esd(mut core: ControlCore) -> ControlCore {
    let mut s = *core.settings();
    s.supervisor.limits[SensorId::EsdInput.index()] = Some(InputLimits {
        min: 0.0,
        max: 1.0,
        timeout_s: 0.05,
    });
    core.set_settings(s);
    core
}

#[test]
fn the_esd_input_opens_the_valve_at_once_and_the_law_resumes_from_open() {
    let (core, mut raw, op) = started(0.0);
    let mut core = with_esd(core);
    let mut t = 0.0;
    let mut cycle = |core: &mut ControlCore, raw: &RawSensors| {
        t += 1e-3;
        core.cycle(t, raw, &op)
    };
    raw.values.set(SensorId::EsdInput, 0.0);
    let mut u0 = f64::NAN;
    for _ in 0..50 {
        let out = cycle(&mut core, &raw);
        assert_eq!(out.mode, Mode::Auto);
        assert!(!out.esd_active);
        u0 = out.commands.get(ActuatorId::RecycleValve);
    }
    assert!(u0 < 0.5, "the law holds the valve at {u0}");
    // set: fully open in the same cycle (no rate limit), held while set
    raw.values.set(SensorId::EsdInput, 1.0);
    for k in 0..20 {
        let out = cycle(&mut core, &raw);
        assert!(out.esd_active, "cycle {k}");
        assert_eq!(out.commands.get(ActuatorId::RecycleValve), 1.0, "cycle {k}");
        assert_eq!(out.mode, Mode::Auto, "protection, not a fault");
    }
    // a stale contact is not believed (same freshness rule as every input)
    raw.age_s[SensorId::EsdInput.index()] = 0.2;
    let out = cycle(&mut core, &raw);
    assert!(!out.esd_active);
    assert_eq!(
        out.validity.fault[SensorId::EsdInput.index()],
        InputFault::Stale
    );
    raw.age_s[SensorId::EsdInput.index()] = 0.0;
    // cleared: the law starts from the open valve and closes at its own rate
    raw.values.set(SensorId::EsdInput, 0.0);
    let out = cycle(&mut core, &raw);
    assert!(!out.esd_active);
    let u = out.commands.get(ActuatorId::RecycleValve);
    assert!(
        u > 0.9 && u <= 1.0,
        "bumpless from open, got {u} (law held {u0})"
    );
}

#[test]
fn the_esd_input_acts_in_init_and_manual_and_an_unbound_one_is_ignored() {
    let desc = kvangardsnes();
    let mut core = with_esd(core_for(&desc, 1.0));
    let op = op(&core);
    let mut raw = RawSensors::missing();
    raw.values.set(SensorId::EsdInput, 1.0);
    raw.age_s[SensorId::EsdInput.index()] = 0.0;
    let out = core.cycle(0.0, &raw, &op);
    assert_eq!(out.mode, Mode::Init);
    assert!(out.esd_active);
    assert_eq!(out.commands.get(ActuatorId::RecycleValve), 1.0);
    assert!(out.commands.get(ActuatorId::DriveTorque).is_nan());

    // manual: the station output is open when the contact clears
    let (core, mut raw, op) = started(0.0);
    let mut core = with_esd(core);
    core.request_auto(false);
    raw.values.set(SensorId::EsdInput, 0.0);
    let mut t = 0.0;
    for _ in 0..10 {
        t += 1e-3;
        assert_eq!(core.cycle(t, &raw, &op).mode, Mode::Manual);
    }
    raw.values.set(SensorId::EsdInput, 1.0);
    t += 1e-3;
    assert_eq!(
        core.cycle(t, &raw, &op)
            .commands
            .get(ActuatorId::RecycleValve),
        1.0
    );
    raw.values.set(SensorId::EsdInput, 0.0);
    t += 1e-3;
    let out = core.cycle(t, &raw, &op);
    assert!(!out.esd_active);
    assert_eq!(out.commands.get(ActuatorId::RecycleValve), 1.0);

    // not bound (no limits): a 1 on the input changes nothing
    let (mut core, mut raw, op) = started(0.0);
    raw.values.set(SensorId::EsdInput, 1.0);
    let out = core.cycle(1e-3, &raw, &op);
    assert!(!out.esd_active);
    assert!(out.commands.get(ActuatorId::RecycleValve) < 0.5);
}

#[test]
fn no_inputs_at_start_commands_nothing_then_fail_safe_after_the_grace() {
    let desc = kvangardsnes();
    let mut core = core_for(&desc, 0.5);
    let op = op(&core);
    for k in 0..500 {
        let out = core.cycle(k as f64 * 1e-3, &RawSensors::missing(), &op);
        assert_eq!(out.mode, Mode::Init, "cycle {k}");
        for id in ActuatorId::ALL {
            assert!(out.commands.get(id).is_nan(), "{id:?} commanded in init");
        }
    }
    let out = core.cycle(0.5, &RawSensors::missing(), &op);
    assert_eq!(out.mode, Mode::FailSafe);
    assert_eq!(out.commands.get(ActuatorId::RecycleValve), 1.0);
}

#[test]
fn a_start_waits_for_the_valve_position_that_comes_in_a_later_frame() {
    // pressures and flow in one frame, the valve position in another arriving 10 ms
    // later: the law starts from the measured position, not from a closed valve
    let (mut core, raw, op) = started(1.0);
    let measured = raw.values.get(SensorId::RecycleValvePosition);
    assert!(measured > 0.01, "{measured}");
    let mut partial = raw;
    partial.values.set(SensorId::RecycleValvePosition, f64::NAN);
    partial.age_s[SensorId::RecycleValvePosition.index()] = f64::INFINITY;
    for k in 0..10 {
        let out = core.cycle(k as f64 * 1e-3, &partial, &op);
        assert_eq!(out.mode, Mode::Init, "cycle {k}");
        assert!(out.commands.get(ActuatorId::RecycleValve).is_nan());
    }
    let out = core.cycle(0.010, &raw, &op);
    assert_eq!(out.mode, Mode::Auto);
    let u = out.commands.get(ActuatorId::RecycleValve);
    assert!(
        (u - measured).abs() < 0.005,
        "first command {u}, valve at {measured}"
    );

    // a position that never comes does not keep the controller from starting: after
    // the grace it runs (from the last applied output) like any start without feedback
    let (mut core, _, _) = started(0.05);
    let mut k = 0;
    let mode = loop {
        let out = core.cycle(k as f64 * 1e-3, &partial, &op);
        if out.mode != Mode::Init || k > 100 {
            break out.mode;
        }
        k += 1;
    };
    assert_eq!(mode, Mode::Auto, "started after {k} ms");
    assert!((50..=52).contains(&k), "started after {k} ms, grace 50 ms");
}

#[test]
fn first_healthy_cycle_takes_over_from_the_measured_valve_position() {
    // a controller (re)start on a running machine, inputs arriving after 30 ms: the law
    // starts from where the valve is, not from the fail-safe opening
    let (mut core, raw, op) = started(1.0);
    let measured = raw.values.get(SensorId::RecycleValvePosition);
    assert!(measured.is_finite() && measured < 0.5, "{measured}");
    for k in 0..30 {
        let out = core.cycle(k as f64 * 1e-3, &RawSensors::missing(), &op);
        assert_eq!(out.mode, Mode::Init);
    }
    let out = core.cycle(0.030, &raw, &op);
    assert_eq!(out.mode, Mode::Auto);
    let u = out.commands.get(ActuatorId::RecycleValve);
    assert!(
        (u - measured).abs() < 0.005,
        "first command {u}, valve at {measured}"
    );

    // with no grace, the same start goes fail-safe first (commanding 100 %), and the law
    // still resumes from the measured position, not from the fail-safe command
    let (mut eager, _, _) = started(0.0);
    let fs = eager.cycle(0.0, &RawSensors::missing(), &op);
    assert_eq!(fs.mode, Mode::FailSafe);
    assert_eq!(fs.commands.get(ActuatorId::RecycleValve), 1.0);
    let u = eager
        .cycle(0.001, &raw, &op)
        .commands
        .get(ActuatorId::RecycleValve);
    assert!(
        (u - measured).abs() < 0.005,
        "resumed at {u}, valve at {measured}"
    );
}

/// A core with the default supervision following a 50 Hz poll, and a function giving the
/// raw sample at `t` with its poll age (arrivals every 20 ms), late by `late_s`.
fn polled() -> (ControlCore, RawSensors, OperatorInputs) {
    let (mut core, raw, op) = started(1.0);
    let model = core.model().clone();
    let mut settings = CoreSettings::defaults_for(&model);
    settings.follow_poll_period(0.02);
    core.set_settings(settings);
    (core, raw, op)
}

/// `raw` read at `t_s`, `age_s` after it was sampled: its sample number counts the
/// microseconds of its sampling time (one number per sample, as the sensor board's).
fn aged(raw: &RawSensors, t_s: f64, age_s: f64) -> RawSensors {
    let mut r = *raw;
    r.age_s = [age_s; SensorId::COUNT];
    r.sample_seq = [((t_s - age_s) * 1e6).round() as u64 + 1; SensorId::COUNT];
    r
}

#[test]
fn freshness_follows_the_poll_period() {
    let (core, _, _) = polled();
    let lim = core.settings().supervisor.limits[SensorId::PSuction.index()].unwrap();
    assert!((lim.timeout_s - 0.06).abs() < 1e-12, "{}", lim.timeout_s);
}

#[test]
fn blips_of_100_ms_every_second_do_not_enter_fail_safe() {
    // 50 Hz poll; from t = 1 s, for 10 s, every second the answers stop for 100 ms
    let (mut core, raw, op) = polled();
    let dt = 1e-3;
    let mut last_arrival = 0.0;
    let mut stale_cycles = 0;
    for k in 0..12_000 {
        let t = k as f64 * dt;
        let in_blip = (1.0..11.0).contains(&t) && (t - t.floor()) < 0.1;
        let due = (t / 0.02).floor() * 0.02;
        if !in_blip && due > last_arrival {
            last_arrival = due;
        }
        let out = core.cycle(t, &aged(&raw, t, t - last_arrival), &op);
        assert_ne!(out.mode, Mode::FailSafe, "fail-safe at {t:.3} s");
        if !out.validity.ok(SensorId::PSuction) {
            stale_cycles += 1;
        }
    }
    // the blips were seen (inputs stale), and held through
    assert!(stale_cycles > 300, "{stale_cycles}");
}

#[test]
fn a_loss_longer_than_the_hold_enters_fail_safe_in_time_and_leaves_with_hysteresis() {
    let (mut core, raw, op) = polled();
    let s = *core.settings();
    let timeout = s.supervisor.limits[SensorId::PSuction.index()]
        .unwrap()
        .timeout_s;
    let dt = 1e-3;
    for k in 0..1000 {
        let t = k as f64 * dt;
        assert_eq!(core.cycle(t, &aged(&raw, t, 0.0), &op).mode, Mode::Auto);
    }
    // answers stop at t = 1 s
    let mut entered = None;
    for k in 1000..2000 {
        let t = k as f64 * dt;
        let out = core.cycle(t, &aged(&raw, t, t - 0.999), &op);
        if out.mode == Mode::FailSafe && entered.is_none() {
            entered = Some(t);
        }
    }
    let entered = entered.expect("never entered fail-safe");
    let due = 0.999 + timeout + s.failure_hold_s;
    assert!(
        entered <= due + 2.0 * dt && entered >= due - 2.0 * dt,
        "fail-safe at {entered}, due at {due}"
    );
    // back: healthy for less than the exit time keeps fail-safe, then auto
    let mut resumed = None;
    for k in 2000..3000 {
        let t = k as f64 * dt;
        let out = core.cycle(t, &aged(&raw, t, 0.0), &op);
        if out.mode == Mode::Auto && resumed.is_none() {
            resumed = Some(t);
        }
    }
    let resumed = resumed.expect("never resumed");
    assert!(
        (resumed - (2.0 + s.failsafe_exit_s)).abs() < 2.0 * dt,
        "resumed at {resumed}"
    );
}

/// [`started`], one cycle run in auto: with the torque it commands, N·m.
fn started_holding_torque() -> (ControlCore, RawSensors, OperatorInputs, f64) {
    let (mut core, raw, op) = started(1.0);
    let held = core
        .cycle(0.0, &raw, &op)
        .commands
        .get(ActuatorId::DriveTorque);
    assert!(held.is_finite());
    (core, raw, op, held)
}

#[test]
fn resume_after_fail_safe_takes_over_from_the_reported_drive_torque() {
    // the drive ran on its own governor during the fail-safe and now delivers 300 N·m
    // more than the controller held: the speed loop restarts from what the drive reports
    let (mut core, raw, op, held) = started_holding_torque();
    for k in 1..=100 {
        let out = core.cycle(k as f64 * 1e-3, &RawSensors::missing(), &op);
        assert_eq!(out.mode, Mode::FailSafe);
        assert_eq!(out.commands.get(ActuatorId::DriveTorque), held);
    }
    let mut back = raw;
    back.values.set(SensorId::DriveTorque, held + 300.0);
    let out = core.cycle(0.101, &back, &op);
    assert_eq!(out.mode, Mode::Auto);
    let t = out.commands.get(ActuatorId::DriveTorque);
    assert!(
        (t - (held + 300.0)).abs() < 5.0,
        "resumed at {t}, drive at {}",
        held + 300.0
    );

    // without the drive's report, it resumes from the held torque
    let (mut core, _, _) = started(1.0);
    core.cycle(0.0, &raw, &op);
    core.cycle(0.001, &RawSensors::missing(), &op);
    let mut blind = raw;
    blind.values.set(SensorId::DriveTorque, f64::NAN);
    let t = core
        .cycle(0.002, &blind, &op)
        .commands
        .get(ActuatorId::DriveTorque);
    assert!((t - held).abs() < 5.0, "resumed at {t}, held {held}");
}

#[test]
fn with_the_link_down_fail_safe_leaves_the_torque_to_the_drive_and_resumes_from_its_report() {
    // a link down: every reading stale (the last values kept, aged past their timeouts)
    let (mut core, raw, op, held) = started_holding_torque();
    for k in 1..=200 {
        let out = core.cycle(
            k as f64 * 1e-3,
            &aged(&raw, k as f64 * 1e-3, k as f64 * 1e-3),
            &op,
        );
        if out.mode == Mode::FailSafe {
            // not commanded: the drive keeps its own governor, and no stale command
            // reaches it in the first frames after the link is back
            assert!(
                out.commands.get(ActuatorId::DriveTorque).is_nan(),
                "torque {} commanded in fail-safe with the drive's report stale",
                out.commands.get(ActuatorId::DriveTorque)
            );
        }
    }
    // the link is back, the drive delivering 400 N·m more on its governor: fail-safe
    // holds that, and the resume takes over from it
    let mut back = raw;
    back.values.set(SensorId::DriveTorque, held + 400.0);
    let mut first = None;
    for k in 201..=1500 {
        let out = core.cycle(k as f64 * 1e-3, &back, &op);
        let t = out.commands.get(ActuatorId::DriveTorque);
        first.get_or_insert(t);
        assert!(
            (t - (held + 400.0)).abs() < 5.0,
            "torque {t} at {} s ({:?}), the drive at {}",
            k as f64 * 1e-3,
            out.mode,
            held + 400.0
        );
    }
    assert!(first.is_some());
    // a drive that does not report torque (its reading not available): fail-safe holds
    // the last command, as before
    let (mut core, raw, op) = started(1.0);
    core.cycle(0.0, &raw, &op);
    let out = core.cycle(0.001, &RawSensors::missing(), &op);
    assert_eq!(out.mode, Mode::FailSafe);
    assert_eq!(out.commands.get(ActuatorId::DriveTorque), held);
}

#[test]
fn a_repeated_sample_holds_the_outputs_and_is_processed_once() {
    // the controller's clock runs ahead of the sender's: the second cycle sees the same
    // sample (arrival time unchanged, age one period older) and must hold, not re-run the
    // observer and the law on it
    let (mut core, raw, op) = started(1.0);
    let first = core.cycle(0.0, &raw, &op);
    assert_eq!(first.mode, Mode::Auto);
    let mut again = raw;
    again.age_s = [0.001; SensorId::COUNT];
    let held = core.cycle(0.001, &again, &op);
    // (NaN fields: compare the printed values)
    assert_eq!(
        format!("{:?}", held.commands),
        format!("{:?}", first.commands)
    );
    assert_eq!(
        format!("{:?}", held.measurements),
        format!("{:?}", first.measurements)
    );
    assert!(held.law_diagnostic.is_nan(), "the law did not run");
    // a new sample runs the law, with dt over both periods
    let mut next = raw;
    next.sample_seq = raw.sample_seq.map(|n| n + 1);
    next.values.set(
        SensorId::PDischarge,
        raw.values.get(SensorId::PDischarge) + 50.0,
    );
    let out = core.cycle(0.002, &next, &op);
    assert!(out.law_diagnostic.is_finite());
    assert!((out.measurements.t_s - 0.002).abs() < 1e-12);
    // the number decides, not the age: a new sample whose age puts it at the last one's
    // time (two frames handed over in one batch) runs the law; the last one again holds
    let mut batched = next;
    batched.sample_seq = next.sample_seq.map(|n| n + 1);
    batched.age_s = [0.001; SensorId::COUNT];
    assert!(core.cycle(0.003, &batched, &op).law_diagnostic.is_finite());
    let mut late = batched;
    late.age_s = [0.002; SensorId::COUNT];
    assert!(core.cycle(0.004, &late, &op).law_diagnostic.is_nan());
    // a sample that stops coming still goes stale and fails safe
    let mut stale = batched;
    stale.age_s = [0.2; SensorId::COUNT];
    assert_eq!(core.cycle(0.2, &stale, &op).mode, Mode::FailSafe);
}

/// Redundant Δp transmitters: a vote of three feeds the core like one transmitter; two
/// of them failing leave a hold-last vote (no fail-safe), and the degraded policy widens
/// the control line at 1 %/s up to 5 %, acting on the law's flow only; back to three,
/// the shift goes out at the same rate. A slow link asks for the same 5 %.
#[test]
fn a_vote_feeds_the_core_and_a_degraded_vote_widens_the_control_line_at_its_rate() {
    use crate::control::vote::{VoteLimits, VoteRule};
    let (mut core, raw, op) = started(1.0);
    let mut s = *core.settings();
    s.vote.per_sensor[SensorId::OrificeDp.index()] = Some(VoteLimits::defaults(3));
    core.set_settings(s);
    let dp = raw.values.get(SensorId::OrificeDp);
    let pd = raw.values.get(SensorId::PDischarge);
    let sample = |k: usize, b: f64, c: f64| {
        let mut r = raw;
        r.values.set(SensorId::PDischarge, pd + (k % 2) as f64);
        r.sample_seq = raw.sample_seq.map(|n| n + k as u64);
        r.spare.set(SensorId::OrificeDp, 1, b, 0.0);
        r.spare.set(SensorId::OrificeDp, 2, c, 0.0);
        r
    };
    let first = core.cycle(0.0, &sample(0, dp * 1.2, dp * 1.001), &op);
    assert_eq!(first.mode, Mode::Auto);
    let v = *core.vote().of(SensorId::OrificeDp).expect("voted");
    assert_eq!(
        (v.rule, v.valid, v.value),
        (VoteRule::Median, 3, dp * 1.001)
    );
    assert_eq!(core.margin_shift().now, 0.0);
    let dt = 1e-3;
    let mut t = 0.0;
    for k in 1..=7000 {
        t = k as f64 * dt;
        let out = core.cycle(t, &sample(k, f64::NAN, f64::NAN), &op);
        assert_eq!(out.mode, Mode::Auto, "{t}");
        assert!(out.measurements.m_kg_s.is_finite());
        if k == 1000 {
            let sh = core.margin_shift().now;
            assert!((sh - 0.01).abs() < 2e-3, "{sh} after 1 s");
        }
    }
    let v = *core.vote().of(SensorId::OrificeDp).expect("voted");
    assert_eq!((v.rule, v.valid, v.degraded), (VoteRule::HoldLast, 1, true));
    let sh = core.margin_shift();
    assert!((sh.now - 0.05).abs() < 1e-9 && sh.vote == 0.05, "{sh:?}");
    // the law's flow, not the measured one
    let m = core.last_meas;
    let law = core.law_measurements(&m);
    assert!((law.flow_map * 1.05 - m.flow_map).abs() < 1e-9 * m.flow_map.abs());
    // three again (live transmitters: their readings move): the shift goes out at 1 %/s
    for k in 1..=2000 {
        let wobble = 1.0 + 1e-4 * (k % 7) as f64;
        core.cycle(t + k as f64 * dt, &sample(k, dp * wobble, dp / wobble), &op);
    }
    let sh = core.margin_shift();
    assert!(
        sh.target == 0.0 && (sh.now - 0.03).abs() < 2e-3,
        "{sh:?} {:?}",
        core.vote().of(SensorId::OrificeDp)
    );
    // a slow link asks for the slow-link margin
    core.set_link_slow(true);
    core.cycle(t + 2.001, &sample(1, dp, dp), &op);
    assert_eq!(core.margin_shift().target, SLOW_LINK_MARGIN);
}
