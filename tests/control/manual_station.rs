//! The manual station keeps its protection: with the operator's output low, a throttle step
//! still fires the recycle trip; an output above what protection needs is applied as set;
//! transfer auto → manual → auto is bumpless.

use crate::common;

use antisurge::control::LawId;
use common::{plant, scenario_text, simulate};

fn run(manual_output: f64) -> antisurge::sim::SimResult {
    let text = format!(
        r#"name = "manual-throttle-step"
description = "manual at 2 s (output {manual_output}), throttle step 60 % -> 20 % at 5 s, auto at 12 s"
duration_s = 16.0
[initial]
throttle = 0.6
[[event]]
at_s = 2.0
mode = "manual"
[[event]]
at_s = 2.5
step = {{ signal = "recycle_manual", to = {manual_output} }}
[[event]]
at_s = 5.0
step = {{ signal = "throttle", to = 0.2 }}
[[event]]
at_s = 12.0
mode = "auto"
"#
    );
    simulate(
        &plant("kvangardsnes2009_recycle"),
        &scenario_text(&text),
        LawId::RecyclePi,
    )
}

fn largest_step(r: &antisurge::sim::SimResult, from_s: f64, to_s: f64) -> f64 {
    r.trace
        .windows(2)
        .filter(|w| w[0].t_s >= from_s && w[1].t_s <= to_s)
        .map(|w| (w[1].cmd_recycle_valve - w[0].cmd_recycle_valve).abs())
        .fold(0.0, f64::max)
}

#[test]
fn low_manual_output_still_trips_on_a_throttle_step() {
    let r = run(0.0);
    assert!(
        r.summary.law_events.recycle_trips >= 1,
        "no recycle trip in manual: {:?}",
        r.summary.law_events
    );
    assert_eq!(r.summary.surge_cycles, 0, "surged in manual");
    // in manual (mode code 1) during the step, the valve opened beyond the manual 0 %
    let opened = r
        .trace
        .iter()
        .filter(|row| row.t_s > 5.0 && row.t_s < 7.0 && row.mode == 1.0)
        .map(|row| row.cmd_recycle_valve)
        .fold(0.0, f64::max);
    assert!(opened > 0.3, "protection opened only to {opened}");
    // bumpless: switching to manual and back to auto moves the output by less than 1 %
    assert!(
        largest_step(&r, 1.9, 2.2) < 0.01,
        "{}",
        largest_step(&r, 1.9, 2.2)
    );
    assert!(
        largest_step(&r, 11.9, 12.2) < 0.01,
        "{}",
        largest_step(&r, 11.9, 12.2)
    );
}

#[test]
fn a_manual_output_above_the_protection_is_applied() {
    let r = run(0.6);
    let at = |t: f64| {
        r.trace
            .iter()
            .find(|row| row.t_s >= t)
            .map(|row| row.cmd_recycle_valve)
            .expect("row")
    };
    assert!((at(4.5) - 0.6).abs() < 1e-9, "{}", at(4.5));
    assert!((at(10.0) - 0.6).abs() < 0.05, "{}", at(10.0));
}
