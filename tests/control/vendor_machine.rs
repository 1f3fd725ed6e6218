//! Commissioning from vendor data, end to end: `antisurge run` with only
//! `config/machines/vendor_example.toml` (surge line q = 0.354·√(Rp − 1) m³/s, a flow-element
//! constant, gas, recycle valve, transmitter ranges) against `antisurge plant` simulating an
//! independently built recycle skid (`tests/plants/vendor_skid_recycle.toml`: its surge line
//! lies 1.5 % right of the vendor's; volumes, line lengths and valve capacities the controller
//! is not told; the drive keeps its own governor) over Modbus TCP. Throttle closure and
//! throttle step: zero surge cycles (open loop, both surge this skid: 14 and 15 cycles).

use crate::common;

use common::daemon::*;
use common::root;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Leaf keys of a TOML table (an inline table's keys count one by one).
fn leaf_keys(t: &toml::Table) -> usize {
    t.values()
        .map(|v| match v {
            toml::Value::Table(t) => leaf_keys(t),
            _ => 1,
        })
        .sum()
}

#[test]
fn the_vendor_example_needs_at_most_20_keys_and_check_config_accepts_it() {
    let read = |p: &str| -> toml::Table {
        toml::from_str(&std::fs::read_to_string(root().join(p)).expect("read")).expect("toml")
    };
    let machine = read("config/machines/vendor_example.toml");
    let daemon = read("config/vendor_example.toml");
    let n = leaf_keys(&machine) + leaf_keys(&daemon);
    assert!(n <= 20, "{n} keys");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(["check-config", &shipped("vendor_example.toml")])
        .output()
        .expect("run");
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    assert!(!text.contains("warning"), "{text}");
}

/// The controller's config: the shipped vendor example, with the test's port, heartbeat
/// watchdog, event log and input freshness (50 Hz polling on a loaded CI machine).
fn controller_config(dir: &Path, port: u16) -> PathBuf {
    let text = std::fs::read_to_string(root().join("config/vendor_example.toml"))
        .expect("vendor example")
        .replace(
            "machines/vendor_example.toml",
            &shipped("machines/vendor_example.toml"),
        )
        .replace(
            "signals_vendor_modbus.toml",
            &shipped("signals_vendor_modbus.toml"),
        )
        .replace("127.0.0.1:5020", &format!("127.0.0.1:{port}"));
    let mut cfg = text.replace(
        "[bus.modbus.client]",
        "[bus.modbus]\nheartbeat_register = { unit_id = 1, address = 300 }\n[bus.modbus.client]",
    );
    cfg += &format!(
        r#"timeout_ms = 100
[event_log]
path = "{events}"
[status]
log_interval_s = 5.0
"#,
        events = dir.join("events.jsonl").display()
    );
    for s in [
        "p_suction",
        "p_discharge",
        "orifice_dp",
        "t_suction",
        "recycle_valve_position",
    ] {
        let (min, max) = match s {
            "t_suction" => (200.0, 400.0),
            "recycle_valve_position" => (-0.05, 1.05),
            "orifice_dp" => (-1.0e5, 1.0e6),
            _ => (1.0e4, 1.2e7),
        };
        cfg += &format!("[inputs.{s}]\nmin = {min:e}\nmax = {max:e}\ntimeout_ms = 200.0\n");
    }
    let path = dir.join("controller.toml");
    std::fs::write(&path, cfg).expect("write");
    path
}

/// The simulated skid's config: the controller's config (same bus, same map) plus the
/// independent plant and the scenario. `[machine]` stays the vendor file, so the plant file is
/// only the simulated skid here.
fn plant_config(dir: &Path, controller: &Path, scenario: &str) -> PathBuf {
    let mut cfg = std::fs::read_to_string(controller).expect("controller config");
    cfg = cfg.replace("events.jsonl", "plant-events.jsonl");
    let port = cfg
        .split("127.0.0.1:")
        .nth(1)
        .and_then(|r| r.split('"').next())
        .expect("port")
        .to_string();
    cfg += &format!(
        r#"[plant]
file = "{plant}"
[simulation]
scenario = "{scenario}"
heartbeat_timeout_ms = 300.0
[simulation.modbus_server]
listen = "127.0.0.1:{port}"
heartbeat_register = {{ unit_id = 1, address = 300 }}
"#,
        plant = root()
            .join("tests/plants/vendor_skid_recycle.toml")
            .display(),
        scenario = shipped(&format!("scenarios/{}.toml", scenario.replace('-', "_"))),
    );
    let path = dir.join("plant.toml");
    std::fs::write(&path, cfg).expect("write");
    path
}

fn run_scenario(scenario: &str) {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let port = free_port();
    let cc = controller_config(dir, port);
    let pc = plant_config(dir, &cc, scenario);
    let out = dir.join("plant");
    let mut plant = spawn(
        dir,
        "plant",
        &[
            "plant",
            "--config",
            &pc.display().to_string(),
            "--out",
            &out.display().to_string(),
        ],
    );
    std::thread::sleep(Duration::from_millis(500));
    let mut ctl = spawn(dir, "run", &["run", "--config", &cc.display().to_string()]);
    let st = wait(&mut plant, Duration::from_secs(60), "plant", dir);
    assert!(st.success(), "plant failed:\n{}", logs(dir));
    signal(&ctl, libc::SIGTERM);
    let st = wait(&mut ctl, Duration::from_secs(10), "controller", dir);
    assert!(st.success(), "controller exit {st:?}:\n{}", logs(dir));

    let s = summary(&out);
    let ctx = format!("{s:#}\n{}", logs(dir));
    assert_eq!(s["surge_cycles"], 0, "{ctx}");
    assert_eq!(s["flow_reversal"], false, "{ctx}");
    assert_eq!(s["field_failsafe_entries"], 0, "{ctx}");
    // the true surge line is 1.5 % right of the vendor's; the 10 % control margin keeps the
    // machine right of it
    let min_margin = s["min_surge_margin"].as_f64().expect("margin");
    assert!(min_margin > 0.0, "min surge margin {min_margin}: {ctx}");
    // the valve really was driven over the bus, and the drive was left to its governor
    let peak = s["actuator_peaks"]["recycle_valve_opening"]
        .as_f64()
        .expect("peak");
    assert!(peak > 0.05, "recycle valve peak {peak}: {ctx}");
    eprintln!("{scenario}: min surge margin {min_margin:.4}, recycle valve peak {peak:.3}");
}

#[test]
fn vendor_data_only_keeps_an_independent_skid_out_of_surge_through_a_throttle_closure() {
    run_scenario("throttle-closure");
}

#[test]
fn vendor_data_only_keeps_an_independent_skid_out_of_surge_through_a_throttle_step() {
    run_scenario("throttle-step");
}
