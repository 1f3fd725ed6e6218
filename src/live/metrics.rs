//! The Prometheus/OpenMetrics endpoint (`GET /metrics`), encoded by the `prometheus-client`
//! crate from the live snapshot at scrape time. Loopback by default (`status.metrics_listen`,
//! default `127.0.0.1:9650`); a non-loopback address needs `status.metrics_allow_remote`.
//! Read-only: the endpoint accepts no writes.

use std::net::SocketAddr;
use std::sync::Arc;

use prometheus_client::collector::Collector;
use prometheus_client::encoding::{DescriptorEncoder, EncodeMetric};
use prometheus_client::metrics::counter::ConstCounter;
use prometheus_client::metrics::gauge::ConstGauge;
use prometheus_client::registry::Registry;

use super::snapshot::LiveBoard;
use crate::runtime::rt_loop::CycleStats;
use crate::vocab::signals::SensorId;
use crate::vocab::Mode;

/// Default endpoint.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:9650";

#[derive(Debug)]
struct LiveCollector {
    live: Arc<LiveBoard>,
    stats: Arc<CycleStats>,
}

fn gauge(e: &mut DescriptorEncoder, name: &str, help: &str, v: f64) -> std::fmt::Result {
    let g = ConstGauge::new(v);
    let m = e.encode_descriptor(name, help, None, g.metric_type())?;
    g.encode(m)
}

fn counter(e: &mut DescriptorEncoder, name: &str, help: &str, v: u64) -> std::fmt::Result {
    let c = ConstCounter::new(v);
    let m = e.encode_descriptor(name, help, None, c.metric_type())?;
    c.encode(m)
}

