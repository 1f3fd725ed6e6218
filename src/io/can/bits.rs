//! Bit-level packing of DBC signals into classic CAN payloads: pure and allocation-free.
//!
//! Bit numbering follows the DBC convention: bit `n` of the payload is bit `n % 8` of byte
//! `n / 8`, bit 0 being the least significant bit of a byte.
//!
//! - Intel (`@1`, little-endian): the start bit is the signal's least significant bit; more
//!   significant bits go to higher bit numbers, continuing into the next byte.
//! - Motorola (`@0`, big-endian): the start bit is the signal's most significant bit; less
//!   significant bits go down within the byte (bit 7 → 0) and then continue at bit 7 of the
//!   *next* byte (the "sawtooth" numbering).
//!
//! Internally the 8-byte payload is read as one `u64`: little-endian for Intel signals, so a
//! signal is a contiguous run starting at its start bit, and big-endian for Motorola signals, so
//! a signal is a contiguous run ending at its most significant bit.
//!
//! Raw values are carried as `i128`, which holds every raw value of a signal up to 64 bits,
//! signed or unsigned.

use std::fmt;

/// Payload size of a classic CAN frame, bytes.
pub const MAX_PAYLOAD: usize = 8;

/// Byte order of a signal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ByteOrder {
    /// DBC `@1`, little-endian: the start bit is the least significant bit.
    Intel,
    /// DBC `@0`, big-endian: the start bit is the most significant bit (sawtooth numbering).
    Motorola,
}

impl fmt::Display for ByteOrder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ByteOrder::Intel => "Intel @1",
            ByteOrder::Motorola => "Motorola @0",
        })
    }
}

/// Why a signal's position does not fit a classic CAN payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum LayoutError {
    /// Size outside 1..=64 bits.
    #[error("size {size} bits is not in 1..=64")]
    BadSize {
        /// Size as written in the DBC, bits.
        size: u64,
    },
    /// Start bit beyond bit 63.
    #[error("start bit {start_bit} is outside the 64-bit payload")]
    StartOutOfRange {
        /// Start bit as written in the DBC.
        start_bit: u64,
    },
    /// The bits run past byte 7.
    #[error("{size} bits from start bit {start_bit} ({byte_order}) run past the end of an 8-byte payload")]
    PastEnd {
        /// Start bit.
        start_bit: u64,
        /// Size, bits.
        size: u64,
        /// Byte order.
        byte_order: ByteOrder,
    },
}

/// Where a signal sits in the payload and how its raw bits are interpreted.
///
/// Constructed only through [`SignalLayout::new`], so every layout fits an 8-byte payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SignalLayout {
    start_bit: u8,
    size: u8,
    byte_order: ByteOrder,
    signed: bool,
    /// Position of the least significant bit in the `u64` view of the payload
    /// (little-endian view for Intel, big-endian view for Motorola).
    shift: u8,
}

/// All-ones mask of `size` bits, `size` in 1..=64.
#[inline]
const fn low_mask(size: u8) -> u64 {
    u64::MAX >> (64 - size as u32)
}

impl SignalLayout {
    /// A validated layout: `start_bit` and `size` as written in the DBC (`start|size@order±`).
    pub fn new(
        start_bit: u64,
        size: u64,
        byte_order: ByteOrder,
        signed: bool,
    ) -> Result<SignalLayout, LayoutError> {
        if !(1..=64).contains(&size) {
            return Err(LayoutError::BadSize { size });
        }
        if start_bit > 63 {
            return Err(LayoutError::StartOutOfRange { start_bit });
        }
        let past_end = LayoutError::PastEnd {
            start_bit,
            size,
            byte_order,
        };
        let shift = match byte_order {
            ByteOrder::Intel => {
                if start_bit + size > 64 {
                    return Err(past_end);
                }
                start_bit
            }
            ByteOrder::Motorola => {
                // Position of the MSB in the big-endian u64 view: byte k occupies bits
                // (7 - k) * 8 .. (7 - k) * 8 + 7 of that view.
                let msb = (7 - start_bit / 8) * 8 + start_bit % 8;
                if msb + 1 < size {
                    return Err(past_end);
                }
                msb + 1 - size
            }
        };
        Ok(SignalLayout {
            start_bit: start_bit as u8,
            size: size as u8,
            byte_order,
            signed,
            shift: shift as u8,
        })
    }

    /// Start bit as written in the DBC.
    pub fn start_bit(&self) -> u8 {
        self.start_bit
    }

