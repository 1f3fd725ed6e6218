//! `drive-torque` (seed 000 eq. 7, 22) closed loop on the bohagen2007 plant, through the same
//! code path as `antisurge sim` (`sim::run`).

use crate::common;

use antisurge::control::laws::drive_torque::{check_eq8, eq8_bound, DriveTorque, Eq8Region};
use antisurge::control::LawId;
use antisurge::scenario::Scenario;
use antisurge::sim::case::PlantCase;
use antisurge::sim::SimResult;

const PLANT: &str = "bohagen2007_plenum";
/// Largest uniform white noise (both pressure transmitters) at which the closure stays out of
/// surge for every seed tried, with the 0.5 kg·m² rotor: 6 Pa holds on 3 seeds, 8 Pa saturates
/// the drive a quarter of the time, 14 Pa surges (≈ 25 Pa with the former 0.2 kg·m² rotor).
const TOLERATED_NOISE_PA: f64 = 6.0;

fn bohagen() -> PlantCase {
    common::plant(PLANT)
}

fn run(plant: &PlantCase, scenario: &Scenario) -> SimResult {
    common::simulate(plant, scenario, LawId::DriveTorque)
}

/// The shipped pressure-noise scenario (seed 000 §6.3) with another amplitude and noise seed.
fn noise_scenario(amplitude_pa: f64, seed: u64) -> Scenario {
    let text = std::fs::read_to_string(common::root().join("config/scenarios/pressure_noise.toml"))
        .expect("read pressure_noise.toml");
    assert!(text.contains("amplitude = 5000.0") && text.contains("seed = 20070601"));
    common::scenario_text(
        &text
            .replace(
                "amplitude = 5000.0",
                &format!("amplitude = {amplitude_pa:.1}"),
            )
            .replace("seed = 20070601", &format!("seed = {seed}")),
    )
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    s / n as f64
}

#[test]
fn eq8_bound_from_the_map_and_tuned_gains_satisfy_eq8_and_eq9() {
    let plant = bohagen();
    let model = antisurge::sim::control_model(&plant);
    let region = Eq8Region::default_for(&model).expect("map has a surge point");
    let bound = eq8_bound(&model, region);
    // cubic map with fan-law scaling: sup (∂Ψ/∂m)/(∂Ψ/∂ω) = ω_ref/W · max H g'/(2(ψc0 − 1 + H g)
    // − (x+1) H g') = 141.0 rad/s per kg/s at x ≈ −0.08 (m ≈ 0.46 q_peak), the same at every speed
    assert!(
        (bound.c1_min - 141.0).abs() < 0.5,
        "eq. 8 bound {}",
        bound.c1_min
    );
    let q_peak = 7.0; // 2W at ω0; the surge flow scales with speed
    let (m_star, w_star) = bound.argmax;
    let w0 = plant.file.drive.nominal_speed_rad_s;
    assert!(
        (m_star / (q_peak * w_star / w0) - 0.46).abs() < 0.02,
        "{:?}",
        bound.argmax
    );
    assert!(bound.c1_max.is_infinite(), "∂Ψ/∂ω > 0 on the region");
    // the seed's c1 = 100 (§6.2) violates eq. 8 on this map; the tuned gains satisfy 8 and 9
    assert!(!bound.admits(100.0));
    let cfg = &model.controller.drive_torque;
    assert!(
        bound.admits(cfg.c1_rad_s_per_kg_s),
        "c1 = {} vs bound {}",
        cfg.c1_rad_s_per_kg_s,
        bound.c1_min
    );
    assert!(cfg.c1_rad_s_per_kg_s > 1.2 * bound.c1_min, "keep a margin");
    assert_eq!(
        check_eq8(cfg, &model),
        Ok(bound),
        "config validation agrees"
    );
    let law = DriveTorque::new(cfg, &model).expect("law");
    assert_eq!(law.k2(), law.k1() * law.c1(), "eq. 9");
    assert!((law.k2() - 350.0 * 180.0).abs() < 1e-9);
    // over a wider region the inequality reverses where ∂Ψ/∂ω < 0 (deep choke side of the
    // linearly continued cubic): eq. 8 holds on a region only (ERRATA.md)
    let wide = eq8_bound(
        &model,
        Eq8Region {
            flow_kg_s: (-q_peak, 6.0 * q_peak),
            ..region
        },
    );
    assert!(wide.c1_max.is_finite() && wide.c1_max > 0.0, "{wide:?}");
}

