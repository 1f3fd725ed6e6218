//! Sensor/actuator values ↔ CAN frames, through bindings to DBC signals.
//!
//! [`CanCodec::new`] turns a [`CanDatabase`] and a list of [`SignalBinding`]s into flat
//! tables (this allocates, once, at start-up). After that, [`CanCodec::decode`] and
//! [`CanCodec::encode`] do not allocate and never panic: unknown ids, wrong lengths and bad
//! CRCs come back as [`FrameError`]s for the runtime to count.
//!
//! Typical controller loop:
//!
//! ```no_run
//! # use antisurge::io::can::*;
//! # use antisurge::vocab::signals::*;
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let db = CanDatabase::from_file("config/skid.dbc")?;
//! let codec = CanCodec::new(&db, &skid_bindings())?;
//! let mut checkers = codec.alive_checkers();
//! let mut counters = codec.alive_counters();
//! let mut snapshot = SensorSnapshot::default();
//! # let (id, data) = (FrameId::Standard(0x100), [0u8; 8]);
//! // receive
//! match codec.decode(id, &data) {
//!     Ok(frame) => {
//!         let _status = checkers.check(&frame); // Some(AliveStatus::Skipped { .. }) → count
//!         frame.apply_to_sensors(&mut snapshot);
//!     }
//!     Err(_e) => { /* count unknown id / wrong DLC / bad CRC */ }
//! }
//! // send
//! let cmd1 = codec.message_index("CTRL_ActuatorCmd1").ok_or("no such message")?;
//! let commands = ActuatorCommands::default();
//! let frame = codec.encode(cmd1, &commands, counters.next_value(cmd1))?;
//! let _bytes = frame.payload(); // send with id frame.id
//! # Ok(()) }
//! ```

use std::fmt;

use serde::{Deserialize, Serialize};

use super::bits::{pack_value, unpack_value, EncodeStatus, SignalLayout, MAX_PAYLOAD};
use super::dbc::{CanDatabase, FrameId, SignalRole};
use super::e2e::{AliveChecker, AliveCounter, AliveStatus, FrameError, FrameGuard};
use crate::vocab::signals::{ActuatorCommands, ActuatorId, SensorId, SensorSnapshot};

/// The quantity a CAN signal carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SignalTarget {
    /// A measured value, SI units (see [`SensorId`]).
    Sensor(SensorId),
    /// A setpoint, SI units (see [`ActuatorId`]).
    Actuator(ActuatorId),
}

impl SignalTarget {
    /// Position of this target among all targets (sensors first, then actuators), below
    /// [`MAX_TARGETS`].
    pub const fn index(self) -> usize {
        match self {
            SignalTarget::Sensor(s) => s.index(),
            SignalTarget::Actuator(a) => SensorId::COUNT + a.index(),
        }
    }

    /// Bit of this target in a [`TargetSet`].
    const fn bit(self) -> u16 {
        match self {
            SignalTarget::Sensor(s) => 1 << s.index(),
            SignalTarget::Actuator(a) => 1 << (SensorId::COUNT + a.index()),
        }
    }

    /// SI unit of the value.
    pub const fn unit(self) -> &'static str {
        match self {
            SignalTarget::Sensor(s) => s.unit(),
            SignalTarget::Actuator(a) => a.unit(),
        }
    }
}

impl fmt::Display for SignalTarget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SignalTarget::Sensor(s) => write!(f, "sensor {}", s.name()),
            SignalTarget::Actuator(a) => write!(f, "actuator {}", a.name()),
        }
    }
}

/// Most values one frame can deliver: every target at most once.
pub const MAX_TARGETS: usize = SensorId::COUNT + ActuatorId::COUNT;
const _: () = assert!(MAX_TARGETS <= 16, "TargetSet is a u16");

/// A set of [`SignalTarget`]s (no allocation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub struct TargetSet(u16);

impl TargetSet {
    /// Whether `t` is in the set.
    pub const fn contains(self, t: SignalTarget) -> bool {
        self.0 & t.bit() != 0
    }
    /// Whether the set is empty.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
    /// Number of members.
    pub const fn len(self) -> usize {
        self.0.count_ones() as usize
    }
    /// Add `t`.
    pub fn insert(&mut self, t: SignalTarget) {
        self.0 |= t.bit();
    }
    /// Members: sensors in [`SensorId::ALL`] order, then actuators.
    pub fn iter(self) -> impl Iterator<Item = SignalTarget> {
        SensorId::ALL
            .into_iter()
            .map(SignalTarget::Sensor)
            .chain(ActuatorId::ALL.into_iter().map(SignalTarget::Actuator))
            .filter(move |t| self.contains(*t))
    }
}

/// Binds one sensor or actuator to one DBC signal.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct SignalBinding {
    /// The sensor or actuator.
    pub target: SignalTarget,
    /// DBC message name.
    pub message: String,
    /// DBC signal name within the message.
    pub signal: String,
}

