//! Async Modbus client (TCP or RTU) with timeouts, reconnect-with-backoff and counters.
//!
//! tokio-modbus has no timeouts of its own, and a context that saw a timeout can later
//! receive the late answer to the abandoned request and pair it with the next one (upstream
//! issue 324). This client therefore wraps every connect and request in
//! [`tokio::time::timeout`], and after any timeout, I/O error or malformed/mismatched
//! response it **drops the context** (closing the socket or serial port) and reconnects on a
//! later call, no earlier than an exponentially growing backoff. A late answer can then only
//! arrive on a socket that no longer exists. Exception responses are the device's answer to
//! a well-formed exchange and leave the connection up.
//!
//! Reads and writes are cancellation-safe in the same sense: if the caller drops one
//! mid-exchange, the next call replaces the connection instead of reusing it.
//!
//! The client never blocks a caller through a backoff: while the link is down and the
//! backoff has not elapsed, calls fail at once with [`ModbusError::Backoff`], so a control
//! loop can go fail-safe and keep its cycle time.

use std::borrow::Cow;
use std::io;
use std::net::SocketAddr;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use thiserror::Error;
use tokio::net::TcpStream;
use tokio::time::{timeout, Instant};
use tokio_modbus::client::{Client as _, Context};
use tokio_modbus::prelude::SlaveContext as _;
use tokio_modbus::{ExceptionCode, FunctionCode, Request, Response, Slave};
use tokio_serial::SerialPort as _;

use super::plan::{PlannedRequest, ReadPlan, WritePlan};
use super::register::{EncodeError, EncodeOutcome, RegisterTable};
use crate::vocab::signals::{SensorId, SensorSnapshot};

/// Serial parity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Parity {
    /// No parity bit (usually paired with 2 stop bits per the Modbus spec).
    None,
    /// Even parity: the Modbus RTU default.
    #[default]
    Even,
    /// Odd parity.
    Odd,
}

fn default_stop_bits() -> u8 {
    1
}
fn default_data_bits() -> u8 {
    8
}
fn default_true() -> bool {
    true
}

/// Serial line settings for Modbus RTU.
///
/// Config keys: `path` (e.g. `/dev/ttyUSB0`), `baud` (bit/s), `parity`
/// (`none` | `even` | `odd`, default `even`), `stop_bits` (1 | 2, default 1),
/// `data_bits` (5..=8, default 8), `exclusive` (lock the port against other openers,
/// default true).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RtuConfig {
    /// Serial device path.
    pub path: String,
    /// Baud rate, bit/s.
    pub baud: u32,
    /// Parity.
    #[serde(default)]
    pub parity: Parity,
    /// Stop bits, 1 or 2.
    #[serde(default = "default_stop_bits")]
    pub stop_bits: u8,
    /// Data bits, 5 to 8 (Modbus RTU uses 8).
    #[serde(default = "default_data_bits")]
    pub data_bits: u8,
    /// Open the port exclusively (TIOCEXCL + flock) so a second process cannot interleave
    /// frames. Turn off only to share the line deliberately (e.g. with a bus sniffer).
    #[serde(default = "default_true")]
    pub exclusive: bool,
}

impl RtuConfig {
    /// 8 data bits, even parity, 1 stop bit (the Modbus RTU default framing).
    pub fn new(path: impl Into<String>, baud: u32) -> RtuConfig {
        RtuConfig {
            path: path.into(),
            baud,
            parity: Parity::Even,
            stop_bits: 1,
            data_bits: 8,
            exclusive: true,
        }
    }

    /// Check baud, stop and data bits.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.baud == 0 {
            return Err(ConfigError::invalid(
                "transport.baud",
                "baud must be > 0".into(),
            ));
        }
        if !matches!(self.stop_bits, 1 | 2) {
            return Err(ConfigError::invalid(
                "transport.stop_bits",
                format!("stop_bits must be 1 or 2, got {}", self.stop_bits),
            ));
        }
        if !(5..=8).contains(&self.data_bits) {
            return Err(ConfigError::invalid(
                "transport.data_bits",
                format!("data_bits must be 5..=8, got {}", self.data_bits),
            ));
        }
        Ok(())
    }

    /// The tokio-serial builder for these settings.
    pub fn builder(&self) -> tokio_serial::SerialPortBuilder {
        let parity = match self.parity {
            Parity::None => tokio_serial::Parity::None,
            Parity::Even => tokio_serial::Parity::Even,
            Parity::Odd => tokio_serial::Parity::Odd,
        };
        let stop_bits = if self.stop_bits == 2 {
            tokio_serial::StopBits::Two
        } else {
            tokio_serial::StopBits::One
        };
        let data_bits = match self.data_bits {
            5 => tokio_serial::DataBits::Five,
            6 => tokio_serial::DataBits::Six,
            7 => tokio_serial::DataBits::Seven,
            _ => tokio_serial::DataBits::Eight,
        };
        tokio_serial::new(self.path.as_str(), self.baud)
            .parity(parity)
            .stop_bits(stop_bits)
            .data_bits(data_bits)
            .flow_control(tokio_serial::FlowControl::None)
            .exclusive(self.exclusive)
    }
}

