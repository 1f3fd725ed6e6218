//! CAN: DBC parsing and signal packing/unpacking.
//!
//! - [`bits`]: pure, allocation-free bit packing following the DBC rules (Intel and Motorola
//!   byte order, two's-complement sign extension, `physical = raw × factor + offset`).
//! - [`dbc`]: loading a DBC file into a validated [`CanDatabase`].
//! - [`e2e`]: end-to-end protection: DLC check, alive counters, CRC-8/SAE-J1850.
//! - [`codec`]: bindings of [`crate::vocab::signals::SensorId`] / [`crate::vocab::signals::ActuatorId`] to
//!   signals, and the allocation-free hot-path [`CanCodec::decode`] / [`CanCodec::encode`].
//! - [`heartbeat`]: the controller heartbeat frame.
//! - [`bus`]: the SocketCAN tasks of the controller and plant nodes (RX, TX, reconnect).
//!
//! Only classic CAN (payload ≤ 8 bytes) is supported. Outside [`bus`], a received
//! `socketcan::CanFrame` maps to `FrameId::from(frame.id())` and `frame.data()`; a frame to send
//! is `CanFrame::new(encoded.id.to_socketcan()?, encoded.payload())`.

pub mod bits;
pub mod bus;
pub mod busload;
pub mod codec;
pub mod dbc;
pub mod e2e;
pub mod heartbeat;

pub use bits::{ByteOrder, EncodeStatus, LayoutError, SignalLayout, MAX_PAYLOAD};
pub use codec::{
    skid_bindings, AliveCheckers, AliveCounters, BindingError, CanCodec, Decoded, EncodeReport,
    Encoded, MessageIndex, NoSuchMessage, SignalBinding, SignalTarget, SignalValues, TargetSet,
    MAX_TARGETS,
};
pub use dbc::{
    CanDatabase, DbcError, DbcErrorKind, FrameId, MessageDef, SignalDef, SignalRole,
    CYCLE_TIME_ATTRIBUTE, ROLE_ATTRIBUTE,
};
pub use e2e::{
    crc8_sae_j1850, frame_crc, AliveChecker, AliveCounter, AliveStatus, Crc8, FrameError,
    FrameGuard,
};
pub use heartbeat::{Heartbeat, HeartbeatCodec, HeartbeatConfig, HeartbeatNames};
