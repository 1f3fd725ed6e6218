//! What a controller link reports: its errors, failure causes, write health, state, counters
//! and the monitor that publishes them.

use crate::io::modbus::client::{ConfigError, ModbusError};
use crate::io::modbus::plan::PlanError;
use crate::io::modbus::register::{find_overlaps, RegisterBinding};
use crate::io::signal_map::SignalMap;
use crate::vocab::signals::ActuatorId;
use std::io;
use std::sync::Arc;
use thiserror::Error;
use tokio::sync::watch;
use tokio_modbus::ExceptionCode;

use super::*;

/// Why a link task could not start or had to stop.
#[derive(Debug, Error)]
pub enum LinkError {
    /// The client settings are unusable.
    #[error(transparent)]
    Client(#[from] ConfigError),
    /// A link setting is out of range.
    #[error("invalid Modbus link config: {message}")]
    Invalid {
        /// The key, relative to the link settings (`poll_rate_hz`, `heartbeat_register`).
        key: &'static str,
        /// What is wrong with it.
        message: String,
    },
    /// The signal map's Modbus bindings are inconsistent (overlaps, read-only actuators,
    /// heartbeat block on top of a signal).
    #[error("signal map: {0}")]
    Map(String),
    /// The bindings could not be planned into requests.
    #[error("Modbus request plan: {0}")]
    Plan(#[from] PlanError),
    /// An OS-level failure (binding the listener, registering the wakeup eventfd, accept).
    #[error("{context}: {source}")]
    Io {
        /// What was being done.
        context: &'static str,
        /// The OS error.
        #[source]
        source: io::Error,
    },
}

impl LinkError {
    /// The settings key a configuration error is about, relative to the link settings
    /// (`poll_rate_hz`, `client.timeout_ms`); `None` for errors that are not about one key.
    pub fn config_key(&self) -> Option<String> {
        match self {
            LinkError::Invalid { key, .. } => Some((*key).to_string()),
            LinkError::Client(c) => Some(format!("client.{}", c.key())),
            _ => None,
        }
    }
}

/// Check the map and that the heartbeat block does not sit on a mapped signal.
pub(crate) fn check_map(
    map: &SignalMap,
    heartbeat: Option<&HeartbeatRegister>,
) -> Result<(), LinkError> {
    let problems: Vec<_> = map.check().into_iter().filter(|p| !p.warning).collect();
    if !problems.is_empty() {
        let text: Vec<String> = problems
            .iter()
            .map(|p| format!("{}: {}", p.key, p.message))
            .collect();
        return Err(LinkError::Map(text.join("; ")));
    }
    let Some(hb) = heartbeat else {
        return Ok(());
    };
    let mut all: Vec<RegisterBinding> = map.modbus_sensors().iter().map(|(_, b)| *b).collect();
    all.extend(map.modbus_spares().iter().map(|(_, _, b)| *b));
    all.extend(map.modbus_actuators().iter().map(|(_, b)| *b));
    let signals = all.len();
    all.extend(hb.bindings());
    if let Some(o) = find_overlaps(&all)
        .iter()
        .find(|o| (o.first < signals) != (o.second < signals))
    {
        let b = all[o.first.min(o.second)];
        return Err(LinkError::Map(format!(
            "heartbeat_register (unit {}, holding {}..{}) overlaps the signal at unit {} {} register {}",
            hb.unit_id,
            hb.address,
            u32::from(hb.address) + u32::from(HEARTBEAT_REGISTERS) - 1,
            b.unit_id,
            b.table.name(),
            b.address
        )));
    }
    Ok(())
}

/// Why the link is down (the last real failure; fast-failing backoff waits keep it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FailureCause {
    /// A request got no answer within `timeout_ms`.
    Timeout,
    /// Connecting did not finish within `timeout_ms`.
    ConnectTimeout,
    /// Connecting failed (refused, unreachable, no such serial device).
    Connect,
    /// I/O error during a request (reset, EOF, broken pipe).
    Transport,
    /// A malformed or mismatched response.
    Protocol,
}

impl FailureCause {
    pub(super) fn of(e: &ModbusError) -> Option<FailureCause> {
        Some(match e {
            ModbusError::Timeout { .. } => FailureCause::Timeout,
            ModbusError::ConnectTimeout { .. } => FailureCause::ConnectTimeout,
            ModbusError::Connect(_) => FailureCause::Connect,
            ModbusError::Transport(_) => FailureCause::Transport,
            ModbusError::Protocol(_) => FailureCause::Protocol,
            ModbusError::Exception { .. }
            | ModbusError::Backoff { .. }
            | ModbusError::LengthMismatch { .. } => return None,
        })
    }
}

/// A Modbus exception answer, as reported in a degraded [`LinkState`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ExceptionInfo {
    /// Unit that answered.
    pub unit_id: u8,
    /// Function code of the refused request.
    pub function: u8,
    /// First address of the refused request.
    pub address: u16,
    /// Exception code.
    pub code: ExceptionCode,
}