impl Collector for LiveCollector {
    fn encode(&self, mut e: DescriptorEncoder) -> Result<(), std::fmt::Error> {
        let r = self.stats.report();
        counter(&mut e, "antisurge_cycles", "Control cycles run", r.cycles)?;
        let http = super::station::stats();
        counter(
            &mut e,
            "antisurge_http_requests",
            "Requests served by the HMI and metrics endpoints",
            http.requests.load(std::sync::atomic::Ordering::Relaxed),
        )?;
        counter(
            &mut e,
            "antisurge_http_requests_on_realtime_threads",
            "Requests that were handled on a real-time thread (must stay 0)",
            http.realtime.load(std::sync::atomic::Ordering::Relaxed),
        )?;
        counter(
            &mut e,
            "antisurge_http_connections_shed",
            "HTTP connections closed at once because the endpoint was at its connection cap",
            http.shed.load(std::sync::atomic::Ordering::Relaxed),
        )?;
        counter(
            &mut e,
            "antisurge_overruns",
            "Control cycles that ended after the next deadline",
            r.overruns,
        )?;
        gauge(
            &mut e,
            "antisurge_cycle_jitter_p99_seconds",
            "99th percentile of the control loop's wake-up lateness",
            r.wake_jitter.p99_us * 1e-6,
        )?;
        gauge(
            &mut e,
            "antisurge_cycle_compute_p99_seconds",
            "99th percentile of the control cycle's compute time",
            r.compute.p99_us * 1e-6,
        )?;
        {
            // the fault word of the field links (the one the heartbeat and watchdog carry)
            let g = ConstGauge::new(0i64);
            let mut fam = e.encode_descriptor(
                "antisurge_field_fault",
                "Field fault active (1) by category: link down, write failed, actuator feedback mismatch (latched until acknowledged), ...",
                None,
                g.metric_type(),
            )?;
            let word =
                crate::vocab::faults::FaultSet(self.live.latest().map_or(0, |s| s.field_faults));
            for c in crate::vocab::faults::FaultCategory::ALL {
                let g = ConstGauge::new(i64::from(word.has(c)));
                g.encode(fam.encode_family(&[("fault", c.name())])?)?;
            }
        }
        dcs_counters(&mut e)?;
        link_metrics(&mut e)?;
        let Some(s) = self.live.latest() else {
            return Ok(());
        };
        gauge(
            &mut e,
            "antisurge_deviation_ratio",
            "Deviation of the operating point from the surge control line, fraction of the control-line flow (positive = safe)",
            0.01 * s.deviation_pct,
        )?;
        gauge(
            &mut e,
            "antisurge_surge_margin_ratio",
            "Surge margin (q - surge-line flow)/surge-line flow",
            0.01 * s.surge_margin_pct,
        )?;
        gauge(
            &mut e,
            "antisurge_flow_map",
            "Operating point: flow in the compressor map's flow coordinate",
            s.flow_map,
        )?;
        gauge(
            &mut e,
            "antisurge_pressure_ratio",
            "Operating point: pressure ratio p_discharge/p_suction",
            s.pressure_ratio,
        )?;
        gauge(
            &mut e,
            "antisurge_valve_output_ratio",
            "Recycle valve opening commanded, fraction",
            s.valve_output,
        )?;
        gauge(
            &mut e,
            "antisurge_valve_position_ratio",
            "Recycle valve opening measured, fraction",
            s.valve_position,
        )?;
        counter(
            &mut e,
            "antisurge_surges",
            "Surge counter (kept across restarts; reset by the operator)",
            s.surge_count,
        )?;
        gauge(
            &mut e,
            "antisurge_safety_on_steps",
            "Safety-on steps of the control line in force",
            f64::from(s.safety_on_count),
        )?;
        {
            let g = ConstGauge::new(1i64);
            let mut fam = e.encode_descriptor(
                "antisurge_mode",
                "Controller mode (1 for the current one)",
                None,
                g.metric_type(),
            )?;
            for m in [Mode::Init, Mode::Manual, Mode::Auto, Mode::FailSafe] {
                let labels = [("mode", m.name()), ("law", s.law.name())];
                let g = ConstGauge::new(i64::from(m == s.mode));
                g.encode(fam.encode_family(&labels)?)?;
            }
        }
        {
            let g = ConstGauge::new(0i64);
            let mut fam = e.encode_descriptor(
                "antisurge_input_fault",
                "Fault lamp per input (1: not usable)",
                None,
                g.metric_type(),
            )?;
            for id in SensorId::ALL {
                let on = s.fault_bits & (1 << id.index()) != 0;
                let labels = [("input", id.name())];
                ConstGauge::new(i64::from(on)).encode(fam.encode_family(&labels)?)?;
            }
        }
        gauge(
            &mut e,
            "antisurge_margin_shift_ratio",
            "Degraded policy: control-line shift in force, fraction of the control-line flow",
            s.votes.shift.now,
        )?;
        let voted: Vec<_> = s.votes.votes.iter().filter(|v| v.bound > 0).collect();
        if !voted.is_empty() {
            let g = ConstGauge::new(0.0f64);
            let mut fam = e.encode_descriptor(
                "antisurge_transmitter_value",
                "Reading of each redundant transmitter, SI unit of its measurement",
                None,
                g.metric_type(),
            )?;
            for v in &voted {
                for t in 0..usize::from(v.bound) {
                    let labels = [
                        ("measurement", v.input.name()),
                        ("binding", crate::control::vote::TRANSMITTER_NAMES[t]),
                    ];
                    ConstGauge::new(v.values[t]).encode(fam.encode_family(&labels)?)?;
                }
            }
            let g = ConstGauge::new(0i64);
            let mut fam = e.encode_descriptor(
                "antisurge_transmitter_state",
                "State of each redundant transmitter (1 for the current one: healthy, deviating, voted_out)",
                None,
                g.metric_type(),
            )?;
            for v in &voted {
                for t in 0..usize::from(v.bound) {
                    for state in ["healthy", "deviating", "voted_out"] {
                        let labels = [
                            ("measurement", v.input.name()),
                            ("binding", crate::control::vote::TRANSMITTER_NAMES[t]),
                            ("state", state),
                        ];
                        let on = v.states[t].name() == state;
                        ConstGauge::new(i64::from(on)).encode(fam.encode_family(&labels)?)?;
                    }
                }
            }
            let g = ConstGauge::new(0i64);
            let mut fam = e.encode_descriptor(
                "antisurge_vote_valid_transmitters",
                "Valid transmitters in each vote",
                None,
                g.metric_type(),
            )?;
            for v in &voted {
                let labels = [("measurement", v.input.name())];
                ConstGauge::new(i64::from(v.valid)).encode(fam.encode_family(&labels)?)?;
            }
        }
        Ok(())
    }
}

