//! Issue 23 ("Link down: ... the HMI lamp name the link within 1 s"; "each transmitter's value
//! and state in status and the HMI"; feedback faults "in events, status, HMI lamps") and issue
//! 24 (lamps for each link, each transmitter, feedback), end to end over Modbus TCP: `antisurge
//! run` with the vendor-data machine (`config/machines/vendor_example.toml`) polls a device
//! of this suite (`tests/common/modbus_skid.rs`), and the test reads the web HMI's own JSON (`GET /api/status`, what
//! `src/live/hmi.html` draws its lamps from: the link lamp from `links.modbus.name`/`.state`
//! and `field_faults` (`field_link_down`), the transmitter lamps from `transmitters[]`, the
//! feedback lamp from `field_faults` (`actuator_feedback_mismatch`) and `links.feedback`, the
//! header's cause from `cause`/`cause_text`).
//!
//! The device serves the independent vendor skid's steady state
//! (`tests/plants/vendor_skid_recycle.toml`, computed in process) with a little noise on every
//! reading (no transmitter looks frozen), three Δp transmitters of which `c` reads no value (an
//! f32 NaN: voted out), and a recycle valve stuck at 40 % whatever it is told (a command/
//! feedback mismatch, latched). Then the test stops the device (listener and connections
//! closed) and polls the HMI: the link lamp's data must name the Modbus link, down, within
//! 1 s, measured on one clock (this process's monotonic clock from the stop to the answer's
//! arrival); the fail-safe cause names the link, not a sensor.

use crate::common;

use antisurge::vocab::signals::SensorId;
use common::daemon::{logs, signal, spawn, until, wait};
use common::modbus_skid::{controller_config, hmi_status, lock, start_device, status_json};
use std::time::{Duration, Instant};

/// The controller's signal map: the vendor skid's Modbus map, two more Δp transmitters voting
/// with `a`, and the valve's feedback supervised.
const SIGNAL_MAP: &str = r#"
[sensors]
p_suction = { modbus = { unit_id = 1, table = "input", address = 0, data_type = "f32" } }
p_discharge = { modbus = { unit_id = 1, table = "input", address = 2, data_type = "f32" } }
orifice_dp = { modbus = { unit_id = 1, table = "input", address = 6, data_type = "f32" } }
t_suction = { modbus = { unit_id = 1, table = "input", address = 8, data_type = "i16", scale = 0.01, offset = 273.15 } }
recycle_valve_position = { modbus = { unit_id = 1, table = "input", address = 9, data_type = "u16", scale = 1e-4 } }

[actuators]
recycle_valve = { modbus = { unit_id = 1, table = "holding", address = 102, data_type = "u16", scale = 1e-4 } }

[feedback]
recycle_valve = { tolerance = 0.05, time_ms = 300 }

[vote.orifice_dp]
b = { modbus = { unit_id = 1, table = "input", address = 11, data_type = "f32" } }
c = { modbus = { unit_id = 1, table = "input", address = 13, data_type = "f32" } }
"#;

/// Whether the page's link lamp is lit and names the Modbus link (the data `hmi.html` draws
/// it from: `links.modbus.name`, `links.modbus.state`, `field_faults`).
fn link_lamp_names_the_link_down(v: &serde_json::Value, device_port: u16) -> bool {
    let l = &v["links"]["modbus"];
    l["name"] == format!("modbus:127.0.0.1:{device_port}").as_str()
        && l["state"] == "down"
        && v["field_faults"]
            .as_array()
            .is_some_and(|a| a.iter().any(|f| f == "field_link_down"))
}

