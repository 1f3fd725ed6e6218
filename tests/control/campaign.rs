//! The robustness campaign (issue 22): the skid generator keeps to its documented ranges and
//! repeats with its seed, the oracle separates feasible from infeasible cases, the reduced
//! campaign's safety lines (recycle-pi against the late oracle and against baseline-pi), the
//! same case at 50 Hz and 1 kHz, and README.md's campaign block.
//!
//! The reduced campaign (32 cases) runs once per test binary ([`common::campaign::reduced`]).

use crate::common;

use antisurge::campaign::runner::{self, Controller, RunResult};
use antisurge::campaign::skid::{self, DisturbanceKind};
use antisurge::campaign::{self as cmp, CaseResult, Feasibility};
use antisurge::control::LawId;
use common::campaign::{bases, case_line, reduced};
use std::process::Command;

fn within(x: f64, r: (f64, f64)) -> bool {
    x >= r.0 && x <= r.1
}

/// Every drawn skid lies in the documented ranges: its surge frequency and step-to-reversal
/// time recomputed from the plant it carries (not only the numbers it reports), and every
/// other drawn quantity.
#[test]
fn every_drawn_skid_lies_in_the_documented_ranges() {
    let b = bases();
    let mut rates = Vec::new();
    let mut kinds = Vec::new();
    for k in 0..48 {
        let s = skid::draw_skid(&b, cmp::DEFAULT_SEED, k).expect("skid");
        let p = &s.params;
        let rs = s.plant.file.recycle_system.expect("recycle plant");
        let f = skid::helmholtz_hz(&rs);
        assert!(within(f, skid::SURGE_FREQUENCY_HZ), "case {k}: {f} Hz");
        assert_eq!(f, p.surge_frequency_hz, "case {k}");
        let t = skid::step_to_reversal_s(&s.plant, 1.0).expect("reverses");
        assert!(within(t, skid::STEP_TO_REVERSAL_S), "case {k}: {t} s");
        assert_eq!(t, p.step_to_reversal_s, "case {k}");
        assert!(p.initial_margin >= skid::MIN_INITIAL_MARGIN, "case {k}");
        assert!(within(p.recycle_stroke_time_s, skid::RECYCLE_STROKE_S));
        assert_eq!(rs.recycle_valve.stroke_time_s, p.recycle_stroke_time_s);
        assert!(within(p.valve_dead_time_s, skid::VALVE_DEAD_TIME_S));
        assert!(within(p.throttle_stroke_time_s, skid::THROTTLE_STROKE_S));
        assert!(within(p.latency_s, skid::LATENCY_S));
        assert!(p.jitter_s >= 0.0 && p.jitter_s <= skid::JITTER_FRACTION.1 * p.latency_s);
        assert!(within(p.map_flow_factor, skid::MAP_FLOW_FACTOR));
        assert!(within(p.map_rise_factor, skid::MAP_RISE_FACTOR));
        assert!(within(p.pressure_noise_pct_span, skid::PRESSURE_NOISE_PCT));
        assert!(within(p.dp_noise_pct_span, skid::DP_NOISE_PCT));
        assert!(
            (skid::QUANTISATION_BITS.0..=skid::QUANTISATION_BITS.1).contains(&p.quantisation_bits)
        );
        assert!(skid::LOOP_RATES_HZ.contains(&p.rate_hz));
        rates.push(p.rate_hz);
        kinds.push(p.disturbance.kind());
    }
    for r in skid::LOOP_RATES_HZ {
        assert_eq!(rates.iter().filter(|x| **x == r).count(), 12, "{r} Hz");
    }
    for d in DisturbanceKind::ALL {
        assert_eq!(kinds.iter().filter(|x| **x == d).count(), 12, "{d:?}");
    }
}