/// The DCS block's server counters (only while the block is on).
/// The controller's field links, as the daemon started them (a scrape reads their watch
/// channels and atomics through the one [`FieldLink`](crate::io::link::FieldLink) face), and
/// its Modbus link's monitor for the poll period, latency and heartbeats only a polled link has.
#[derive(Default)]
struct Links {
    all: crate::io::link::FieldLinks,
    modbus: Option<Arc<crate::io::modbus::ModbusLinkView>>,
}
static LINKS: std::sync::Mutex<Option<Links>> = std::sync::Mutex::new(None);

/// Expose the controller's field links in the metrics (the daemon, once it started them):
/// every link's state and traffic, and the Modbus link's quality.
pub fn register_links(
    all: crate::io::link::FieldLinks,
    modbus: Option<Arc<crate::io::modbus::ModbusLinkView>>,
) {
    *LINKS
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(Links { all, modbus });
}

/// Every field link's state and traffic ([`crate::io::link::LinkTraffic`]), labelled with its
/// name; the Modbus link's quality and heartbeats.
fn link_metrics(e: &mut DescriptorEncoder) -> std::fmt::Result {
    use crate::io::link::{FieldLink, LinkTraffic};
    let Some(Links { all, modbus }) = LINKS
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .as_ref()
        .map(|l| Links {
            all: l.all.clone(),
            modbus: l.modbus.clone(),
        })
    else {
        return Ok(());
    };
    if all.iter().next().is_some() {
        let mut fam = e.encode_descriptor(
            "antisurge_link_up",
            "Field link up and passing traffic (1)",
            None,
            ConstGauge::new(0i64).metric_type(),
        )?;
        for l in all.iter() {
            ConstGauge::new(i64::from(l.is_up()))
                .encode(fam.encode_family(&[("link", l.name())])?)?;
        }
        type Pick = fn(&LinkTraffic) -> u64;
        let traffic: [(&str, &str, Pick); 5] = [
            ("antisurge_link_sent", "Field link: frames written (CAN) or requests sent (Modbus)", |t| t.sent),
            ("antisurge_link_received", "Field link: frames read (CAN) or answers received (Modbus)", |t| t.received),
            ("antisurge_link_errors", "Field link: frames refused, error frames and refused writes (CAN); timeouts, exceptions, I/O and protocol errors (Modbus)", |t| t.errors),
            ("antisurge_link_down", "Field link: times the link went down", |t| t.down),
            ("antisurge_link_reconnects", "Field link: reconnects after the first open", |t| t.reconnects),
        ];
        let figures: Vec<(String, LinkTraffic)> = all
            .iter()
            .map(|l| (l.name().to_string(), l.traffic()))
            .collect();
        for (metric, help, pick) in traffic {
            let mut fam =
                e.encode_descriptor(metric, help, None, ConstCounter::new(0u64).metric_type())?;
            for (name, t) in &figures {
                ConstCounter::new(pick(t))
                    .encode(fam.encode_family(&[("link", name.as_str())])?)?;
            }
        }
    }
    let Some(view) = modbus else {
        return Ok(());
    };
    let c = view.monitor.counters().snapshot();
    let name = view.name();
    let link = [("link", name)];
    let g = ConstGauge::new(c.poll_period_us as f64 * 1e-6);
    g.encode(
        e.encode_descriptor(
            "antisurge_link_poll_period_seconds",
            "Field link: achieved poll period (interval between polls answered in full) over the last second",
            None,
            g.metric_type(),
        )?
        .encode_family(&link)?,
    )?;
    {
        let g = ConstGauge::new(0.0);
        let mut fam = e.encode_descriptor(
            "antisurge_link_latency_seconds",
            "Field link: answer latency over the last ten seconds, by quantile",
            None,
            g.metric_type(),
        )?;
        for (q, v) in [("0.5", c.latency_p50_us), ("0.99", c.latency_p99_us)] {
            ConstGauge::new(v as f64 * 1e-6)
                .encode(fam.encode_family(&[("link", name), ("quantile", q)])?)?;
        }
    }
    for (metric, help, v) in [
        (
            "antisurge_link_requests",
            "Field link: requests sent",
            c.requests,
        ),
        (
            "antisurge_link_timeouts",
            "Field link: requests without an answer within the timeout",
            c.timeouts,
        ),
        (
            "antisurge_link_exceptions",
            "Field link: exception answers",
            c.exceptions,
        ),
        (
            "antisurge_link_heartbeats",
            "Field link: heartbeats (watchdog beats) written and acknowledged",
            c.heartbeats,
        ),
    ] {
        let k = ConstCounter::new(v);
        k.encode(
            e.encode_descriptor(metric, help, None, k.metric_type())?
                .encode_family(&link)?,
        )?;
    }
    Ok(())
}

