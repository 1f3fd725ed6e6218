//! SocketCAN bus tasks for both ends of the skid bus.
//!
//! - [`run_controller`] (daemon side): publishes received sensor frames into the
//!   [`SensorBoard`], sends the control thread's [`OutputBoard`] as actuator frames when its
//!   [`Wakeup`] fires, and sends the heartbeat every `heartbeat_period_ms`.
//! - [`run_plant`] (simulated plant / field gateway side): publishes received actuator frames
//!   into the [`CommandBoard`] and the heartbeat into the [`HeartbeatBoard`], and sends the
//!   latest [`SnapshotBoard`] snapshot as sensor frames when the plant's [`Wakeup`] fires.
//!
//! Each message goes out at the cycle time its DBC declares (`GenMsgCycleTime`, see
//! [`FrameEncoder`]), whatever the wakeup rate: the bus carries the load check-config computed.
//!
//! Both run until the shutdown signal and never give up on the bus: any socket error
//! (interface down → `ENETDOWN`, interface deleted → `ENODEV`/`ENXIO`, …) or a bus-off error
//! frame closes the socket, and a new one is opened after an exponential backoff
//! (`reconnect_backoff_initial_ms`, doubling up to `reconnect_backoff_max_ms`; back to the
//! initial delay once a session carried a frame). An open only succeeds if the interface is up
//! and its controller (as reported over netlink, where the driver reports one) is not bus-off:
//! restarting a bus-off controller is the kernel's job (`restart-ms`) or the operator's.
//!
//! While the link is down nothing is published, so the real-time loop sees its inputs go stale
//! and applies its own fail-safe; these tasks never decide fail-safe themselves. Link state
//! changes go to a [`watch`] channel of [`BusState`] and, losslessly, to an optional
//! [`StateHook`] (the daemon turns them into event-log entries, see [`BusState::to_event`]);
//! every anomaly is counted in [`CanCounters`].
//!
//! The frame handling is separate from the socket: [`RxHandler`] turns one received frame into
//! board updates and counter increments, [`FrameEncoder`] and [`HeartbeatTx`] turn board
//! contents into frames. None of them allocates per frame.

mod cycle_trigger;
mod link;
mod rx;
mod sender_clock;
mod tx;

use std::convert::Infallible;
use std::fmt;
use std::io;
use std::os::fd::{AsRawFd, RawFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use socketcan::nl::CanState;
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;
use tokio::sync::watch;
use tokio::time::MissedTickBehavior;

use super::codec::{BindingError, CanCodec, SignalBinding, SignalValues};
use super::dbc::{CanDatabase, DbcError, FrameId, FrameIdError, FrameIdOverride};
use super::heartbeat::{HeartbeatCodec, HeartbeatConfig, HeartbeatNames};
use crate::runtime::handoff::{
    monotonic_ns, CommandBoard, HeartbeatBoard, OutputBoard, SensorBoard, SnapshotBoard, Wakeup,
};
use crate::runtime::trigger::CycleTrigger;

pub use cycle_trigger::{CycleTriggerSpec, TriggerPlan, MAX_TRIGGER_MESSAGES};
pub use link::CanLink;
pub use rx::{classify_error_frame, BusCondition, RxHandler, RxOutcome, RxReject};
pub use sender_clock::{RateMismatch, SenderClock};
pub use tx::{FrameEncoder, HeartbeatTx};

fn default_heartbeat_period_ms() -> u64 {
    10
}
fn default_heartbeat_timeout_ms() -> u64 {
    100
}
fn default_backoff_initial_ms() -> u64 {
    50
}
fn default_backoff_max_ms() -> u64 {
    2000
}

/// How a device on the bus reads "no value" (`bus.can.not_available`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NotAvailable {
    /// Follow the receiving device's DBC (default): a DBC that declares a J1939 network
    /// (`BA_ "ProtocolType" "J1939";`, as `config/skid.dbc` does) reads all ones as "no
    /// value" ([`NotAvailable::J1939`]); any other device gets, in a data signal nothing is
    /// bound to, the signal's DBC start value (`GenSigStartValue`), and a config whose sent
    /// message leaves a signal without one is refused naming it; a bound value that is not
    /// computed is handled as [`NotAvailable::None`] does.
    #[default]
    Dbc,
    /// SAE J1939: one reserved raw value per signal (all ones unsigned, the most negative
    /// signed) means "no value" (`config/skid.dbc`'s convention). Unbound data signals of a
    /// sent message carry it.
    J1939,
    /// The device has no such value (it would read all ones as a number, e.g. 655.35 %): a
    /// message goes out only once every bound value was computed, a value that becomes NaN
    /// repeats the last number sent, and an unbound data signal in a sent message is an error.
    None,
}

