//! What the operator sees on a running daemon (in-process plant): causes of a fail-safe in
//! the event log, the journal and `antisurge status`; the surge counter and safety-on steps
//! kept across kill -9; operator actions refused without the token.

use crate::common;

use common::daemon::{logs, shipped, wait};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_antisurge")
}

/// A config in `dir` for the in-process plant with `scenario` (a file in `dir`) and `extra`
/// TOML appended.
fn config(dir: &Path, scenario: &str, extra: &str) -> PathBuf {
    let text = format!(
        r#"[plant]
file = "{plant}"
[control]
law = "recycle-pi"
[cycle]
rate_hz = 1000.0
lock_memory = false
[event_log]
path = "{dir}/events.jsonl"
fsync = "always"
[simulation]
scenario = "{dir}/{scenario}"
[status]
socket = "{dir}/status.sock"
state_dir = "{dir}/state"
metrics_listen = ""
hmi_listen = ""
operator_token_file = "{dir}/operator.token"
{extra}
"#,
        plant = shipped("plants/kvangardsnes2009_recycle.toml"),
        dir = dir.display(),
    );
    let p = dir.join("antisurge.toml");
    std::fs::write(&p, text).expect("config");
    p
}

fn start(dir: &Path, name: &str, cfg: &Path) -> Child {
    let log = std::fs::File::create(dir.join(format!("{name}.log"))).expect("log");
    Command::new(bin())
        .args(["run", "--config", &cfg.display().to_string()])
        .current_dir(dir)
        .env("ANTISURGE_LOG", "info")
        .env_remove("LOGS_DIRECTORY")
        .env_remove("STATE_DIRECTORY")
        .env_remove("RUNTIME_DIRECTORY")
        .stdout(Stdio::from(log.try_clone().expect("clone")))
        .stderr(Stdio::from(log))
        .spawn()
        .expect("spawn")
}

fn status(dir: &Path, json: bool) -> Option<String> {
    let sock = dir.join("status.sock").display().to_string();
    let mut args = vec!["status", "--socket", &sock];
    if json {
        args.push("--json");
    }
    let out = Command::new(bin()).args(&args).output().expect("status");
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).into_owned())
}

fn status_json(dir: &Path) -> Option<serde_json::Value> {
    status(dir, true).and_then(|s| serde_json::from_str(&s).ok())
}

