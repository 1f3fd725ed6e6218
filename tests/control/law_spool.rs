//! Seed 003 laws (`ccv`, `throttle-backstep`, `robust`) on the spool plant `liaw2004`, closed
//! loop through `sim::run` (the code path of `antisurge sim`).
//!
//! Flow settling is measured on the true compressor flow from the end of the throttle ramp
//! (t = 7 s) against the flow of the last 0.5 s; the residual oscillation is the peak-to-peak
//! flow over a window.

use crate::common;

use antisurge::control::LawId;
use antisurge::plant::{PlantInputs, SimPlant};
use antisurge::sim::case::PlantCase;
use antisurge::sim::trace::TraceRow;
use antisurge::sim::SimResult;

const PLANT: &str = "liaw2004_spool";
/// End of the throttle-closure ramp, s.
const RAMP_END_S: f64 = 7.0;

fn spool_plant() -> PlantCase {
    common::plant(PLANT)
}

/// The rightmost steady state of the nominal model at a throttle opening and nominal speed:
/// (flow kg/s, speed rad/s), from the plant's own equations (seed 003 eq. 8–9).
fn equilibrium(plant: &PlantCase, throttle: f64) -> (f64, f64) {
    let inputs = PlantInputs {
        throttle_process: 0.6,
        ..PlantInputs::default()
    };
    let SimPlant::Spool(p) = SimPlant::new(plant, &inputs).expect("plant") else {
        panic!("not a spool plant")
    };
    let sp = plant.file.spool.expect("spool");
    let w0 = plant.file.drive.nominal_speed_rad_s / sp.speed_scale_rad_s;
    let phi0 = p.operating_flow(throttle, w0);
    (
        phi0 * sp.flow_scale_kg_s,
        plant.file.drive.nominal_speed_rad_s,
    )
}

/// Mean flow over the last 0.5 s.
fn final_flow(r: &SimResult) -> f64 {
    let t_end = r.trace.last().expect("trace").t_s;
    let w: Vec<f64> = r
        .trace
        .iter()
        .filter(|x| x.t_s >= t_end - 0.5)
        .map(|x| x.m_kg_s)
        .collect();
    w.iter().sum::<f64>() / w.len() as f64
}

/// Time after `t0` at which the flow last left ±`band` (relative) of its final value.
fn settle_after(r: &SimResult, t0: f64, band: f64) -> f64 {
    let fin = final_flow(r);
    r.trace
        .iter()
        .filter(|x| x.t_s >= t0 && (x.m_kg_s - fin).abs() > band * fin.abs())
        .map(|x| x.t_s - t0)
        .fold(0.0, f64::max)
}

/// Peak-to-peak flow over [a, b], kg/s.
fn peak_to_peak(r: &SimResult, a: f64, b: f64) -> f64 {
    let (lo, hi) = r
        .trace
        .iter()
        .filter(|x| x.t_s >= a && x.t_s <= b)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
            (lo.min(x.m_kg_s), hi.max(x.m_kg_s))
        });
    hi - lo
}

/// Last time after `t0` with reversed flow (None: no reversal after `t0`).
fn last_reversal_after(r: &SimResult, t0: f64) -> Option<f64> {
    r.trace
        .iter()
        .filter(|x| x.t_s >= t0 && x.m_kg_s < 0.0)
        .map(|x| x.t_s - t0)
        .reduce(f64::max)
}