/// Settings of one CAN bus node (the `[io.can]` section).
///
/// Config keys: `interface` (`can0`, `vcan0`, …), `dbc` (path of the DBC file),
/// `heartbeat_period_ms` (default 10), `heartbeat_timeout_ms` (default 100, used by the plant
/// loop, carried here), `reconnect_backoff_initial_ms` (default 50),
/// `reconnect_backoff_max_ms` (default 2000), `tx_on_change_only` (default false).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CanBusConfig {
    /// Network interface name.
    pub interface: String,
    /// DBC file describing the bus.
    pub dbc: PathBuf,
    /// Controller: period of the heartbeat frame, ms. Also the longest gap between two frames
    /// of one message when `tx_on_change_only` is set.
    #[serde(default = "default_heartbeat_period_ms")]
    pub heartbeat_period_ms: u64,
    /// Plant: the heartbeat is lost when none arrived for this long, ms. Not used by the bus
    /// tasks (the plant's real-time loop checks the age on the [`HeartbeatBoard`]).
    #[serde(default = "default_heartbeat_timeout_ms")]
    pub heartbeat_timeout_ms: u64,
    /// First delay before reopening the socket after a failure, ms.
    #[serde(default = "default_backoff_initial_ms")]
    pub reconnect_backoff_initial_ms: u64,
    /// Longest delay between reconnect attempts, ms (the delay doubles per failed attempt).
    #[serde(default = "default_backoff_max_ms")]
    pub reconnect_backoff_max_ms: u64,
    /// Send a frame only when its data bits changed (still at least once per
    /// `heartbeat_period_ms`, so the receiver's staleness checks hold).
    #[serde(default)]
    pub tx_on_change_only: bool,
    /// Bit rate of the bus, bit/s (as set on the interface, e.g. `BitRate=` in
    /// deploy/80-can0.network; default 1 000 000, the rate that file sets). check-config
    /// computes the worst-case load of the DBC's periodic messages at this rate and refuses
    /// more than `max_load_pct`.
    #[serde(default = "default_bitrate_bps")]
    pub bitrate_bps: Option<u64>,
    /// Highest accepted worst-case bus load, % of the bit rate (default 70).
    #[serde(default = "default_max_load_pct")]
    pub max_load_pct: u32,
    /// How the devices read "no value": `j1939` (default, the reserved pattern) or `none`.
    #[serde(default)]
    pub not_available: NotAvailable,
    /// `[bus.can.heartbeat]`: the heartbeat message and its counter, mode, law and faults
    /// signals in the DBC (default: `config/skid.dbc`'s `CTRL_Heartbeat`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heartbeat: Option<HeartbeatConfig>,
    /// `[bus.can.frame_ids]`: per DBC message, the CAN id to use instead of the DBC's
    /// (`CTRL_ActuatorCmd1 = 0x18FF1234`: 29-bit because above 0x7FF; or
    /// `{ id = 0x100, extended = true }`). Both ends, the bus load and the codec use it.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub frame_ids: std::collections::BTreeMap<String, FrameIdOverride>,
    /// Controller: what starts a control cycle: `"inputs"` (default: the messages carrying
    /// the pressures and the speed), `"deadline"` (the fixed period only), or DBC message
    /// names. The deadline stays the fallback ([`crate::runtime::trigger`]).
    #[serde(default)]
    pub cycle_trigger: CycleTriggerSpec,
}

fn default_max_load_pct() -> u32 {
    70
}

/// The bit rate deploy/80-can0.network sets (`BitRate=1M`).
fn default_bitrate_bps() -> Option<u64> {
    Some(1_000_000)
}

impl CanBusConfig {
    /// A configuration with the defaults for everything but the interface and the DBC.
    pub fn new(interface: impl Into<String>, dbc: impl Into<PathBuf>) -> CanBusConfig {
        CanBusConfig {
            interface: interface.into(),
            dbc: dbc.into(),
            heartbeat_period_ms: default_heartbeat_period_ms(),
            heartbeat_timeout_ms: default_heartbeat_timeout_ms(),
            reconnect_backoff_initial_ms: default_backoff_initial_ms(),
            reconnect_backoff_max_ms: default_backoff_max_ms(),
            tx_on_change_only: false,
            bitrate_bps: default_bitrate_bps(),
            max_load_pct: default_max_load_pct(),
            not_available: NotAvailable::Dbc,
            heartbeat: None,
            frame_ids: Default::default(),
            cycle_trigger: CycleTriggerSpec::Inputs,
        }
    }

    /// The DBC at `dbc` (already resolved against the config file) with the
    /// `[bus.can.frame_ids]` overrides applied: the one way every bus user gets its ids.
    pub fn database(&self, dbc: &Path) -> Result<CanDatabase, CanBusError> {
        let mut db = CanDatabase::from_file(dbc)?;
        db.override_frame_ids(self.frame_ids.iter().map(|(k, v)| (k.as_str(), *v)))?;
        Ok(db)
    }

