//! Issue 23 ("Link down: ... the HMI lamp name the link within 1 s"; "each transmitter's value
//! and state in status and the HMI"; feedback faults "in events, status, HMI lamps") and issue
//! 24 (lamps for each link, each transmitter, feedback), end to end over Modbus TCP: `antisurge
//! run` with the vendor-data machine (`config/machines/vendor_example.toml`) polls a device
//! written here, and the test reads the web HMI's own JSON (`GET /api/status`, what
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

mod common;

use antisurge::plant::file::PlantDescription;
use antisurge::plant::{PlantInputs, SimPlant};
use antisurge::signals::SensorId;
use common::daemon::{free_port, logs, signal, spawn, until, wait};
use common::root;
use std::future::Future;
use std::io::{Read, Write};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio_modbus::{ExceptionCode, Request, Response, SlaveRequest};

/// Input registers: 0–10 as `config/signals_vendor_modbus.toml` (f32 high word first; t_suction
/// i16 in 0.01 °C; valve position u16 in 1e-4), 11–14 Δp transmitters `b` and `c` (f32).
const INPUT_WORDS: usize = 15;
/// The valve command's holding register.
const VALVE_HOLDING: u16 = 102;
/// Where the stuck valve stays, fraction.
const STUCK_AT: f64 = 0.4;

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

/// splitmix64: the device's noise.
struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    /// `v` with a uniform relative noise of ± `rel`.
    fn noisy(&mut self, v: f64, rel: f64) -> f64 {
        v * (1.0 + rel * (2.0 * self.unit() - 1.0))
    }
}

fn f32_words(v: f64) -> [u16; 2] {
    let b = (v as f32).to_bits();
    [(b >> 16) as u16, b as u16]
}

fn fraction_word(v: f64) -> u16 {
    (v * 1e4).round().clamp(0.0, 65535.0) as u16
}

/// The device: the steady readings, its noise, and the last valve command written.
struct Device {
    steady: antisurge::signals::SensorSnapshot,
    rng: Rng,
    valve_cmd: f64,
}

impl Device {
    /// The input registers now: each reading with its own ±0.2 % noise.
    fn words(&mut self) -> [u16; INPUT_WORDS] {
        let s = self.steady;
        let mut w = [0u16; INPUT_WORDS];
        let dp = s.get(SensorId::OrificeDp);
        w[0..2].copy_from_slice(&f32_words(self.rng.noisy(s.get(SensorId::PSuction), 0.002)));
        w[2..4].copy_from_slice(&f32_words(
            self.rng.noisy(s.get(SensorId::PDischarge), 0.002),
        ));
        w[6..8].copy_from_slice(&f32_words(self.rng.noisy(dp, 0.002)));
        let t_c = self.rng.noisy(s.get(SensorId::TSuction), 0.0005) - 273.15;
        w[8] = (t_c * 100.0).round() as i16 as u16;
        // stuck: the stem stays where it is whatever the command (a seized valve)
        w[9] = fraction_word(self.rng.noisy(STUCK_AT, 0.002));
        w[11..13].copy_from_slice(&f32_words(self.rng.noisy(dp, 0.002)));
        // transmitter c reads no value
        w[13..15].copy_from_slice(&f32_words(f64::NAN));
        w
    }
}

type Shared = Arc<Mutex<Device>>;

fn lock(s: &Shared) -> std::sync::MutexGuard<'_, Device> {
    s.lock().unwrap_or_else(|e| e.into_inner())
}

#[derive(Clone)]
struct DeviceService(Shared);

type ServiceFuture = Pin<Box<dyn Future<Output = Result<Option<Response>, ExceptionCode>> + Send>>;

impl tokio_modbus::server::Service for DeviceService {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = ServiceFuture;

    fn call(&self, req: Self::Request) -> Self::Future {
        let answer = if req.slave != 1 {
            Err(ExceptionCode::GatewayTargetDevice)
        } else {
            match req.request {
                Request::ReadInputRegisters(addr, cnt) => {
                    let (a, n) = (usize::from(addr), usize::from(cnt));
                    if n == 0 || a + n > INPUT_WORDS {
                        Err(ExceptionCode::IllegalDataAddress)
                    } else {
                        let w = lock(&self.0).words();
                        Ok(Some(Response::ReadInputRegisters(w[a..a + n].to_vec())))
                    }
                }
                Request::ReadHoldingRegisters(VALVE_HOLDING, 1) => {
                    let cmd = lock(&self.0).valve_cmd;
                    Ok(Some(Response::ReadHoldingRegisters(vec![fraction_word(
                        cmd.max(0.0),
                    )])))
                }
                Request::WriteSingleRegister(VALVE_HOLDING, word) => {
                    lock(&self.0).valve_cmd = f64::from(word) * 1e-4;
                    Ok(Some(Response::WriteSingleRegister(VALVE_HOLDING, word)))
                }
                Request::WriteMultipleRegisters(VALVE_HOLDING, ref words) if words.len() == 1 => {
                    lock(&self.0).valve_cmd = f64::from(words[0]) * 1e-4;
                    Ok(Some(Response::WriteMultipleRegisters(VALVE_HOLDING, 1)))
                }
                Request::WriteSingleRegister(..) | Request::WriteMultipleRegisters(..) => {
                    Err(ExceptionCode::IllegalDataAddress)
                }
                _ => Err(ExceptionCode::IllegalFunction),
            }
        };
        Box::pin(std::future::ready(answer))
    }
}

/// Serve the device on `listener` until the task is aborted (listener and connections close).
fn serve(listener: tokio::net::TcpListener, shared: Shared) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let server = tokio_modbus::server::tcp::Server::new(listener);
        let on_connected = move |stream: tokio::net::TcpStream, _peer: SocketAddr| {
            let service = DeviceService(Arc::clone(&shared));
            async move {
                stream.set_nodelay(true)?;
                Ok(Some((service, stream)))
            }
        };
        let _ = server.serve(&on_connected, |_e| {}).await;
    })
}