    /// Size, bits (1..=64).
    pub fn size(&self) -> u8 {
        self.size
    }

    /// Byte order.
    pub fn byte_order(&self) -> ByteOrder {
        self.byte_order
    }

    /// Whether the raw value is two's-complement signed (DBC `-`).
    pub fn is_signed(&self) -> bool {
        self.signed
    }

    /// The bits the signal occupies, as a mask in DBC numbering (bit `n` = byte `n / 8`,
    /// bit `n % 8`). Used to detect overlaps.
    pub fn occupancy(&self) -> u64 {
        let run = low_mask(self.size) << self.shift;
        match self.byte_order {
            ByteOrder::Intel => run,
            // Big-endian view → DBC numbering: byte lanes are mirrored.
            ByteOrder::Motorola => run.swap_bytes(),
        }
    }

    /// Number of payload bytes needed to hold the signal (index of its last byte + 1).
    pub fn bytes_needed(&self) -> u8 {
        let occ = self.occupancy();
        // occupancy is never zero: size >= 1.
        ((63 - occ.leading_zeros()) / 8 + 1) as u8
    }

    /// Smallest raw value.
    pub fn raw_min(&self) -> i128 {
        if self.signed {
            -(1i128 << (self.size - 1))
        } else {
            0
        }
    }

    /// Largest raw value.
    pub fn raw_max(&self) -> i128 {
        if self.signed {
            (1i128 << (self.size - 1)) - 1
        } else {
            (1i128 << self.size) - 1
        }
    }

    /// The raw pattern that means "not available" (a NaN value: no reading, or an actuator
    /// the controller does not drive): all bits set for an unsigned signal, the most negative
    /// value for a signed one (the SAE J1939 convention; skid.dbc states it per signal).
    /// A receiver decodes it as NaN, so a failed transmitter or an undriven actuator is never
    /// mistaken for a value, not even for the zero of a fresh frame.
    pub fn raw_not_available(&self) -> i128 {
        if self.signed {
            self.raw_min()
        } else {
            self.raw_max()
        }
    }

    /// Smallest raw value that carries a number ([`Self::raw_not_available`] excluded).
    pub fn raw_value_min(&self) -> i128 {
        if self.signed {
            self.raw_min() + 1
        } else {
            self.raw_min()
        }
    }

    /// Largest raw value that carries a number ([`Self::raw_not_available`] excluded).
    pub fn raw_value_max(&self) -> i128 {
        if self.signed {
            self.raw_max()
        } else {
            self.raw_max() - 1
        }
    }

    #[inline]
    fn word(&self, data: &[u8; MAX_PAYLOAD]) -> u64 {
        match self.byte_order {
            ByteOrder::Intel => u64::from_le_bytes(*data),
            ByteOrder::Motorola => u64::from_be_bytes(*data),
        }
    }

    /// The raw value in `data`, sign-extended for signed signals.
    #[inline]
    pub fn unpack(&self, data: &[u8; MAX_PAYLOAD]) -> i128 {
        let bits = (self.word(data) >> self.shift) & low_mask(self.size);
        if self.signed {
            let spare = 64 - u32::from(self.size);
            // Move the sign bit to bit 63, then arithmetic shift back.
            (((bits << spare) as i64) >> spare) as i128
        } else {
            bits as i128
        }
    }

    /// Write the low `size` bits of `raw` (two's complement for negative values) into `data`,
    /// leaving every other bit unchanged. The caller clamps; see [`physical_to_raw`].
    #[inline]
    pub fn pack(&self, data: &mut [u8; MAX_PAYLOAD], raw: i128) {
        let mask = low_mask(self.size) << self.shift;
        let bits = ((raw as u64) << self.shift) & mask;
        let word = (self.word(data) & !mask) | bits;
        *data = match self.byte_order {
            ByteOrder::Intel => word.to_le_bytes(),
            ByteOrder::Motorola => word.to_be_bytes(),
        };
    }
}

/// What happened when a physical value was turned into a raw value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum EncodeStatus {
    /// The rounded raw value fit the signal.
    InRange,
    /// The value was outside the raw range (or infinite) and was clamped to its limit.
    Clamped,
    /// The value was NaN: nothing was written ([`pack_physical`]), or the "not available"
    /// pattern ([`pack_value`]).
    NotANumber,
}