    /// The heartbeat names: `[bus.can.heartbeat]`, or `config/skid.dbc`'s.
    pub fn heartbeat_names(&self) -> HeartbeatNames<'_> {
        self.heartbeat
            .as_ref()
            .map_or(HeartbeatNames::SKID, HeartbeatConfig::names)
    }

    /// Check the values (interface name length, non-zero periods, backoff order, heartbeat
    /// timeout longer than its period).
    pub fn validate(&self) -> Result<(), CanBusError> {
        let bad = |key: &'static str, message: String| Err(CanBusError::Config { key, message });
        if self.interface.is_empty() || self.interface.len() > 15 {
            return bad(
                "interface",
                format!(
                    "{:?} is not an interface name (1 to 15 bytes)",
                    self.interface
                ),
            );
        }
        if self.interface.contains(['/', '\0']) || self.interface.contains(char::is_whitespace) {
            return bad(
                "interface",
                format!("{:?} contains a character not allowed", self.interface),
            );
        }
        if self.heartbeat_period_ms == 0 {
            return bad("heartbeat_period_ms", "must be at least 1".into());
        }
        if self.heartbeat_timeout_ms <= self.heartbeat_period_ms {
            return bad(
                "heartbeat_timeout_ms",
                format!(
                    "{} ms must be longer than heartbeat_period_ms ({} ms)",
                    self.heartbeat_timeout_ms, self.heartbeat_period_ms
                ),
            );
        }
        if self.reconnect_backoff_initial_ms == 0 {
            return bad("reconnect_backoff_initial_ms", "must be at least 1".into());
        }
        if self.reconnect_backoff_max_ms < self.reconnect_backoff_initial_ms {
            return bad(
                "reconnect_backoff_max_ms",
                format!(
                    "{} ms is shorter than reconnect_backoff_initial_ms ({} ms)",
                    self.reconnect_backoff_max_ms, self.reconnect_backoff_initial_ms
                ),
            );
        }
        Ok(())
    }

    fn heartbeat_period(&self) -> Duration {
        Duration::from_millis(self.heartbeat_period_ms.max(1))
    }
}

/// Why a CAN bus task could not start. Runtime socket failures are not errors: they lead to a
/// reconnect.
#[derive(Debug, thiserror::Error)]
pub enum CanBusError {
    /// A configuration value is unusable.
    #[error("CAN bus configuration, {key}: {message}")]
    Config {
        /// Config key.
        key: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The DBC file cannot be loaded.
    #[error(transparent)]
    Dbc(#[from] DbcError),
    /// A `[bus.can.frame_ids]` entry names no message, does not fit its id kind, or clashes
    /// with another message's id.
    #[error(transparent)]
    FrameId(#[from] FrameIdError),
    /// The signal bindings or the heartbeat do not fit the DBC.
    #[error(transparent)]
    Binding(#[from] BindingError),
    /// A message to send has an identifier socketcan cannot represent.
    #[error("message {message}: CAN id {id} cannot be sent")]
    BadId {
        /// Message name.
        message: String,
        /// Its identifier.
        id: FrameId,
    },
    /// The wakeup eventfd cannot be registered with the tokio reactor.
    #[error("cannot poll the wakeup eventfd: {0}")]
    Wakeup(#[source] io::Error),
}

/// Both codecs a bus node needs: the signal codec (sensor and actuator frames) and the
/// heartbeat codec, built once from one DBC.
#[derive(Debug, Clone)]
pub struct BusCodec {
    /// Sensor and actuator frames.
    pub frames: CanCodec,
    /// The controller heartbeat.
    pub heartbeat: HeartbeatCodec,
}

impl BusCodec {
    /// Build both codecs from a parsed DBC (heartbeat names of `config/skid.dbc`).
    pub fn new(db: &CanDatabase, bindings: &[SignalBinding]) -> Result<BusCodec, CanBusError> {
        BusCodec::with_heartbeat(db, bindings, &HeartbeatNames::SKID)
    }

    /// Build both codecs from a parsed DBC with the heartbeat `names`.
    pub fn with_heartbeat(
        db: &CanDatabase,
        bindings: &[SignalBinding],
        names: &HeartbeatNames<'_>,
    ) -> Result<BusCodec, CanBusError> {
        Ok(BusCodec {
            frames: CanCodec::new(db, bindings)?,
            heartbeat: HeartbeatCodec::new(db, names)?,
        })
    }

    /// Load the DBC at `dbc` and build both codecs (`bindings`: e.g.
    /// [`SignalMap::can_bindings`](crate::io::signal_map::SignalMap::can_bindings);
    /// heartbeat names of `config/skid.dbc`).
    pub fn load(dbc: &Path, bindings: &[SignalBinding]) -> Result<BusCodec, CanBusError> {
        BusCodec::new(&CanDatabase::from_file(dbc)?, bindings)
    }

    /// Load the DBC at `dbc` (already resolved against the config file) and build both codecs
    /// with the heartbeat `cfg` names (`[bus.can.heartbeat]`).
    pub fn load_for(
        cfg: &CanBusConfig,
        dbc: &Path,
        bindings: &[SignalBinding],
    ) -> Result<BusCodec, CanBusError> {
        let codec =
            BusCodec::with_heartbeat(&cfg.database(dbc)?, bindings, &cfg.heartbeat_names())?;
        // both ends' senders, checked once here so that check-config sees it
        let all: Vec<_> = codec.frames.actuator_messages().collect();
        FrameEncoder::with_not_available(
            &codec.frames,
            &all,
            false,
            cfg.heartbeat_period(),
            cfg.not_available,
        )?;
        let all: Vec<_> = codec.frames.sensor_messages().collect();
        FrameEncoder::with_not_available(
            &codec.frames,
            &all,
            false,
            cfg.heartbeat_period(),
            cfg.not_available,
        )?;
        codec.trigger_plan(&cfg.cycle_trigger)?;
        Ok(codec)
    }
}

/// What an operation on the socket was doing when it failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum IoOp {
    /// Opening, binding or configuring the socket.
    Open,
    /// Reading a frame.
    Receive,
    /// Writing a frame.
    Send,
    /// Waiting on the wakeup eventfd.
    Wakeup,
}

impl fmt::Display for IoOp {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            IoOp::Open => "open",
            IoOp::Receive => "receive",
            IoOp::Send => "send",
            IoOp::Wakeup => "wakeup",
        })
    }
}

/// Why the link went down.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DownCause {
    /// The CAN controller reported bus-off in an error frame.
    BusOff,
    /// A socket call failed (`ENETDOWN`: interface down, `ENODEV`: interface gone, …).
    Io {
        /// Which call.
        op: IoOp,
        /// OS error number, if the error came from the OS.
        errno: Option<i32>,
        /// Error kind.
        kind: io::ErrorKind,
    },
}

