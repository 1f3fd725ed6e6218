//! Issue 24: the operator station cannot be turned against the machine.
//!
//! - a squatted HMI port stops the start (exit 69, a message naming the address and that
//!   another process holds it);
//! - a token file others may write (0642) is refused at start (exit 78) and at reload;
//! - 1 000 wrong-token requests: 401 up to the limit, 429 after it (the right token too),
//!   one journal line and one event with the count;
//! - `HEAD /` answers 200, and a connection is kept alive between requests;
//! - a flood of `GET /api/events` (200 requests/s) is served off the real-time threads
//!   (counted by the handling thread itself) and the Modbus link keeps its poll period within
//!   20 %. `ANTISURGE_FLOOD_S` sets the flood's length (default 10 s; `.ci/station_flood.sh`
//!   runs 60 s beside an unflooded minute and prints the figures README.md records).

use crate::common;

use common::daemon::{
    embedded_config, free_port, logs, signal, spawn, until, wait, write_modbus_e2e_config,
    ModbusE2e,
};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::Child;
use std::time::{Duration, Instant};

/// A held scenario for the in-process plant.
fn hold(dir: &Path) -> String {
    let p = dir.join("hold.toml");
    std::fs::write(
        &p,
        "name = \"hold\"\ndescription = \"hold\"\nduration_s = 600.0\n",
    )
    .expect("scenario");
    p.display().to_string()
}

fn token(dir: &Path, mode: u32) -> PathBuf {
    let p = dir.join("operator.token");
    std::fs::write(&p, "s3cret\n").expect("token");
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(mode)).expect("chmod");
    p
}

/// The in-process daemon config with the HMI on `hmi` (None: off) and the token file.
fn config(dir: &Path, hmi: Option<u16>) -> PathBuf {
    let text = embedded_config(
        dir,
        &hold(dir),
        "",
        &format!(
            "operator_token_file = \"{}\"\n[reload]\nwatch_files = false\n",
            dir.join("operator.token").display()
        ),
    );
    let text = match hmi {
        Some(port) => text.replace(
            "hmi_listen = \"\"",
            &format!("hmi_listen = \"127.0.0.1:{port}\""),
        ),
        None => text,
    };
    let p = dir.join("antisurge.toml");
    std::fs::write(&p, text).expect("config");
    p
}

/// A keep-alive HTTP/1.1 client: one request, its status and body.
struct Client {
    rd: BufReader<TcpStream>,
    wr: TcpStream,
}

impl Client {
    fn connect(port: u16) -> Client {
        let s = TcpStream::connect(("127.0.0.1", port)).expect("connect");
        s.set_read_timeout(Some(Duration::from_secs(10)))
            .expect("timeout");
        s.set_nodelay(true).expect("nodelay");
        Client {
            rd: BufReader::new(s.try_clone().expect("clone")),
            wr: s,
        }
    }

    fn request(
        &mut self,
        method: &str,
        path: &str,
        headers: &str,
        body: &str,
    ) -> std::io::Result<(u16, String)> {
        // one write (a request in pieces meets Nagle and the delayed ACK: 40 ms each)
        let req = format!(
            "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n{headers}Content-Length: {}\r\n\r\n{body}",
            body.len()
        );
        self.wr.write_all(req.as_bytes())?;
        let mut line = String::new();
        self.rd.read_line(&mut line)?;
        let code: u16 = line
            .split_whitespace()
            .nth(1)
            .and_then(|c| c.parse().ok())
            .ok_or_else(|| std::io::Error::other(format!("status line `{line}`")))?;
        let mut len = 0usize;
        loop {
            let mut h = String::new();
            self.rd.read_line(&mut h)?;
            if h.trim().is_empty() {
                break;
            }
            if let Some((k, v)) = h.split_once(':') {
                if k.eq_ignore_ascii_case("content-length") {
                    len = v.trim().parse().unwrap_or(0);
                }
            }
        }
        let mut b = vec![0u8; if method == "HEAD" { 0 } else { len }];
        self.rd.read_exact(&mut b)?;
        Ok((code, String::from_utf8_lossy(&b).into_owned()))
    }

    fn get(&mut self, path: &str) -> (u16, String) {
        self.request("GET", path, "", "").expect("GET")
    }
}

fn wait_for_hmi(port: u16, dir: &Path) {
    until(dir, "the HMI to answer", || {
        TcpStream::connect(("127.0.0.1", port)).is_ok_and(|s| {
            let mut c = Client {
                rd: BufReader::new(s.try_clone().expect("clone")),
                wr: s,
            };
            c.request("GET", "/api/status", "", "")
                .is_ok_and(|(code, _)| code == 200)
        })
    });
}