impl ExceptionInfo {
    pub(super) fn of(e: &ModbusError) -> Option<ExceptionInfo> {
        match *e {
            ModbusError::Exception {
                unit_id,
                function,
                address,
                code,
            } => Some(ExceptionInfo {
                unit_id,
                function,
                address,
                code,
            }),
            _ => None,
        }
    }
}

/// Why writes fail.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WriteFailure {
    /// The device answered a write with an exception (e.g. code 2, illegal data address).
    Exception(ExceptionInfo),
    /// The link failed during a write (timeout, connection lost).
    Link(FailureCause),
}

impl std::fmt::Display for WriteFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            WriteFailure::Exception(x) => write!(
                f,
                "device refused the write with exception {} ({:?}) at unit {} function 0x{:02X} address {}",
                u8::from(x.code),
                x.code,
                x.unit_id,
                x.function,
                x.address
            ),
            WriteFailure::Link(c) => write!(f, "write not answered: {c:?}"),
        }
    }
}

/// Health of the controller's writes, published on change through
/// [`LinkMonitor::subscribe_writes`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WriteHealth {
    /// The last write was acknowledged in full (or nothing was written yet).
    Ok,
    /// Writes are failing.
    Failing {
        /// The first failure of this episode.
        cause: WriteFailure,
        /// The failures lasted `write_fault_timeout_ms`: the watchdog is withheld.
        safe_state: bool,
    },
}

/// State of a controller link: the field links' one [`LinkState`](crate::io::link::LinkState),
/// degraded by a device's exception answers ([`ExceptionInfo`]: connected, but the device
/// refused at least one request of the last cycle; the first one is shown, the values of the
/// refused requests go stale), down for a [`FailureCause`] (the client reconnects with backoff;
/// `attempt` counts the failures since the last good exchange, connect attempts included;
/// sensor values go stale). Published on change through [`LinkMonitor::subscribe`].
pub type LinkState = crate::io::link::LinkState<ExceptionInfo, FailureCause>;

impl crate::io::link::Degradation for ExceptionInfo {
    fn status_name(&self) -> &'static str {
        "exception"
    }
}

impl std::fmt::Display for ExceptionInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "exception {} ({:?}) at unit {} function 0x{:02X} address {}",
            u8::from(self.code),
            self.code,
            self.unit_id,
            self.function,
            self.address
        )
    }
}

impl crate::io::link::DownReason for FailureCause {}

impl std::fmt::Display for FailureCause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            FailureCause::Timeout => "no answer within the timeout",
            FailureCause::ConnectTimeout => "connect timed out",
            FailureCause::Connect => "connect failed",
            FailureCause::Transport => "I/O error",
            FailureCause::Protocol => "malformed or mismatched answer",
        })
    }
}

pub(crate) use crate::io::link::link_counters as counters;

counters! {
    /// Controller link counters (atomics, updated by the link task, read by anyone).
    atomic LinkCounters;
    /// A copy of [`LinkCounters`].
    plain LinkCounts;
    {
        /// Link cycles run.
        cycles,
        /// Cycles that took longer than the period (e.g. waiting for timeouts).
        overruns,
        /// Duration of the last cycle, µs.
        last_cycle_us,
        /// Longest cycle, µs.
        max_cycle_us,
        /// Sensor polls (one read plan per cycle).
        polls,
        /// Polls in which every read request was answered.
        polls_ok,
        /// Sensor values published into the sensor board.
        values_published,
        /// Write attempts (cycles that had a new output set to send).
        writes,
        /// Write attempts acknowledged in full.
        writes_ok,
        /// Output sets not written because they were older than `max_output_age_ms`.
        writes_stale,
        /// Setpoints left out because they had not changed (`write_on_change_only`).
        setpoints_unchanged,
        /// Heartbeat blocks written and acknowledged.
        heartbeats,
        /// Write attempts refused with an exception or not answered.
        write_failures,
        /// Output sets written with the watchdog withheld (writes failing too long).
        watchdog_withheld,
        /// Requests sent (client counter).
        requests,
        /// Requests without an answer within the timeout (client counter).
        timeouts,
        /// Exception answers (client counter).
        exceptions,
        /// I/O errors during requests (client counter).
        transport_errors,
        /// Malformed or mismatched answers (client counter).
        protocol_errors,
        /// Achieved poll period over the last second, µs (gauge; see [`quality`]).
        poll_period_us,
        /// Answer latency over the last ten seconds, median, µs (gauge).
        latency_p50_us,
        /// Answer latency over the last ten seconds, 99th percentile, µs (gauge).
        latency_p99_us,
        /// Connect attempts (client counter).
        connect_attempts,
        /// Failed connect attempts (client counter).
        connect_failures,
        /// Successful connects after the first (client counter).
        reconnects,
        /// Times the link went down (up, degraded or idle to down).
        link_down,
        /// Setpoints saturated to the register type's range (client counter).
        clamped_values,
    }
}

