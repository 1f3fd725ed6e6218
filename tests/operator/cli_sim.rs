//! `antisurge sim` end to end through the binary: outputs, and errors that name file, key and
//! line with a non-zero exit.

use crate::common;

use std::process::Command;

fn antisurge() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_antisurge"));
    c.current_dir(common::root());
    c
}

#[test]
fn sim_writes_trace_summary_and_says_where() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = antisurge()
        .args([
            "sim",
            "--plant",
            "liaw2004",
            "--scenario",
            "throttle-closure",
            "--law",
            "none",
            "--out",
        ])
        .arg(dir.path())
        .output()
        .expect("run");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("SURGE"), "{stdout}");
    assert!(
        stdout.contains(&dir.path().display().to_string()),
        "{stdout}"
    );
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("summary.json")).expect("summary"))
            .expect("json");
    for key in [
        "plant",
        "scenario",
        "law",
        "duration_s",
        "stable",
        "flow_reversal",
        "surge_cycles",
        "surge_frequency_hz",
        "min_flow_kg_s",
        "min_surge_margin",
        "settle_time_s",
        "actuator_peaks",
    ] {
        assert!(summary.get(key).is_some(), "summary.json lacks `{key}`");
    }
    assert_eq!(summary["plant"], "liaw2004");
    assert_eq!(summary["stable"], false);
    let trace = std::fs::read_to_string(dir.path().join("trace.csv")).expect("trace");
    let header = trace.lines().next().expect("header");
    for col in [
        "t_s",
        "m_kg_s",
        "p_discharge_pa",
        "meas_orifice_dp_pa",
        "est_m_kg_s",
        "cmd_drive_torque_nm",
    ] {
        assert!(header.split(',').any(|c| c == col), "trace lacks {col}");
    }
    // 20 s at 5 ms + header
    assert_eq!(trace.lines().count(), 4002);
}

#[test]
fn unknown_plant_lists_the_available_ones() {
    let out = antisurge()
        .args(["sim", "--plant", "nosuchplant"])
        .output()
        .expect("run");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("unknown plant `nosuchplant`"), "{err}");
    assert!(err.contains("kvangardsnes2009_recycle"), "{err}");
}

#[test]
fn unknown_law_is_rejected_with_the_list() {
    let out = antisurge()
        .args(["sim", "--law", "magic"])
        .output()
        .expect("run");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("unknown law `magic`") && err.contains("none"),
        "{err}"
    );
}

#[test]
fn malformed_scenario_names_file_and_line() {
    let dir = tempfile::tempdir().expect("tmp");
    let path = dir.path().join("broken.toml");
    std::fs::write(
        &path,
        "name = \"b\"\ndescription = \"d\"\nduration_s = 10\n[[event]\nat_s = 1\n",
    )
    .expect("write");
    let out = antisurge()
        .args(["sim", "--scenario"])
        .arg(&path)
        .output()
        .expect("run");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&format!("{}:4:", path.display())), "{err}");
    assert!(err.contains("syntax"), "{err}");
}

#[test]
fn unknown_key_in_a_plant_file_names_key_and_line() {
    let dir = tempfile::tempdir().expect("tmp");
    let text =
        std::fs::read_to_string(common::root().join("config/plants/bohagen2007_plenum.toml"))
            .expect("plant")
            .replace("plenum_volume_m3 = 1.5", "plenum_volume_m = 1.5");
    let line = text
        .lines()
        .position(|l| l.starts_with("plenum_volume_m ="))
        .expect("line")
        + 1;
    let path = dir.path().join("typo.toml");
    std::fs::write(&path, text).expect("write");
    let out = antisurge()
        .args(["sim", "--plant"])
        .arg(&path)
        .output()
        .expect("run");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&format!("{}:{line}:", path.display())),
        "{err}"
    );
    assert!(err.contains("unknown field `plenum_volume_m`"), "{err}");
    assert!(
        err.contains("plenum_volume_m3"),
        "the expected keys are listed: {err}"
    );
}

#[test]
fn negative_volume_names_the_key() {
    let dir = tempfile::tempdir().expect("tmp");
    let text =
        std::fs::read_to_string(common::root().join("config/plants/bohagen2007_plenum.toml"))
            .expect("plant")
            .replace("plenum_volume_m3 = 1.5", "plenum_volume_m3 = -1.5");
    let path = dir.path().join("neg.toml");
    std::fs::write(&path, text).expect("write");
    let out = antisurge()
        .args(["sim", "--plant"])
        .arg(&path)
        .output()
        .expect("run");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("plenum_duct.plenum_volume_m3") && err.contains("positive"),
        "{err}"
    );
}
