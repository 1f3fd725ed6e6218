//! The trace of a plant stepped in real time (`antisurge run --out`, `antisurge plant`)
//! streams to `trace.csv` from a writer thread (issue 25): the same bytes as the trace the
//! plant used to keep until exit, no row dropped on a normal run, and a kill mid-run leaves the
//! rows written so far in whole lines.

use crate::common;

use antisurge::node::plant::{finish_trace, start_trace};
use antisurge::runtime::handoff::OutputBoard;
use antisurge::sim::trace::COLUMNS;
use antisurge::sim::PlantRun;
use common::daemon::*;
use common::plant_node::{drive, keep_up, node};
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

/// The trace the daemon's in-process plant wrote before it streamed (the whole trace kept,
/// written by `sim::output::write_data` at exit) and the streamed one, of the same run: the
/// same bytes, and the same summary (but for the wall-clock figures and the dropped count, 0).
#[test]
fn the_streamed_trace_is_the_bytes_of_the_kept_trace() {
    let desc = common::plant("kvangardsnes2009_recycle");
    let sc = common::scenario("throttle_closure");
    let tmp = tempfile::tempdir().expect("tmp");
    let (old_dir, new_dir) = (tmp.path().join("old"), tmp.path().join("new"));

    // the old path: the trace kept in memory, written at exit
    let outputs = Arc::new(OutputBoard::default());
    let dt = sc.file.control_period_s;
    let mut old = node(&desc, PlantRun::new(&desc, &sc).expect("run"), &outputs);
    drive(&mut old, &outputs, dt, || {});
    let old_result = old.result("recycle-pi");
    antisurge::sim::output::write_data(&old_dir, &old_result, &desc.map).expect("write");

    // the streamed path, paced so that the writer keeps up (the node itself never waits)
    let outputs = Arc::new(OutputBoard::default());
    let (handoff, writer) = start_trace(&desc, &sc, &new_dir).expect("trace");
    let run = PlantRun::handing_trace_to(&desc, &sc, handoff).expect("run");
    let mut new = node(&desc, run, &outputs);
    drive(&mut new, &outputs, dt, || keep_up(|| writer.backlog()));
    let new_result = finish_trace(&mut new, writer, "recycle-pi").expect("finish");
    antisurge::sim::output::write_summary(&new_dir, &new_result.summary).expect("summary");

    let old_csv = std::fs::read(old_dir.join("trace.csv")).expect("old");
    let new_csv = std::fs::read(new_dir.join("trace.csv")).expect("new");
    assert_eq!(
        String::from_utf8_lossy(&old_csv).lines().count(),
        4001,
        "20 s at a 5-ms trace period, and the header"
    );
    assert!(
        old_csv == new_csv,
        "the streamed trace differs from the kept one"
    );
    assert!(new_result.trace.is_empty(), "no trace kept");

    let mut a = old_result.summary.clone();
    let mut b = new_result.summary.clone();
    assert_eq!(b.trace_rows_dropped, Some(0));
    assert_eq!(a.trace_rows_dropped, None);
    for s in [&mut a, &mut b] {
        s.wall_time_s = 0.0;
        s.realtime_factor = 0.0;
        s.trace_rows_dropped = None;
    }
    assert!(a.stable && a.settle_time_s.is_some(), "{}", a.verdict);
    assert_eq!(
        serde_json::to_string(&a).expect("json"),
        serde_json::to_string(&b).expect("json")
    );
    let text = std::fs::read_to_string(new_dir.join("summary.json")).expect("summary");
    assert!(text.contains("\"trace_rows_dropped\": 0"), "{text}");
}

/// A config for `run` on the in-process recycle plant at 100 Hz running `scenario` (a file
/// written beside the config).
fn config(dir: &Path, scenario_duration_s: f64) -> String {
    std::fs::write(
        dir.join("long.toml"),
        format!(
            r#"name = "long-hold"
description = "throttle closure at 5 s, then held"
duration_s = {scenario_duration_s}
[initial]
throttle = 0.6
[[event]]
at_s = 5.0
ramp = {{ signal = "throttle", to = 0.2, over_s = 2.0 }}
"#
        ),
    )
    .expect("scenario");
    let cfg = dir.join("antisurge.toml");
    let scenario = dir.join("long.toml").display().to_string();
    std::fs::write(&cfg, embedded_config(dir, &scenario, "", "")).expect("config");
    cfg.display().to_string()
}

