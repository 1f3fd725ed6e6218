//! Modbus link tasks: the controller's poll/write loop and the plant node's server.
//!
//! **Controller role** ([`run_controller`]): one [`ModbusClient`] (TCP or RTU) reads every
//! Modbus sensor of the signal map once per link cycle and publishes the values into the
//! [`SensorBoard`], stamped with the monotonic time the response arrived. It then writes the
//! setpoints the control thread computed from those values (waiting for its next cycle, at
//! most one link period) from the [`OutputBoard`], and reads back the command registers
//! configured with `readback`. A failed or timed-out read
//! publishes nothing: the control loop sees its inputs age and goes fail-safe by itself.
//! The link never decides fail-safe; it only keeps trying (the client reconnects with
//! backoff) and reports its state through a [`tokio::sync::watch`] channel
//! ([`LinkMonitor`]).
//!
//! **Plant role** ([`run_plant_server`], [`PlantServer`]): a Modbus TCP server whose register
//! image holds the plant's sensors, re-encoded from the [`SnapshotBoard`] whenever a read
//! request arrives and a newer snapshot exists (so answers are never older than the latest
//! published snapshot). Client writes to actuator registers are published into the
//! [`CommandBoard`] with their arrival time, and as the controller heartbeat into the
//! [`HeartbeatBoard`] (see [`HeartbeatRegister`]).
//!
//! [`SnapshotBoard`]: crate::runtime::handoff::SnapshotBoard
//! [`CommandBoard`]: crate::runtime::handoff::CommandBoard
//! [`HeartbeatBoard`]: crate::runtime::handoff::HeartbeatBoard
//!
//! **Pacing.** Modbus is request/response: every value costs a round trip (≈0.1–1 ms on TCP,
//! tens of ms per request on RTU at 19 200 Bd), so the link rate must be chosen for the bus,
//! not derived from the control rate. The default [`Pacing::Interval`] therefore runs a
//! fixed-rate loop at `poll_rate_hz` (a `tokio::time::interval`, adequate at ≥ 1 ms periods;
//! 50 Hz by default), which samples the sensors at regular instants and needs no coupling to
//! the control thread. [`Pacing::Wakeup`] instead runs one cycle after each control-thread
//! wakeup (rate-limited to `poll_rate_hz`), writing the fresh outputs first and reading the
//! sensors right after, which removes up to one link period of output latency when the
//! control thread runs at or below the link rate.
//!
//! **Output freshness.** Each new output set (new control-thread cycle number) is written
//! once (retried only until the device acknowledges it); sets older than `max_output_age_ms`
//! are never written. If the control thread
//! stops, the writes (and the heartbeat) stop with it, so the plant's heartbeat timeout sees
//! the controller die instead of a link task replaying its last setpoints.

mod commands;
mod plant;
pub mod quality;

pub use plant::{run_plant_server, PlantCounters, PlantCounts, PlantServer};

use std::future::Future;
use std::io;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use thiserror::Error;
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;
use tokio::sync::watch;

/// Longest a link back from a failure withholds a fail-safe output set, ns: twice the core's
/// fail-safe exit hysteresis (0.5 s), so a core that resumes is written from its resumed
/// output and a fail-safe that lasts reaches the device.
const RESYNC_FAILSAFE_NS: u64 = 1_000_000_000;
use tokio::time::{Instant, MissedTickBehavior};
use tokio_modbus::ExceptionCode;

use super::client::{ClientConfig, ConfigError, ConnectionState, ModbusClient, ModbusError};
use super::plan::{PlanError, ReadPlan, WritePlan};
use super::register::{find_overlaps, DataType, RegisterBinding, RegisterTable};
use crate::io::signal_map::SignalMap;
use crate::runtime::handoff::{monotonic_ns, OutputBoard, SensorBoard, Wakeup};
use crate::vocab::signals::{ActuatorId, SensorId};
use crate::vocab::Mode;

/// Highest accepted `poll_rate_hz` (the tokio timer has 1 ms resolution).
pub const MAX_POLL_RATE_HZ: f64 = 1000.0;

/// Number of holding registers a [`HeartbeatRegister`] block spans.
pub const HEARTBEAT_REGISTERS: u16 = 4;

/// The optional controller heartbeat block: four consecutive holding registers the
/// controller writes with every new output set, so the plant can tell a live controller
/// from a dead one even when no setpoint changes (Modbus has no heartbeat frame).
///
/// Layout (16-bit registers from `address`, standard big-endian bytes):
///
/// | register      | content                                                        |
/// |---------------|----------------------------------------------------------------|
/// | `address + 0` | high byte: controller mode (0 init, 1 manual, 2 auto, 3 fail-safe, 4 shutdown); low byte: alive counter (+1 per write, wraps at 255) |
/// | `address + 1` | active law id (low byte; high byte 0)                          |
/// | `address + 2` | fault bits 31..16                                              |
/// | `address + 3` | fault bits 15..0                                               |
///
/// Config keys: `unit_id`, `address` (0-based protocol address of the first register).
/// The controller's [`ModbusLinkConfig`] and the plant's [`ModbusServerConfig`] must name
/// the same block.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeartbeatRegister {
    /// Unit (slave) id of the block.
    pub unit_id: u8,
    /// 0-based protocol address of the first of the four holding registers.
    pub address: u16,
}

/// Content of a heartbeat block.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct HeartbeatWords {
    /// Controller mode code.
    pub mode: u8,
    /// Alive counter (increments with every write, wraps).
    pub alive: u8,
    /// Active law id.
    pub law: u8,
    /// Fault bits.
    pub faults: u32,
}

impl HeartbeatRegister {
    /// The block as register bindings (u16 mode/alive, u16 law, u32 faults), for a write plan.
    pub fn bindings(&self) -> [RegisterBinding; 3] {
        let a = self.address;
        [
            RegisterBinding::new(self.unit_id, RegisterTable::Holding, a, DataType::U16),
            RegisterBinding::new(
                self.unit_id,
                RegisterTable::Holding,
                a.wrapping_add(1),
                DataType::U16,
            ),
            RegisterBinding::new(
                self.unit_id,
                RegisterTable::Holding,
                a.wrapping_add(2),
                DataType::U32,
            ),
        ]
    }

    /// Whether the block fits below address 65536.
    pub fn validate(&self) -> Result<(), LinkError> {
        if u32::from(self.address) + u32::from(HEARTBEAT_REGISTERS) > 1 << 16 {
            return Err(LinkError::Invalid {
                key: "heartbeat_register",
                message: format!(
                    "heartbeat_register: {HEARTBEAT_REGISTERS} registers from address {} run past 65535",
                    self.address
                ),
            });
        }
        Ok(())
    }

    /// Whether the write `[address, address + count)` on `unit_id` touches the block.
    pub fn touched_by(&self, unit_id: u8, address: u16, count: u16) -> bool {
        unit_id == self.unit_id
            && ranges_intersect(
                u32::from(address),
                u32::from(count),
                u32::from(self.address),
                u32::from(HEARTBEAT_REGISTERS),
            )
    }
}

