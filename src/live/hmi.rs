//! The web HMI served by the daemon: one page (embedded in the binary, no external assets)
//! with the compressor map (speed lines, surge limit line, control line with its safety-on
//! shift, trip line), the live operating point and its trail, deviation, valve output and
//! position, mode and law, fault lamps with causes, the surge counter, 10-minute trends and
//! the event list.
//!
//! Read-only by default. Operator actions (`POST /api/op`, body `auto`, `manual 20`,
//! `output 20`, `reset-surge-counter`, `ack`) need `Authorization: Bearer <token>` with the
//! token of the root-owned token file; anything else gets 401 and changes nothing. Each
//! accepted action is recorded in the event log with what changed. The HMI binds loopback
//! by default (`status.hmi_listen`, default `127.0.0.1:9651`); a non-loopback address is
//! accepted only with `[status.tls]` (HTTPS, [`super::tls`]) and a usable operator token file
//! (checked by `check-config`, `daemon::config::tls`). With TLS, a plain-HTTP request gets a
//! 400 that says to use https:// and nothing else.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use serde::Serialize;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

use super::server::{LiveContext, OpError};
use crate::control::model::ControlModel;
use crate::control::surge_control_line::SurgeControlLine;
use crate::control::ControllerConfig;

/// Default HMI address.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:9651";

const PAGE: &str = include_str!("hmi.html");

/// The map's static lines, in the map's coordinates (flow, pressure ratio).
#[derive(Debug, Clone, Serialize)]
pub struct MapLines {
    /// Flow coordinate label.
    pub flow_label: String,
    /// Speed lines: (speed rad/s, points).
    pub speed_lines: Vec<(f64, Vec<(f64, f64)>)>,
    /// Pressure ratios the line arrays are sampled at.
    pub ratios: Vec<f64>,
    /// Surge-line flow at each ratio.
    pub surge: Vec<f64>,
    /// Control-line flow without safety-on at each ratio (empty: the law has none).
    pub control: Vec<f64>,
    /// Trip line margin, fraction of surge-line flow (NaN: none).
    pub trip_margin: f64,
}

impl MapLines {
    /// Lines of a machine under a controller configuration (the control line of recycle-pi).
    pub fn new(model: &ControlModel, cfg: &ControllerConfig, has_control_line: bool) -> MapLines {
        let Some(map) = &model.map else {
            // a machine described without a map: the HMI shows the live values only
            return MapLines {
                flow_label: String::new(),
                speed_lines: Vec::new(),
                ratios: Vec::new(),
                surge: Vec::new(),
                control: Vec::new(),
                trip_margin: f64::NAN,
            };
        };
        let (w_lo, w_hi) = map.surge_line.omega_range();
        let mut speed_lines = Vec::new();
        for k in 0..5 {
            let w = w_lo + (w_hi - w_lo) * k as f64 / 4.0;
            let Some((q_s, _)) = map.peak(w) else {
                continue;
            };
            let pts: Vec<(f64, f64)> = (0..=40)
                .map(|i| {
                    let q = q_s * (0.7 + 1.3 * i as f64 / 40.0);
                    (q, map.pressure_ratio(q, w))
                })
                .filter(|(_, r)| r.is_finite() && *r > 1.0)
                .collect();
            speed_lines.push((w, pts));
        }
        let r_max = map
            .surge_line
            .points()
            .map(|(_, r)| r)
            .fold(1.0f64, f64::max)
            * 1.05;
        let ratios: Vec<f64> = (0..=60)
            .map(|i| 1.0 + (r_max - 1.0) * i as f64 / 60.0)
            .collect();
        let surge = ratios
            .iter()
            .map(|r| map.surge_line.flow_at_ratio(*r))
            .collect();
        let scl = SurgeControlLine::new(map.surge_line, cfg.recycle_pi.control_line);
        let control = if has_control_line {
            ratios.iter().map(|r| scl.flow_at_ratio(*r)).collect()
        } else {
            Vec::new()
        };
        MapLines {
            flow_label: format!("{:?}", map.flow_coordinate),
            speed_lines,
            ratios,
            surge,
            control,
            trip_margin: if has_control_line {
                0.01 * cfg.recycle_pi.trip.margin_pct
            } else {
                f64::NAN
            },
        }
    }
}

