//! The controller heartbeat frame: mode, active law, fault bits, alive counter, CRC.

use std::fmt;

use super::bits::{SignalLayout, MAX_PAYLOAD};
use super::codec::BindingError;
use super::dbc::{CanDatabase, FrameId, SignalDef};
use super::e2e::{FrameError, FrameGuard};

/// Controller mode, as in the DBC value table of the heartbeat's mode signal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ControllerMode {
    /// 0: starting up, no commands yet.
    Init = 0,
    /// 1: operator sets the actuators.
    Manual = 1,
    /// 2: a control law is in charge.
    Auto = 2,
    /// 3: a fault forced the safe actuator positions.
    FailSafe = 3,
    /// 4: orderly shutdown.
    Shutdown = 4,
}

impl ControllerMode {
    /// Every mode, by raw value.
    pub const ALL: [ControllerMode; 5] = [
        ControllerMode::Init,
        ControllerMode::Manual,
        ControllerMode::Auto,
        ControllerMode::FailSafe,
        ControllerMode::Shutdown,
    ];

    /// Raw value on the bus.
    pub const fn raw(self) -> u8 {
        self as u8
    }

    /// Mode of a raw value.
    pub fn from_raw(raw: u8) -> Option<ControllerMode> {
        Self::ALL.get(usize::from(raw)).copied()
    }

    /// Name used in the DBC value table.
    pub const fn name(self) -> &'static str {
        match self {
            ControllerMode::Init => "init",
            ControllerMode::Manual => "manual",
            ControllerMode::Auto => "auto",
            ControllerMode::FailSafe => "fail_safe",
            ControllerMode::Shutdown => "shutdown",
        }
    }
}

impl fmt::Display for ControllerMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Content of a heartbeat frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Heartbeat {
    /// Controller mode.
    pub mode: ControllerMode,
    /// Id of the active control law (DBC value table; 0 = none).
    pub active_law: u8,
    /// Fault bits (meaning in the DBC comment of the faults signal).
    pub faults: u32,
}

/// Names of the heartbeat message and its signals in the DBC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HeartbeatNames<'a> {
    /// Message name.
    pub message: &'a str,
    /// Mode signal (value table must match [`ControllerMode`]).
    pub mode: &'a str,
    /// Active-law signal.
    pub active_law: &'a str,
    /// Fault bitfield signal.
    pub faults: &'a str,
}

impl HeartbeatNames<'static> {
    /// The names in `config/skid.dbc`.
    pub const SKID: HeartbeatNames<'static> = HeartbeatNames {
        message: "CTRL_Heartbeat",
        mode: "Mode",
        active_law: "ActiveLaw",
        faults: "Faults",
    };
}

/// Encoder/decoder of the heartbeat frame (no allocation after [`HeartbeatCodec::new`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HeartbeatCodec {
    guard: FrameGuard,
    mode: SignalLayout,
    active_law: SignalLayout,
    faults: SignalLayout,
}

fn unfit(message: &str, signal: &str, reason: impl Into<String>) -> BindingError {
    BindingError::Unfit {
        message: message.to_string(),
        signal: signal.to_string(),
        reason: reason.into(),
    }
}

/// An unsigned, factor 1, offset 0 signal of at most `max_bits` bits.
fn plain_unsigned(
    msg: &str,
    sig: Option<&SignalDef>,
    name: &str,
    max_bits: u8,
) -> Result<SignalLayout, BindingError> {
    let s = sig.ok_or_else(|| unfit(msg, name, "no such signal"))?;
    let l = *s.layout();
    if l.is_signed() || s.factor() != 1.0 || s.offset() != 0.0 || l.size() > max_bits {
        return Err(unfit(
            msg,
            name,
            format!("must be unsigned, factor 1, offset 0, at most {max_bits} bits"),
        ));
    }
    Ok(l)
}

impl HeartbeatCodec {
    /// Find the heartbeat in `db` and check it: mode (≥ 3 bits, value table naming every
    /// [`ControllerMode`]), active law (≤ 8 bits), faults (≤ 32 bits), all unsigned raw.
    pub fn new(db: &CanDatabase, names: &HeartbeatNames<'_>) -> Result<Self, BindingError> {
        let msg = names.message;
        let m = db
            .message(msg)
            .ok_or_else(|| unfit(msg, "", "no such message"))?;
        let mode = plain_unsigned(msg, m.signal(names.mode), names.mode, 8)?;
        if mode.size() < 3 {
            return Err(unfit(msg, names.mode, "needs at least 3 bits for 5 modes"));
        }
        if let Some(s) = m.signal(names.mode) {
            for mo in ControllerMode::ALL {
                if s.value_name(i64::from(mo.raw())) != Some(mo.name()) {
                    return Err(unfit(
                        msg,
                        names.mode,
                        format!(
                            "value table must map {} to \"{}\" (found {:?})",
                            mo.raw(),
                            mo.name(),
                            s.value_name(i64::from(mo.raw()))
                        ),
                    ));
                }
            }
        }
        let active_law = plain_unsigned(msg, m.signal(names.active_law), names.active_law, 8)?;
        let faults = plain_unsigned(msg, m.signal(names.faults), names.faults, 32)?;
        Ok(HeartbeatCodec {
            guard: m.guard(),
            mode,
            active_law,
            faults,
        })
    }

