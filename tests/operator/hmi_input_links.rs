//! Issues 23/24: which link carries which input, and a skid without a suction temperature
//! transmitter, end to end over Modbus TCP. `antisurge run` with the vendor-data machine polls
//! the test-side skid device (`tests/common/modbus_skid.rs`) through a map that binds the
//! pressures, the Δp (transmitters `a` and `b`) and the valve position, and neither a shaft
//! speed nor a suction temperature.
//!
//! - The status (`GET /api/status`, what `src/live/hmi.html` draws from, and `antisurge status
//!   --json`) carries, per bound input and transmitter, the link that carries it
//!   (`inputs[].link`, named as `links.modbus.name`), and no row, fault or lamp for a sensor
//!   the skid does not have.
//! - With no temperature transmitter, `t_suction_k` is null (the nominal temperature the cycle
//!   falls back to is no measurement) and `antisurge status` prints "–".
//! - The device stops: every input of that link reads `link_down`, naming the link, in both
//!   surfaces, and the faults line of `antisurge status` names the link beside the inputs.
//!
//! A config with two field links of which one goes down (CAN beside Modbus) needs a CAN
//! interface (vcan), which this suite cannot assume; nor can a config hold two Modbus links
//! (one `[bus.modbus]`). That case is covered by the unit tests of the table
//! (`io::signal_map`, both buses) and of the report (`live::report`, one of two links down),
//! and on the page by the browser test (`.ci/hmi/browser_test.mjs`).

use crate::common;

use common::daemon::{free_port, signal, spawn, until, wait};
use common::modbus_skid::{controller_config, hmi_status, start_device, status_cli, status_json};
use std::time::Duration;

/// The skid's map: no `t_suction`, no `shaft_speed`; Δp `b` votes with `a` (the device's
/// registers 11–12).
const SIGNAL_MAP: &str = r#"
[sensors]
p_suction = { modbus = { unit_id = 1, table = "input", address = 0, data_type = "f32" } }
p_discharge = { modbus = { unit_id = 1, table = "input", address = 2, data_type = "f32" } }
orifice_dp = { modbus = { unit_id = 1, table = "input", address = 6, data_type = "f32" } }
recycle_valve_position = { modbus = { unit_id = 1, table = "input", address = 9, data_type = "u16", scale = 1e-4 } }

[actuators]
recycle_valve = { modbus = { unit_id = 1, table = "holding", address = 102, data_type = "u16", scale = 1e-4 } }

[vote.orifice_dp]
b = { modbus = { unit_id = 1, table = "input", address = 11, data_type = "f32" } }
"#;

/// The bound transmitters, in the table's order (sensor order, `a` before the spares).
const BOUND: [(&str, &str); 5] = [
    ("p_suction", "a"),
    ("p_discharge", "a"),
    ("orifice_dp", "a"),
    ("orifice_dp", "b"),
    ("recycle_valve_position", "a"),
];

/// The sensors this skid does not have.
const UNBOUND: [&str; 2] = ["t_suction", "shaft_speed"];

/// `inputs[]` as (input, transmitter, link, link_down, state).
fn rows(v: &serde_json::Value) -> Vec<(String, String, String, bool, String)> {
    let s = |x: &serde_json::Value| x.as_str().unwrap_or("<none>").to_string();
    v["inputs"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|r| {
                    (
                        s(&r["input"]),
                        s(&r["transmitter"]),
                        s(&r["link"]),
                        r["link_down"] == true,
                        s(&r["state"]),
                    )
                })
                .collect()
        })
        .unwrap_or_default()
}

/// The rows every bound input should have: on `link`, with `link_down` and `state`.
fn expected(
    link: &str,
    link_down: bool,
    state: &str,
) -> Vec<(String, String, String, bool, String)> {
    BOUND
        .iter()
        .map(|(i, t)| {
            (
                i.to_string(),
                t.to_string(),
                link.to_string(),
                link_down,
                state.to_string(),
            )
        })
        .collect()
}