fn stop(d: &mut Child, dir: &Path) {
    signal(d, libc::SIGTERM);
    wait(d, Duration::from_secs(20), "daemon", dir);
}

#[test]
fn a_squatted_hmi_port_stops_the_start_with_a_clear_message() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    token(dir, 0o600);
    // the squatter: another process's listener on the HMI's port
    let squat = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = squat.local_addr().expect("addr").port();
    let cfg = config(dir, Some(port));
    let mut d = spawn(dir, "run", &["run", "--config", &cfg.display().to_string()]);
    let status = wait(&mut d, Duration::from_secs(30), "the refused start", dir);
    let log = logs(dir);
    assert_eq!(
        status.code(),
        Some(69),
        "exit status (EX_UNAVAILABLE):\n{log}"
    );
    assert!(
        log.contains(&format!("web HMI on 127.0.0.1:{port}"))
            && log.contains("another process holds it")
            && log.contains("does not start"),
        "{log}"
    );
    let events = std::fs::read_to_string(dir.join("events.jsonl")).unwrap_or_default();
    assert!(
        events.contains("not started") && events.contains(&format!("127.0.0.1:{port}")),
        "{events}"
    );
    assert!(
        !events.contains("\"event\":\"mode_changed\""),
        "the control loop ran: {events}"
    );
    drop(squat);
}

#[test]
fn a_token_file_others_may_write_is_refused_at_start_and_at_reload() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let tf = token(dir, 0o642);
    let cfg = config(dir, None);
    let mut d = spawn(
        dir,
        "start",
        &["run", "--config", &cfg.display().to_string()],
    );
    let status = wait(&mut d, Duration::from_secs(30), "the refused start", dir);
    let log = logs(dir);
    assert_eq!(status.code(), Some(78), "exit status (EX_CONFIG):\n{log}");
    assert!(
        log.contains("status.operator_token_file")
            && log.contains(&tf.display().to_string())
            && log.contains("writable by everyone"),
        "{log}"
    );

    // a safe file: it starts; the file made writable by others: the reload is refused
    std::fs::set_permissions(&tf, std::fs::Permissions::from_mode(0o640)).expect("chmod");
    let mut d = spawn(dir, "run", &["run", "--config", &cfg.display().to_string()]);
    let sock = dir.join("status.sock");
    until(dir, "the status socket", || sock.exists());
    let events = dir.join("events.jsonl");
    until(dir, "the first cycles", || {
        common::daemon::count(&events, "mode_changed") > 0
    });
    std::fs::set_permissions(&tf, std::fs::Permissions::from_mode(0o642)).expect("chmod");
    signal(&d, libc::SIGHUP);
    until(dir, "the refused reload", || {
        common::daemon::count(&events, "config_rejected") > 0
    });
    let text = std::fs::read_to_string(&events).expect("events");
    let rejected = text
        .lines()
        .find(|l| l.contains("\"event\":\"config_rejected\""))
        .expect("rejected");
    assert!(
        rejected.contains("status.operator_token_file") && rejected.contains("writable"),
        "{rejected}"
    );
    // and an action with the right token is refused while the file is unsafe
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args([
            "operate",
            "--socket",
            &sock.display().to_string(),
            "--token-file",
            &tf.display().to_string(),
            "manual",
            "10",
        ])
        .output()
        .expect("operate");
    let said =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{said}");
    assert!(said.contains("writable"), "{said}");
    stop(&mut d, dir);
}

#[test]
fn a_thousand_wrong_tokens_make_one_log_line_one_event_and_429_after_the_limit() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    token(dir, 0o600);
    let port = free_port();
    let cfg = config(dir, Some(port));
    let mut d = spawn(dir, "run", &["run", "--config", &cfg.display().to_string()]);
    wait_for_hmi(port, dir);
    let mut c = Client::connect(port);
    let mut codes = Vec::new();
    for k in 0..1000 {
        // the last one carries the right token: refused as well once the source is locked out
        let auth = if k == 999 { "s3cret" } else { "guess" };
        let (code, body) = c
            .request(
                "POST",
                "/api/op",
                &format!("Authorization: Bearer {auth}\r\n"),
                "manual 0",
            )
            .expect("op");
        if k == 999 {
            assert!(body.contains("too many wrong tokens"), "{body}");
        }
        codes.push(code);
    }
    let limit = antisurge::live::guard::MAX_FAILURES as usize;
    assert!(
        codes[..limit].iter().all(|&c| c == 401),
        "{:?}",
        &codes[..limit + 2]
    );
    assert!(codes[limit..].iter().all(|&c| c == 429), "{codes:?}");
    let (_, st) = c.get("/api/status");
    let st: serde_json::Value = serde_json::from_str(&st).expect("status");
    assert_eq!(st["mode"], "auto", "a refused action changed the mode");

    let events = dir.join("events.jsonl");
    let notes = || {
        std::fs::read_to_string(&events)
            .unwrap_or_default()
            .lines()
            .filter(|l| l.contains("wrong or no token"))
            .map(str::to_string)
            .collect::<Vec<_>>()
    };
    until(dir, "the aggregated event", || !notes().is_empty());
    // one more quiet period: nothing else comes
    std::thread::sleep(antisurge::live::guard::BURST_QUIET + Duration::from_secs(1));
    let n = notes();
    assert_eq!(n.len(), 1, "{n:#?}");
    assert!(
        n[0].contains("1000 operator action(s)") && n[0].contains("127.0.0.1"),
        "{}",
        n[0]
    );
    stop(&mut d, dir);
    let log = std::fs::read_to_string(dir.join("run.log")).expect("log");
    let lines: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("wrong or no token"))
        .collect();
    assert_eq!(lines.len(), 1, "{lines:#?}");
    assert!(lines[0].contains("1000"), "{}", lines[0]);
}