/// Every command of every trace row inside the ratings of the plant file; returns the peaks
/// (|CCV command|, drive torque command max, min, throttle command min, max).
fn assert_within_ratings(plant: &PlantCase, r: &SimResult, law: LawId) -> [f64; 5] {
    let sp = plant.file.spool.expect("spool");
    let d = plant.file.drive;
    let mut peaks = [0.0, f64::NEG_INFINITY, f64::INFINITY, f64::INFINITY, 0.0f64];
    for x in &r.trace {
        let TraceRow {
            cmd_ccv,
            cmd_drive_torque_nm: tq,
            cmd_throttle,
            ccv,
            ..
        } = *x;
        if cmd_ccv.is_finite() {
            assert!(
                cmd_ccv.abs() <= sp.ccv_max + 1e-12,
                "{law}: CCV command {cmd_ccv} beyond ccv_max {} at t = {}",
                sp.ccv_max,
                x.t_s
            );
            peaks[0] = peaks[0].max(cmd_ccv.abs());
        }
        assert!(ccv.abs() <= sp.ccv_max + 1e-12, "{law}: applied CCV {ccv}");
        assert!(
            tq >= d.min_torque_nm - 1e-9 && tq <= d.rated_torque_nm + 1e-9,
            "{law}: drive torque command {tq} N·m outside [{}, {}] at t = {}",
            d.min_torque_nm,
            d.rated_torque_nm,
            x.t_s
        );
        peaks[1] = peaks[1].max(tq);
        peaks[2] = peaks[2].min(tq);
        if cmd_throttle.is_finite() {
            assert!(
                (0.0..=1.0).contains(&cmd_throttle),
                "{law}: throttle command {cmd_throttle} at t = {}",
                x.t_s
            );
            peaks[3] = peaks[3].min(cmd_throttle);
            peaks[4] = peaks[4].max(cmd_throttle);
        }
    }
    let s = &r.summary.actuator_peaks;
    assert!(s.drive_torque_cmd_nm <= s.drive_torque_rating_nm + 1e-9);
    assert!(s.ccv <= s.ccv_rating + 1e-12);
    peaks
}

#[test]
fn none_surges_on_throttle_closure() {
    let plant = spool_plant();
    let r = common::simulate(&plant, &common::scenario("throttle_closure"), LawId::None);
    let s = &r.summary;
    assert!(!s.stable, "open loop must not settle");
    assert!(s.flow_reversal, "open-loop deep surge reverses the flow");
    assert!(s.surge_cycles >= 20, "{} surge cycles", s.surge_cycles);
    assert!(s.min_flow_kg_s < -1.0, "min flow {}", s.min_flow_kg_s);
}

/// Throttle closure 60 % → 20 %: no reversal, no surge cycle, flow within 2 % of its final
/// value within `settle_bound_s` of the ramp's end (summary) and within 0.5 % within 1.5 s, final
/// flow and speed at x⁰ of the 20 % throttle (0.2 %), every command inside the ratings.
fn closure_case(law: LawId, settle_bound_s: f64) -> [f64; 5] {
    let plant = spool_plant();
    let r = common::simulate(&plant, &common::scenario("throttle_closure"), law);
    let s = &r.summary;
    assert!(!s.flow_reversal, "{law}: flow reversal");
    assert_eq!(s.surge_cycles, 0, "{law}: surge cycles");
    assert!(s.stable, "{law}: not stable");
    let settle = s.settle_time_s.expect("settles");
    assert!(
        settle <= settle_bound_s,
        "{law}: 2 % settling {settle} s > {settle_bound_s} s"
    );
    let settle_tight = settle_after(&r, RAMP_END_S, 0.005);
    assert!(
        settle_tight <= 1.5,
        "{law}: 0.5 % settling {settle_tight} s"
    );
    let (m0, w0) = equilibrium(&plant, 0.2);
    let last = r.trace.last().expect("trace");
    assert!(
        (final_flow(&r) - m0).abs() <= 2e-3 * m0,
        "{law}: final flow {} vs x⁰ {m0}",
        final_flow(&r)
    );
    assert!(
        (last.omega_rad_s - w0).abs() <= 2e-3 * w0,
        "{law}: final speed {} vs setpoint {w0}",
        last.omega_rad_s
    );
    // never dips far below the new operating flow (no surge transient)
    assert!(
        s.min_flow_kg_s >= 0.9 * m0,
        "{law}: min flow {} < 0.9 × {m0}",
        s.min_flow_kg_s
    );
    assert_within_ratings(&plant, &r, law)
}

// Measured (2 % / 0.5 % settling after the ramp, s): ccv 0.115 / 0.355, throttle-backstep
// 0.025 / 0.965, robust 0.045 / 0.325; CCV peaks 0.034 (ccv) and 0.046 (robust) of 0.2; drive
// torque command 16.6–65.5 N·m of 150; throttle command 0.199–0.600.

#[test]
fn ccv_stabilises_throttle_closure_within_ratings() {
    let [ccv, tq_max, tq_min, ..] = closure_case(LawId::Ccv, 0.5);
    // the CCV works well inside its authority (0.2) on the slow closure; the drive torque
    // follows the eq. 7 schedule from 65.5 N·m down to Γ(φ⁰, ω̃⁰) ≈ 17.5 N·m
    assert!(ccv > 0.005 && ccv < 0.1, "CCV peak {ccv}");
    assert!(tq_max < 70.0 && tq_min > 10.0, "torque {tq_min}..{tq_max}");
}

