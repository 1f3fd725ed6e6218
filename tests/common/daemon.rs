//! Helpers for the end-to-end daemon tests: config files in a temporary directory, the
//! `antisurge` binary as child processes, summaries and traces read back.

use super::root;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The controller part of a 50-Hz recycle-pi daemon config on the kvangardsnes2009 skid
/// over a field bus: law, cycle and input supervision (200 ms freshness for a 50 Hz poll).
pub const RECYCLE_PI_50HZ: &str = r#"[control]
law = "recycle-pi"
[cycle]
rate_hz = 50.0
lock_memory = false
[inputs.p_suction]
min = 1.0e4
max = 1.2e7
timeout_ms = 200.0
[inputs.p_discharge]
min = 1.0e4
max = 1.2e7
timeout_ms = 200.0
[inputs.shaft_speed]
min = 0.0
max = 2000.0
timeout_ms = 200.0
[inputs.orifice_dp]
min = -1.0e5
max = 1.0e6
timeout_ms = 200.0
[inputs.recycle_valve_position]
min = -0.05
max = 1.05
timeout_ms = 200.0
[inputs.throttle_position]
min = -0.05
max = 1.05
timeout_ms = 200.0"#;

/// A free TCP port on 127.0.0.1 (bound, then released).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .expect("bind")
        .local_addr()
        .expect("addr")
        .port()
}

/// Absolute path of a shipped config file.
pub fn shipped(rel: &str) -> String {
    root().join("config").join(rel).display().to_string()
}

/// The operator surfaces a `run` must not share with the other tests' daemons (issue 24: a
/// surface that cannot be bound stops the start): for each `[status]` key the config named
/// by `--config` does not set, the environment override that keeps it to this test (its own
/// status socket in `dir`; the HMI and metrics ports, one per machine by default, off).
pub fn own_surfaces(dir: &Path, args: &[&str]) -> Vec<(&'static str, String)> {
    let text = args
        .iter()
        .position(|a| *a == "--config")
        .and_then(|i| args.get(i + 1))
        // (only a regular file of sane size: the tests also pass /dev/zero and FIFOs, which
        // a plain read would never finish)
        .filter(|p| std::fs::metadata(p).is_ok_and(|m| m.is_file() && m.len() < 1 << 20))
        .and_then(|p| std::fs::read_to_string(p).ok());
    let Some(text) = text.filter(|_| args.first() == Some(&"run")) else {
        return Vec::new();
    };
    let set = |key: &str| {
        text.lines()
            .any(|l| l.trim_start().starts_with(key) && l.contains('='))
    };
    let mut env = Vec::new();
    if !set("socket") {
        env.push((
            "ANTISURGE_STATUS__SOCKET",
            dir.join("status.sock").display().to_string(),
        ));
    }
    if !set("hmi_listen") {
        env.push(("ANTISURGE_STATUS__HMI_LISTEN", String::new()));
    }
    if !set("metrics_listen") {
        env.push(("ANTISURGE_STATUS__METRICS_LISTEN", String::new()));
    }
    env
}

/// Start `antisurge <args>` with its output in `dir/<name>.log` (a `run` gets the surfaces
/// of [`own_surfaces`]).
pub fn spawn(dir: &Path, name: &str, args: &[&str]) -> Child {
    let log = std::fs::File::create(dir.join(format!("{name}.log"))).expect("log file");
    Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .envs(own_surfaces(dir, args))
        .args(args)
        .env("ANTISURGE_LOG", "info")
        .env_remove("LOGS_DIRECTORY")
        // every test keeps its own persistent state (surge counter, safety-on shifts): the
        // default ./out/state is shared by every run from the checkout
        .env_remove("STATE_DIRECTORY")
        .env("ANTISURGE_STATUS__STATE_DIR", dir.join("state"))
        .stdout(Stdio::from(log.try_clone().expect("clone")))
        .stderr(Stdio::from(log))
        .spawn()
        .expect("spawn antisurge")
}