impl DownCause {
    /// The cause for a failed socket call.
    pub fn io(op: IoOp, e: &io::Error) -> DownCause {
        DownCause::Io {
            op,
            errno: e.raw_os_error(),
            kind: e.kind(),
        }
    }
}

impl fmt::Display for DownCause {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DownCause::BusOff => f.write_str("bus-off"),
            DownCause::Io {
                op, errno: Some(n), ..
            } => write!(f, "{op} failed: {}", io::Error::from_raw_os_error(*n)),
            DownCause::Io { op, kind, .. } => write!(f, "{op} failed: {kind}"),
        }
    }
}

/// What a CAN controller reports while the link still passes traffic: its error state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CanTrouble {
    /// An error counter passed the warning level (error frame).
    ErrorWarning,
    /// The controller is error-passive (error frame). Traffic may still pass.
    ErrorPassive,
}

impl fmt::Display for CanTrouble {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            CanTrouble::ErrorWarning => "error warning",
            CanTrouble::ErrorPassive => "error passive",
        })
    }
}

impl crate::io::link::Degradation for CanTrouble {
    /// Warning and error-passive count as up in the status: traffic still passes.
    fn status_name(&self) -> &'static str {
        "up"
    }
}

impl crate::io::link::DownReason for DownCause {
    fn is_bus_off(&self) -> bool {
        *self == DownCause::BusOff
    }
}

/// State of a CAN link: the field links' one [`LinkState`](crate::io::link::LinkState), its
/// degradation the controller's error state and its cause a [`DownCause`]. Published on a
/// [`watch`] channel and to the optional [`StateHook`].
///
/// A failure reads `Up` → `Down { attempt: 0, .. }` → `Down { attempt: 1, .. }` → (`2`, …
/// while reopening fails) → `Up`. A watch channel keeps only the latest value, so a watcher may
/// miss the short-lived first `Down`; later ones repeat the cause, the hook sees every change,
/// and [`CanCounters`] count every event.
pub type BusState = crate::io::link::LinkState<CanTrouble, DownCause>;

crate::io::link::link_counters! {
    /// Lock-free event counters of one CAN node (monotonic since start).
    atomic CanCounters;
    /// A copy of [`CanCounters`] for statistics and logs.
    plain CanCountersSnapshot;
    {
    /// Frames read from the socket, of any kind.
    rx_frames,
    /// Data frames decoded and published to a board.
    rx_published,
    /// Frames written to the socket.
    tx_frames,
    /// Writes refused with a transient error (`ENOBUFS`: queue full, `EAGAIN`): frame dropped.
    tx_errors,
    /// Frames not sent because their data did not change (`tx_on_change_only`).
    tx_unchanged,
    /// Wakeups on which a message was not sent because its DBC cycle time
    /// (`GenMsgCycleTime`) had not come round yet.
    tx_not_due,
    /// Data frames whose identifier is not in the DBC.
    unknown_id,
    /// Data frames of a known message with the wrong length.
    wrong_dlc,
    /// Data frames of a known message with a bad CRC byte.
    bad_crc,
    /// Frames with a value that is not finite or not in its value table.
    invalid_value,
    /// Valid frames of messages this node does not consume (e.g. another controller's
    /// commands seen by the controller).
    foreign,
    /// Frames dropped because their alive counter repeated (stuck sender).
    alive_repeated,
    /// Frames whose alive counter skipped values (published anyway).
    alive_skipped,
    /// Frames lost according to the alive counters (sum of the skipped values).
    frames_lost,
    /// Sensor messages whose alive counter, over a second of arrivals, disagreed with their
    /// DBC cycle time by more than 20 %: their samples are then timed by arrival until the
    /// link is reset (`SenderClock`; the journal names the message).
    sender_clock_distrusted,
    /// Remote (RTR) frames, ignored.
    remote_frames,
    /// CAN FD frames, ignored (the DBC describes classic CAN).
    fd_frames,
    /// Error frames from the CAN controller or driver.
    error_frames,
    /// Heartbeats not sent because the control thread published nothing since the last one.
    heartbeats_withheld,
    /// Bus-off error frames.
    bus_off,
    /// Entries into the error-passive state.
    error_passive,
    /// Sessions ended by a socket error or bus-off.
    link_down,
    /// Failed attempts to open the socket.
    open_failures,
    /// Successful socket opens after the first one.
    reconnects,
    }
}

/// A running CAN link as the daemon sees it ([`FieldLink`](crate::io::link::FieldLink)): its
/// counters and its state channel.
pub struct CanLinkView {
    /// `can:<interface>`.
    pub name: String,
    /// The task's counters.
    pub counters: Arc<CanCounters>,
    /// The task's state.
    pub state: watch::Receiver<BusState>,
}

