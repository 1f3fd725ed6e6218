//! The Modbus TCP server block for the DCS: the live state in **input registers** (function
//! 0x04, read-only by nature; writes are refused with an exception), unit id 1, addresses
//! 0–15, refreshed every 100 ms from the live snapshot. Off unless `status.modbus_listen` is
//! set (e.g. `0.0.0.0:502`: Modbus has no authentication, so it serves read-only data only).
//! The register map is in README.md ("Modbus block for the DCS") and [`REGISTERS`].
//!
//! The block is served by [`crate::io::modbus::bounded_server`]: a connection cap
//! (`status.modbus_max_connections`), an idle time-out (`status.modbus_idle_timeout_s`), a
//! request budget per connection (`status.modbus_max_requests_per_s`) and an accept loop that
//! backs off and carries on when the process runs out of descriptors. Its counters are in the
//! metrics endpoint ([`counters`]); shedding writes a `connections_shed` event.

use std::sync::{Arc, LazyLock};
use std::time::Duration;

use super::snapshot::{LiveBoard, LiveSnapshot};
use crate::events::{Event, EventSender};
use crate::io::modbus::bounded_server::{
    spawn_bounded_tcp_server, ServerCounters, ServerLimits, ShedCause, ShedReport,
};
use crate::io::modbus::server::{lock_image, RegisterImage, SharedImage};
use crate::io::modbus::RegisterTable;
use crate::live::settings::StatusSection;

static COUNTERS: LazyLock<Arc<ServerCounters>> = LazyLock::new(Arc::default);

/// The DCS block's counters (one block per process; all zero and not `serving` while off).
pub fn counters() -> Arc<ServerCounters> {
    Arc::clone(&COUNTERS)
}

/// The block's limits from `[status]`.
pub fn limits(status: &StatusSection) -> ServerLimits {
    ServerLimits {
        max_connections: status.modbus_max_connections() as usize,
        idle_timeout: Duration::from_secs_f64(status.modbus_idle_timeout_s.clamp(1e-3, 3600.0)),
        max_requests_per_s: status.modbus_max_requests_per_s,
    }
}

/// The event for a shed report.
pub fn shed_event(r: &ShedReport) -> Event {
    Event::ConnectionsShed {
        server: format!("dcs-modbus {}", r.local_addr),
        cause: match r.cause {
            ShedCause::ConnectionCap => "connection_cap",
            ShedCause::DescriptorsExhausted => "descriptors_exhausted",
        }
        .to_string(),
        detail: r.error.clone(),
        open: r.counters.open,
        shed_total: r.counters.shed,
        accept_exhausted_total: r.counters.accept_exhausted,
    }
}

/// Unit id of the block.
pub const UNIT_ID: u8 = 1;

/// (address, name, encoding) of every register, in address order.
pub const REGISTERS: [(u16, &str, &str); 16] = [
    (0, "mode", "0 init, 1 manual, 2 auto, 3 fail-safe"),
    (1, "law", "law code (0 none, 1 recycle-pi, 2 recycle-fl, …)"),
    (2, "deviation", "int16, 0.01 % of control-line flow (positive = safe); -32768 unknown"),
    (3, "surge_margin", "int16, 0.01 %; -32768 unknown"),
    (4, "valve_output", "uint16, 0.01 % open; 65535 unknown"),
    (5, "valve_position", "uint16, 0.01 % open; 65535 unknown"),
    (6, "surge_count_lo", "surge counter, low 16 bits"),
    (7, "surge_count_hi", "surge counter, high 16 bits"),
    (8, "safety_on_steps", "safety-on steps in force"),
    (9, "fault_bits", "bit i: input i not usable (p_suction, p_discharge, shaft_speed, orifice_dp, …)"),
    (10, "cause_kind", "0 none, 1 input_fault, 2 flow_unavailable, 3 inputs_healthy, 4 operator, 5 surge_margin, 6 shutdown"),
    (11, "cause_input", "0 none, else input index + 1"),
    (12, "cause_fault", "0 none, 1 stale, 2 out_of_range, 3 nan, 4 alive_counter, 5 bus_off, 6 frozen, 7 drift"),
    (13, "flow_source", "0 none, 1 orifice, 2 observer, 3 observer standing in, 4 speed line standing in"),
    (14, "alive", "control cycle counter, low 16 bits (changes while the controller runs)"),
    (15, "trip_count", "recycle trips since start"),
];

