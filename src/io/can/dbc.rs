//! Loading a DBC file into a validated [`CanDatabase`].
//!
//! The text is parsed with the `can-dbc` crate, then checked for what the codec relies on:
//! classic CAN (DLC ≤ 8), unique ids and names, every signal inside the DLC, no two signals
//! sharing a bit, finite non-zero factors, no multiplexing, no float signals. Signals can carry
//! an end-to-end protection role through the signal attribute [`ROLE_ATTRIBUTE`]
//! (`"Data"`, `"AliveCounter"`, `"Crc8"`); see [`crate::io::can::e2e`].

use std::collections::HashMap;
use std::fmt;
use std::path::Path;

use can_dbc::{
    AttributeDefinition, AttributeValue, AttributeValueType, ByteOrder as DbcByteOrder, Comment,
    Dbc, MessageId, MultiplexIndicator, NumericValue, SignalExtendedValueType, ValueType,
};

use super::bits::{
    pack_physical, physical_to_raw, raw_to_physical, ByteOrder, EncodeStatus, LayoutError,
    SignalLayout, MAX_PAYLOAD,
};
use super::e2e::FrameGuard;

/// Name of the DBC signal attribute (`BA_DEF_ SG_ … ENUM "Data","AliveCounter","Crc8"`) that
/// marks alive counters and CRC bytes.
pub const ROLE_ATTRIBUTE: &str = "AntisurgeRole";

/// Name of the standard DBC signal attribute holding a signal's raw start value.
pub const START_VALUE_ATTRIBUTE: &str = "GenSigStartValue";

/// Name of the standard DBC database attribute naming the protocol (`"J1939"` on a J1939
/// network: there, all ones means "not available").
pub const PROTOCOL_ATTRIBUTE: &str = "ProtocolType";

/// Name of the standard DBC message attribute holding the cycle time, ms.
pub const CYCLE_TIME_ATTRIBUTE: &str = "GenMsgCycleTime";

/// A CAN identifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum FrameId {
    /// 11-bit identifier, 0..=0x7FF.
    Standard(u16),
    /// 29-bit identifier, 0..=0x1FFF_FFFF.
    Extended(u32),
}

impl FrameId {
    /// The identifier value without any flag bits.
    pub const fn raw(self) -> u32 {
        match self {
            FrameId::Standard(id) => id as u32,
            FrameId::Extended(id) => id,
        }
    }

    /// Whether this is a 29-bit identifier.
    pub const fn is_extended(self) -> bool {
        matches!(self, FrameId::Extended(_))
    }

    /// Whether the value fits its kind (11 or 29 bits).
    pub const fn is_valid(self) -> bool {
        match self {
            FrameId::Standard(id) => id <= 0x7FF,
            FrameId::Extended(id) => id <= 0x1FFF_FFFF,
        }
    }

    /// The socketcan / embedded-can identifier; `None` if the value does not fit its kind.
    pub fn to_socketcan(self) -> Option<socketcan::Id> {
        match self {
            FrameId::Standard(id) => socketcan::StandardId::new(id).map(socketcan::Id::Standard),
            FrameId::Extended(id) => socketcan::ExtendedId::new(id).map(socketcan::Id::Extended),
        }
    }
}

impl From<socketcan::Id> for FrameId {
    fn from(id: socketcan::Id) -> FrameId {
        match id {
            socketcan::Id::Standard(s) => FrameId::Standard(s.as_raw()),
            socketcan::Id::Extended(e) => FrameId::Extended(e.as_raw()),
        }
    }
}

impl fmt::Display for FrameId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FrameId::Standard(id) => write!(f, "0x{id:03X}"),
            FrameId::Extended(id) => write!(f, "0x{id:08X} (extended)"),
        }
    }
}

/// What a signal is for, from the [`ROLE_ATTRIBUTE`] attribute.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SignalRole {
    /// An ordinary value.
    Data,
    /// Alive counter: +1 per transmitted frame, modulo 2^size (unsigned, ≤ 8 bits, factor 1).
    AliveCounter,
    /// CRC-8/SAE-J1850 byte over id and payload (8 bits, byte-aligned, factor 1).
    Crc8,
}

impl fmt::Display for SignalRole {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SignalRole::Data => "data signal",
            SignalRole::AliveCounter => "alive counter",
            SignalRole::Crc8 => "CRC byte",
        })
    }
}

/// One signal of a message, validated.
#[derive(Debug, Clone, PartialEq)]
pub struct SignalDef {
    name: String,
    layout: SignalLayout,
    factor: f64,
    offset: f64,
    min: f64,
    max: f64,
    unit: String,
    comment: Option<String>,
    role: SignalRole,
    value_names: Vec<(i64, String)>,
    /// Raw start value (`GenSigStartValue`): what the signal carries before and without a
    /// value (the receiving device's own "no command" value).
    start_raw: Option<i128>,
}