impl SignalBinding {
    /// Bind a sensor to `message.signal`.
    pub fn sensor(id: SensorId, message: &str, signal: &str) -> SignalBinding {
        SignalBinding {
            target: SignalTarget::Sensor(id),
            message: message.to_string(),
            signal: signal.to_string(),
        }
    }
    /// Bind an actuator to `message.signal`.
    pub fn actuator(id: ActuatorId, message: &str, signal: &str) -> SignalBinding {
        SignalBinding {
            target: SignalTarget::Actuator(id),
            message: message.to_string(),
            signal: signal.to_string(),
        }
    }
}

/// The bindings for `config/skid.dbc`: every sensor and actuator.
pub fn skid_bindings() -> Vec<SignalBinding> {
    use ActuatorId as A;
    use SensorId as S;
    vec![
        SignalBinding::sensor(S::PSuction, "PLANT_Pressures", "PSuction"),
        SignalBinding::sensor(S::PDischarge, "PLANT_Pressures", "PDischarge"),
        SignalBinding::sensor(S::ShaftSpeed, "PLANT_SpeedFlowTemp", "ShaftSpeed"),
        SignalBinding::sensor(S::OrificeDp, "PLANT_SpeedFlowTemp", "OrificeDp"),
        SignalBinding::sensor(S::TSuction, "PLANT_SpeedFlowTemp", "TSuction"),
        SignalBinding::sensor(
            S::RecycleValvePosition,
            "PLANT_Positions",
            "RecycleValvePosition",
        ),
        SignalBinding::sensor(S::ThrottlePosition, "PLANT_Positions", "ThrottlePosition"),
        SignalBinding::sensor(S::ThrustPosition, "PLANT_Positions", "ThrustPosition"),
        SignalBinding::sensor(S::DriveTorque, "PLANT_Drive", "DriveTorque"),
        SignalBinding::actuator(A::DriveTorque, "CTRL_ActuatorCmd1", "DriveTorqueCmd"),
        SignalBinding::actuator(A::RecycleValve, "CTRL_ActuatorCmd1", "RecycleValveCmd"),
        SignalBinding::actuator(A::Throttle, "CTRL_ActuatorCmd1", "ThrottleCmd"),
        SignalBinding::actuator(
            A::CloseCoupledValve,
            "CTRL_ActuatorCmd2",
            "CloseCoupledValveCmd",
        ),
        SignalBinding::actuator(A::TipClearance, "CTRL_ActuatorCmd2", "TipClearanceCmd"),
    ]
}

/// A binding list that does not fit the database.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BindingError {
    /// The message does not exist.
    #[error("{target}: the DBC has no message {message}")]
    UnknownMessage {
        /// Bound target.
        target: SignalTarget,
        /// Message name in the binding.
        message: String,
    },
    /// The signal does not exist in the message.
    #[error("{target}: message {message} has no signal {signal}")]
    UnknownSignal {
        /// Bound target.
        target: SignalTarget,
        /// Message name.
        message: String,
        /// Signal name in the binding.
        signal: String,
    },
    /// A target bound to two signals.
    #[error("{target} is bound twice: to {first} and to {second}")]
    DuplicateTarget {
        /// Bound target.
        target: SignalTarget,
        /// First `message.signal`.
        first: String,
        /// Second `message.signal`.
        second: String,
    },
    /// A signal bound to two targets.
    #[error("signal {signal} is bound to both {first} and {second}")]
    SignalBoundTwice {
        /// `message.signal`.
        signal: String,
        /// First target.
        first: SignalTarget,
        /// Second target.
        second: SignalTarget,
    },
    /// A target bound to an alive counter or CRC.
    #[error("{target}: {message}.{signal} is the message's {role}, not a data signal")]
    ProtectionSignal {
        /// Bound target.
        target: SignalTarget,
        /// Message name.
        message: String,
        /// Signal name.
        signal: String,
        /// Its role.
        role: SignalRole,
    },
    /// The signal's unit (DBC) does not measure what the target is, or is unknown.
    #[error("{target}: signal {message}.{signal}: {reason}")]
    Unit {
        /// Bound target.
        target: SignalTarget,
        /// Message name.
        message: String,
        /// Signal name.
        signal: String,
        /// Why (the unit and the quantities).
        reason: String,
    },
    /// A signal unfit for a fixed-purpose codec (e.g. the heartbeat).
    #[error("message {message}, signal {signal}: {reason}")]
    Unfit {
        /// Message name.
        message: String,
        /// Signal name (empty when the message itself is missing).
        signal: String,
        /// Why.
        reason: String,
    },
}

/// Index of a message in a [`CanCodec`] (from [`CanCodec::message_index`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct MessageIndex(u16);

impl MessageIndex {
    /// Position in [`CanCodec`]'s message list (= file order of the DBC).
    pub const fn get(self) -> usize {
        self.0 as usize
    }
}

/// Values for [`CanCodec::encode`], looked up by target (NaN: no value).
pub trait SignalValues {
    /// Value of `target` in SI units, NaN if absent.
    fn value(&self, target: SignalTarget) -> f64;
}

impl SignalValues for SensorSnapshot {
    fn value(&self, target: SignalTarget) -> f64 {
        match target {
            SignalTarget::Sensor(s) => self.get(s),
            SignalTarget::Actuator(_) => f64::NAN,
        }
    }
}