/// No row, fault, transmitter or temperature for a sensor the skid does not have.
fn nothing_unbound(v: &serde_json::Value, surface: &str) {
    assert!(v["t_suction_k"].is_null(), "{surface}: t_suction_k {v}");
    for u in UNBOUND {
        for list in ["inputs", "faults", "transmitters"] {
            let named = v[list]
                .as_array()
                .is_some_and(|a| a.iter().any(|r| r["input"] == u || r["measurement"] == u));
            assert!(!named, "{surface}: the unbound {u} in {list}: {v}");
        }
    }
}

#[test]
fn each_input_names_its_link_a_link_down_marks_them_and_a_skid_without_temperature_shows_none() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime");
    let (_device, device_port, server) = start_device(&rt);
    let hmi_port = free_port();
    let cfg = controller_config(dir, SIGNAL_MAP, device_port, hmi_port);
    let mut d = spawn(dir, "run", &["run", "--config", &cfg.display().to_string()]);
    let link = format!("modbus:127.0.0.1:{device_port}");

    // running: the link up, every bound input healthy on it, the process values in
    let mut seen = serde_json::Value::Null;
    until(dir, "the HMI to show every input ok on the link", || {
        seen = hmi_status(hmi_port).unwrap_or_default();
        seen["links"]["modbus"]["state"] == "up"
            && rows(&seen) == expected(&link, false, "ok")
            && seen["p_suction_pa"].is_number()
    });
    eprintln!(
        "running: inputs {}\n  t_suction_k {}, p_suction_pa {}, faults {}",
        seen["inputs"], seen["t_suction_k"], seen["p_suction_pa"], seen["faults"]
    );
    nothing_unbound(&seen, "/api/status");
    let st = status_json(dir);
    assert_eq!(
        rows(&st),
        expected(&link, false, "ok"),
        "status --json: {st}"
    );
    nothing_unbound(&st, "status --json");
    assert!(st["p_suction_pa"].is_number(), "{st}");
    let text = status_cli(dir, &[]);
    let process = text
        .lines()
        .find(|l| l.starts_with("process"))
        .unwrap_or_else(|| panic!("no process line in antisurge status:\n{text}"));
    assert!(process.ends_with("T suction –"), "{process}");
    assert!(
        !process.contains("suction –  "),
        "the pressures are measured: {process}"
    );
    eprintln!("antisurge status: {process}");

    // the device stops: every input of its link is the link's, named, in both surfaces
    server.abort();
    let _ = rt.block_on(server);
    until(dir, "the HMI to mark every input of the link down", || {
        seen = hmi_status(hmi_port).unwrap_or_default();
        rows(&seen) == expected(&link, true, "link_down")
    });
    assert_eq!(seen["links"]["modbus"]["name"], link.as_str(), "{seen}");
    assert_eq!(seen["links"]["modbus"]["state"], "down", "{seen}");
    nothing_unbound(&seen, "/api/status, link down");
    // once the inputs go stale (200 ms) the faults line names the link beside them
    let mut st = serde_json::Value::Null;
    until(dir, "status --json to show the stale inputs", || {
        st = status_json(dir);
        st["faults"]
            .as_array()
            .is_some_and(|f| f.iter().any(|f| f["input"] == "p_suction"))
    });
    assert_eq!(
        rows(&st),
        expected(&link, true, "link_down"),
        "status --json: {st}"
    );
    nothing_unbound(&st, "status --json, link down");
    let text = status_cli(dir, &[]);
    let faults = text
        .lines()
        .find(|l| l.starts_with("faults"))
        .unwrap_or_else(|| panic!("no faults line in antisurge status:\n{text}"));
    assert!(
        faults.contains(&format!("p_suction (link {link} down)")),
        "{faults}"
    );
    assert!(
        UNBOUND.iter().all(|u| !faults.contains(u)),
        "an unbound sensor among the faults: {faults}"
    );
    eprintln!(
        "link down: inputs {}\n  antisurge status: {faults}\n  cause: {}",
        st["inputs"], st["cause_text"]
    );

    signal(&d, libc::SIGTERM);
    let _ = wait(&mut d, Duration::from_secs(20), "controller", dir);
    drop(rt);
}