impl SignalDef {
    /// The raw start value from the DBC attribute [`START_VALUE_ATTRIBUTE`], if set.
    pub fn start_raw(&self) -> Option<i128> {
        self.start_raw
    }
    /// Signal name.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// Position and raw interpretation.
    pub fn layout(&self) -> &SignalLayout {
        &self.layout
    }
    /// Physical units per raw bit.
    pub fn factor(&self) -> f64 {
        self.factor
    }
    /// Physical value of raw 0, in the signal's unit.
    pub fn offset(&self) -> f64 {
        self.offset
    }
    /// DBC minimum (physical, informational: encoding clamps to the raw range only).
    pub fn min(&self) -> f64 {
        self.min
    }
    /// DBC maximum (physical, informational).
    pub fn max(&self) -> f64 {
        self.max
    }
    /// Unit string from the DBC.
    pub fn unit(&self) -> &str {
        &self.unit
    }
    /// `CM_ SG_` comment, if any.
    pub fn comment(&self) -> Option<&str> {
        self.comment.as_deref()
    }
    /// End-to-end protection role.
    pub fn role(&self) -> SignalRole {
        self.role
    }
    /// `VAL_` entries (raw value, name), in file order.
    pub fn value_names(&self) -> &[(i64, String)] {
        &self.value_names
    }
    /// Name given by `VAL_` to a raw value.
    pub fn value_name(&self, raw: i64) -> Option<&str> {
        self.value_names
            .iter()
            .find(|(v, _)| *v == raw)
            .map(|(_, n)| n.as_str())
    }
    /// Smallest physical value the signal can carry.
    pub fn physical_min(&self) -> f64 {
        let a = raw_to_physical(self.layout.raw_min(), self.factor, self.offset);
        let b = raw_to_physical(self.layout.raw_max(), self.factor, self.offset);
        a.min(b)
    }
    /// Largest physical value the signal can carry.
    pub fn physical_max(&self) -> f64 {
        let a = raw_to_physical(self.layout.raw_min(), self.factor, self.offset);
        let b = raw_to_physical(self.layout.raw_max(), self.factor, self.offset);
        a.max(b)
    }
    /// Raw value in `data`.
    pub fn decode_raw(&self, data: &[u8; MAX_PAYLOAD]) -> i128 {
        self.layout.unpack(data)
    }
    /// Physical value in `data`, in the signal's unit.
    pub fn decode(&self, data: &[u8; MAX_PAYLOAD]) -> f64 {
        raw_to_physical(self.layout.unpack(data), self.factor, self.offset)
    }
    /// Write a physical value (rounded, clamped to the raw range; NaN writes nothing).
    pub fn encode(&self, data: &mut [u8; MAX_PAYLOAD], physical: f64) -> EncodeStatus {
        pack_physical(data, &self.layout, self.factor, self.offset, physical)
    }
    /// Write a raw value, clamped to the raw range.
    pub fn encode_raw(&self, data: &mut [u8; MAX_PAYLOAD], raw: i128) -> EncodeStatus {
        let clamped = raw.clamp(self.layout.raw_min(), self.layout.raw_max());
        self.layout.pack(data, clamped);
        if clamped == raw {
            EncodeStatus::InRange
        } else {
            EncodeStatus::Clamped
        }
    }
    /// Raw value a physical value encodes to, with its status (`None` for NaN).
    pub fn to_raw(&self, physical: f64) -> Option<(i128, EncodeStatus)> {
        physical_to_raw(physical, self.factor, self.offset, &self.layout)
    }
}

/// One message (frame) of the database, validated.
#[derive(Debug, Clone, PartialEq)]
pub struct MessageDef {
    name: String,
    id: FrameId,
    dlc: u8,
    transmitter: Option<String>,
    cycle_time_ms: Option<u32>,
    comment: Option<String>,
    signals: Vec<SignalDef>,
}

impl MessageDef {
    /// Message name.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// CAN identifier.
    pub fn id(&self) -> FrameId {
        self.id
    }
    /// Payload length, bytes (0..=8).
    pub fn dlc(&self) -> u8 {
        self.dlc
    }
    /// Sending node, if named.
    pub fn transmitter(&self) -> Option<&str> {
        self.transmitter.as_deref()
    }
    /// Cycle time from `GenMsgCycleTime`, ms (`None` when absent or 0).
    pub fn cycle_time_ms(&self) -> Option<u32> {
        self.cycle_time_ms
    }
    /// `CM_ BO_` comment, if any.
    pub fn comment(&self) -> Option<&str> {
        self.comment.as_deref()
    }
    /// Signals, in file order.
    pub fn signals(&self) -> &[SignalDef] {
        &self.signals
    }
    /// Signal by name.
    pub fn signal(&self, name: &str) -> Option<&SignalDef> {
        self.signals.iter().find(|s| s.name == name)
    }
    /// The message's alive counter signal, if any.
    pub fn alive_counter(&self) -> Option<&SignalDef> {
        self.signals
            .iter()
            .find(|s| s.role == SignalRole::AliveCounter)
    }
    /// The message's CRC signal, if any.
    pub fn crc(&self) -> Option<&SignalDef> {
        self.signals.iter().find(|s| s.role == SignalRole::Crc8)
    }
    /// DLC, alive-counter and CRC checks for this message's frames.
    pub fn guard(&self) -> FrameGuard {
        FrameGuard::new(
            self.id,
            self.dlc,
            self.alive_counter().map(|s| s.layout),
            self.crc().map(|s| s.layout.start_bit() / 8),
        )
    }
}

/// A DBC file, parsed and validated.
#[derive(Debug, Clone, PartialEq)]
pub struct CanDatabase {
    source: String,
    comment: Option<String>,
    messages: Vec<MessageDef>,
    /// The database declares a J1939 network (`ProtocolType = "J1939"`).
    j1939: bool,
}

/// A DBC that cannot be used, with the file it came from.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {kind}")]
pub struct DbcError {
    /// Path (or source name) of the DBC.
    pub file: String,
    /// What is wrong.
    #[source]
    pub kind: DbcErrorKind,
}

