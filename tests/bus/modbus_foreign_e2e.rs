//! `antisurge run` against `antisurge plant` emulating a foreign Modbus device
//! (tests/fixtures/foreign_skid/modbus_map.toml: Modicon numbering, engineering units, CDAB
//! floats, valve in % × 0.01, one watchdog counter register at holding 3 in a table that
//! ends at 5). Each test runs the throttle-closure scenario in real time (≈ 15 s). The same
//! skid with a PLC that speaks in bits (modbus_map_coils.toml: a watchdog toggle coil and an
//! ESD discrete input) runs the throttle closure and the emergency shutdown.

use crate::common;

use antisurge::events::Timestamp;
use common::daemon::*;
use std::path::{Path, PathBuf};
use std::process::Child;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

fn fixture(name: &str) -> String {
    common::root()
        .join("tests/fixtures/foreign_skid")
        .join(name)
        .display()
        .to_string()
}

fn config(dir: &Path, name: &str, port: u16, map: &str, scenario: &str) -> PathBuf {
    let cfg = format!(
        r#"
[plant]
file = "{plant}"
{recycle_pi_50hz}
[bus]
transport = "field"
signal_map = "{map}"
[bus.modbus]
poll_rate_hz = 50.0
[bus.modbus.client]
timeout_ms = 100
transport = {{ kind = "tcp", address = "127.0.0.1:{port}" }}
[event_log]
path = "{events}"
fsync = "always"
[simulation]
scenario = "{scenario}"
[simulation.modbus_server]
listen = "127.0.0.1:{port}"
[status]
log_interval_s = 5.0
"#,
        recycle_pi_50hz = RECYCLE_PI_50HZ,
        plant = shipped("plants/kvangardsnes2009_recycle.toml"),
        events = dir.join("events.jsonl").display(),
    );
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, cfg).expect("write config");
    path
}

/// `antisurge plant` on the foreign map, then `antisurge run` with `ctl_map`.
fn start(dir: &Path, ctl_map: &str) -> (Child, Child, PathBuf, u16) {
    start_with(dir, "modbus_map.toml", ctl_map, "throttle-closure")
}

/// `antisurge plant` on `plant_map`, then `antisurge run` with `ctl_map`, both on `scenario`.
fn start_with(
    dir: &Path,
    plant_map: &str,
    ctl_map: &str,
    scenario: &str,
) -> (Child, Child, PathBuf, u16) {
    let port = free_port();
    let plant_cfg = config(dir, "plant", port, &fixture(plant_map), scenario);
    let ctl_cfg = config(dir, "controller", port, &fixture(ctl_map), scenario);
    let out = dir.join("plant-out");
    let plant = spawn(
        dir,
        "plant",
        &[
            "plant",
            "--config",
            &plant_cfg.display().to_string(),
            "--out",
            &out.display().to_string(),
        ],
    );
    std::thread::sleep(Duration::from_millis(500));
    let ctl = spawn(
        dir,
        "run",
        &["run", "--config", &ctl_cfg.display().to_string()],
    );
    (plant, ctl, out, port)
}

fn events(dir: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(dir.join("events.jsonl"))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

fn ts(e: &serde_json::Value) -> Timestamp {
    Timestamp::parse_rfc3339(e["ts"].as_str().expect("ts")).expect("rfc3339")
}

fn secs_between(a: Timestamp, b: Timestamp) -> f64 {
    b.to_system_time()
        .duration_since(a.to_system_time())
        .map_or_else(|e| -e.duration().as_secs_f64(), |d| d.as_secs_f64())
}

/// The foreign layout end to end: the throttle closure is held with zero surge cycles and
/// no field fail-safe, the valve really driven through the % register.
#[test]
fn foreign_modbus_map_holds_the_throttle_closure() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (mut plant, mut ctl, out, _) = start(dir, "modbus_map.toml");
    let st = wait(&mut plant, Duration::from_secs(60), "plant", dir);
    assert!(st.success(), "plant failed:\n{}", logs(dir));
    signal(&ctl, libc::SIGTERM);
    let _ = wait(&mut ctl, Duration::from_secs(10), "controller", dir);
    let s = summary(&out);
    let ev = events(dir);
    let ctx = format!("{s:#}\n{ev:#?}\n{}", logs(dir));
    assert_eq!(s["surge_cycles"], 0, "{ctx}");
    assert_eq!(s["flow_reversal"], false, "{ctx}");
    assert_eq!(s["field_failsafe_entries"], 0, "{ctx}");
    let peak = s["actuator_peaks"]["recycle_valve_opening"]
        .as_f64()
        .expect("peak");
    assert!(peak > 0.13, "recycle valve peak {peak}: {ctx}");
    // the link came up and no write was refused
    assert!(
        ev.iter()
            .any(|e| e["event"] == "bus_state" && e["state"] == "up"),
        "{ctx}"
    );
    // (the plant stopping at the end takes the link down: only faults before that count)
    let end = ev
        .iter()
        .position(|e| e["event"] == "bus_state" && e["state"] == "down")
        .unwrap_or(ev.len());
    assert!(
        !ev[..end]
            .iter()
            .any(|e| e["event"] == "field_fault" && e["active"] == true),
        "{ctx}"
    );
}