fn i16_scaled(x: f64) -> u16 {
    if x.is_finite() {
        ((x * 100.0).round().clamp(-32767.0, 32767.0) as i16) as u16
    } else {
        0x8000
    }
}

fn u16_scaled(x: f64) -> u16 {
    if x.is_finite() {
        (x * 100.0).round().clamp(0.0, 65534.0) as u16
    } else {
        0xFFFF
    }
}

/// The block's words for a snapshot.
pub fn words(s: &LiveSnapshot) -> [u16; 16] {
    let c = s.cause;
    [
        u16::from(s.mode.code()),
        u16::from(s.law.code()),
        i16_scaled(s.deviation_pct),
        i16_scaled(s.surge_margin_pct),
        u16_scaled(100.0 * s.valve_output),
        u16_scaled(100.0 * s.valve_position),
        s.surge_count as u16,
        (s.surge_count >> 16) as u16,
        s.safety_on_count.min(65535) as u16,
        s.fault_bits as u16,
        c.map(|c| u16::from(c.kind.code())).unwrap_or(0),
        c.and_then(|c| c.input)
            .map(|i| i.index() as u16 + 1)
            .unwrap_or(0),
        match c.and_then(|c| c.fault) {
            None => 0,
            Some(crate::events::FallbackReason::Stale) => 1,
            Some(crate::events::FallbackReason::OutOfRange) => 2,
            Some(crate::events::FallbackReason::Nan) => 3,
            Some(crate::events::FallbackReason::AliveCounter) => 4,
            Some(crate::events::FallbackReason::BusOff) => 5,
            Some(crate::events::FallbackReason::Frozen) => 6,
            Some(crate::events::FallbackReason::Drift) => 7,
        },
        u16::from(s.flow_source.code()),
        s.cycle as u16,
        s.trip_count.min(65535) as u16,
    ]
}

/// Serve the block on `listener` within `limits`, refreshing it from `live` every 100 ms until
/// `shutdown`; shedding is logged to `events` and the journal.
pub async fn serve(
    listener: tokio::net::TcpListener,
    live: Arc<LiveBoard>,
    limits: ServerLimits,
    events: EventSender,
    mut shutdown: tokio::sync::watch::Receiver<bool>,
) {
    let mut image = RegisterImage::new();
    image.map(UNIT_ID, RegisterTable::Input, 0, REGISTERS.len() as u16);
    let image: SharedImage = image.into_shared();
    let on_shed = Arc::new(move |r: ShedReport| {
        let e = shed_event(&r);
        tracing::warn!(target: "status", "Modbus block for the DCS on {}: shedding connections ({:?}{}): {} open, {} shed, {} accept failures for want of descriptors",
            r.local_addr, r.cause, r.error.as_deref().map(|e| format!(", {e}")).unwrap_or_default(),
            r.counters.open, r.counters.shed, r.counters.accept_exhausted);
        let _ = events.send(e);
    });
    let server =
        match spawn_bounded_tcp_server(listener, Arc::clone(&image), limits, counters(), on_shed) {
            Ok(s) => s,
            Err(e) => {
                tracing::error!(target: "status", "Modbus block for the DCS: {e}");
                return;
            }
        };
    let mut tick = tokio::time::interval(Duration::from_millis(100));
    loop {
        tokio::select! {
            _ = tick.tick() => {
                if let Some(s) = live.latest() {
                    let _ = lock_image(&image).write_words(UNIT_ID, RegisterTable::Input, 0, &words(&s));
                }
            }
            _ = shutdown.changed() => break,
        }
    }
    server.shutdown().await;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::cause::{Cause, CauseKind};
    use crate::events::FallbackReason;
    use crate::vocab::signals::SensorId;
    use crate::vocab::Mode;

    #[test]
    fn encodes_the_snapshot() {
        let s = LiveSnapshot {
            mode: Mode::FailSafe,
            deviation_pct: -1.25,
            valve_output: 1.0,
            surge_count: 70_000,
            cause: Some(Cause {
                input: Some(SensorId::PDischarge),
                fault: Some(FallbackReason::Stale),
                ..Cause::of(CauseKind::InputFault)
            }),
            ..LiveSnapshot::default()
        };
        let w = words(&s);
        assert_eq!(w[0], 3);
        assert_eq!(w[2] as i16, -125);
        assert_eq!(w[3], 0x8000, "unknown margin");
        assert_eq!(w[4], 10000);
        assert_eq!(u32::from(w[6]) | u32::from(w[7]) << 16, 70_000);
        assert_eq!((w[10], w[11], w[12]), (1, 2, 1));
    }
}
