//! The black box: a daemon run (in-process plant, throttle closure) is recorded, and the
//! recording replayed through the control core reproduces every command bit for bit; with a
//! changed gain the replay shows different commands.

mod common;

use antisurge::blackbox::{self, replay};
use antisurge::daemon::config;
use common::daemon::{shipped, spawn, wait};
use std::time::Duration;

#[test]
fn a_recorded_daemon_run_replays_with_identical_commands() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let events = dir.join("events.jsonl");
    let cfg = dir.join("antisurge.toml");
    std::fs::write(
        &cfg,
        format!(
            r#"[plant]
file = "{plant}"
[control]
law = "recycle-pi"
[cycle]
rate_hz = 1000.0
lock_memory = false
[event_log]
path = "{events}"
[simulation]
scenario = "throttle-closure"
"#,
            plant = shipped("plants/kvangardsnes2009_recycle.toml"),
            events = events.display(),
        ),
    )
    .expect("write config");
    let out = dir.join("plant");
    let mut ctl = spawn(
        dir,
        "run",
        &[
            "run",
            "--config",
            &cfg.display().to_string(),
            "--duration-s",
            "8",
            "--out",
            &out.display().to_string(),
        ],
    );
    let status = wait(&mut ctl, Duration::from_secs(60), "antisurge run", dir);
    assert!(status.success(), "{}", common::daemon::logs(dir));
    let bb_dir = dir.join("blackbox");
    let exit_file = std::fs::read_dir(&bb_dir)
        .unwrap_or_else(|e| panic!("{}: {e}\n{}", bb_dir.display(), common::daemon::logs(dir)))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.to_string_lossy().contains("blackbox-exit-"))
        .expect("an exit dump");
    let rec = blackbox::read_file(&exit_file).expect("read the recording");
    assert_eq!(rec.header.law, "recycle-pi");
    assert_eq!(
        rec.records.first().map(|r| r.cycle),
        Some(0),
        "starts at the first cycle"
    );
    // 8 s at 1 kHz, minus start-up: the closure (5–7 s) is in it
    assert!(rec.records.len() > 6000, "{} records", rec.records.len());
    assert!(rec.records.iter().any(|r| r.t_s > 7.0));
    let loaded = config::load(&cfg).unwrap_or_else(|p| panic!("{p:?}"));
    let setup = |controller| replay::ReplaySetup {
        model: loaded.model.clone(),
        controller,
        settings: loaded.core,
        law: loaded.law,
        recorded_settings: true,
    };
    let r = replay::replay(&rec, setup(rec.header.controller.clone())).expect("replay");
    assert_eq!(
        r.report.identical_cycles, r.report.cycles,
        "{:#?}",
        r.report
    );
    assert!(r.report.updates_at_cycles.is_empty());
    eprintln!(
        "replayed {} cycles, {} identical",
        r.report.cycles, r.report.identical_cycles
    );

    // a different gain commands something else over the same inputs
    let mut other = rec.header.controller.clone();
    other.recycle_pi.kp_per_map_flow *= 3.0;
    let changed = replay::replay(&rec, setup(other)).expect("replay");
    assert!(
        changed.report.identical_cycles < changed.report.cycles,
        "{:#?}",
        changed.report
    );

    // and the command line says the same, with exit status 0
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(["replay", &exit_file.display().to_string()])
        .output()
        .expect("antisurge replay");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        text.contains(&format!(
            "{0} of {0} cycles bit-identical",
            rec.records.len()
        )),
        "{text}"
    );
}