    /// Identifier of the heartbeat frame.
    pub fn frame_id(&self) -> FrameId {
        self.guard.id()
    }

    /// Payload length, bytes.
    pub fn dlc(&self) -> u8 {
        self.guard.dlc()
    }

    /// Width of the alive counter, bits (`None`: the message has none).
    pub fn alive_bits(&self) -> Option<u8> {
        self.guard.alive_bits()
    }

    /// Encode a heartbeat with alive counter `alive`; the payload is the first
    /// [`HeartbeatCodec::dlc`] bytes. Law and fault values wider than their signals are
    /// truncated to the signal width.
    pub fn encode(&self, hb: &Heartbeat, alive: u8) -> [u8; MAX_PAYLOAD] {
        let mut data = [0u8; MAX_PAYLOAD];
        self.mode.pack(&mut data, i128::from(hb.mode.raw()));
        self.active_law.pack(&mut data, i128::from(hb.active_law));
        self.faults.pack(&mut data, i128::from(hb.faults));
        self.guard.seal(&mut data, alive);
        data
    }

    /// Decode a received heartbeat payload: checks DLC and CRC, then the mode.
    /// Returns the heartbeat and its alive counter.
    pub fn decode(&self, data: &[u8]) -> Result<(Heartbeat, Option<u8>), FrameError> {
        let frame = self.guard.check(data)?;
        let raw_mode = self.mode.unpack(&frame);
        let mode = u8::try_from(raw_mode)
            .ok()
            .and_then(ControllerMode::from_raw)
            .ok_or(FrameError::InvalidValue {
                id: self.guard.id(),
                raw: raw_mode as i64,
            })?;
        let hb = Heartbeat {
            mode,
            active_law: self.active_law.unpack(&frame) as u8,
            faults: self.faults.unpack(&frame) as u32,
        };
        Ok((hb, self.guard.alive(&frame)))
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

    #[test]
    fn heartbeat_bit_exact_and_round_trip() {
        let hb = HeartbeatCodec::new(&skid(), &HeartbeatNames::SKID).expect("heartbeat");
        assert_eq!(hb.frame_id(), FrameId::Standard(0x80));
        assert_eq!(hb.alive_bits(), Some(8));
        let v = Heartbeat {
            mode: ControllerMode::FailSafe,
            active_law: 7,
            faults: 0x0000_0105,
        };
        let data = hb.encode(&v, 0xAB);
        // byte 0: mode 3 in the low nibble, law 7 in the high nibble; byte 1: counter;
        // bytes 2..5: faults little-endian; byte 6 unused; byte 7 CRC.
        assert_eq!(&data[..7], &[0x73, 0xAB, 0x05, 0x01, 0x00, 0x00, 0x00]);
        assert_eq!(data[7], frame_crc(FrameId::Standard(0x80), &data, 7));
        assert_eq!(hb.decode(&data), Ok((v, Some(0xAB))));
    }

    #[test]
    fn heartbeat_rejects_unknown_mode_and_bad_crc() {
        let hb = HeartbeatCodec::new(&skid(), &HeartbeatNames::SKID).expect("heartbeat");
        let mut data = [0x09, 0, 0, 0, 0, 0, 0, 0];
        data[7] = frame_crc(FrameId::Standard(0x80), &data, 7);
        assert_eq!(
            hb.decode(&data),
            Err(FrameError::InvalidValue {
                id: FrameId::Standard(0x80),
                raw: 9
            })
        );
        data[7] ^= 0xFF;
        assert!(matches!(hb.decode(&data), Err(FrameError::BadCrc { .. })));
        assert!(matches!(
            hb.decode(&data[..4]),
            Err(FrameError::WrongDlc { actual: 4, .. })
        ));
    }

    #[test]
    fn heartbeat_names_checked() {
        let db = skid();
        let e = HeartbeatCodec::new(
            &db,
            &HeartbeatNames {
                mode: "Modus",
                ..HeartbeatNames::SKID
            },
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "message CTRL_Heartbeat, signal Modus: no such signal"
        );
        // A mode signal without the value table is rejected.
        let e = HeartbeatCodec::new(
            &db,
            &HeartbeatNames {
                mode: "ActiveLaw",
                ..HeartbeatNames::SKID
            },
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("value table must map 0 to \"init\""),
            "{e}"
        );
        assert_eq!(ControllerMode::from_raw(4), Some(ControllerMode::Shutdown));
        assert_eq!(ControllerMode::from_raw(5), None);
    }
}
