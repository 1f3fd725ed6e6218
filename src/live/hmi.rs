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
//! (checked by `check-config`, `live::tls_settings`). With TLS, a plain-HTTP request gets a
//! 400 that says to use https:// and nothing else.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::extract::{Extension, Request, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use serde::Serialize;

use super::guard::AuthGuard;
use super::server::{LiveContext, OpError};
use super::station::Peer;
use crate::control::model::ControlModel;
use crate::control::surge_control_line::SurgeControlLine;
use crate::control::ControllerConfig;
use crate::physics::compressor_map::FlowCoordinate;

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
        // speed lines where the machine has a map; the surge, control and trip lines for
        // every machine (a vendor-data machine has its surge line without a map)
        let mut speed_lines = Vec::new();
        if let Some(map) = &model.map {
            let (w_lo, w_hi) = map.surge_line.omega_range();
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
        }
        let surge_line = model
            .map
            .as_ref()
            .map_or(model.surge_line, |m| m.surge_line);
        let flow_coordinate = model
            .map
            .as_ref()
            .map_or(model.flow_coordinate, |m| m.flow_coordinate);
        let r_max = surge_line.points().map(|(_, r)| r).fold(1.0f64, f64::max) * 1.05;
        let ratios: Vec<f64> = (0..=60)
            .map(|i| 1.0 + (r_max - 1.0) * i as f64 / 60.0)
            .collect();
        let surge = ratios
            .iter()
            .map(|r| surge_line.flow_at_ratio(*r))
            .collect();
        let scl = SurgeControlLine::new(surge_line, cfg.recycle_pi.control_line);
        let control = if has_control_line {
            ratios.iter().map(|r| scl.flow_at_ratio(*r)).collect()
        } else {
            Vec::new()
        };
        MapLines {
            flow_label: match flow_coordinate {
                FlowCoordinate::MassKgS => "mass flow, kg/s".into(),
                FlowCoordinate::InletVolumeM3S => "inlet volume flow, m³/s".into(),
            },
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
    /// Which controller this is (machine, host, instance).
    pub identity: super::Identity,
    /// Wrong-token bookkeeping.
    pub guard: Arc<AuthGuard>,
    /// The last event list served, by the log file's (length, modification time).
    pub events_cache: Arc<Mutex<Option<CachedEvents>>>,
    /// The daemon's own trend ring ([`TREND_SPAN`] at [`TREND_PERIOD`]).
    pub trends: Arc<Mutex<std::collections::VecDeque<TrendPoint>>>,
}

/// How long the trends reach back: the ten minutes an operator looks at after a trip.
pub const TREND_SPAN: Duration = Duration::from_secs(600);

/// One trend sample per second: the deviation settles in seconds, a surge cycle lasts about
/// one, and 600 samples are 60 KiB of JSON.
pub const TREND_PERIOD: Duration = Duration::from_secs(1);

/// One trend sample (units in the names; `null`: unknown).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct TrendPoint {
    /// Wall-clock time, s since the Unix epoch.
    pub t_unix_s: f64,
    /// Deviation from the control line, % of control-line flow.
    pub deviation_pct: Option<f64>,
    /// Recycle valve output, %.
    pub valve_output_pct: Option<f64>,
    /// Recycle valve position, %.
    pub valve_position_pct: Option<f64>,
    /// Operating point: flow in map coordinates.
    pub flow_map: Option<f64>,
    /// Operating point: pressure ratio.
    pub pressure_ratio: Option<f64>,
}

impl TrendPoint {
    fn of(s: &super::snapshot::LiveSnapshot) -> TrendPoint {
        let f = |x: f64| x.is_finite().then_some(x);
        TrendPoint {
            t_unix_s: crate::events::Timestamp::now().unix_micros() as f64 * 1e-6,
            deviation_pct: f(s.deviation_pct),
            valve_output_pct: f(100.0 * s.valve_output),
            valve_position_pct: f(100.0 * s.valve_position),
            flow_map: f(s.flow_map),
            pressure_ratio: f(s.pressure_ratio),
        }
    }
}

/// How much of the end of the event log the HMI reads per refresh, bytes: 30 events of at
/// most a few hundred bytes each fit many times over; the read is bounded whatever the log's
/// size (up to 16 MiB per file).
pub const EVENTS_TAIL_BYTES: u64 = 64 * 1024;