/// What is wrong with a DBC.
#[derive(Debug, thiserror::Error)]
pub enum DbcErrorKind {
    /// The file could not be read.
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    /// The text is not valid DBC.
    #[error("DBC syntax error: {0}")]
    Syntax(String),
    /// DLC above 8.
    #[error("message {message}: DLC {dlc} is larger than 8 bytes (only classic CAN is supported)")]
    DlcTooLarge {
        /// Message name.
        message: String,
        /// DLC in the file.
        dlc: u64,
    },
    /// Standard id above 0x7FF.
    #[error("message {message}: standard id {id:#X} does not fit 11 bits")]
    IdOutOfRange {
        /// Message name.
        message: String,
        /// Id in the file.
        id: u32,
    },
    /// Two messages with one id.
    #[error("messages {first} and {second} both use id {id}")]
    DuplicateId {
        /// The id.
        id: FrameId,
        /// First message with it.
        first: String,
        /// Second message with it.
        second: String,
    },
    /// Two messages with one name.
    #[error("two messages are named {message}")]
    DuplicateMessage {
        /// The name.
        message: String,
    },
    /// Two signals with one name in a message.
    #[error("message {message}: two signals are named {signal}")]
    DuplicateSignal {
        /// Message name.
        message: String,
        /// Signal name.
        signal: String,
    },
    /// Start bit / size impossible in 8 bytes.
    #[error("message {message}, signal {signal}: {source}")]
    Layout {
        /// Message name.
        message: String,
        /// Signal name.
        signal: String,
        /// The layout problem.
        source: LayoutError,
    },
    /// Signal reaches beyond the message's DLC.
    #[error("message {message}, signal {signal}: needs {needed} data bytes but the DLC is {dlc}")]
    PastDlc {
        /// Message name.
        message: String,
        /// Signal name.
        signal: String,
        /// Bytes the signal needs.
        needed: u8,
        /// DLC of the message.
        dlc: u8,
    },
    /// Two signals share bits.
    #[error("message {message}: signals {first} and {second} overlap in bit(s) {}", bit_list(*.bits))]
    Overlap {
        /// Message name.
        message: String,
        /// Signal defined first.
        first: String,
        /// Signal defined second.
        second: String,
        /// Shared bits, DBC numbering mask.
        bits: u64,
    },
    /// Factor zero or not finite, or offset not finite.
    #[error("message {message}, signal {signal}: factor {factor} / offset {offset} unusable (factor must be finite and non-zero, offset finite)")]
    BadScaling {
        /// Message name.
        message: String,
        /// Signal name.
        signal: String,
        /// Factor in the file.
        factor: f64,
        /// Offset in the file.
        offset: f64,
    },
    /// Multiplexed signals are not supported.
    #[error("message {message}, signal {signal}: multiplexed signals are not supported")]
    Multiplexed {
        /// Message name.
        message: String,
        /// Signal name.
        signal: String,
    },
    /// IEEE float signals (`SIG_VALTYPE_`) are not supported.
    #[error("message {message}, signal {signal}: float signals (SIG_VALTYPE_) are not supported")]
    FloatSignal {
        /// Message name.
        message: String,
        /// Signal name.
        signal: String,
    },
    /// Role attribute value not understood.
    #[error("message {message}, signal {signal}: {ROLE_ATTRIBUTE} value {value} is not Data, AliveCounter or Crc8")]
    UnknownRole {
        /// Message name.
        message: String,
        /// Signal name.
        signal: String,
        /// Value in the file.
        value: String,
    },
    /// Role attribute set on a signal that does not exist.
    #[error("{ROLE_ATTRIBUTE} is set for signal {signal} of id {id}, which has no such signal")]
    RoleForUnknownSignal {
        /// Message id in the `BA_` line.
        id: FrameId,
        /// Signal name in the `BA_` line.
        signal: String,
    },
    /// Signal unfit for its role.
    #[error("message {message}, signal {signal}: cannot be the {role}: {reason}")]
    BadRole {
        /// Message name.
        message: String,
        /// Signal name.
        signal: String,
        /// The role.
        role: SignalRole,
        /// Why.
        reason: &'static str,
    },
    /// A message with two alive counters or two CRCs.
    #[error("message {message}: signals {first} and {second} are both the {role}")]
    DuplicateRole {
        /// Message name.
        message: String,
        /// The role.
        role: SignalRole,
        /// First signal.
        first: String,
        /// Second signal.
        second: String,
    },
}

/// "3, 4, 10" for a bit mask (error messages only).
fn bit_list(bits: u64) -> String {
    let list: Vec<String> = (0..64)
        .filter(|b| bits & (1u64 << b) != 0)
        .map(|b| b.to_string())
        .collect();
    list.join(", ")
}

fn numeric(v: NumericValue) -> f64 {
    match v {
        NumericValue::Uint(u) => u as f64,
        NumericValue::Int(i) => i as f64,
        NumericValue::Double(d) => d,
    }
}

fn frame_id(id: MessageId) -> FrameId {
    match id {
        MessageId::Standard(s) => FrameId::Standard(s),
        MessageId::Extended(e) => FrameId::Extended(e),
    }
}

/// The role names of the [`ROLE_ATTRIBUTE`] enum definition, if the file defines it.
fn role_enum(dbc: &Dbc) -> Option<&[String]> {
    dbc.attribute_definitions.iter().find_map(|d| match d {
        AttributeDefinition::Signal(name, AttributeValueType::Enum(values))
            if name == ROLE_ATTRIBUTE =>
        {
            Some(values.as_slice())
        }
        _ => None,
    })
}

/// Text of an attribute value: enum indices are looked up in the definition.
fn role_text(value: &AttributeValue, names: Option<&[String]>) -> String {
    let index = match value {
        AttributeValue::String(s) => return s.clone(),
        AttributeValue::Uint(u) => usize::try_from(*u).ok(),
        AttributeValue::Int(i) => usize::try_from(*i).ok(),
        AttributeValue::Double(d) => return d.to_string(),
    };
    match (index, names) {
        (Some(i), Some(names)) => names
            .get(i)
            .cloned()
            .unwrap_or_else(|| format!("index {i}")),
        _ => format!("{value:?}"),
    }
}

fn parse_role(text: &str) -> Option<SignalRole> {
    match text {
        "Data" => Some(SignalRole::Data),
        "AliveCounter" => Some(SignalRole::AliveCounter),
        "Crc8" => Some(SignalRole::Crc8),
        _ => None,
    }
}

fn check_role(sig: &SignalDef) -> Result<(), &'static str> {
    let l = &sig.layout;
    let unit_scale = sig.factor == 1.0 && sig.offset == 0.0;
    match sig.role {
        SignalRole::Data => Ok(()),
        SignalRole::AliveCounter => {
            if l.is_signed() || !unit_scale || l.size() > 8 {
                Err("an alive counter must be unsigned, at most 8 bits, factor 1, offset 0")
            } else {
                Ok(())
            }
        }
        SignalRole::Crc8 => {
            let byte_aligned = l.occupancy() == 0xFFu64 << (8 * u32::from(l.start_bit() / 8));
            if l.is_signed() || !unit_scale || l.size() != 8 || !byte_aligned {
                Err("a CRC-8 must be one whole unsigned byte, factor 1, offset 0")
            } else {
                Ok(())
            }
        }
    }
}

impl CanDatabase {
    /// Read and validate a DBC file (UTF-8).
    pub fn from_file(path: impl AsRef<Path>) -> Result<CanDatabase, DbcError> {
        let path = path.as_ref();
        let file = path.display().to_string();
        let text = crate::config::read_config_text(path).map_err(|e| DbcError {
            file: file.clone(),
            kind: DbcErrorKind::Io(e),
        })?;
        CanDatabase::parse(&text, &file)
    }

