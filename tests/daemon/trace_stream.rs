//! The streamed trace of `antisurge sim` (issue 25: memory bounded by streaming): the bytes of
//! `trace.csv` are those the whole-trace writer writes (through the library, compared row by row
//! with the trace kept in memory) and a golden file (first written by the binary of commit
//! 1ec4728, which kept the whole trace in memory; rewritten by the streaming binary when
//! recycle-pi's throttle watch changed this run's trajectory, issue 22: the library test below
//! still holds the streamed bytes equal to the whole-trace writer's), and the summary is the
//! one of the run kept in memory.

use crate::common;

use antisurge::control::LawId;
use antisurge::scenario::Scenario;
use antisurge::sim::{self, SimOptions};
use std::path::PathBuf;
use std::process::Command;

fn fixture(name: &str) -> PathBuf {
    common::root()
        .join("tests/fixtures/trace_stream")
        .join(name)
}

fn golden() -> Vec<u8> {
    std::fs::read(fixture("trace.csv")).expect("golden trace")
}

fn options() -> SimOptions {
    SimOptions {
        law: LawId::RecyclePi,
        ..SimOptions::default()
    }
}

/// Rows as bits (NaN columns compare equal).
fn bits(rows: &[antisurge::sim::trace::TraceRow]) -> Vec<[u64; 33]> {
    rows.iter().map(|r| r.values().map(f64::to_bits)).collect()
}

/// The summary as JSON without the wall-clock figures.
fn comparable(s: &antisurge::sim::Summary) -> serde_json::Value {
    let mut v = serde_json::to_value(s).expect("json");
    let o = v.as_object_mut().expect("object");
    o.remove("wall_time_s");
    o.remove("realtime_factor");
    v
}

#[test]
fn streamed_trace_is_byte_identical_to_the_whole_trace_and_the_golden_file() {
    let desc = common::plant("kvangardsnes2009_recycle");
    let scenario = Scenario::load(&fixture("scenario.toml")).expect("scenario");
    let dir = tempfile::tempdir().expect("tmp");

    let (summary, trace) = sim::run_streamed(
        &desc,
        sim::control_model(&desc),
        &scenario,
        options(),
        dir.path(),
        &mut |_| {},
        &mut |_, _| {},
    )
    .expect("streamed run");
    let streamed = std::fs::read(dir.path().join("trace.csv")).expect("trace.csv");
    assert_eq!(trace.rows, 301, "3 s at 10 ms, both ends");
    assert!(trace.pictures.is_exact() && trace.pictures.len() == 301);
    assert!(
        streamed == golden(),
        "streamed trace.csv differs from the golden file"
    );
    // nothing else is left in the directory (the settle log has no name)
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .expect("dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["trace.csv"]);

    // the run kept in memory: same bytes, same summary, and the pictures' rows are its rows
    let kept = sim::run_with_model(
        &desc,
        sim::control_model(&desc),
        &scenario,
        options(),
        &mut |_| {},
        &mut |_, _| {},
    )
    .expect("kept run");
    let kept_dir = tempfile::tempdir().expect("tmp");
    sim::output::write_data(kept_dir.path(), &kept, &desc.map).expect("write");
    let whole = std::fs::read(kept_dir.path().join("trace.csv")).expect("trace.csv");
    assert!(
        whole == golden(),
        "whole-trace trace.csv differs from the golden file"
    );
    assert_eq!(comparable(&summary), comparable(&kept.summary));
    // (the run no longer settles within its 3 s since the throttle watch trips on its step
    // and the valve returns at 0.1/s: the settle figure, None, is compared above with the kept
    // run's)
    assert!(summary.settle_time_s.is_none(), "{summary:?}");
    assert_eq!(bits(trace.pictures.map_rows()), bits(&kept.trace));
    assert_eq!(bits(&trace.pictures.series_rows()), bits(&kept.trace));
}

#[test]
fn summary_of_a_streamed_surging_run_is_the_kept_runs() {
    // open loop into surge: the verdict, surge cycles and closest approach come from running
    // statistics, the kept run from the whole trace
    let desc = common::plant("kvangardsnes2009_recycle");
    let scenario = common::scenario("throttle_closure");
    let dir = tempfile::tempdir().expect("tmp");
    let opts = SimOptions {
        law: LawId::None,
        ..SimOptions::default()
    };
    let (summary, _) = sim::run_streamed(
        &desc,
        sim::control_model(&desc),
        &scenario,
        opts,
        dir.path(),
        &mut |_| {},
        &mut |_, _| {},
    )
    .expect("streamed run");
    let kept = sim::run_with_model(
        &desc,
        sim::control_model(&desc),
        &scenario,
        opts,
        &mut |_| {},
        &mut |_, _| {},
    )
    .expect("kept run");
    assert!(
        !summary.stable && summary.surge_cycles > 0,
        "{}",
        summary.verdict
    );
    assert_eq!(comparable(&summary), comparable(&kept.summary));
    let kept_dir = tempfile::tempdir().expect("tmp");
    sim::output::write_data(kept_dir.path(), &kept, &desc.map).expect("write");
    let whole = std::fs::read(kept_dir.path().join("trace.csv")).expect("trace.csv");
    assert!(std::fs::read(dir.path().join("trace.csv")).expect("trace") == whole);
}

#[test]
fn the_binary_writes_the_golden_trace() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .current_dir(common::root())
        .args([
            "sim",
            "--plant",
            "kvangardsnes2009",
            "--law",
            "recycle-pi",
            "--scenario",
        ])
        .arg(fixture("scenario.toml"))
        .arg("--out")
        .arg(dir.path())
        .output()
        .expect("run");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(std::fs::read(dir.path().join("trace.csv")).expect("trace") == golden());
    for f in ["summary.json", "map.svg", "timeseries.svg"] {
        assert!(dir.path().join(f).is_file(), "{f}");
    }
}

#[test]
fn an_unwritable_output_directory_is_an_error_naming_it() {
    let dir = tempfile::tempdir().expect("tmp");
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, "not a directory").expect("write");
    let desc = common::plant("kvangardsnes2009_recycle");
    let scenario = Scenario::load(&fixture("scenario.toml")).expect("scenario");
    let e = sim::run_streamed(
        &desc,
        sim::control_model(&desc),
        &scenario,
        options(),
        &blocker.join("out"),
        &mut |_| {},
        &mut |_, _| {},
    )
    .expect_err("not a directory");
    assert!(
        e.to_string().contains(&blocker.display().to_string()),
        "{e}"
    );
}