impl crate::io::link::FieldLink for CanLinkView {
    fn kind(&self) -> crate::vocab::faults::FieldLinkKind {
        crate::vocab::faults::FieldLinkKind::Can
    }
    fn name(&self) -> &str {
        &self.name
    }
    fn status_name(&self) -> &'static str {
        self.state.borrow().status_name()
    }
    fn is_up(&self) -> bool {
        self.state.borrow().is_up()
    }
    fn traffic(&self) -> crate::io::link::LinkTraffic {
        let c = self.counters.snapshot();
        crate::io::link::LinkTraffic {
            sent: c.tx_frames,
            received: c.rx_frames,
            errors: c.unknown_id
                + c.wrong_dlc
                + c.bad_crc
                + c.invalid_value
                + c.error_frames
                + c.tx_errors,
            down: c.link_down,
            reconnects: c.reconnects,
        }
    }
    fn counters_json(&self) -> serde_json::Value {
        serde_json::to_value(self.counters.snapshot()).unwrap_or_default()
    }
}

/// Called by the bus task on every state change, in order and without coalescing (e.g. to
/// write event-log entries). Runs on the bus task: it must not block.
pub type StateHook = Arc<dyn Fn(&BusState) + Send + Sync>;

/// What a bus task shares with the daemon: counters, state channel, change hook and shutdown
/// signal.
#[derive(Clone)]
pub struct BusHandles {
    /// Counters, updated by the task.
    pub counters: Arc<CanCounters>,
    /// Current link state, written by the task (the daemon keeps receivers). A watch channel
    /// keeps only the latest value; use `on_change` to see every transition.
    pub state: watch::Sender<BusState>,
    /// Optional hook called on every state change.
    pub on_change: Option<StateHook>,
    /// Shutdown: the task returns once the value is `true` or the sender is dropped.
    pub shutdown: watch::Receiver<bool>,
}

impl fmt::Debug for BusHandles {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("BusHandles")
            .field("counters", &self.counters)
            .field("state", &*self.state.borrow())
            .field("on_change", &self.on_change.is_some())
            .field("shutdown", &*self.shutdown.borrow())
            .finish()
    }
}

impl BusHandles {
    /// Fresh counters, a state channel starting at [`BusState::Idle`], no hook, and the
    /// given shutdown receiver. Returns the handles and a state receiver.
    pub fn new(shutdown: watch::Receiver<bool>) -> (BusHandles, watch::Receiver<BusState>) {
        let (state, rx) = watch::channel(BusState::Idle);
        (
            BusHandles {
                counters: Arc::new(CanCounters::default()),
                state,
                on_change: None,
                shutdown,
            },
            rx,
        )
    }

    /// The same handles with `hook` called on every state change.
    pub fn with_hook(mut self, hook: StateHook) -> BusHandles {
        self.on_change = Some(hook);
        self
    }
}

/// Boards of the controller node.
#[derive(Debug, Clone)]
pub struct ControllerBoards {
    /// Received sensor values (written by this task).
    pub sensors: Arc<SensorBoard>,
    /// The control thread's outputs (read by this task).
    pub outputs: Arc<OutputBoard>,
    /// Signalled by the control thread after each publish.
    pub wake: Arc<Wakeup>,
    /// Fired when the cycle's trigger messages arrived (`bus.can.cycle_trigger`); `None`:
    /// the control thread runs on its deadline only.
    pub trigger: Option<Arc<CycleTrigger>>,
}

/// Boards of the plant node.
#[derive(Debug, Clone)]
pub struct PlantBoards {
    /// Received actuator setpoints (written by this task).
    pub commands: Arc<CommandBoard>,
    /// Received heartbeat (written by this task).
    pub heartbeat: Arc<HeartbeatBoard>,
    /// The plant loop's sensor snapshot (read by this task).
    pub snapshots: Arc<SnapshotBoard>,
    /// Signalled by the plant loop after each publish.
    pub wake: Arc<Wakeup>,
}

/// Run the controller node on `cfg.interface` until shutdown.
///
/// Receives sensor frames into `boards.sensors` (stamped with [`monotonic_ns`] at reception),
/// sends `boards.outputs` as actuator frames on wakeups (each message at its DBC cycle time)
/// and the heartbeat every `heartbeat_period_ms` (withheld while the control thread publishes nothing new, so a hung
/// control thread stops the heartbeat). Returns `Ok` on shutdown; errors only for unusable
/// configuration.
pub async fn run_controller(
    cfg: CanBusConfig,
    codec: BusCodec,
    boards: ControllerBoards,
    handles: BusHandles,
) -> Result<(), CanBusError> {
    cfg.validate()?;
    let codec = Arc::new(codec);
    let refresh = cfg.heartbeat_period();
    let actuators: Vec<_> = codec.frames.actuator_messages().collect();
    let mut rx = RxHandler::controller(
        Arc::clone(&codec),
        Arc::clone(&boards.sensors),
        Arc::clone(&handles.counters),
    );
    if let Some(trigger) = &boards.trigger {
        match codec.trigger_plan(&cfg.cycle_trigger)? {
            Some(plan) => {
                tracing::info!(target: "can", "control cycle starts on {} (deadline as fallback)", plan.describe());
                rx = rx.with_trigger(Arc::clone(trigger), &plan);
            }
            None => trigger.arm(0),
        }
    }
    let mut role = ControllerRole {
        rx,
        tx: FrameEncoder::with_not_available(
            &codec.frames,
            &actuators,
            cfg.tx_on_change_only,
            refresh,
            cfg.not_available,
        )?,
        hb: HeartbeatTx::new(&codec.heartbeat)?,
        outputs: Arc::clone(&boards.outputs),
        wake: WakeFd::register(&boards.wake)?,
        period: refresh,
    };
    run_link(&cfg, &mut role, handles).await;
    Ok(())
}