    /// Validate DBC text; `source` names it in errors (a path or e.g. `"<inline>"`).
    pub fn parse(text: &str, source: &str) -> Result<CanDatabase, DbcError> {
        Self::build(text, source).map_err(|kind| DbcError {
            file: source.to_string(),
            kind,
        })
    }

    fn build(text: &str, source: &str) -> Result<CanDatabase, DbcErrorKind> {
        let dbc = Dbc::try_from(text).map_err(|e| DbcErrorKind::Syntax(e.to_string()))?;

        // Role attributes: check they point at real signals.
        let role_names = role_enum(&dbc);
        for a in dbc
            .attribute_values_signal
            .iter()
            .filter(|a| a.name == ROLE_ATTRIBUTE)
        {
            if dbc.signal_by_name(a.message_id, &a.signal_name).is_none() {
                return Err(DbcErrorKind::RoleForUnknownSignal {
                    id: frame_id(a.message_id),
                    signal: a.signal_name.clone(),
                });
            }
        }

        let mut messages: Vec<MessageDef> = Vec::with_capacity(dbc.messages.len());
        let mut by_id: HashMap<FrameId, String> = HashMap::new();
        for m in &dbc.messages {
            let id = frame_id(m.id);
            if !id.is_valid() {
                return Err(DbcErrorKind::IdOutOfRange {
                    message: m.name.clone(),
                    id: id.raw(),
                });
            }
            if let Some(first) = by_id.get(&id) {
                return Err(DbcErrorKind::DuplicateId {
                    id,
                    first: first.clone(),
                    second: m.name.clone(),
                });
            }
            if messages.iter().any(|x| x.name == m.name) {
                return Err(DbcErrorKind::DuplicateMessage {
                    message: m.name.clone(),
                });
            }
            by_id.insert(id, m.name.clone());
            let dlc = match u8::try_from(m.size) {
                Ok(d) if usize::from(d) <= MAX_PAYLOAD => d,
                _ => {
                    return Err(DbcErrorKind::DlcTooLarge {
                        message: m.name.clone(),
                        dlc: m.size,
                    })
                }
            };

            let mut signals: Vec<SignalDef> = Vec::with_capacity(m.signals.len());
            let mut used: u64 = 0;
            for s in &m.signals {
                let at = |signal: &str| (m.name.clone(), signal.to_string());
                if signals.iter().any(|x| x.name == s.name) {
                    let (message, signal) = at(&s.name);
                    return Err(DbcErrorKind::DuplicateSignal { message, signal });
                }
                if s.multiplexer_indicator != MultiplexIndicator::Plain {
                    let (message, signal) = at(&s.name);
                    return Err(DbcErrorKind::Multiplexed { message, signal });
                }
                if matches!(
                    dbc.extended_value_type_for_signal(m.id, &s.name),
                    Some(
                        SignalExtendedValueType::IEEEfloat32Bit
                            | SignalExtendedValueType::IEEEdouble64bit
                    )
                ) {
                    let (message, signal) = at(&s.name);
                    return Err(DbcErrorKind::FloatSignal { message, signal });
                }
                let order = match s.byte_order {
                    DbcByteOrder::LittleEndian => ByteOrder::Intel,
                    DbcByteOrder::BigEndian => ByteOrder::Motorola,
                };
                let signed = s.value_type == ValueType::Signed;
                let layout =
                    SignalLayout::new(s.start_bit, s.size, order, signed).map_err(|source| {
                        let (message, signal) = at(&s.name);
                        DbcErrorKind::Layout {
                            message,
                            signal,
                            source,
                        }
                    })?;
                if layout.bytes_needed() > dlc {
                    let (message, signal) = at(&s.name);
                    return Err(DbcErrorKind::PastDlc {
                        message,
                        signal,
                        needed: layout.bytes_needed(),
                        dlc,
                    });
                }
                let occ = layout.occupancy();
                if used & occ != 0 {
                    let other = signals
                        .iter()
                        .find(|x| x.layout.occupancy() & occ != 0)
                        .map(|x| x.name.clone())
                        .unwrap_or_default();
                    return Err(DbcErrorKind::Overlap {
                        message: m.name.clone(),
                        first: other,
                        second: s.name.clone(),
                        bits: used & occ,
                    });
                }
                used |= occ;
                if !(s.factor.is_finite() && s.factor != 0.0 && s.offset.is_finite()) {
                    let (message, signal) = at(&s.name);
                    return Err(DbcErrorKind::BadScaling {
                        message,
                        signal,
                        factor: s.factor,
                        offset: s.offset,
                    });
                }
                let role = match dbc.resolved_signal_attribute(m.id, &s.name, ROLE_ATTRIBUTE) {
                    None => SignalRole::Data,
                    Some(v) => {
                        let text = role_text(v, role_names);
                        parse_role(&text).ok_or_else(|| {
                            let (message, signal) = at(&s.name);
                            DbcErrorKind::UnknownRole {
                                message,
                                signal,
                                value: text,
                            }
                        })?
                    }
                };
                let value_names = dbc
                    .value_descriptions_for_signal(m.id, &s.name)
                    .map(|v| v.iter().map(|d| (d.id, d.description.clone())).collect())
                    .unwrap_or_default();
                let start_raw = match dbc.signal_attribute(m.id, &s.name, START_VALUE_ATTRIBUTE) {
                    Some(AttributeValue::Uint(v)) => Some(i128::from(*v)),
                    Some(AttributeValue::Int(v)) => Some(i128::from(*v)),
                    Some(AttributeValue::Double(v)) if v.is_finite() => Some(v.round() as i128),
                    _ => None,
                };
                let def = SignalDef {
                    start_raw,
                    name: s.name.clone(),
                    layout,
                    factor: s.factor,
                    offset: s.offset,
                    min: numeric(s.min),
                    max: numeric(s.max),
                    unit: s.unit.clone(),
                    comment: dbc.signal_comment(m.id, &s.name).map(str::to_string),
                    role,
                    value_names,
                };
                check_role(&def).map_err(|reason| {
                    let (message, signal) = at(&s.name);
                    DbcErrorKind::BadRole {
                        message,
                        signal,
                        role,
                        reason,
                    }
                })?;
                if role != SignalRole::Data {
                    if let Some(first) = signals.iter().find(|x| x.role == role) {
                        return Err(DbcErrorKind::DuplicateRole {
                            message: m.name.clone(),
                            role,
                            first: first.name.clone(),
                            second: s.name.clone(),
                        });
                    }
                }
                signals.push(def);
            }

            let cycle_time_ms = match dbc.message_attribute(m.id, CYCLE_TIME_ATTRIBUTE) {
                Some(AttributeValue::Uint(v)) => u32::try_from(*v).ok(),
                Some(AttributeValue::Int(v)) => u32::try_from(*v).ok(),
                _ => None,
            }
            .filter(|v| *v > 0);

            messages.push(MessageDef {
                name: m.name.clone(),
                id,
                dlc,
                transmitter: m.transmitter.clone(),
                cycle_time_ms,
                comment: dbc.message_comment(m.id).map(str::to_string),
                signals,
            });
        }

        let comment = dbc.comments.iter().find_map(|c| match c {
            Comment::Plain { comment } => Some(comment.clone()),
            _ => None,
        });
        let j1939 = dbc
            .attribute_values_database
            .iter()
            .filter(|a| a.name == PROTOCOL_ATTRIBUTE)
            .any(|a| matches!(&a.value, AttributeValue::String(v) if v.eq_ignore_ascii_case("J1939")));
        Ok(CanDatabase {
            source: source.to_string(),
            comment,
            messages,
            j1939,
        })
    }

