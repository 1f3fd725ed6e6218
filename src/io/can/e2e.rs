//! End-to-end protection of frames: DLC check, alive counter and CRC-8.
//!
//! Every frame of `config/skid.dbc` carries an alive counter (the sender adds 1 per frame,
//! modulo 2^bits) and a CRC byte. The CRC is CRC-8/SAE-J1850 (polynomial 0x1D, initial value
//! 0xFF, no reflection, final XOR 0xFF; check value 0x4B over `b"123456789"`) computed over
//! the 4 bytes of the identifier value (no flag bits, least significant byte first) followed by
//! every payload byte except the CRC byte, in order. The counter is written before the CRC.

use std::fmt;

use super::bits::{SignalLayout, MAX_PAYLOAD};
use super::dbc::FrameId;

/// CRC-8/SAE-J1850 lookup table (polynomial 0x1D, MSB first).
const CRC8_TABLE: [u8; 256] = {
    let mut table = [0u8; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u8;
        let mut bit = 0;
        while bit < 8 {
            c = if c & 0x80 != 0 {
                (c << 1) ^ 0x1D
            } else {
                c << 1
            };
            bit += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
};

/// Running CRC-8/SAE-J1850.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Crc8 {
    state: u8,
}

impl Default for Crc8 {
    fn default() -> Self {
        Crc8::new()
    }
}

impl Crc8 {
    /// A CRC at its initial value 0xFF.
    pub const fn new() -> Crc8 {
        Crc8 { state: 0xFF }
    }
    /// Feed bytes.
    #[inline]
    pub fn update(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.state = CRC8_TABLE[usize::from(self.state ^ b)];
        }
    }
    /// The CRC (final XOR 0xFF applied).
    #[inline]
    pub const fn finish(self) -> u8 {
        self.state ^ 0xFF
    }
}

/// CRC-8/SAE-J1850 of `bytes`.
pub fn crc8_sae_j1850(bytes: &[u8]) -> u8 {
    let mut c = Crc8::new();
    c.update(bytes);
    c.finish()
}

/// The frame CRC: over the identifier (4 bytes, little-endian) and `payload` without the byte
/// at `crc_byte`.
pub fn frame_crc(id: FrameId, payload: &[u8], crc_byte: usize) -> u8 {
    let mut c = Crc8::new();
    c.update(&id.raw().to_le_bytes());
    for (i, b) in payload.iter().enumerate() {
        if i != crc_byte {
            c.update(std::slice::from_ref(b));
        }
    }
    c.finish()
}

/// Why a received frame was rejected. `Copy`, no heap: the runtime counts these.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// No message in the database has this identifier.
    #[error("unknown CAN id {id}")]
    UnknownId {
        /// Received identifier.
        id: FrameId,
    },
    /// Payload length differs from the message's DLC.
    #[error("CAN id {id}: {actual} data bytes, expected {expected}")]
    WrongDlc {
        /// Identifier.
        id: FrameId,
        /// DLC from the DBC.
        expected: u8,
        /// Received length.
        actual: usize,
    },
    /// CRC byte does not match the payload.
    #[error("CAN id {id}: CRC {received:#04X} received, {computed:#04X} computed")]
    BadCrc {
        /// Identifier.
        id: FrameId,
        /// CRC computed over the received frame.
        computed: u8,
        /// CRC byte in the frame.
        received: u8,
    },
    /// A signal holds a value its value table does not define (e.g. heartbeat mode 9).
    #[error("CAN id {id}: value {raw} is not defined for this signal")]
    InvalidValue {
        /// Identifier.
        id: FrameId,
        /// Raw value.
        raw: i64,
    },
}

/// DLC, alive-counter and CRC handling for one message (from [`super::MessageDef::guard`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameGuard {
    id: FrameId,
    dlc: u8,
    alive: Option<SignalLayout>,
    crc_byte: Option<u8>,
}

impl FrameGuard {
    /// A guard for frames `id` of `dlc` bytes (at most 8) with an optional alive counter and
    /// CRC byte index. A CRC byte index at or beyond the DLC is ignored (no CRC).
    pub fn new(id: FrameId, dlc: u8, alive: Option<SignalLayout>, crc_byte: Option<u8>) -> Self {
        let dlc = dlc.min(MAX_PAYLOAD as u8);
        FrameGuard {
            id,
            dlc,
            alive,
            crc_byte: crc_byte.filter(|b| *b < dlc),
        }
    }

