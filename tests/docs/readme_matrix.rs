//! docs/benchmarks.md's control benchmark section is the output of `antisurge bench-matrix`, and the
//! safety lines of the matrix hold (zero surge cycles where the valve can do it).

use crate::common;

use antisurge::control::LawId;
use antisurge::sim::bench::{self, CaseResult};
use antisurge::sim::case::PlantCase;
use std::process::Command;

#[test]
fn readme_matrix_is_the_output_of_antisurge_bench_matrix() {
    let readme = std::fs::read_to_string(common::root().join("docs/benchmarks.md"))
        .expect("docs/benchmarks.md");
    let begin = "<!-- matrix:begin -->\n";
    let end = "<!-- matrix:end -->";
    let start = readme
        .find(begin)
        .expect("docs/benchmarks.md lacks <!-- matrix:begin -->")
        + begin.len();
    let stop = readme[start..]
        .find(end)
        .expect("docs/benchmarks.md lacks <!-- matrix:end -->")
        + start;
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .arg("bench-matrix")
        .arg("--config-dir")
        .arg(common::root().join("config"))
        .output()
        .expect("run antisurge bench-matrix");
    assert!(
        out.status.success(),
        "bench-matrix failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let fresh = String::from_utf8(out.stdout).expect("utf-8");
    assert_eq!(
        &readme[start..stop],
        fresh,
        "docs/benchmarks.md's matrix differs from `antisurge bench-matrix`: rerun it and paste its output between the markers"
    );
}

fn matrix() -> Vec<CaseResult> {
    let cfg = common::root().join("config");
    let plants: Vec<PlantCase> = ["kvangardsnes2009_recycle", "hemchi2016_recycle"]
        .iter()
        .map(|s| PlantCase::load(&cfg.join("plants").join(format!("{s}.toml"))).expect("plant"))
        .collect();
    bench::run_matrix(&plants, &cfg, 2).expect("matrix")
}

#[test]
fn recycle_pi_with_defaults_holds_the_matrix_without_surge() {
    let rows = matrix();
    let mut failures = Vec::new();
    // the Δp cross-check: a Δp frozen for 1 s during the closure is found within 300 ms under
    // either law, and nothing else in the matrix looks frozen to it
    for r in &rows {
        if r.case.contains("Δp frozen") {
            assert!(
                r.dp_frozen_found_after_s < 0.3,
                "frozen Δp found after {} s: {r:?}",
                r.dp_frozen_found_after_s
            );
        } else {
            assert_eq!(r.dp_frozen_found, 0, "false frozen-Δp find: {r:?}");
        }
        // the drift check: nothing but the drifting Δp looks drifting to it
        if !r.case.contains("Δp drift") {
            assert_eq!(r.dp_drift_found, 0, "false drift find: {r:?}");
        }
    }
    // a +30 % of span Δp bias is found on both plants under either law, and in time for
    // recycle-pi (zero surge, checked below; baseline-pi closes slower, so later)
    for r in rows.iter().filter(|r| r.case.contains("Δp drift")) {
        let bound = if r.law == LawId::RecyclePi { 0.1 } else { 0.5 };
        assert!(r.dp_drift_found_after_s < bound, "{r:?}");
    }
    for r in rows.iter().filter(|r| r.law == LawId::RecyclePi) {
        // kvangardsnes2009's 2 s valve cannot hold the ESD (the table says so and names the
        // stroke that does at 10 %, checked below)
        let known_valve_limit = r.plant == "kvangardsnes2009" && r.case == "ESD rundown";
        // (kvangardsnes2009's throttle step at 5 % holds since the onset trip fires 4 ms after
        // the step, and its Δp bias since the drift check finds it within 0.1 s: both guarded)
        if r.surge_cycles > 0 && !known_valve_limit {
            failures.push(format!(
                "{} {} at {} %: {} cycles",
                r.plant, r.case, r.margin_pct, r.surge_cycles
            ));
        }
        // no fail-safe on blips; a resume is bumpless from the measured valve position
        if r.case.contains("blips") {
            assert_eq!(r.failsafe_entries, 0, "{r:?}");
        }
        assert!(r.resume_step < 0.02, "{r:?}");
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

// The ESD stroke verdicts and the plant variants they name: tests/control/esd_stroke_check.rs.
