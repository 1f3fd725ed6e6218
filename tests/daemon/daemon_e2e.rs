//! The daemon end to end, as processes: `antisurge run` against the in-process plant (hot
//! reload) and against `antisurge plant` over Modbus TCP on loopback (control at 50 Hz, and
//! kill -9 of the controller). Each test runs a scenario in real time (15–22 s).

use crate::common;

use common::daemon::*;
use std::path::{Path, PathBuf};
use std::process::Child;
use std::time::Duration;

/// Start `antisurge plant` (Modbus server) and, half a second later, `antisurge run`.
fn start_pair(dir: &Path, scenario: &str) -> (Child, Child, PathBuf) {
    let port = free_port();
    let cfg = write_modbus_e2e_config(
        dir,
        &ModbusE2e {
            client_port: port,
            plant_port: port,
            scenario,
            heartbeat_timeout_ms: 200.0,
            client_extra: "",
        },
    );
    let cfg_s = cfg.display().to_string();
    let out = dir.join("plant");
    let out_s = out.display().to_string();
    let plant = spawn(
        dir,
        "plant",
        &["plant", "--config", &cfg_s, "--out", &out_s],
    );
    std::thread::sleep(Duration::from_millis(500));
    let ctl = spawn(dir, "run", &["run", "--config", &cfg_s]);
    (plant, ctl, out)
}

/// Modbus TCP end to end: recycle-pi at a 50 Hz cycle keeps the recycle plant out of surge
/// through the throttle closure.
#[test]
fn modbus_tcp_recycle_pi_at_50_hz_stays_out_of_surge() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (mut plant, mut ctl, out) = start_pair(dir, "throttle-closure");
    let st = wait(&mut plant, Duration::from_secs(60), "plant", dir);
    assert!(st.success(), "plant failed:\n{}", logs(dir));
    signal(&ctl, libc::SIGTERM);
    let st = wait(&mut ctl, Duration::from_secs(10), "controller", dir);
    assert!(st.success(), "controller exit {st:?}:\n{}", logs(dir));

    let s = summary(&out);
    let ctx = format!("{s:#}\n{}", logs(dir));
    assert_eq!(s["law"], "recycle-pi", "{ctx}");
    assert_eq!(s["surge_cycles"], 0, "{ctx}");
    assert_eq!(s["flow_reversal"], false, "{ctx}");
    assert_eq!(s["field_failsafe_entries"], 0, "{ctx}");
    // open loop, this closure surges (tests/control/open_loop_surge.rs); in-process recycle-pi keeps
    // the flow above 11.4 kg/s: over Modbus at 50 Hz it must stay right of the surge line too
    let min_margin = s["min_surge_margin"].as_f64().expect("margin");
    assert!(min_margin > 0.05, "min surge margin {min_margin}: {ctx}");
    // the recycle valve really was driven over the bus
    let peak = s["actuator_peaks"]["recycle_valve_opening"]
        .as_f64()
        .expect("peak");
    assert!(peak > 0.13, "recycle valve peak {peak}: {ctx}");
}

/// kill -9 of the controller mid-scenario: the plant's field devices reach their fail-safe
/// within the heartbeat timeout and the plant does not surge.
#[test]
fn kill_9_of_the_controller_leaves_the_plant_safe() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (mut plant, mut ctl, out) = start_pair(dir, "throttle-closure");
    // the closure runs from t = 5 s to 7 s of scenario (plant) time: kill in the middle of it
    let (killed_at, s, ctx) = kill_controller_at_plant_time(&mut plant, &mut ctl, &out, dir, 5.5);
    assert_eq!(s["field_failsafe_entries"], 1, "{ctx}");
    assert_eq!(s["surge_cycles"], 0, "{ctx}");
    assert_eq!(s["flow_reversal"], false, "{ctx}");
    // the recycle valve failed open: its position ends near 100 %
    let pos = column(&out, "recycle_valve_position");
    let last = pos.last().expect("rows").1;
    assert!(last > 0.95, "recycle valve ends at {last}: {ctx}");
    // fail-safe 200 ms (the plant's heartbeat timeout) after the last heartbeat change
    // it saw, and the controller beat until the kill
    assert_device_watchdog_timing(&out, 0.2, killed_at, &ctx);
}

