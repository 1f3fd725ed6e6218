//! `recycle-pi` acceptance: closed loop through `sim::run` (the code path of `antisurge sim`) on
//! the seed 002 (kvangardsnes2009, primary) and seed 001 (hemchi2016) recycle plants, plus the
//! steady-state gain comparison of seed 002 Fig. 4.7 / 4.11 on the plant's equilibria.

use crate::common;

use common::counting_alloc::allocations;

use antisurge::control::law::api::{LawEvent, LawInputs, SurgeLaw};
use antisurge::control::law::Law;
use antisurge::control::laws::recycle_pi::{ControlVariable, RecyclePi, RecyclePiConfig};
use antisurge::control::measurements::{Measurements, OperatorInputs};
use antisurge::control::model::ControlModel;
use antisurge::control::surge_control_line::{ControlLineForm, SurgeControlLine};
use antisurge::control::LawId;
use antisurge::plant::recycle_system::{ix, RecyclePlant};
use antisurge::plant::PlantInputs;
use antisurge::scenario::Scenario;
use antisurge::sim::case::PlantCase;
use antisurge::sim::trace::TraceRow;
use antisurge::sim::SimResult;
use antisurge::vocab::signals::ActuatorId;

const KV: &str = "kvangardsnes2009_recycle";
const HE: &str = "hemchi2016_recycle";

/// A plant with its `[controller.recycle_pi]` table changed.
fn plant_with(stem: &str, f: impl Fn(&mut RecyclePiConfig)) -> PlantCase {
    let mut p = common::plant(stem);
    f(&mut p.controller.recycle_pi);
    p
}

/// The law as configured for a plant (for its control line and gains).
fn law_of(p: &PlantCase) -> RecyclePi {
    let model = antisurge::sim::control_model(p);
    RecyclePi::new(&model.controller.recycle_pi, &model).expect("law")
}

/// Relative distance of the true operating point from the control line, q/c(R) − 1 (the law's
/// line, including any safety-on shift `shift`).
fn line_error(law: &RecyclePi, shift: f64, row: &TraceRow) -> f64 {
    let mut scl = *law.control_line();
    scl.shift = shift;
    row.flow_map / scl.flow_at_ratio(row.pressure_ratio) - 1.0
}

/// Time after `t0` from which |q/c − 1| stays below `tol` (None if it never does).
fn line_settle_time(r: &SimResult, law: &RecyclePi, shift: f64, t0: f64, tol: f64) -> Option<f64> {
    let last = r.trace.last()?.t_s;
    let mut t_out = t0;
    for row in r.trace.iter().filter(|row| row.t_s >= t0) {
        if line_error(law, shift, row).abs() > tol {
            t_out = row.t_s;
        }
    }
    (t_out < last - 1.0).then_some(t_out - t0)
}

/// Every actuator within its rating, through the whole run.
fn assert_within_ratings(stem: &str, p: &PlantCase, r: &SimResult) {
    let peaks = &r.summary.actuator_peaks;
    assert!(
        peaks.drive_torque_cmd_nm <= p.file.drive.rated_torque_nm + 1e-9,
        "{stem}: torque command {} N·m above the rating {}",
        peaks.drive_torque_cmd_nm,
        p.file.drive.rated_torque_nm
    );
    for row in &r.trace {
        if row.cmd_recycle_valve.is_finite() {
            assert!(
                (0.0..=1.0).contains(&row.cmd_recycle_valve),
                "{stem}: valve command {} at {} s",
                row.cmd_recycle_valve,
                row.t_s
            );
        }
    }
}

/// No surge at all: no counted cycle, no reversal, true flow positive throughout.
fn assert_no_surge(what: &str, r: &SimResult) {
    let s = &r.summary;
    assert_eq!(s.surge_cycles, 0, "{what}: surge cycles: {s:#?}");
    assert!(!s.flow_reversal, "{what}: flow reversal: {s:#?}");
    assert!(
        s.min_flow_kg_s > 0.0,
        "{what}: min flow {}",
        s.min_flow_kg_s
    );
    assert!(s.min_surge_margin > 0.0, "{what}: crossed the surge line");
}

/// The acceptance check of one closed-loop run that must settle on the control line.
fn assert_settles_on_line(what: &str, p: &PlantCase, r: &SimResult, bound_s: f64) {
    let law = law_of(p);
    let s = &r.summary;
    assert_no_surge(what, r);
    assert!(s.stable, "{what}: not stable at the end: {s:#?}");
    // on the line: |q/c(R) − 1| < 0.5 % within the bound after the disturbance (t = 5 s)
    let t_line = line_settle_time(r, &law, 0.0, 5.0, 0.005)
        .unwrap_or_else(|| panic!("{what}: never settles on the control line"));
    println!(
        "{what}: on the line after {t_line:.2} s, flow settled after {:?} s, min margin {:.3}",
        s.settle_time_s, s.min_surge_margin
    );
    assert!(
        t_line <= bound_s,
        "{what}: on the line only after {t_line:.2} s"
    );
    // the law's own control variable (trace diagnostic) goes to zero
    let tail: Vec<f64> = r
        .trace
        .iter()
        .filter(|row| row.t_s >= s.duration_s - 2.0)
        .map(|row| row.law_diagnostic)
        .collect();
    let zmax = tail.iter().fold(0.0f64, |a, z| a.max(z.abs()));
    let scale = match p.controller.recycle_pi.pi.control_variable {
        ControlVariable::Strategy2 => 1.0,
        // z₁ = c² z₂: compare in strategy-2 units
        ControlVariable::Strategy1 => law.design_flow().powi(2),
        // z = −d ≈ z₂/2
        ControlVariable::Deviation => 0.5,
    };
    assert!(zmax / scale < 1e-3, "{what}: |z| = {zmax} in the last 2 s");
    // the flow settles (summary: within ±2 % of its final value)
    let settle = s
        .settle_time_s
        .unwrap_or_else(|| panic!("{what}: flow never settles"));
    assert!(
        settle <= bound_s,
        "{what}: flow settles after {settle:.2} s"
    );
    assert_within_ratings(what, p, r);
}

fn with_strategy(stem: &str, cv: ControlVariable) -> PlantCase {
    plant_with(stem, |c| c.pi.control_variable = cv)
}

const STRATEGIES: [ControlVariable; 2] = [ControlVariable::Strategy1, ControlVariable::Strategy2];

#[test]
fn open_loop_surges_on_the_acceptance_scenarios() {
    for (stem, sc) in [
        (KV, "throttle_closure"),
        (KV, "feed_drop"),
        (KV, "throttle_step"),
        (HE, "throttle_closure"),
        (HE, "recycle_pi_feed_drop_deep"),
        (HE, "throttle_step"),
    ] {
        let r = common::simulate(&common::plant(stem), &common::scenario(sc), LawId::None);
        let s = &r.summary;
        assert!(
            s.flow_reversal && s.surge_cycles >= 5,
            "{stem}/{sc}: open loop should surge: {s:#?}"
        );
    }
    // the shared feed_drop (feed valve to 60 %) does not surge the seed 001 plant: it stays
    // ≈ 20 % right of its surge line, hence recycle_pi_feed_drop_deep (40 %)
    let r = common::simulate(
        &common::plant(HE),
        &common::scenario("feed_drop"),
        LawId::None,
    );
    assert!(r.summary.stable && r.summary.surge_cycles == 0);
    assert!(r.summary.min_surge_margin > 0.15, "{:?}", r.summary);
}

#[test]
fn throttle_closure_settles_on_the_control_line_with_either_strategy() {
    for (stem, bound) in [(KV, 10.0), (HE, 9.0)] {
        for cv in STRATEGIES {
            let p = with_strategy(stem, cv);
            let r = common::simulate(&p, &common::scenario("throttle_closure"), LawId::RecyclePi);
            assert_settles_on_line(&format!("{stem}/throttle_closure/{cv:?}"), &p, &r, bound);
        }
    }
}