#[test]
fn throttle_closure_is_stabilised_with_torque_within_rating() {
    let plant = bohagen();
    let sc = common::scenario("throttle_closure");
    let r = run(&plant, &sc);
    let s = &r.summary;
    assert!(s.stable, "{s:#?}");
    assert!(!s.flow_reversal && s.surge_cycles == 0, "{s:#?}");
    // settles 0.19 s after the ramp ends (flow within ±2 %)
    let settle = s.settle_time_s.expect("settles");
    assert!(settle < 0.5, "settle {settle} s");
    // ends at the open-loop-unstable 20 % equilibrium, 56 % left of the surge line
    assert!((s.final_flow_kg_s - 2.66).abs() < 0.03, "{s:#?}");
    assert!(s.final_surge_margin < -0.5, "{s:#?}");
    assert!(s.min_flow_kg_s > 2.2, "{s:#?}");
    // torque: within the rating and ≤ 3× the 400 N·m nominal load (peak 400 N·m, min −5 N·m)
    let p = &s.actuator_peaks;
    let rating = plant.file.drive.rated_torque_nm;
    let nominal = p.nominal_load_torque_nm;
    assert!((nominal - 400.0).abs() < 1.0);
    assert!(p.drive_torque_nm <= rating.min(3.0 * nominal), "{p:#?}");
    assert!(p.drive_torque_nm <= 1.05 * nominal, "{p:#?}");
    let tau_min = r
        .trace
        .iter()
        .map(|t| t.drive_torque_nm)
        .fold(f64::INFINITY, f64::min);
    // the law brakes the 0.5 kg·m² rotor down to ≈ −175 N·m where the closure ends (four-
    // quadrant drive); a quarter of the rating at most
    assert!(
        tau_min >= plant.file.drive.min_torque_nm && tau_min > -0.25 * rating,
        "{tau_min}"
    );
    // speed: excursion within ±5 % of ω0, and the speed loop brings it back (law is zero at the
    // steady state, so the mean speed is the setpoint)
    let w0 = plant.file.drive.nominal_speed_rad_s;
    for t in &r.trace {
        assert!(
            (t.omega_rad_s / w0 - 1.0).abs() < 0.05,
            "t {}: {}",
            t.t_s,
            t.omega_rad_s
        );
    }
    let last = r.trace.last().expect("trace");
    assert!(
        (last.omega_rad_s / w0 - 1.0).abs() < 0.002,
        "{}",
        last.omega_rad_s
    );
    assert!(
        last.law_diagnostic.abs() < 0.01,
        "m̄ = {}",
        last.law_diagnostic
    );

    // the same scenario without surge control surges
    let open = common::simulate(&plant, &sc, LawId::None).summary;
    assert!(open.surge_cycles > 10 && open.flow_reversal, "{open:#?}");
}

#[test]
fn throttle_step_and_sweep_are_stabilised() {
    let plant = bohagen();
    let step = run(&plant, &common::scenario("throttle_step")).summary;
    assert!(
        step.stable && step.surge_cycles == 0 && !step.flow_reversal,
        "{step:#?}"
    );
    assert!(step.settle_time_s.expect("settles") < 3.0, "{step:#?}");
    // peak 428 N·m with the 0.5 kg·m² rotor (1.07× the nominal load)
    assert!(
        step.actuator_peaks.drive_torque_nm <= 1.1 * 400.0,
        "{step:#?}"
    );
    // minimum stable flow: down to 5 % throttle, 0.62 kg/s against a surge point of 7 kg/s
    let sweep = run(&plant, &common::scenario("throttle_sweep")).summary;
    assert!(
        sweep.stable && sweep.surge_cycles == 0 && !sweep.flow_reversal,
        "{sweep:#?}"
    );
    assert!(sweep.final_flow_kg_s < 1.0, "{sweep:#?}");
}

#[test]
fn gains_below_the_eq8_bound_do_not_stabilise() {
    // the seed's c1 = 100 (§6.2) with the tuned K1: c1 below the local ratio 137 at the 20 %
    // equilibrium leaves the effective characteristic rising, and the closure surges
    let mut plant = bohagen();
    plant.controller.drive_torque.c1_rad_s_per_kg_s = 100.0;
    let s = run(&plant, &common::scenario("throttle_closure")).summary;
    assert!(s.surge_cycles > 0 || s.flow_reversal, "{s:#?}");
}