/// Run the plant node on `cfg.interface` until shutdown.
///
/// Receives actuator frames into `boards.commands` and heartbeats into `boards.heartbeat`,
/// and sends the latest `boards.snapshots` snapshot as sensor frames on wakeups (each message
/// at its DBC cycle time). Returns `Ok` on shutdown; errors only for unusable configuration.
pub async fn run_plant(
    cfg: CanBusConfig,
    codec: BusCodec,
    boards: PlantBoards,
    handles: BusHandles,
) -> Result<(), CanBusError> {
    cfg.validate()?;
    let codec = Arc::new(codec);
    let sensors: Vec<_> = codec.frames.sensor_messages().collect();
    let mut role = PlantRole {
        rx: RxHandler::plant(
            Arc::clone(&codec),
            Arc::clone(&boards.commands),
            Arc::clone(&boards.heartbeat),
            Arc::clone(&handles.counters),
        ),
        tx: FrameEncoder::with_not_available(
            &codec.frames,
            &sensors,
            cfg.tx_on_change_only,
            cfg.heartbeat_period(),
            cfg.not_available,
        )?
        .counting_sample_periods(),
        snapshots: Arc::clone(&boards.snapshots),
        wake: WakeFd::register(&boards.wake)?,
    };
    run_link(&cfg, &mut role, handles).await;
    Ok(())
}

/// The wakeup eventfd as something [`AsyncFd`] can register.
struct WakeFd(Arc<Wakeup>);

impl AsRawFd for WakeFd {
    fn as_raw_fd(&self) -> RawFd {
        self.0.fd().as_raw_fd()
    }
}

impl WakeFd {
    fn register(w: &Arc<Wakeup>) -> Result<AsyncFd<WakeFd>, CanBusError> {
        // SAFETY: WakeFd keeps the Wakeup (and so its owned eventfd) alive and always returns
        // that same descriptor, for as long as the AsyncFd exists.
        unsafe { AsyncFd::register_with_interest(WakeFd(Arc::clone(w)), Interest::READABLE) }
            .map_err(|e| CanBusError::Wakeup(e.into()))
    }
}

/// Wait until the eventfd was signalled, then clear it. Returns the number of signals.
async fn wait_wake(fd: &AsyncFd<WakeFd>) -> io::Result<u64> {
    loop {
        let mut guard = fd.readable().await?;
        let cleared = guard.try_io(|w| match w.get_ref().0.clear() {
            0 => Err(io::ErrorKind::WouldBlock.into()),
            n => Ok(n),
        });
        match cleared {
            Ok(result) => return result,
            Err(_would_block) => continue,
        }
    }
}

/// Resolves once shutdown is requested (value `true` or sender gone).
async fn shutdown_requested(rx: &mut watch::Receiver<bool>) {
    let _ = rx.wait_for(|stop| *stop).await;
}

fn shutdown_now(rx: &watch::Receiver<bool>) -> bool {
    *rx.borrow() || rx.has_changed().is_err()
}

/// Publishes state changes and logs them.
struct Reporter<'a> {
    interface: &'a str,
    state: &'a watch::Sender<BusState>,
    hook: Option<&'a StateHook>,
    counters: &'a CanCounters,
}

impl Reporter<'_> {
    fn set(&self, new: BusState) {
        let changed = self.state.send_if_modified(|cur| {
            if *cur == new {
                false
            } else {
                *cur = new;
                true
            }
        });
        if !changed {
            return;
        }
        if let Some(hook) = self.hook {
            hook(&new);
        }
        let iface = self.interface;
        match new {
            BusState::Up | BusState::Stopped | BusState::Idle => {
                tracing::info!(target: "can", interface = iface, "CAN link {new}")
            }
            BusState::Degraded(CanTrouble::ErrorPassive) => {
                CanCounters::inc(&self.counters.error_passive);
                tracing::warn!(target: "can", interface = iface, "CAN link {new}")
            }
            BusState::Degraded(CanTrouble::ErrorWarning) | BusState::Down { attempt: 0, .. } => {
                tracing::warn!(target: "can", interface = iface, "CAN link {new}")
            }
            BusState::Down { attempt: 1, .. } => {
                tracing::info!(target: "can", interface = iface, "CAN link {new}")
            }
            BusState::Down { .. } => {
                tracing::debug!(target: "can", interface = iface, "CAN link {new}")
            }
        }
    }
}

/// What one open socket's life ended with.
enum SessionEnd {
    Shutdown,
    Failed(DownCause),
}

/// Per-session context shared by the RX and TX halves of a role.
struct Session<'a> {
    link: &'a CanLink,
    report: &'a Reporter<'a>,
    counters: &'a CanCounters,
    /// Set once a frame was received or sent: the link works, so the backoff restarts.
    carried: AtomicBool,
}