#[test]
fn throttle_backstep_stabilises_throttle_closure_within_ratings() {
    let [ccv, _, _, thr_min, thr_max] = closure_case(LawId::ThrottleBackstep, 0.5);
    assert_eq!(ccv, 0.0, "throttle law must not drive the CCV");
    assert!(
        thr_min > 0.1 && thr_max < 0.7,
        "throttle {thr_min}..{thr_max}"
    );
}

#[test]
fn robust_stabilises_throttle_closure_within_ratings() {
    let [ccv, ..] = closure_case(LawId::Robust, 0.5);
    assert!(ccv > 0.005 && ccv < 0.1, "CCV peak {ccv}");
}

/// The plant with the matched uncertainty A sin(k x₂) of seed 003 eq. 53.
fn uncertain_plant(amplitude: f64, frequency: f64) -> PlantCase {
    let mut plant = spool_plant();
    let sp = plant.file.spool.as_mut().expect("spool");
    sp.uncertainty_amplitude = amplitude;
    sp.uncertainty_frequency = frequency;
    plant
}

#[test]
fn robust_beats_seed_ccv_under_eq53_uncertainty() {
    // seed 003 §IV Case 3: Δf = ΔCss = 0.1 sin(10 x₂) in the plant. The nominal law is Case 1,
    // eq. 48 as printed (u(x₂) = x₂); the robust law adds eq. 46–47 with δ₁ = δ₂ = 0.1.
    let sc = common::scenario("throttle_closure");
    let mut seed_ccv = uncertain_plant(0.1, 10.0);
    seed_ccv.controller.ccv.x2_gain_nd = 1.0;
    let ccv = common::simulate(&seed_ccv, &sc, LawId::Ccv);
    let robust = common::simulate(&uncertain_plant(0.1, 10.0), &sc, LawId::Robust);
    // the same nominal law without the uncertainty: the uncertainty must matter
    let mut nominal = spool_plant();
    nominal.controller.ccv.x2_gain_nd = 1.0;
    let ccv_nominal = common::simulate(&nominal, &sc, LawId::Ccv);

    let (t_ccv, t_rob, t_nom) = (
        settle_after(&ccv, RAMP_END_S, 0.01),
        settle_after(&robust, RAMP_END_S, 0.01),
        settle_after(&ccv_nominal, RAMP_END_S, 0.01),
    );
    let (a_ccv, a_rob) = (
        peak_to_peak(&ccv, 7.5, 8.5),
        peak_to_peak(&robust, 7.5, 8.5),
    );
    let report = format!(
        "1 % settling after the ramp: ccv {t_ccv:.3} s, robust {t_rob:.3} s (ccv without \
         uncertainty {t_nom:.3} s); residual p-p flow 0.5–1.5 s after the ramp: ccv {a_ccv:.4}, \
         robust {a_rob:.4} kg/s"
    );
    eprintln!("{report}");
    // measured: ccv 1.16 s, robust 0.20 s (5.9×); residual 0.033 vs 0.0012 kg/s (28×)
    assert!(t_ccv > 2.0 * t_nom, "uncertainty had no effect: {report}");
    assert!(t_ccv >= 3.0 * t_rob, "robust not 3× faster: {report}");
    assert!(
        a_rob * 5.0 <= a_ccv,
        "robust residual not smaller: {report}"
    );
    for (law, r) in [(LawId::Ccv, &ccv), (LawId::Robust, &robust)] {
        assert!(
            !r.summary.flow_reversal && r.summary.surge_cycles == 0,
            "{law}"
        );
        assert_within_ratings(&seed_ccv, r, law);
    }
    // ERRATA: the nominal law does not keep oscillating here, it decays (slowly)
    let late = peak_to_peak(&ccv, 15.0, 20.0);
    assert!(late < 1e-3, "ccv residual at 15–20 s {late}");
}