#[test]
fn feed_drop_settles_on_the_control_line_with_either_strategy() {
    for (stem, sc, bound) in [
        (KV, "feed_drop", 2.0),
        (HE, "recycle_pi_feed_drop_deep", 8.0),
    ] {
        for cv in STRATEGIES {
            let p = with_strategy(stem, cv);
            let r = common::simulate(&p, &common::scenario(sc), LawId::RecyclePi);
            assert_settles_on_line(&format!("{stem}/{sc}/{cv:?}"), &p, &r, bound);
        }
    }
}

#[test]
fn final_operating_point_is_the_control_line_margin() {
    // kvangardsnes: SCL c0 = 0.6 on a surge line 0.5 √(R−1): 20 % margin; hemchi: 10 %
    for (stem, sc, margin) in [
        (KV, "throttle_closure", 0.20),
        (HE, "throttle_closure", 0.10),
    ] {
        let r = common::simulate(
            &common::plant(stem),
            &common::scenario(sc),
            LawId::RecyclePi,
        );
        let m = r.summary.final_surge_margin;
        assert!((m - margin).abs() < 0.003, "{stem}: final margin {m}");
    }
}

/// Throttle step with a 1 ms trace (to see every command).
fn fine_step() -> Scenario {
    common::scenario_text(
        "name='step-fine'\ndescription='throttle_step at 1 ms trace'\nduration_s=20\ntrace_period_s=0.001\n\
         [initial]\nthrottle=0.6\n[[event]]\nat_s=5\nstep={signal='throttle', to=0.2}\n",
    )
}

#[test]
fn valve_never_closes_faster_than_its_closing_rate() {
    for stem in [KV, HE] {
        let p = common::plant(stem);
        let rate = p.controller.recycle_pi.closing.rate_per_s;
        let r = common::simulate(&p, &fine_step(), LawId::RecyclePi);
        let cmd: Vec<(f64, f64, f64)> = r
            .trace
            .iter()
            .filter(|row| row.cmd_recycle_valve.is_finite())
            .map(|row| (row.t_s, row.cmd_recycle_valve, row.recycle_valve_position))
            .collect();
        let mut fastest = 0.0f64;
        let mut to_stem = 0;
        for w in cmd.windows(2) {
            let closing = (w[0].1 - w[1].1) / (w[1].0 - w[0].0);
            // the one exception: a trip released early takes the command down to where the
            // stem has got to (still opening towards the step), never below it
            if closing > rate * (1.0 + 1e-9) + 1e-12 {
                assert!(
                    (w[1].1 - w[0].2).abs() < 0.01 && w[1].1 < w[0].1,
                    "{stem}: closes at {closing}/s at {} s (limit {rate}/s) to {} with the stem at {}",
                    w[1].0,
                    w[1].1,
                    w[0].2
                );
                to_stem += 1;
                continue;
            }
            fastest = fastest.max(closing);
        }
        assert!(to_stem <= 1, "{stem}: {to_stem} steps to the stem");
        // the limit was exercised where the trip overshoots the final opening: after the
        // trip the valve closed a long way, at the limit (on hemchi2016 the trip now lands on
        // the final opening: the closed-limit anti-windup no longer pre-opens the valve on
        // the approach, so there is nothing to close)
        let peak = cmd.iter().fold(0.0f64, |a, c| a.max(c.1));
        let end = cmd.last().expect("commands").1;
        if stem == KV {
            assert!(peak - end > 0.05, "{stem}: peak {peak}, end {end}");
            assert!(fastest > 0.99 * rate, "{stem}: fastest closing {fastest}/s");
        }
        // the stem follows: never faster than the command (positioner lag only slows it)
        let stem_rate = r.summary.actuator_peaks.recycle_valve_closing_rate_per_s;
        assert!(
            stem_rate <= rate * 1.01,
            "{stem}: stem closed at {stem_rate}/s"
        );
    }
}

#[test]
fn throttle_step_is_caught_by_the_recycle_trip() {
    // (30 s rather than the scenario's 20: where the throttle watch sees the slam and the
    // trip opens fully, the closing limiter brings the valve back at its designed 0.1/s and
    // waits while the point still drifts towards the line: on kvangardsnes2009's large
    // volumes the point is on the line after 15 s and the flow settled after 18.3 s (bound 20 s,
    // 12 s before the throttle watch): 0.74 of travel at 0.1/s, and
    // the waits)
    let text = std::fs::read_to_string(common::root().join("config/scenarios/throttle_step.toml"))
        .expect("scenario")
        .replace("duration_s = 20.0", "duration_s = 30.0");
    let long_step = common::scenario_text(&text);
    for (stem, bound) in [(KV, 20.0), (HE, 10.0)] {
        let p = common::plant(stem);
        let r = common::simulate(&p, &long_step, LawId::RecyclePi);
        let ev = r.summary.law_events;
        // both steps are seen by the throttle watch and trip once on its prediction (a slam
        // is a slam before the flow shows how deep it goes: on hemchi2016 the PI alone would
        // have kept the point 8.8 % right of the surge line, outside its 5 % trip line, and the
        // trip there is the head start's price); no more than the watch's one step and the
        // margin's repeats
        assert!(ev.recycle_trips >= 1, "{stem}: no trip: {ev:?}");
        assert!(ev.recycle_trips <= 3, "{stem}: repeated trips: {ev:?}");
        assert_settles_on_line(&format!("{stem}/throttle_step"), &p, &r, bound);
        // the trace's largest command jump between two consecutive 5 ms rows within 3 s of
        // the throttle step
        let step = p.controller.recycle_pi.trip.step;
        let rows: Vec<&TraceRow> = r
            .trace
            .iter()
            .filter(|row| row.t_s >= 5.0 && row.t_s <= 8.0)
            .collect();
        let jump = rows
            .windows(2)
            .map(|w| w[1].cmd_recycle_valve - w[0].cmd_recycle_valve)
            .fold(0.0f64, f64::max);
        let no_trip = plant_with(stem, |c| c.trip.step = 0.0);
        let r = common::simulate(
            &no_trip,
            &common::scenario("throttle_step"),
            LawId::RecyclePi,
        );
        let pi_jump = r
            .trace
            .windows(2)
            .map(|w| w[1].cmd_recycle_valve - w[0].cmd_recycle_valve)
            .fold(0.0f64, f64::max);
        assert!(pi_jump < 0.5 * step, "{stem}: the PI alone jumps {pi_jump}");
        // (the trip's own jump is no longer a full `trip_step` here: a rate trip still right
        // of the trip line steps in proportion to the predicted penetration, which on these
        // tuned plants is small; the slow-PI case below shows the trip saving the machine)
        let _ = jump;
    }
    // the trip is what saves a slowly tuned PI: without it the step surges the machine
    let slow = |trip: bool| {
        plant_with(KV, move |c| {
            c.pi.kp_per_map_flow = 0.2;
            c.pi.ki_per_map_flow_s = 0.5;
            if !trip {
                c.trip.step = 0.0;
            }
        })
    };
    let sc = common::scenario("throttle_step");
    let without = common::simulate(&slow(false), &sc, LawId::RecyclePi);
    assert!(
        without.summary.flow_reversal && without.summary.surge_cycles >= 1,
        "slow PI without trip should surge: {:?}",
        without.summary
    );
    let with = common::simulate(&slow(true), &sc, LawId::RecyclePi);
    assert!(with.summary.law_events.recycle_trips >= 1);
    assert_no_surge("slow PI with trip", &with);
    // (the early rate trip is proportional, the level trip escalates it at the trip line:
    // the closest approach is 4 % where a full early step kept 5 %)
    assert!(
        with.summary.min_surge_margin > 0.03,
        "{}",
        with.summary.min_surge_margin
    );
}

