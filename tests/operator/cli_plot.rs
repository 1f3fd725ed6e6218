//! `antisurge plot TRACE.csv` draws the map and the time series of a trace written by another
//! command (here `sim`'s trace.csv, the same columns `run --out`, `plant` and HIL write), and
//! refuses a file that is not a trace.

use std::process::Command;

#[test]
fn plots_a_trace_from_another_run_and_refuses_a_non_trace() {
    let tmp = tempfile::tempdir().expect("tmp");
    let sim = tmp.path().join("sim");
    let st = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(["sim", "--scenario", "throttle_step", "--no-plots", "--out"])
        .arg(&sim)
        .status()
        .expect("sim");
    assert!(st.success());
    let pics = tmp.path().join("pics");
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .arg("plot")
        .arg(sim.join("trace.csv"))
        .arg("--out")
        .arg(&pics)
        .output()
        .expect("plot");
    assert!(out.status.success(), "{out:?}");
    for f in ["map.svg", "timeseries.svg"] {
        let svg = std::fs::read_to_string(pics.join(f)).expect(f);
        assert!(svg.contains("<svg") && svg.contains("<polyline"), "{f}");
    }
    let bad = tmp.path().join("bad.csv");
    std::fs::write(&bad, "a,b\n1,2\n").expect("write");
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .arg("plot")
        .arg(&bad)
        .output()
        .expect("plot");
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("not a trace"),
        "{out:?}"
    );
}