impl Session<'_> {
    /// Write one frame. Transient refusals (queue full) are counted and the frame dropped: the
    /// next cycle carries fresher values anyway. Anything else ends the session.
    fn send(&self, frame: &socketcan::CanDataFrame) -> Result<(), DownCause> {
        match self.link.send(frame) {
            Ok(()) => {
                CanCounters::inc(&self.counters.tx_frames);
                self.carried.store(true, Ordering::Relaxed);
                Ok(())
            }
            Err(e) if link::is_transient_send_error(&e) => {
                CanCounters::inc(&self.counters.tx_errors);
                Ok(())
            }
            Err(e) => Err(DownCause::io(IoOp::Send, &e)),
        }
    }

    /// Receive and handle frames until the socket fails or a bus-off arrives.
    async fn receive_loop(&self, rx: &mut RxHandler) -> Result<Infallible, DownCause> {
        loop {
            let frame = self
                .link
                .recv()
                .await
                .map_err(|e| DownCause::io(IoOp::Receive, &e))?;
            match rx.handle_frame(&frame, monotonic_ns()) {
                RxOutcome::Published => self.carried.store(true, Ordering::Relaxed),
                RxOutcome::Rejected(_) => {}
                RxOutcome::Bus(c) => match c {
                    BusCondition::BusOff => return Err(DownCause::BusOff),
                    BusCondition::Passive => self
                        .report
                        .set(BusState::Degraded(CanTrouble::ErrorPassive)),
                    BusCondition::Warning => self
                        .report
                        .set(BusState::Degraded(CanTrouble::ErrorWarning)),
                    BusCondition::Active => self.report.set(BusState::Up),
                    BusCondition::Other => {}
                },
            }
        }
    }
}

/// One end of the bus: what it does while a socket is open.
trait Role {
    /// Forget per-link receive state (alive counters) after a reconnect.
    fn reset(&mut self);
    /// Run RX and TX on an open socket until it fails or shutdown.
    async fn session(
        &mut self,
        s: &Session<'_>,
        shutdown: &mut watch::Receiver<bool>,
    ) -> SessionEnd;
}

struct ControllerRole {
    rx: RxHandler,
    tx: FrameEncoder,
    hb: HeartbeatTx,
    outputs: Arc<OutputBoard>,
    wake: AsyncFd<WakeFd>,
    period: Duration,
}

impl Role for ControllerRole {
    fn reset(&mut self) {
        self.rx.reset_alive();
    }

    async fn session(
        &mut self,
        s: &Session<'_>,
        shutdown: &mut watch::Receiver<bool>,
    ) -> SessionEnd {
        let ControllerRole {
            rx,
            tx,
            hb,
            outputs,
            wake,
            period,
        } = self;
        let send = controller_send_loop(s, tx, hb, outputs, wake, *period);
        run_halves(s.receive_loop(rx), send, shutdown).await
    }
}

/// Controller TX: actuator frames on every wakeup, the heartbeat on every tick.
async fn controller_send_loop(
    s: &Session<'_>,
    tx: &mut FrameEncoder,
    hb: &mut HeartbeatTx,
    outputs: &OutputBoard,
    wake: &AsyncFd<WakeFd>,
    period: Duration,
) -> Result<Infallible, DownCause> {
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            woke = wait_wake(wake) => {
                woke.map_err(|e| DownCause::io(IoOp::Wakeup, &e))?;
                if let Some(o) = outputs.latest() {
                    send_all(s, tx, &o.commands)?;
                }
            }
            _ = tick.tick() => {
                match hb.next_frame(outputs.latest().as_ref()) {
                    Some(frame) => s.send(&frame)?,
                    None => CanCounters::inc(&s.counters.heartbeats_withheld),
                }
            }
        }
    }
}

/// Encode and send every message of `tx` from `values`, now.
fn send_all<V: SignalValues>(
    s: &Session<'_>,
    tx: &mut FrameEncoder,
    values: &V,
) -> Result<(), DownCause> {
    send_all_at(s, tx, values, monotonic_ns())
}

/// Encode and send every message of `tx` from `values`, at `now` on the sender's clock (each
/// message at its DBC cycle time on that clock).
fn send_all_at<V: SignalValues>(
    s: &Session<'_>,
    tx: &mut FrameEncoder,
    values: &V,
    now: u64,
) -> Result<(), DownCause> {
    for i in 0..tx.len() {
        if !tx.is_due(i, now) {
            CanCounters::inc(&s.counters.tx_not_due);
            continue;
        }
        match tx.encode(i, values, now) {
            Some(frame) => s.send(&frame)?,
            None => CanCounters::inc(&s.counters.tx_unchanged),
        }
    }
    Ok(())
}

struct PlantRole {
    rx: RxHandler,
    tx: FrameEncoder,
    snapshots: Arc<SnapshotBoard>,
    wake: AsyncFd<WakeFd>,
}

impl Role for PlantRole {
    fn reset(&mut self) {
        self.rx.reset_alive();
    }

    async fn session(
        &mut self,
        s: &Session<'_>,
        shutdown: &mut watch::Receiver<bool>,
    ) -> SessionEnd {
        let PlantRole {
            rx,
            tx,
            snapshots,
            wake,
        } = self;
        let send = plant_send_loop(s, tx, snapshots, wake);
        run_halves(s.receive_loop(rx), send, shutdown).await
    }
}