/// Wait for a child to exit, at most `limit`; kills it and panics on timeout.
pub fn wait(
    child: &mut Child,
    limit: Duration,
    what: &str,
    dir: &Path,
) -> std::process::ExitStatus {
    let t0 = Instant::now();
    loop {
        if let Some(s) = child.try_wait().expect("try_wait") {
            return s;
        }
        if t0.elapsed() > limit {
            let _ = child.kill();
            panic!(
                "{what} did not finish within {limit:?}; logs:\n{}",
                logs(dir)
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Send a signal to a child.
pub fn signal(child: &Child, sig: i32) {
    // SAFETY: kill(2) on our own child's pid.
    unsafe {
        libc::kill(child.id() as i32, sig);
    }
}

/// All `*.log` files of `dir`, for failure messages.
pub fn logs(dir: &Path) -> String {
    let mut out = String::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            if p.extension().is_some_and(|x| x == "log") {
                out += &format!(
                    "--- {}\n{}\n",
                    p.display(),
                    std::fs::read_to_string(&p).unwrap_or_default()
                );
            }
        }
    }
    out
}

/// A parsed summary.json.
pub fn summary(dir: &Path) -> serde_json::Value {
    let p = dir.join("summary.json");
    let text = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    serde_json::from_str(&text).expect("summary json")
}

/// One column of a trace.csv with its time column.
pub fn column(dir: &Path, name: &str) -> Vec<(f64, f64)> {
    let mut r = csv::Reader::from_path(dir.join("trace.csv")).expect("trace.csv");
    let headers = r.headers().expect("headers").clone();
    let i = headers
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("no column {name}"));
    r.records()
        .map(|rec| {
            let rec = rec.expect("row");
            (
                rec[0].parse().unwrap_or(f64::NAN),
                rec[i].parse().unwrap_or(f64::NAN),
            )
        })
        .collect()
}

/// The daemon config the reload tests run: kvangardsnes2009's recycle plant in process at
/// 100 Hz running `scenario` (held at its end), event log and status socket in `dir`, with
/// `control` added to `[control]` and `rest` after the shared sections.
pub fn embedded_config(dir: &Path, scenario: &str, control: &str, rest: &str) -> String {
    format!(
        r#"[plant]
file = "{plant}"
[control]
law = "recycle-pi"
{control}[cycle]
rate_hz = 100.0
lock_memory = false
[event_log]
path = "{events}"
fsync = "always"
[simulation]
scenario = "{scenario}"
hold_after_end = true
[status]
log_interval_s = 0.0
socket = "{socket}"
metrics_listen = ""
hmi_listen = ""
{rest}"#,
        plant = shipped("plants/kvangardsnes2009_recycle.toml"),
        events = dir.join("events.jsonl").display(),
        socket = dir.join("status.sock").display(),
    )
}

/// Write `text` to `path` the way editors do: a temporary file renamed over the target.
pub fn write_atomically(path: &Path, text: &str) {
    let tmp: PathBuf = path.with_extension("toml.tmp~");
    std::fs::write(&tmp, text).expect("write tmp");
    std::fs::rename(&tmp, path).expect("rename");
}

/// The Modbus TCP links of a kvangardsnes2009 recycle-pi e2e config: where the controller
/// connects (`client_port`, the plant itself or a relay in front of it), where `antisurge
/// plant` listens, the scenario, the plant's heartbeat timeout and any extra
/// `[bus.modbus.client]` lines (backoff settings).
pub struct ModbusE2e<'a> {
    pub client_port: u16,
    pub plant_port: u16,
    pub scenario: &'a str,
    pub heartbeat_timeout_ms: f64,
    pub client_extra: &'a str,
}