/// How to reach the device.
///
/// TOML: `{ kind = "tcp", address = "192.168.0.10:502" }` or
/// `{ kind = "rtu", path = "/dev/ttyUSB0", baud = 19200, parity = "even" }`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum TransportConfig {
    /// Modbus TCP to `address` (IP:port; 502 is the standard port).
    Tcp {
        /// Socket address of the server.
        address: SocketAddr,
    },
    /// Modbus RTU over a serial line.
    Rtu(RtuConfig),
}

fn default_timeout_ms() -> u64 {
    100
}
fn default_backoff_initial_ms() -> u64 {
    100
}
fn default_backoff_max_ms() -> u64 {
    5000
}

/// Client configuration.
///
/// Config keys: `transport` (see [`TransportConfig`]), `timeout_ms` (per connect and per
/// request, default 100), `backoff_initial_ms` (wait after the first failure, default 100),
/// `backoff_max_ms` (cap of the doubling wait, default 5000).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClientConfig {
    /// TCP or RTU.
    pub transport: TransportConfig,
    /// Deadline for one connect or one request/response exchange, ms.
    #[serde(default = "default_timeout_ms")]
    pub timeout_ms: u64,
    /// Wait before the first reconnect attempt after a link failure, ms.
    #[serde(default = "default_backoff_initial_ms")]
    pub backoff_initial_ms: u64,
    /// Upper bound of the wait, which doubles after each consecutive failure, ms.
    #[serde(default = "default_backoff_max_ms")]
    pub backoff_max_ms: u64,
}

impl ClientConfig {
    /// TCP client with default timeout and backoff.
    pub fn tcp(address: SocketAddr) -> ClientConfig {
        ClientConfig {
            transport: TransportConfig::Tcp { address },
            timeout_ms: default_timeout_ms(),
            backoff_initial_ms: default_backoff_initial_ms(),
            backoff_max_ms: default_backoff_max_ms(),
        }
    }

    /// RTU client with default timeout and backoff.
    pub fn rtu(rtu: RtuConfig) -> ClientConfig {
        ClientConfig {
            transport: TransportConfig::Rtu(rtu),
            ..ClientConfig::tcp(SocketAddr::from(([127, 0, 0, 1], 502)))
        }
    }

    /// Check ranges: timeout > 0, max backoff ≥ initial backoff, serial settings.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.timeout_ms == 0 {
            return Err(ConfigError::invalid(
                "timeout_ms",
                "timeout_ms must be > 0".into(),
            ));
        }
        if self.backoff_max_ms < self.backoff_initial_ms {
            return Err(ConfigError::invalid(
                "backoff_max_ms",
                format!(
                    "backoff_max_ms ({}) < backoff_initial_ms ({})",
                    self.backoff_max_ms, self.backoff_initial_ms
                ),
            ));
        }
        if let TransportConfig::Rtu(rtu) = &self.transport {
            rtu.validate()?;
        }
        Ok(())
    }
}

/// A configuration that cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum ConfigError {
    /// A value is out of range.
    #[error("invalid Modbus client config: {message}")]
    Invalid {
        /// The key, relative to the client settings (`timeout_ms`, `transport.baud`).
        key: &'static str,
        /// What is wrong with it.
        message: String,
    },
}

impl ConfigError {
    fn invalid(key: &'static str, message: String) -> ConfigError {
        ConfigError::Invalid { key, message }
    }

    /// The key the error is about, relative to the client settings.
    pub fn key(&self) -> &'static str {
        match self {
            ConfigError::Invalid { key, .. } => key,
        }
    }
}