impl SignalValues for ActuatorCommands {
    fn value(&self, target: SignalTarget) -> f64 {
        match target {
            SignalTarget::Actuator(a) => self.get(a),
            SignalTarget::Sensor(_) => f64::NAN,
        }
    }
}

impl SignalValues for (SensorSnapshot, ActuatorCommands) {
    fn value(&self, target: SignalTarget) -> f64 {
        match target {
            SignalTarget::Sensor(s) => self.0.get(s),
            SignalTarget::Actuator(a) => self.1.get(a),
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct BoundSignal {
    target: SignalTarget,
    layout: SignalLayout,
    factor: f64,
    offset: f64,
}

#[derive(Debug, Clone)]
struct CodecMessage {
    name: String,
    guard: FrameGuard,
    /// DBC `GenMsgCycleTime`, ms (`None` or 0: event-driven).
    cycle_time_ms: Option<u32>,
    bound: Vec<BoundSignal>,
    /// Data signals of the message that no binding uses (name, layout, DBC start value).
    unbound: Vec<(String, SignalLayout, Option<i128>)>,
}

/// Precomputed tables for decoding and encoding every message of a database.
#[derive(Debug, Clone)]
pub struct CanCodec {
    messages: Vec<CodecMessage>,
    /// (id, index), sorted by id for binary search.
    by_id: Vec<(FrameId, MessageIndex)>,
    /// The database declares a J1939 network ([`CanDatabase::declares_j1939`]).
    j1939: bool,
}

/// The values one received frame delivered (fixed capacity, no heap).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decoded {
    message: MessageIndex,
    id: FrameId,
    alive: Option<u8>,
    len: u8,
    values: [(SignalTarget, f64); MAX_TARGETS],
}

impl Decoded {
    fn new(message: MessageIndex, id: FrameId, alive: Option<u8>) -> Decoded {
        Decoded {
            message,
            id,
            alive,
            len: 0,
            values: [(SignalTarget::Sensor(SensorId::PSuction), f64::NAN); MAX_TARGETS],
        }
    }
    fn push(&mut self, target: SignalTarget, value: f64) {
        if let Some(slot) = self.values.get_mut(usize::from(self.len)) {
            *slot = (target, value);
            self.len += 1;
        }
    }
    /// Which message the frame was.
    pub fn message(&self) -> MessageIndex {
        self.message
    }
    /// Identifier of the frame.
    pub fn id(&self) -> FrameId {
        self.id
    }
    /// Alive counter in the frame, if the message has one.
    pub fn alive(&self) -> Option<u8> {
        self.alive
    }
    /// (target, SI value) for every bound signal of the message.
    pub fn values(&self) -> &[(SignalTarget, f64)] {
        self.values.get(..usize::from(self.len)).unwrap_or(&[])
    }
    /// Value of one target, if this frame carried it.
    pub fn get(&self, target: SignalTarget) -> Option<f64> {
        self.values()
            .iter()
            .find(|(t, _)| *t == target)
            .map(|(_, v)| *v)
    }
    /// Store the sensor values in `snapshot`; returns how many were stored.
    pub fn apply_to_sensors(&self, snapshot: &mut SensorSnapshot) -> usize {
        let mut n = 0;
        for (t, v) in self.values() {
            if let SignalTarget::Sensor(s) = t {
                snapshot.set(*s, *v);
                n += 1;
            }
        }
        n
    }
    /// Store the actuator values in `commands`; returns how many were stored.
    pub fn apply_to_actuators(&self, commands: &mut ActuatorCommands) -> usize {
        let mut n = 0;
        for (t, v) in self.values() {
            if let SignalTarget::Actuator(a) = t {
                commands.set(*a, *v);
                n += 1;
            }
        }
        n
    }
}

/// What encoding did with the values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub struct EncodeReport {
    /// Targets whose value was outside the signal's raw range and was clamped.
    pub clamped: TargetSet,
    /// Targets whose value was NaN: sent as "not available".
    pub not_a_number: TargetSet,
}

impl EncodeReport {
    /// Whether every value was written unchanged.
    pub fn is_clean(&self) -> bool {
        self.clamped.is_empty() && self.not_a_number.is_empty()
    }
}

/// An encoded frame, ready to send.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Encoded {
    /// Identifier.
    pub id: FrameId,
    /// Payload length, bytes.
    pub dlc: u8,
    /// Payload, zero beyond `dlc`.
    pub data: [u8; MAX_PAYLOAD],
    /// Clamped and NaN values.
    pub report: EncodeReport,
}

impl Encoded {
    /// The `dlc` payload bytes.
    pub fn payload(&self) -> &[u8] {
        self.data.get(..usize::from(self.dlc)).unwrap_or(&self.data)
    }
}

/// Encoding asked for a message the codec does not have.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("no message #{} in this codec", .0.get())]
pub struct NoSuchMessage(pub MessageIndex);