#[test]
fn washout_equilibrium_fails_where_the_outflow_construction_holds() {
    // m0 = LP(m̂) instead of m0 = m_t(p, position) + slow bias: during the 2 s ramp the washed-out
    // flow deviation asks for hundreds of rad/s of speed change and the torque saturates
    let mut plant = bohagen();
    plant.controller.drive_torque.equilibrium_flow =
        antisurge::control::laws::drive_torque::EquilibriumFlow::Washout;
    plant.controller.drive_torque.equilibrium_time_constant_s = 1.0;
    let s = run(&plant, &common::scenario("throttle_closure")).summary;
    assert!(s.surge_cycles > 0, "{s:#?}");
}

#[test]
fn tolerated_pressure_noise() {
    let plant = bohagen();
    let w0 = plant.file.drive.nominal_speed_rad_s;
    let shipped = common::scenario("drive_torque_noise_tolerated");
    let text = std::fs::read_to_string(
        common::root().join("config/scenarios/drive_torque_noise_tolerated.toml"),
    )
    .expect("read");
    assert!(text.contains(&format!("amplitude = {TOLERATED_NOISE_PA:.1}")));
    for (k, seed) in [20070601, 1, 2].into_iter().enumerate() {
        let sc = if k == 0 {
            shipped.clone()
        } else {
            noise_scenario(TOLERATED_NOISE_PA, seed)
        };
        let r = run(&plant, &sc);
        let s = &r.summary;
        assert!(
            s.surge_cycles == 0 && !s.flow_reversal,
            "{TOLERATED_NOISE_PA} Pa, seed {seed}: {s:#?}"
        );
        assert!(s.min_flow_kg_s > 2.0, "{s:#?}");
        // the mean flow holds the 20 % equilibrium; the torque stays within the rating
        let tail = r.trace.iter().filter(|t| t.t_s > 12.0);
        let m = mean(tail.map(|t| t.m_kg_s));
        assert!((m - 2.66).abs() < 0.05, "mean flow {m}");
        // the speed loop keeps the mean speed although the sum saturates now and then
        let w = mean(
            r.trace
                .iter()
                .filter(|t| t.t_s > 12.0)
                .map(|t| t.omega_rad_s),
        );
        assert!((w / w0 - 1.0).abs() < 0.005, "mean speed {w}");
        assert!(s.actuator_peaks.drive_torque_nm <= plant.file.drive.rated_torque_nm + 1e-9);
    }
    // the limit is real: 5× the tolerated amplitude, and the seed's 5000 Pa (§6.3), surge
    for a in [5.0 * TOLERATED_NOISE_PA, 5000.0] {
        let s = run(&plant, &noise_scenario(a, 20070601)).summary;
        assert!(s.surge_cycles > 0, "{a} Pa: {s:#?}");
    }
}

#[test]
fn observer_feedback_survives_flow_transmitter_failure() {
    let sc = common::scenario("flow_transmitter_failure");
    // default: the law feeds back the observer (Theorem 3), the core falls back to it too
    let plant = bohagen();
    let r = run(&plant, &sc);
    let s = &r.summary;
    assert!(
        s.stable && s.surge_cycles == 0 && !s.flow_reversal,
        "{s:#?}"
    );
    assert!(s.settle_time_s.expect("settles") < 0.5, "{s:#?}");
    let last = r.trace.last().expect("trace");
    assert!(
        last.meas_m_kg_s.is_nan(),
        "the transmitter is failed (stale)"
    );
    assert!(
        (last.est_m_kg_s - last.m_kg_s).abs() < 0.01,
        "observer {} vs true {}",
        last.est_m_kg_s,
        last.m_kg_s
    );
    // pressure-and-speed only: the core uses the observer as flow source, the law its choice
    let mut obs_only = bohagen();
    obs_only.controller.flow_source = antisurge::control::config::FlowSource::Observer;
    obs_only.controller.drive_torque.flow =
        antisurge::control::laws::drive_torque::FlowInput::Selected;
    let s = run(&obs_only, &sc).summary;
    assert!(
        s.stable && s.surge_cycles == 0 && !s.flow_reversal,
        "{s:#?}"
    );
}

/// Largest command step between consecutive control cycles in [t0, t1].
fn max_step(r: &SimResult, t0: f64, t1: f64) -> f64 {
    r.trace
        .windows(2)
        .filter(|w| w[1].t_s >= t0 && w[1].t_s <= t1)
        .map(|w| (w[1].cmd_drive_torque_nm - w[0].cmd_drive_torque_nm).abs())
        .fold(0.0, f64::max)
}

