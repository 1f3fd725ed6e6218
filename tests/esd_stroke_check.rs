//! The machine check (`antisurge check-config`) warns when the recycle valve strokes too
//! slowly for an emergency shutdown without surge, and names the stroke time that would do
//! (issue 10); a valve fast enough gets no such warning.

mod common;

use std::process::Command;

fn check(plant: &str) -> String {
    let tmp = tempfile::tempdir().expect("tmp");
    let cfg = tmp.path().join("antisurge.toml");
    let plant = common::root()
        .join("config/plants")
        .join(format!("{plant}.toml"));
    std::fs::write(
        &cfg,
        format!(
            "[plant]\nfile = \"{}\"\n[control]\nlaw = \"recycle-pi\"\n",
            plant.display()
        ),
    )
    .expect("write");
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .arg("check-config")
        .arg(&cfg)
        .output()
        .expect("run check-config");
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "check-config failed: {err}");
    err
}

#[test]
fn a_valve_too_slow_for_an_esd_is_named_with_the_stroke_that_holds() {
    let err = check("kvangardsnes2009_recycle");
    let line = err
        .lines()
        .find(|l| l.contains("stroke_time_s"))
        .unwrap_or_else(|| panic!("no ESD stroke warning:\n{err}"));
    assert!(line.starts_with("warning: "), "{line}");
    assert!(line.contains("kvangardsnes2009_recycle.toml"), "{line}");
    assert!(
        line.contains("emergency shutdown")
            && line.contains("recycle valve's 2 s stroke is too slow"),
        "{line}"
    );
    // the stroke named is the benchmark's verdict (tests/readme_matrix.rs runs that variant)
    let p = common::plant("kvangardsnes2009_recycle");
    let sc = antisurge::bench_matrix::builtin_esd_scenario().expect("scenario");
    let v = antisurge::bench_matrix::esd_stroke(&p, &sc, 10.0)
        .expect("ESD run")
        .expect("recycle valve");
    let named = v.holding_stroke_s.expect("a stroke that holds");
    assert!(
        line.contains(&format!("a {named} s stroke holds the ESD without surge")),
        "{line}"
    );
}

#[test]
fn a_valve_fast_enough_gets_no_esd_warning() {
    let err = check("hemchi2016_recycle");
    assert!(!err.contains("stroke"), "{err}");
}
