//! Shared helpers for the end-to-end tests.
#![allow(dead_code)]

use antisurge::control::LawId;
use antisurge::scenario::Scenario;
use antisurge::sim::case::PlantCase;
use antisurge::sim::{SimOptions, SimResult};
use std::path::{Path, PathBuf};

/// The repository root (tests run from the package directory).
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Benchmark plants shipped in config/plants, by file stem.
pub const PLANTS: [&str; 5] = [
    "bohagen2007_plenum",
    "kvangardsnes2009_recycle",
    "hemchi2016_recycle",
    "sanadgol2006_tip",
    "liaw2004_spool",
];

/// Load a shipped plant by file stem.
pub fn plant(stem: &str) -> PlantCase {
    let p = root().join("config/plants").join(format!("{stem}.toml"));
    PlantCase::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

/// Load a shipped scenario by file stem.
pub fn scenario(stem: &str) -> Scenario {
    let p = root().join("config/scenarios").join(format!("{stem}.toml"));
    Scenario::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

/// Parse a scenario from text (for scenarios made up in a test).
pub fn scenario_text(text: &str) -> Scenario {
    let path = Path::new("inline.toml");
    let file = antisurge::config::toml_file::parse(text, path).unwrap_or_else(|e| panic!("{e}"));
    Scenario::from_file(file, path, text).unwrap_or_else(|e| panic!("{e}"))
}

/// The long-hold scenario of the memory tests: transmitter noise from the start, the
/// throttle closed 60 % -> 20 % over 2 s at 5 s, then held for `duration_s`.
pub fn long_hold_scenario(duration_s: f64) -> Scenario {
    scenario_text(&format!(
        r#"
name = "long-hold"
description = "throttle closure at 5 s, then held"
duration_s = {duration_s}
[initial]
throttle = 0.6
[[event]]
at_s = 0.0
noise = {{ sensors = ["p_discharge", "p_suction"], amplitude = 2000.0, distribution = "uniform" }}
[[event]]
at_s = 5.0
ramp = {{ signal = "throttle", to = 0.2, over_s = 2.0 }}
"#
    ))
}

/// Run a scenario through the same code path as `antisurge sim`.
pub fn simulate(plant: &PlantCase, scenario: &Scenario, law: LawId) -> SimResult {
    simulate_with(plant, scenario, law, &mut |_, _| {})
}

/// [`simulate`], calling `before_cycle(t_s, core)` before every control cycle (a hot reload
/// or a law switch at an exact time).
pub fn simulate_with(
    plant: &PlantCase,
    scenario: &Scenario,
    law: LawId,
    before_cycle: &mut dyn FnMut(f64, &mut antisurge::control::core::ControlCore),
) -> SimResult {
    antisurge::sim::run_with(
        plant,
        scenario,
        SimOptions {
            law,
            ..SimOptions::default()
        },
        &mut |_| {},
        before_cycle,
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

pub mod campaign;
pub mod counting_alloc;
pub mod daemon;
pub mod faults;
pub mod modbus_skid;
pub mod node;
pub mod plant_node;

/// Mean of one trace column over the rows from `t0_s` on (a settled tail), NaN if none.
pub fn mean_from(
    trace: &[antisurge::sim::trace::TraceRow],
    t0_s: f64,
    column: impl Fn(&antisurge::sim::trace::TraceRow) -> f64,
) -> f64 {
    let (sum, n) = trace
        .iter()
        .filter(|row| row.t_s >= t0_s)
        .fold((0.0, 0usize), |(s, n), row| (s + column(row), n + 1));
    if n == 0 {
        f64::NAN
    } else {
        sum / n as f64
    }
}

/// The name libtest gives test `f` of the module `module` (its `module_path!()`): a test
/// binary that groups several test files as modules names it `<file>::f` (the crate's own
/// name is not part of it); at a crate's root it is `f`. For tests that re-run their own
/// binary with `--exact`.
pub fn own_test_name(module: &str, f: &str) -> String {
    match module.split_once("::") {
        Some((_, m)) => format!("{m}::{f}"),
        None => f.to_string(),
    }
}