#[test]
fn transmitter_failure_falls_back_to_the_observer_and_stays_out_of_surge() {
    for (stem, min_margin) in [(KV, 0.15), (HE, 0.05)] {
        let p = common::plant(stem);
        let r = common::simulate(
            &p,
            &common::scenario("flow_transmitter_failure"),
            LawId::RecyclePi,
        );
        // the flow the law used came from the observer after the failure
        for row in r.trace.iter().filter(|row| row.t_s >= 4.1) {
            assert!(row.meas_m_kg_s.is_nan(), "{stem}: transmitter still read");
            assert_eq!(row.used_m_kg_s, row.est_m_kg_s, "{stem} at {}", row.t_s);
            assert_eq!(row.mode, 2.0, "{stem}: not in auto at {}", row.t_s);
        }
        assert_settles_on_line(&format!("{stem}/flow_transmitter_failure"), &p, &r, 10.0);
        assert!(
            r.summary.min_surge_margin > min_margin,
            "{stem}: {}",
            r.summary.min_surge_margin
        );
    }
    // on the seed 002 plant the observer's one-step update misread the throttle transient
    // (closest approach 0.12 without the speed-line cross-check); its implicit update follows
    // it, and the observer alone keeps the margin the cross-checked run keeps
    let bare = plant_with(KV, |c| c.fallback_speed_line_check = false);
    let r = common::simulate(
        &bare,
        &common::scenario("flow_transmitter_failure"),
        LawId::RecyclePi,
    );
    assert_eq!(r.summary.surge_cycles, 0, "{:?}", r.summary);
    assert!(!r.summary.flow_reversal);
    assert!(
        r.summary.min_surge_margin > 0.15,
        "observer alone: {}",
        r.summary.min_surge_margin
    );
}

/// The equilibrium of the plant with recycle opening `u` at speed ω (rightmost steady state),
/// as (flow in map units, pressure ratio).
fn equilibrium(plant: &RecyclePlant, u: f64, throttle: f64, omega: f64) -> (f64, f64) {
    let x = plant
        .equilibria(u, throttle, 1.0, omega)
        .pop()
        .unwrap_or_else(|| panic!("no equilibrium at u = {u}, ω = {omega}"));
    (plant.map_flow(x[ix::WC], x[ix::P1]), x[ix::P2] / x[ix::P1])
}

#[test]
fn strategy_2_gain_varies_less_across_speeds_than_strategy_1() {
    // seed 002 §4.2.4 / §4.3.4: steady-state gain ∂z/∂u at equilibria on the SCL across the
    // speed range, normalised by its smallest value (Fig. 4.7: 3.6×, Fig. 4.11: 1.46×)
    let desc = common::plant(KV);
    let model = antisurge::sim::control_model(&desc);
    let scl = SurgeControlLine::new(model.surge_line, ControlLineForm::Sqrt { c0: 0.6 });
    let init = desc.file.initial;
    let plant = RecyclePlant::new(
        &desc,
        &PlantInputs {
            throttle_process: init.throttle,
            recycle_manual: init.recycle_valve,
            feed: init.feed,
            ..PlantInputs::default()
        },
    )
    .expect("plant");
    let z = |cv: ControlVariable, (q, r): (f64, f64)| cv.z(q, scl.flow_at_ratio(r));
    let (w_lo, w_hi) = model.speed_map().omega_range();
    let mut g1 = Vec::new();
    let mut g2 = Vec::new();
    for k in 0..=8 {
        let w = w_lo + (w_hi - w_lo) * k as f64 / 8.0;
        // the opening that puts the equilibrium on the SCL: z(u) = 0, z falls as u opens
        let (mut lo, mut hi) = (0.002, 1.0);
        assert!(
            z(
                ControlVariable::Strategy2,
                equilibrium(&plant, lo, init.throttle, w)
            ) > 0.0
        );
        assert!(
            z(
                ControlVariable::Strategy2,
                equilibrium(&plant, hi, init.throttle, w)
            ) < 0.0
        );
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if z(
                ControlVariable::Strategy2,
                equilibrium(&plant, mid, init.throttle, w),
            ) > 0.0
            {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let u = 0.5 * (lo + hi);
        let du = 1e-3;
        let (a, b) = (
            equilibrium(&plant, u + du, init.throttle, w),
            equilibrium(&plant, u - du, init.throttle, w),
        );
        let d1 = (z(ControlVariable::Strategy1, a) - z(ControlVariable::Strategy1, b)) / (2.0 * du);
        let d2 = (z(ControlVariable::Strategy2, a) - z(ControlVariable::Strategy2, b)) / (2.0 * du);
        // opening the valve lowers z (eq. 4.30: negative gain)
        assert!(d1 < 0.0 && d2 < 0.0, "ω = {w}: {d1} {d2}");
        // eq. 4.45: H_u,1(0)/H_u,2(0) = c(R_e)²
        let (q_e, r_e) = equilibrium(&plant, u, init.throttle, w);
        let c = scl.flow_at_ratio(r_e);
        assert!((q_e / c - 1.0).abs() < 1e-4, "not on the SCL at ω = {w}");
        assert!(
            (d1 / d2 / (c * c) - 1.0).abs() < 1e-2,
            "eq. 4.45 at ω = {w}: {} vs {}",
            d1 / d2,
            c * c
        );
        g1.push(d1.abs());
        g2.push(d2.abs());
    }
    let ratio = |g: &[f64]| {
        g.iter().cloned().fold(0.0, f64::max) / g.iter().cloned().fold(f64::INFINITY, f64::min)
    };
    let (r1, r2) = (ratio(&g1), ratio(&g2));
    println!("steady-state gain max/min over {w_lo}..{w_hi} rad/s: strategy 1 {r1:.3}, strategy 2 {r2:.3} (seed 002: 3.6, 1.46)");
    println!("strategy 1 gains: {g1:?}\nstrategy 2 gains: {g2:?}");
    assert!(
        r2 < r1,
        "strategy 2 ({r2}) should vary less than strategy 1 ({r1})"
    );
    assert!(r1 > 1.2, "strategy 1 should vary noticeably: {r1}");
}

fn measurements(flow_map: f64, ratio: f64) -> Measurements {
    Measurements {
        t_s: 0.0,
        p_suction_pa: 2.0e6,
        p_discharge_pa: 2.0e6 * ratio,
        omega_rad_s: 1000.0,
        t_suction_k: 295.16,
        m_kg_s: 11.0,
        m_measured_kg_s: 11.0,
        m_observer_kg_s: 11.0,
        flow_map,
        pressure_ratio: ratio,
        recycle_position: 0.2,
        throttle_position: 0.6,
        thrust_position_m: f64::NAN,
        dp_suction_dt_pa_s: 0.0,
        dp_discharge_dt_pa_s: 0.0,
        flow_fallback: false,
    }
}

/// Operator inputs of the law-level tests (nominal speed, recycle station at 20 %).
fn operator() -> OperatorInputs {
    OperatorInputs {
        speed_setpoint_rad_s: 1000.0,
        throttle_demand: 0.6,
        flow_setpoint_kg_s: f64::NAN,
        recycle_manual: 0.2,
    }
}

/// The law's inputs for measurements `m`, and a bumpless start from a 20 % valve.
fn start_at_20pct<'a>(
    law: &mut RecyclePi,
    m: &'a Measurements,
    op: &'a OperatorInputs,
    model: &'a ControlModel,
) -> LawInputs<'a> {
    let inputs = LawInputs {
        m,
        op,
        model,
        history: &antisurge::control::law::api::LoopHistory::EMPTY,
    };
    let mut cur = antisurge::vocab::signals::ActuatorCommands::default();
    cur.set(ActuatorId::RecycleValve, 0.2);
    law.start(&inputs, &cur);
    inputs
}