#[test]
fn bumpless_switch_from_none_mid_closure() {
    let plant = bohagen();
    let rating = plant.file.drive.rated_torque_nm;
    // switch at 5.8 s: the throttle is closing and the flow (6.9 kg/s) is already left of the
    // surge point; the speed has drifted 7 rad/s from the setpoint, so −K1 ω̄ alone would step
    // ≈ 1 kN·m
    let text = |t_switch: f64| {
        format!(
            "name='switch'\ndescription='none → drive-torque'\nduration_s=20\ntrace_period_s=0.001\n\
             [initial]\nthrottle=0.6\n\
             [[event]]\nat_s=5\nramp={{signal='throttle', to=0.2, over_s=2}}\n\
             [[event]]\nat_s={t_switch}\nlaw='drive-torque'\n"
        )
    };
    let r = common::simulate(&plant, &common::scenario_text(&text(5.8)), LawId::None);
    assert_eq!(r.summary.law, "drive-torque");
    let k = r
        .trace
        .iter()
        .position(|t| t.t_s >= 5.8 - 1e-9)
        .expect("switch");
    let w0 = plant.file.drive.nominal_speed_rad_s;
    assert!(
        (r.trace[k].omega_rad_s - w0).abs() > 3.0,
        "the test needs a speed error at the switch"
    );
    let before = max_step(&r, 5.7, 5.799);
    let at = (r.trace[k].cmd_drive_torque_nm - r.trace[k - 1].cmd_drive_torque_nm).abs();
    assert!(
        at <= 0.01 * rating,
        "step at the switch {at} N·m (natural {before})"
    );
    // the hand-over offset −K1·ω̄ decays with transfer_time_constant_s; K1 = 350 (0.5 kg·m²)
    // makes it 2.5× what K1 = 140 (0.2 kg·m²) did: 38 N·m per ms at most
    let after = max_step(&r, 5.8, 5.9);
    assert!(
        after <= 0.05 * rating,
        "largest step in 100 ms after: {after}"
    );
    let s = &r.summary;
    assert!(
        s.stable && s.surge_cycles == 0 && !s.flow_reversal,
        "{s:#?}"
    );

    // switched at a steady state, nothing moves at all
    let r = common::simulate(&plant, &common::scenario_text(&text(3.0)), LawId::None);
    assert!(max_step(&r, 2.9, 4.9) < 1e-6, "{}", max_step(&r, 2.9, 4.9));
    assert!(r.summary.stable && r.summary.surge_cycles == 0);
}

/// The throttle closure with `delay_compensation_ms` and a simulated loop delay of
/// `delay` periods plus up to `jitter` more.
fn closure_with_delay(compensate_ms: f64, delay: usize, jitter: usize) -> SimResult {
    let mut p = bohagen();
    p.controller.drive_torque.delay_compensation_ms = compensate_ms;
    antisurge::sim::run(
        &p,
        &common::scenario("throttle_closure"),
        antisurge::sim::SimOptions {
            law: LawId::DriveTorque,
            loop_delay_periods: delay,
            loop_delay_jitter_periods: jitter,
            ..Default::default()
        },
        &mut |_| {},
    )
    .expect("sim")
}

#[test]
fn loop_delay_needs_the_predictor_and_the_predictor_covers_it() {
    // The unstable duct mode at 20 % throttle (≈ 143 rad/s) leaves the law about one period
    // of delay: at 2 periods (a CAN round trip out of phase with the plant) it surges.
    let surged = |r: &SimResult| r.summary.surge_cycles > 0 || r.summary.flow_reversal;
    assert!(
        !surged(&closure_with_delay(0.0, 1, 0)),
        "one period is held"
    );
    let r = closure_with_delay(0.0, 2, 0);
    assert!(surged(&r), "two periods uncompensated: {:?}", r.summary);
    // Predicting 2 ms ahead with the machine model holds delays of 1 to 4 periods, fixed or
    // jittering, with the torque inside the rating and the same minimum flow as the ideal
    // loop (2.347 kg/s) within 1 %.
    let ideal = closure_with_delay(0.0, 0, 0).summary.min_flow_kg_s;
    for (delay, jitter) in [(1, 0), (2, 0), (3, 0), (1, 1), (1, 2), (1, 3), (2, 2)] {
        let r = closure_with_delay(2.0, delay, jitter);
        let s = &r.summary;
        assert!(!surged(&r), "compensated, delay {delay}+0..{jitter}: {s:?}");
        assert!(
            (s.min_flow_kg_s - ideal).abs() < 0.01 * ideal,
            "delay {delay}+0..{jitter}: min flow {} vs {ideal}",
            s.min_flow_kg_s
        );
        assert!(s.actuator_peaks.drive_torque_cmd_nm <= 1000.0 + 1e-9);
    }
    // where the delay is matched, the torque stays at the nominal load torque (no chatter)
    let matched = closure_with_delay(2.0, 2, 0);
    assert!(
        matched.summary.actuator_peaks.drive_torque_cmd_nm < 450.0,
        "{:?}",
        matched.summary.actuator_peaks
    );
}

