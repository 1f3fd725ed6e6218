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

/// Wall-clock (Unix) time now, s: taken just before a kill, to set against the plant's
/// record of the last heartbeat change.
pub fn unix_now_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .expect("clock after 1970")
        .as_secs_f64()
}

/// The plant's record of its device watchdog's first trip (`summary.json`,
/// `device_watchdog`): (t_fail_safe, t_last_beat) in plant time, s, and the last beat's
/// Unix time, s. Checks that the trace's `cmd_recycle_valve` is 1.0 from that step to the
/// end, and also returns the heartbeat age the device measured at the trip (monotonic
/// clock), s, and the trace step, s.
pub fn device_watchdog_trip(out: &Path) -> (f64, f64, f64, f64, f64) {
    let s = summary(out);
    let w = &s["device_watchdog"];
    let f = |k: &str| {
        w[k].as_f64()
            .unwrap_or_else(|| panic!("device_watchdog.{k} in {s:#}"))
    };
    let (t_fs, t_beat, beat_unix) = (f("failsafe_t_s"), f("last_beat_t_s"), f("last_beat_unix_s"));
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
    (t_fs, t_beat, beat_unix, age_s, dt)
}

/// Assert the device watchdog's timing from the plant's record (see
/// [`device_watchdog_trip`]): it failed the valve safe `timeout_s` after the last heartbeat
/// change it saw: the age it measured on the monotonic clock must exceed the timeout (the
/// check is `age > timeout`) by at most 5 ms; in plant time the fail-safe comes after the last
/// beat and at most the timeout + 5 ms after it (under load the plant skips late steps, so its
/// clock may lag the monotonic one: seen 196 ms for a 200-ms timeout, 293 ms for 300 ms). And
/// that last beat came at most one heartbeat period (`beat_period_s`, + 5 ms for the bus)
/// before the kill at `kill_unix_s`, i.e. the controller beat until it died. Returns
/// t_fs − t_last_beat, s.
pub fn assert_device_watchdog_timing(
    out: &Path,
    timeout_s: f64,
    beat_period_s: f64,
    kill_unix_s: f64,
    ctx: &str,
) -> f64 {
    let (t_fs, t_beat, beat_unix, age_s, dt) = device_watchdog_trip(out);
    let gap = t_fs - t_beat;
    const TOL_S: f64 = 0.005;
    eprintln!(
        "device watchdog: fail-safe at plant time {t_fs:.3} s, last beat {t_beat:.3} s: {:.1} ms after it, age {:.1} ms (timeout {:.0} ms, trace step {:.1} ms); last beat {:.1} ms before the kill",
        gap * 1e3,
        age_s * 1e3,
        timeout_s * 1e3,
        dt * 1e3,
        (kill_unix_s - beat_unix) * 1e3
    );
    // The timeout is judged on the monotonic clock (the age below); plant time may lag that
    // clock under load (late steps are skipped), so in plant time the fail-safe only has to
    // come after the last beat and no later than the timeout (seen: 293 ms for 300 ms on a
    // busy 2-core machine): an ordering and a bound, not an equality across two clocks.
    assert!(
        gap > 0.0 && gap <= timeout_s + TOL_S + 1e-6,
        "fail-safe {:.1} ms (plant time) after the last heartbeat change, timeout {:.0} ms (+ {:.0} ms): {ctx}",
        gap * 1e3,
        timeout_s * 1e3,
        TOL_S * 1e3
    );
    assert!(
        age_s > timeout_s && age_s <= timeout_s + TOL_S,
        "the device measured a heartbeat age of {:.1} ms at the trip, timeout {:.0} ms (+ {:.0} ms): {ctx}",
        age_s * 1e3,
        timeout_s * 1e3,
        TOL_S * 1e3
    );
    assert!(
        beat_unix >= kill_unix_s - beat_period_s - 0.005,
        "the last heartbeat change came {:.1} ms before the kill (period {:.0} ms): the controller stopped beating before it died: {ctx}",
        (kill_unix_s - beat_unix) * 1e3,
        beat_period_s * 1e3
    );
    assert!(
        beat_unix <= kill_unix_s + 0.05,
        "a heartbeat change {:.1} ms after the kill: {ctx}",
        (beat_unix - kill_unix_s) * 1e3
    );
    gap
}

/// The kill -9 scenario shared by the device-watchdog tests: let the pair run `after`, SIGKILL
/// the controller, let the plant finish its scenario (it must exit 0). Returns the Unix time of
/// the kill, s, the plant's summary and a context string (summary + logs) for assertions.
pub fn kill_controller_and_finish(
    plant: &mut Child,
    ctl: &mut Child,
    out: &Path,
    dir: &Path,
    after: Duration,
) -> (f64, serde_json::Value, String) {
    std::thread::sleep(after);
    let kill_unix_s = unix_now_s();
    signal(ctl, libc::SIGKILL);
    let _ = wait(ctl, Duration::from_secs(5), "killed controller", dir);
    let st = wait(plant, Duration::from_secs(60), "plant", dir);
    assert!(st.success(), "plant failed:\n{}", logs(dir));
    let s = summary(out);
    let ctx = format!("{s:#}\n{}", logs(dir));
    (kill_unix_s, s, ctx)
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