/// Where the HMI binds (None: off). A non-loopback address is refused unless `tls` (the
/// token file is checked by `check-config`).
pub fn listen_addr(listen: Option<&str>, tls: bool) -> Result<Option<SocketAddr>, String> {
    let text = listen.unwrap_or(DEFAULT_LISTEN).trim();
    if text.is_empty() {
        return Ok(None);
    }
    let addr: SocketAddr = text
        .parse()
        .map_err(|e| format!("status.hmi_listen `{text}`: {e} (expected host:port)"))?;
    if !addr.ip().is_loopback() && !tls {
        return Err(format!(
            "status.hmi_listen `{text}` is not a loopback address: the HMI is served beyond \
             loopback only over TLS ([status.tls] cert_file and key_file) with the operator token"
        ));
    }
    Ok(Some(addr))
}

/// What the HMI server needs besides the live context.
#[derive(Clone)]
pub struct Hmi {
    /// The shared live context (status, operator actions).
    pub ctx: LiveContext,
    /// Static map lines, as JSON.
    pub map_json: String,
    /// The event log (the list shows its tail).
    pub events_path: PathBuf,
}

fn response(code: &str, ctype: &str, body: &str) -> String {
    format!(
        "HTTP/1.1 {code}\r\nContent-Type: {ctype}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
}

fn tail_events(path: &std::path::Path, n: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().rev().take(n).collect();
    format!("[{}]", lines.join(","))
}

impl Hmi {
    /// Answer one request (head and body already read).
    pub fn answer(&self, head: &str, body: &str, who: &str) -> String {
        let first = head.lines().next().unwrap_or("");
        let mut parts = first.split_whitespace();
        let (method, path) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
        let json = "application/json";
        match (method, path) {
            ("GET", "/") | ("GET", "/index.html") => {
                response("200 OK", "text/html; charset=utf-8", PAGE)
            }
            ("GET", "/api/status") => match self.ctx.report() {
                Some(r) => response(
                    "200 OK",
                    json,
                    &serde_json::to_string(&r).unwrap_or_default(),
                ),
                None => response(
                    "503 Service Unavailable",
                    json,
                    r#"{"error":"no cycle yet"}"#,
                ),
            },
            ("GET", "/api/map") => response("200 OK", json, &self.map_json),
            ("GET", "/api/events") => response("200 OK", json, &tail_events(&self.events_path, 30)),
            ("POST", "/api/op") => {
                let token = head
                    .lines()
                    .find_map(|l| {
                        let (k, v) = l.split_once(':')?;
                        k.trim()
                            .eq_ignore_ascii_case("authorization")
                            .then(|| v.trim().strip_prefix("Bearer ").unwrap_or("").to_string())
                    })
                    .unwrap_or_default();
                let words: Vec<&str> = body.split_whitespace().collect();
                match self.ctx.operate(&token, &words, who) {
                    Ok(what) => {
                        response("200 OK", json, &serde_json::json!({"ok": what}).to_string())
                    }
                    Err(e @ OpError::Unauthorized(_)) => response(
                        "401 Unauthorized",
                        json,
                        &serde_json::json!({"error": e.to_string()}).to_string(),
                    ),
                    Err(e) => response(
                        "400 Bad Request",
                        json,
                        &serde_json::json!({"error": e.to_string()}).to_string(),
                    ),
                }
            }
            ("GET", _) => response("404 Not Found", "text/plain", "not found\n"),
            _ => response(
                "405 Method Not Allowed",
                "text/plain",
                "read-only; operator actions: POST /api/op\n",
            ),
        }
    }
}

/// Serve the HMI on `listener` until `shutdown`; over TLS when `tls` is given.
pub async fn serve(
    listener: tokio::net::TcpListener,
    hmi: Hmi,
    tls: Option<tokio_rustls::TlsAcceptor>,
    mut shutdown: tokio::sync::watch::Receiver<bool>,
) {
    loop {
        let (mut sock, peer) = tokio::select! {
            r = listener.accept() => match r {
                Ok(s) => s,
                Err(_) => { tokio::time::sleep(Duration::from_millis(100)).await; continue; }
            },
            _ = shutdown.changed() => break,
        };
        let hmi = hmi.clone();
        let tls = tls.clone();
        tokio::spawn(async move {
            let who = format!("HMI {peer}");
            let Some(acceptor) = tls else {
                return answer_connection(sock, &hmi, &who).await;
            };
            // a TLS connection opens with a handshake record (0x16); anything else is refused
            let mut first = [0u8; 1];
            let opened = tokio::time::timeout(Duration::from_secs(5), sock.peek(&mut first)).await;
            if !matches!(opened, Ok(Ok(1))) {
                return;
            }
            if first[0] != 0x16 {
                let resp = response(
                    "400 Bad Request",
                    "text/plain",
                    "this HMI is served over TLS only: open it with https://\n",
                );
                let _ = sock.write_all(resp.as_bytes()).await;
                let _ = sock.shutdown().await;
                return;
            }
            match tokio::time::timeout(Duration::from_secs(5), acceptor.accept(sock)).await {
                Ok(Ok(stream)) => answer_connection(stream, &hmi, &format!("{who} (TLS)")).await,
                Ok(Err(e)) => {
                    tracing::debug!(target: "status", "HMI TLS handshake with {peer}: {e}")
                }
                Err(_) => {
                    tracing::debug!(target: "status", "HMI TLS handshake with {peer}: timed out")
                }
            }
        });
    }
}

/// Read one request from `sock` (head and body, at most 8 KiB, 2 s) and answer it.
async fn answer_connection<S: AsyncRead + AsyncWrite + Unpin>(mut sock: S, hmi: &Hmi, who: &str) {
    let mut buf = vec![0u8; 8192];
    let mut n = 0;
    let _ = tokio::time::timeout(Duration::from_secs(2), async {
        loop {
            if n == buf.len() {
                break;
            }
            match sock.read(&mut buf[n..]).await {
                Ok(0) | Err(_) => break,
                Ok(k) => n += k,
            }
            let text = String::from_utf8_lossy(&buf[..n]);
            if let Some(end) = text.find("\r\n\r\n") {
                let len = text[..end]
                    .lines()
                    .find_map(|l| {
                        let (k, v) = l.split_once(':')?;
                        k.trim()
                            .eq_ignore_ascii_case("content-length")
                            .then(|| v.trim().parse::<usize>().ok())?
                    })
                    .unwrap_or(0);
                if n >= end + 4 + len.min(1024) {
                    break;
                }
            }
        }
    })
    .await;
    let text = String::from_utf8_lossy(&buf[..n]).into_owned();
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    let resp = hmi.answer(head, body, who);
    let _ = sock.write_all(resp.as_bytes()).await;
    let _ = sock.shutdown().await;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loopback_only() {
        assert_eq!(
            listen_addr(None, false).expect("default"),
            Some(DEFAULT_LISTEN.parse().expect("addr"))
        );
        assert!(listen_addr(Some("[::1]:9651"), false)
            .expect("v6")
            .is_some());
        let e = listen_addr(Some("0.0.0.0:9651"), false).unwrap_err();
        assert!(e.contains("TLS"), "{e}");
        assert!(listen_addr(Some("0.0.0.0:9651"), true)
            .expect("tls")
            .is_some());
        assert_eq!(listen_addr(Some(""), false).expect("off"), None);
    }
}