/// The HIL closure (the command acts from the plant's next step; 0.5 ms of delay
/// compensation, `hil/configs/can_drive_torque.toml`), with the plant paused once, at
/// `pause_at_s`, for `pause_s` by its host while the controller's clock goes on: the sample after
/// the pause is one scenario period after the one before, and the controller runs
/// `pause_s` later. `sender_clock`: the samples carry the plant's step time as their sender
/// clock, as the CAN receive side rebuilds it from the alive counter and the in-process plant
/// publishes it (`RawSensors::sample_clock_s`).
fn closure_with_a_host_pause(pause_at_s: f64, pause_s: f64, sender_clock: bool) -> SimResult {
    use antisurge::control::core::{ControlCore, CoreSettings};
    use antisurge::sim::{operator_inputs, ControllerView, PlantRun};
    use antisurge::vocab::signals::ActuatorCommands;
    let mut case = bohagen();
    case.controller.drive_torque.delay_compensation_ms = 0.5;
    let scenario = common::scenario("throttle_closure");
    let model = antisurge::sim::control_model(&case);
    let mut pr = PlantRun::new(&case, &scenario).expect("plant");
    let nominal = model.drive.nominal_speed_rad_s;
    let t0 = pr.plant().truth().load_torque_nm;
    let settings = CoreSettings::defaults_for(&model);
    let config = model.controller.clone();
    let mut core = ControlCore::new(model, config, settings, LawId::DriveTorque, t0).expect("core");
    let dt = pr.dt_s();
    let n = pr.n_steps();
    let mut applied = ActuatorCommands::default();
    for k in 0..=n {
        let t = k as f64 * dt;
        let (st, mut raw) = pr.sense(t);
        if sender_clock {
            raw.sample_clock_s = [t; antisurge::vocab::signals::SensorId::COUNT];
        }
        // the controller's clock: the plant's, plus the pause once it happened
        let t_controller = if t >= pause_at_s { t + pause_s } else { t };
        let out = core.cycle(t_controller, &raw, &operator_inputs(&st, nominal));
        pr.record(k, t, dt, &raw, &out.commands, &ControllerView::of(&out));
        if k == n {
            break;
        }
        pr.advance(&st, &applied, dt);
        applied = out.commands;
    }
    pr.finish("drive-torque")
}

#[test]
fn a_plant_paused_by_its_host_is_controlled_on_the_senders_clock() {
    // CI, 2026-11-29, HIL `timing`: the emulated machine stood still for 3.4 ms (plant and
    // controller alike); the controller's next cycle came 3.4 ms after the last, its sample
    // one plant step (1 ms) after the last. Integrated over its own 3.4 ms the observer's
    // estimate jumped by K_z·ṗ·2.4 ms ≈ 0.05 kg/s, K2 = 63 000 N·m per kg/s saturated the
    // torque, and the plant surged 54 times (min flow −3.535 kg/s).
    let surged = |r: &SimResult| r.summary.surge_cycles > 0 || r.summary.flow_reversal;
    let ideal = closure_with_a_host_pause(f64::INFINITY, 0.0, true);
    assert!(!surged(&ideal), "{:?}", ideal.summary);
    for pause_s in [1e-3, 3.4e-3, 10e-3] {
        let on_arrivals = closure_with_a_host_pause(6.47, pause_s, false);
        assert!(
            surged(&on_arrivals),
            "{pause_s} s on the controller's own clock: {:?}",
            on_arrivals.summary
        );
        let r = closure_with_a_host_pause(6.47, pause_s, true);
        assert!(
            !surged(&r),
            "{pause_s} s on the sender's clock: {:?}",
            r.summary
        );
        assert!(
            (r.summary.min_flow_kg_s - ideal.summary.min_flow_kg_s).abs()
                < 1e-3 * ideal.summary.min_flow_kg_s,
            "{pause_s} s: min flow {} vs {}",
            r.summary.min_flow_kg_s,
            ideal.summary.min_flow_kg_s
        );
    }
}