    /// Whether the database declares a J1939 network (`BA_ "ProtocolType" "J1939";`): its
    /// devices read all ones (the most negative value, signed) as "not available".
    pub fn declares_j1939(&self) -> bool {
        self.j1939
    }

    /// Path or name the database was loaded from.
    pub fn source(&self) -> &str {
        &self.source
    }
    /// The database-level `CM_ "…"` comment, if any.
    pub fn comment(&self) -> Option<&str> {
        self.comment.as_deref()
    }
    /// Messages, in file order.
    pub fn messages(&self) -> &[MessageDef] {
        &self.messages
    }
    /// Message by name.
    pub fn message(&self, name: &str) -> Option<&MessageDef> {
        self.messages.iter().find(|m| m.name == name)
    }
    /// Message by CAN identifier.
    pub fn message_by_id(&self, id: FrameId) -> Option<&MessageDef> {
        self.messages.iter().find(|m| m.id == id)
    }

    /// Give messages other identifiers than the DBC's (`[bus.can.frame_ids]`): a device
    /// configured to another id, or a 29-bit id for a message the DBC lists with 11 bits.
    /// Every later user of the database (codec, RX lookup, TX frames, bus load) sees the new
    /// ids. On error nothing changes.
    pub fn override_frame_ids<'a>(
        &mut self,
        overrides: impl IntoIterator<Item = (&'a str, FrameIdOverride)>,
    ) -> Result<(), FrameIdError> {
        let mut ids: Vec<FrameId> = self.messages.iter().map(|m| m.id).collect();
        for (name, o) in overrides {
            let Some(k) = self.messages.iter().position(|m| m.name == name) else {
                let known: Vec<&str> = self.messages.iter().map(|m| m.name.as_str()).collect();
                return Err(FrameIdError {
                    message: name.to_string(),
                    reason: format!(
                        "no message of that name in the DBC (messages: {})",
                        known.join(", ")
                    ),
                });
            };
            ids[k] = o.frame_id().map_err(|reason| FrameIdError {
                message: name.to_string(),
                reason,
            })?;
        }
        for (k, id) in ids.iter().enumerate() {
            if let Some(j) = ids[..k].iter().position(|x| x == id) {
                // name the message whose id was overridden (the later one if both)
                let (named, other) = if ids[k] != self.messages[k].id {
                    (k, j)
                } else {
                    (j, k)
                };
                return Err(FrameIdError {
                    message: self.messages[named].name.clone(),
                    reason: format!(
                        "CAN id {id} is also the id of message {}",
                        self.messages[other].name
                    ),
                });
            }
        }
        for (m, id) in self.messages.iter_mut().zip(ids) {
            m.id = id;
        }
        Ok(())
    }
}

/// One entry of `[bus.can.frame_ids]`: `Name = 0x18FF1234` (29-bit when above 0x7FF, else
/// 11-bit) or `Name = { id = 0x123, extended = true }` (a 29-bit id below 0x800).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(untagged)]
pub enum FrameIdOverride {
    /// The id; extended when it does not fit 11 bits.
    Id(u32),
    /// The id and its kind.
    Explicit {
        /// The id.
        id: u32,
        /// 29-bit (true) or 11-bit (false) identifier; inferred from the value when absent.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        extended: Option<bool>,
    },
}

impl FrameIdOverride {
    /// The identifier, or why it cannot be one.
    pub fn frame_id(self) -> Result<FrameId, String> {
        let (id, extended) = match self {
            FrameIdOverride::Id(id) => (id, None),
            FrameIdOverride::Explicit { id, extended } => (id, extended),
        };
        let fid = match extended.unwrap_or(id > 0x7FF) {
            true => FrameId::Extended(id),
            false => FrameId::Standard(u16::try_from(id).unwrap_or(u16::MAX)),
        };
        if fid.is_valid() && fid.raw() == id {
            Ok(fid)
        } else if fid.is_extended() {
            Err(format!(
                "{id:#X} does not fit a 29-bit (extended) id (at most 0x1FFFFFFF)"
            ))
        } else {
            Err(format!(
                "{id:#X} does not fit an 11-bit (standard) id (at most 0x7FF): drop `extended = false` or give a smaller id"
            ))
        }
    }
}

