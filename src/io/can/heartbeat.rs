//! The controller heartbeat frame: mode, active law, fault bits, alive counter, CRC.

use serde::{Deserialize, Serialize};

use super::bits::{SignalLayout, MAX_PAYLOAD};
use super::codec::BindingError;
use super::dbc::{CanDatabase, FrameId, SignalDef, SignalRole};
use super::e2e::{FrameError, FrameGuard};
use crate::vocab::Mode;

/// Content of a heartbeat frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Heartbeat {
    /// Controller mode.
    pub mode: Mode,
    /// Id of the active control law (DBC value table; 0 = none).
    pub active_law: u8,
    /// Fault bits (meaning in the DBC comment of the faults signal).
    pub faults: u32,
}

/// Names of the heartbeat message and its signals in the DBC. Every signal is optional: a
/// device that watches only a counter gets only a counter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HeartbeatNames<'a> {
    /// Message name.
    pub message: &'a str,
    /// Alive counter signal: unsigned, factor 1, offset 0, 1..32 bits; +1 per heartbeat,
    /// wrapping at 2^length − 1 → 0. May be the message's `AntisurgeRole AliveCounter`
    /// signal (the end-to-end counter) or a plain signal.
    pub counter: Option<&'a str>,
    /// Mode signal (value table must match [`Mode`]).
    pub mode: Option<&'a str>,
    /// Active-law signal.
    pub active_law: Option<&'a str>,
    /// Fault bitfield signal (the fault word of src/faults.rs).
    pub faults: Option<&'a str>,
}

impl HeartbeatNames<'static> {
    /// The names in `config/skid.dbc`.
    pub const SKID: HeartbeatNames<'static> = HeartbeatNames {
        message: "CTRL_Heartbeat",
        counter: Some("AliveCounter"),
        mode: Some("Mode"),
        active_law: Some("ActiveLaw"),
        faults: Some("Faults"),
    };
}

/// `[bus.can.heartbeat]`: which DBC message is the controller heartbeat and which of its
/// signals carry the alive counter, mode, active law and fault word (each optional; a signal
/// left out is not written). Without the section: `config/skid.dbc`'s `CTRL_Heartbeat` with
/// `AliveCounter`, `Mode`, `ActiveLaw` and `Faults`.
///
/// ```toml
/// [bus.can.heartbeat]            # a device that watches a 16-bit counter only
/// message = "DCS_Watchdog"
/// counter = "WdCounter"
/// ```
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeartbeatConfig {
    /// DBC message sent as the heartbeat.
    pub message: String,
    /// Alive counter signal (width and wrap from its DBC length).
    #[serde(default)]
    pub counter: Option<String>,
    /// Mode signal (value table 0 init, 1 manual, 2 auto, 3 fail_safe, 4 shutdown).
    #[serde(default)]
    pub mode: Option<String>,
    /// Active-law signal (DBC ActiveLaw ids).
    #[serde(default)]
    pub law: Option<String>,
    /// Fault word signal (src/faults.rs categories).
    #[serde(default)]
    pub faults: Option<String>,
}

impl HeartbeatConfig {
    /// The names to look up in the DBC.
    pub fn names(&self) -> HeartbeatNames<'_> {
        HeartbeatNames {
            message: &self.message,
            counter: self.counter.as_deref(),
            mode: self.mode.as_deref(),
            active_law: self.law.as_deref(),
            faults: self.faults.as_deref(),
        }
    }
}

/// Where the heartbeat's alive counter is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum CounterSlot {
    /// No counter.
    None,
    /// The message's end-to-end counter (`AntisurgeRole AliveCounter`), written by the guard
    /// before the CRC.
    Guard(u8),
    /// A plain signal of the heartbeat.
    Signal(SignalLayout),
}