/// Write `dir/antisurge.toml`: the 50-Hz recycle-pi controller on kvangardsnes2009 over the
/// shipped Modbus signal map, the plant node's server on the same file, and return its path.
pub fn write_modbus_e2e_config(dir: &Path, m: &ModbusE2e) -> PathBuf {
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
heartbeat_register = {{ unit_id = 1, address = 300 }}
[bus.modbus.client]
timeout_ms = 100
{client_extra}
transport = {{ kind = "tcp", address = "127.0.0.1:{client_port}" }}
[event_log]
path = "{events}"
[simulation]
scenario = "{scenario}"
heartbeat_timeout_ms = {hb:.1}
[simulation.modbus_server]
listen = "127.0.0.1:{plant_port}"
heartbeat_register = {{ unit_id = 1, address = 300 }}
[status]
log_interval_s = 5.0
"#,
        recycle_pi_50hz = RECYCLE_PI_50HZ,
        plant = shipped("plants/kvangardsnes2009_recycle.toml"),
        map = shipped("signals_modbus.toml"),
        events = dir.join("events.jsonl").display(),
        client_extra = m.client_extra,
        client_port = m.client_port,
        scenario = m.scenario,
        hb = m.heartbeat_timeout_ms,
        plant_port = m.plant_port,
    );
    let path = dir.join("antisurge.toml");
    std::fs::write(&path, cfg).expect("write config");
    path
}

/// The plant's time now, s, as far as its trace in `out` shows: the time of the last whole row
/// of `out/trace.csv` (the plant flushes whole lines every 0.5 s; None before its first row).
pub fn plant_time_s(out: &Path) -> Option<f64> {
    let text = std::fs::read_to_string(out.join("trace.csv")).ok()?;
    let whole = &text[..text.rfind('\n')?];
    whole
        .lines()
        .skip(1)
        .last()?
        .split(',')
        .next()?
        .parse()
        .ok()
}

/// The plant's record of its device watchdog's first trip (`summary.json`,
/// `device_watchdog`): (t_fail_safe, t_last_beat) in plant time, s. Checks that the trace's
/// `cmd_recycle_valve` is 1.0 from that step to the end, and also returns the heartbeat age
/// the device measured at the trip (its monotonic clock), s, and the trace step, s.
pub fn device_watchdog_trip(out: &Path) -> (f64, f64, f64, f64) {
    let s = summary(out);
    let w = &s["device_watchdog"];
    let f = |k: &str| {
        w[k].as_f64()
            .unwrap_or_else(|| panic!("device_watchdog.{k} in {s:#}"))
    };
    let (t_fs, t_beat) = (f("failsafe_t_s"), f("last_beat_t_s"));
    let age_s = f("age_s");
    let cmd = column(out, "cmd_recycle_valve");
    let dt = cmd[1].0 - cmd[0].0;
    // the trace is decimated (one row every `dt`, the plant steps faster): the first row at
    // or after the record's fail-safe step, and every later row, carry the device's
    // fail-safe command (the controller may itself have commanded 100 % before)
    let from = cmd
        .iter()
        .position(|(t, _)| *t >= t_fs - 1e-9)
        .expect("trace rows after the recorded fail-safe");
    assert!(
        cmd[from].0 - t_fs < dt && cmd[from..].iter().all(|(_, v)| *v >= 0.999),
        "the trace does not hold the valve command at 100 % from the plant's recorded fail-safe at {t_fs:.4} s: {:?}",
        &cmd[from.saturating_sub(2)..(from + 4).min(cmd.len())]
    );
    (t_fs, t_beat, age_s, dt)
}