/// kill -9 of the controller: the device watchdog (one counter register, 300 ms) fails the
/// valve open within its timeout.
#[test]
fn kill_9_on_the_foreign_map_fails_the_valve_open() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (mut plant, mut ctl, out, _) = start(dir, "modbus_map.toml");
    // in the closure (plant time 5–7 s)
    let (killed_at, s, ctx) = kill_controller_at_plant_time(&mut plant, &mut ctl, &out, dir, 5.5);
    assert_eq!(s["field_failsafe_entries"], 1, "{ctx}");
    let pos = column(&out, "recycle_valve_position");
    assert!(pos.last().expect("rows").1 > 0.95, "{ctx}");
    // the map's device watchdog: 300 ms on the counter
    assert_device_watchdog_timing(&out, FOREIGN_WATCHDOG_S, killed_at, &ctx);
}

/// The foreign maps' device watchdog time (`timeout_ms = 300` in tests/fixtures/foreign_skid):
/// written here on its own so that a changed fixture fails the timing tests.
const FOREIGN_WATCHDOG_S: f64 = 0.3;

/// A controller configured with the valve at a register the device does not have: every
/// valve write is refused (exception 2). While the link stays up: a field fault with the
/// exception code; then the watchdog is withheld and the device fails the valve open itself.
/// (Ordering in the controller's own event log, no wall-clock bound: a busy machine must
/// not fail it.)
#[test]
fn refused_writes_are_a_fault_with_the_exception_code() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (mut plant, mut ctl, out, _) = start(dir, "modbus_map_wrong_valve.toml");
    std::thread::sleep(Duration::from_millis(4000));
    signal(&ctl, libc::SIGTERM);
    let _ = wait(&mut ctl, Duration::from_secs(10), "controller", dir);
    signal(&plant, libc::SIGTERM);
    let _ = wait(&mut plant, Duration::from_secs(20), "plant", dir);
    let ev = events(dir);
    let ctx = format!("{ev:#?}\n{}", logs(dir));
    let up = ev
        .iter()
        .position(|e| e["event"] == "bus_state" && e["state"] == "up")
        .unwrap_or_else(|| panic!("no bus_state up: {ctx}"));
    let at = ev
        .iter()
        .position(|e| {
            e["event"] == "field_fault" && e["fault"] == "field_write_failed" && e["active"] == true
        })
        .unwrap_or_else(|| panic!("no field_write_failed fault: {ctx}"));
    let fault = &ev[at];
    let cause = fault["cause"].as_str().expect("cause");
    assert!(cause.contains("exception 2"), "{cause}");
    assert!(cause.contains("address 1"), "{cause}");
    assert!(fault["link"]
        .as_str()
        .unwrap()
        .starts_with("modbus:127.0.0.1:"));
    // raised while the link that came up stayed up (no bus_state change in between), and
    // the time between is printed (the event log's clock), not bounded
    assert!(up < at, "the fault came before the link was up: {ctx}");
    assert!(
        !ev[up + 1..at].iter().any(|e| e["event"] == "bus_state"),
        "the link went down before the refusal was a fault: {ctx}"
    );
    eprintln!(
        "refused write: fault {:.3} s after the link came up (event log time)",
        secs_between(ts(&ev[up]), ts(fault))
    );
    // the safe behaviour, after the fault: watchdog withheld, the device's own fail-safe
    // took over
    assert!(
        ev[at..].iter().any(|e| e["event"] == "field_fault"
            && e["cause"]
                .as_str()
                .is_some_and(|c| c.contains("watchdog withheld"))),
        "{ctx}"
    );
    let s = summary(&out);
    assert!(
        s["field_failsafe_entries"].as_u64().unwrap_or(0) >= 1,
        "{s:#}\n{ctx}"
    );
}