impl HeartbeatWords {
    /// The four register words of the block.
    pub fn encode(&self) -> [u16; 4] {
        [
            (u16::from(self.mode) << 8) | u16::from(self.alive),
            u16::from(self.law),
            (self.faults >> 16) as u16,
            self.faults as u16,
        ]
    }

    /// Decode the four register words of the block.
    pub fn decode(words: &[u16; 4]) -> HeartbeatWords {
        HeartbeatWords {
            mode: (words[0] >> 8) as u8,
            alive: words[0] as u8,
            law: words[1] as u8,
            faults: (u32::from(words[2]) << 16) | u32::from(words[3]),
        }
    }
}

fn ranges_intersect(a: u32, a_len: u32, b: u32, b_len: u32) -> bool {
    a < b + b_len && b < a + a_len
}

fn default_poll_rate_hz() -> f64 {
    50.0
}
fn default_max_output_age_ms() -> u64 {
    500
}
fn default_write_fault_ms() -> u64 {
    500
}

/// Controller-side Modbus link configuration.
///
/// Config keys:
/// - `client`: transport, `timeout_ms`, `backoff_initial_ms`, `backoff_max_ms`
///   (see [`ClientConfig`]);
/// - `poll_rate_hz`: link cycles per second, each one sensor read and one write
///   (default 50, at most 1000);
/// - `write_on_change_only`: write a setpoint only when its value differs from the last one
///   the device acknowledged (default false: every new output set is written in full). All
///   setpoints are rewritten after any link failure or exception. With this on, the plant's
///   command timestamps show the last change, not liveness: configure `heartbeat_register`;
/// - `max_output_age_ms`: outputs the control thread published longer ago than this are not
///   written (default 500);
/// - `cycle_trigger`: `"reads"` (default): each completed read starts a control cycle at once
///   (the cycle's deadline stays as fallback, [`crate::runtime::trigger`]); `"deadline"`: the
///   control thread runs on its own clock only;
/// - `command_connection`: `"shared"` (default): commands and reads on one connection;
///   `"own"`: the commands on a second TCP connection ([`CommandConnection`]);
/// - `heartbeat_register`: optional `{ unit_id, address }` of the heartbeat block
///   ([`HeartbeatRegister`]).
///
/// ```toml
/// poll_rate_hz = 50
/// heartbeat_register = { unit_id = 1, address = 300 }
/// [client]
/// timeout_ms = 100
/// transport = { kind = "tcp", address = "192.168.0.10:502" }
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModbusLinkConfig {
    /// Transport (TCP address or RTU serial line), timeouts and reconnect backoff.
    pub client: ClientConfig,
    /// Link cycles per second, Hz.
    #[serde(default = "default_poll_rate_hz")]
    pub poll_rate_hz: f64,
    /// Write only setpoints that changed since the last acknowledged write.
    #[serde(default)]
    pub write_on_change_only: bool,
    /// Oldest output set still written, ms.
    #[serde(default = "default_max_output_age_ms")]
    pub max_output_age_ms: u64,
    /// Heartbeat block written with every output set, if any (legacy 4-register layout;
    /// prefer `[watchdog.modbus]` in the signal map).
    #[serde(default)]
    pub heartbeat_register: Option<HeartbeatRegister>,
    /// Merge setpoints at adjacent registers into one write-multiple request (default
    /// false: every setpoint and watchdog register is its own request).
    #[serde(default)]
    pub merge_writes: bool,
    /// After writes have failed (exception or timeout) for this long, the link withholds
    /// the watchdog (alive counter and toggle stand still) so that the device's own
    /// watchdog takes it to its safe state, ms (default 500).
    #[serde(default = "default_write_fault_ms")]
    pub write_fault_timeout_ms: u64,
    /// What starts a control cycle (default: the link's reads).
    #[serde(default)]
    pub cycle_trigger: ModbusCycleTrigger,
    /// Whether the commands share the reads' connection (default) or have their own.
    #[serde(default)]
    pub command_connection: CommandConnection,
}

/// Which TCP connection carries the commands (`[bus.modbus] command_connection`).
///
/// Purpose: a device that answers one connection's requests one after the other (gateways
/// and most PLC servers do) makes every command wait behind the read before it, and every
/// sample wait behind the write before it. On one connection a sample is therefore taken up
/// to one read plus one write latency after a disturbance (the link cycle) and its answer
/// lands a read and a write latency later: up to 4 device latencies, 80 ms on a device
/// answering in 5–20 ms, against 60–80 ms from a throttle step to flow reversal on a fast
/// machine. With its own connection the reads follow each other at the poll period (or one
/// read latency) and each answer is written the moment the control cycle computed it: up to
/// a poll period plus about 3 latencies (the write connection may still carry the previous
/// command), 60–65 ms on that device at 50–100 Hz (`tests/modbus_rate_e2e.rs`).
/// Needs a device that accepts two client connections (Modbus TCP servers commonly take
/// several); refused for RTU (one serial line, one request at a time).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CommandConnection {
    /// Commands and reads on one connection, one request after the other.
    #[default]
    Shared,
    /// A second TCP connection for the commands and their read-backs.
    Own,
}

/// What starts the controller's cycles on a Modbus skid (`[bus.modbus] cycle_trigger`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModbusCycleTrigger {
    /// Each completed read of the sensors: the control cycle runs on the values the moment
    /// they arrive, and the link writes its answer right after. On a clock of its own the
    /// cycle finds the values up to one control period late (10–20 ms at 100–50 Hz: a
    /// quarter of the 60–80 ms from a throttle step to flow reversal on a fast machine).
    #[default]
    Reads,
    /// The control thread's own deadline only.
    Deadline,
}

impl ModbusLinkConfig {
    /// A configuration with default rate, full writes and no heartbeat block.
    pub fn new(client: ClientConfig) -> ModbusLinkConfig {
        ModbusLinkConfig {
            client,
            poll_rate_hz: default_poll_rate_hz(),
            write_on_change_only: false,
            max_output_age_ms: default_max_output_age_ms(),
            heartbeat_register: None,
            merge_writes: false,
            write_fault_timeout_ms: default_write_fault_ms(),
            cycle_trigger: ModbusCycleTrigger::default(),
            command_connection: CommandConnection::default(),
        }
    }