/// Where a controller link reports: counters and the state channel. Share it (`Arc`) with
/// whoever logs or displays the link.
#[derive(Debug)]
pub struct LinkMonitor {
    pub(super) counters: LinkCounters,
    pub(super) state: watch::Sender<LinkState>,
    pub(super) writes: watch::Sender<WriteHealth>,
    pub(super) another_writer: watch::Sender<Option<AnotherWriter>>,
}

/// An actuator's command register, read back, holds a value this controller did not write.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnotherWriter {
    /// The actuator.
    pub actuator: ActuatorId,
    /// Its register: unit, table and protocol address.
    pub unit_id: u8,
    /// Protocol address (0-based) of the holding register.
    pub address: u16,
    /// The value read back, SI units of the actuator.
    pub read: f64,
    /// The value this controller last wrote and the device acknowledged.
    pub written: f64,
}

impl std::fmt::Display for AnotherWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "another writer: {}'s holding register {} (unit {}) reads {:.4}, this controller last wrote {:.4}",
            self.actuator.name(),
            self.address,
            self.unit_id,
            self.read,
            self.written
        )
    }
}

impl Default for LinkMonitor {
    fn default() -> Self {
        LinkMonitor::new()
    }
}

impl LinkMonitor {
    /// Counters at zero, state idle.
    pub fn new() -> LinkMonitor {
        LinkMonitor {
            counters: LinkCounters::default(),
            state: watch::Sender::new(LinkState::Idle),
            writes: watch::Sender::new(WriteHealth::Ok),
            another_writer: watch::Sender::new(None),
        }
    }

    /// A receiver that sees every change of the read-back verdict (`Some`: another writer
    /// seen on the last read-back).
    pub fn subscribe_another_writer(&self) -> watch::Receiver<Option<AnotherWriter>> {
        self.another_writer.subscribe()
    }

    pub(super) fn set_another_writer(&self, new: Option<AnotherWriter>) {
        self.another_writer.send_if_modified(|s| {
            if *s == new {
                false
            } else {
                *s = new;
                true
            }
        });
    }

    /// A receiver that sees every change of the write health.
    pub fn subscribe_writes(&self) -> watch::Receiver<WriteHealth> {
        self.writes.subscribe()
    }

    /// Current write health.
    pub fn write_health(&self) -> WriteHealth {
        *self.writes.borrow()
    }

    pub(super) fn set_writes(&self, new: WriteHealth) {
        self.writes.send_if_modified(|s| {
            if *s == new {
                false
            } else {
                *s = new;
                true
            }
        });
    }

    /// A receiver that sees every state change (`changed().await`, then `borrow()`).
    pub fn subscribe(&self) -> watch::Receiver<LinkState> {
        self.state.subscribe()
    }

    /// Current state.
    pub fn state(&self) -> LinkState {
        *self.state.borrow()
    }

    /// Live counters.
    pub fn counters(&self) -> &LinkCounters {
        &self.counters
    }

    pub(super) fn set_state(&self, new: LinkState) {
        self.state.send_if_modified(|s| {
            if *s == new {
                false
            } else {
                if new.is_down() && !s.is_down() {
                    LinkCounters::inc(&self.counters.link_down);
                }
                *s = new;
                true
            }
        });
    }
}

/// A running Modbus controller link as the daemon sees it
/// ([`FieldLink`](crate::io::link::FieldLink)): its monitor.
pub struct ModbusLinkView {
    /// `modbus:<address>` or `modbus:<serial device>`.
    pub name: String,
    /// The link's monitor.
    pub monitor: Arc<LinkMonitor>,
}

impl crate::io::link::FieldLink for ModbusLinkView {
    fn kind(&self) -> crate::vocab::faults::FieldLinkKind {
        crate::vocab::faults::FieldLinkKind::Modbus
    }
    fn name(&self) -> &str {
        &self.name
    }
    fn status_name(&self) -> &'static str {
        self.monitor.state().status_name()
    }
    fn is_up(&self) -> bool {
        self.monitor.state().is_up()
    }
    fn traffic(&self) -> crate::io::link::LinkTraffic {
        let c = self.monitor.counters().snapshot();
        crate::io::link::LinkTraffic {
            sent: c.requests,
            received: c.requests.saturating_sub(c.timeouts + c.transport_errors),
            errors: c.timeouts + c.exceptions + c.transport_errors + c.protocol_errors,
            down: c.link_down,
            reconnects: c.reconnects,
        }
    }
    fn counters_json(&self) -> serde_json::Value {
        serde_json::to_value(self.monitor.counters().snapshot()).unwrap_or_default()
    }
}