    /// Identifier.
    pub fn id(&self) -> FrameId {
        self.id
    }
    /// Payload length, bytes.
    pub fn dlc(&self) -> u8 {
        self.dlc
    }
    /// Width of the alive counter, bits (`None`: the message has none).
    pub fn alive_bits(&self) -> Option<u8> {
        self.alive.map(|l| l.size())
    }
    /// Index of the CRC byte (`None`: the message has none).
    pub fn crc_byte(&self) -> Option<u8> {
        self.crc_byte
    }

    /// Check a received payload: length equals the DLC and the CRC matches. Returns the
    /// payload zero-padded to 8 bytes.
    #[inline]
    pub fn check(&self, data: &[u8]) -> Result<[u8; MAX_PAYLOAD], FrameError> {
        if data.len() != usize::from(self.dlc) {
            return Err(FrameError::WrongDlc {
                id: self.id,
                expected: self.dlc,
                actual: data.len(),
            });
        }
        let mut frame = [0u8; MAX_PAYLOAD];
        frame[..data.len()].copy_from_slice(data);
        if let Some(at) = self.crc_byte {
            let at = usize::from(at);
            let computed = frame_crc(self.id, data, at);
            let received = frame.get(at).copied().unwrap_or_default();
            if computed != received {
                return Err(FrameError::BadCrc {
                    id: self.id,
                    computed,
                    received,
                });
            }
        }
        Ok(frame)
    }

    /// Alive counter value in a frame.
    #[inline]
    pub fn alive(&self, frame: &[u8; MAX_PAYLOAD]) -> Option<u8> {
        self.alive.map(|l| l.unpack(frame) as u8)
    }

    /// Write the alive counter (taken modulo 2^bits), then the CRC.
    #[inline]
    pub fn seal(&self, frame: &mut [u8; MAX_PAYLOAD], alive: u8) {
        if let Some(l) = self.alive {
            l.pack(frame, i128::from(alive));
        }
        if let Some(at) = self.crc_byte {
            let at = usize::from(at);
            let dlc = usize::from(self.dlc);
            let crc = frame_crc(self.id, frame.get(..dlc).unwrap_or(&[]), at);
            if let Some(byte) = frame.get_mut(at) {
                *byte = crc;
            }
        }
    }
}

/// Alive counter of a sender: 0, 1, …, 2^bits − 1, 0, …
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AliveCounter {
    mask: u8,
    next: u8,
}

impl AliveCounter {
    /// A counter of `bits` bits (1..=8, clamped), starting at 0.
    pub fn new(bits: u8) -> AliveCounter {
        let bits = bits.clamp(1, 8);
        AliveCounter {
            mask: (0xFFu16 >> (8 - bits)) as u8,
            next: 0,
        }
    }
    /// The value for the next frame; advances the counter.
    #[inline]
    pub fn next_value(&mut self) -> u8 {
        let v = self.next;
        self.next = self.next.wrapping_add(1) & self.mask;
        v
    }
    /// The value the next frame will get, without advancing.
    pub fn peek(&self) -> u8 {
        self.next
    }
}

/// How a received alive counter relates to the previous one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AliveStatus {
    /// First frame seen (or first after [`AliveChecker::reset`]).
    First,
    /// Previous + 1: nothing lost.
    InSequence,
    /// Same value as before: the sender is stuck or the frame was duplicated.
    Repeated,
    /// `missed` frames were lost (modulo 2^bits: a counter cannot tell k from k + 2^bits).
    Skipped {
        /// Number of counter values skipped.
        missed: u8,
    },
}

impl fmt::Display for AliveStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            AliveStatus::First => f.write_str("first frame"),
            AliveStatus::InSequence => f.write_str("in sequence"),
            AliveStatus::Repeated => f.write_str("repeated counter"),
            AliveStatus::Skipped { missed } => write!(f, "{missed} frame(s) skipped"),
        }
    }
}

/// Receiver side: compares each alive counter with the previous one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AliveChecker {
    mask: u8,
    last: Option<u8>,
}