/// A `[bus.can.frame_ids]` entry that cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("frame id of message {message}: {reason}")]
pub struct FrameIdError {
    /// The message named by the entry (config key `bus.can.frame_ids.<message>`).
    pub message: String,
    /// What is wrong.
    pub reason: String,
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn skid_path() -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("config/skid.dbc")
    }

    const HEADER: &str = "VERSION \"\"\n\nNS_ :\n\nBS_:\n\nBU_: A B\n\n";

    #[test]
    fn frame_id_overrides_are_checked_and_all_or_nothing() {
        use FrameIdOverride::{Explicit, Id};
        let fresh = || CanDatabase::from_file(skid_path()).expect("skid");
        let id = |db: &CanDatabase, m: &str| db.message(m).map(|m| m.id());
        // inferred kind: above 0x7FF extended, else standard; explicit kind either way
        assert_eq!(Id(0x7FF).frame_id(), Ok(FrameId::Standard(0x7FF)));
        assert_eq!(Id(0x800).frame_id(), Ok(FrameId::Extended(0x800)));
        let ext = Explicit {
            id: 0x10,
            extended: Some(true),
        };
        assert_eq!(ext.frame_id(), Ok(FrameId::Extended(0x10)));
        let too_big = Explicit {
            id: 0x800,
            extended: Some(false),
        };
        assert!(too_big.frame_id().unwrap_err().contains("11-bit"));
        assert!(Id(0x2000_0000).frame_id().unwrap_err().contains("29-bit"));

        let mut db = fresh();
        db.override_frame_ids([("CTRL_Heartbeat", Id(0x18FF_0080))])
            .expect("override");
        assert_eq!(
            id(&db, "CTRL_Heartbeat"),
            Some(FrameId::Extended(0x18FF_0080))
        );
        assert_eq!(
            db.message_by_id(FrameId::Standard(0x80)).map(|m| m.name()),
            None
        );

        // errors name the message; nothing changes
        let mut db = fresh();
        let e = db
            .override_frame_ids([("CTRL_Heartbeat", Id(0x555)), ("Nope", Id(1))])
            .unwrap_err();
        assert_eq!(e.message, "Nope");
        assert!(e.reason.contains("CTRL_ActuatorCmd1"), "{e}");
        assert_eq!(id(&db, "CTRL_Heartbeat"), Some(FrameId::Standard(0x80)));
        let e = db
            .override_frame_ids([("PLANT_Drive", Id(0x100))])
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "frame id of message PLANT_Drive: CAN id 0x100 is also the id of message PLANT_Pressures"
        );
        // swapping two ids is fine
        db.override_frame_ids([("PLANT_Drive", Id(0x100)), ("PLANT_Pressures", Id(0x103))])
            .expect("swap");
        assert_eq!(id(&db, "PLANT_Drive"), Some(FrameId::Standard(0x100)));
        // TOML forms
        let t: std::collections::BTreeMap<String, FrameIdOverride> = toml::from_str(
            "A = 0x18FF1234\nB = { id = 0x100, extended = true }\nC = { id = 0x100 }\n",
        )
        .expect("toml");
        assert_eq!(t["A"], Id(0x18FF_1234));
        assert_eq!(t["B"].frame_id(), Ok(FrameId::Extended(0x100)));
        assert_eq!(t["C"].frame_id(), Ok(FrameId::Standard(0x100)));
    }

    fn parse(body: &str) -> Result<CanDatabase, DbcError> {
        CanDatabase::parse(&format!("{HEADER}{body}"), "test.dbc")
    }

    fn err(body: &str) -> String {
        match parse(body) {
            Ok(_) => panic!("expected an error for:\n{body}"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn skid_dbc_loads_with_expected_layout() {
        let db = CanDatabase::from_file(skid_path()).expect("config/skid.dbc is valid");
        assert!(db.source().ends_with("config/skid.dbc"));
        let names: Vec<&str> = db.messages().iter().map(|m| m.name()).collect();
        assert_eq!(
            names,
            [
                "CTRL_Heartbeat",
                "CTRL_ActuatorCmd1",
                "CTRL_ActuatorCmd2",
                "PLANT_Pressures",
                "PLANT_SpeedFlowTemp",
                "PLANT_Positions",
                "PLANT_Drive",
            ]
        );
        for m in db.messages() {
            assert_eq!(m.dlc(), 8, "{}", m.name());
            assert!(m.alive_counter().is_some(), "{} has no counter", m.name());
            assert!(m.crc().is_some(), "{} has no CRC", m.name());
            assert!(m.comment().is_some(), "{} has no comment", m.name());
            for s in m.signals() {
                assert!(
                    s.comment().is_some(),
                    "{}.{} uncommented",
                    m.name(),
                    s.name()
                );
            }
        }
        let p = db.message("PLANT_Pressures").expect("pressures");
        assert_eq!(p.id(), FrameId::Standard(0x100));
        assert_eq!(p.cycle_time_ms(), Some(1));
        let ps = p.signal("PSuction").expect("PSuction");
        assert_eq!(ps.layout().byte_order(), ByteOrder::Motorola);
        assert_eq!((ps.layout().start_bit(), ps.layout().size()), (7, 24));
        assert_eq!(ps.unit(), "Pa");
        let t = db
            .message("PLANT_SpeedFlowTemp")
            .and_then(|m| m.signal("TSuction"))
            .expect("TSuction");
        assert!(t.layout().is_signed());
        assert_eq!((t.factor(), t.offset()), (0.01, 273.15));
        let hb = db.message("CTRL_Heartbeat").expect("heartbeat");
        assert_eq!(hb.cycle_time_ms(), Some(10));
        let mode = hb.signal("Mode").expect("Mode");
        assert_eq!(mode.value_name(3), Some("fail_safe"));
        assert_eq!(mode.value_name(9), None);
        assert_eq!(
            hb.alive_counter().map(|s| s.layout().size()),
            Some(8),
            "8-bit heartbeat counter"
        );
        assert!(db.comment().is_some_and(|c| c.contains("CRC-8/SAE-J1850")));
    }

    #[test]
    fn skid_requirements_ranges_and_resolution() {
        let db = CanDatabase::from_file(skid_path()).expect("valid");
        let sig = |m: &str, s: &str| {
            db.message(m)
                .and_then(|m| m.signal(s))
                .unwrap_or_else(|| panic!("{m}.{s} missing"))
                .clone()
        };
        // (message, signal, max resolution, required min, required max)
        let reqs = [
            ("PLANT_Pressures", "PSuction", 1.0, 0.0, 10e6),
            ("PLANT_Pressures", "PDischarge", 1.0, 0.0, 10e6),
            ("PLANT_SpeedFlowTemp", "ShaftSpeed", 0.1, 0.0, 6000.0),
            ("PLANT_SpeedFlowTemp", "OrificeDp", 1.0, 0.0, 60e3),
            ("PLANT_SpeedFlowTemp", "TSuction", 0.1, 200.0, 500.0),
            ("PLANT_Positions", "RecycleValvePosition", 1e-4, 0.0, 1.0),
            ("PLANT_Positions", "ThrottlePosition", 1e-4, 0.0, 1.0),
            ("PLANT_Positions", "ThrustPosition", 1e-8, -1e-3, 1e-3),
            ("PLANT_Drive", "DriveTorque", 1.0, -30e3, 30e3),
            ("CTRL_ActuatorCmd1", "DriveTorqueCmd", 1.0, -30e3, 30e3),
            ("CTRL_ActuatorCmd1", "RecycleValveCmd", 1e-4, 0.0, 1.0),
            ("CTRL_ActuatorCmd1", "ThrottleCmd", 1e-4, 0.0, 1.0),
            ("CTRL_ActuatorCmd2", "CloseCoupledValveCmd", 1e-4, -1.0, 1.0),
            ("CTRL_ActuatorCmd2", "TipClearanceCmd", 1e-8, -1e-3, 1e-3),
        ];
        for (m, s, res, lo, hi) in reqs {
            let d = sig(m, s);
            assert!(d.factor() <= res * (1.0 + 1e-12), "{m}.{s} resolution");
            assert!(d.physical_min() <= lo, "{m}.{s} min {}", d.physical_min());
            assert!(d.physical_max() >= hi, "{m}.{s} max {}", d.physical_max());
        }
    }

    #[test]
    fn missing_file_names_the_file() {
        let e = CanDatabase::from_file("/nonexistent/skid.dbc").unwrap_err();
        assert_eq!(e.file, "/nonexistent/skid.dbc");
        assert!(matches!(e.kind, DbcErrorKind::Io(_)));
        assert!(e
            .to_string()
            .starts_with("/nonexistent/skid.dbc: cannot read"));
    }

    #[test]
    fn syntax_error_names_the_file() {
        let e = CanDatabase::parse("this is not a dbc", "broken.dbc").unwrap_err();
        assert!(matches!(e.kind, DbcErrorKind::Syntax(_)));
        assert!(e.to_string().starts_with("broken.dbc: DBC syntax error"));
    }

    #[test]
    fn rejects_signal_past_dlc() {
        let msg = err("BO_ 16 M1: 2 A\n SG_ Wide : 8|16@1+ (1,0) [0|0] \"\" B\n");
        assert_eq!(
            msg,
            "test.dbc: message M1, signal Wide: needs 3 data bytes but the DLC is 2"
        );
        // Motorola reaching byte 2 from byte 1.
        let msg = err("BO_ 16 M1: 2 A\n SG_ Be : 15|12@0+ (1,0) [0|0] \"\" B\n");
        assert!(msg.contains("signal Be: needs 3 data bytes"), "{msg}");
    }

    #[test]
    fn rejects_overlap_and_names_both_signals() {
        let msg = err(concat!(
            "BO_ 16 M1: 8 A\n",
            " SG_ First : 0|12@1+ (1,0) [0|0] \"\" B\n",
            " SG_ Second : 10|4@1+ (1,0) [0|0] \"\" B\n"
        ));
        assert_eq!(
            msg,
            "test.dbc: message M1: signals First and Second overlap in bit(s) 10, 11"
        );
        // Motorola 16 bits from bit 7 covers bytes 0 and 1: overlaps an Intel byte 1 signal.
        let msg = err(concat!(
            "BO_ 16 M1: 8 A\n",
            " SG_ Be : 7|16@0+ (1,0) [0|0] \"\" B\n",
            " SG_ Le : 15|1@1+ (1,0) [0|0] \"\" B\n"
        ));
        assert!(
            msg.contains("signals Be and Le overlap in bit(s) 15"),
            "{msg}"
        );
    }

    #[test]
    fn rejects_bad_layouts_and_dlc() {
        let msg = err("BO_ 16 M1: 8 A\n SG_ S : 60|8@1+ (1,0) [0|0] \"\" B\n");
        assert!(
            msg.contains("message M1, signal S: 8 bits from start bit 60"),
            "{msg}"
        );
        let msg = err("BO_ 16 M1: 12 A\n SG_ S : 0|8@1+ (1,0) [0|0] \"\" B\n");
        assert!(msg.contains("message M1: DLC 12 is larger than 8"), "{msg}");
        let msg = err("BO_ 4000 M1: 8 A\n SG_ S : 0|8@1+ (1,0) [0|0] \"\" B\n");
        assert!(
            msg.contains("standard id 0xFA0 does not fit 11 bits"),
            "{msg}"
        );
        let msg = err("BO_ 16 M1: 8 A\n SG_ S : 0|8@1+ (0,0) [0|0] \"\" B\n");
        assert!(msg.contains("signal S: factor 0"), "{msg}");
    }

    #[test]
    fn rejects_duplicates() {
        let msg = err(concat!(
            "BO_ 16 M1: 8 A\n SG_ S : 0|8@1+ (1,0) [0|0] \"\" B\n",
            "BO_ 16 M2: 8 A\n SG_ S : 0|8@1+ (1,0) [0|0] \"\" B\n"
        ));
        assert!(
            msg.contains("messages M1 and M2 both use id 0x010"),
            "{msg}"
        );
        let msg = err(concat!(
            "BO_ 16 M1: 8 A\n SG_ S : 0|8@1+ (1,0) [0|0] \"\" B\n",
            " SG_ S : 8|8@1+ (1,0) [0|0] \"\" B\n"
        ));
        assert!(msg.contains("message M1: two signals are named S"), "{msg}");
    }

    #[test]
    fn rejects_multiplexed_signals() {
        let msg = err(concat!(
            "BO_ 16 M1: 8 A\n",
            " SG_ Mux M : 0|4@1+ (1,0) [0|0] \"\" B\n",
            " SG_ Sub m1 : 8|8@1+ (1,0) [0|0] \"\" B\n"
        ));
        assert!(msg.contains("signal Mux: multiplexed signals are not supported"));
    }

    #[test]
    fn extended_ids_and_roles() {
        let body = concat!(
            "BO_ 2147488128 Ext: 4 A\n",
            " SG_ Cnt : 0|4@1+ (1,0) [0|15] \"\" B\n",
            " SG_ Crc : 24|8@1+ (1,0) [0|255] \"\" B\n",
            "BA_DEF_ SG_ \"AntisurgeRole\" ENUM \"Data\",\"AliveCounter\",\"Crc8\";\n",
            "BA_DEF_DEF_ \"AntisurgeRole\" \"Data\";\n",
            "BA_ \"AntisurgeRole\" SG_ 2147488128 Cnt 1;\n",
            "BA_ \"AntisurgeRole\" SG_ 2147488128 Crc 2;\n",
        );
        let db = parse(body).expect("valid");
        let m = db.message("Ext").expect("Ext");
        // 2147488128 = 0x8000_1180: bit 31 flags an extended id 0x1180.
        assert_eq!(m.id(), FrameId::Extended(0x1180));
        assert_eq!(m.id().to_string(), "0x00001180 (extended)");
        assert_eq!(m.dlc(), 4);
        assert_eq!(m.alive_counter().map(|s| s.name()), Some("Cnt"));
        assert_eq!(m.crc().map(|s| s.name()), Some("Crc"));
        assert_eq!(db.message_by_id(FrameId::Extended(0x1180)), Some(m));
        assert_eq!(db.message_by_id(FrameId::Standard(0x180)), None);
    }

    #[test]
    fn frame_id_socketcan_conversion() {
        use socketcan::{ExtendedId, Id, StandardId};
        let std_id = FrameId::Standard(0x100).to_socketcan();
        assert_eq!(std_id, StandardId::new(0x100).map(Id::Standard));
        assert_eq!(std_id.map(FrameId::from), Some(FrameId::Standard(0x100)));
        let ext = FrameId::Extended(0x18FF_1234).to_socketcan();
        assert_eq!(ext, ExtendedId::new(0x18FF_1234).map(Id::Extended));
        assert_eq!(ext.map(FrameId::from), Some(FrameId::Extended(0x18FF_1234)));
        assert_eq!(FrameId::Standard(0x800).to_socketcan(), None);
        assert_eq!(FrameId::Extended(0x2000_0000).to_socketcan(), None);
        assert_eq!(FrameId::Standard(0x80).to_string(), "0x080");
    }

    #[test]
    fn rejects_bad_roles() {
        let defs = concat!(
            "BA_DEF_ SG_ \"AntisurgeRole\" ENUM \"Data\",\"AliveCounter\",\"Crc8\";\n",
            "BA_DEF_DEF_ \"AntisurgeRole\" \"Data\";\n",
        );
        // CRC not byte-aligned.
        let msg = err(&format!(
            "BO_ 16 M1: 8 A\n SG_ Crc : 4|8@1+ (1,0) [0|0] \"\" B\n{defs}BA_ \"AntisurgeRole\" SG_ 16 Crc 2;\n"
        ));
        assert!(
            msg.contains("signal Crc: cannot be the CRC byte: a CRC-8 must be one whole"),
            "{msg}"
        );
        // Signed counter.
        let msg = err(&format!(
            "BO_ 16 M1: 8 A\n SG_ C : 0|4@1- (1,0) [0|0] \"\" B\n{defs}BA_ \"AntisurgeRole\" SG_ 16 C 1;\n"
        ));
        assert!(
            msg.contains("signal C: cannot be the alive counter"),
            "{msg}"
        );
        // Two counters.
        let msg = err(&format!(
            "BO_ 16 M1: 8 A\n SG_ C1 : 0|4@1+ (1,0) [0|0] \"\" B\n SG_ C2 : 4|4@1+ (1,0) [0|0] \"\" B\n{defs}BA_ \"AntisurgeRole\" SG_ 16 C1 1;\nBA_ \"AntisurgeRole\" SG_ 16 C2 1;\n"
        ));
        assert!(
            msg.contains("message M1: signals C1 and C2 are both the alive counter"),
            "{msg}"
        );
        // Role for a signal that does not exist.
        let msg = err(&format!(
            "BO_ 16 M1: 8 A\n SG_ C : 0|4@1+ (1,0) [0|0] \"\" B\n{defs}BA_ \"AntisurgeRole\" SG_ 16 Nope 1;\n"
        ));
        assert!(msg.contains("signal Nope of id 0x010"), "{msg}");
        // Enum index out of range.
        let msg = err(&format!(
            "BO_ 16 M1: 8 A\n SG_ C : 0|4@1+ (1,0) [0|0] \"\" B\n{defs}BA_ \"AntisurgeRole\" SG_ 16 C 7;\n"
        ));
        assert!(msg.contains("value index 7 is not Data"), "{msg}");
    }

    #[test]
    fn signal_def_encode_decode() {
        let db = CanDatabase::from_file(skid_path()).expect("valid");
        let t = db
            .message("PLANT_SpeedFlowTemp")
            .and_then(|m| m.signal("TSuction"))
            .expect("TSuction")
            .clone();
        let mut data = [0u8; 8];
        // 253.15 K = -20 °C = raw -2000 = 0xF830 in bits 36..51.
        assert_eq!(t.encode(&mut data, 253.15), EncodeStatus::InRange);
        assert_eq!(t.decode_raw(&data), -2000);
        // bits 36..39 = 0x0 (low nibble of 0xF830) in byte 4's high nibble, byte 5 = 0x83,
        // byte 6 low nibble = 0xF.
        assert_eq!(data, [0, 0, 0, 0, 0x00, 0x83, 0x0F, 0]);
        assert!((t.decode(&data) - 253.15).abs() < 1e-9);
        assert_eq!(t.encode_raw(&mut data, 40_000), EncodeStatus::Clamped);
        assert_eq!(t.decode_raw(&data), 32_767);
        assert_eq!(t.to_raw(f64::NAN), None);
    }
}