/// Physical value of a raw value: `raw × factor + offset`.
#[inline]
pub fn raw_to_physical(raw: i128, factor: f64, offset: f64) -> f64 {
    raw as f64 * factor + offset
}

/// Raw value of a physical value: `round((physical − offset) / factor)`, ties to even (as
/// Python's `round`, so results match cantools bit for bit), clamped to the raw range of
/// `layout`. Returns `None` for NaN.
#[inline]
pub fn physical_to_raw(
    physical: f64,
    factor: f64,
    offset: f64,
    layout: &SignalLayout,
) -> Option<(i128, EncodeStatus)> {
    let scaled = ((physical - offset) / factor).round_ties_even();
    if scaled.is_nan() {
        return None;
    }
    // `as` saturates (±inf → i128 limits), far beyond any 64-bit raw range.
    let raw = scaled as i128;
    let (lo, hi) = (layout.raw_min(), layout.raw_max());
    Some(if raw < lo {
        (lo, EncodeStatus::Clamped)
    } else if raw > hi {
        (hi, EncodeStatus::Clamped)
    } else {
        (raw, EncodeStatus::InRange)
    })
}

/// Encode `physical` into `data` at `layout` (plain DBC semantics). NaN leaves `data`
/// unchanged.
#[inline]
pub fn pack_physical(
    data: &mut [u8; MAX_PAYLOAD],
    layout: &SignalLayout,
    factor: f64,
    offset: f64,
    physical: f64,
) -> EncodeStatus {
    match physical_to_raw(physical, factor, offset, layout) {
        Some((raw, status)) => {
            layout.pack(data, raw);
            status
        }
        None => EncodeStatus::NotANumber,
    }
}

/// Decode the physical value at `layout` from `data` (plain DBC semantics).
#[inline]
pub fn unpack_physical(
    data: &[u8; MAX_PAYLOAD],
    layout: &SignalLayout,
    factor: f64,
    offset: f64,
) -> f64 {
    raw_to_physical(layout.unpack(data), factor, offset)
}

/// Encode a value of a bound signal (the signal map's convention on top of the DBC): NaN
/// writes the "not available" pattern ([`SignalLayout::raw_not_available`]), a number is
/// clamped to the raw range that carries numbers, so it can never read as "not available".
#[inline]
pub fn pack_value(
    data: &mut [u8; MAX_PAYLOAD],
    layout: &SignalLayout,
    factor: f64,
    offset: f64,
    value: f64,
) -> EncodeStatus {
    match physical_to_raw(value, factor, offset, layout) {
        Some((raw, status)) => {
            let kept = raw.clamp(layout.raw_value_min(), layout.raw_value_max());
            layout.pack(data, kept);
            if kept == raw {
                status
            } else {
                EncodeStatus::Clamped
            }
        }
        None => {
            layout.pack(data, layout.raw_not_available());
            EncodeStatus::NotANumber
        }
    }
}