#[test]
fn safety_on_moves_the_line_one_step_per_surge_up_to_its_cap() {
    let desc = common::plant(KV);
    let model = antisurge::sim::control_model(&desc);
    let mut cfg = model.controller.recycle_pi.clone();
    cfg.safety_on.step_pct = 5.0;
    cfg.safety_on.max_pct = 12.0;
    let mut law = RecyclePi::new(&cfg, &model).expect("law");
    let op = operator();
    let r = 2.2;
    let q0 = law.control_line().flow_at_ratio(r);
    let m = measurements(q0, r);
    let inputs = start_at_20pct(&mut law, &m, &op, &model);
    let j = model.surge_line.flow_at_ratio(r);
    let expected = [0.05, 0.10, 0.12, 0.12];
    for (k, &total) in expected.iter().enumerate() {
        law.surge_detected();
        assert!((law.control_line().shift - total).abs() < 1e-12);
        assert_eq!(law.safety_on_count(), (k + 1).min(3) as u32);
        // the line at R moved right by the shift, in surge-line flow
        let q = law.control_line().flow_at_ratio(r);
        assert!((q - q0 - total * j).abs() < 1e-12, "{q} {q0} {total}");
        let out = law.update(&inputs, 1e-3);
        if k < 3 {
            assert_eq!(
                out.event,
                Some(LawEvent::SafetyOnShift {
                    total_margin: total,
                    count: (k + 1) as u32
                })
            );
        } else {
            assert_eq!(out.event, None, "capped: no further shift");
        }
        // the operating point that was on the line is now left of it: z > 0 opens the valve
        assert!(out.diagnostic > 0.0);
    }
}

#[test]
fn safety_on_shifts_after_a_surge_in_closed_loop() {
    // a slowly tuned PI without trip cannot hold the throttle step: the machine surges, the
    // detector reports it and the control line moves right; the machine then settles on the
    // shifted line
    let p = plant_with(KV, |c| {
        c.pi.kp_per_map_flow = 0.2;
        c.pi.ki_per_map_flow_s = 0.5;
        c.trip.step = 0.0;
    });
    let sc = common::scenario_text(
        "name='step-long'\ndescription='throttle_step, 40 s'\nduration_s=40\n\
         [initial]\nthrottle=0.6\n[[event]]\nat_s=5\nstep={signal='throttle', to=0.2}\n",
    );
    let r = common::simulate(&p, &sc, LawId::RecyclePi);
    let ev = r.summary.law_events;
    let step = 0.01 * p.controller.recycle_pi.safety_on.step_pct;
    assert!(r.summary.surge_cycles >= 1, "{:?}", r.summary);
    assert!(ev.safety_on_shifts >= 1, "{ev:?}");
    assert!(
        (ev.safety_on_total_margin - step * f64::from(ev.safety_on_shifts)).abs() < 1e-12,
        "{ev:?}"
    );
    // settles on the shifted line: surge margin 20 % + the shift (sqrt line: c = 1.2 j + shift j)
    let law = law_of(&p);
    let last = r.trace.last().expect("trace");
    let e = line_error(&law, ev.safety_on_total_margin, last);
    assert!(e.abs() < 0.005, "off the shifted line by {e}");
    let m = r.summary.final_surge_margin;
    assert!(
        (m - 0.2 - ev.safety_on_total_margin).abs() < 0.005,
        "final margin {m}, shift {}",
        ev.safety_on_total_margin
    );
}

/// Largest change of the valve command between consecutive 1 ms rows in [t0, t1].
fn max_command_step(r: &SimResult, t0: f64, t1: f64) -> f64 {
    let rows: Vec<&TraceRow> = r
        .trace
        .iter()
        .filter(|row| row.t_s >= t0 && row.t_s <= t1)
        .collect();
    let mut worst = 0.0f64;
    for w in rows.windows(2) {
        // before the switch the valve follows the manual station: compare with the position
        let a = if w[0].cmd_recycle_valve.is_finite() {
            w[0].cmd_recycle_valve
        } else {
            w[0].recycle_valve_position
        };
        let b = w[1].cmd_recycle_valve;
        if b.is_finite() {
            worst = worst.max((b - a).abs());
        }
    }
    worst
}

#[test]
fn switching_from_none_to_recycle_pi_is_bumpless() {
    // the initial point lies left of the kvangardsnes control line (17 % < 20 % margin): z > 0,
    // so a start without integrator initialisation would step the valve by K_p z
    let p = common::plant(KV);
    let sc = common::scenario_text(
        "name='switch'\ndescription='none, then recycle-pi at 2 s'\nduration_s=12\ntrace_period_s=0.001\n\
         [initial]\nthrottle=0.6\n[[event]]\nat_s=2\nlaw='recycle-pi'\n",
    );
    let r = common::simulate(&p, &sc, LawId::None);
    let row = r.trace.iter().find(|row| row.t_s >= 2.0).expect("t = 2 s");
    let law = law_of(&p);
    let z = law.z_at(row.flow_map, row.pressure_ratio);
    assert!(
        law.z_gains().0 * z > 0.05,
        "test is meaningless: K_p z = {}",
        law.z_gains().0 * z
    );
    let worst = max_command_step(&r, 1.9, 2.5);
    assert!(worst < 0.01, "valve step {worst} at the switch");
    // and the law then does its job: onto the line, no surge
    assert_no_surge("switch", &r);
    let last = r.trace.last().expect("trace");
    assert!(line_error(&law, 0.0, last).abs() < 0.005);
}

#[test]
fn return_from_manual_is_bumpless() {
    // auto → manual at 2 s (the station holds the output), the operator opens to 35 % at 3 s
    // (far right of the line: z < 0), back to auto at 6 s
    for stem in [KV, HE] {
        let p = common::plant(stem);
        let sc = common::scenario_text(
            "name='manual'\ndescription='manual and back'\nduration_s=20\ntrace_period_s=0.001\n\
             [initial]\nthrottle=0.6\n[[event]]\nat_s=2\nmode='manual'\n\
             [[event]]\nat_s=3\nstep={signal='recycle_manual', to=0.35}\n\
             [[event]]\nat_s=6\nmode='auto'\n",
        );
        let r = common::simulate(&p, &sc, LawId::RecyclePi);
        assert!(
            max_command_step(&r, 1.9, 2.5) < 0.01,
            "{stem}: step entering manual"
        );
        let row = r.trace.iter().find(|row| row.t_s >= 6.0).expect("t = 6 s");
        assert_eq!(row.mode, 2.0);
        let law = law_of(&p);
        let kz = law.z_gains().0 * law.z_at(row.flow_map, row.pressure_ratio);
        assert!(kz < -0.05, "{stem}: test is meaningless: K_p z = {kz}");
        let worst = max_command_step(&r, 5.9, 6.5);
        assert!(
            worst < 0.01,
            "{stem}: valve step {worst} at the return to auto"
        );
        assert_no_surge(stem, &r);
    }
}

#[test]
fn control_line_left_of_the_trip_line_is_rejected() {
    let desc = common::plant(HE);
    let model = antisurge::sim::control_model(&desc);
    let mut cfg = model.controller.recycle_pi.clone();
    cfg.control_line = ControlLineForm::Margin {
        margin_pct: 3.0,
        offset: 0.0,
    };
    cfg.trip.margin_pct = 5.0;
    let mut all = model.controller.clone();
    all.recycle_pi = cfg;
    let e = Law::new(LawId::RecyclePi, &all, &model).unwrap_err();
    assert!(e.to_string().contains("control_line"), "{e}");
}