/// What went wrong with a Modbus operation.
///
/// [`is_link_failure`](Self::is_link_failure) errors mean the connection was dropped (or is
/// still down); [`ModbusError::Exception`] means the device answered and the link is fine.
#[derive(Debug, Error)]
pub enum ModbusError {
    /// No response within `timeout_ms`. The connection was dropped.
    #[error("unit {unit_id}: no response within {timeout_ms} ms")]
    Timeout {
        /// Unit addressed.
        unit_id: u8,
        /// The configured deadline, ms.
        timeout_ms: u64,
    },
    /// Connecting (TCP connect / serial open) did not finish within `timeout_ms`.
    #[error("connect did not complete within {timeout_ms} ms")]
    ConnectTimeout {
        /// The configured deadline, ms.
        timeout_ms: u64,
    },
    /// Connecting failed (refused, unreachable, no such serial device, ...).
    #[error("connect failed: {0}")]
    Connect(#[source] io::Error),
    /// I/O error during a request (reset, broken pipe, EOF). The connection was dropped.
    #[error("transport error: {0}")]
    Transport(#[source] io::Error),
    /// The response did not match the request (transaction id, unit id, function code,
    /// register count) or could not be decoded. The connection was dropped.
    #[error("protocol error: {0}")]
    Protocol(String),
    /// The device answered with a Modbus exception. The connection stays up.
    #[error("unit {unit_id}: exception {code} for function {function:#04x} at address {address}")]
    Exception {
        /// Unit that answered.
        unit_id: u8,
        /// Function code of the request (0x03, 0x04, 0x10, ...).
        function: u8,
        /// First address of the request.
        address: u16,
        /// Exception code (illegal data address, device busy, ...).
        code: ExceptionCode,
    },
    /// The link is down and the reconnect backoff has not elapsed; no I/O was attempted.
    #[error("link down, next reconnect attempt in {retry_in_ms} ms")]
    Backoff {
        /// Time until the next connect attempt is allowed, ms.
        retry_in_ms: u64,
    },
    /// The value slice does not match the plan's binding count (a caller bug).
    #[error("expected {expected} values, got {got}")]
    LengthMismatch {
        /// Bindings in the plan.
        expected: usize,
        /// Slice length given.
        got: usize,
    },
}

impl ModbusError {
    /// Whether the link is (now) down: timeouts, connect/transport/protocol errors, backoff.
    pub fn is_link_failure(&self) -> bool {
        matches!(
            self,
            ModbusError::Timeout { .. }
                | ModbusError::ConnectTimeout { .. }
                | ModbusError::Connect(_)
                | ModbusError::Transport(_)
                | ModbusError::Protocol(_)
                | ModbusError::Backoff { .. }
        )
    }

    /// Whether this is a Modbus exception response.
    pub fn is_exception(&self) -> bool {
        matches!(self, ModbusError::Exception { .. })
    }
}

/// Link state, for status displays and fail-safe logic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ConnectionState {
    /// No connection attempted yet.
    Idle,
    /// A transport is open. (The backoff resets only once an exchange on it succeeds, so a
    /// server that accepts and then drops connections still backs off.)
    Connected,
    /// The link failed; the next connect attempt waits `backoff_ms` from the failure.
    Broken {
        /// Failures (connect or request) since the last successful exchange.
        consecutive_failures: u32,
        /// Current backoff, ms (doubles per consecutive failure up to `backoff_max_ms`).
        backoff_ms: u64,
    },
}

/// Monotonic counters since the client was created.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ClientCounters {
    /// Requests sent.
    pub requests: u64,
    /// Requests that got no answer within `timeout_ms`.
    pub timeouts: u64,
    /// Exception responses.
    pub exceptions: u64,
    /// I/O errors during requests.
    pub transport_errors: u64,
    /// Mismatched or malformed responses.
    pub protocol_errors: u64,
    /// Connect attempts (TCP connect / serial open).
    pub connect_attempts: u64,
    /// Failed or timed-out connect attempts.
    pub connect_failures: u64,
    /// Successful connects after the first one.
    pub reconnects: u64,
    /// Values saturated by integer/float range limits when writing.
    pub clamped_values: u64,
    /// Exchanges abandoned because the caller dropped a read/write future mid-request (the
    /// connection is then replaced on the next call).
    pub cancelled: u64,
}

/// What a write did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WriteReport {
    /// Write requests sent.
    pub requests: u32,
    /// Bindings written.
    pub written: u32,
    /// Bindings skipped because their value was NaN ("not commanded").
    pub skipped_nan: u32,
    /// Bindings whose value was saturated to the raw type's range.
    pub clamped: u32,
}