/// A third Modbus client writing the valve closed every 10 ms: the controller notices that
/// the valve does not follow (feedback mismatch, 0.05 for 500 ms) and names it.
#[test]
fn a_second_master_closing_the_valve_is_a_feedback_mismatch() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (mut plant, mut ctl, out, port) = start(dir, "modbus_map.toml");
    // from just before the closure (scenario 5–7 s) to the end
    std::thread::sleep(Duration::from_millis(4500));
    let stop = Arc::new(AtomicBool::new(false));
    let st = Arc::clone(&stop);
    let intruder = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("rt");
        rt.block_on(async move {
            use tokio_modbus::client::Writer;
            let addr = std::net::SocketAddr::from(([127, 0, 0, 1], port));
            let mut ctx = tokio_modbus::client::tcp::connect_slave(addr, tokio_modbus::Slave(1))
                .await
                .expect("third client connects");
            let mut n = 0u64;
            while !st.load(Ordering::Relaxed) {
                // 40001 = holding 0: recycle valve 0.00 %
                let _ = ctx.write_single_register(0, 0).await;
                n += 1;
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
            n
        })
    });
    let stp = wait(&mut plant, Duration::from_secs(60), "plant", dir);
    stop.store(true, Ordering::Relaxed);
    let writes = intruder.join().expect("intruder");
    signal(&ctl, libc::SIGTERM);
    let _ = wait(&mut ctl, Duration::from_secs(10), "controller", dir);
    assert!(stp.success(), "plant failed:\n{}", logs(dir));
    assert!(writes > 100, "third client wrote {writes} times");
    let ev = events(dir);
    let s = summary(&out);
    let ctx = format!("{s:#}\n{ev:#?}\n{}", logs(dir));
    let m = ev
        .iter()
        .find(|e| {
            e["event"] == "field_fault"
                && e["fault"] == "actuator_feedback_mismatch"
                && e["active"] == true
        })
        .unwrap_or_else(|| panic!("no feedback mismatch: {ctx}"));
    assert_eq!(m["link"], "recycle_valve", "{ctx}");
    let cause = m["cause"].as_str().expect("cause");
    assert!(
        cause.contains("recycle_valve") && cause.contains("difference"),
        "{cause}"
    );
    // raised as soon as the configured 500 ms had passed (10-ms checks)
    let lasted: f64 = cause
        .rsplit("for ")
        .next()
        .and_then(|t| t.trim_end_matches(" s").parse().ok())
        .expect("duration in the cause");
    assert!((0.5..0.6).contains(&lasted), "{cause}");
}

/// The PLC's watchdog watches a coil: the controller toggles coil 00001 (function 0x05) with
/// every output set, so the device stays out of its fail-safe through the closure; after
/// kill -9 the coil stops flipping and the device fails the valve open within 300 ms.
#[test]
fn a_watchdog_toggle_coil_keeps_the_device_alive_until_kill_9() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let map = "modbus_map_coils.toml";
    let (mut plant, mut ctl, out, _) = start_with(dir, map, map, "throttle-closure");
    // past the closure (plant time 5–7 s): the device watchdog saw the coil flip all along
    let (killed_at, s, ctx) = kill_controller_at_plant_time(&mut plant, &mut ctl, &out, dir, 7.5);
    assert_eq!(s["field_failsafe_entries"], 1, "only the kill: {ctx}");
    assert_eq!(s["surge_cycles"], 0, "{ctx}");
    // the coil flipped until the kill (the fail-safe came after it, on the plant's clock),
    // and the device failed safe 300 ms after its last flip
    assert_device_watchdog_timing(&out, FOREIGN_WATCHDOG_S, killed_at, &ctx);
}

/// The skid's ESD / drive-trip contact is a discrete input (10001): when the drive trips
/// (emergency-shutdown scenario, t = 5 s) the plant closes it, the controller reads it with
/// function 0x02 and opens the recycle valve fully at once; the event log says why.
#[test]
fn an_esd_discrete_input_opens_the_valve_at_once_and_the_event_says_why() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let map = "modbus_map_coils.toml";
    let (mut plant, mut ctl, out, _) = start_with(dir, map, map, "emergency-shutdown");
    let st = wait(&mut plant, Duration::from_secs(60), "plant", dir);
    assert!(st.success(), "plant failed:\n{}", logs(dir));
    signal(&ctl, libc::SIGTERM);
    let _ = wait(&mut ctl, Duration::from_secs(10), "controller", dir);
    let s = summary(&out);
    let ev = events(dir);
    let ctx = format!("{s:#}\n{ev:#?}\n{}", logs(dir));
    let trip = ev
        .iter()
        .find(|e| e["event"] == "recycle_trip" && e["reason"] == "external")
        .unwrap_or_else(|| panic!("no external recycle trip: {ctx}"));
    assert_eq!(trip["cause"]["kind"], "esd_input", "{ctx}");
    assert_eq!(trip["cause"]["input"], "esd_input", "{ctx}");
    assert_eq!(trip["cause"]["value"], 1.0, "{ctx}");
    // before the trip the valve is the law's; from the contact on it is commanded 100 %
    let cmd = column(&out, "cmd_recycle_valve");
    assert!(
        cmd.iter()
            .filter(|(t, _)| *t > 1.0 && *t < 4.9)
            .all(|(_, u)| *u < 0.9),
        "{ctx}"
    );
    let open = cmd
        .iter()
        .find(|(t, u)| *t >= 5.0 && *u >= 0.999)
        .unwrap_or_else(|| panic!("valve never commanded open after the trip: {ctx}"))
        .0;
    eprintln!(
        "ESD input: valve commanded open {:.3} s after the drive trip",
        open - 5.0
    );
    // one 50-Hz poll + one control cycle + one 50-Hz write + trace rows
    assert!(
        open - 5.0 <= 0.1,
        "valve commanded open {:.3} s after the trip: {ctx}",
        open - 5.0
    );
    assert_eq!(s["field_failsafe_entries"], 0, "{ctx}");
}