/// The rows of a trace.csv a reader of complete lines sees: the header, then every line
/// checked for the format (34 fields, every time a whole trace period after the last).
fn complete_rows(path: &Path) -> Vec<Vec<String>> {
    let bytes = std::fs::read(path).expect("trace.csv");
    let end = bytes.iter().rposition(|b| *b == b'\n').map_or(0, |i| i + 1);
    let text = std::str::from_utf8(&bytes[..end]).expect("utf8");
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some(COLUMNS.join(",").as_str()), "the header");
    let rows: Vec<Vec<String>> = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    for (k, r) in rows.iter().enumerate() {
        assert_eq!(r.len(), COLUMNS.len(), "row {k}: {r:?}");
        let t: f64 = r[0].parse().expect("t_s");
        assert_eq!(
            r[0],
            format!("{:.7e}", k as f64 * 0.005),
            "row {k}: t = {t}"
        );
        for v in &r[1..] {
            assert!(v.is_empty() || v.parse::<f64>().is_ok(), "row {k}: {v:?}");
        }
    }
    rows
}

/// `run --out DIR --duration-s S`: trace.csv in the format of `sim --out`, its first row's
/// plant state that of the library simulation's, no row dropped (summary and log say so).
#[test]
fn run_out_streams_the_trace_with_no_row_dropped() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let cfg = config(dir, 3600.0);
    let out = dir.join("out");
    let out_s = out.display().to_string();
    let mut ctl = spawn(
        dir,
        "run",
        &[
            "run",
            "--config",
            &cfg,
            "--duration-s",
            "4",
            "--out",
            &out_s,
        ],
    );
    let st = wait(&mut ctl, Duration::from_secs(60), "run", dir);
    assert!(st.success(), "run exit {st:?}:\n{}", logs(dir));
    let rows = complete_rows(&out.join("trace.csv"));
    let ctx = logs(dir);
    assert!(rows.len() > 100, "{} rows:\n{ctx}", rows.len());
    let s = summary(&out);
    assert_eq!(s["trace_rows_dropped"], 0, "{s:#}");
    let duration_s = s["duration_s"].as_f64().expect("duration");
    assert!(
        (duration_s - (rows.len() - 1) as f64 * 0.005).abs() < 1e-9,
        "{s:#}"
    );
    assert!(
        ctx.contains(&format!("{} trace rows written, 0 dropped", rows.len())),
        "{ctx}"
    );
    // the first row's plant state (before any command acts) is the simulation's
    let desc = common::plant("kvangardsnes2009_recycle");
    let sc = antisurge::scenario::Scenario::load(&dir.join("long.toml")).expect("scenario");
    let run = PlantRun::new(&desc, &sc).expect("run");
    let truth = run.plant().truth();
    let f = |v: f64| format!("{v:.7e}");
    for (name, v) in [
        ("m_kg_s", truth.m_kg_s),
        ("p_suction_pa", truth.p_suction_pa),
        ("p_discharge_pa", truth.p_discharge_pa),
        ("omega_rad_s", truth.omega_rad_s),
        ("recycle_valve_position", truth.recycle_valve_position),
        ("throttle_position", truth.throttle_position),
    ] {
        let i = COLUMNS.iter().position(|c| *c == name).expect("column");
        assert_eq!(rows[0][i], f(v), "{name}");
    }
}

/// kill -9 mid-run: trace.csv holds the rows written so far, every complete line a whole row,
/// and the file grew while the run went on (rows are flushed as they come, not at exit).
#[test]
fn a_killed_run_leaves_the_rows_written_so_far() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let cfg = config(dir, 3600.0);
    let out = dir.join("out");
    let out_s = out.display().to_string();
    let trace = out.join("trace.csv");
    let mut ctl = spawn(
        dir,
        "run",
        &[
            "run",
            "--config",
            &cfg,
            "--duration-s",
            "120",
            "--out",
            &out_s,
        ],
    );
    let lines = || std::fs::read(&trace).map_or(0, |b| b.iter().filter(|c| **c == b'\n').count());
    until(dir, "trace rows in trace.csv", || lines() > 200);
    let seen = lines();
    until(dir, "more trace rows in trace.csv", || lines() > seen + 200);
    let before_kill = lines();
    signal(&ctl, libc::SIGKILL);
    let st = wait(&mut ctl, Duration::from_secs(10), "run", dir);
    assert!(!st.success());
    let rows = complete_rows(&trace);
    assert!(
        rows.len() + 1 >= before_kill,
        "{} < {before_kill}",
        rows.len()
    );
    assert!(
        !out.join("summary.json").exists(),
        "no summary of a killed run"
    );
}