impl CanCodec {
    /// Build the tables. Every message of `db` is known to the codec (so its frames are
    /// checked and recognised); `bindings` say which signals carry which values.
    pub fn new(db: &CanDatabase, bindings: &[SignalBinding]) -> Result<CanCodec, BindingError> {
        let mut messages: Vec<CodecMessage> = db
            .messages()
            .iter()
            .map(|m| CodecMessage {
                name: m.name().to_string(),
                guard: m.guard(),
                cycle_time_ms: m.cycle_time_ms(),
                bound: Vec::new(),
                unbound: Vec::new(),
            })
            .collect();
        let mut seen: Vec<(SignalTarget, String)> = Vec::new();
        for b in bindings {
            let (mi, m) = db
                .messages()
                .iter()
                .enumerate()
                .find(|(_, m)| m.name() == b.message)
                .ok_or_else(|| BindingError::UnknownMessage {
                    target: b.target,
                    message: b.message.clone(),
                })?;
            let s = m
                .signal(&b.signal)
                .ok_or_else(|| BindingError::UnknownSignal {
                    target: b.target,
                    message: b.message.clone(),
                    signal: b.signal.clone(),
                })?;
            if s.role() != SignalRole::Data {
                return Err(BindingError::ProtectionSignal {
                    target: b.target,
                    message: b.message.clone(),
                    signal: b.signal.clone(),
                    role: s.role(),
                });
            }
            let path = format!("{}.{}", b.message, b.signal);
            if let Some((_, first)) = seen.iter().find(|(t, _)| *t == b.target) {
                return Err(BindingError::DuplicateTarget {
                    target: b.target,
                    first: first.clone(),
                    second: path,
                });
            }
            if let Some((first, _)) = seen.iter().find(|(_, p)| *p == path) {
                return Err(BindingError::SignalBoundTwice {
                    signal: path,
                    first: *first,
                    second: b.target,
                });
            }
            seen.push((b.target, path));
            // The DBC's unit, checked against the target's quantity and folded into factor
            // and offset so that the decoded value is SI (e.g. % → fraction: × 0.01).
            let quantity = match b.target {
                SignalTarget::Sensor(id) => crate::io::units::Quantity::of_sensor(id),
                SignalTarget::Actuator(id) => crate::io::units::Quantity::of_actuator(id),
            };
            let unit =
                crate::io::units::resolve(s.unit(), quantity).map_err(|e| BindingError::Unit {
                    target: b.target,
                    message: b.message.clone(),
                    signal: b.signal.clone(),
                    reason: e.to_string(),
                })?;
            if let Some(cm) = messages.get_mut(mi) {
                cm.bound.push(BoundSignal {
                    target: b.target,
                    layout: *s.layout(),
                    factor: s.factor() * unit.factor,
                    offset: s.offset() * unit.factor + unit.offset,
                });
            }
        }
        for (cm, m) in messages.iter_mut().zip(db.messages()) {
            cm.unbound = m
                .signals()
                .iter()
                .filter(|s| s.role() == SignalRole::Data)
                .filter(|s| {
                    !bindings
                        .iter()
                        .any(|b| b.message == cm.name && b.signal == s.name())
                })
                .map(|s| (s.name().to_string(), *s.layout(), s.start_raw()))
                .collect();
        }
        let mut by_id: Vec<(FrameId, MessageIndex)> = messages
            .iter()
            .enumerate()
            .map(|(i, m)| (m.guard.id(), MessageIndex(i as u16)))
            .collect();
        by_id.sort_unstable();
        Ok(CanCodec {
            messages,
            by_id,
            j1939: db.declares_j1939(),
        })
    }

    /// Index of a message by name (start-up use).
    pub fn message_index(&self, name: &str) -> Option<MessageIndex> {
        self.messages
            .iter()
            .position(|m| m.name == name)
            .map(|i| MessageIndex(i as u16))
    }

    /// Index of the message with identifier `id`.
    #[inline]
    pub fn message_for_id(&self, id: FrameId) -> Option<MessageIndex> {
        self.by_id
            .binary_search_by(|(k, _)| k.cmp(&id))
            .ok()
            .and_then(|i| self.by_id.get(i))
            .map(|(_, m)| *m)
    }

    /// Number of messages.
    pub fn len(&self) -> usize {
        self.messages.len()
    }

    /// Whether the codec has no messages.
    pub fn is_empty(&self) -> bool {
        self.messages.is_empty()
    }

    /// Name of a message.
    pub fn message_name(&self, message: MessageIndex) -> Option<&str> {
        self.messages.get(message.get()).map(|m| m.name.as_str())
    }

    /// The message's cycle time from the DBC (`GenMsgCycleTime`), ms; `None` for an
    /// event-driven message (no attribute, or 0).
    pub fn cycle_time_ms(&self, message: MessageIndex) -> Option<u32> {
        self.messages
            .get(message.get())
            .and_then(|m| m.cycle_time_ms)
            .filter(|&ms| ms > 0)
    }

    /// Whether the database declares a J1939 network ([`CanDatabase::declares_j1939`]).
    pub fn declares_j1939(&self) -> bool {
        self.j1939
    }