/// Events the HMI lists.
pub const EVENTS_LISTED: usize = 30;

/// The event list as JSON (newest first): each event's stored fields plus `text`, its
/// readable line as `antisurge events` prints it.
pub fn events_json(path: &std::path::Path) -> String {
    let records = crate::events::reader::tail_records(path, EVENTS_TAIL_BYTES, EVENTS_LISTED);
    let items: Vec<serde_json::Value> = records
        .iter()
        .rev()
        .map(|r| {
            let mut v: serde_json::Value = serde_json::from_str(&r.raw).unwrap_or_default();
            let mut text = String::new();
            crate::events::print::format_pretty(&mut text, r, false);
            if let Some(o) = v.as_object_mut() {
                o.insert("text".into(), text.into());
            }
            v
        })
        .collect();
    serde_json::to_string(&items).unwrap_or_else(|_| "[]".into())
}

/// What identifies a version of the event log: its length and modification time (s, ns).
pub type FileKey = (u64, i64, i64);

/// The event list served last, by the version of the log it was read from.
pub type CachedEvents = (FileKey, Arc<str>);

fn file_key(path: &std::path::Path) -> Option<FileKey> {
    use std::os::unix::fs::MetadataExt;
    let m = std::fs::metadata(path).ok()?;
    Some((m.len(), m.mtime(), m.mtime_nsec()))
}

fn json(code: StatusCode, body: String) -> Response {
    (
        code,
        [
            (header::CONTENT_TYPE, "application/json"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        body,
    )
        .into_response()
}

fn error(code: StatusCode, text: String) -> Response {
    json(code, serde_json::json!({ "error": text }).to_string())
}

async fn page() -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        PAGE,
    )
        .into_response()
}

impl Hmi {
    /// The status report with the station's identity and HTTP counters (None before the
    /// first cycle).
    pub fn status_json(&self) -> Option<serde_json::Value> {
        let r = self.ctx.report()?;
        let mut v = serde_json::to_value(r).ok()?;
        if let Some(o) = v.as_object_mut() {
            o.insert(
                "station".into(),
                serde_json::to_value(&self.identity).unwrap_or_default(),
            );
            o.insert("http".into(), super::station::stats().to_json());
        }
        Some(v)
    }

    async fn events(&self) -> String {
        let key = file_key(&self.events_path);
        if let (Some(k), Ok(cache)) = (key, self.events_cache.lock()) {
            if let Some((ck, body)) = cache.as_ref() {
                if *ck == k {
                    return body.to_string();
                }
            }
        }
        let path = self.events_path.clone();
        let body: Arc<str> = tokio::task::spawn_blocking(move || events_json(&path))
            .await
            .unwrap_or_else(|_| "[]".into())
            .into();
        if let (Some(k), Ok(mut cache)) = (key, self.events_cache.lock()) {
            *cache = Some((k, Arc::clone(&body)));
        }
        body.to_string()
    }