/// Hot reload in a running daemon: a valid gain change during the throttle closure is
/// applied with no output step over 1 %; an invalid edit is rejected and control goes on
/// untouched; both are in the event log.
#[test]
fn hot_reload_is_bumpless_and_rejects_invalid_edits() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let events = dir.join("events.jsonl");
    let base = format!(
        r#"[plant]
file = "{plant}"
[control]
law = "recycle-pi"
[cycle]
rate_hz = 1000.0
lock_memory = false
[event_log]
path = "{events}"
fsync = "always"
[simulation]
scenario = "throttle-closure"
[reload]
watch_files = true
settle_ms = 300.0
[controller.recycle_pi.pi]
kp_per_map_flow = KP
[controller.recycle_pi.throttle]
# (off: the reload's bumplessness is measured on the PI and the closing limiter; the throttle
# watch's head start near the end of the closure, at 7.0 s, is a 0.15 step by design)
enabled = false
"#,
        plant = shipped("plants/kvangardsnes2009_recycle.toml"),
        events = events.display(),
    );
    let cfg = dir.join("antisurge.toml");
    std::fs::write(&cfg, base.replace("KP", "10.0")).expect("write");
    let cfg_s = cfg.display().to_string();
    let out = dir.join("plant");
    let out_s = out.display().to_string();
    let mut ctl = spawn(
        dir,
        "run",
        &[
            "run",
            "--config",
            &cfg_s,
            "--duration-s",
            "14",
            "--out",
            &out_s,
        ],
    );
    // mid-closure (scenario time ≈ 6 s): a valid gain change, saved like an editor does
    std::thread::sleep(Duration::from_millis(6000));
    write_atomically(&cfg, &base.replace("KP", "16.0"));
    // then an invalid edit
    std::thread::sleep(Duration::from_millis(2000));
    write_atomically(&cfg, &base.replace("KP", "\"fast\""));
    std::thread::sleep(Duration::from_millis(1000));
    signal(&ctl, libc::SIGHUP); // SIGHUP reloads too (and is rejected again)
    let st = wait(&mut ctl, Duration::from_secs(30), "controller", dir);
    assert!(st.success(), "controller exit {st:?}:\n{}", logs(dir));

    let log = std::fs::read_to_string(&events).expect("events");
    let ctx = format!("{log}\n{}", logs(dir));
    let applied: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("\"config_applied\""))
        .collect();
    assert_eq!(applied.len(), 1, "{ctx}");
    assert!(
        applied[0].contains("controller.recycle_pi.pi.kp_per_map_flow"),
        "{ctx}"
    );
    assert!(applied[0].contains("16.0"), "{ctx}");
    let rejected: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("\"config_rejected\""))
        .collect();
    assert!(!rejected.is_empty(), "{ctx}");
    assert!(rejected[0].contains("kp_per_map_flow"), "{ctx}");

    // control unaffected: no surge, and no output step over 1 % between 5-ms trace rows
    let s = summary(&out);
    assert_eq!(s["surge_cycles"], 0, "{s:#}");
    // (up to 13 s: at the end of the 14-s run the shutdown commands the safe state, 100 %)
    let cmd = column(&out, "cmd_recycle_valve");
    let mut worst = (0.0, 0.0);
    for w in cmd.windows(2) {
        if w[0].0 > 0.5 && w[1].0 < 13.0 && w[1].1.is_finite() && w[0].1.is_finite() {
            let step = (w[1].1 - w[0].1).abs();
            if step > worst.0 {
                worst = (step, w[1].0);
            }
        }
    }
    assert!(
        worst.0 < 0.01,
        "output step {:.4} at t = {:.3} s",
        worst.0,
        worst.1
    );
}