/// Assert the device watchdog's timing from the plant's record (see
/// [`device_watchdog_trip`]), each check on ONE clock, each holding however loaded the
/// machine is, each failing for a watchdog that trips early, late or before the kill:
/// - not early: the heartbeat age the device measured at the trip, on its monotonic clock,
///   exceeds `timeout_s` (load only makes the age larger);
/// - not late: in plant time, the fail-safe step comes after the step that saw the last
///   heartbeat change and at most `timeout_s` + 5 ms after it. The plant steps every 1 ms
///   on deadlines it skips (never catches up) when it runs late, so its clock never runs
///   ahead of the monotonic one by more than a step or two: load only makes this gap
///   smaller (293 ms of plant time for a 300.1-ms age was seen on a busy 2-core box);
/// - caused by the kill: the fail-safe comes after `killed_at_plant_s`, a plant time the
///   plant's trace had already reached when the test sent SIGKILL (so the controller kept
///   the device alive until it died; callers also check there was one fail-safe entry).
///
/// Returns t_fs − t_last_beat, s (plant time).
pub fn assert_device_watchdog_timing(
    out: &Path,
    timeout_s: f64,
    killed_at_plant_s: f64,
    ctx: &str,
) -> f64 {
    let (t_fs, t_beat, age_s, dt) = device_watchdog_trip(out);
    let gap = t_fs - t_beat;
    const TOL_S: f64 = 0.005;
    eprintln!(
        "device watchdog: fail-safe at plant time {t_fs:.3} s, last beat {t_beat:.3} s: {:.1} ms after it, age {:.1} ms (timeout {:.0} ms, trace step {:.1} ms); kill at plant time >= {killed_at_plant_s:.3} s",
        gap * 1e3,
        age_s * 1e3,
        timeout_s * 1e3,
        dt * 1e3,
    );
    assert!(
        age_s > timeout_s,
        "the device measured a heartbeat age of {:.1} ms at the trip, timeout {:.0} ms: it tripped early: {ctx}",
        age_s * 1e3,
        timeout_s * 1e3,
    );
    assert!(
        gap > 0.0 && gap <= timeout_s + TOL_S + 1e-6,
        "fail-safe {:.1} ms (plant time) after the last heartbeat change, timeout {:.0} ms (+ {:.0} ms): {ctx}",
        gap * 1e3,
        timeout_s * 1e3,
        TOL_S * 1e3
    );
    assert!(
        t_fs > killed_at_plant_s,
        "fail-safe at plant time {t_fs:.3} s, before the kill (plant time >= {killed_at_plant_s:.3} s): the controller stopped beating before it died: {ctx}"
    );
    gap
}

/// The kill -9 scenario shared by the device-watchdog tests: let the pair run until the
/// plant's own clock (its trace) has reached `at_plant_s`, SIGKILL the controller, let the
/// plant finish its scenario (it must exit 0). Returns the plant time the trace showed at the
/// kill, s (the plant's clock was at least there), the plant's summary and a context string
/// (summary + logs) for assertions.
pub fn kill_controller_at_plant_time(
    plant: &mut Child,
    ctl: &mut Child,
    out: &Path,
    dir: &Path,
    at_plant_s: f64,
) -> (f64, serde_json::Value, String) {
    let mut seen = None;
    until(
        dir,
        &format!("plant time {at_plant_s} s in the trace"),
        || {
            seen = plant_time_s(out).filter(|t| *t >= at_plant_s);
            seen.is_some()
        },
    );
    let killed_at_plant_s = seen.expect("plant time");
    signal(ctl, libc::SIGKILL);
    let _ = wait(ctl, Duration::from_secs(5), "killed controller", dir);
    let st = wait(plant, Duration::from_secs(60), "plant", dir);
    assert!(st.success(), "plant failed:\n{}", logs(dir));
    let s = summary(out);
    let ctx = format!("{s:#}\n{}", logs(dir));
    (killed_at_plant_s, s, ctx)
}

/// Events of `kind` in the event log at `events`.
pub fn count(events: &Path, kind: &str) -> usize {
    std::fs::read_to_string(events)
        .unwrap_or_default()
        .lines()
        .filter(|l| l.contains(&format!("\"event\":\"{kind}\"")))
        .count()
}

/// Wait until `f` holds (a liveness bound of 60 s, with the daemon's logs in `dir` on failure).
pub fn until(dir: &Path, what: &str, mut f: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !f() {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "gave up waiting for {what}:\n{}",
            logs(dir)
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}