    /// Data signals of a message that no binding uses (name, layout, DBC start value): the
    /// sender fills them with "not available" or the start value, or refuses them (see
    /// `bus.can.not_available`).
    pub fn unbound_signals(
        &self,
        message: MessageIndex,
    ) -> &[(String, SignalLayout, Option<i128>)] {
        self.messages
            .get(message.get())
            .map_or(&[], |m| m.unbound.as_slice())
    }

    /// DLC / alive / CRC handling of a message (identifier: `guard.id()`).
    pub fn guard(&self, message: MessageIndex) -> Option<&FrameGuard> {
        self.messages.get(message.get()).map(|m| &m.guard)
    }

    /// Targets bound to signals of a message.
    pub fn targets(&self, message: MessageIndex) -> TargetSet {
        let mut set = TargetSet::default();
        if let Some(m) = self.messages.get(message.get()) {
            for b in &m.bound {
                set.insert(b.target);
            }
        }
        set
    }

    /// Messages carrying at least one actuator (the ones a controller sends).
    pub fn actuator_messages(&self) -> impl Iterator<Item = MessageIndex> + '_ {
        self.messages_where(|t| matches!(t, SignalTarget::Actuator(_)))
    }

    /// Messages carrying at least one sensor (the ones a plant node sends).
    pub fn sensor_messages(&self) -> impl Iterator<Item = MessageIndex> + '_ {
        self.messages_where(|t| matches!(t, SignalTarget::Sensor(_)))
    }

    fn messages_where(
        &self,
        pred: fn(&SignalTarget) -> bool,
    ) -> impl Iterator<Item = MessageIndex> + '_ {
        self.messages
            .iter()
            .enumerate()
            .filter(move |(_, m)| m.bound.iter().any(|b| pred(&b.target)))
            .map(|(i, _)| MessageIndex(i as u16))
    }

    /// Decode a received frame: check its length and CRC, then return the SI value of every
    /// bound signal and the alive counter. No allocation.
    #[inline]
    pub fn decode(&self, id: FrameId, data: &[u8]) -> Result<Decoded, FrameError> {
        let index = self
            .message_for_id(id)
            .ok_or(FrameError::UnknownId { id })?;
        let m = self
            .messages
            .get(index.get())
            .ok_or(FrameError::UnknownId { id })?;
        let frame = m.guard.check(data)?;
        let mut out = Decoded::new(index, id, m.guard.alive(&frame));
        for b in &m.bound {
            out.push(
                b.target,
                unpack_value(&frame, &b.layout, b.factor, b.offset),
            );
        }
        Ok(out)
    }

    /// Encode a message into a zeroed payload: every bound signal from `values`, then the
    /// alive counter `alive` (modulo 2^bits) and the CRC. NaN values are sent as "not
    /// available" (all ones, or the most negative raw value of a signed signal).
    #[inline]
    pub fn encode<V: SignalValues + ?Sized>(
        &self,
        message: MessageIndex,
        values: &V,
        alive: u8,
    ) -> Result<Encoded, NoSuchMessage> {
        let mut data = [0u8; MAX_PAYLOAD];
        let report = self.encode_into(message, values, alive, &mut data)?;
        let guard = self.guard(message).ok_or(NoSuchMessage(message))?;
        Ok(Encoded {
            id: guard.id(),
            dlc: guard.dlc(),
            data,
            report,
        })
    }

    /// Like [`CanCodec::encode`] but over an existing payload (unbound bits keep theirs).
    #[inline]
    pub fn encode_into<V: SignalValues + ?Sized>(
        &self,
        message: MessageIndex,
        values: &V,
        alive: u8,
        data: &mut [u8; MAX_PAYLOAD],
    ) -> Result<EncodeReport, NoSuchMessage> {
        let m = self
            .messages
            .get(message.get())
            .ok_or(NoSuchMessage(message))?;
        let mut report = EncodeReport::default();
        for b in &m.bound {
            let v = values.value(b.target);
            match pack_value(data, &b.layout, b.factor, b.offset, v) {
                EncodeStatus::InRange => {}
                EncodeStatus::Clamped => report.clamped.insert(b.target),
                EncodeStatus::NotANumber => report.not_a_number.insert(b.target),
            }
        }
        m.guard.seal(data, alive);
        Ok(report)
    }

    /// One sending alive counter per message (for [`CanCodec::encode`]).
    pub fn alive_counters(&self) -> AliveCounters {
        AliveCounters(
            self.messages
                .iter()
                .map(|m| m.guard.alive_bits().map(AliveCounter::new))
                .collect(),
        )
    }

    /// One sender clock per message that has both an alive counter and a DBC cycle time
    /// (None for the others), indexed by [`MessageIndex::get`]
    /// ([`SenderClock`](crate::io::can::bus::SenderClock)).
    pub fn sender_clocks(&self) -> Vec<Option<crate::io::can::bus::SenderClock>> {
        self.messages
            .iter()
            .map(|m| match (m.guard.alive_bits(), m.cycle_time_ms) {
                (Some(bits), Some(ms)) if ms > 0 => Some(crate::io::can::bus::SenderClock::new(
                    u64::from(ms) * 1_000_000,
                    1u64 << bits.clamp(1, 8),
                )),
                _ => None,
            })
            .collect()
    }

    /// One receiving alive checker per message (for [`Decoded`]).
    pub fn alive_checkers(&self) -> AliveCheckers {
        AliveCheckers(
            self.messages
                .iter()
                .map(|m| m.guard.alive_bits().map(AliveChecker::new))
                .collect(),
        )
    }
}