#[test]
fn law_cycle_does_not_allocate() {
    // every branch: PI, trip (the point left of the trip line), fallback cross-check with the
    // speed line, safety-on event, both strategies
    let desc = common::plant(KV);
    let model = antisurge::sim::control_model(&desc);
    let op = OperatorInputs {
        speed_setpoint_rad_s: 1000.0,
        throttle_demand: 0.6,
        flow_setpoint_kg_s: f64::NAN,
        recycle_manual: 0.2,
    };
    for cv in STRATEGIES {
        let mut cfg = model.controller.recycle_pi.clone();
        cfg.pi.control_variable = cv;
        let mut law = RecyclePi::new(&cfg, &model).expect("law");
        let mut cur = antisurge::vocab::signals::ActuatorCommands::default();
        cur.set(ActuatorId::RecycleValve, 0.2);
        let r = 2.2;
        let j = model.surge_line.flow_at_ratio(r);
        let mut ms = [measurements(1.3 * j, r), measurements(1.02 * j, r)];
        ms[1].flow_fallback = true;
        law.start(
            &LawInputs {
                m: &ms[0],
                op: &op,
                model: &model,
                history: &antisurge::control::law::api::LoopHistory::EMPTY,
            },
            &cur,
        );
        let before = allocations();
        let mut trips = 0;
        for k in 0..4000 {
            let mut m = ms[(k / 500) % 2];
            m.t_s = k as f64 * 1e-3;
            let m = &m;
            if k % 1000 == 999 {
                law.surge_detected();
            }
            let out = std::hint::black_box(law.update(
                &LawInputs {
                    m,
                    op: &op,
                    model: &model,
                    history: &antisurge::control::law::api::LoopHistory::EMPTY,
                },
                1e-3,
            ));
            if matches!(out.event, Some(LawEvent::RecycleTrip { .. })) {
                trips += 1;
            }
        }
        assert_eq!(allocations() - before, 0, "{cv:?}: the law allocated");
        assert!(
            trips >= 1 && law.safety_on_count() >= 3,
            "branches not exercised: {trips} trips, {} shifts",
            law.safety_on_count()
        );
    }
}

/// Kvangardsnes under recycle-pi: the operator holds the recycle valve at 60 % in manual from
/// 1 s, hands back to auto at 3 s (the law then closes the valve at its closing rate, far right
/// of the control line), and the throttle closes 60 → 20 % from 5 s. `at_switch(core)` is
/// called once, at the first cycle at or after `t_switch_s` (1-ms trace rows).
fn rate_limited_closure_with_switch(
    t_switch_s: f64,
    mut at_switch: impl FnMut(&mut antisurge::control::core::ControlCore),
) -> SimResult {
    let p = common::plant(KV);
    let sc = common::scenario_text(
        "name='retune'\ndescription='valve closing at its rate limit during a throttle closure'\n\
         duration_s=10\ntrace_period_s=0.001\n[initial]\nthrottle=0.6\n\
         [[event]]\nat_s=1\nmode='manual'\n\
         [[event]]\nat_s=1.5\nstep={signal='recycle_manual', to=0.6}\n\
         [[event]]\nat_s=3\nmode='auto'\n\
         [[event]]\nat_s=5\nramp={signal='throttle', to=0.2, over_s=2}\n",
    );
    let mut done = false;
    common::simulate_with(&p, &sc, LawId::RecyclePi, &mut |t, core| {
        if !done && t >= t_switch_s - 1e-9 {
            done = true;
            at_switch(core);
        }
    })
}

/// Largest change of the valve command over `lag` rows, for rows ending in [t0, t1].
fn max_step_over(r: &SimResult, lag: usize, t0: f64, t1: f64) -> (f64, f64) {
    let rows = &r.trace;
    let mut worst = (0.0f64, f64::NAN);
    for k in lag..rows.len() {
        let (a, b) = (&rows[k - lag], &rows[k]);
        if b.t_s >= t0 && b.t_s <= t1 {
            let d = (b.cmd_recycle_valve - a.cmd_recycle_valve).abs();
            if d > worst.0 {
                worst = (d, b.t_s);
            }
        }
    }
    worst
}

#[test]
fn hot_retune_while_the_valve_closes_at_its_rate_limit_is_bumpless() {
    // the daemon's hot-reload case: K_p 10 → 16 while the trip-opened valve closes at its
    // closing rate and the PI demand lies below it
    let base = rate_limited_closure_with_switch(f64::INFINITY, |_| {});
    let rate = common::plant(KV).controller.recycle_pi.closing.rate_per_s;
    // a moment after the return to auto where the valve has closed at exactly the rate limit
    // for the last 20 ms
    let rows = &base.trace;
    let k_sw = (20..rows.len())
        .find(|&k| {
            rows[k].t_s > 3.1
                && rows[k].t_s < 7.0
                && ((rows[k - 20].cmd_recycle_valve - rows[k].cmd_recycle_valve) / 0.020 - rate)
                    .abs()
                    < 0.01 * rate
        })
        .expect("the valve closes at its rate limit during the closure");
    let t_sw = rows[k_sw].t_s;
    let retune = |core: &mut antisurge::control::core::ControlCore| {
        let mut cfg = core.config().clone();
        cfg.recycle_pi.pi.kp_per_map_flow = 16.0;
        reconfigure(core, cfg, core.law());
    };
    let r = rate_limited_closure_with_switch(t_sw, retune);
    // at the switch the valve goes on closing at its rate: no step in the switching cycle
    let (at_switch, _) = max_step_over(&r, 1, t_sw - 0.0005, t_sw + 0.0015);
    assert!(
        at_switch <= 1.01 * rate * 0.001,
        "step {at_switch} at the switch (t = {t_sw:.3} s)"
    );
    // and no 5-ms output step over 1 % afterwards (the daemon test's measure)
    let (worst, t_worst) = max_step_over(&r, 5, t_sw, t_sw + 1.0);
    assert!(worst < 0.01, "5-ms step {worst} at t = {t_worst:.3} s");
    assert_no_surge("retuned", &r);

    // what the fix is for: a fresh bumpless start of the retuned law at the same instant
    // (integrator set so that its demand equals the closing valve) re-opens the valve
    let restart = |core: &mut antisurge::control::core::ControlCore| {
        retune(core);
        let cfg = core.config().clone();
        reconfigure(core, cfg.clone(), LawId::None);
        reconfigure(core, cfg, LawId::RecyclePi);
    };
    let fresh = rate_limited_closure_with_switch(t_sw, restart);
    let (fresh_worst, _) = max_step_over(&fresh, 5, t_sw, t_sw + 1.0);
    eprintln!(
        "t_sw {t_sw:.3} s: 5-ms step after retune {worst:.4}, after a fresh start {fresh_worst:.4}"
    );
    // (a fresh start now takes over from the applied output as well: both are bumpless,
    // one closing-rate step at most)
    let rate_step = 5e-3 * common::plant(KV).controller.recycle_pi.closing.rate_per_s;
    assert!(
        worst <= rate_step + 1e-9 && fresh_worst <= rate_step + 1e-9,
        "take-over {worst}, fresh start {fresh_worst}, one rate step {rate_step}"
    );
}