impl AliveChecker {
    /// A checker for a counter of `bits` bits (1..=8, clamped).
    pub fn new(bits: u8) -> AliveChecker {
        let bits = bits.clamp(1, 8);
        AliveChecker {
            mask: (0xFFu16 >> (8 - bits)) as u8,
            last: None,
        }
    }
    /// Classify `value` against the previous counter and remember it.
    #[inline]
    pub fn check(&mut self, value: u8) -> AliveStatus {
        let value = value & self.mask;
        let status = match self.last {
            None => AliveStatus::First,
            Some(last) => match value.wrapping_sub(last) & self.mask {
                0 => AliveStatus::Repeated,
                1 => AliveStatus::InSequence,
                d => AliveStatus::Skipped { missed: d - 1 },
            },
        };
        self.last = Some(value);
        status
    }
    /// Forget the previous counter (e.g. after a timeout).
    pub fn reset(&mut self) {
        self.last = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::can::bits::ByteOrder;

    #[test]
    fn crc8_check_value() {
        assert_eq!(crc8_sae_j1850(b"123456789"), 0x4B);
        assert_eq!(crc8_sae_j1850(&[]), 0x00);
        // Incremental feeding equals one shot.
        let mut c = Crc8::new();
        c.update(b"1234");
        c.update(b"56789");
        assert_eq!(c.finish(), 0x4B);
    }

    #[test]
    fn frame_crc_covers_id_and_skips_crc_byte() {
        let payload = [1, 2, 3, 4, 5, 6, 7, 0xEE];
        let expected = crc8_sae_j1850(&[0x00, 0x01, 0, 0, 1, 2, 3, 4, 5, 6, 7]);
        assert_eq!(frame_crc(FrameId::Standard(0x100), &payload, 7), expected);
        // The CRC byte's content does not matter; the id does.
        let mut other = payload;
        other[7] = 0x00;
        assert_eq!(frame_crc(FrameId::Standard(0x100), &other, 7), expected);
        assert_ne!(frame_crc(FrameId::Standard(0x101), &payload, 7), expected);
    }

    #[test]
    fn crc_byte_outside_dlc_is_ignored() {
        let g = FrameGuard::new(FrameId::Standard(1), 4, None, Some(6));
        assert_eq!(g.crc_byte(), None);
        let g = FrameGuard::new(FrameId::Standard(1), 12, None, Some(7));
        assert_eq!((g.dlc(), g.crc_byte()), (8, Some(7)));
    }

    fn guard() -> FrameGuard {
        let alive = SignalLayout::new(48, 4, ByteOrder::Intel, false).expect("layout");
        FrameGuard::new(FrameId::Standard(0x100), 8, Some(alive), Some(7))
    }

    #[test]
    fn seal_then_check() {
        let g = guard();
        let mut frame = [0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0xF0, 0];
        g.seal(&mut frame, 0x1B);
        // Counter 0x1B modulo 16 = 0xB in the low nibble of byte 6; high nibble kept.
        assert_eq!(frame[6], 0xFB);
        assert_eq!(frame[7], frame_crc(FrameId::Standard(0x100), &frame, 7));
        assert_eq!(g.check(&frame), Ok(frame));
        assert_eq!(g.alive(&frame), Some(0xB));

        let mut bad = frame;
        bad[0] ^= 0x01;
        assert!(matches!(
            g.check(&bad),
            Err(FrameError::BadCrc { received, .. }) if received == frame[7]
        ));
        assert_eq!(
            g.check(&frame[..7]),
            Err(FrameError::WrongDlc {
                id: FrameId::Standard(0x100),
                expected: 8,
                actual: 7
            })
        );
        let long = [0u8; 12];
        assert!(matches!(
            g.check(&long),
            Err(FrameError::WrongDlc { actual: 12, .. })
        ));
    }

    #[test]
    fn alive_counter_wraps() {
        let mut c = AliveCounter::new(4);
        let seq: Vec<u8> = (0..18).map(|_| c.next_value()).collect();
        assert_eq!(
            seq,
            [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 0, 1]
        );
        let mut c = AliveCounter::new(8);
        for _ in 0..255 {
            c.next_value();
        }
        assert_eq!(c.next_value(), 255);
        assert_eq!(c.peek(), 0);
    }

    #[test]
    fn alive_checker_flags_skips_and_repeats() {
        let mut k = AliveChecker::new(4);
        assert_eq!(k.check(14), AliveStatus::First);
        assert_eq!(k.check(15), AliveStatus::InSequence);
        assert_eq!(k.check(0), AliveStatus::InSequence, "wrap 15 -> 0");
        assert_eq!(k.check(0), AliveStatus::Repeated);
        assert_eq!(k.check(3), AliveStatus::Skipped { missed: 2 });
        // Going "back" by one = 14 skipped modulo 16.
        assert_eq!(k.check(2), AliveStatus::Skipped { missed: 14 });
        k.reset();
        assert_eq!(k.check(9), AliveStatus::First);
        let mut k = AliveChecker::new(8);
        k.check(255);
        assert_eq!(k.check(0), AliveStatus::InSequence);
        assert_eq!(k.check(10), AliveStatus::Skipped { missed: 9 });
        assert_eq!(
            AliveStatus::Skipped { missed: 9 }.to_string(),
            "9 frame(s) skipped"
        );
    }
}
