//! The Modbus links' settings: the controller's link, the plant's server, the heartbeat block.

use crate::io::modbus::client::ClientConfig;
use crate::io::modbus::register::{DataType, RegisterBinding, RegisterTable};
use serde::{Deserialize, Serialize};
use std::time::Duration;

use super::*;

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
                crate::io::modbus::client::TransportConfig::Tcp { .. }
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