#[test]
fn hot_reload_during_observer_fallback_stays_in_auto() {
    // the flow transmitter fails at 4 s; reloads at 6 s (a law gain) and at 7 s (the observer
    // gain) must not throw the observer away, or the law would lose its flow and the core go
    // fail-safe
    let p = common::plant(KV);
    let sc = common::scenario("flow_transmitter_failure");
    let c2 = p.controller.observer.c2_pa_s_kg;
    let r = common::simulate_with(&p, &sc, LawId::RecyclePi, &mut |t, core| {
        let mut cfg = core.config().clone();
        if (t - 6.0).abs() < 1e-9 {
            cfg.recycle_pi.pi.ki_per_map_flow_s *= 1.01;
            reconfigure(core, cfg, core.law());
        } else if (t - 7.0).abs() < 1e-9 {
            cfg.observer.c2_pa_s_kg = 1.5 * c2;
            reconfigure(core, cfg, core.law());
        }
    });
    for row in r.trace.iter().filter(|row| row.t_s >= 4.1) {
        assert_eq!(row.mode, 2.0, "not in auto at {}", row.t_s);
        assert!(row.est_m_kg_s.is_finite(), "no estimate at {}", row.t_s);
        assert_eq!(row.used_m_kg_s, row.est_m_kg_s, "at {}", row.t_s);
    }
    // with its own settings unchanged, the observer goes on exactly as without the reload
    let base = common::simulate(&p, &sc, LawId::RecyclePi);
    let at = |res: &SimResult, t: f64| {
        res.trace
            .iter()
            .find(|row| row.t_s >= t - 1e-9)
            .expect("row")
            .est_m_kg_s
    };
    let (with, without) = (at(&r, 6.0), at(&base, 6.0));
    assert!(
        (with - without).abs() < 1e-9 * without.abs(),
        "estimate at the reload {with} kg/s, without it {without} kg/s"
    );
    assert_no_surge("reload in fallback", &r);
}

#[test]
fn retune_keeps_safety_on_shifts_and_counters() {
    let desc = common::plant(KV);
    let model = antisurge::sim::control_model(&desc);
    let mut law = law_of(&desc);
    let op = operator();
    let r = 2.2;
    let m = measurements(law.control_line().flow_at_ratio(r), r);
    let inputs = start_at_20pct(&mut law, &m, &op, &model);
    law.surge_detected();
    law.surge_detected();
    let u_old = law
        .update(&inputs, 1e-3)
        .commands
        .get(ActuatorId::RecycleValve);
    let shift = law.control_line().shift;
    assert!(shift > 0.0);

    let mut cfg = model.controller.recycle_pi.clone();
    cfg.pi.kp_per_map_flow *= 2.0;
    let mut retuned = RecyclePi::new(&cfg, &model).expect("law");
    assert!(retuned.take_over_from(&law));
    assert_eq!(retuned.control_line().shift, shift);
    assert_eq!(retuned.safety_on_count(), 2);
    // same z: the next output continues from the last one (only the integral moves it)
    let u_new = retuned
        .update(&inputs, 1e-3)
        .commands
        .get(ActuatorId::RecycleValve);
    let u_same = law
        .update(&inputs, 1e-3)
        .commands
        .get(ActuatorId::RecycleValve);
    assert!((u_new - u_same).abs() < 1e-12, "{u_new} vs {u_same}");
    assert!((u_new - u_old).abs() < 2e-3, "{u_new} vs {u_old}");

    // a changed control line changes z: the state is not taken over (a fresh bumpless start
    // follows), but the safety-on shift is
    let mut moved = cfg.clone();
    moved.control_line = ControlLineForm::Sqrt { c0: 0.62 };
    let mut other = RecyclePi::new(&moved, &model).expect("law");
    assert!(!other.take_over_from(&law));
    assert_eq!(other.control_line().shift, shift);
}

/// Drive the law open loop with flows `q(k)` at a fixed pressure ratio, 1 kHz, the
/// measurements' clock advancing; returns the sample of the first recycle trip, if any.
fn first_trip(
    law: &mut RecyclePi,
    model: &ControlModel,
    ratio: f64,
    n: usize,
    q: impl Fn(usize) -> f64,
) -> Option<usize> {
    let op = operator();
    let m0 = measurements(q(0), ratio);
    start_at_20pct(law, &m0, &op, model);
    first_trip_step(law, model, ratio, n, 0.2, q).map(|(k, _)| k)
}

/// [`first_trip`] on a started law, the valve standing at `u0`, with the trip's step: the
/// opening it commands less the command of the cycle before, valve fraction.
fn first_trip_step(
    law: &mut RecyclePi,
    model: &ControlModel,
    ratio: f64,
    n: usize,
    u0: f64,
    q: impl Fn(usize) -> f64,
) -> Option<(usize, f64)> {
    let op = operator();
    let mut u_before = u0;
    for k in 0..n {
        let mut m = measurements(q(k), ratio);
        m.t_s = k as f64 * 1e-3;
        m.recycle_position = u0;
        let inputs = LawInputs {
            m: &m,
            op: &op,
            model,
            history: &antisurge::control::law::api::LoopHistory::EMPTY,
        };
        let out = law.update(&inputs, 1e-3);
        if let Some(LawEvent::RecycleTrip { opening, .. }) = out.event {
            return Some((k, opening - u_before));
        }
        u_before = out.commands.get(ActuatorId::RecycleValve);
    }
    None
}

#[test]
fn onset_trip_catches_a_clean_slam_within_its_window_and_noise_never_fires_it() {
    let desc = common::plant(KV);
    let model = antisurge::sim::control_model(&desc);
    let cfg = RecyclePiConfig::default();
    // samples at 1 kHz within which the slam must trip: the confirmation (10 ms) and the
    // few samples before the 20-ms slope predicts the crossing
    let confirm = (1e3 * cfg.trip.confirm_s) as usize + 15;
    let ratio = 2.2;
    let q_line = RecyclePi::new(&cfg, &model)
        .expect("law")
        .control_line()
        .flow_at_ratio(ratio);
    // a throttle slam on the control line: the flow falls by 0.1 % of the line's flow per
    // millisecond from sample 200 on (the 2 Hz approach filter alone needs ~20 samples)
    let mut law = RecyclePi::new(&cfg, &model).expect("law");
    let slam = |k: usize| q_line * (1.0 - 1e-3 * k.saturating_sub(200) as f64);
    let k = first_trip(&mut law, &model, ratio, 400, slam).expect("the slam trips");
    assert!(
        k > 200 && k <= 200 + confirm + 1,
        "tripped at sample {k}, the slam began at 200 (window {confirm})"
    );
    // white noise of ±2 % of the line's flow on the line, every sample, then held for 10
    // samples (a 100 Hz poll under a 1 kHz loop): 20 s each without a trip
    let noise = uniform_noise(0, 20_000);
    for hold in [1usize, 10] {
        let mut law = RecyclePi::new(&cfg, &model).expect("law");
        let noisy = |k: usize| q_line * (1.0 + 0.02 * noise[k / hold * hold]);
        let k = first_trip(&mut law, &model, ratio, noise.len(), noisy);
        assert_eq!(k, None, "noise (held {hold} samples) fired a trip");
    }
}