/// A fixed seed draws the same skids (case by case, in any order); another seed draws others.
#[test]
fn a_fixed_seed_draws_the_same_skids() {
    let b = bases();
    let first: Vec<_> = (0..8)
        .map(|k| skid::draw_skid(&b, 7, k).expect("skid").params)
        .collect();
    let again: Vec<_> = (0..8)
        .rev()
        .map(|k| skid::draw_skid(&b, 7, k).expect("skid").params)
        .collect();
    let again: Vec<_> = again.into_iter().rev().collect();
    assert_eq!(first, again);
    let other: Vec<_> = (0..8)
        .map(|k| skid::draw_skid(&b, 8, k).expect("skid").params)
        .collect();
    for (a, o) in first.iter().zip(&other) {
        assert_ne!(a, o);
    }
}

/// The reduced campaign spans every loop rate and every disturbance, the disturbances
/// challenge the machines (the held valve surges in some cases), and the oracle holds some
/// cases and fails others: it separates, it is not a constant.
#[test]
fn the_reduced_campaign_spans_every_rate_and_disturbance_and_the_oracle_separates() {
    let c = reduced();
    assert!(c.cases.len() >= 30);
    for r in skid::LOOP_RATES_HZ {
        for d in DisturbanceKind::ALL {
            assert!(
                c.cases
                    .iter()
                    .any(|x| x.skid.rate_hz == r && x.skid.disturbance.kind() == d),
                "no {r} Hz × {d:?} case"
            );
        }
    }
    let held = c.cases.iter().filter(|x| x.held.surge_cycles > 0).count();
    let holds = c
        .cases
        .iter()
        .filter(|x| x.oracle.surge_cycles == 0)
        .count();
    let fails = c.cases.len() - holds;
    println!("valve held surges in {held}, oracle holds {holds}, fails {fails}");
    assert!(held > 0, "no case challenges the machine");
    assert!(holds > 0, "the oracle holds no case");
    assert!(fails > 0, "the oracle holds every case");
    // the oracle acts no later than the late oracle: where it surges, so does the late one
    for x in &c.cases {
        if x.class == Feasibility::Infeasible {
            assert!(x.late_oracle.surge_cycles > 0, "case {}", x.case);
        }
    }
}