/// Encoder/decoder of the heartbeat frame (no allocation after [`HeartbeatCodec::new`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HeartbeatCodec {
    guard: FrameGuard,
    counter: CounterSlot,
    mode: Option<SignalLayout>,
    active_law: Option<SignalLayout>,
    faults: Option<SignalLayout>,
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
    /// Find the heartbeat in `db` and check the named signals: counter (≤ 32 bits), mode
    /// (≥ 3 bits, value table naming every [`Mode`]), active law (≤ 8 bits), faults
    /// (≤ 32 bits), all unsigned raw.
    pub fn new(db: &CanDatabase, names: &HeartbeatNames<'_>) -> Result<Self, BindingError> {
        let msg = names.message;
        let m = db
            .message(msg)
            .ok_or_else(|| unfit(msg, "", "no such message"))?;
        let mode = match names.mode {
            None => None,
            Some(name) => {
                let s = m.signal(name);
                let l = plain_unsigned(msg, s, name, 8)?;
                if l.size() < 3 {
                    return Err(unfit(msg, name, "needs at least 3 bits for 5 modes"));
                }
                for mo in Mode::ALL {
                    let found = s.and_then(|s| s.value_name(i64::from(mo.code())));
                    if found != Some(mo.name()) {
                        return Err(unfit(
                            msg,
                            name,
                            format!(
                                "value table must map {} to \"{}\" (found {:?})",
                                mo.code(),
                                mo.name(),
                                found
                            ),
                        ));
                    }
                }
                Some(l)
            }
        };
        let active_law = names
            .active_law
            .map(|n| plain_unsigned(msg, m.signal(n), n, 8))
            .transpose()?;
        let faults = names
            .faults
            .map(|n| plain_unsigned(msg, m.signal(n), n, 32))
            .transpose()?;
        let counter = match names.counter {
            None => CounterSlot::None,
            Some(n) => {
                let s = m.signal(n).ok_or_else(|| unfit(msg, n, "no such signal"))?;
                match s.role() {
                    SignalRole::AliveCounter => CounterSlot::Guard(s.layout().size()),
                    SignalRole::Data => CounterSlot::Signal(plain_unsigned(msg, Some(s), n, 32)?),
                    other => {
                        return Err(unfit(
                            msg,
                            n,
                            format!("is the message's {other}, not a counter"),
                        ))
                    }
                }
            }
        };
        Ok(HeartbeatCodec {
            guard: m.guard(),
            counter,
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

    /// Width of the heartbeat's alive counter, bits (`None`: no counter named).
    pub fn alive_bits(&self) -> Option<u8> {
        match self.counter {
            CounterSlot::None => None,
            CounterSlot::Guard(bits) => Some(bits),
            CounterSlot::Signal(l) => Some(l.size()),
        }
    }

    /// Whether the heartbeat carries a mode signal.
    pub fn has_mode(&self) -> bool {
        self.mode.is_some()
    }

    /// Encode a heartbeat with alive counter `alive` (taken modulo 2^counter width); the
    /// payload is the first [`HeartbeatCodec::dlc`] bytes. Law and fault values wider than
    /// their signals are truncated to the signal width; signals not named stay 0.
    pub fn encode(&self, hb: &Heartbeat, alive: u32) -> [u8; MAX_PAYLOAD] {
        let mut data = [0u8; MAX_PAYLOAD];
        if let Some(l) = self.mode {
            l.pack(&mut data, i128::from(hb.mode.code()));
        }
        if let Some(l) = self.active_law {
            l.pack(&mut data, i128::from(hb.active_law));
        }
        if let Some(l) = self.faults {
            l.pack(&mut data, i128::from(hb.faults));
        }
        let guard_alive = match self.counter {
            CounterSlot::Signal(l) => {
                l.pack(&mut data, i128::from(alive) & ((1i128 << l.size()) - 1));
                0
            }
            // the guard takes its counter modulo its own width
            CounterSlot::Guard(_) | CounterSlot::None => alive as u8,
        };
        self.guard.seal(&mut data, guard_alive);
        data
    }

    /// Decode a received heartbeat payload: checks DLC and CRC, then the mode. Returns the
    /// heartbeat and the low 8 bits of its alive counter (enough to see a skipped or repeated
    /// frame; a wider counter wraps at a multiple of 256). A heartbeat without a mode signal
    /// reads as `auto` (its arrival is all it says); one without law or faults as 0.
    pub fn decode(&self, data: &[u8]) -> Result<(Heartbeat, Option<u8>), FrameError> {
        let frame = self.guard.check(data)?;
        let mode = match self.mode {
            None => Mode::Auto,
            Some(l) => {
                let raw_mode = l.unpack(&frame);
                u8::try_from(raw_mode)
                    .ok()
                    .and_then(Mode::from_code)
                    .ok_or(FrameError::InvalidValue {
                        id: self.guard.id(),
                        raw: raw_mode as i64,
                    })?
            }
        };
        let hb = Heartbeat {
            mode,
            active_law: self.active_law.map_or(0, |l| l.unpack(&frame) as u8),
            faults: self.faults.map_or(0, |l| l.unpack(&frame) as u32),
        };
        let alive = match self.counter {
            CounterSlot::None => None,
            CounterSlot::Guard(_) => self.guard.alive(&frame),
            CounterSlot::Signal(l) => Some(l.unpack(&frame) as u8),
        };
        Ok((hb, alive))
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
            mode: Mode::FailSafe,
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
                mode: Some("Modus"),
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
                mode: Some("ActiveLaw"),
                ..HeartbeatNames::SKID
            },
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("value table must map 0 to \"init\""),
            "{e}"
        );
        assert_eq!(Mode::from_code(4), Some(Mode::Shutdown));
        assert_eq!(Mode::from_code(5), None);
    }
}