#[test]
fn robust_keeps_its_guarantee_where_the_tuned_ccv_fails() {
    // same bound δ = 0.1, steeper uncertainty: ΔCss = 0.1 sin(50 x₂) has slope 5 at x₂ = 0, more
    // than the tuned CCV's damping k = 3; the robust law only needs the bound (Theorem 3)
    let sc = common::scenario("throttle_closure");
    let plant = uncertain_plant(0.1, 50.0);
    let ccv = common::simulate(&plant, &sc, LawId::Ccv);
    let robust = common::simulate(&plant, &sc, LawId::Robust);
    assert!(
        !ccv.summary.stable && ccv.summary.surge_cycles > 0,
        "tuned ccv: {:?}",
        ccv.summary.surge_cycles
    );
    assert!(peak_to_peak(&ccv, 15.0, 20.0) > 0.1);
    let s = &robust.summary;
    assert!(s.stable && !s.flow_reversal && s.surge_cycles == 0);
    assert!(s.settle_time_s.expect("settles") < 0.5);
    assert!(peak_to_peak(&robust, 15.0, 20.0) < 1e-3);
    assert_within_ratings(&plant, &robust, LawId::Robust);
}

/// Throttle closure under `none` (deep surge develops), then the operator switches to `law` at
/// `switch_s` (seed 003 §IV: the control is applied to a surging machine).
fn rescue_scenario(law: &str, switch_s: f64, duration_s: f64, trace_s: f64) -> String {
    format!(
        "name = \"spool-rescue\"\ndescription = \"surge under none, then {law}\"\n\
         duration_s = {duration_s}\ntrace_period_s = {trace_s}\n[initial]\nthrottle = 0.6\n\
         [[event]]\nat_s = 5.0\nramp = {{ signal = \"throttle\", to = 0.2, over_s = 2.0 }}\n\
         [[event]]\nat_s = {switch_s}\nlaw = \"{law}\"\n"
    )
}

#[test]
fn ccv_limit_0_1_recovers_slower_than_0_2() {
    // seed 003 §IV Case 1 with the CCV limited to 0.1 and 0.2: both stabilise, the tighter limit
    // takes longer. Switched in at 8 s, after five deep-surge cycles.
    let switch_s = 8.0;
    let sc = common::scenario_text(&rescue_scenario("ccv", switch_s, 20.0, 0.005));
    let mut out = Vec::new();
    for limit in [0.1, 0.2] {
        let mut plant = spool_plant();
        plant.file.spool.as_mut().expect("spool").ccv_max = limit;
        let r = common::simulate(&plant, &sc, LawId::None);
        let s = &r.summary;
        assert!(s.stable, "limit {limit}: not stable: {s:#?}");
        let (m0, _) = equilibrium(&plant, 0.2);
        assert!((final_flow(&r) - m0).abs() < 2e-3 * m0, "limit {limit}");
        let peaks = assert_within_ratings(&plant, &r, LawId::Ccv);
        assert!((peaks[0] - limit).abs() < 1e-12, "the limit is reached");
        let reversal = last_reversal_after(&r, switch_s).expect("it was surging");
        out.push((
            limit,
            reversal,
            settle_after(&r, switch_s, 0.2),
            settle_after(&r, switch_s, 0.02),
        ));
    }
    let report = format!("(limit, last reversal, 20 % band, 2 % band) after the switch: {out:?}");
    eprintln!("{report}");
    let ((_, rev1, b1, s1), (_, rev2, b2, s2)) = (out[0], out[1]);
    // measured: last reversal 1.25 s vs 0.35 s, ±20 % band 1.27 s vs 0.54 s; the 2 % settling
    // (2.55 s vs 2.65 s) is set by the spool speed coming back from its runaway under `none`
    assert!(rev1 >= 2.0 * rev2, "{report}");
    assert!(b1 >= 1.5 * b2, "{report}");
    assert!(s1 < 3.5 && s2 < 3.5, "{report}");
}