/// Fail with every failing case listed, one per line.
fn assert_none(what: &str, failures: &[String]) {
    assert!(
        failures.is_empty(),
        "{} {what}:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

/// The failures of one safety line over the reduced campaign, each with its rerun command.
fn safety_failures(line: impl Fn(&CaseResult) -> Option<String>) -> Vec<String> {
    let c = reduced();
    c.cases
        .iter()
        .filter_map(|r| line(r).map(|what| case_line(c, r, &what)))
        .collect()
}

/// Safety line of issue 22 on the reduced campaign: in every case recycle-pi has no more
/// surge cycles than baseline-pi on the same skid, disturbance and noise.
#[test]
fn recycle_pi_never_surges_more_than_baseline_pi() {
    let failures = safety_failures(|r| {
        let (rp, bp) = (r.recycle_pi.surge_cycles, r.baseline_pi.surge_cycles);
        (rp > bp).then(|| format!("{rp} surge cycles, more than baseline-pi's {bp}"))
    });
    assert_none("safety-line failures", &failures);
}

/// Safety line of issue 22 on the reduced campaign: recycle-pi has zero surge cycles in every
/// case the late oracle holds. Every failing case is listed with the command that reruns it.
#[test]
fn recycle_pi_holds_every_case_the_late_oracle_holds() {
    let failures = safety_failures(|r| {
        let rp = r.recycle_pi.surge_cycles;
        (r.class == Feasibility::FeasibleWithMargin && rp > 0)
            .then(|| format!("{rp} surge cycles where the late oracle holds"))
    });
    assert_none("safety-line failures", &failures);
}

/// Tolerance on the closest approach between the same case at 50 Hz and at 1 kHz, fraction of
/// surge-line flow: half the default control-line margin (10 %). A difference below it does
/// not decide whether the margin the control line keeps suffices; a larger one means the loop
/// rate, not the machine, decides how close the machine comes.
const SAME_OUTCOME_TOLERANCE: f64 = 0.5 * cmp::DEFAULT_MARGIN_PCT / 100.0;

/// Every reduced case the oracle holds, at 50 Hz and at 1 kHz: (case, run at 50 Hz, run at
/// 1 kHz).
fn at_50_hz_and_1_khz() -> Vec<(&'static CaseResult, RunResult, RunResult)> {
    let c = reduced();
    let b = bases();
    c.cases
        .iter()
        .filter(|r| r.class != Feasibility::Infeasible)
        .map(|r| {
            let mut s = skid::draw_skid(&b, c.seed, r.case).expect("skid");
            let mut at = |hz: f64| {
                s.params.rate_hz = hz;
                runner::run(&s, Controller::Law(LawId::RecyclePi), c.margin_pct).expect("run")
            };
            let slow = at(50.0);
            let fast = at(1000.0);
            (r, slow, fast)
        })
        .collect()
}

fn rate_line(slow: &RunResult, fast: &RunResult) -> String {
    format!(
        "50 Hz: {} surge cycles, closest {:+.1} %; 1 kHz: {} surge cycles, closest {:+.1} %",
        slow.surge_cycles,
        100.0 * slow.min_margin,
        fast.surge_cycles,
        100.0 * fast.min_margin
    )
}

/// The same case at 50 Hz and at 1 kHz gives recycle-pi the same protection outcome: it
/// surges at both rates or at neither (no parameter hides a cycle count). The cases: every
/// reduced case the oracle holds (an infeasible case surges whatever the rate).
#[test]
fn the_same_case_at_50_hz_and_1_khz_surges_at_both_rates_or_at_neither() {
    let c = reduced();
    let failures: Vec<String> = at_50_hz_and_1_khz()
        .iter()
        .filter(|(_, slow, fast)| (slow.surge_cycles > 0) != (fast.surge_cycles > 0))
        .map(|(r, slow, fast)| {
            format!(
                "{} (rerun: antisurge campaign --case {} --rate-hz 50, --rate-hz 1000)",
                case_line(c, r, &rate_line(slow, fast)),
                r.case
            )
        })
        .collect();
    assert_none("cases differ between 50 Hz and 1 kHz", &failures);
}

/// Where the case surges at neither rate, its closest approach differs by less than
/// [`SAME_OUTCOME_TOLERANCE`] between 50 Hz and 1 kHz, counted up to the control line: a point
/// that stays right of the control line at both rates was protected alike, however far right
/// (a faster loop that opens the valve later by a few milliseconds keeps less of a distance it
/// did not need: cases 7 and 9 came to +31 % and +33 % at 50 Hz, +19 % and +18 % at 1 kHz).
#[test]
fn the_same_case_at_50_hz_and_1_khz_comes_equally_close() {
    let c = reduced();
    let line = c.margin_pct / 100.0;
    let failures: Vec<String> = at_50_hz_and_1_khz()
        .iter()
        .filter(|(_, slow, fast)| {
            slow.surge_cycles == 0
                && fast.surge_cycles == 0
                && (slow.min_margin.min(line) - fast.min_margin.min(line)).abs()
                    >= SAME_OUTCOME_TOLERANCE
        })
        .map(|(r, slow, fast)| case_line(c, r, &rate_line(slow, fast)))
        .collect();
    assert_none("cases differ between 50 Hz and 1 kHz", &failures);
}

/// docs/benchmarks.md's campaign block is the output of `antisurge campaign --reduced --readme`.
#[test]
fn readme_campaign_is_the_output_of_antisurge_campaign_reduced() {
    let readme = std::fs::read_to_string(common::root().join("docs/benchmarks.md"))
        .expect("docs/benchmarks.md");
    let begin = "<!-- campaign:begin -->\n";
    let end = "<!-- campaign:end -->\n";
    let start = readme
        .find(begin)
        .expect("docs/benchmarks.md lacks <!-- campaign:begin -->");
    let stop = readme[start..]
        .find(end)
        .expect("docs/benchmarks.md lacks <!-- campaign:end -->")
        + start
        + end.len();
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(["campaign", "--reduced", "--readme", "--threads", "2"])
        .arg("--config-dir")
        .arg(common::root().join("config"))
        .output()
        .expect("run antisurge campaign");
    assert!(
        out.status.success(),
        "campaign failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let fresh = String::from_utf8(out.stdout).expect("utf-8");
    assert_eq!(
        &readme[start..stop],
        fresh,
        "docs/benchmarks.md's campaign block differs from `antisurge campaign --reduced --readme`: rerun it and paste its output over the block"
    );
    // and the binary's table is the library's on the same campaign
    assert!(fresh.contains(&antisurge::campaign::report::markdown(reduced())));
}

/// `--case K --json` reruns one case and writes it as JSON.
#[test]
fn one_case_reruns_and_writes_json() {
    let dir = tempfile::tempdir().expect("tempdir");
    let json = dir.path().join("case.json");
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(["campaign", "--case", "5", "--json"])
        .arg(&json)
        .arg("--config-dir")
        .arg(common::root().join("config"))
        .output()
        .expect("run antisurge campaign");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("parse");
    let cases = v["cases"].as_array().expect("cases");
    assert_eq!(cases.len(), 1);
    assert_eq!(cases[0]["case"], 5);
    // the rerun is the campaign's case 5
    let r = &reduced().cases[5];
    assert_eq!(
        cases[0]["recycle_pi"]["surge_cycles"].as_u64(),
        Some(u64::from(r.recycle_pi.surge_cycles))
    );
    let text = String::from_utf8(out.stdout).expect("utf-8");
    assert!(text.contains("case 5"), "{text}");
}

/// The energy from the disturbance on is the part of the run's recycle energy the
/// simulator sums from the disturbance's instant: positive, and less than the whole run's
/// wherever the valve returned gas before the disturbance (every law starts from the skid's
/// initial opening); the trips are counted for the laws only.
#[test]
fn the_energy_from_the_disturbance_on_is_part_of_the_runs() {
    for c in &reduced().cases {
        for (name, r) in [
            ("recycle-pi", &c.recycle_pi),
            ("baseline-pi", &c.baseline_pi),
        ] {
            let (all, from) = (r.recycle_energy_j, r.recycle_energy_from_event_j);
            assert!(
                from >= 0.0 && from <= all,
                "case {} {name}: {from} J from the disturbance of {all} J",
                c.case
            );
            if r.opening_at_event > 0.01 {
                assert!(from < all, "case {} {name}: no energy before it", c.case);
            }
        }
        assert_eq!(
            c.baseline_pi.recycle_trips, 0,
            "case {}: baseline-pi has no trip",
            c.case
        );
        assert_eq!(c.oracle.recycle_trips, 0, "case {}", c.case);
    }
    // the reduced campaign has recycle trips
    assert!(reduced()
        .cases
        .iter()
        .any(|c| c.recycle_pi.recycle_trips > 0));
}

/// The oracle's open command reaches the valve when the runner says: issued one latency and
/// one sample period after the disturbance (two periods more for the late oracle), delivered
/// one latency plus the valve's dead time later; the valve does not move before.
#[test]
fn the_oracle_moves_the_valve_one_latency_period_latency_and_dead_time_after_the_disturbance() {
    let b = bases();
    for k in [0, 5, 10, 15] {
        let s = skid::draw_skid(&b, cmp::DEFAULT_SEED, k).expect("skid");
        let p = &s.params;
        for late in [0, runner::LATE_ORACLE_PERIODS] {
            let c = Controller::Oracle { late_periods: late };
            let (_, sim) = runner::run_traced(&s, c, 10.0, skid::PLANT_STEP_S).expect("run");
            let dt = skid::PLANT_STEP_S;
            let period = (1.0 / p.rate_hz / dt).round() * dt;
            let issue = ((skid::EVENT_AT_S + p.latency_s + period * (1.0 + f64::from(late))) / dt
                - 1e-9)
                .ceil()
                * dt;
            let arrive =
                issue + (p.latency_s / dt).round() * dt + (p.valve_dead_time_s / dt).round() * dt;
            let x0 = sim.trace[0].recycle_valve_position;
            let moved = sim
                .trace
                .iter()
                .find(|r| r.recycle_valve_position > x0 + 1e-9)
                .map(|r| r.t_s)
                .expect("the valve opens");
            assert!(
                moved > arrive - 1e-9 && moved <= arrive + 2.0 * dt + 1e-9,
                "case {k}, late {late}: valve moved at {moved} s, command due at {arrive} s"
            );
        }
    }
}

/// The oracles and the held valve start where the laws held the valve when the disturbance
/// came (the larger of the openings of the laws that had not surged before it), not at the
/// skid's drawn initial opening (15-30 % margin): the valve sits there until the oracle's
/// command arrives.
#[test]
fn the_oracle_starts_on_the_control_line_the_laws_held() {
    let b = bases();
    let mut moved_start = 0;
    for k in [0, 5, 10, 13, 16, 22] {
        let s = skid::draw_skid(&b, cmp::DEFAULT_SEED, k).expect("skid");
        let rp = runner::run(&s, Controller::Law(LawId::RecyclePi), 10.0).expect("recycle-pi");
        let bp = runner::run(&s, Controller::Law(LawId::BaselinePi), 10.0).expect("baseline-pi");
        let settled: Vec<f64> = [&rp, &bp]
            .iter()
            .filter(|r| !r.reversed_before_event)
            .map(|r| r.opening_at_event)
            .collect();
        let opening = if settled.is_empty() {
            rp.opening_at_event.max(bp.opening_at_event)
        } else {
            settled.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        };
        assert!(opening.is_finite(), "case {k}");
        let c = Controller::Oracle { late_periods: 0 };
        let on = cmp::skid_for(c, &s, [&rp, &bp]);
        let (_, sim) = runner::run_traced(&on, c, 10.0, skid::PLANT_STEP_S).expect("oracle");
        let before = sim
            .trace
            .iter()
            .rev()
            .find(|r| r.t_s < skid::EVENT_AT_S)
            .expect("a row before the disturbance");
        assert!(
            (before.recycle_valve_position - opening).abs() < 1e-3,
            "case {k}: valve {} before the disturbance, the laws held {opening}",
            before.recycle_valve_position
        );
        if (s.plant.file.initial.recycle_valve - opening).abs() > 1e-3 {
            moved_start += 1;
        }
    }
    // (the drawn initial opening differs from the control line's in these cases)
    assert!(moved_start > 0, "every case started on its initial opening");
}

/// A law that surged before the disturbance was recovering from its own surge when it came,
/// its valve wide open: the oracle does not start from its opening. Case 84 of the campaign:
/// baseline-pi surges at 3.1 s and holds ≈ 0.75 at 5 s; recycle-pi holds ≈ 0.09 on the line.
#[test]
fn a_law_that_surged_before_the_disturbance_does_not_set_the_oracles_start() {
    let b = bases();
    let s = skid::draw_skid(&b, cmp::DEFAULT_SEED, 84).expect("skid");
    let rp = runner::run(&s, Controller::Law(LawId::RecyclePi), 10.0).expect("recycle-pi");
    let bp = runner::run(&s, Controller::Law(LawId::BaselinePi), 10.0).expect("baseline-pi");
    assert!(
        bp.reversed_before_event && !rp.reversed_before_event,
        "the case no longer shows it: baseline-pi reversed {}, recycle-pi {}",
        bp.reversed_before_event,
        rp.reversed_before_event
    );
    assert!(bp.opening_at_event > rp.opening_at_event + 0.2);
    let on = cmp::on_the_control_line(&s, [&rp, &bp]);
    assert!(
        (on.plant.file.initial.recycle_valve - rp.opening_at_event).abs() < 1e-12,
        "the oracle starts at {}, recycle-pi held {}",
        on.plant.file.initial.recycle_valve,
        rp.opening_at_event
    );
    // both surged before it: the larger opening, as before
    let mut rp2 = rp;
    rp2.reversed_before_event = true;
    let on2 = cmp::on_the_control_line(&s, [&rp2, &bp]);
    assert_eq!(
        on2.plant.file.initial.recycle_valve,
        bp.opening_at_event.clamp(0.0, 1.0)
    );
}