/// The vendor skid's steady readings at its initial throttle and valve.
fn steady_readings() -> antisurge::signals::SensorSnapshot {
    let desc = PlantDescription::load(&root().join("tests/plants/vendor_skid_recycle.toml"))
        .unwrap_or_else(|e| panic!("{e}"));
    let init = &desc.file.initial;
    let inputs = PlantInputs {
        throttle_process: init.throttle,
        recycle_manual: init.recycle_valve,
        feed: init.feed,
        ..PlantInputs::default()
    };
    SimPlant::new(&desc, &inputs)
        .unwrap_or_else(|e| panic!("{e}"))
        .sensors()
}

/// The controller's config: the shipped vendor example (machine, law, 50 Hz), this test's
/// map, device port, event log, status socket and HMI port, 200-ms input freshness.
fn controller_config(dir: &Path, device_port: u16, hmi_port: u16) -> PathBuf {
    let map = dir.join("signals.toml");
    std::fs::write(&map, SIGNAL_MAP).expect("write map");
    let token = dir.join("operator.token");
    std::fs::write(&token, "lamps-token\n").expect("token");
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    }
    let mut cfg = std::fs::read_to_string(root().join("config/vendor_example.toml"))
        .expect("vendor example")
        .replace(
            "machines/vendor_example.toml",
            &common::daemon::shipped("machines/vendor_example.toml"),
        )
        .replace("signals_vendor_modbus.toml", &map.display().to_string())
        .replace("127.0.0.1:5020", &format!("127.0.0.1:{device_port}"));
    cfg += &format!(
        r#"timeout_ms = 100
[event_log]
path = "{events}"
[status]
log_interval_s = 5.0
socket = "{socket}"
operator_token_file = "{token}"
metrics_listen = ""
hmi_listen = "127.0.0.1:{hmi_port}"
"#,
        events = dir.join("events.jsonl").display(),
        socket = dir.join("status.sock").display(),
        token = token.display(),
    );
    for (s, min, max) in [
        ("p_suction", 1.0e4, 1.2e7),
        ("p_discharge", 1.0e4, 1.2e7),
        ("orifice_dp", -1.0e5, 1.0e6),
        ("t_suction", 200.0, 400.0),
        ("recycle_valve_position", -0.05, 1.05),
    ] {
        cfg += &format!("[inputs.{s}]\nmin = {min:e}\nmax = {max:e}\ntimeout_ms = 200.0\n");
    }
    let path = dir.join("antisurge.toml");
    std::fs::write(&path, cfg).expect("write config");
    path
}

/// `GET path` on the HMI (plain HTTP on loopback, `Host: localhost`): status code and body.
fn hmi_get(port: u16, path: &str) -> Option<(u16, String)> {
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut text = String::new();
    s.read_to_string(&mut text).ok()?;
    let code = text.split(' ').nth(1)?.parse().ok()?;
    let body = text.split_once("\r\n\r\n")?.1.to_string();
    Some((code, body))
}

/// The HMI's status JSON (what the page draws from), if it answers 200.
fn hmi_status(port: u16) -> Option<serde_json::Value> {
    match hmi_get(port, "/api/status")? {
        (200, body) => serde_json::from_str(&body).ok(),
        _ => None,
    }
}

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
fn the_hmi_data_names_a_voted_out_transmitter_the_feedback_mismatch_and_the_link_down_within_1_s() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let shared: Shared = Arc::new(Mutex::new(Device {
        steady: steady_readings(),
        rng: Rng(0x5EED),
        valve_cmd: f64::NAN,
    }));
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime");
    let listener = rt
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .expect("bind port 0");
    let device_port = listener.local_addr().expect("addr").port();
    let server = {
        let _g = rt.enter();
        serve(listener, Arc::clone(&shared))
    };
    let hmi_port = free_port();
    let cfg = controller_config(dir, device_port, hmi_port);
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
    let sock = dir.join("status.sock").display().to_string();
    let status: serde_json::Value = serde_json::from_slice(
        &std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
            .args(["status", "--json", "--socket", &sock])
            .output()
            .expect("status")
            .stdout,
    )
    .expect("status json");
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
    while t_stop.elapsed() < Duration::from_secs(5) && cause_named.is_none() {
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
            "the HMI's link lamp never named the Modbus link down within 5 s ({answers} answers)\n{}",
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
    assert!(
        at <= Duration::from_secs(1),
        "the HMI's link lamp named the link {:.0} ms after the device stopped (at most 1 s)",
        at.as_secs_f64() * 1e3
    );
    let (at_cause, c) = cause_named.unwrap_or_else(|| {
        panic!(
            "no fail-safe cause naming the link within 5 s of the stop\n{}",
            logs(dir)
        )
    });
    eprintln!(
        "the HMI's cause named the link {:.0} ms after the stop: {} ({})",
        at_cause.as_secs_f64() * 1e3,
        c["cause_text"],
        c["cause"]
    );
    // the cause is the link, not a sensor it carries, within 1 s too (the inputs' 200-ms
    // freshness and the core's 250-ms failure hold come first)
    assert!(
        at_cause <= Duration::from_secs(1),
        "the HMI's cause named the link {:.0} ms after the device stopped (at most 1 s)",
        at_cause.as_secs_f64() * 1e3
    );
    assert_eq!(c["cause"]["link"], "modbus", "{c}");
    assert!(
        c["cause_text"]
            .as_str()
            .is_some_and(|t| t.starts_with("Modbus link down")),
        "{c}"
    );
}