    /// An operator action from `peer` with the request's headers and body.
    fn operate(&self, peer: &Peer, headers: &HeaderMap, body: &str) -> Response {
        let ip = peer.addr.ip();
        if !peer.tls && !ip.is_loopback() {
            return error(
                StatusCode::FORBIDDEN,
                "operator actions beyond loopback only over TLS".into(),
            );
        }
        let now = std::time::Instant::now();
        if !self.guard.admit(ip, now) {
            return error(
                StatusCode::TOO_MANY_REQUESTS,
                format!(
                    "too many wrong tokens from {ip}: operator actions from it are refused until it has made none for {} s",
                    super::guard::BURST_QUIET.as_secs()
                ),
            );
        }
        let token = headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.trim().strip_prefix("Bearer "))
            .unwrap_or("");
        let words: Vec<&str> = body.split_whitespace().collect();
        let who = format!("HMI {}{}", peer.addr, if peer.tls { " (TLS)" } else { "" });
        match self.ctx.operate(token, &words, &who) {
            Ok(what) => json(
                StatusCode::OK,
                serde_json::json!({ "ok": what }).to_string(),
            ),
            Err(e @ OpError::Unauthorized(_)) => {
                self.guard.failed(ip, now);
                error(StatusCode::UNAUTHORIZED, e.to_string())
            }
            Err(e) => error(StatusCode::BAD_REQUEST, e.to_string()),
        }
    }

    /// The HMI's routes (page, status, map, events, operator actions), behind the `Host`
    /// and `Origin` check.
    pub fn router(self) -> Router {
        let host_name = super::guard::host_name();
        Router::new()
            .route("/", get(page))
            .route("/index.html", get(page))
            .route(
                "/api/status",
                get(|State(h): State<Hmi>| async move {
                    match h.status_json() {
                        Some(v) => json(StatusCode::OK, v.to_string()),
                        None => error(StatusCode::SERVICE_UNAVAILABLE, "no cycle yet".into()),
                    }
                }),
            )
            .route(
                "/api/trends",
                get(|State(h): State<Hmi>| async move {
                    let body = h
                        .trends
                        .lock()
                        .map(|q| serde_json::to_string(&*q).unwrap_or_else(|_| "[]".into()))
                        .unwrap_or_else(|_| "[]".into());
                    json(StatusCode::OK, body)
                }),
            )
            .route(
                "/api/map",
                get(|State(h): State<Hmi>| async move { json(StatusCode::OK, h.map_json.clone()) }),
            )
            .route(
                "/api/events",
                get(|State(h): State<Hmi>| async move { json(StatusCode::OK, h.events().await) }),
            )
            .route(
                "/api/op",
                post(
                    |State(h): State<Hmi>,
                     Extension(peer): Extension<Peer>,
                     headers: HeaderMap,
                     body: String| async move { h.operate(&peer, &headers, &body) },
                ),
            )
            .fallback(|| async {
                (
                    StatusCode::NOT_FOUND,
                    "not found; the page is /, operator actions POST /api/op\n",
                )
            })
            .layer(axum::middleware::from_fn(
                move |Extension(peer): Extension<Peer>, req: Request, next: Next| {
                    let host_name = host_name.clone();
                    async move {
                        let refused = {
                            let h = |n| req.headers().get(n).and_then(|v| v.to_str().ok());
                            let host = h(header::HOST);
                            if !super::guard::host_allowed(host, peer.tls, &host_name) {
                                Some("the Host header does not name this controller\n")
                            } else if !super::guard::origin_allowed(
                                h(header::ORIGIN),
                                host,
                                peer.tls,
                            ) {
                                Some("requests from another site's page are refused\n")
                            } else {
                                None
                            }
                        };
                        if let Some(why) = refused {
                            return (StatusCode::FORBIDDEN, why).into_response();
                        }
                        next.run(req).await
                    }
                },
            ))
            .with_state(self)
    }
}

/// Serve the HMI on `listener` until `shutdown`; over TLS when `tls` is given. Runs on the
/// station runtime ([`super::station`]); wrong-token bursts are reported once a second.
pub async fn serve(
    listener: tokio::net::TcpListener,
    hmi: Hmi,
    tls: Option<tokio_rustls::TlsAcceptor>,
    shutdown: tokio::sync::watch::Receiver<bool>,
) {
    let guard = Arc::clone(&hmi.guard);
    let events = hmi.ctx.events.clone();
    let (trends, live) = (Arc::clone(&hmi.trends), Arc::clone(&hmi.ctx.live));
    let mut sd = shutdown.clone();
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(TREND_PERIOD);
        let keep = (TREND_SPAN.as_secs_f64() / TREND_PERIOD.as_secs_f64()).round() as usize;
        loop {
            tokio::select! {
                _ = tick.tick() => {
                    guard.report_due(std::time::Instant::now(), &events);
                    if let (Some(s), Ok(mut q)) = (live.latest(), trends.lock()) {
                        if q.len() >= keep {
                            q.pop_front();
                        }
                        q.push_back(TrendPoint::of(&s));
                    }
                }
                _ = sd.changed() => {
                    // what is still open is reported at shutdown
                    guard.report_due(std::time::Instant::now() + super::guard::BURST_REPORT_EVERY, &events);
                    break;
                }
            }
        }
    });
    let router = hmi.router();
    super::station::serve_http(
        listener,
        router,
        tls,
        super::station::HttpLimits::default(),
        shutdown,
    )
    .await;
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