#[test]
fn head_answers_200_on_a_kept_alive_connection_and_foreign_hosts_are_refused() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    token(dir, 0o600);
    let port = free_port();
    let cfg = config(dir, Some(port));
    let mut d = spawn(dir, "run", &["run", "--config", &cfg.display().to_string()]);
    wait_for_hmi(port, dir);
    let mut c = Client::connect(port);
    let (code, body) = c.request("HEAD", "/", "", "").expect("HEAD");
    assert_eq!((code, body.as_str()), (200, ""));
    // the same connection serves the next requests
    let (code, page) = c.get("/");
    assert_eq!(code, 200);
    assert!(page.contains("<canvas id=\"map\""), "{page}");
    let (code, ev) = c.get("/api/events");
    assert_eq!(code, 200);
    let ev: serde_json::Value = serde_json::from_str(&ev).expect("events json");
    assert!(
        ev.as_array()
            .is_some_and(|a| !a.is_empty() && a[0]["text"].is_string()),
        "{ev}"
    );
    let (code, st) = c.get("/api/status");
    assert_eq!(code, 200);
    let st: serde_json::Value = serde_json::from_str(&st).expect("status");
    assert_eq!(st["station"]["machine"], "kvangardsnes2009", "{st}");
    assert!(
        st["station"]["host"].is_string()
            && st["station"]["instance"]
                .as_str()
                .is_some_and(|i| i.ends_with("antisurge.toml")),
        "{st}"
    );
    // a page of another site reaching the HMI by a rebound name, or posting to it
    let mut e = Client::connect(port);
    write!(
        e.wr,
        "GET /api/status HTTP/1.1\r\nHost: attacker.example:{port}\r\nConnection: close\r\n\r\n"
    )
    .expect("write");
    let mut resp = String::new();
    let _ = e.rd.read_to_string(&mut resp);
    assert!(resp.starts_with("HTTP/1.1 403"), "{resp}");
    let (code, _) = c
        .request(
            "POST",
            "/api/op",
            "Origin: http://attacker.example\r\nAuthorization: Bearer s3cret\r\n",
            "manual 0",
        )
        .expect("op");
    assert_eq!(code, 403);
    stop(&mut d, dir);
}

/// What one window of the flood test saw.
#[derive(Debug, Default)]
struct Window {
    requests: u64,
    poll_period_max_us: f64,
    poll_period_sum_us: f64,
    samples: u32,
    control_overruns: u64,
    link_overruns: u64,
    jitter_max_us: f64,
    jitter_p99_us: f64,
}

fn status(c: &mut Client) -> serde_json::Value {
    let (code, body) = c.get("/api/status");
    assert_eq!(code, 200, "{body}");
    serde_json::from_str(&body).expect("status json")
}