/// Poll the status until `pred` holds (at most `limit`).
fn until(
    dir: &Path,
    limit: Duration,
    what: &str,
    pred: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let t0 = Instant::now();
    let mut last = None;
    while t0.elapsed() < limit {
        if let Some(v) = status_json(dir) {
            if pred(&v) {
                return v;
            }
            last = Some(v);
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!(
        "{what}: not reached in {limit:?}; last status {last:#?}\n{}",
        logs(dir)
    );
}

fn stop(child: &mut Child, dir: &Path) {
    common::daemon::signal(child, libc::SIGTERM);
    wait(child, Duration::from_secs(10), "daemon", dir);
}

#[test]
fn each_input_fault_is_named_in_events_journal_and_status() {
    for (fault_toml, fault) in [
        (r#"fault = "stale""#, "stale"),
        (r#"fault = "nan""#, "nan"),
        (r#"fault = "value", value = 5.0e7"#, "out_of_range"),
    ] {
        let tmp = tempfile::tempdir().expect("tmp");
        let dir = tmp.path();
        std::fs::write(
            dir.join("fault.toml"),
            format!(
                "name = \"fault\"\ndescription = \"p_discharge fails\"\nduration_s = 30.0\n\
                 [[event]]\nat_s = 1.5\nsensor_fault = {{ sensor = \"p_discharge\", {fault_toml} }}\n"
            ),
        )
        .expect("scenario");
        let cfg = config(dir, "fault.toml", "");
        let mut d = start(dir, "run", &cfg);
        until(dir, Duration::from_secs(10), "auto", |v| {
            v["mode"] == "auto"
        });
        let v = until(dir, Duration::from_secs(10), "fail-safe", |v| {
            v["mode"] == "fail_safe"
        });
        assert_eq!(v["cause"]["input"], "p_discharge", "{fault}: {v:#}");
        assert_eq!(v["cause"]["fault"], fault, "{v:#}");
        assert_eq!(v["faults"][0]["input"], "p_discharge", "{v:#}");
        let text = status(dir, false).expect("status");
        assert!(
            text.contains("mode          fail_safe") && text.contains("cause         p_discharge"),
            "{text}"
        );
        let status_line = match fault {
            "stale" => "stale",
            "nan" => "not a number",
            _ => "out of range: 5.000e7 Pa",
        };
        assert!(text.contains(status_line), "{fault}: {text}");
        stop(&mut d, dir);

        let events = std::fs::read_to_string(dir.join("events.jsonl")).expect("events");
        let line = events
            .lines()
            .find(|l| l.contains(r#""event":"mode_changed""#) && l.contains(r#""to":"fail_safe""#))
            .unwrap_or_else(|| panic!("no mode_changed to fail_safe:\n{events}"));
        let e: serde_json::Value = serde_json::from_str(line).expect("json");
        assert_eq!(e["cause"]["input"], "p_discharge", "{line}");
        assert_eq!(e["cause"]["fault"], fault, "{line}");
        assert_eq!(e["cause"]["kind"], "input_fault", "{line}");
        let journal = std::fs::read_to_string(dir.join("run.log")).expect("log");
        let jl = journal
            .lines()
            .find(|l| l.contains("ERROR") && l.contains(r#"event="mode_changed""#))
            .unwrap_or_else(|| panic!("no ERROR journal line:\n{journal}"));
        assert!(
            jl.contains(r#"input="p_discharge""#) && jl.contains(&format!(r#"fault="{fault}""#)),
            "{jl}"
        );
        assert!(jl.contains(r#"to="fail_safe""#), "{jl}");
    }
}

/// A closure the weakly tuned controller (no trip) lets the machine surge once per run; three
/// runs each ended by kill -9 accumulate three surges and their safety-on steps.
#[test]
fn surge_counter_and_safety_on_survive_kill_9() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    std::fs::write(
        dir.join("closure.toml"),
        "name = \"deep-closure\"\ndescription = \"throttle to 10 %\"\nduration_s = 60.0\n\
         [initial]\nthrottle = 0.6\n\
         [[event]]\nat_s = 2.0\nramp = { signal = \"throttle\", to = 0.1, over_s = 1.0 }\n",
    )
    .expect("scenario");
    let weak = "[controller.recycle_pi.pi]\nkp_per_map_flow = 0.05\nki_per_map_flow_s = 0.02\n[controller.recycle_pi.trip]\nstep = 0.0\n";
    let cfg = config(dir, "closure.toml", weak);
    let mut seen = Vec::new();
    for run in 0..3u64 {
        let mut d = start(dir, &format!("run{run}"), &cfg);
        let v = until(dir, Duration::from_secs(15), "a surge", |v| {
            v["surge_count"].as_u64() == Some(run + 1)
        });
        seen.push((v["surge_count"].clone(), v["safety_on_count"].clone()));
        // the state file follows (its 50-ms period): kill once it holds what the status
        // showed, not after a fixed wall-clock wait (a busy machine may write it later)
        let state = dir.join("state/state.json");
        let t0 = std::time::Instant::now();
        while !std::fs::read_to_string(&state)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .is_some_and(|k| {
                k["surge_count"] == v["surge_count"] && k["safety_on_count"] == v["safety_on_count"]
            })
        {
            assert!(
                t0.elapsed() < Duration::from_secs(60),
                "the state file never showed {v:#}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        d.kill().expect("kill -9");
        let _ = d.wait();
    }
    let before = seen.last().cloned().expect("runs");
    assert_eq!(before.0, 3, "{seen:?}");
    assert!(before.1.as_u64().unwrap_or(0) >= 1, "{seen:?}");
    let mut d = start(dir, "after", &cfg);
    let v = until(dir, Duration::from_secs(10), "restored", |v| {
        v["mode"] == "auto"
    });
    assert_eq!(v["surge_count"], before.0, "{v:#}");
    assert_eq!(v["safety_on_count"], before.1, "{v:#}");

    // operator actions: refused without the token (nothing changes), applied with it
    let sock = dir.join("status.sock").display().to_string();
    let op = |token_file: &Path, words: &[&str]| {
        let tf = token_file.display().to_string();
        let mut args = vec!["operate", "--socket", &sock, "--token-file", &tf];
        args.extend_from_slice(words);
        Command::new(bin()).args(&args).output().expect("operate")
    };
    let wrong = dir.join("wrong.token");
    std::fs::write(&wrong, "guess\n").expect("token");
    let out = op(&wrong, &["reset-surge-counter"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("unauthorized"), "{err}");
    std::thread::sleep(Duration::from_millis(200));
    assert_eq!(status_json(dir).expect("status")["surge_count"], 3);

    let token = dir.join("operator.token");
    std::fs::write(&token, "s3cret\n").expect("token");
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o640)).expect("chmod");
    let out = op(&token, &["reset-surge-counter"]);
    assert!(out.status.success(), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("surge counter 3 → 0"));
    until(dir, Duration::from_secs(3), "reset", |v| {
        v["surge_count"] == 0
    });
    stop(&mut d, dir);
    let events = std::fs::read_to_string(dir.join("events.jsonl")).expect("events");
    assert!(
        events.contains("operator action (uid") && events.contains(r#""event":"surge_counter""#),
        "{events}"
    );
}

fn http(port: u16, req: &str) -> (u16, String) {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).expect("connect");
    s.write_all(req.as_bytes()).expect("write");
    let mut out = String::new();
    s.read_to_string(&mut out).expect("read");
    let code = out
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    (code, out)
}

/// One Modbus TCP request to unit 1 (`pdu`: function code and data); returns the raw
/// response (MBAP header, then the function code at byte 7).
fn modbus(port: u16, pdu: &[u8]) -> Vec<u8> {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).expect("connect modbus");
    s.set_read_timeout(Some(Duration::from_secs(3)))
        .expect("timeout");
    let mut req = vec![0, 1, 0, 0, 0, (pdu.len() + 1) as u8, 1];
    req.extend_from_slice(pdu);
    s.write_all(&req).expect("write");
    let mut buf = [0u8; 64];
    let n = s.read(&mut buf).expect("read");
    buf[..n].to_vec()
}

fn post_op(port: u16, auth: Option<&str>, body: &str) -> (u16, String) {
    let auth = auth
        .map(|t| format!("Authorization: Bearer {t}\r\n"))
        .unwrap_or_default();
    http(
        port,
        &format!(
            "POST /api/op HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n{auth}Content-Length: {}\r\n\r\n{body}",
            body.len()
        ),
    )
}

#[test]
fn hmi_is_read_only_without_the_token() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    std::fs::write(
        dir.join("hold.toml"),
        "name = \"hold\"\ndescription = \"hold\"\nduration_s = 60.0\n",
    )
    .expect("scenario");
    let port = common::daemon::free_port();
    let mb_port = common::daemon::free_port();
    let cfg = config(dir, "hold.toml", "");
    let text = std::fs::read_to_string(&cfg).expect("cfg").replace(
        "hmi_listen = \"\"",
        &format!("hmi_listen = \"127.0.0.1:{port}\"\nmodbus_listen = \"127.0.0.1:{mb_port}\""),
    );
    std::fs::write(&cfg, text).expect("cfg");
    let token = dir.join("operator.token");
    std::fs::write(&token, "s3cret\n").expect("token");
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o640)).expect("chmod");
    let mut d = start(dir, "run", &cfg);
    until(dir, Duration::from_secs(10), "auto", |v| {
        v["mode"] == "auto"
    });

    // the DCS block: input registers 0-15 of unit 1 (mode 2 = auto); a write is refused
    std::thread::sleep(Duration::from_millis(300));
    let regs = modbus(mb_port, &[4, 0, 0, 0, 16]);
    assert_eq!(regs[7], 4, "{regs:?}");
    assert_eq!(
        u16::from_be_bytes([regs[9], regs[10]]),
        2,
        "mode word: {regs:?}"
    );
    let write = modbus(mb_port, &[6, 0, 0, 0, 1]);
    assert_eq!(write[7], 0x86, "a write must get an exception: {write:?}");

    let (code, page) = http(
        port,
        "GET / HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n",
    );
    assert_eq!(code, 200);
    assert!(page.contains("<canvas id=\"map\""), "{page}");
    let (code, body) = http(
        port,
        "GET /api/status HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n",
    );
    assert_eq!(code, 200, "{body}");
    assert!(body.contains("\"mode\":\"auto\""), "{body}");

    for auth in [None, Some("guess"), Some("")] {
        let (code, body) = post_op(port, auth, "manual 10");
        assert_eq!(code, 401, "{auth:?}: {body}");
    }
    let (code, _) = http(
        port,
        "PUT /api/op HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\nContent-Length: 4\r\n\r\nauto",
    );
    assert_eq!(code, 405);
    std::thread::sleep(Duration::from_millis(300));
    let v = status_json(dir).expect("status");
    assert_eq!(
        v["mode"], "auto",
        "an unauthenticated write changed the mode"
    );
    assert_eq!(v["auto_requested"], true);

    let (code, body) = post_op(port, Some("s3cret"), "manual 10");
    assert_eq!(code, 200, "{body}");
    assert!(body.contains("manual output"), "{body}");
    let v = until(dir, Duration::from_secs(3), "manual", |v| {
        v["mode"] == "manual"
    });
    assert_eq!(v["manual_output_pct"], 10.0, "{v:#}");
    stop(&mut d, dir);
    let events = std::fs::read_to_string(dir.join("events.jsonl")).expect("events");
    let actions: Vec<&str> = events
        .lines()
        .filter(|l| l.contains("operator action (HMI 127.0.0.1"))
        .collect();
    assert_eq!(actions.len(), 1, "{events}");
    assert!(actions[0].contains("mode auto → manual"), "{}", actions[0]);
    let manual = events
        .lines()
        .find(|l| l.contains(r#""to":"manual""#))
        .unwrap_or_else(|| panic!("{events}"));
    assert!(manual.contains(r#""kind":"operator""#), "{manual}");
}