#[test]
fn bumpless_switch_from_none_to_each_law() {
    // Three instants: steady before the closure (3 s), mid-ramp left of the surge line but not
    // yet surging (6 s: the state is off x⁰, the law's own output differs from the current one),
    // and in deep surge (8 s, ccv and robust only: a throttle cannot end a deep surge). No
    // output may step by more than 1 % of its range at the switch; in the first two cases no
    // output moves by more than 1 % per cycle in the 50 ms after it, and the law then stabilises.
    let plant = spool_plant();
    let sp = plant.file.spool.expect("spool");
    let d = plant.file.drive;
    let ranges = [2.0 * sp.ccv_max, 1.0, d.rated_torque_nm - d.min_torque_nm];
    for law in [LawId::Ccv, LawId::ThrottleBackstep, LawId::Robust] {
        for switch_s in [3.0, 6.0, 8.0] {
            if law == LawId::ThrottleBackstep && switch_s > 7.0 {
                continue;
            }
            let text = rescue_scenario(law.name(), switch_s, 16.0, 0.001);
            let r = common::simulate(&plant, &common::scenario_text(&text), LawId::None);
            let k = r
                .trace
                .iter()
                .position(|x| (x.t_s - switch_s).abs() < 1e-9)
                .expect("row at switch");
            // effective setpoints: the command, or what the device holds when not commanded
            let eff = |x: &TraceRow| {
                let or = |c: f64, held: f64| if c.is_finite() { c } else { held };
                [
                    or(x.cmd_ccv, x.ccv),
                    or(x.cmd_throttle, x.throttle_position),
                    x.cmd_drive_torque_nm,
                ]
            };
            let step = |i: usize| {
                let (a, b) = (eff(&r.trace[i - 1]), eff(&r.trace[i]));
                [0, 1, 2].map(|j| (b[j] - a[j]).abs() / ranges[j])
            };
            let at = step(k);
            assert!(
                at.iter().all(|s| *s <= 0.01),
                "{law} at {switch_s} s: steps {at:?} (fractions of range)"
            );
            if switch_s < 7.0 {
                for i in k + 1..k + 50 {
                    let s = step(i);
                    assert!(
                        s.iter().all(|s| *s <= 0.01),
                        "{law} at {switch_s} s: {s:?} at t = {}",
                        r.trace[i].t_s
                    );
                }
            }
            assert!(
                r.summary.stable,
                "{law} switched in at {switch_s} s does not stabilise: {:#?}",
                r.summary
            );
            if switch_s < 7.0 {
                assert_eq!(r.summary.surge_cycles, 0, "{law} at {switch_s} s");
            }
            // the law really took over: it drives its valve
            let last = r.trace.last().expect("trace");
            match law {
                LawId::ThrottleBackstep => assert!(last.cmd_throttle.is_finite()),
                _ => assert!(last.cmd_ccv.is_finite()),
            }
        }
    }
}

#[test]
fn plant_uncertainty_is_off_by_default_and_keeps_the_equilibrium() {
    let plant = spool_plant();
    let sp = plant.file.spool.expect("spool");
    assert_eq!(sp.uncertainty_amplitude, 0.0);
    assert_eq!(sp.uncertainty_frequency, 10.0);
    // the operating flow the plant uses for x₂ is its steady state (seed 003 eq. 8–9)
    let inputs = PlantInputs {
        throttle_process: 0.6,
        ..PlantInputs::default()
    };
    let SimPlant::Spool(p) = SimPlant::new(&plant, &inputs).expect("plant") else {
        panic!()
    };
    for throttle in [0.2, 0.4, 0.6, 0.9] {
        let eq = p.equilibria(throttle, 1.0);
        let phi = p.operating_flow(throttle, 1.0);
        let right = eq.last().expect("equilibrium")[1];
        assert!((phi - right).abs() < 1e-6, "{throttle}: {phi} vs {right}");
    }
    // with the uncertainty on, the stable 60 % point holds (Δ vanishes there) ...
    let unc = uncertain_plant(0.1, 10.0);
    let hold = common::simulate(&unc, &common::scenario("hold"), LawId::None);
    let m0 = hold.trace[0].m_kg_s;
    assert!(hold
        .trace
        .iter()
        .all(|x| (x.m_kg_s - m0).abs() < 1e-9 * m0.abs().max(1.0)));
    // ... and the uncertainty changes the open-loop surge (it is in the dynamics)
    let sc = common::scenario("throttle_closure");
    let a = common::simulate(&plant, &sc, LawId::None);
    let b = common::simulate(&unc, &sc, LawId::None);
    let diff = a
        .trace
        .iter()
        .zip(&b.trace)
        .map(|(x, y)| (x.m_kg_s - y.m_kg_s).abs())
        .fold(0.0, f64::max);
    assert!(diff > 0.1, "max flow difference {diff}");
}