/// Watch the status once a second for `secs`, flooding `/api/events` at `rate_hz` meanwhile
/// (0: no flood).
fn window(port: u16, secs: u64, rate_hz: u32) -> Window {
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let threads: Vec<_> = (0..if rate_hz > 0 { 4 } else { 0 })
        .map(|_| {
            let stop = std::sync::Arc::clone(&stop);
            std::thread::spawn(move || {
                let mut c = Client::connect(port);
                let every = Duration::from_secs_f64(4.0 / f64::from(rate_hz));
                let t0 = Instant::now();
                let mut n = 0u64;
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    let (code, _) = c.get("/api/events");
                    assert_eq!(code, 200);
                    n += 1;
                    if let Some(w) = (every * n as u32).checked_sub(t0.elapsed()) {
                        std::thread::sleep(w);
                    }
                }
                n
            })
        })
        .collect();
    let mut c = Client::connect(port);
    let first = status(&mut c);
    let mut w = Window::default();
    let mut last = first.clone();
    for _ in 0..secs {
        std::thread::sleep(Duration::from_secs(1));
        last = status(&mut c);
        let p = last["links"]["modbus"]["poll_period_us"]
            .as_f64()
            .unwrap_or(f64::NAN);
        w.poll_period_max_us = w.poll_period_max_us.max(p);
        w.poll_period_sum_us += p;
        w.samples += 1;
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    w.requests = threads.into_iter().map(|t| t.join().expect("flood")).sum();
    let u =
        |v: &serde_json::Value, k: &[&str]| k.iter().fold(v, |v, k| &v[*k]).as_u64().unwrap_or(0);
    w.control_overruns =
        u(&last, &["cycle_stats", "overruns"]) - u(&first, &["cycle_stats", "overruns"]);
    w.link_overruns =
        u(&last, &["links", "modbus", "overruns"]) - u(&first, &["links", "modbus", "overruns"]);
    w.jitter_max_us = last["cycle_stats"]["wake_jitter"]["max_us"]
        .as_f64()
        .unwrap_or(f64::NAN);
    w.jitter_p99_us = last["cycle_stats"]["wake_jitter"]["p99_us"]
        .as_f64()
        .unwrap_or(f64::NAN);
    w
}

#[test]
fn an_event_list_flood_is_served_off_the_realtime_threads_and_the_link_keeps_its_period() {
    let secs: u64 = std::env::var("ANTISURGE_FLOOD_S")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let scenario = hold(dir);
    let (plant_port, hmi_port) = (free_port(), free_port());
    let cfg = write_modbus_e2e_config(
        dir,
        &ModbusE2e {
            client_port: plant_port,
            plant_port,
            scenario: &scenario,
            heartbeat_timeout_ms: 1000.0,
            client_extra: "",
        },
    );
    // the bus I/O threads at SCHED_FIFO (granted to root or with an rtprio limit), the HMI on
    // its own port; the status socket in the test's directory
    let text = std::fs::read_to_string(&cfg).expect("cfg");
    let text = text.replacen(
        "lock_memory = false",
        "lock_memory = false\npriority = 60",
        1,
    ) + &format!(
        "socket = \"{}\"\nhmi_listen = \"127.0.0.1:{hmi_port}\"\nmetrics_listen = \"\"\n",
        dir.join("status.sock").display()
    );
    std::fs::write(&cfg, text).expect("cfg");
    let c = cfg.display().to_string();
    let mut plant = spawn(dir, "plant", &["plant", "--config", &c]);
    let mut d = spawn(dir, "run", &["run", "--config", &c]);
    wait_for_hmi(hmi_port, dir);
    let mut client = Client::connect(hmi_port);
    until(dir, "the Modbus link", || {
        status(&mut client)["links"]["modbus"]["poll_period_us"]
            .as_f64()
            .is_some_and(|p| p > 0.0)
    });
    let quiet = window(hmi_port, secs, 0);
    let flooded = window(hmi_port, secs, 200);
    // a new connection: the first one has idled out meanwhile (15 s)
    let st = status(&mut Client::connect(hmi_port));
    stop(&mut d, dir);
    signal(&plant, libc::SIGTERM);
    let _ = wait(&mut plant, Duration::from_secs(20), "plant", dir);
    let log = std::fs::read_to_string(dir.join("run.log")).unwrap_or_default();
    let fifo = log.contains("antisurge-io threads: SCHED_FIFO");
    eprintln!(
        "bus I/O threads real-time: {fifo}\nunflooded {secs} s: {quiet:?}\nflooded {secs} s at 200 req/s: {flooded:?}\nstation: {}",
        st["http"]
    );
    assert!(
        flooded.requests as f64 >= 0.8 * 200.0 * secs as f64,
        "the flood did not reach 200 requests/s: {} in {secs} s",
        flooded.requests
    );
    assert_eq!(
        st["http"]["http_requests_on_realtime_threads"], 0,
        "requests were handled on a real-time thread: {}",
        st["http"]
    );
    assert!(
        st["http"]["http_requests"].as_u64().unwrap_or(0) >= flooded.requests,
        "{}",
        st["http"]
    );
    // the configured poll period is 20 ms (50 Hz): within 20 %
    let limit_us = 1.2 * 20_000.0;
    assert!(
        flooded.poll_period_max_us <= limit_us,
        "link period under the flood: {flooded:?}\nunflooded: {quiet:?}"
    );
}