/// Plant TX: sensor frames from the latest snapshot on every wakeup, on the plant's own clock
/// (the snapshot's sampling time): a message goes out at its DBC cycle time of *plant* time,
/// and its alive counter counts those cycle times (`counting_sample_periods`), so that a
/// receiver timing samples by the counter (`SenderClock`) sees the plant's time even when the
/// plant's host stopped it or this task ran late. (On the wall clock, the first step after a
/// stop was sent and the next one, 0.3 ms later, was "not due": two plant steps under one
/// counter step, and the drive-torque law surged in the HIL `plant_pause` case.)
async fn plant_send_loop(
    s: &Session<'_>,
    tx: &mut FrameEncoder,
    snapshots: &SnapshotBoard,
    wake: &AsyncFd<WakeFd>,
) -> Result<Infallible, DownCause> {
    loop {
        wait_wake(wake)
            .await
            .map_err(|e| DownCause::io(IoOp::Wakeup, &e))?;
        if let Some((snapshot, _cycle, sampled_ns)) = snapshots.latest() {
            send_all_at(s, tx, &snapshot, sampled_ns)?;
        }
    }
}

/// Drive the receive and send halves of a session concurrently (same task) until one fails or
/// shutdown is requested.
///
/// Polled in a fixed order: shutdown, send, receive. Under a frame flood the receive half
/// spends the task's whole tokio co-operative budget (and then yields); polling the send half
/// first keeps the actuator frames and the heartbeat going out regardless.
async fn run_halves(
    receive: impl std::future::Future<Output = Result<Infallible, DownCause>>,
    send: impl std::future::Future<Output = Result<Infallible, DownCause>>,
    shutdown: &mut watch::Receiver<bool>,
) -> SessionEnd {
    tokio::select! {
        biased;
        _ = shutdown_requested(shutdown) => SessionEnd::Shutdown,
        r = send => match r {
            Err(cause) => SessionEnd::Failed(cause),
            Ok(never) => match never {},
        },
        r = receive => match r {
            Err(cause) => SessionEnd::Failed(cause),
            Ok(never) => match never {},
        },
    }
}

/// Open the socket and read the controller state. A controller still in bus-off (no
/// automatic restart, or not restarted yet) counts as a failed open, so the task keeps
/// backing off instead of reporting a link that cannot carry frames.
fn open_link(interface: &str) -> Result<(CanLink, BusState), DownCause> {
    let link = CanLink::open(interface).map_err(|e| DownCause::io(IoOp::Open, &e))?;
    match link::controller_state(interface) {
        Some(CanState::BusOff) => Err(DownCause::BusOff),
        Some(CanState::ErrorPassive) => Ok((link, BusState::Degraded(CanTrouble::ErrorPassive))),
        Some(CanState::ErrorWarning) => Ok((link, BusState::Degraded(CanTrouble::ErrorWarning))),
        _ => Ok((link, BusState::Up)),
    }
}

/// Open, run, and on failure close and reopen after a backoff, until shutdown.
async fn run_link<R: Role>(cfg: &CanBusConfig, role: &mut R, handles: BusHandles) {
    let BusHandles {
        counters,
        state,
        on_change,
        mut shutdown,
    } = handles;
    let report = Reporter {
        interface: &cfg.interface,
        state: &state,
        hook: on_change.as_ref(),
        counters: &counters,
    };
    let mut backoff = crate::io::link::Backoff::new(
        Duration::from_millis(cfg.reconnect_backoff_initial_ms),
        Duration::from_millis(cfg.reconnect_backoff_max_ms),
    );
    let mut opened_before = false;
    let mut attempt: u32 = 0;
    while !shutdown_now(&shutdown) {
        let cause = match open_link(&cfg.interface) {
            Ok((link, initial)) => {
                if opened_before {
                    CanCounters::inc(&counters.reconnects);
                }
                opened_before = true;
                attempt = 0;
                role.reset();
                report.set(initial);
                let session = Session {
                    link: &link,
                    report: &report,
                    counters: &counters,
                    carried: AtomicBool::new(false),
                };
                let end = role.session(&session, &mut shutdown).await;
                if session.carried.load(Ordering::Relaxed) {
                    backoff.reset();
                }
                drop(link);
                match end {
                    SessionEnd::Shutdown => break,
                    SessionEnd::Failed(cause) => {
                        CanCounters::inc(&counters.link_down);
                        if cause == DownCause::BusOff {
                            CanCounters::inc(&counters.bus_off);
                        }
                        cause
                    }
                }
            }
            Err(cause) => {
                CanCounters::inc(&counters.open_failures);
                cause
            }
        };
        if attempt == 0 {
            // First failure since the link was up (or since start); later failed reopen
            // attempts only update the attempt and its backoff.
            report.set(BusState::down(cause));
        }
        let delay = backoff.next_delay();
        attempt = attempt.saturating_add(1);
        report.set(BusState::Down {
            attempt,
            backoff_ms: u64::try_from(delay.as_millis()).unwrap_or(u64::MAX),
            cause,
        });
        tokio::select! {
            _ = tokio::time::sleep(delay) => {}
            _ = shutdown_requested(&mut shutdown) => break,
        }
    }
    report.set(BusState::Stopped);
}

#[cfg(test)]
mod tests;
