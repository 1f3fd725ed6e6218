//! The Δp drift/bias cross-check (`src/control/drift_check.rs`) on the recycle plants, end to
//! end through the benchmark matrix's field model: a +30 %-of-span Δp bias is found before a
//! law acting on it closes the machine into surge, and nothing else looks drifting to it — not
//! the matrix's other cases on a compressor map that is slightly wrong (the controller is not
//! told the machine exactly), nor pressure and Δp noise with other seeds.

use crate::common;

use antisurge::control::LawId;
use antisurge::scenario::Scenario;
use antisurge::sim::bench::{self, Case, FieldFault, CASES};
use antisurge::sim::case::PlantCase;

const PLANTS: [&str; 2] = ["kvangardsnes2009_recycle", "hemchi2016_recycle"];

fn scenario_of(case: &Case) -> Scenario {
    common::scenario(&case.scenario.replace('-', "_"))
}

fn drift_case() -> &'static Case {
    CASES
        .iter()
        .find(|c| matches!(c.fault, FieldFault::DpDrift { .. }))
        .expect("the matrix has a Δp drift case")
}

#[test]
fn a_step_bias_is_found_within_100_ms_and_recycle_pi_holds_the_line() {
    let case = drift_case();
    let sc = scenario_of(case);
    for stem in PLANTS {
        let p = common::plant(stem);
        for margin in bench::MARGINS_PCT {
            let r = bench::run_case(&p, &sc, case, LawId::RecyclePi, margin).unwrap();
            // found once, early: the bias is fully there 30 ms after its start, and a law
            // acting on it closes kvangardsnes2009 into surge ≈ 150 ms after the start
            assert_eq!(r.dp_drift_found, 1, "{r:?}");
            assert!(r.dp_drift_found_after_s < 0.1, "{stem} @ {margin} %: {r:?}");
            // and the fallback (the lower of the observer's and the transmitter's flow) holds
            // the machine right of its surge line during and after the event
            assert_eq!(r.surge_cycles, 0, "{stem} @ {margin} %: {r:?}");
            assert!(r.min_margin_during > 0.0, "{stem} @ {margin} %: {r:?}");
            assert!(r.min_margin_after > 0.0, "{stem} @ {margin} %: {r:?}");
        }
    }
}

/// The controller's map off by up to the declared `map_uncertainty_pct` (3 %) in flow or in
/// pressure rise: none of the matrix's other cases fires the check, and the bias is still found
/// (later where a map that under-states the rise puts kvangardsnes2009's control line at or
/// above the speed line's peak: the speed-line flow is not defined there until the law has
/// moved the machine; ≈ 0.42 s, one surge cycle, README).
#[test]
#[ignore = "regression of the recycle-pi rebuild, not yet fixed: with kvangardsnes2009's map 3 % low in pressure rise the Δp drift is found after 1.57 s (bound 0.5 s) and the case surges once"]
fn a_slightly_wrong_map_fires_no_false_find() {
    let offs = [(1.03, 1.0), (0.97, 1.0), (1.0, 1.03), (1.0, 0.97)];
    let mut false_finds = Vec::new();
    let mut missed = Vec::new();
    for stem in PLANTS {
        let p: PlantCase = common::plant(stem);
        let truth = antisurge::sim::control_model(&p);
        for (flow, rise) in offs {
            let model = bench::map_off(&truth, flow, rise);
            assert_ne!(model.map, truth.map, "map_off changed nothing on {stem}");
            for case in CASES.iter() {
                let sc = scenario_of(case);
                let r = bench::run_case_with_model(
                    &p,
                    &sc,
                    case,
                    LawId::RecyclePi,
                    10.0,
                    model.clone(),
                )
                .unwrap();
                let what = format!("{stem} map ×{flow} flow ×{rise} rise, {}", case.name);
                if matches!(case.fault, FieldFault::DpDrift { .. }) {
                    if r.dp_drift_found_after_s.is_nan() || r.dp_drift_found_after_s >= 0.5 {
                        missed.push(format!("{what}: {r:?}"));
                    }
                } else if r.dp_drift_found != 0 {
                    false_finds.push(format!("{what}: {} finds", r.dp_drift_found));
                }
            }
        }
    }
    assert!(false_finds.is_empty(), "{false_finds:#?}");
    assert!(missed.is_empty(), "{missed:#?}");
}

#[test]
fn noise_with_other_seeds_fires_no_false_find() {
    for stem in PLANTS {
        let p = common::plant(stem);
        for seed in [1u64, 7, 424242] {
            let case = Case {
                name: "closure + noise",
                scenario: "throttle-closure",
                fault: FieldFault::Noise { seed },
            };
            let sc = scenario_of(&case);
            for law in bench::LAWS {
                for margin in bench::MARGINS_PCT {
                    let r = bench::run_case(&p, &sc, &case, law, margin).unwrap();
                    assert_eq!(
                        r.dp_drift_found, 0,
                        "{stem} seed {seed} {law:?} @ {margin} %: {r:?}"
                    );
                }
            }
        }
    }
}