/// Sending alive counters, one per message of a [`CanCodec`].
#[derive(Debug, Clone)]
pub struct AliveCounters(Vec<Option<AliveCounter>>);

impl AliveCounters {
    /// The counter value for the next frame of `message` (0 if it has no counter); advances.
    #[inline]
    pub fn next_value(&mut self, message: MessageIndex) -> u8 {
        match self.0.get_mut(message.get()) {
            Some(Some(c)) => c.next_value(),
            _ => 0,
        }
    }
}

/// Receiving alive checkers, one per message of a [`CanCodec`].
#[derive(Debug, Clone)]
pub struct AliveCheckers(Vec<Option<AliveChecker>>);

impl AliveCheckers {
    /// Check the counter of a decoded frame (`None`: the message has no counter).
    #[inline]
    pub fn check(&mut self, frame: &Decoded) -> Option<AliveStatus> {
        let value = frame.alive()?;
        match self.0.get_mut(frame.message().get()) {
            Some(Some(c)) => Some(c.check(value)),
            _ => None,
        }
    }
    /// Forget the last counter of a message (e.g. after a timeout).
    pub fn reset(&mut self, message: MessageIndex) {
        if let Some(Some(c)) = self.0.get_mut(message.get()) {
            c.reset();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::can::e2e::frame_crc;

    fn skid() -> CanDatabase {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/skid.dbc");
        CanDatabase::from_file(path).expect("config/skid.dbc")
    }

    fn codec() -> CanCodec {
        CanCodec::new(&skid(), &skid_bindings()).expect("skid bindings fit skid.dbc")
    }

    fn idx(c: &CanCodec, name: &str) -> MessageIndex {
        c.message_index(name).expect("message exists")
    }

    #[test]
    fn every_target_is_bound_once() {
        let c = codec();
        let mut all = TargetSet::default();
        for i in 0..c.len() {
            let t = c.targets(MessageIndex(i as u16));
            assert!(all.0 & t.0 == 0);
            all.0 |= t.0;
        }
        // every target but the ESD contact, which the shipped DBC does not carry (a
        // hard-wired contact, e.g. a Modbus discrete input)
        let contacts = SensorId::ALL.iter().filter(|s| s.is_contact()).count();
        assert_eq!(all.len(), MAX_TARGETS - contacts);
        let sending: Vec<&str> = c
            .actuator_messages()
            .filter_map(|m| c.message_name(m))
            .collect();
        assert_eq!(sending, ["CTRL_ActuatorCmd1", "CTRL_ActuatorCmd2"]);
        assert_eq!(c.sensor_messages().count(), 4);
    }

    #[test]
    fn encode_actuator_frame_bit_exact() {
        let c = codec();
        let m = idx(&c, "CTRL_ActuatorCmd1");
        let mut cmd = ActuatorCommands::default();
        cmd.set(ActuatorId::DriveTorque, -1.5); // raw -3 = 0x3FFFD, bits 0..17
        cmd.set(ActuatorId::RecycleValve, 0.5); // raw 5000 = 0x1388, bits 18..31
        cmd.set(ActuatorId::Throttle, 1.0); // raw 10000 = 0x2710, bits 32..45
        let f = c.encode(m, &cmd, 0x13).expect("encode");
        assert_eq!(f.id, FrameId::Standard(0xA0));
        assert!(f.report.is_clean());
        // byte 0 = 0xFD, byte 1 = 0xFF, byte 2 = 0b11 | (0x1388 & 0x3F) << 2 = 0x03 | 0x20 = 0x23,
        // byte 3 = 0x1388 >> 6 = 0x4E; bytes 4..5 = 0x2710 (14 bits); byte 6 = counter 3.
        assert_eq!(&f.data[..7], &[0xFD, 0xFF, 0x23, 0x4E, 0x10, 0x27, 0x03]);
        assert_eq!(f.data[7], frame_crc(f.id, &f.data, 7));

        let d = c.decode(f.id, f.payload()).expect("decode own frame");
        assert_eq!(d.message(), m);
        assert_eq!(d.alive(), Some(3));
        assert_eq!(
            d.get(SignalTarget::Actuator(ActuatorId::DriveTorque)),
            Some(-1.5)
        );
        assert_eq!(
            d.get(SignalTarget::Actuator(ActuatorId::RecycleValve)),
            Some(0.5)
        );
        let mut back = ActuatorCommands::default();
        assert_eq!(d.apply_to_actuators(&mut back), 3);
        assert_eq!(back.get(ActuatorId::Throttle), 1.0);
        assert!(back.get(ActuatorId::TipClearance).is_nan());
    }

    #[test]
    fn decode_sensor_frame_bit_exact() {
        let c = codec();
        // PLANT_Pressures: PSuction 101325 Pa = 0x01_8B_CD big-endian in bytes 0..2,
        // PDischarge 350000 Pa = 0x05_57_30 in bytes 3..5, counter 7.
        let mut data = [0x01, 0x8B, 0xCD, 0x05, 0x57, 0x30, 0x07, 0x00];
        data[7] = frame_crc(FrameId::Standard(0x100), &data, 7);
        let d = c.decode(FrameId::Standard(0x100), &data).expect("valid");
        let mut snap = SensorSnapshot::default();
        assert_eq!(d.apply_to_sensors(&mut snap), 2);
        assert_eq!(snap.get(SensorId::PSuction), 101_325.0);
        assert_eq!(snap.get(SensorId::PDischarge), 350_000.0);
        assert_eq!(d.alive(), Some(7));
        assert!(snap.get(SensorId::ShaftSpeed).is_nan());
    }

    #[test]
    fn motorola_signed_thrust_position() {
        let c = codec();
        let m = idx(&c, "PLANT_Positions");
        let mut s = SensorSnapshot::default();
        s.set(SensorId::ThrustPosition, -2e-8); // raw -2: bytes 0..2 = 03 FF FE
        s.set(SensorId::RecycleValvePosition, -0.1); // raw 0 (offset -0.1)
        s.set(SensorId::ThrottlePosition, 0.0); // raw 1000 = 0x3E8 at bits 38..51
        let f = c.encode(m, &s, 0).expect("encode");
        // 0x3E8 << 6 in bytes 4..6: bits 38,39 = 0b00 → byte 4 = 0x00;
        // byte 5 = (0x3E8 >> 2) & 0xFF = 0xFA; byte 6 low nibble = 0x3E8 >> 10 = 0.
        assert_eq!(&f.data[..7], &[0x03, 0xFF, 0xFE, 0x00, 0x00, 0xFA, 0x00]);
        let d = c.decode(f.id, f.payload()).expect("decode");
        let thrust = d.get(SignalTarget::Sensor(SensorId::ThrustPosition));
        assert_eq!(thrust, Some(-2e-8));
    }

    #[test]
    fn clamped_and_nan_reported() {
        let c = codec();
        let m = idx(&c, "CTRL_ActuatorCmd2");
        let mut cmd = ActuatorCommands::default();
        cmd.set(ActuatorId::CloseCoupledValve, 5.0); // above 3.2767
        let f = c.encode(m, &cmd, 0).expect("encode");
        assert!(f
            .report
            .clamped
            .contains(SignalTarget::Actuator(ActuatorId::CloseCoupledValve)));
        assert!(f
            .report
            .not_a_number
            .contains(SignalTarget::Actuator(ActuatorId::TipClearance)));
        assert_eq!(f.report.not_a_number.len(), 1);
        assert_eq!(&f.data[..2], &[0xFF, 0x7F], "clamped to raw 32767");

        // a NaN (not driven) signal goes out as "not available" and decodes as NaN, not as
        // the value it had before nor as zero; a value cannot produce that pattern
        let mut last = [0u8; 8];
        cmd.set(ActuatorId::TipClearance, 1e-4);
        c.encode_into(m, &cmd, 0, &mut last).expect("encode");
        let tip = SignalTarget::Actuator(ActuatorId::TipClearance);
        let before = c.decode(FrameId::Standard(0xA1), &last).expect("decode");
        assert!((before.get(tip).unwrap_or(f64::NAN) - 1e-4).abs() < 1e-12);
        cmd.set(ActuatorId::TipClearance, f64::NAN);
        cmd.set(ActuatorId::CloseCoupledValve, -0.25);
        let r = c.encode_into(m, &cmd, 1, &mut last).expect("encode");
        assert_eq!(r.not_a_number.len(), 1);
        let after = c.decode(FrameId::Standard(0xA1), &last).expect("decode");
        assert!(
            after.get(tip).is_some_and(f64::is_nan),
            "{:?}",
            after.get(tip)
        );
        // TipClearanceCmd: Motorola signed 18 bits from bit 17: raw −2^17 = 0b10_0000…0
        assert_eq!(&last[2..5], &[0b10, 0x00, 0x00], "{last:02x?}");
        cmd.set(ActuatorId::TipClearance, -1.0); // far below the range: clamped, still a number
        let r = c.encode_into(m, &cmd, 2, &mut last).expect("encode");
        assert!(r.clamped.contains(tip));
        let low = c.decode(FrameId::Standard(0xA1), &last).expect("decode");
        assert!((low.get(tip).unwrap_or(f64::NAN) + 0.00131071).abs() < 1e-12);
        assert_eq!(
            after.get(SignalTarget::Actuator(ActuatorId::CloseCoupledValve)),
            Some(-0.25)
        );
    }

    #[test]
    fn frame_errors_are_typed() {
        let c = codec();
        assert_eq!(
            c.decode(FrameId::Standard(0x7FF), &[0; 8]).unwrap_err(),
            FrameError::UnknownId {
                id: FrameId::Standard(0x7FF)
            }
        );
        // Same number, other id kind: unknown too.
        assert!(matches!(
            c.decode(FrameId::Extended(0x100), &[0; 8]),
            Err(FrameError::UnknownId { .. })
        ));
        let e = c.decode(FrameId::Standard(0x100), &[0; 5]).unwrap_err();
        assert_eq!(
            e,
            FrameError::WrongDlc {
                id: FrameId::Standard(0x100),
                expected: 8,
                actual: 5
            }
        );
        assert_eq!(e.to_string(), "CAN id 0x100: 5 data bytes, expected 8");
        let e = c.decode(FrameId::Standard(0x100), &[0; 8]).unwrap_err();
        assert!(matches!(e, FrameError::BadCrc { received: 0, .. }), "{e}");
        assert_eq!(
            c.encode(MessageIndex(99), &ActuatorCommands::default(), 0),
            Err(NoSuchMessage(MessageIndex(99)))
        );
    }

    #[test]
    fn counters_and_checkers_per_message() {
        let c = codec();
        let m = idx(&c, "PLANT_Pressures");
        let hb = idx(&c, "CTRL_Heartbeat");
        let mut tx = c.alive_counters();
        let mut rx = c.alive_checkers();
        let snap = SensorSnapshot::default();
        let mut statuses = Vec::new();
        for i in 0..20 {
            let f = c.encode(m, &snap, tx.next_value(m)).expect("encode");
            if i == 10 || i == 11 {
                continue; // two frames lost on the bus
            }
            let d = c.decode(f.id, f.payload()).expect("decode");
            statuses.push(rx.check(&d));
            if i == 15 {
                statuses.push(rx.check(&d)); // duplicated frame
            }
        }
        assert_eq!(statuses[0], Some(AliveStatus::First));
        assert_eq!(statuses[1], Some(AliveStatus::InSequence));
        assert_eq!(statuses[10], Some(AliveStatus::Skipped { missed: 2 }));
        assert_eq!(statuses[13], Some(AliveStatus::InSequence));
        assert_eq!(statuses[14], Some(AliveStatus::Repeated));
        assert_eq!(statuses.last(), Some(&Some(AliveStatus::InSequence)));
        // The heartbeat counter is independent and 8 bits wide.
        for _ in 0..200 {
            tx.next_value(hb);
        }
        assert_eq!(tx.next_value(hb), 200);
        assert_eq!(tx.next_value(m), 4, "20 % 16");
    }

    #[test]
    fn binding_errors_name_the_culprit() {
        let db = skid();
        let e = CanCodec::new(
            &db,
            &[SignalBinding::sensor(
                SensorId::PSuction,
                "Nope",
                "PSuction",
            )],
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "sensor p_suction: the DBC has no message Nope"
        );
        let e = CanCodec::new(
            &db,
            &[SignalBinding::sensor(
                SensorId::PSuction,
                "PLANT_Pressures",
                "Psuction",
            )],
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "sensor p_suction: message PLANT_Pressures has no signal Psuction"
        );
        let e = CanCodec::new(
            &db,
            &[
                SignalBinding::sensor(SensorId::PSuction, "PLANT_Pressures", "PSuction"),
                SignalBinding::sensor(SensorId::PSuction, "PLANT_Pressures", "PDischarge"),
            ],
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "sensor p_suction is bound twice: to PLANT_Pressures.PSuction and to PLANT_Pressures.PDischarge"
        );
        let e = CanCodec::new(
            &db,
            &[
                SignalBinding::sensor(SensorId::PSuction, "PLANT_Pressures", "PSuction"),
                SignalBinding::sensor(SensorId::PDischarge, "PLANT_Pressures", "PSuction"),
            ],
        )
        .unwrap_err();
        assert!(matches!(e, BindingError::SignalBoundTwice { .. }), "{e}");
        let e = CanCodec::new(
            &db,
            &[SignalBinding::sensor(
                SensorId::PSuction,
                "PLANT_Pressures",
                "Crc8",
            )],
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "sensor p_suction: PLANT_Pressures.Crc8 is the message's CRC byte, not a data signal"
        );
    }

    #[test]
    fn bindings_deserialize_from_toml() {
        #[derive(Deserialize)]
        struct Map {
            binding: Vec<SignalBinding>,
        }
        let text = r#"
            [[binding]]
            target = { sensor = "p_suction" }
            message = "PLANT_Pressures"
            signal = "PSuction"
            [[binding]]
            target = { actuator = "drive_torque" }
            message = "CTRL_ActuatorCmd1"
            signal = "DriveTorqueCmd"
        "#;
        let map: Map = toml::from_str(text).expect("toml");
        assert_eq!(
            map.binding,
            skid_bindings()[..1]
                .iter()
                .cloned()
                .chain(std::iter::once(SignalBinding::actuator(
                    ActuatorId::DriveTorque,
                    "CTRL_ActuatorCmd1",
                    "DriveTorqueCmd"
                )))
                .collect::<Vec<_>>()
        );
    }
}