/// Decode a value of a bound signal: NaN for the "not available" pattern.
#[inline]
pub fn unpack_value(
    data: &[u8; MAX_PAYLOAD],
    layout: &SignalLayout,
    factor: f64,
    offset: f64,
) -> f64 {
    let raw = layout.unpack(data);
    if raw == layout.raw_not_available() {
        f64::NAN
    } else {
        raw_to_physical(raw, factor, offset)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ByteOrder::{Intel, Motorola};

    fn layout(start: u64, size: u64, order: ByteOrder, signed: bool) -> SignalLayout {
        SignalLayout::new(start, size, order, signed).expect("valid test layout")
    }

    /// Pack into a zeroed frame, check the exact bytes, and read the value back.
    fn roundtrip(l: &SignalLayout, raw: i128, expected: [u8; 8]) {
        let mut data = [0u8; 8];
        l.pack(&mut data, raw);
        assert_eq!(data, expected, "pack {raw:#x} into {l:?}");
        assert_eq!(l.unpack(&data), raw, "unpack {l:?}");
    }

    #[test]
    fn intel_byte_aligned() {
        let l = layout(0, 8, Intel, false);
        roundtrip(&l, 0xAB, [0xAB, 0, 0, 0, 0, 0, 0, 0]);
        let l = layout(16, 16, Intel, false);
        roundtrip(&l, 0x1234, [0, 0, 0x34, 0x12, 0, 0, 0, 0]);
    }

    #[test]
    fn intel_crossing_bytes_odd_start() {
        // 10 bits from bit 3: raw 0x2AB = 0b10_1010_1011.
        // byte 0 bits 3..7 take raw bits 0..4 = 0b01011 -> 0b0101_1000 = 0x58,
        // byte 1 bits 0..4 take raw bits 5..9 = 0b10101 -> 0x15.
        let l = layout(3, 10, Intel, false);
        roundtrip(&l, 0x2AB, [0x58, 0x15, 0, 0, 0, 0, 0, 0]);
        // 12 bits from bit 4: low nibble into byte 0's high nibble, rest into byte 1.
        let l = layout(4, 12, Intel, false);
        roundtrip(&l, 0xA35, [0x50, 0xA3, 0, 0, 0, 0, 0, 0]);
        // 18 bits from bit 18 (bytes 2..4), as OrificeDp in skid.dbc: raw 0x2_5A5A.
        // bits 18..23 = raw bits 0..5 = 0b01_1010 -> byte 2 = 0b0110_1000 = 0x68,
        // byte 3 = raw bits 6..13 = 0x69, byte 4 bits 0..3 = raw bits 14..17 = 0b1001 = 0x9.
        let l = layout(18, 18, Intel, false);
        roundtrip(&l, 0x2_5A5A, [0, 0, 0x68, 0x69, 0x09, 0, 0, 0]);
    }

    #[test]
    fn motorola_byte_aligned() {
        // 16 bits, MSB at bit 7 of byte 0: plain big-endian bytes 0..1.
        let l = layout(7, 16, Motorola, false);
        roundtrip(&l, 0x1234, [0x12, 0x34, 0, 0, 0, 0, 0, 0]);
        // 24 bits from bit 31 (byte 3 bit 7), as PDischarge in skid.dbc.
        let l = layout(31, 24, Motorola, false);
        roundtrip(&l, 0x0A_BC_DE, [0, 0, 0, 0x0A, 0xBC, 0xDE, 0, 0]);
    }

    #[test]
    fn motorola_odd_start_crossing_bytes() {
        // 12 bits, MSB at byte 0 bit 3: byte 0 bits 3..0 = raw bits 11..8, byte 1 = raw 7..0.
        let l = layout(3, 12, Motorola, false);
        roundtrip(&l, 0xABC, [0x0A, 0xBC, 0, 0, 0, 0, 0, 0]);
        // 10 bits, MSB at bit 13 = byte 1 bit 5: byte 1 bits 5..0 = raw bits 9..4,
        // byte 2 bits 7..4 = raw bits 3..0. raw 0x3A5 = 0b11_1010_0101.
        let l = layout(13, 10, Motorola, false);
        roundtrip(&l, 0x3A5, [0, 0x3A, 0x50, 0, 0, 0, 0, 0]);
        // 18 bits, MSB at bit 17 = byte 2 bit 1 (TipClearanceCmd in skid.dbc):
        // byte 2 bits 1..0 = raw bits 17..16, byte 3 = raw 15..8, byte 4 = raw 7..0.
        let l = layout(17, 18, Motorola, false);
        roundtrip(&l, 0x2_C3D4, [0, 0, 0x02, 0xC3, 0xD4, 0, 0, 0]);
    }

    #[test]
    fn signed_values_sign_extend() {
        let l = layout(0, 8, Intel, true);
        roundtrip(&l, -1, [0xFF, 0, 0, 0, 0, 0, 0, 0]);
        roundtrip(&l, -128, [0x80, 0, 0, 0, 0, 0, 0, 0]);
        roundtrip(&l, 127, [0x7F, 0, 0, 0, 0, 0, 0, 0]);
        // 4 bits in the high nibble: 0b1000 = -8.
        let l = layout(4, 4, Intel, true);
        roundtrip(&l, -8, [0x80, 0, 0, 0, 0, 0, 0, 0]);
        // 18-bit Motorola at bit 1 (ThrustPosition): -2 = 0b11_1111_1111_1111_1110.
        let l = layout(1, 18, Motorola, true);
        roundtrip(&l, -2, [0x03, 0xFF, 0xFE, 0, 0, 0, 0, 0]);
        // Most negative value: only the sign bit set = byte 0 bit 1.
        roundtrip(&l, -131_072, [0x02, 0, 0, 0, 0, 0, 0, 0]);
        // 18-bit Intel at 0 (DriveTorqueCmd): -3 = 0x3FFFD.
        let l = layout(0, 18, Intel, true);
        roundtrip(&l, -3, [0xFD, 0xFF, 0x03, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn one_bit_signals() {
        let l = layout(63, 1, Intel, false);
        roundtrip(&l, 1, [0, 0, 0, 0, 0, 0, 0, 0x80]);
        let l = layout(0, 1, Motorola, false);
        roundtrip(&l, 1, [0x01, 0, 0, 0, 0, 0, 0, 0]);
        let l = layout(13, 1, Intel, true);
        // A signed 1-bit signal holds 0 and -1.
        roundtrip(&l, -1, [0, 0x20, 0, 0, 0, 0, 0, 0]);
        assert_eq!((l.raw_min(), l.raw_max()), (-1, 0));
    }

    #[test]
    fn sixty_four_bit_signals() {
        let bytes = [0x01, 0x23, 0x45, 0x67, 0x89, 0xAB, 0xCD, 0xEF];
        let l = layout(0, 64, Intel, false);
        roundtrip(&l, 0xEFCD_AB89_6745_2301, bytes);
        let l = layout(7, 64, Motorola, false);
        roundtrip(&l, 0x0123_4567_89AB_CDEF, bytes);
        let l = layout(0, 64, Intel, true);
        roundtrip(&l, -1, [0xFF; 8]);
        roundtrip(&l, i128::from(i64::MIN), [0, 0, 0, 0, 0, 0, 0, 0x80]);
        let l = layout(0, 64, Intel, false);
        assert_eq!(l.raw_max(), i128::from(u64::MAX));
    }

    #[test]
    fn pack_leaves_other_bits_alone() {
        let l = layout(3, 10, Intel, false);
        let mut data = [0xFF; 8];
        l.pack(&mut data, 0);
        // Bits 3..12 cleared: byte 0 keeps bits 0..2, byte 1 keeps bits 5..7.
        assert_eq!(data, [0x07, 0xE0, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]);
        let l = layout(13, 10, Motorola, false);
        let mut data = [0xFF; 8];
        l.pack(&mut data, 0);
        assert_eq!(data, [0xFF, 0xC0, 0x0F, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]);
    }

    #[test]
    fn occupancy_and_bytes_needed() {
        let l = layout(3, 12, Motorola, false);
        assert_eq!(l.occupancy(), 0xFF0F);
        assert_eq!(l.bytes_needed(), 2);
        let l = layout(3, 10, Intel, false);
        assert_eq!(l.occupancy(), 0x1FF8);
        let l = layout(7, 64, Motorola, false);
        assert_eq!(l.occupancy(), u64::MAX);
        assert_eq!(l.bytes_needed(), 8);
        let l = layout(1, 18, Motorola, true);
        assert_eq!(l.occupancy(), 0x00FF_FF03);
        assert_eq!(l.bytes_needed(), 3);
    }

    #[test]
    fn layout_errors() {
        assert_eq!(
            SignalLayout::new(0, 0, Intel, false),
            Err(LayoutError::BadSize { size: 0 })
        );
        assert_eq!(
            SignalLayout::new(0, 65, Intel, false),
            Err(LayoutError::BadSize { size: 65 })
        );
        assert_eq!(
            SignalLayout::new(64, 1, Intel, false),
            Err(LayoutError::StartOutOfRange { start_bit: 64 })
        );
        assert!(matches!(
            SignalLayout::new(60, 8, Intel, false),
            Err(LayoutError::PastEnd { .. })
        ));
        // Motorola from byte 7 bit 0 has room for one bit only.
        assert!(SignalLayout::new(56, 1, Motorola, false).is_ok());
        let err = SignalLayout::new(56, 2, Motorola, false).unwrap_err();
        assert_eq!(
            err.to_string(),
            "2 bits from start bit 56 (Motorola @0) run past the end of an 8-byte payload"
        );
    }

    #[test]
    fn physical_scaling_and_rounding() {
        let l = layout(0, 8, Intel, true);
        assert_eq!(raw_to_physical(-3, 0.5, -10.0), -11.5);
        assert_eq!(
            physical_to_raw(-11.5, 0.5, -10.0, &l),
            Some((-3, EncodeStatus::InRange))
        );
        // Ties go to even, like Python's round().
        assert_eq!(
            physical_to_raw(2.5, 1.0, 0.0, &l),
            Some((2, EncodeStatus::InRange))
        );
        assert_eq!(
            physical_to_raw(3.5, 1.0, 0.0, &l),
            Some((4, EncodeStatus::InRange))
        );
        assert_eq!(
            physical_to_raw(-2.5, 1.0, 0.0, &l),
            Some((-2, EncodeStatus::InRange))
        );
        // Temperature: 0.01 K per bit, offset 273.15 K. 293.15 K = +20 °C = raw 2000.
        let t = layout(36, 16, Intel, true);
        assert_eq!(
            physical_to_raw(293.15, 0.01, 273.15, &t),
            Some((2000, EncodeStatus::InRange))
        );
        assert_eq!(
            physical_to_raw(0.0, 0.01, 273.15, &t),
            Some((-27315, EncodeStatus::InRange))
        );
    }

    #[test]
    fn clamping_and_nan() {
        let l = layout(0, 8, Intel, true);
        assert_eq!(
            physical_to_raw(1000.0, 1.0, 0.0, &l),
            Some((127, EncodeStatus::Clamped))
        );
        assert_eq!(
            physical_to_raw(-128.4, 1.0, 0.0, &l),
            Some((-128, EncodeStatus::InRange))
        );
        assert_eq!(
            physical_to_raw(-128.6, 1.0, 0.0, &l),
            Some((-128, EncodeStatus::Clamped))
        );
        assert_eq!(
            physical_to_raw(f64::INFINITY, 1.0, 0.0, &l),
            Some((127, EncodeStatus::Clamped))
        );
        assert_eq!(
            physical_to_raw(f64::NEG_INFINITY, 1.0, 0.0, &l),
            Some((-128, EncodeStatus::Clamped))
        );
        assert_eq!(physical_to_raw(f64::NAN, 1.0, 0.0, &l), None);
        let u = layout(0, 64, Intel, false);
        assert_eq!(
            physical_to_raw(1e30, 1.0, 0.0, &u),
            Some((i128::from(u64::MAX), EncodeStatus::Clamped))
        );
        assert_eq!(
            physical_to_raw(-1.0, 1.0, 0.0, &u),
            Some((0, EncodeStatus::Clamped))
        );

        let mut data = [0x5A; 8];
        assert_eq!(
            pack_physical(&mut data, &l, 1.0, 0.0, f64::NAN),
            EncodeStatus::NotANumber
        );
        assert_eq!(data, [0x5A; 8], "NaN must not touch the frame");
        assert_eq!(
            pack_physical(&mut data, &l, 1.0, 0.0, -300.0),
            EncodeStatus::Clamped
        );
        assert_eq!(data[0], 0x80);
        assert_eq!(unpack_physical(&data, &l, 1.0, 0.0), -128.0);
    }

    #[test]
    fn values_reserve_the_not_available_pattern() {
        // signed: the most negative raw value; values stop one above it
        let l = layout(0, 8, Intel, true);
        assert_eq!(l.raw_not_available(), -128);
        let mut data = [0x5A; 8];
        assert_eq!(
            pack_value(&mut data, &l, 1.0, 0.0, f64::NAN),
            EncodeStatus::NotANumber
        );
        assert_eq!(data[0], 0x80, "NaN is sent as not available");
        assert_eq!(data[1..], [0x5A; 7], "other bits untouched");
        assert!(unpack_value(&data, &l, 1.0, 0.0).is_nan());
        assert_eq!(
            unpack_physical(&data, &l, 1.0, 0.0),
            -128.0,
            "plain DBC view"
        );
        for v in [-128.0, -300.0, f64::NEG_INFINITY] {
            assert_eq!(
                pack_value(&mut data, &l, 1.0, 0.0, v),
                EncodeStatus::Clamped
            );
            assert_eq!(unpack_value(&data, &l, 1.0, 0.0), -127.0);
        }
        assert_eq!(
            pack_value(&mut data, &l, 1.0, 0.0, -127.0),
            EncodeStatus::InRange
        );
        // unsigned: all ones; values stop one below
        let b = layout(8, 4, Intel, false);
        assert_eq!(b.raw_not_available(), 15);
        assert_eq!(
            pack_value(&mut data, &b, 1.0, 0.0, f64::NAN),
            EncodeStatus::NotANumber
        );
        assert_eq!(data[1] & 0x0F, 0x0F);
        assert!(unpack_value(&data, &b, 1.0, 0.0).is_nan());
        assert_eq!(
            pack_value(&mut data, &b, 1.0, 0.0, 15.0),
            EncodeStatus::Clamped
        );
        assert_eq!(unpack_value(&data, &b, 1.0, 0.0), 14.0);
    }
}
