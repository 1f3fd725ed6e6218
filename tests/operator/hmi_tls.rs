//! The web HMI over TLS (issue 11: "bound beyond loopback only with TLS and the token"): a
//! daemon with `[status.tls]` (a self-signed certificate made here) answers over HTTPS,
//! refuses plain HTTP, and still wants the operator token for actions; `check-config` refuses
//! a non-loopback HMI without TLS or without the token file, naming the key and its line.

use crate::common;

use common::daemon::{free_port, logs, shipped, spawn, wait};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio_rustls::rustls;

/// A self-signed certificate for localhost and 127.0.0.1, written as PEM into `dir`;
/// returns (cert, key) paths and the certificate's DER.
fn self_signed(dir: &Path) -> (PathBuf, PathBuf, Vec<u8>) {
    let c = rcgen::generate_simple_self_signed(vec!["localhost".into(), "127.0.0.1".into()])
        .expect("self-signed certificate");
    let (cert, key) = (dir.join("hmi.crt"), dir.join("hmi.key"));
    std::fs::write(&cert, c.cert.pem()).expect("cert");
    std::fs::write(&key, c.signing_key.serialize_pem()).expect("key");
    (cert, key, c.cert.der().to_vec())
}

fn token(dir: &Path, mode: u32) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let p = dir.join("operator.token");
    std::fs::write(&p, "s3cret\n").expect("token");
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(mode)).expect("chmod");
    p
}

/// A daemon config for the in-process plant holding its operating point, with `status`
/// lines for the `[status]` section and `extra` appended.
fn config(dir: &Path, status: &str, extra: &str) -> PathBuf {
    std::fs::write(
        dir.join("hold.toml"),
        "name = \"hold\"\ndescription = \"hold\"\nduration_s = 60.0\n",
    )
    .expect("scenario");
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
[simulation]
scenario = "{dir}/hold.toml"
[status]
socket = "{dir}/status.sock"
state_dir = "{dir}/state"
metrics_listen = ""
operator_token_file = "{dir}/operator.token"
{status}
{extra}
"#,
        plant = shipped("plants/kvangardsnes2009_recycle.toml"),
        dir = dir.display(),
    );
    let p = dir.join("antisurge.toml");
    std::fs::write(&p, text).expect("config");
    p
}

fn client(ca_der: &[u8]) -> Arc<rustls::ClientConfig> {
    let mut roots = rustls::RootCertStore::empty();
    roots
        .add(rustls_pki_types::CertificateDer::from(ca_der.to_vec()))
        .expect("root");
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    Arc::new(
        rustls::ClientConfig::builder_with_provider(provider)
            .with_safe_default_protocol_versions()
            .expect("versions")
            .with_root_certificates(roots)
            .with_no_client_auth(),
    )
}

/// One HTTPS request; (status code, whole response).
fn https(cfg: &Arc<rustls::ClientConfig>, port: u16, req: &str) -> std::io::Result<(u16, String)> {
    let name = rustls_pki_types::ServerName::try_from("localhost").expect("name");
    let conn =
        rustls::ClientConnection::new(Arc::clone(cfg), name).map_err(std::io::Error::other)?;
    let sock = std::net::TcpStream::connect(("127.0.0.1", port))?;
    sock.set_read_timeout(Some(Duration::from_secs(5)))?;
    let mut tls = rustls::StreamOwned::new(conn, sock);
    tls.write_all(req.as_bytes())?;
    let mut out = Vec::new();
    // the server closes after its answer; a missing close_notify is its business, not ours
    match tls.read_to_end(&mut out) {
        Ok(_) => {}
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof && !out.is_empty() => {}
        Err(e) => return Err(e),
    }
    let out = String::from_utf8_lossy(&out).into_owned();
    Ok((code(&out), out))
}

/// One plain-HTTP request; (status code, whole response).
fn http(port: u16, req: &str) -> (u16, String) {
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(5)))
        .expect("timeout");
    s.write_all(req.as_bytes()).expect("write");
    let mut out = Vec::new();
    let _ = s.read_to_end(&mut out);
    let out = String::from_utf8_lossy(&out).into_owned();
    (code(&out), out)
}

fn code(resp: &str) -> u16 {
    resp.split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0)
}