    /// Check ranges: the client settings, 0 < `poll_rate_hz` ≤ [`MAX_POLL_RATE_HZ`],
    /// `max_output_age_ms` > 0, heartbeat block inside the address space.
    pub fn validate(&self) -> Result<(), LinkError> {
        self.client.validate()?;
        if !(self.poll_rate_hz.is_finite()
            && self.poll_rate_hz > 0.0
            && self.poll_rate_hz <= MAX_POLL_RATE_HZ)
        {
            return Err(LinkError::Invalid {
                key: "poll_rate_hz",
                message: format!(
                    "poll_rate_hz must be in (0, {MAX_POLL_RATE_HZ}], got {}",
                    self.poll_rate_hz
                ),
            });
        }
        if self.max_output_age_ms == 0 {
            return Err(LinkError::Invalid {
                key: "max_output_age_ms",
                message: "max_output_age_ms must be > 0".into(),
            });
        }
        if let Some(hb) = &self.heartbeat_register {
            hb.validate()?;
        }
        if self.command_connection == CommandConnection::Own
            && !matches!(
                self.client.transport,
                super::client::TransportConfig::Tcp { .. }
            )
        {
            return Err(LinkError::Invalid {
                key: "command_connection",
                message: "command_connection = \"own\" needs Modbus TCP: an RTU line carries one \
                          request at a time"
                    .into(),
            });
        }
        Ok(())
    }

    /// Link cycle period.
    pub fn period(&self) -> Duration {
        Duration::from_secs_f64(1.0 / self.poll_rate_hz)
    }
}

fn default_listen() -> std::net::SocketAddr {
    std::net::SocketAddr::from(([127, 0, 0, 1], 5020))
}

/// Plant-side Modbus server configuration. The unit ids and registers served are those of
/// the signal map's Modbus bindings (plus the heartbeat block).
///
/// Config keys: `listen` (socket address, default `"127.0.0.1:5020"`; port 0 picks a free
/// port), `heartbeat_register` (optional `{ unit_id, address }`, see [`HeartbeatRegister`]:
/// when set, only writes to that block count as controller heartbeats; when absent, every
/// client write does, reported as mode 2 (auto) with the write count as alive counter),
/// `allow_writes_from` (client IP addresses allowed to write, default loopback only:
/// `["127.0.0.1", "::1"]`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModbusServerConfig {
    /// Address to listen on.
    #[serde(default = "default_listen")]
    pub listen: std::net::SocketAddr,
    /// Heartbeat block, if the controller writes one.
    #[serde(default)]
    pub heartbeat_register: Option<HeartbeatRegister>,
    /// Client IP addresses whose writes (actuator setpoints, heartbeat) are applied. Any
    /// client may read; a write from any other address is answered with exception 0x01
    /// (illegal function), changes nothing and is logged (rate-limited). A third client
    /// must not be able to close the valve or forge the controller's heartbeat (issue 12,
    /// item 8). An IPv4-mapped IPv6 peer (`::ffff:a.b.c.d`) counts as its IPv4 address.
    #[serde(default = "default_allow_writes_from")]
    pub allow_writes_from: Vec<std::net::IpAddr>,
}

impl Default for ModbusServerConfig {
    fn default() -> Self {
        ModbusServerConfig {
            listen: default_listen(),
            heartbeat_register: None,
            allow_writes_from: default_allow_writes_from(),
        }
    }
}

impl ModbusServerConfig {
    /// Whether a client at `ip` may write.
    pub fn may_write(&self, ip: std::net::IpAddr) -> bool {
        let ip = ip.to_canonical();
        self.allow_writes_from
            .iter()
            .any(|a| a.to_canonical() == ip)
    }
}