#[test]
fn the_hmi_data_names_a_voted_out_transmitter_the_feedback_mismatch_and_the_link_down() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime");
    let (shared, device_port, server) = start_device(&rt);
    let hmi_port = common::daemon::free_port();
    let cfg = controller_config(dir, SIGNAL_MAP, device_port, hmi_port);
    let mut d = spawn(dir, "run", &["run", "--config", &cfg.display().to_string()]);

    // running: the link up, the voted-out transmitter and the latched feedback mismatch on
    // the HMI's data (the mismatch is raised 300 ms after the valve stops following)
    let mut seen = serde_json::Value::Null;
    until(
        dir,
        "the HMI to show the link up, c voted out and the mismatch",
        || {
            seen = hmi_status(hmi_port).unwrap_or_default();
            seen["links"]["modbus"]["state"] == "up"
                && seen["transmitters"]
                    .as_array()
                    .is_some_and(|t| t.iter().any(|t| t["state"] == "voted_out"))
                && seen["field_faults"]
                    .as_array()
                    .is_some_and(|a| a.iter().any(|f| f == "actuator_feedback_mismatch"))
        },
    );
    let v = seen.clone();
    eprintln!(
        "before the stop: mode {}, links.modbus {}, field_faults {}, links.feedback {}\n  transmitters {}\n  process: p_suction_pa {} p_discharge_pa {} orifice_dp_pa {} t_suction_k {}",
        v["mode"], v["links"]["modbus"], v["field_faults"], v["links"]["feedback"], v["transmitters"],
        v["p_suction_pa"], v["p_discharge_pa"], v["orifice_dp_pa"], v["t_suction_k"]
    );
    // each transmitter of the vote: a and b healthy, c voted out for reading no value
    let tx = v["transmitters"].as_array().expect("transmitters");
    let by = |b: &str| {
        tx.iter()
            .find(|t| t["measurement"] == "orifice_dp" && t["binding"] == b)
            .unwrap_or_else(|| panic!("no orifice_dp.{b} in {v}"))
    };
    assert_eq!(by("a")["state"], "healthy", "{v}");
    assert_eq!(by("b")["state"], "healthy", "{v}");
    assert_eq!(by("c")["state"], "voted_out", "{v}");
    assert_eq!(by("c")["reason"], "nan", "{v}");
    assert!(by("c")["value"].is_null(), "{v}");
    // the feedback lamp's data: the supervised valve, and the mismatch in the fault record
    // that antisurge status shows (the same record)
    assert_eq!(
        v["links"]["feedback"],
        serde_json::json!(["recycle_valve"]),
        "{v}"
    );
    let status = status_json(dir);
    assert!(
        status["field_faults"]
            .as_array()
            .is_some_and(|a| a.iter().any(|f| f == "actuator_feedback_mismatch")),
        "{status}"
    );
    // the process values the cycle used: the skid's readings within their noise
    let steady = lock(&shared).steady;
    for (k, id, rel) in [
        ("p_suction_pa", SensorId::PSuction, 0.01),
        ("p_discharge_pa", SensorId::PDischarge, 0.01),
        ("orifice_dp_pa", SensorId::OrificeDp, 0.01),
        ("t_suction_k", SensorId::TSuction, 0.01),
    ] {
        let want = steady.get(id);
        let got = v[k].as_f64().unwrap_or_else(|| panic!("{k} missing: {v}"));
        assert!(
            (got - want).abs() <= rel * want.abs(),
            "{k}: HMI {got}, device {want}"
        );
    }

    // the device stops: listener and connections closed
    let t_stop = Instant::now();
    server.abort();
    let _ = rt.block_on(server);
    let stopped_after = t_stop.elapsed();
    // poll the page's data; each answer is dated by its arrival on the same monotonic clock
    let mut first_named: Option<(Duration, serde_json::Value)> = None;
    let mut cause_named: Option<(Duration, serde_json::Value)> = None;
    let mut answers = 0;
    // (a liveness bound: the delays are printed, not asserted, so a busy machine passes)
    while t_stop.elapsed() < Duration::from_secs(60) && cause_named.is_none() {
        if let Some(v) = hmi_status(hmi_port) {
            let at = t_stop.elapsed();
            answers += 1;
            if first_named.is_none() && link_lamp_names_the_link_down(&v, device_port) {
                first_named = Some((at, v.clone()));
            }
            if v["cause"]["kind"] == "link_down" {
                cause_named = Some((at, v));
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    signal(&d, libc::SIGTERM);
    let _ = wait(&mut d, Duration::from_secs(20), "controller", dir);
    drop(rt);

    let (at, v) = first_named.unwrap_or_else(|| {
        panic!(
            "the HMI's link lamp never named the Modbus link down within 60 s ({answers} answers)\n{}",
            logs(dir)
        )
    });
    eprintln!(
        "device stopped (abort took {:.1} ms); the HMI's data named the link down {:.0} ms after the stop (answer arrival, this process's monotonic clock; {answers} answers polled): links.modbus {}, field_faults {}",
        stopped_after.as_secs_f64() * 1e3,
        at.as_secs_f64() * 1e3,
        v["links"]["modbus"],
        v["field_faults"]
    );
    let (at_cause, c) = cause_named.unwrap_or_else(|| {
        panic!(
            "no fail-safe cause naming the link within 60 s of the stop\n{}",
            logs(dir)
        )
    });
    eprintln!(
        "the HMI's cause named the link {:.0} ms after the stop: {} ({})",
        at_cause.as_secs_f64() * 1e3,
        c["cause_text"],
        c["cause"]
    );
    // the cause is the link, not a sensor it carries (the inputs' 200-ms freshness and the
    // core's 250-ms failure hold come first)
    assert_eq!(c["cause"]["link"], "modbus", "{c}");
    assert!(
        c["cause_text"]
            .as_str()
            .is_some_and(|t| t.starts_with("Modbus link down")),
        "{c}"
    );
}