fn post_op(
    cfg: &Arc<rustls::ClientConfig>,
    port: u16,
    auth: Option<&str>,
    body: &str,
) -> (u16, String) {
    let auth = auth
        .map(|t| format!("Authorization: Bearer {t}\r\n"))
        .unwrap_or_default();
    https(
        cfg,
        port,
        &format!(
            "POST /api/op HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n{auth}Content-Length: {}\r\n\r\n{body}",
            body.len()
        ),
    )
    .expect("https op")
}

const STATUS: &str = "GET /api/status HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n";

#[test]
fn the_hmi_over_tls_answers_https_refuses_plain_http_and_wants_the_token() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (cert, key, der) = self_signed(dir);
    token(dir, 0o640);
    let port = free_port();
    let cfg = config(
        dir,
        &format!("hmi_listen = \"127.0.0.1:{port}\""),
        &format!(
            "[status.tls]\ncert_file = \"{}\"\nkey_file = \"{}\"",
            cert.display(),
            key.display()
        ),
    );
    let mut d = spawn(dir, "run", &["run", "--config", &cfg.display().to_string()]);
    let tls = client(&der);

    // HTTPS: the status once the controller runs in auto
    let t0 = Instant::now();
    let body = loop {
        if let Ok((200, body)) = https(&tls, port, STATUS) {
            if body.contains("\"mode\":\"auto\"") {
                break body;
            }
        }
        if t0.elapsed() > Duration::from_secs(15) {
            let _ = d.kill();
            panic!("no HTTPS status in auto within 15 s\n{}", logs(dir));
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(body.contains("\"deviation_pct\""), "{body}");

    // the snapshot the page got is the one `antisurge status --json --cycle N` reports
    let served: serde_json::Value =
        serde_json::from_str(body.split("\r\n\r\n").nth(1).expect("body")).expect("json");
    let n = served["cycle"].as_u64().expect("cycle");
    std::thread::sleep(Duration::from_millis(200));
    let sock = dir.join("status.sock").display().to_string();
    let ask = |cycle: u64| {
        std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
            .args([
                "status",
                "--json",
                "--socket",
                &sock,
                "--cycle",
                &cycle.to_string(),
            ])
            .output()
            .expect("status")
    };
    let out = ask(n);
    assert!(out.status.success(), "{out:?}");
    let same: serde_json::Value = serde_json::from_slice(&out.stdout).expect("status json");
    assert_eq!(same["cycle"], served["cycle"]);
    assert_eq!(same["deviation_pct"], served["deviation_pct"]);
    assert_eq!(same["flow_map"], served["flow_map"]);
    let out = ask(n + 1_000_000);
    assert!(!out.status.success(), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("no longer kept"),
        "{out:?}"
    );
    let (c, page) = https(
        &tls,
        port,
        "GET / HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n",
    )
    .expect("page");
    assert_eq!(c, 200);
    assert!(page.contains("<canvas id=\"map\""), "{page}");

    // plain HTTP on the same port: refused, told to use https, no data
    let (c, plain) = http(port, STATUS);
    assert_eq!(c, 400, "{plain}");
    assert!(plain.contains("https://"), "{plain}");
    assert!(!plain.contains("deviation_pct"), "{plain}");
    let (c, plain) = http(
        port,
        "POST /api/op HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\nAuthorization: Bearer s3cret\r\nContent-Length: 9\r\n\r\nmanual 10",
    );
    assert_eq!(c, 400, "a plain-HTTP action with the right token: {plain}");

    // a client that does not trust this certificate gets no answer at all
    let other = rcgen::generate_simple_self_signed(vec!["localhost".into()]).expect("cert");
    assert!(
        https(&client(other.cert.der()), port, STATUS).is_err(),
        "a client trusting another certificate was answered"
    );

    // over TLS, operator actions still need the token
    for auth in [None, Some("guess")] {
        let (c, body) = post_op(&tls, port, auth, "manual 10");
        assert_eq!(c, 401, "{auth:?}: {body}");
    }
    std::thread::sleep(Duration::from_millis(300));
    let (_, body) = https(&tls, port, STATUS).expect("status");
    assert!(
        body.contains("\"auto_requested\":true"),
        "an unauthenticated or plain-HTTP action changed the mode: {body}"
    );
    let (c, body) = post_op(&tls, port, Some("s3cret"), "manual 10");
    assert_eq!(c, 200, "{body}");
    let t0 = Instant::now();
    loop {
        let (_, body) = https(&tls, port, STATUS).expect("status");
        if body.contains("\"mode\":\"manual\"") {
            break;
        }
        // (a liveness bound, not a timing claim)
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the authenticated action did not take: {body}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    common::daemon::signal(&d, libc::SIGTERM);
    wait(&mut d, Duration::from_secs(10), "daemon", dir);
    let log = logs(dir);
    assert!(
        log.contains(&format!("web HMI on https://127.0.0.1:{port}/")),
        "{log}"
    );
    let events = std::fs::read_to_string(dir.join("events.jsonl")).expect("events");
    let actions: Vec<&str> = events
        .lines()
        .filter(|l| l.contains("operator action (HMI 127.0.0.1"))
        .collect();
    assert_eq!(actions.len(), 1, "{events}");
    assert!(actions[0].contains("(TLS)"), "{}", actions[0]);
}

/// `antisurge check-config FILE`: (exit code, stdout + stderr).
fn check_config(dir: &Path, cfg: &Path) -> (i32, String) {
    let mut c = spawn(dir, "check", &["check-config", &cfg.display().to_string()]);
    let s = wait(&mut c, Duration::from_secs(20), "check-config", dir);
    let out = std::fs::read_to_string(dir.join("check.log")).expect("log");
    (s.code().unwrap_or(-1), out)
}

#[test]
fn a_hmi_beyond_loopback_needs_tls_and_the_token_file() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (cert, key, _) = self_signed(dir);
    let tls = format!(
        "[status.tls]\ncert_file = \"{}\"\nkey_file = \"{}\"",
        cert.display(),
        key.display()
    );
    let wild = "hmi_listen = \"0.0.0.0:9651\"";
    // the line of hmi_listen in the generated file
    let line_of = |cfg: &Path, key: &str| {
        std::fs::read_to_string(cfg)
            .expect("cfg")
            .lines()
            .position(|l| l.starts_with(key))
            .expect("key line")
            + 1
    };

    // no TLS (token in place): refused, located at status.hmi_listen
    token(dir, 0o640);
    let cfg = config(dir, wild, "");
    let (rc, out) = check_config(dir, &cfg);
    assert_eq!(rc, 78, "{out}");
    let at = format!("{}:{}:", cfg.display(), line_of(&cfg, "hmi_listen"));
    assert!(out.contains(&at), "not located at {at}: {out}");
    assert!(out.contains("status.hmi_listen"), "{out}");
    assert!(out.contains("TLS"), "{out}");

    // TLS, but the token file is missing, then readable by everyone: refused
    std::fs::remove_file(dir.join("operator.token")).expect("rm");
    let cfg = config(dir, wild, &tls);
    let (rc, out) = check_config(dir, &cfg);
    assert_eq!(rc, 78, "{out}");
    assert!(out.contains("status.hmi_listen"), "{out}");
    assert!(out.contains("operator token file"), "{out}");
    assert!(out.contains("missing"), "{out}");
    token(dir, 0o644);
    let (rc, out) = check_config(dir, &cfg);
    assert_eq!(rc, 78, "{out}");
    assert!(out.contains("readable by everyone"), "{out}");

    // TLS and the token: accepted
    token(dir, 0o640);
    let (rc, out) = check_config(dir, &cfg);
    assert_eq!(rc, 0, "{out}");

    // a key that is not PEM: refused, located at status.tls.key_file
    std::fs::write(dir.join("bad.key"), "not a key\n").expect("bad key");
    let cfg = config(
        dir,
        wild,
        &format!(
            "[status.tls]\ncert_file = \"{}\"\nkey_file = \"bad.key\"",
            cert.display()
        ),
    );
    let (rc, out) = check_config(dir, &cfg);
    assert_eq!(rc, 78, "{out}");
    let at = format!("{}:{}:", cfg.display(), line_of(&cfg, "key_file"));
    assert!(out.contains(&at), "not located at {at}: {out}");
    assert!(out.contains("status.tls.key_file"), "{out}");
    assert!(
        out.contains(&dir.join("bad.key").display().to_string()),
        "the relative key path is not resolved from the config's directory: {out}"
    );

    // loopback without TLS stays the default and needs nothing
    std::fs::remove_file(dir.join("operator.token")).expect("rm");
    let cfg = config(dir, "hmi_listen = \"127.0.0.1:9651\"", "");
    let (rc, out) = check_config(dir, &cfg);
    assert_eq!(rc, 0, "{out}");
}