/// ±1 uniform samples (xorshift64*), `n` of them from `seed`.
fn uniform_noise(seed: u64, n: usize) -> Vec<f64> {
    let mut state = 0x9E37_79B9_7F4A_7C15u64 ^ seed.wrapping_mul(0xD1B5_4A32_D192_ED03);
    (0..n)
        .map(|_| {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            let r = state.wrapping_mul(0x2545_F491_4F6C_DD1D);
            (r >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        })
        .collect()
}

/// recycle-pi with its defaults, started on a closed valve at flow `q` (map units) and
/// pressure ratio `ratio`; with the control line's flow at that ratio.
fn started_closed(model: &ControlModel, q: impl Fn(f64) -> f64, ratio: f64) -> (RecyclePi, f64) {
    let cfg = RecyclePiConfig::default();
    let mut law = RecyclePi::new(&cfg, model).expect("law");
    let q_line = law.control_line().flow_at_ratio(ratio);
    let (m, op) = (measurements(q(q_line), ratio), operator());
    let inputs = LawInputs {
        m: &m,
        op: &op,
        model,
        history: &antisurge::control::law::api::LoopHistory::EMPTY,
    };
    let mut cur = antisurge::vocab::signals::ActuatorCommands::default();
    cur.set(ActuatorId::RecycleValve, 0.0);
    law.start(&inputs, &cur);
    (law, q_line)
}

/// A steady approach under noise trips with about the step the same approach trips with
/// clean: the step is sized on the shallowest prediction of the samples that agreed, not on
/// the last one, whose filtered rate carries the noise (hemchi2016's noisy closure stepped
/// 4.3 % of valve where the clean one stepped 0.8 %, and recycled more than baseline-pi).
#[test]
fn noise_does_not_enlarge_the_trip_step_of_a_steady_approach() {
    for plant in [KV, HE] {
        let model = antisurge::sim::control_model(&common::plant(plant));
        let ratio = 2.0;
        // 3 s 30 % right of the control line (the noise estimates settle), then towards it
        // at 45 % of its flow per second (hemchi2016's 2-s throttle closure approaches its
        // line at about that rate)
        let ramp = |q_line: f64, k: usize| q_line * (1.3 - 0.45e-3 * k.saturating_sub(3000) as f64);
        let (mut law, q_line) = started_closed(&model, |q| ramp(q, 0), ratio);
        let (_, clean) = first_trip_step(&mut law, &model, ratio, 5000, 0.0, |k| ramp(q_line, k))
            .expect("the approach trips");
        for seed in 1..=8u64 {
            let (mut law, _) = started_closed(&model, |q| ramp(q, 0), ratio);
            // ±4 % of the line's flow, uniform (σ ≈ 2.3 %)
            let noise = uniform_noise(seed, 5000);
            let noisy = |k: usize| ramp(q_line, k) + 0.04 * q_line * noise[k];
            let (k, step) = first_trip_step(&mut law, &model, ratio, 5000, 0.0, noisy)
                .expect("the noisy approach trips too");
            assert!(
                step <= clean + 0.01,
                "{plant} seed {seed}: noisy step {step:.4} at sample {k}, clean step {clean:.4}"
            );
        }
    }
}

/// Noise from the first sample of a fresh start, the point 30 % right of the control line:
/// no trip. The noise estimates start as a plain mean of their first samples; a 1-s average
/// starting from zero had reached a fifth of this noise after 200 ms, and the onset trip
/// fired a 30 % step on it then.
#[test]
fn noise_from_the_first_sample_after_a_start_fires_no_trip() {
    for plant in [KV, HE] {
        let model = antisurge::sim::control_model(&common::plant(plant));
        let ratio = 2.0;
        for seed in 1..=8u64 {
            let (mut law, q_line) = started_closed(&model, |q| 1.3 * q, ratio);
            let noise = uniform_noise(seed, 3000);
            let noisy = |k: usize| q_line * (1.3 + 0.04 * noise[k]);
            let trip = first_trip_step(&mut law, &model, ratio, noise.len(), 0.0, noisy);
            assert_eq!(
                trip, None,
                "{plant} seed {seed}: (sample, step) of a trip on noise"
            );
        }
    }
}

/// The HIL link bounce in process: every input stale for 0.6 s after the throttle closure
/// (the controller fails safe, the valve opens fully), then back. The closing that follows
/// the resume is the law's own approach: it stops at the control line and fires no trip.
/// (It used to close on past the line, to 17 % on kvangardsnes2009's 20 % line, until the
/// PI's unwound demand met the valve, and then the rate trip saw the point still approaching
/// at 0.35/s of margin and stepped the valve 15 %: the HIL suite's intermittent failure.)
#[test]
fn the_closing_after_a_link_bounce_stops_at_the_control_line_without_a_trip() {
    let mut text = String::from(
        "name='link-bounce'\ndescription='all inputs stale 0.6 s after a closure'\nduration_s=20\n\
         [initial]\nthrottle=0.6\n[[event]]\nat_s=5\nramp={signal='throttle', to=0.2, over_s=2}\n",
    );
    let inputs = [
        "p_suction",
        "p_discharge",
        "shaft_speed",
        "orifice_dp",
        "recycle_valve_position",
        "drive_torque",
        "t_suction",
        "throttle_position",
    ];
    for (at_s, fault) in [(8.9, "stale"), (9.5, "restore")] {
        for s in inputs {
            text += &format!(
                "[[event]]\nat_s={at_s}\nsensor_fault={{sensor='{s}', fault='{fault}'}}\n"
            );
        }
    }
    let sc = common::scenario_text(&text);
    for stem in [KV, HE] {
        let p = common::plant(stem);
        let law = law_of(&p);
        let r = common::simulate(&p, &sc, LawId::RecyclePi);
        let resumed = r
            .trace
            .iter()
            .position(|row| row.t_s > 9.5 && row.mode == 2.0)
            .expect("back in auto");
        let after = &r.trace[resumed..];
        // no step beyond 1 % of travel between trace rows once the resume is done (the HIL
        // suite's bump check)
        let (mut worst, mut at) = (0.0f64, 0.0);
        for w in after.windows(2).skip(1) {
            let step = (w[1].cmd_recycle_valve - w[0].cmd_recycle_valve).abs();
            if step > worst {
                (worst, at) = (step, w[1].t_s);
            }
        }
        assert!(
            worst < 0.01,
            "{stem}: valve command step {worst:.4} at {at:.3} s"
        );
        // and the point never went past (left of) the control line by more than 1 % of its
        // flow
        let left = after
            .iter()
            .map(|row| line_error(&law, 0.0, row))
            .fold(f64::INFINITY, f64::min);
        assert!(
            left > -0.01,
            "{stem}: {left:.4} of the line's flow left of it"
        );
    }
}

/// A controller written in the test: (dt, measurements) → valve command.
type TextbookPi<'a> = dyn FnMut(f64, &Measurements) -> f64 + 'a;

/// Seed 002's recycle plant (kvangardsnes2009), feed 12 → 7 kg/s over 1 s, closed through the
/// same measurement path (the control core) by `law` or, with `law = None`, by the textbook
/// PI of `textbook` below; returns the valve command trajectory (one value per 1-ms cycle)
/// and the run's summary.
fn feed_drop_12_to_7(
    p: &PlantCase,
    law: LawId,
    mut textbook: Option<&mut TextbookPi<'_>>,
) -> (Vec<f64>, antisurge::sim::Summary) {
    use antisurge::control::core::{ControlCore, CoreSettings};
    use antisurge::sim::PlantRun;
    let sc = common::scenario_text(
        "name='feed-12-to-7'\ndescription='feed 12 -> 7 kg/s'\nduration_s=12\n\
         [initial]\nfeed=1.7142857142857142\n\
         [[event]]\nat_s=2\nramp={signal='feed', to=1.0, over_s=1.0}\n",
    );
    let model = antisurge::sim::control_model(p);
    let settings = CoreSettings::defaults_for(&model);
    let mut pr = PlantRun::new(p, &sc).expect("plant");
    let t0_torque = pr.plant().truth().load_torque_nm;
    let nominal = model.drive.nominal_speed_rad_s;
    let config = model.controller.clone();
    let mut core = ControlCore::new(model, config, settings, law, t0_torque).expect("core");
    let dt = pr.dt_s();
    let n = pr.n_steps();
    let mut valve = Vec::with_capacity(n + 1);
    for k in 0..=n {
        let t = k as f64 * dt;
        let (st, raw) = pr.sense(t);
        let op = antisurge::sim::operator_inputs(&st, nominal);
        let out = core.cycle(t, &raw, &op);
        let mut cmd = out.commands;
        if let Some(f) = textbook.as_mut() {
            cmd.set(ActuatorId::RecycleValve, f(dt, &out.measurements));
        }
        valve.push(cmd.get(ActuatorId::RecycleValve));
        let view = antisurge::sim::ControllerView::of(&out);
        pr.record(k, t, dt, &raw, &cmd, &view);
        if k == n {
            break;
        }
        pr.advance(&st, &cmd, dt);
    }
    (valve, pr.finish(law.name()).summary)
}

/// With every extra off, recycle-pi *is* a textbook PI: seed 002's recycle plant with the
/// seed's strategy-1 gains (K_p = 2, K_i = 10 on z₁ = c(R)² − q|q|, configured per map flow
/// as 2·(2 q_ref) and 10·(2 q_ref)), feed 12 → 7 kg/s: it settles, and its valve trajectory
/// matches an independent textbook PI with conditional integration, written here, on the
/// same plant through the same measurements, within 1 % of travel.
#[test]
fn with_every_extra_off_recycle_pi_is_the_textbook_pi() {
    let mut p = common::plant(KV);
    let model = antisurge::sim::control_model(&p);
    let q_ref = RecyclePi::new(&model.controller.recycle_pi, &model)
        .expect("law")
        .design_flow();
    {
        let c = &mut p.controller.recycle_pi;
        c.pi.control_variable = ControlVariable::Strategy1;
        c.pi.kp_per_map_flow = 2.0 * (2.0 * q_ref);
        c.pi.ki_per_map_flow_s = 10.0 * (2.0 * q_ref);
        c.pi.z_filter_hz = 0.0;
        c.trip.enabled = false;
        c.closing.enabled = false;
        c.safety_on.step_pct = 0.0;
        c.esd.decel_pct_per_s = 0.0;
        c.min_opening = 0.0;
    }
    let law = law_of(&p);
    let scl = *law.control_line();
    let (ours, summary) = feed_drop_12_to_7(&p, LawId::RecyclePi, None);
    assert_eq!(
        summary.surge_cycles, 0,
        "recycle-pi, every extra off: {summary:#?}"
    );
    assert!(
        !summary.flow_reversal,
        "recycle-pi, every extra off: {summary:#?}"
    );
    // the independent textbook PI: u = clamp(K_p e + I), İ = K_i e unless saturated with e
    // pushing further; e = c(R)² − q|q| (seed 002 eq. 4.19)
    let (kp, ki) = (2.0, 10.0);
    let mut integ = f64::NAN;
    let mut pi = |dt: f64, m: &Measurements| -> f64 {
        let c = scl.flow_at_ratio(m.pressure_ratio);
        let e = c * c - m.flow_map * m.flow_map.abs();
        if integ.is_nan() {
            // bumpless from the valve's measured position
            integ = m.recycle_position - kp * e;
        }
        let raw = kp * e + integ;
        let u = raw.clamp(0.0, 1.0);
        if !((raw >= 1.0 && e > 0.0) || (raw <= 0.0 && e < 0.0)) {
            integ += ki * e * dt;
        }
        u
    };
    let (theirs, their_summary) = feed_drop_12_to_7(&p, LawId::None, Some(&mut pi));
    assert_eq!(their_summary.surge_cycles, 0, "the textbook PI settles too");
    let worst = ours
        .iter()
        .zip(&theirs)
        .enumerate()
        .map(|(k, (a, b))| ((a - b).abs(), k))
        .fold((0.0f64, 0), |w, x| if x.0 > w.0 { x } else { w });
    let travel = theirs.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
        - theirs.iter().cloned().fold(f64::INFINITY, f64::min);
    eprintln!(
        "textbook PI: travel {travel:.4}, largest difference {:.5} at {:.3} s",
        worst.0,
        worst.1 as f64 * 1e-3
    );
    assert!(travel > 0.05, "the disturbance moves the valve: {travel}");
    assert!(
        worst.0 <= 0.01,
        "differs by {:.4} at {:.3} s",
        worst.0,
        worst.1 as f64 * 1e-3
    );
    // and it settles: the last 2 s hold the valve within 0.5 % of travel
    let tail = &ours[ours.len() - 2000..];
    let (lo, hi) = tail
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), u| {
            (l.min(*u), h.max(*u))
        });
    assert!(hi - lo < 0.005, "still moving {lo:.4}..{hi:.4}");
}