fn dcs_counters(e: &mut DescriptorEncoder) -> std::fmt::Result {
    let c = super::dcs::counters();
    if !c.serving.load(std::sync::atomic::Ordering::Relaxed) {
        return Ok(());
    }
    let c = c.snapshot();
    gauge(
        e,
        "antisurge_dcs_connections",
        "Modbus block for the DCS: connections open",
        c.open as f64,
    )?;
    for (name, help, v) in [
        ("antisurge_dcs_connections_accepted", "Modbus block for the DCS: connections accepted", c.accepted),
        ("antisurge_dcs_connections_shed", "Modbus block for the DCS: connections closed to make room at the cap or refused at it", c.shed),
        ("antisurge_dcs_connections_idle_closed", "Modbus block for the DCS: connections closed by the idle time-out", c.idle_closed),
        ("antisurge_dcs_connections_malformed", "Modbus block for the DCS: connections closed on a malformed frame", c.malformed),
        ("antisurge_dcs_accept_exhausted", "Modbus block for the DCS: accept failures for want of descriptors (EMFILE and the like), each followed by a back-off", c.accept_exhausted),
        ("antisurge_dcs_requests", "Modbus block for the DCS: requests answered", c.requests),
        ("antisurge_dcs_requests_throttled", "Modbus block for the DCS: requests held back by the per-connection budget", c.throttled),
    ] {
        counter(e, name, help, v)?;
    }
    Ok(())
}

/// Where the endpoint binds: `listen` (None: the default; empty: off). A non-loopback
/// address is refused unless `allow_remote`.
pub fn listen_addr(listen: Option<&str>, allow_remote: bool) -> Result<Option<SocketAddr>, String> {
    let text = listen.unwrap_or(DEFAULT_LISTEN).trim();
    if text.is_empty() {
        return Ok(None);
    }
    let addr: SocketAddr = text
        .parse()
        .map_err(|e| format!("status.metrics_listen `{text}`: {e} (expected host:port)"))?;
    if !addr.ip().is_loopback() && !allow_remote {
        return Err(format!(
            "status.metrics_listen `{text}` is not a loopback address; set status.metrics_allow_remote = true to serve it there"
        ));
    }
    Ok(Some(addr))
}

/// The exposition text now.
pub fn render(live: &Arc<LiveBoard>, stats: &Arc<CycleStats>) -> String {
    let mut reg = Registry::default();
    reg.register_collector(Box::new(LiveCollector {
        live: Arc::clone(live),
        stats: Arc::clone(stats),
    }));
    let mut out = String::new();
    let _ = prometheus_client::encoding::text::encode(&mut out, &reg);
    out
}