fn default_allow_writes_from() -> Vec<std::net::IpAddr> {
    vec![
        std::net::IpAddr::from([127, 0, 0, 1]),
        std::net::IpAddr::from(std::net::Ipv6Addr::LOCALHOST),
    ]
}

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
    fn of(e: &ModbusError) -> Option<FailureCause> {
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

/// A Modbus exception answer, as reported in [`LinkState::Exception`].
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
    fn of(e: &ModbusError) -> Option<ExceptionInfo> {
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

/// State of a controller link, published on change through [`LinkMonitor::subscribe`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkState {
    /// No exchange yet.
    Idle,
    /// Every request of the last cycle was answered normally.
    Up,
    /// Connected, but the device refused at least one request of the last cycle with an
    /// exception (the first one is shown). Values of the refused requests go stale.
    Exception(ExceptionInfo),
    /// The link failed and the client is reconnecting with backoff. Sensor values go stale.
    Down {
        /// Failures since the last good exchange (connect attempts included).
        consecutive_failures: u32,
        /// Current backoff before the next connect attempt, ms.
        backoff_ms: u64,
        /// The last failure.
        cause: FailureCause,
    },
    /// The task has stopped (shutdown).
    Stopped,
}

macro_rules! counters {
    (
        $(#[$atomic_meta:meta])* atomic $atomic:ident;
        $(#[$plain_meta:meta])* plain $plain:ident;
        { $( $(#[doc = $doc:literal])* $field:ident ),* $(,)? }
    ) => {
        $(#[$atomic_meta])*
        #[derive(Debug, Default)]
        pub struct $atomic {
            $( $(#[doc = $doc])* $field: AtomicU64, )*
        }

        $(#[$plain_meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
        pub struct $plain {
            $( $(#[doc = $doc])* pub $field: u64, )*
        }

        impl $atomic {
            /// A consistent-enough copy of every counter (each read atomically, relaxed).
            pub fn snapshot(&self) -> $plain {
                $plain { $( $field: self.$field.load(Ordering::Relaxed), )* }
            }
        }
    };
}
pub(crate) use counters;

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
        /// Setpoints saturated to the register type's range (client counter).
        clamped_values,
    }
}

impl LinkCounters {
    fn add(c: &AtomicU64, n: u64) {
        c.fetch_add(n, Ordering::Relaxed);
    }
}

/// Where a controller link reports: counters and the state channel. Share it (`Arc`) with
/// whoever logs or displays the link.
#[derive(Debug)]
pub struct LinkMonitor {
    counters: LinkCounters,
    state: watch::Sender<LinkState>,
    writes: watch::Sender<WriteHealth>,
    another_writer: watch::Sender<Option<AnotherWriter>>,
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
    /// Counters at zero, state [`LinkState::Idle`].
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

    fn set_another_writer(&self, new: Option<AnotherWriter>) {
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

    fn set_writes(&self, new: WriteHealth) {
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

    fn set_state(&self, new: LinkState) {
        self.state.send_if_modified(|s| {
            if *s == new {
                false
            } else {
                *s = new;
                true
            }
        });
    }
}

/// What starts a controller link cycle.
#[derive(Debug, Clone)]
pub enum Pacing {
    /// A fixed-rate loop at `poll_rate_hz`: read sensors, publish, then write the outputs
    /// computed from them (or the latest after one link period). A cycle that overruns
    /// delays the next tick (no catch-up bursts).
    Interval,
    /// One cycle per control-thread wakeup, at most `poll_rate_hz`: write the fresh outputs,
    /// then read sensors for the next control cycle. Nothing happens while the control
    /// thread is silent. The eventfd must be this task's own: each waiter clears it, and
    /// tokio cannot register one descriptor twice.
    Wakeup(Arc<Wakeup>),
}

/// The sensors of one planned read request (a contiguous range of one unit and table), so
/// each group gets the arrival time of its own response and an exception spoils only it.
#[derive(Debug)]
struct SensorGroup {
    plan: ReadPlan,
    /// Sensor and transmitter slot (0 = `a`, the `[sensors]` binding; 1, 2 = `[vote]`'s).
    ids: Vec<(SensorId, usize)>,
    values: Vec<f64>,
}

/// What happened during one cycle.
#[derive(Debug, Default)]
struct Outcome {
    /// At least one exchange got a normal answer.
    answered: bool,
    /// First exception answer.
    exception: Option<ExceptionInfo>,
    /// A link failure (including a backoff wait) ended an operation.
    link_failed: bool,
    /// A write was attempted: `Some(None)` acknowledged, `Some(Some(_))` failed.
    write: Option<Option<WriteFailure>>,
}

/// Whether a request's outcome is a latency sample: an answer (normal or exception), or a
/// timeout, counted with the time waited (a lower bound of its latency, so that the p99 does
/// not hide a device that answers after the timeout). A refused connection or a reset is no
/// latency.
fn counts_for_latency<T>(r: &Result<T, ModbusError>) -> bool {
    match r {
        Ok(_) => true,
        Err(e) => ExceptionInfo::of(e).is_some() || matches!(e, ModbusError::Timeout { .. }),
    }
}

/// The controller link's state between cycles.
struct Controller {
    client: ModbusClient,
    groups: Vec<SensorGroup>,
    write_plan: WritePlan,
    actuators: Vec<ActuatorId>,
    /// Values for `write_plan` (actuators, then the heartbeat bindings).
    write_values: Vec<f64>,
    /// Bits of the last acknowledged value per actuator (`write_on_change_only`).
    acknowledged: Vec<u64>,
    /// Whether `acknowledged` reflects the device (false after any failure).
    acknowledged_valid: bool,
    heartbeat: bool,
    alive: u8,
    /// The map's watchdog contract, written after the actuators (and legacy block).
    watchdog: Option<super::watchdog::ModbusWatchdog>,
    watchdog_writer: super::watchdog::WatchdogWriter,
    /// Index of the first watchdog value in `write_values`.
    watchdog_at: usize,
    /// Writes failing since (monotonic ns) and why.
    write_failing: Option<(u64, WriteFailure)>,
    write_fault_ns: u64,
    change_only: bool,
    max_output_age_ns: u64,
    /// Control cycle number of the last output set written in full.
    last_written_cycle: Option<u64>,
    /// After a link failure: nothing is written until the control thread has published an
    /// output set computed from the first values read after the failure. `Some(None)`: no
    /// values read yet; `Some(Some(k))`: values read while output set `k` was the latest, so
    /// set `k + 2` is the first computed after them. (The sets published while the link was
    /// down were computed without inputs: a 3-s outage wrote the fail-safe 100 % onto a valve
    /// measured at 4 % first thing after the resume.)
    resync: Option<Option<u64>>,
    /// When the first values after the failure were read (monotonic ns).
    resync_read_ns: u64,
    last_cause: FailureCause,
    sensors: Arc<SensorBoard>,
    outputs: Arc<OutputBoard>,
    monitor: Arc<LinkMonitor>,
    /// Achieved poll period and answer latency.
    quality: quality::QualityWindow,
    /// Actuators whose command register is read back: (index in `actuators`, plan, value).
    readbacks: Vec<(usize, ReadPlan, [f64; 1])>,
    /// When the next read-back is due (monotonic ns).
    next_readback_ns: u64,
    /// The link period, ns: the longest a write waits for the output set computed from the
    /// values just read.
    period_ns: u64,
    /// When this cycle's read published its values (monotonic ns; 0: nothing published).
    read_done_ns: u64,
    /// Fired after each read that published values (`cycle_trigger = "reads"`).
    trigger: Option<Arc<crate::runtime::trigger::CycleTrigger>>,
    /// What this task does of the link: all of it, or one side of `command_connection = "own"`.
    role: Role,
    /// Shared by the two tasks of `command_connection = "own"`.
    split: Option<Arc<commands::Split>>,
}

/// What one link task does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    /// Reads, writes and read-backs on one connection.
    Both,
    /// The reads of `command_connection = "own"`; reports the link's state for both.
    Reads,
    /// The commands and read-backs of `command_connection = "own"`, on their own connection.
    Commands,
}

/// The link's one trigger bit ([`crate::runtime::trigger::CycleTrigger::arm`]): a read.
const READ_TRIGGER_BIT: u32 = 1;

/// How often the command registers with `readback` are read back, ns: 100 ms, a third of the
/// 300 ms within which another writer must be found (issue 23), so the first or second
/// read-back after a foreign write finds it.
const READBACK_PERIOD_NS: u64 = 100_000_000;

impl Controller {
    fn new(
        cfg: &ModbusLinkConfig,
        map: &SignalMap,
        sensors: Arc<SensorBoard>,
        outputs: Arc<OutputBoard>,
        monitor: Arc<LinkMonitor>,
    ) -> Result<Controller, LinkError> {
        cfg.validate()?;
        check_map(map, cfg.heartbeat_register.as_ref())?;
        let mut sensor_bindings: Vec<((SensorId, usize), RegisterBinding)> = map
            .modbus_sensors()
            .into_iter()
            .map(|(id, b)| ((id, 0), b))
            .collect();
        sensor_bindings.extend(
            map.modbus_spares()
                .into_iter()
                .map(|(id, slot, b)| ((id, slot), b)),
        );
        let all: Vec<RegisterBinding> = sensor_bindings.iter().map(|(_, b)| *b).collect();
        let full = ReadPlan::new(&all)?;
        let mut groups = Vec::with_capacity(full.requests().len());
        for req in full.requests() {
            let members = full.members(req);
            let bindings: Vec<RegisterBinding> = members.iter().map(|&i| all[i]).collect();
            let ids: Vec<(SensorId, usize)> =
                members.iter().map(|&i| sensor_bindings[i].0).collect();
            let plan = ReadPlan::new(&bindings)?;
            debug_assert_eq!(plan.requests().len(), 1);
            groups.push(SensorGroup {
                values: vec![f64::NAN; ids.len()],
                plan,
                ids,
            });
        }
        let actuator_bindings = map.modbus_actuators();
        let actuators: Vec<ActuatorId> = actuator_bindings.iter().map(|(id, _)| *id).collect();
        let mut readbacks = Vec::new();
        for (k, (id, b)) in actuator_bindings.iter().enumerate() {
            if map.feedback.get(id).is_some_and(|l| l.readback) && b.table == RegisterTable::Holding
            {
                readbacks.push((k, ReadPlan::new(&[*b])?, [f64::NAN]));
            }
        }
        let mut writes: Vec<RegisterBinding> = actuator_bindings.iter().map(|(_, b)| *b).collect();
        if let Some(hb) = &cfg.heartbeat_register {
            writes.extend(hb.bindings());
        }
        let watchdog_at = writes.len();
        let watchdog = map.watchdog.modbus;
        if let Some(wd) = &watchdog {
            writes.extend(wd.parts().iter().map(|(_, b)| *b));
        }
        let write_plan = if cfg.merge_writes {
            WritePlan::new(&writes)?
        } else {
            WritePlan::separate(&writes)?
        };
        Ok(Controller {
            client: ModbusClient::new(cfg.client.clone())?,
            groups,
            write_values: vec![f64::NAN; write_plan.len()],
            write_plan,
            acknowledged: vec![0; actuators.len()],
            acknowledged_valid: false,
            actuators,
            heartbeat: cfg.heartbeat_register.is_some(),
            alive: 0,
            watchdog,
            watchdog_writer: Default::default(),
            watchdog_at,
            write_failing: None,
            write_fault_ns: cfg.write_fault_timeout_ms.saturating_mul(1_000_000),
            change_only: cfg.write_on_change_only,
            max_output_age_ns: cfg.max_output_age_ms.saturating_mul(1_000_000),
            last_written_cycle: None,
            resync: None,
            resync_read_ns: 0,
            last_cause: FailureCause::Connect,
            sensors,
            outputs,
            monitor,
            quality: quality::QualityWindow::default(),
            readbacks,
            next_readback_ns: 0,
            period_ns: u64::try_from(cfg.period().as_nanos()).unwrap_or(u64::MAX),
            read_done_ns: 0,
            trigger: None,
            role: Role::Both,
            split: None,
        })
    }

    /// Read back the command registers with `readback` (every [`READBACK_PERIOD_NS`]) and
    /// report a value this controller did not write.
    async fn read_back(&mut self, out: &mut Outcome) {
        if self.readbacks.is_empty() {
            return;
        }
        let now = monotonic_ns();
        if now < self.next_readback_ns {
            return;
        }
        self.next_readback_ns = now + READBACK_PERIOD_NS;
        let mut found = None;
        for i in 0..self.readbacks.len() {
            let (k, plan, value) = &mut self.readbacks[i];
            let k = *k;
            match self.client.read(plan, value).await {
                Ok(()) => {
                    out.answered = true;
                    let bits = self.acknowledged[k];
                    if !self.acknowledged_valid || f64::from_bits(bits).is_nan() {
                        continue;
                    }
                    let written = f64::from_bits(bits);
                    let b = plan.bindings()[0];
                    // one register step of the encoding, and a hair for the decode's rounding
                    let tol = 1.01 * b.resolution(written) + 1e-12 * written.abs().max(1.0);
                    if (value[0] - written).abs() > tol {
                        found = Some(AnotherWriter {
                            actuator: self.actuators[k],
                            unit_id: b.unit_id,
                            address: b.address,
                            read: value[0],
                            written,
                        });
                    }
                }
                Err(e) => {
                    if self.note_error(&e, out) {
                        return;
                    }
                }
            }
        }
        self.monitor.set_another_writer(found);
    }

    /// Nothing to read and nothing to write.
    fn is_idle(&self) -> bool {
        self.groups.is_empty() && self.write_plan.is_empty()
    }

    /// Note a failed operation; returns whether it was a link failure.
    fn note_error(&mut self, e: &ModbusError, out: &mut Outcome) -> bool {
        if let Some(x) = ExceptionInfo::of(e) {
            out.exception.get_or_insert(x);
            return false;
        }
        if let Some(cause) = FailureCause::of(e) {
            self.last_cause = cause;
        }
        if !e.is_link_failure() {
            // Only a length mismatch remains: a planning bug, not a device answer.
            tracing::error!(target: "modbus", error = %e, "link: inconsistent request plan");
        }
        out.link_failed = true;
        true
    }

    /// One read of every sensor group; publishes what was answered.
    async fn read(&mut self, out: &mut Outcome) {
        if self.groups.is_empty() {
            // a write-only link reads nothing to resync on (the command side of
            // `command_connection = "own"` resyncs on the read side's reads instead)
            if self.role != Role::Commands {
                self.resync = None;
            }
            return;
        }
        let c = &self.monitor.counters;
        LinkCounters::add(&c.polls, 1);
        let mut all_ok = true;
        let mut published = 0u64;
        let latest_cycle = self.outputs.latest().map_or(0, |o| o.cycle);
        for k in 0..self.groups.len() {
            let g = &mut self.groups[k];
            let sent_ns = monotonic_ns();
            let result = self.client.read(&g.plan, &mut g.values).await;
            let t_ns = monotonic_ns();
            if counts_for_latency(&result) {
                self.quality.answered(sent_ns, t_ns);
            }
            match result {
                Ok(()) => {
                    for ((id, slot), v) in g.ids.iter().zip(&g.values) {
                        self.sensors.publish_transmitter(*id, *slot, *v, t_ns);
                    }
                    published += g.ids.len() as u64;
                    out.answered = true;
                    if self.resync == Some(None) {
                        self.resync = Some(Some(latest_cycle));
                        self.resync_read_ns = t_ns;
                    }
                }
                Err(e) => {
                    all_ok = false;
                    if self.note_error(&e, out) {
                        break;
                    }
                }
            }
        }
        self.read_done_ns = if published > 0 { monotonic_ns() } else { 0 };
        if let (Some(t), true) = (&self.trigger, published > 0) {
            t.note(READ_TRIGGER_BIT, self.read_done_ns);
        }
        if let (Some(sp), true) = (&self.split, published > 0) {
            sp.read_done_ns.store(self.read_done_ns, Ordering::Release);
        }
        let c = &self.monitor.counters;
        LinkCounters::add(&c.values_published, published);
        if all_ok {
            LinkCounters::add(&c.polls_ok, 1);
            self.quality.poll_answered(monotonic_ns());
        }
    }

    /// Write the latest output set if it is new and fresh.
    async fn write(&mut self, out: &mut Outcome) {
        if self.write_plan.is_empty() {
            return;
        }
        let Some(o) = self.outputs.latest() else {
            return;
        };
        if self.last_written_cycle == Some(o.cycle) {
            return;
        }
        // ... and while the core still holds fail-safe on those first values (it leaves it
        // after its exit hysteresis, then resumes from the measured valve position), at most
        // RESYNC_FAILSAFE_NS: a fail-safe that lasts is written
        match self.resync {
            Some(Some(k))
                if o.cycle >= k.saturating_add(2)
                    && (o.mode != Mode::FailSafe
                        || monotonic_ns().saturating_sub(self.resync_read_ns)
                            >= RESYNC_FAILSAFE_NS) =>
            {
                self.resync = None
            }
            Some(_) => return,
            None => {}
        }
        let c = &self.monitor.counters;
        if monotonic_ns().saturating_sub(o.t_ns) > self.max_output_age_ns {
            LinkCounters::add(&c.writes_stale, 1);
            return;
        }
        let mut unchanged = 0u64;
        for (k, id) in self.actuators.iter().enumerate() {
            let v = o.commands.get(*id);
            self.write_values[k] = if self.change_only
                && self.acknowledged_valid
                && !v.is_nan()
                && v.to_bits() == self.acknowledged[k]
            {
                unchanged += 1;
                f64::NAN
            } else {
                v
            };
        }
        if self.heartbeat {
            let n = self.actuators.len();
            self.alive = self.alive.wrapping_add(1);
            let w = HeartbeatWords {
                mode: o.mode.code(),
                alive: self.alive,
                law: o.law,
                faults: o.faults,
            }
            .encode();
            self.write_values[n] = f64::from(w[0]);
            self.write_values[n + 1] = f64::from(w[1]);
            self.write_values[n + 2] = f64::from(o.faults);
        }
        // whether this set carries a beat the device sees: the legacy heartbeat block, or the
        // watchdog contract's counter when it is not withheld
        let mut beat = self.heartbeat;
        if let Some(wd) = &self.watchdog {
            // Writes failing for longer than write_fault_timeout_ms: the counter stands
            // still, so the device's own watchdog takes it to its safe state.
            let withheld = self
                .write_failing
                .is_some_and(|(t0, _)| monotonic_ns().saturating_sub(t0) >= self.write_fault_ns);
            if withheld {
                LinkCounters::add(&c.watchdog_withheld, 1);
            } else {
                beat = true;
            }
            let at = self.watchdog_at;
            self.watchdog_writer.values(
                wd,
                o.mode.code(),
                o.law,
                o.faults,
                !withheld,
                &mut self.write_values[at..],
            );
        }
        LinkCounters::add(&c.setpoints_unchanged, unchanged);
        if self.write_values.iter().all(|v| v.is_nan()) {
            // Nothing commanded or nothing changed: this set is done.
            self.last_written_cycle = Some(o.cycle);
            return;
        }
        LinkCounters::add(&c.writes, 1);
        let sent_ns = monotonic_ns();
        let result = self
            .client
            .write(&self.write_plan, &self.write_values)
            .await;
        if counts_for_latency(&result) {
            self.quality.answered(sent_ns, monotonic_ns());
        }
        match result {
            Ok(report) => {
                out.write = Some(None);
                let c = &self.monitor.counters;
                LinkCounters::add(&c.writes_ok, 1);
                if beat {
                    LinkCounters::add(&c.heartbeats, 1);
                }
                out.answered |= report.requests > 0;
                self.last_written_cycle = Some(o.cycle);
                if !self.acknowledged_valid {
                    // Start from the device's view: what this write carried. Setpoints
                    // left out as NaN stay unknown, so keep them distinct from any value.
                    self.acknowledged.fill(f64::NAN.to_bits());
                }
                for (k, v) in self.write_values[..self.actuators.len()].iter().enumerate() {
                    if !v.is_nan() {
                        self.acknowledged[k] = v.to_bits();
                    }
                }
                self.acknowledged_valid = true;
            }
            Err(e) => {
                self.acknowledged_valid = false;
                LinkCounters::add(&self.monitor.counters.write_failures, 1);
                let failure = match ExceptionInfo::of(&e) {
                    Some(x) => WriteFailure::Exception(x),
                    None => WriteFailure::Link(FailureCause::of(&e).unwrap_or(self.last_cause)),
                };
                out.write = Some(Some(failure));
                if let WriteFailure::Exception(_) = failure {
                    // The set was delivered and refused: retrying it unchanged would be
                    // refused again. The next output set is tried afresh.
                    self.last_written_cycle = Some(o.cycle);
                }
                self.note_error(&e, out);
            }
        }
    }

    /// Wait until the control thread has published an output set computed from the values
    /// this cycle's read published (its wake time is later), at most one link period after
    /// the read; then the write carries the answer to these values, not to the previous
    /// read's. Without the wait, every command reached the device one link cycle (a read and a
    /// write, 25–40 ms on a gateway answering in 5–20 ms) later than it could.
    async fn await_outputs_on_read(&mut self) {
        if self.read_done_ns == 0 || self.write_plan.is_empty() {
            return;
        }
        let deadline = self.read_done_ns.saturating_add(self.period_ns);
        loop {
            if self
                .outputs
                .latest()
                .is_some_and(|o| o.t_ns >= self.read_done_ns)
            {
                return;
            }
            let now = monotonic_ns();
            if now >= deadline {
                return;
            }
            // (tokio's timer ticks in ms: the wait ends within 1 ms of the control cycle)
            tokio::time::sleep(Duration::from_nanos((deadline - now).min(1_000_000))).await;
        }
    }

    /// One link cycle. `write_first`: outputs before sensors (wakeup pacing). Otherwise the
    /// sensors are read, the write carries the output set computed from them (see
    /// [`Self::await_outputs_on_read`]), and the command registers are read back after the
    /// write: a read-back sees this controller's last write unless another master wrote since.
    async fn cycle(&mut self, write_first: bool) -> Outcome {
        let mut out = Outcome::default();
        if write_first {
            self.write(&mut out).await;
            if !out.link_failed {
                self.read(&mut out).await;
            }
            if !out.link_failed {
                self.read_back(&mut out).await;
            }
        } else {
            self.read(&mut out).await;
            if !out.link_failed {
                self.await_outputs_on_read().await;
                self.write(&mut out).await;
            }
            if !out.link_failed {
                self.read_back(&mut out).await;
            }
        }
        out
    }

    /// Counters and state after a cycle that took `elapsed`.
    fn finish(&mut self, out: &Outcome, elapsed: Duration, period: Duration) {
        let c = &self.monitor.counters;
        if self.role != Role::Commands {
            // the link cycle and its quality are the reads' (the command side writes when
            // there is something to write, at no period of its own)
            LinkCounters::add(&c.cycles, 1);
            if elapsed > period {
                LinkCounters::add(&c.overruns, 1);
            }
            let us = u64::try_from(elapsed.as_micros()).unwrap_or(u64::MAX);
            c.last_cycle_us.store(us, Ordering::Relaxed);
            c.max_cycle_us.fetch_max(us, Ordering::Relaxed);
            let q = self.quality.quality(monotonic_ns());
            c.poll_period_us.store(q.poll_period_us, Ordering::Relaxed);
            c.latency_p50_us.store(q.latency_p50_us, Ordering::Relaxed);
            c.latency_p99_us.store(q.latency_p99_us, Ordering::Relaxed);
        }
        self.mirror_client_counters();
        if out.link_failed {
            self.acknowledged_valid = false;
            self.resync = Some(None);
            if let Some(sp) = &self.split {
                if self.role == Role::Commands {
                    sp.note_command_failure(monotonic_ns());
                }
            }
        }
        let now = monotonic_ns();
        if self.role != Role::Reads {
            match out.write {
                Some(None) => self.write_failing = None,
                Some(Some(f)) => {
                    self.write_failing.get_or_insert((now, f));
                }
                None => {}
            }
            if out.link_failed && out.write.is_none() && self.write_failing.is_none() {
                // The link is down: writes cannot reach the device either.
                self.write_failing = Some((now, WriteFailure::Link(self.last_cause)));
            }
            self.monitor.set_writes(match self.write_failing {
                None => WriteHealth::Ok,
                Some((t0, cause)) => WriteHealth::Failing {
                    cause,
                    safe_state: now.saturating_sub(t0) >= self.write_fault_ns,
                },
            });
        }
        let new = match self.client.state() {
            ConnectionState::Broken {
                consecutive_failures,
                backoff_ms,
            } => LinkState::Down {
                consecutive_failures,
                backoff_ms,
                cause: self.last_cause,
            },
            ConnectionState::Connected => match (out.exception, out.answered) {
                (Some(x), _) => LinkState::Exception(x),
                (None, true) => LinkState::Up,
                (None, false) => return,
            },
            ConnectionState::Idle => return,
        };
        match (self.role, &self.split) {
            (Role::Commands, Some(sp)) => {
                // the read side reports the link: it carries this connection's failure
                sp.set_commands_down(match new {
                    LinkState::Down { .. } => Some(new),
                    _ => None,
                });
            }
            (Role::Reads, Some(sp)) => match (new, sp.commands_down()) {
                (LinkState::Down { .. }, _) | (_, None) => self.monitor.set_state(new),
                (_, Some(down)) => self.monitor.set_state(down),
            },
            _ => self.monitor.set_state(new),
        }
    }

    /// Copy the client's counters into the shared atomics.
    fn mirror_client_counters(&self) {
        let c = &self.monitor.counters;
        let mut k = self.client.counters();
        match (self.role, &self.split) {
            (Role::Commands, Some(sp)) => {
                // the read side mirrors the sum of both connections
                sp.set_command_counters(k);
                return;
            }
            (Role::Reads, Some(sp)) => k = commands::add_counters(k, sp.command_counters()),
            _ => {}
        }
        for (slot, v) in [
            (&c.requests, k.requests),
            (&c.timeouts, k.timeouts),
            (&c.exceptions, k.exceptions),
            (&c.transport_errors, k.transport_errors),
            (&c.protocol_errors, k.protocol_errors),
            (&c.connect_attempts, k.connect_attempts),
            (&c.connect_failures, k.connect_failures),
            (&c.reconnects, k.reconnects),
            (&c.clamped_values, k.clamped_values),
        ] {
            slot.store(v, Ordering::Relaxed);
        }
    }
}

/// Run the controller side of the Modbus link until `shutdown` completes.
///
/// Reads every Modbus sensor of `map` each cycle (requests grouped by unit, table and
/// contiguous range) and publishes the values into `sensors` with the monotonic arrival time
/// of their response; writes the latest new output set of `outputs` (NaN setpoints are
/// skipped: the device keeps its last value) and the heartbeat block if configured. Link
/// failures and exceptions never stop the task: the client reconnects with backoff and the
/// state goes to `monitor`. Returns at once (Ok, state [`LinkState::Stopped`]) if there is
/// nothing to read or write: no Modbus signal in `map` and no heartbeat block.
///
/// Errors: invalid configuration or map, or (wakeup pacing) a failure to register the
/// eventfd with the runtime.
pub async fn run_controller(
    cfg: &ModbusLinkConfig,
    map: &SignalMap,
    sensors: Arc<SensorBoard>,
    outputs: Arc<OutputBoard>,
    pacing: Pacing,
    monitor: Arc<LinkMonitor>,
    shutdown: impl Future<Output = ()>,
) -> Result<(), LinkError> {
    run_controller_triggering(cfg, map, sensors, outputs, pacing, monitor, None, shutdown).await
}

/// [`run_controller`], firing `trigger` after every read that published values (the control
/// cycle runs on them at once: `cycle_trigger = "reads"`).
#[allow(clippy::too_many_arguments)] // the boards and handles of one link task
pub async fn run_controller_triggering(
    cfg: &ModbusLinkConfig,
    map: &SignalMap,
    sensors: Arc<SensorBoard>,
    outputs: Arc<OutputBoard>,
    pacing: Pacing,
    monitor: Arc<LinkMonitor>,
    trigger: Option<Arc<crate::runtime::trigger::CycleTrigger>>,
    shutdown: impl Future<Output = ()>,
) -> Result<(), LinkError> {
    let own = cfg.command_connection == CommandConnection::Own;
    let (sensors_c, outputs_c) = (Arc::clone(&sensors), Arc::clone(&outputs));
    let mut ctl = Controller::new(cfg, map, sensors, outputs, Arc::clone(&monitor))?;
    if let Some(t) = &trigger {
        t.arm(READ_TRIGGER_BIT);
    }
    ctl.trigger = trigger;
    if ctl.is_idle() {
        tracing::debug!(target: "modbus", "link: no Modbus signals in the map, nothing to do");
        monitor.set_state(LinkState::Stopped);
        return Ok(());
    }
    let period = cfg.period();
    tokio::pin!(shutdown);
    let mut commands = None;
    let result = match pacing {
        Pacing::Interval if own && !ctl.groups.is_empty() && !ctl.write_plan.is_empty() => {
            let second = Controller::new(cfg, map, sensors_c, outputs_c, Arc::clone(&monitor))?;
            let mut cmd = commands::split(&mut ctl, second);
            tokio::select! {
                biased;
                () = &mut shutdown => {}
                () = poll_at_interval(&mut ctl, period) => {}
                () = commands::run(&mut cmd, period) => {}
            }
            commands = Some(cmd);
            Ok(())
        }
        Pacing::Interval => {
            tokio::select! {
                biased;
                () = &mut shutdown => {}
                () = poll_at_interval(&mut ctl, period) => {}
            }
            Ok(())
        }
        Pacing::Wakeup(wake) => run_on_wakeup(&mut ctl, &wake, period, &mut shutdown).await,
    };
    if let Some(mut cmd) = commands {
        cmd.client.disconnect().await;
        cmd.mirror_client_counters();
    }
    ctl.client.disconnect().await;
    ctl.mirror_client_counters();
    monitor.set_state(LinkState::Stopped);
    result
}

/// The link's cycles at `period` (never returns; the caller selects it against shutdown).
async fn poll_at_interval(ctl: &mut Controller, period: Duration) {
    let mut ticker = tokio::time::interval(period);
    ticker.set_missed_tick_behavior(MissedTickBehavior::Delay);
    loop {
        ticker.tick().await;
        let start = Instant::now();
        let out = ctl.cycle(false).await;
        ctl.finish(&out, start.elapsed(), period);
    }
}

async fn run_on_wakeup<S: Future<Output = ()> + Unpin>(
    ctl: &mut Controller,
    wake: &Wakeup,
    period: Duration,
    shutdown: &mut S,
) -> Result<(), LinkError> {
    // SAFETY: the descriptor is owned by `wake`, which this function borrows for longer than
    // `fd` lives, and a `Wakeup` never replaces or closes its eventfd while it exists.
    let fd =
        unsafe { AsyncFd::register_with_interest(wake.fd(), Interest::READABLE) }.map_err(|e| {
            LinkError::Io {
                context: "registering the wakeup eventfd",
                source: e.into(),
            }
        })?;
    let mut next_allowed = Instant::now();
    loop {
        tokio::select! {
            biased;
            () = &mut *shutdown => return Ok(()),
            ready = fd.readable() => {
                let mut guard = ready.map_err(|source| LinkError::Io {
                    context: "waiting on the wakeup eventfd",
                    source,
                })?;
                // Drain first, then clear readiness: a signal in between re-arms the fd.
                wake.clear();
                guard.clear_ready();
            }
        }
        if Instant::now() < next_allowed {
            tokio::select! {
                biased;
                () = &mut *shutdown => return Ok(()),
                () = tokio::time::sleep_until(next_allowed) => {}
            }
        }
        let start = Instant::now();
        next_allowed = start + period;
        let out = tokio::select! {
            biased;
            () = &mut *shutdown => return Ok(()),
            out = ctl.cycle(true) => out,
        };
        ctl.finish(&out, start.elapsed(), period);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::signal_map::Binding;

    #[test]
    fn link_config_from_toml_with_defaults() {
        let c: ModbusLinkConfig = toml::from_str(
            r#"
            heartbeat_register = { unit_id = 1, address = 300 }
            [client]
            timeout_ms = 40
            transport = { kind = "tcp", address = "10.0.0.5:502" }
            "#,
        )
        .unwrap();
        assert_eq!(c.poll_rate_hz, 50.0);
        assert!(!c.write_on_change_only);
        assert_eq!(c.max_output_age_ms, 500);
        assert_eq!(c.client.timeout_ms, 40);
        assert_eq!(c.client.backoff_max_ms, 5000);
        assert_eq!(
            c.heartbeat_register,
            Some(HeartbeatRegister {
                unit_id: 1,
                address: 300
            })
        );
        assert_eq!(c.period(), Duration::from_millis(20));
        assert!(c.validate().is_ok());

        let rtu: ModbusLinkConfig = toml::from_str(
            "poll_rate_hz = 10\nwrite_on_change_only = true\n\
             [client]\ntransport = { kind = \"rtu\", path = \"/dev/ttyUSB0\", baud = 19200 }\n",
        )
        .unwrap();
        assert!(rtu.write_on_change_only && rtu.validate().is_ok());

        for bad in [
            "pol_rate_hz = 5\n[client]\ntransport = { kind = \"tcp\", address = \"1.2.3.4:502\" }",
            "heartbeat_register = { unit_id = 1, address = 3, table = \"input\" }\n\
             [client]\ntransport = { kind = \"tcp\", address = \"1.2.3.4:502\" }",
        ] {
            assert!(toml::from_str::<ModbusLinkConfig>(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn link_config_validation() {
        let mut c = ModbusLinkConfig::new(ClientConfig::tcp("127.0.0.1:502".parse().unwrap()));
        assert!(c.validate().is_ok());
        for rate in [0.0, -1.0, f64::NAN, 1000.5] {
            c.poll_rate_hz = rate;
            assert!(
                matches!(c.validate(), Err(LinkError::Invalid { .. })),
                "{rate}"
            );
        }
        c.poll_rate_hz = 1000.0;
        assert!(c.validate().is_ok());
        c.max_output_age_ms = 0;
        assert!(c.validate().is_err());
        c.max_output_age_ms = 1;
        c.heartbeat_register = Some(HeartbeatRegister {
            unit_id: 1,
            address: 65533,
        });
        assert!(c.validate().is_err());
        c.heartbeat_register = Some(HeartbeatRegister {
            unit_id: 1,
            address: 65532,
        });
        assert!(c.validate().is_ok());
        c.command_connection = CommandConnection::Own;
        assert!(c.validate().is_ok());
        c.client.timeout_ms = 0;
        assert!(matches!(c.validate(), Err(LinkError::Client(_))));
        // a second connection needs TCP: an RTU line carries one request at a time
        let mut rtu = c.clone();
        rtu.client.timeout_ms = 100;
        rtu.client.transport = super::super::client::TransportConfig::Rtu(
            super::super::client::RtuConfig::new("/dev/ttyUSB0", 19200),
        );
        assert!(matches!(
            rtu.validate(),
            Err(LinkError::Invalid {
                key: "command_connection",
                ..
            })
        ));
        rtu.command_connection = CommandConnection::Shared;
        assert!(rtu.validate().is_ok());
    }

    #[test]
    fn server_config_defaults() {
        let s: ModbusServerConfig = toml::from_str("").unwrap();
        assert_eq!(s, ModbusServerConfig::default());
        assert_eq!(s.listen.port(), 5020);
        assert!(toml::from_str::<ModbusServerConfig>("listn = \"0.0.0.0:502\"").is_err());
    }

    #[test]
    fn heartbeat_words_round_trip_through_bindings() {
        let hb = HeartbeatRegister {
            unit_id: 3,
            address: 10,
        };
        let w = HeartbeatWords {
            mode: 3,
            alive: 255,
            law: 7,
            faults: 0xdead_beef,
        };
        let words = w.encode();
        assert_eq!(words, [0x03ff, 7, 0xdead, 0xbeef]);
        assert_eq!(HeartbeatWords::decode(&words), w);
        // The controller writes the block through the bindings: same words on the wire.
        let b = hb.bindings();
        let mut wire = [0u16; 4];
        let _ = b[0].encode(f64::from(words[0]), &mut wire[0..1]).unwrap();
        let _ = b[1].encode(f64::from(words[1]), &mut wire[1..2]).unwrap();
        let _ = b[2].encode(f64::from(w.faults), &mut wire[2..4]).unwrap();
        assert_eq!(wire, words);
        assert!(hb.touched_by(3, 13, 1));
        assert!(hb.touched_by(3, 0, 11));
        assert!(!hb.touched_by(3, 14, 2));
        assert!(!hb.touched_by(3, 0, 10));
        assert!(!hb.touched_by(2, 10, 4));
    }

    #[test]
    fn heartbeat_block_must_not_overlap_signals() {
        let mut map = SignalMap::default();
        map.actuators.insert(
            ActuatorId::RecycleValve,
            Binding::Modbus(RegisterBinding::new(
                1,
                RegisterTable::Holding,
                102,
                DataType::F32,
            )),
        );
        let at = |address| HeartbeatRegister {
            unit_id: 1,
            address,
        };
        assert!(check_map(&map, Some(&at(104))).is_ok());
        assert!(check_map(&map, Some(&at(99))).is_err());
        let e = check_map(&map, Some(&at(103))).unwrap_err();
        assert!(e.to_string().contains("holding register 102"), "{e}");
        // Same address on another unit is fine.
        assert!(check_map(
            &map,
            Some(&HeartbeatRegister {
                unit_id: 2,
                address: 102
            })
        )
        .is_ok());
    }
}
