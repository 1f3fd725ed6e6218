//! A Modbus TCP skid for the HMI's end-to-end tests (`tests/operator/hmi_field_lamps.rs`,
//! `tests/operator/hmi_input_links.rs`): a device written here serves the independent vendor skid's
//! steady state (`tests/plants/vendor_skid_recycle.toml`, computed in process) with a little
//! noise on every reading (no transmitter looks frozen), Δp transmitters `b` (registers 11–12)
//! and `c` (13–14, an f32 NaN: no value), and a recycle valve stuck at 40 % whatever it is told;
//! `antisurge run` with the vendor-data machine (`config/machines/vendor_example.toml`) polls it
//! through the signal map a test gives; the test reads the web HMI's JSON and `antisurge
//! status --json`.

use super::daemon::shipped;
use super::root;
use antisurge::plant::file::PlantDescription;
use antisurge::plant::{PlantInputs, SimPlant};
use antisurge::vocab::signals::SensorId;
use std::future::Future;
use std::io::{Read, Write};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio_modbus::{ExceptionCode, Request, Response, SlaveRequest};

/// Input registers: 0–10 as `config/signals_vendor_modbus.toml` (f32 high word first; t_suction
/// i16 in 0.01 °C; valve position u16 in 1e-4), 11–14 Δp transmitters `b` and `c` (f32).
pub const INPUT_WORDS: usize = 15;
/// The valve command's holding register.
pub const VALVE_HOLDING: u16 = 102;
/// Where the stuck valve stays, fraction.
pub const STUCK_AT: f64 = 0.4;

/// splitmix64: the device's noise.
pub struct Rng(pub u64);

impl Rng {
    pub fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    /// `v` with a uniform relative noise of ± `rel`.
    pub fn noisy(&mut self, v: f64, rel: f64) -> f64 {
        v * (1.0 + rel * (2.0 * self.unit() - 1.0))
    }
}

pub fn f32_words(v: f64) -> [u16; 2] {
    let b = (v as f32).to_bits();
    [(b >> 16) as u16, b as u16]
}

pub fn fraction_word(v: f64) -> u16 {
    (v * 1e4).round().clamp(0.0, 65535.0) as u16
}

/// The device: the steady readings, its noise, and the last valve command written.
pub struct Device {
    /// The steady readings.
    pub steady: antisurge::vocab::signals::SensorSnapshot,
    /// The noise.
    pub rng: Rng,
    /// The last valve command written (NaN: none yet).
    pub valve_cmd: f64,
}

impl Device {
    /// The input registers now: each reading with its own ±0.2 % noise.
    pub fn words(&mut self) -> [u16; INPUT_WORDS] {
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

/// The device, shared with its service.
pub type Shared = Arc<Mutex<Device>>;

/// Lock the device (a poisoned lock still holds the device).
pub fn lock(s: &Shared) -> std::sync::MutexGuard<'_, Device> {
    s.lock().unwrap_or_else(|e| e.into_inner())
}

#[derive(Clone)]
pub struct DeviceService(pub Shared);

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
pub fn serve(listener: tokio::net::TcpListener, shared: Shared) -> tokio::task::JoinHandle<()> {
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
pub fn steady_readings() -> antisurge::vocab::signals::SensorSnapshot {
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

/// The controller's config: the shipped vendor example (machine, law, 50 Hz), `signal_map`
/// (its text), device port, event log, status socket and HMI port, 200-ms input freshness.
pub fn controller_config(dir: &Path, signal_map: &str, device_port: u16, hmi_port: u16) -> PathBuf {
    let map = dir.join("signals.toml");
    std::fs::write(&map, signal_map).expect("write map");
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
            &shipped("machines/vendor_example.toml"),
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
pub fn hmi_get(port: u16, path: &str) -> Option<(u16, String)> {
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
pub fn hmi_status(port: u16) -> Option<serde_json::Value> {
    match hmi_get(port, "/api/status")? {
        (200, body) => serde_json::from_str(&body).ok(),
        _ => None,
    }
}

/// A fresh device on the steady readings, served on a port-0 listener of `rt`: the device,
/// its port and its task (abort it to stop the device: listener and connections close).
pub fn start_device(rt: &tokio::runtime::Runtime) -> (Shared, u16, tokio::task::JoinHandle<()>) {
    let shared: Shared = Arc::new(Mutex::new(Device {
        steady: steady_readings(),
        rng: Rng(0x5EED),
        valve_cmd: f64::NAN,
    }));
    let listener = rt
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .expect("bind port 0");
    let port = listener.local_addr().expect("addr").port();
    let task = {
        let _g = rt.enter();
        serve(listener, Arc::clone(&shared))
    };
    (shared, port, task)
}

/// `antisurge status --json` on the daemon's status socket `dir/status.sock`.
pub fn status_json(dir: &Path) -> serde_json::Value {
    let out = status_cli(dir, &["--json"]);
    serde_json::from_str(&out).unwrap_or_else(|e| panic!("status --json: {e}: {out}"))
}

/// `antisurge status ARGS…` on the daemon's status socket `dir/status.sock`: its output.
pub fn status_cli(dir: &Path, args: &[&str]) -> String {
    let sock = dir.join("status.sock").display().to_string();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .arg("status")
        .args(args)
        .args(["--socket", &sock])
        .output()
        .expect("antisurge status");
    String::from_utf8_lossy(&out.stdout).into_owned()
}