/// The same exposition in the classic Prometheus text format 0.0.4 (for clients that do not
/// ask for OpenMetrics, and `promtool check metrics`): counter families are named with their
/// `_total` suffix, and the `# EOF` marker is left out.
pub fn render_classic(live: &Arc<LiveBoard>, stats: &Arc<CycleStats>) -> String {
    let om = render(live, stats);
    let counters: Vec<&str> = om
        .lines()
        .filter_map(|l| l.strip_prefix("# TYPE "))
        .filter_map(|l| l.strip_suffix(" counter"))
        .collect();
    let mut out = String::with_capacity(om.len());
    for line in om.lines() {
        if line == "# EOF" || line.starts_with("# UNIT ") {
            continue;
        }
        let mut rewritten = None;
        for c in &counters {
            for tag in ["# HELP ", "# TYPE "] {
                if let Some(rest) = line.strip_prefix(tag).and_then(|r| r.strip_prefix(c)) {
                    if rest.starts_with(' ') {
                        rewritten = Some(format!("{tag}{c}_total{rest}"));
                    }
                }
            }
        }
        out += rewritten.as_deref().unwrap_or(line);
        out.push('\n');
    }
    out
}

/// The endpoint's routes: `GET /metrics` (and `HEAD`), OpenMetrics when the client asks for
/// it, else the classic text format.
pub fn router(live: Arc<LiveBoard>, stats: Arc<CycleStats>) -> axum::Router {
    use axum::http::{header, HeaderMap, StatusCode};
    use axum::response::IntoResponse;
    axum::Router::new()
        .route(
            "/metrics",
            axum::routing::get(move |headers: HeaderMap| {
                let (live, stats) = (Arc::clone(&live), Arc::clone(&stats));
                async move {
                    let om = headers
                        .get_all(header::ACCEPT)
                        .iter()
                        .filter_map(|v| v.to_str().ok())
                        .any(|v| v.contains("application/openmetrics-text"));
                    let (body, ctype) = if om {
                        (
                            render(&live, &stats),
                            "application/openmetrics-text; version=1.0.0; charset=utf-8",
                        )
                    } else {
                        (
                            render_classic(&live, &stats),
                            "text/plain; version=0.0.4; charset=utf-8",
                        )
                    };
                    ([(header::CONTENT_TYPE, ctype)], body).into_response()
                }
            }),
        )
        .fallback(|| async {
            (
                StatusCode::NOT_FOUND,
                "not found; metrics are at /metrics\n",
            )
        })
}

