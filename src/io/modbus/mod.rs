//! Modbus: register encoding, a client with timeouts and reconnect, and a server over a
//! shared register image.
//!
//! - [`register`]: [`RegisterBinding`] (unit id, table, 0-based address, data type, byte and
//!   word order, scale and offset) with pure encode/decode and overlap detection.
//! - [`plan`]: bindings grouped once into as few read/write requests as possible.
//! - [`client`]: [`ModbusClient`] over TCP or RTU; every call under a timeout, reconnect with
//!   exponential backoff after any link failure, typed errors and counters.
//! - [`server`]: a Modbus TCP (and RTU) server answering from a [`SharedImage`], for the
//!   simulated plant and hardware-in-the-loop tests.
//! - [`bounded_server`]: a read-only Modbus TCP server with a connection cap, idle time-out,
//!   request budget and descriptor-exhaustion back-off (the DCS block's).
//! - [`link`]: the link tasks. Controller: poll sensors into the sensor board, write the
//!   control thread's outputs and a heartbeat block. Plant: a server over the snapshot,
//!   command and heartbeat boards.

pub mod bounded_server;
pub mod client;
pub mod link;
pub mod plan;
pub mod register;
pub mod request_guard;
pub mod server;
pub mod watchdog;

pub use client::{
    ClientConfig, ClientCounters, ConfigError, ConnectionState, ModbusClient, ModbusError, Parity,
    RtuConfig, TransportConfig, WriteReport,
};
pub use link::{
    run_controller, run_controller_triggering, run_plant_server, AnotherWriter, CommandConnection,
    ExceptionInfo, FailureCause, HeartbeatRegister, HeartbeatWords, LinkCounters, LinkCounts,
    LinkError, LinkMonitor, LinkState, ModbusLinkConfig, ModbusLinkView, ModbusServerConfig,
    Pacing, PlantCounters, PlantCounts, PlantServer, WriteFailure, WriteHealth,
};
pub use plan::{PlanError, PlannedRequest, ReadPlan, WritePlan};
pub use register::{
    find_overlaps, BindingError, ByteOrder, DataType, DecodeError, EncodeError, EncodeOutcome,
    Overlap, RegisterBinding, RegisterTable, WordOrder,
};
pub use server::{
    lock_image, open_rtu_server, spawn_rtu_server, spawn_tcp_server, spawn_tcp_server_on,
    ImageError, RegisterImage, ResponseMode, RtuServerHandle, SharedImage, TcpServerHandle,
};
/// Modbus exception codes, as reported in [`ModbusError::Exception`].
pub use tokio_modbus::ExceptionCode;
pub use watchdog::{ModbusWatchdog, WatchdogPart, WatchdogWriter};