/// An async Modbus client for cyclic reads and writes of register bindings.
///
/// Not `Clone`; one client owns one connection. All methods take `&mut self`.
pub struct ModbusClient {
    config: ClientConfig,
    timeout: Duration,
    ctx: Option<Context>,
    /// Link failures since the last well-formed exchange.
    failures: u32,
    /// The wait before a reconnect (the field links' one retry strategy).
    backoff: crate::io::link::Backoff,
    next_attempt: Option<Instant>,
    ever_connected: bool,
    /// Set while an exchange is awaited; still set at the next call if the caller dropped
    /// (cancelled) the previous read/write mid-exchange.
    in_flight: bool,
    counters: ClientCounters,
    /// Encoded words of a write (flat, one region per planned request).
    write_words: Vec<u16>,
    /// Per write binding: encoded (true) or NaN (false).
    write_present: Vec<bool>,
    /// Coil states of one write-multiple-coils run.
    write_bits: Vec<bool>,
    /// Values of a sensor read before they go into the snapshot.
    read_values: Vec<f64>,
}

impl std::fmt::Debug for ModbusClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ModbusClient")
            .field("config", &self.config)
            .field("state", &self.state())
            .field("counters", &self.counters)
            .finish_non_exhaustive()
    }
}

impl ModbusClient {
    /// A client for `config`. No I/O happens until the first call.
    pub fn new(config: ClientConfig) -> Result<ModbusClient, ConfigError> {
        config.validate()?;
        let backoff = crate::io::link::Backoff::new(
            Duration::from_millis(config.backoff_initial_ms),
            Duration::from_millis(config.backoff_max_ms),
        );
        Ok(ModbusClient {
            timeout: Duration::from_millis(config.timeout_ms),
            config,
            ctx: None,
            failures: 0,
            backoff,
            next_attempt: None,
            ever_connected: false,
            in_flight: false,
            counters: ClientCounters::default(),
            write_words: Vec::new(),
            write_present: Vec::new(),
            write_bits: Vec::new(),
            read_values: Vec::new(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &ClientConfig {
        &self.config
    }

    /// Current link state.
    pub fn state(&self) -> ConnectionState {
        if self.ctx.is_some() {
            ConnectionState::Connected
        } else if self.failures > 0 {
            ConnectionState::Broken {
                consecutive_failures: self.failures,
                backoff_ms: self.backoff.last().as_millis() as u64,
            }
        } else {
            ConnectionState::Idle
        }
    }

    /// Counters since creation.
    pub fn counters(&self) -> ClientCounters {
        self.counters
    }

    /// Time until a reconnect attempt is allowed (zero if connected or allowed now).
    pub fn retry_in(&self) -> Duration {
        match (self.ctx.is_some(), self.next_attempt) {
            (false, Some(at)) => at.saturating_duration_since(Instant::now()),
            _ => Duration::ZERO,
        }
    }

    /// Connect unless connected. Fails fast with [`ModbusError::Backoff`] while a backoff is
    /// running. Reads and writes call this themselves.
    pub async fn ensure_connected(&mut self) -> Result<(), ModbusError> {
        if self.in_flight {
            // The caller dropped a read/write mid-exchange; its answer may still arrive on
            // this connection, so it must not be reused. Not a link failure: no backoff.
            self.in_flight = false;
            self.ctx = None;
            self.counters.cancelled += 1;
            tracing::debug!(target: "modbus", "previous exchange was cancelled, reconnecting");
        }
        if self.ctx.is_some() {
            return Ok(());
        }
        if let Some(at) = self.next_attempt {
            let now = Instant::now();
            if now < at {
                return Err(ModbusError::Backoff {
                    retry_in_ms: ms_ceil(at - now),
                });
            }
        }
        self.counters.connect_attempts += 1;
        let result = match timeout(self.timeout, open(&self.config.transport)).await {
            Err(_) => Err(ModbusError::ConnectTimeout {
                timeout_ms: self.config.timeout_ms,
            }),
            Ok(Err(e)) => Err(ModbusError::Connect(e)),
            Ok(Ok(ctx)) => Ok(ctx),
        };
        match result {
            Ok(ctx) => {
                self.ctx = Some(ctx);
                self.next_attempt = None;
                if self.ever_connected {
                    self.counters.reconnects += 1;
                    tracing::info!(target: "modbus", "reconnected");
                }
                self.ever_connected = true;
                // The failure count (and so the backoff) only resets after a well-formed
                // exchange, so a server that accepts and then drops connections cannot make
                // us reconnect in a tight loop.
                Ok(())
            }
            Err(e) => {
                self.counters.connect_failures += 1;
                tracing::debug!(target: "modbus", error = %e, "connect failed");
                self.mark_broken();
                Err(e)
            }
        }
    }

    /// Close the connection (e.g. on shutdown). The next call reconnects without backoff.
    pub async fn disconnect(&mut self) {
        if let Some(mut ctx) = self.ctx.take() {
            let _ = timeout(self.timeout, ctx.disconnect()).await;
        }
        self.next_attempt = None;
        self.failures = 0;
        self.backoff.reset();
    }

    /// Read every binding of `plan` into `out` (same order as [`ReadPlan::bindings`]), SI units.
    ///
    /// On error, values whose request did not succeed are NaN; the others are fresh. An
    /// exception in one request does not stop the remaining requests (the first exception is
    /// returned); a link failure stops the cycle.
    pub async fn read(&mut self, plan: &ReadPlan, out: &mut [f64]) -> Result<(), ModbusError> {
        if out.len() != plan.len() {
            return Err(ModbusError::LengthMismatch {
                expected: plan.len(),
                got: out.len(),
            });
        }
        out.fill(f64::NAN);
        if plan.is_empty() {
            return Ok(());
        }
        self.ensure_connected().await?;
        let mut first_exception = None;
        for req in plan.requests() {
            let request = match req.table {
                RegisterTable::Holding => Request::ReadHoldingRegisters(req.address, req.count),
                RegisterTable::Input => Request::ReadInputRegisters(req.address, req.count),
                RegisterTable::Coil => Request::ReadCoils(req.address, req.count),
                RegisterTable::DiscreteInput => Request::ReadDiscreteInputs(req.address, req.count),
            };
            match self.call(req, request).await {
                Ok(Response::ReadHoldingRegisters(words) | Response::ReadInputRegisters(words))
                    if words.len() == req.count as usize =>
                {
                    for &i in plan.members(req) {
                        let b = &plan.bindings()[i];
                        let start = (b.address - req.address) as usize;
                        // The plan guarantees the binding lies inside the request.
                        out[i] = b.decode(&words[start..]).unwrap_or(f64::NAN);
                    }
                }
                // tokio-modbus pads bit answers to whole bytes: at least `count` bits
                Ok(Response::ReadCoils(bits) | Response::ReadDiscreteInputs(bits))
                    if bits.len() >= req.count as usize =>
                {
                    for &i in plan.members(req) {
                        let b = &plan.bindings()[i];
                        let bit = bits[(b.address - req.address) as usize];
                        out[i] = b.decode(&[u16::from(bit)]).unwrap_or(f64::NAN);
                    }
                }
                Ok(other) => {
                    let msg = format!(
                        "read of {} registers at {} answered with {other:?}",
                        req.count, req.address
                    );
                    return Err(self.classify(CallError::Protocol(msg), req.unit_id, req.address));
                }
                Err(e @ ModbusError::Exception { .. }) => {
                    first_exception.get_or_insert(e);
                }
                Err(e) => return Err(e),
            }
        }
        match first_exception {
            None => Ok(()),
            Some(e) => Err(e),
        }
    }

    /// Read a plan whose bindings belong to `ids` (same length, same order) into `snapshot`.
    /// Sensors not in `ids` are left untouched; sensors of failed requests become NaN.
    pub async fn read_sensors(
        &mut self,
        plan: &ReadPlan,
        ids: &[SensorId],
        snapshot: &mut SensorSnapshot,
    ) -> Result<(), ModbusError> {
        if ids.len() != plan.len() {
            return Err(ModbusError::LengthMismatch {
                expected: plan.len(),
                got: ids.len(),
            });
        }
        let mut values = std::mem::take(&mut self.read_values);
        values.clear();
        values.resize(plan.len(), f64::NAN);
        let result = self.read(plan, &mut values).await;
        for (id, v) in ids.iter().zip(&values) {
            snapshot.set(*id, *v);
        }
        self.read_values = values;
        result
    }

    /// Write `values` (SI units, same order as [`WritePlan::bindings`]).
    ///
    /// NaN values are skipped ("not commanded"): the device keeps its last setpoint. The
    /// remaining bindings of each planned request are sent as write-multiple (0x10, coils
    /// 0x0F) requests over their contiguous runs (a run of one: 0x06, coil 0x05). Every value is encoded before any I/O. An exception in one
    /// request does not stop the others (the first exception is returned); a link failure
    /// stops the cycle.
    pub async fn write(
        &mut self,
        plan: &WritePlan,
        values: &[f64],
    ) -> Result<WriteReport, ModbusError> {
        if values.len() != plan.len() {
            return Err(ModbusError::LengthMismatch {
                expected: plan.len(),
                got: values.len(),
            });
        }
        let mut report = WriteReport::default();
        self.write_words.clear();
        self.write_words.resize(plan.total_words(), 0);
        self.write_present.clear();
        self.write_present.resize(plan.len(), false);
        for req in plan.requests() {
            let base = WritePlan::word_offset(req);
            for &i in plan.members(req) {
                let b = &plan.bindings()[i];
                let start = base + (b.address - req.address) as usize;
                match b.encode(values[i], &mut self.write_words[start..]) {
                    Ok(EncodeOutcome::InRange) => self.write_present[i] = true,
                    Ok(EncodeOutcome::Clamped) => {
                        self.write_present[i] = true;
                        report.clamped += 1;
                    }
                    Err(EncodeError::NotANumber) => report.skipped_nan += 1,
                    // Cannot happen: the buffer spans every planned request.
                    Err(EncodeError::BufferTooShort { .. }) => report.skipped_nan += 1,
                }
            }
        }
        self.counters.clamped_values += u64::from(report.clamped);
        if report.skipped_nan as usize == plan.len() {
            return Ok(report);
        }
        self.ensure_connected().await?;
        let mut first_exception = None;
        for req in plan.requests() {
            let members = plan.members(req);
            let base = WritePlan::word_offset(req);
            let mut k = 0;
            while k < members.len() {
                if !self.write_present[members[k]] {
                    k += 1;
                    continue;
                }
                // A run of present members; they are address-contiguous within a request.
                let first = &plan.bindings()[members[k]];
                let run_start = first.address;
                let mut run_end = first.end_address();
                let mut n = 1;
                while k + n < members.len() && self.write_present[members[k + n]] {
                    run_end = plan.bindings()[members[k + n]].end_address();
                    n += 1;
                }
                let lo = base + (run_start - req.address) as usize;
                let hi = lo + (run_end - u32::from(run_start)) as usize;
                let count = (hi - lo) as u16;
                let coils = req.table == RegisterTable::Coil;
                if coils {
                    self.write_bits.clear();
                    self.write_bits
                        .extend(self.write_words[lo..hi].iter().map(|&w| w != 0));
                }
                // One register (coil): write single register (0x06) / coil (0x05), which
                // every device has; a run: write multiple registers (0x10) / coils (0x0F).
                let request = match (coils, count) {
                    (false, 1) => Request::WriteSingleRegister(run_start, self.write_words[lo]),
                    (false, _) => Request::WriteMultipleRegisters(
                        run_start,
                        Cow::Borrowed(&self.write_words[lo..hi]),
                    ),
                    (true, 1) => Request::WriteSingleCoil(run_start, self.write_bits[0]),
                    (true, _) => {
                        Request::WriteMultipleCoils(run_start, Cow::Borrowed(&self.write_bits))
                    }
                };
                report.requests += 1;
                match call(
                    &mut self.ctx,
                    &mut self.counters,
                    &mut self.in_flight,
                    self.timeout,
                    req.unit_id,
                    request,
                )
                .await
                {
                    Ok(Response::WriteMultipleRegisters(addr, qty))
                        if !coils && addr == run_start && qty == count =>
                    {
                        report.written += n as u32;
                        self.mark_good();
                    }
                    Ok(
                        Response::WriteSingleRegister(addr, _) | Response::WriteSingleCoil(addr, _),
                    ) if addr == run_start && count == 1 => {
                        report.written += n as u32;
                        self.mark_good();
                    }
                    Ok(Response::WriteMultipleCoils(addr, qty))
                        if coils && addr == run_start && qty == count =>
                    {
                        report.written += n as u32;
                        self.mark_good();
                    }
                    Ok(other) => {
                        let msg = format!(
                            "write of {count} registers at {run_start} answered with {other:?}"
                        );
                        return Err(self.classify(
                            CallError::Protocol(msg),
                            req.unit_id,
                            run_start,
                        ));
                    }
                    Err(e) => {
                        let e = self.classify(e, req.unit_id, run_start);
                        if e.is_exception() {
                            first_exception.get_or_insert(e);
                        } else {
                            return Err(e);
                        }
                    }
                }
                k += n;
            }
        }
        match first_exception {
            None => Ok(report),
            Some(e) => Err(e),
        }
    }

    /// Send one planned request and classify the outcome.
    async fn call(
        &mut self,
        req: &PlannedRequest,
        request: Request<'_>,
    ) -> Result<Response, ModbusError> {
        match call(
            &mut self.ctx,
            &mut self.counters,
            &mut self.in_flight,
            self.timeout,
            req.unit_id,
            request,
        )
        .await
        {
            Ok(r) => {
                self.mark_good();
                Ok(r)
            }
            Err(e) => Err(self.classify(e, req.unit_id, req.address)),
        }
    }

    /// Turn a raw call failure into a [`ModbusError`], dropping the link unless it is an
    /// exception.
    fn classify(&mut self, e: CallError, unit_id: u8, address: u16) -> ModbusError {
        let err = match e {
            CallError::Exception(function, code) => {
                self.counters.exceptions += 1;
                self.mark_good();
                return ModbusError::Exception {
                    unit_id,
                    function,
                    address,
                    code,
                };
            }
            CallError::NotConnected => {
                ModbusError::Transport(io::Error::new(io::ErrorKind::NotConnected, "not connected"))
            }
            CallError::Timeout => {
                self.counters.timeouts += 1;
                ModbusError::Timeout {
                    unit_id,
                    timeout_ms: self.config.timeout_ms,
                }
            }
            CallError::Io(e) => {
                self.counters.transport_errors += 1;
                ModbusError::Transport(e)
            }
            CallError::Protocol(msg) => {
                self.counters.protocol_errors += 1;
                ModbusError::Protocol(msg)
            }
        };
        tracing::warn!(target: "modbus", error = %err, "link failure, dropping connection");
        self.mark_broken();
        err
    }

    /// A well-formed exchange happened: reset the backoff.
    fn mark_good(&mut self) {
        self.failures = 0;
        self.backoff.reset();
    }

    /// Drop the connection and schedule the next attempt.
    fn mark_broken(&mut self) {
        self.ctx = None;
        let wait = self.backoff.next_delay();
        self.failures = self.failures.saturating_add(1);
        self.next_attempt = Some(Instant::now() + wait);
    }
}

/// Raw outcome of one exchange before classification.
enum CallError {
    NotConnected,
    Timeout,
    Io(io::Error),
    Protocol(String),
    Exception(u8, ExceptionCode),
}

/// One request/response exchange under a deadline. Free function so that the request may
/// borrow the client's word buffer while the context and counters are borrowed mutably.
async fn call(
    ctx: &mut Option<Context>,
    counters: &mut ClientCounters,
    in_flight: &mut bool,
    deadline: Duration,
    unit_id: u8,
    request: Request<'_>,
) -> Result<Response, CallError> {
    let Some(ctx) = ctx.as_mut() else {
        return Err(CallError::NotConnected);
    };
    let function: FunctionCode = request.function_code();
    ctx.set_slave(Slave(unit_id));
    counters.requests += 1;
    *in_flight = true;
    let outcome = timeout(deadline, ctx.call(request)).await;
    *in_flight = false;
    match outcome {
        Err(_) => Err(CallError::Timeout),
        Ok(Err(tokio_modbus::Error::Transport(e))) => Err(CallError::Io(e)),
        Ok(Err(tokio_modbus::Error::Protocol(e))) => Err(CallError::Protocol(e.to_string())),
        Ok(Ok(Err(code))) => Err(CallError::Exception(function.value(), code)),
        Ok(Ok(Ok(response))) => Ok(response),
    }
}

/// Open a fresh transport and wrap it in a tokio-modbus context.
async fn open(transport: &TransportConfig) -> io::Result<Context> {
    match transport {
        TransportConfig::Tcp { address } => {
            let stream = TcpStream::connect(*address).await?;
            // Small request/response frames: do not let Nagle hold them back.
            stream.set_nodelay(true)?;
            Ok(tokio_modbus::client::tcp::attach(stream))
        }
        TransportConfig::Rtu(rtu) => {
            let port = tokio_serial::SerialStream::open(&rtu.builder())?;
            // Discard anything a previous session left in the buffers (e.g. a late answer).
            port.clear(tokio_serial::ClearBuffer::All)?;
            Ok(tokio_modbus::client::rtu::attach(port))
        }
    }
}

fn ms_ceil(d: Duration) -> u64 {
    let ms = d.as_millis();
    let ms = if d > Duration::from_millis(ms as u64) {
        ms + 1
    } else {
        ms
    };
    u64::try_from(ms).unwrap_or(u64::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_from_toml_tcp_and_rtu() {
        let c: ClientConfig = toml::from_str(
            r#"
            timeout_ms = 50
            [transport]
            kind = "tcp"
            address = "10.0.0.5:502"
            "#,
        )
        .unwrap();
        assert_eq!(c.timeout_ms, 50);
        assert_eq!(c.backoff_initial_ms, 100);
        assert_eq!(c.backoff_max_ms, 5000);
        assert_eq!(
            c.transport,
            TransportConfig::Tcp {
                address: "10.0.0.5:502".parse().unwrap()
            }
        );
        let r: ClientConfig = toml::from_str(
            r#"
            backoff_initial_ms = 20
            backoff_max_ms = 1000
            transport = { kind = "rtu", path = "/dev/ttyUSB0", baud = 19200, parity = "none", stop_bits = 2 }
            "#,
        )
        .unwrap();
        let TransportConfig::Rtu(rtu) = &r.transport else {
            panic!("expected rtu");
        };
        assert_eq!(rtu.parity, Parity::None);
        assert_eq!((rtu.stop_bits, rtu.data_bits, rtu.baud), (2, 8, 19200));
        assert!(r.validate().is_ok());
        assert!(toml::from_str::<ClientConfig>(
            "timout_ms = 5\n[transport]\nkind = \"tcp\"\naddress = \"1.2.3.4:502\""
        )
        .is_err());
    }

    #[test]
    fn config_validation() {
        let mut c = ClientConfig::tcp("127.0.0.1:502".parse().unwrap());
        assert!(c.validate().is_ok());
        c.timeout_ms = 0;
        assert!(c.validate().is_err());
        c.timeout_ms = 10;
        c.backoff_max_ms = 5;
        c.backoff_initial_ms = 10;
        assert!(c.validate().is_err());
        let mut rtu = RtuConfig::new("/dev/null", 9600);
        rtu.stop_bits = 3;
        assert!(ClientConfig::rtu(rtu).validate().is_err());
    }

    /// Coils and discrete inputs on the wire: a raw TCP peer records each request PDU and
    /// answers like a device (function codes 0x0F, 0x05, 0x01, 0x02).
    #[tokio::test]
    async fn coil_and_discrete_input_bytes_on_the_wire() {
        use crate::io::modbus::register::{DataType, RegisterBinding};
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let peer = tokio::spawn(async move {
            let (mut s, _) = listener.accept().await.unwrap();
            let mut pdus = Vec::new();
            for _ in 0..4 {
                let mut head = [0u8; 7];
                s.read_exact(&mut head).await.unwrap();
                let len = u16::from_be_bytes([head[4], head[5]]) as usize;
                let mut pdu = vec![0u8; len - 1];
                s.read_exact(&mut pdu).await.unwrap();
                let reply: Vec<u8> = match pdu[0] {
                    0x0F | 0x05 => pdu[..5].to_vec(),
                    // coils 0..3 = 1,0,1; discrete input 8 = 1: one data byte each
                    0x01 => vec![0x01, 0x01, 0b101],
                    0x02 => vec![0x02, 0x01, 0b1],
                    f => panic!("unexpected function {f:#04x}"),
                };
                let mut out = head[..4].to_vec();
                out.extend_from_slice(&((reply.len() + 1) as u16).to_be_bytes());
                out.push(head[6]);
                out.extend_from_slice(&reply);
                s.write_all(&out).await.unwrap();
                pdus.push((head[6], pdu));
            }
            pdus
        });
        let mut client = ModbusClient::new(ClientConfig::tcp(addr)).unwrap();
        let coil = |a| RegisterBinding::new(7, RegisterTable::Coil, a, DataType::Bool);
        let plan = WritePlan::new(&[coil(0), coil(1), coil(2), coil(5)]).unwrap();
        let report = client.write(&plan, &[1.0, 0.0, 1.0, 1.0]).await.unwrap();
        assert_eq!((report.requests, report.written), (2, 4));
        let di = RegisterBinding::new(7, RegisterTable::DiscreteInput, 8, DataType::Bool);
        // an inverted (normally closed) contact read from the same input
        let read =
            ReadPlan::new(&[coil(2), coil(1), coil(0), di, di.with_scaling(-1.0, 1.0)]).unwrap();
        assert_eq!(read.requests().len(), 2);
        let mut out = [f64::NAN; 5];
        client.read(&read, &mut out).await.unwrap();
        assert_eq!(out, [1.0, 0.0, 1.0, 1.0, 0.0]);
        let pdus = peer.await.unwrap();
        assert!(pdus.iter().all(|(unit, _)| *unit == 7));
        assert_eq!(
            pdus[0].1,
            [0x0F, 0x00, 0x00, 0x00, 0x03, 0x01, 0b101],
            "coils 0..3 in one write-multiple-coils, LSB first"
        );
        assert_eq!(
            pdus[1].1,
            [0x05, 0x00, 0x05, 0xFF, 0x00],
            "a lone coil: write single coil, ON = FF00"
        );
        assert_eq!(pdus[2].1, [0x01, 0x00, 0x00, 0x00, 0x03], "read coils 0..3");
        assert_eq!(
            pdus[3].1,
            [0x02, 0x00, 0x08, 0x00, 0x01],
            "read discrete input 8"
        );
    }

    #[test]
    fn ms_ceil_rounds_up() {
        assert_eq!(ms_ceil(Duration::from_micros(1)), 1);
        assert_eq!(ms_ceil(Duration::from_millis(7)), 7);
        assert_eq!(ms_ceil(Duration::from_micros(7001)), 8);
    }
}