/// Reconfigure as the daemon does: prepare off the cycle, commit at its boundary.
fn reconfigure(
    core: &mut antisurge::control::core::ControlCore,
    cfg: antisurge::control::ControllerConfig,
    law: LawId,
) {
    let r =
        antisurge::control::core::ControlCore::prepare(core.model(), cfg, law).expect("prepare");
    let _replaced = core.commit(r);
}

/// Drive a started law open loop at 1 kHz, the valve following the command at once, over
/// `n` cycles from cycle `k0`: flow `q(k)` (map units) at `ratio`, from the fallback while
/// `fallback(k)`. Returns the commands, one a cycle.
fn drive_with_source(
    law: &mut RecyclePi,
    model: &ControlModel,
    ratio: f64,
    (k0, n): (usize, usize),
    u0: f64,
    q: impl Fn(usize) -> f64,
    fallback: impl Fn(usize) -> bool,
) -> Vec<f64> {
    let op = operator();
    let mut u = u0;
    let mut out = Vec::with_capacity(n);
    for k in k0..k0 + n {
        let mut m = measurements(q(k), ratio);
        m.t_s = k as f64 * 1e-3;
        m.recycle_position = u;
        m.flow_fallback = fallback(k);
        let inputs = LawInputs {
            m: &m,
            op: &op,
            model,
            history: &antisurge::control::law::api::LoopHistory::EMPTY,
        };
        u = law
            .update(&inputs, 1e-3)
            .commands
            .get(ActuatorId::RecycleValve);
        out.push(u);
    }
    out
}

/// A frozen Δp under a feed drop (campaign cases 155 and 120): the observer's flow reads
/// reversed, the trip opens the valve fully; when the transmitter is trusted again and shows
/// the point far right of the control line, the trip's hold ends at once and the valve closes
/// at the return rate (the distance to the line over one answer time), faster than the
/// closing limiter's 0.1/s, and never below the line opening. Where the returned
/// transmitter shows the point left of the control line, the hold stays.
#[test]
fn the_flow_transmitters_return_releases_a_trip_taken_on_the_fallback() {
    let model = antisurge::sim::control_model(&common::plant(KV));
    let ratio = 2.0;
    // 2 s 30 % right of the line on the transmitter, 0.5 s reversed on the fallback, then
    // the transmitter again at `back` × the line's flow
    let run = |back: f64| {
        let (mut law, q_line) = started_closed(&model, |q| 1.3 * q, ratio);
        let q = |k: usize| match k {
            0..2000 => 1.3 * q_line,
            2000..2500 => -q_line,
            _ => back * q_line,
        };
        let fb = |k: usize| (2000..2500).contains(&k);
        let u = drive_with_source(&mut law, &model, ratio, (0, 2500), 0.0, q, fb);
        let u_at_return = *u.last().expect("commands");
        let tripped_at_return = law.tripped();
        let after = drive_with_source(&mut law, &model, ratio, (2500, 1000), u_at_return, q, fb);
        (u_at_return, tripped_at_return, law.tripped(), after)
    };
    // far right on the return: released on the first cycle, closing faster than 0.1/s
    let (u0, held, held_after, after) = run(2.0);
    assert!(
        u0 > 0.99 && held,
        "the fallback's reversal trips fully: {u0}"
    );
    assert!(!held_after, "the hold ends on the return");
    let u1 = *after.last().expect("commands");
    assert!(
        u1 < u0 - 0.3,
        "1 s after the return the valve closed from {u0:.3} to {u1:.3} only"
    );
    // never below the line opening: closing from u takes at most the fraction of the flow
    // the valve passes, so u ≥ u0/2 keeps a point at twice the line's flow on it
    let lowest = after.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(lowest >= 0.5 * u0 - 1e-9, "{lowest}");
    // left of the line on the return: the trip keeps holding
    let (_, _, held_left, after) = run(0.95);
    assert!(
        held_left || after.iter().all(|&u| u > 0.99),
        "a return left of the line keeps the valve open"
    );
}