/// Serve `GET /metrics` on `listener` until `shutdown` (on the station runtime).
pub async fn serve(
    listener: tokio::net::TcpListener,
    live: Arc<LiveBoard>,
    stats: Arc<CycleStats>,
    shutdown: tokio::sync::watch::Receiver<bool>,
) {
    let limits = super::station::HttpLimits {
        max_connections: 8,
        ..super::station::HttpLimits::default()
    };
    super::station::serve_http(listener, router(live, stats), None, limits, shutdown).await;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::live::snapshot::LiveSnapshot;

    #[test]
    fn every_links_state_and_traffic_and_the_modbus_links_quality_are_exposed_with_their_names() {
        use crate::io::can::bus::{BusState, CanCounters, CanLinkView};
        let view = Arc::new(crate::io::modbus::ModbusLinkView {
            name: "modbus:10.0.0.5:502".into(),
            monitor: Arc::new(crate::io::modbus::LinkMonitor::new()),
        });
        let can = Arc::new(CanCounters::default());
        can.rx_frames
            .store(12, std::sync::atomic::Ordering::Relaxed);
        let (_tx, rx) = tokio::sync::watch::channel(BusState::Up);
        let mut all = crate::io::link::FieldLinks::default();
        all.push(Arc::new(CanLinkView {
            name: "can:vcan0".into(),
            counters: can,
            state: rx,
        }));
        all.push(view.clone());
        register_links(all, Some(view));
        let live = Arc::new(LiveBoard::default());
        let stats = Arc::new(CycleStats::default());
        let text = render_classic(&live, &stats);
        for want in [
            "antisurge_link_up{link=\"modbus:10.0.0.5:502\"} 0",
            "antisurge_link_up{link=\"can:vcan0\"} 1",
            "antisurge_link_received_total{link=\"can:vcan0\"} 12",
            "antisurge_link_down_total{link=\"modbus:10.0.0.5:502\"} 0",
            "antisurge_link_reconnects_total{link=\"can:vcan0\"} 0",
            "antisurge_link_poll_period_seconds{link=\"modbus:10.0.0.5:502\"} 0",
            "antisurge_link_latency_seconds{link=\"modbus:10.0.0.5:502\",quantile=\"0.99\"} 0",
            "antisurge_link_timeouts_total{link=\"modbus:10.0.0.5:502\"} 0",
            "antisurge_link_exceptions_total{link=\"modbus:10.0.0.5:502\"} 0",
            "antisurge_link_heartbeats_total{link=\"modbus:10.0.0.5:502\"} 0",
        ] {
            assert!(text.contains(want), "{want} missing from\n{text}");
        }
        assert!(
            !text.contains("antisurge_link_poll_period_seconds{link=\"can:vcan0\"}"),
            "a CAN link is not polled"
        );
    }

    #[test]
    fn loopback_by_default_and_remote_only_when_allowed() {
        assert_eq!(
            listen_addr(None, false).expect("default"),
            Some(DEFAULT_LISTEN.parse().expect("addr"))
        );
        assert_eq!(listen_addr(Some(""), false).expect("off"), None);
        let e = listen_addr(Some("0.0.0.0:9650"), false).unwrap_err();
        assert!(e.contains("metrics_allow_remote"), "{e}");
        assert!(listen_addr(Some("0.0.0.0:9650"), true).is_ok());
    }

    #[test]
    fn exposition_carries_the_deviation_and_mode() {
        let live = Arc::new(LiveBoard::default());
        let stats = Arc::new(CycleStats::default());
        live.publish(&LiveSnapshot {
            mode: Mode::Auto,
            deviation_pct: 12.5,
            surge_count: 3,
            fault_bits: 1 << SensorId::OrificeDp.index(),
            ..LiveSnapshot::default()
        });
        let text = render(&live, &stats);
        assert!(text.contains("antisurge_deviation_ratio 0.125"), "{text}");
        assert!(text.contains("antisurge_surges_total 3"), "{text}");
        assert!(
            text.contains(r#"antisurge_mode{mode="auto",law="none"} 1"#),
            "{text}"
        );
        assert!(
            text.contains(r#"antisurge_input_fault{input="orifice_dp"} 1"#),
            "{text}"
        );
        assert!(text.ends_with("# EOF\n"), "{text}");
        assert!(text.contains("antisurge_margin_shift_ratio 0"), "{text}");
        let mut s = live.latest().expect("snapshot");
        s.votes.votes[3] = crate::control::vote::VoteStatus {
            input: SensorId::OrificeDp,
            bound: 2,
            valid: 1,
            rule: crate::control::vote::VoteRule::HoldLast,
            value: 1000.0,
            values: [1000.0, f64::NAN, f64::NAN],
            states: [
                crate::control::vote::TransmitterState::Healthy,
                crate::control::vote::TransmitterState::VotedOut(
                    crate::control::vote::TransmitterCheck::Stale,
                ),
                crate::control::vote::TransmitterState::Unbound,
            ],
            degraded: true,
        };
        live.publish(&s);
        let text = render(&live, &stats);
        assert!(
            text.contains(r#"antisurge_transmitter_state{measurement="orifice_dp",binding="b",state="voted_out"} 1"#),
            "{text}"
        );
        assert!(
            text.contains(r#"antisurge_vote_valid_transmitters{measurement="orifice_dp"} 1"#),
            "{text}"
        );
        let classic = render_classic(&live, &stats);
        assert!(
            classic.contains("# HELP antisurge_surges_total Surge counter"),
            "{classic}"
        );
        assert!(
            classic.contains("# TYPE antisurge_surges_total counter"),
            "{classic}"
        );
        assert!(!classic.contains("# EOF"), "{classic}");
    }
}
