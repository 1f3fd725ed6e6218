//! Register bindings: where one value lives in a Modbus device and how it is encoded.
//!
//! A [`RegisterBinding`] names a unit (slave) id, a register table, a 0-based protocol
//! address and an encoding. It converts between the SI value the controller uses and the
//! raw 16-bit register words on the wire:
//!
//! ```text
//! physical (SI) = raw × scale + offset        raw = (physical − offset) / scale
//! ```
//!
//! Encoding and decoding are pure and allocation-free; they work on caller-provided word
//! slices so the control cycle never allocates.

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Which table a binding lives in: two 16-bit register tables and two one-bit tables.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RegisterTable {
    /// Holding registers (read with function 0x03, written with 0x06/0x10). Read/write.
    Holding,
    /// Input registers (read with function 0x04). Read-only from the client's side.
    Input,
    /// Coils: single bits, read with function 0x01, written with 0x05/0x0F. Read/write.
    /// Modicon numbers 00001–09999.
    Coil,
    /// Discrete inputs: single bits, read with function 0x02. Read-only from the client's
    /// side. Modicon numbers 10001–19999.
    DiscreteInput,
}

impl RegisterTable {
    /// Lower-case name, as in config files.
    pub const fn name(self) -> &'static str {
        match self {
            RegisterTable::Holding => "holding",
            RegisterTable::Input => "input",
            RegisterTable::Coil => "coil",
            RegisterTable::DiscreteInput => "discrete_input",
        }
    }

    /// Whether the table holds single bits (coils, discrete inputs) rather than 16-bit
    /// registers. Bit tables carry only [`DataType::Bool`]; register tables never do.
    pub const fn is_bits(self) -> bool {
        matches!(self, RegisterTable::Coil | RegisterTable::DiscreteInput)
    }

    /// Whether a client may write the table (holding registers and coils).
    pub const fn is_writable(self) -> bool {
        matches!(self, RegisterTable::Holding | RegisterTable::Coil)
    }
}

/// The raw type stored in one or more consecutive registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DataType {
    /// Unsigned 16-bit integer, 1 register.
    U16,
    /// Two's-complement signed 16-bit integer, 1 register.
    I16,
    /// Unsigned 32-bit integer, 2 registers.
    U32,
    /// Two's-complement signed 32-bit integer, 2 registers.
    I32,
    /// IEEE-754 binary32, 2 registers.
    F32,
    /// Unsigned 64-bit integer, 4 registers. Values above 2^53 lose precision in f64.
    U64,
    /// Two's-complement signed 64-bit integer, 4 registers. Same f64 precision caveat.
    I64,
    /// IEEE-754 binary64, 4 registers.
    F64,
    /// One bit (a coil or a discrete input): raw 0 or 1. Only in the bit tables.
    Bool,
}

impl DataType {
    /// Number of 16-bit registers (for [`DataType::Bool`]: bits) the type occupies.
    pub const fn register_count(self) -> u16 {
        match self {
            DataType::U16 | DataType::I16 | DataType::Bool => 1,
            DataType::U32 | DataType::I32 | DataType::F32 => 2,
            DataType::U64 | DataType::I64 | DataType::F64 => 4,
        }
    }

    /// Lower-case name, as in config files.
    pub const fn name(self) -> &'static str {
        match self {
            DataType::U16 => "u16",
            DataType::I16 => "i16",
            DataType::U32 => "u32",
            DataType::I32 => "i32",
            DataType::F32 => "f32",
            DataType::U64 => "u64",
            DataType::I64 => "i64",
            DataType::F64 => "f64",
            DataType::Bool => "bool",
        }
    }

    /// Whether the raw type is an integer (encoding rounds and clamps).
    pub const fn is_integer(self) -> bool {
        !matches!(self, DataType::F32 | DataType::F64)
    }
}

/// Byte order inside each 16-bit register.
///
/// `Big` is the Modbus standard (high byte first on the wire). `Little` swaps the two bytes
/// of every register (the "B A" in orders like BADC).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ByteOrder {
    /// High byte first (standard).
    #[default]
    Big,
    /// Low byte first: each register's bytes are swapped.
    Little,
}

/// Register order of multi-register types.
///
/// `Big`: the lowest address holds the most significant word (ABCD). `Little`: the lowest
/// address holds the least significant word (CDAB for 32-bit; for 64-bit types the four
/// registers are fully reversed).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WordOrder {
    /// Most significant word at the lowest address.
    #[default]
    Big,
    /// Least significant word at the lowest address.
    Little,
}

fn default_scale() -> f64 {
    1.0
}

/// Where a value lives in a Modbus device and how to convert it to SI units.
///
/// Config keys: `unit_id`, then the location either as a Modicon register *number*
/// (`register = 40004`: 4xxxx holding, 3xxxx input, 1-based; six-digit 400001 also) or as
/// `table` (`holding` | `input`) plus the 0-based *protocol* `address`; `data_type`
/// (`u16`, `i16`, `u32`, `i32`, `f32`, `u64`, `i64`, `f64`), `byte_order`
/// (`big` | `little`, default `big`), `word_order` (`big` | `little`, default `big`;
/// `little` with `big` bytes is CDAB), `scale` (default 1), `offset` (default 0) and
/// `unit` (the unit of `raw × scale + offset`, e.g. `"%"`, `"bar"`, `"rpm"`, `"degC"`;
/// default: the signal's SI unit), see [`crate::io::units`].
///
/// `physical = raw × scale + offset` in `unit`, so e.g. a valve position in hundredths of
/// a percent binds as `data_type = "u16", scale = 0.01, unit = "%"`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RegisterBinding {
    /// Modbus unit (slave) id. On TCP devices without a gateway this is usually 1 or 255.
    pub unit_id: u8,
    /// Register table.
    pub table: RegisterTable,
    /// 0-based *protocol* address of the first register (what goes on the wire). Vendor
    /// documentation often uses 1-based "register numbers" such as 40001 for holding address
    /// 0 or 30001 for input address 0: give those as `register`.
    pub address: u16,
    /// Raw type; decides how many consecutive registers the binding spans.
    pub data_type: DataType,
    /// Byte order inside each register.
    pub byte_order: ByteOrder,
    /// Register order for multi-register types (ignored for 16-bit types).
    pub word_order: WordOrder,
    /// Units per raw count: `physical = raw × scale + offset`. Must be finite and non-zero.
    pub scale: f64,
    /// Physical value at raw zero. Must be finite.
    pub offset: f64,
    /// Declared unit of the physical value (`None`: the signal's SI unit). The signal map
    /// checks it and folds the conversion into `scale`/`offset`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unit: Option<&'static str>,
    /// The binding was given as a protocol `address` that looks like a Modicon register
    /// number (≥ 10001): probably a mistake, reported as a warning.
    #[serde(skip)]
    pub address_looks_modicon: bool,
}

/// The config form of a [`RegisterBinding`] (either `register` or `table` + `address`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRegisterBinding {
    unit_id: u8,
    #[serde(default)]
    table: Option<RegisterTable>,
    #[serde(default)]
    address: Option<u16>,
    #[serde(default)]
    register: Option<u32>,
    data_type: DataType,
    #[serde(default)]
    byte_order: ByteOrder,
    #[serde(default)]
    word_order: WordOrder,
    #[serde(default = "default_scale")]
    scale: f64,
    #[serde(default)]
    offset: f64,
    #[serde(default)]
    unit: Option<String>,
}

/// Table and 0-based protocol address of a Modicon register number (`40001` → holding 0,
/// `30010` → input 9, `00001` → coil 0, `10001` → discrete input 0; six-digit numbers
/// `400001` … as well).
pub fn modicon(register: u32) -> Result<(RegisterTable, u16), String> {
    let (prefix, n) = if register >= 100_000 {
        (register / 100_000, register % 100_000)
    } else {
        (register / 10_000, register % 10_000)
    };
    let table = match prefix {
        4 => RegisterTable::Holding,
        3 => RegisterTable::Input,
        1 => RegisterTable::DiscreteInput,
        0 => RegisterTable::Coil,
        _ => {
            return Err(format!(
                "register {register} is not a Modicon number (0xxxx coil, 1xxxx discrete input, 3xxxx input, 4xxxx holding, 1-based)"
            ))
        }
    };
    if n == 0 || n > 65_536 {
        return Err(format!(
            "register {register}: Modicon numbers are 1-based (40001 is holding address 0, 00001 coil 0)"
        ));
    }
    Ok((table, (n - 1) as u16))
}

impl<'de> Deserialize<'de> for RegisterBinding {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        RawRegisterBinding::deserialize(d)?
            .try_into()
            .map_err(serde::de::Error::custom)
    }
}

impl TryFrom<RawRegisterBinding> for RegisterBinding {
    type Error = String;

    fn try_from(r: RawRegisterBinding) -> Result<Self, String> {
        let (table, address, looks) = match (r.register, r.table, r.address) {
            (Some(reg), None, None) => {
                let (t, a) = modicon(reg)?;
                (t, a, false)
            }
            (Some(_), _, _) => {
                return Err(
                    "give either `register` (Modicon number, e.g. 40004) or `table` + `address` (0-based protocol address), not both"
                        .into(),
                )
            }
            (None, Some(t), Some(a)) => (t, a, a >= 10_001),
            (None, _, _) => {
                return Err(
                    "missing location: `register = 40001` (Modicon number) or `table` and `address` (0-based protocol address)"
                        .into(),
                )
            }
        };
        if table.is_bits() != (r.data_type == DataType::Bool) {
            return Err(if table.is_bits() {
                format!(
                    "a {} holds one bit: use data_type = \"bool\", not \"{}\"",
                    table.name(),
                    r.data_type.name()
                )
            } else {
                format!(
                    "data_type = \"bool\" is one bit: it lives in a coil (0xxxx, table = \"coil\") or a discrete input (1xxxx, table = \"discrete_input\"), not in the {} registers",
                    table.name()
                )
            });
        }
        let unit = match r.unit {
            None => None,
            Some(u) => Some(crate::io::units::Unit::static_name(&u).ok_or_else(|| {
                format!(
                    "unknown unit \"{u}\" (known: {})",
                    crate::io::units::Unit::names()
                )
            })?),
        };
        Ok(RegisterBinding {
            unit_id: r.unit_id,
            table,
            address,
            data_type: r.data_type,
            byte_order: r.byte_order,
            word_order: r.word_order,
            scale: r.scale,
            offset: r.offset,
            unit,
            address_looks_modicon: looks,
        })
    }
}

/// Whether an encoded value fit the raw type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[must_use]
pub enum EncodeOutcome {
    /// The (rounded) raw value was representable.
    InRange,
    /// The raw value was outside the type's range (or infinite) and was saturated to the
    /// nearest representable extreme.
    Clamped,
}

/// Why a value could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum EncodeError {
    /// The value (or the raw value derived from it) is NaN: nothing was written.
    #[error("value is NaN")]
    NotANumber,
    /// The output slice is shorter than the binding's register count.
    #[error("need {needed} registers, buffer holds {got}")]
    BufferTooShort {
        /// Registers the binding spans.
        needed: usize,
        /// Length of the slice given.
        got: usize,
    },
}

/// Why registers could not be decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum DecodeError {
    /// The input slice is shorter than the binding's register count.
    #[error("need {needed} registers, got {got}")]
    BufferTooShort {
        /// Registers the binding spans.
        needed: usize,
        /// Length of the slice given.
        got: usize,
    },
}

/// A binding that cannot be used.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum BindingError {
    /// `scale` is NaN, infinite or outside the plausible magnitudes
    /// [`MIN_SCALE`]..=[`MAX_SCALE`] (a subnormal scale broke the round trip, and a scale of
    /// 6.3e-299 left only the rounding of its products: fuzz target `modbus_register_codec`).
    #[error(
        "scale must be finite with a magnitude in 1e-12..=1e12 (units per raw count), got {0}"
    )]
    BadScale(f64),
    /// `offset` is NaN, infinite or beyond ±[`MAX_OFFSET`].
    #[error("offset must be finite and within ±1e12 (SI units), got {0}")]
    BadOffset(f64),
    /// A one-bit table (coil, discrete input) with a value type, or `bool` in a register
    /// table.
    #[error("data type {} does not fit the {} table (bool is for coils and discrete inputs only)", data_type.name(), table.name())]
    TableType {
        /// The table.
        table: RegisterTable,
        /// The data type.
        data_type: DataType,
    },
    /// The binding runs past protocol address 65535.
    #[error("{count} registers starting at {address} run past address 65535")]
    AddressOverflow {
        /// First address.
        address: u16,
        /// Register count of the data type.
        count: u16,
    },
}

/// Smallest plausible `|scale|` (units per raw count). Field devices scale by powers of ten
/// around 1 (0.001 bar per count is 100 Pa); 1e-12 leaves six orders of margin and keeps every
/// product of a round trip far from the subnormal range.
pub const MIN_SCALE: f64 = 1e-12;
/// Largest plausible `|scale|` (units per raw count).
pub const MAX_SCALE: f64 = 1e12;
/// Largest plausible `|offset|`, SI units (1e12 Pa is 10 million bar).
pub const MAX_OFFSET: f64 = 1e12;

impl RegisterBinding {
    /// A binding with standard (big/big) order, scale 1 and offset 0.
    pub const fn new(unit_id: u8, table: RegisterTable, address: u16, data_type: DataType) -> Self {
        RegisterBinding {
            unit_id,
            table,
            address,
            data_type,
            byte_order: ByteOrder::Big,
            word_order: WordOrder::Big,
            scale: 1.0,
            offset: 0.0,
            unit: None,
            address_looks_modicon: false,
        }
    }

    /// Same binding with the given byte and word order.
    pub const fn with_order(mut self, byte_order: ByteOrder, word_order: WordOrder) -> Self {
        self.byte_order = byte_order;
        self.word_order = word_order;
        self
    }

    /// Same binding with the given scale and offset (`physical = raw × scale + offset`).
    pub const fn with_scaling(mut self, scale: f64, offset: f64) -> Self {
        self.scale = scale;
        self.offset = offset;
        self
    }

    /// Number of consecutive registers the binding spans.
    pub const fn register_count(&self) -> u16 {
        self.data_type.register_count()
    }

    /// One past the last address spanned, as u32 so that it cannot overflow.
    pub const fn end_address(&self) -> u32 {
        self.address as u32 + self.register_count() as u32
    }

    /// Check table and data type, scale, offset and address range.
    pub fn validate(&self) -> Result<(), BindingError> {
        if self.table.is_bits() != (self.data_type == DataType::Bool) {
            return Err(BindingError::TableType {
                table: self.table,
                data_type: self.data_type,
            });
        }
        if !(MIN_SCALE..=MAX_SCALE).contains(&self.scale.abs()) {
            return Err(BindingError::BadScale(self.scale));
        }
        if !self.offset.is_finite() || self.offset.abs() > MAX_OFFSET {
            return Err(BindingError::BadOffset(self.offset));
        }
        if self.end_address() > 1 << 16 {
            return Err(BindingError::AddressOverflow {
                address: self.address,
                count: self.register_count(),
            });
        }
        Ok(())
    }

    /// Step between adjacent representable SI values near `value` (SI units).
    ///
    /// For integer types this is `|scale|`; for float types it is one unit in the last place
    /// of the raw value, times `|scale|`. A round trip through [`encode`](Self::encode) and
    /// [`decode`](Self::decode) is exact to within half of this plus the f64 rounding of
    /// `raw × scale + offset` (a few ulp of `|offset| + |value|`: a small value read through a
    /// large offset keeps only the offset's precision).
    pub fn resolution(&self, value: f64) -> f64 {
        let scale = self.scale.abs();
        let raw = ((value - self.offset) / self.scale).abs();
        match self.data_type {
            DataType::F32 => {
                let r = raw as f32;
                (f32::from_bits(r.to_bits() + 1) - r) as f64 * scale
            }
            DataType::F64 => (f64::from_bits(raw.to_bits() + 1) - raw) * scale,
            _ => scale,
        }
    }

    /// Encode an SI value into `out[..register_count()]`, in wire order.
    ///
    /// Integer types round half away from zero and saturate at the type's limits
    /// ([`EncodeOutcome::Clamped`]). Float types saturate infinities and out-of-range values
    /// at ±MAX. NaN is refused and leaves `out` untouched. Allocation-free.
    pub fn encode(&self, value: f64, out: &mut [u16]) -> Result<EncodeOutcome, EncodeError> {
        let n = self.register_count() as usize;
        if out.len() < n {
            return Err(EncodeError::BufferTooShort {
                needed: n,
                got: out.len(),
            });
        }
        let raw = (value - self.offset) / self.scale;
        if raw.is_nan() {
            return Err(EncodeError::NotANumber);
        }
        // Float→int `as` casts saturate in Rust; `hi` is the exclusive upper bound, exactly
        // representable in f64, so the out-of-range test is exact even for 64-bit types.
        let int = |lo: f64, hi: f64| -> (f64, bool) {
            let r = raw.round();
            (r, r < lo || r >= hi)
        };
        const TWO_15: f64 = 32768.0;
        const TWO_16: f64 = 65536.0;
        const TWO_31: f64 = 2_147_483_648.0;
        const TWO_32: f64 = 4_294_967_296.0;
        const TWO_63: f64 = 9_223_372_036_854_775_808.0;
        const TWO_64: f64 = 18_446_744_073_709_551_616.0;
        let (bits, clamped): (u64, bool) = match self.data_type {
            DataType::U16 => {
                let (r, c) = int(0.0, TWO_16);
                (r as u16 as u64, c)
            }
            DataType::I16 => {
                let (r, c) = int(-TWO_15, TWO_15);
                (r as i16 as u16 as u64, c)
            }
            DataType::U32 => {
                let (r, c) = int(0.0, TWO_32);
                (r as u32 as u64, c)
            }
            DataType::I32 => {
                let (r, c) = int(-TWO_31, TWO_31);
                (r as i32 as u32 as u64, c)
            }
            DataType::U64 => {
                let (r, c) = int(0.0, TWO_64);
                (r as u64, c)
            }
            DataType::I64 => {
                let (r, c) = int(-TWO_63, TWO_63);
                (r as i64 as u64, c)
            }
            DataType::F32 => {
                let f = raw as f32;
                if f.is_infinite() {
                    (f32::MAX.copysign(f).to_bits() as u64, true)
                } else {
                    (f.to_bits() as u64, false)
                }
            }
            DataType::F64 => {
                if raw.is_infinite() {
                    (f64::MAX.copysign(raw).to_bits(), true)
                } else {
                    (raw.to_bits(), false)
                }
            }
            // one bit: raw ≥ 0.5 is set; anything outside [0, 1] is clamped
            DataType::Bool => (u64::from(raw >= 0.5), !(0.0..=1.0).contains(&raw)),
        };
        put_words(bits, n, self.byte_order, self.word_order, out);
        Ok(if clamped {
            EncodeOutcome::Clamped
        } else {
            EncodeOutcome::InRange
        })
    }

    /// Decode `words[..register_count()]` (wire order) into an SI value. A float register
    /// holding NaN decodes to NaN ("absent"). Allocation-free.
    pub fn decode(&self, words: &[u16]) -> Result<f64, DecodeError> {
        let n = self.register_count() as usize;
        if words.len() < n {
            return Err(DecodeError::BufferTooShort {
                needed: n,
                got: words.len(),
            });
        }
        let bits = get_words(words, n, self.byte_order, self.word_order);
        let raw = match self.data_type {
            DataType::U16 => bits as u16 as f64,
            DataType::I16 => bits as u16 as i16 as f64,
            DataType::U32 => bits as u32 as f64,
            DataType::I32 => bits as u32 as i32 as f64,
            DataType::U64 => bits as f64,
            DataType::I64 => bits as i64 as f64,
            DataType::F32 => f32::from_bits(bits as u32) as f64,
            DataType::F64 => f64::from_bits(bits),
            DataType::Bool => f64::from(u8::from(bits & 1 != 0)),
        };
        Ok(raw * self.scale + self.offset)
    }
}

/// Split the low `16 × n` bits of `bits` into `n` registers in wire order.
fn put_words(bits: u64, n: usize, byte_order: ByteOrder, word_order: WordOrder, out: &mut [u16]) {
    for i in 0..n {
        // i = 0 is the most significant word.
        let mut w = (bits >> (16 * (n - 1 - i))) as u16;
        if byte_order == ByteOrder::Little {
            w = w.swap_bytes();
        }
        let slot = match word_order {
            WordOrder::Big => i,
            WordOrder::Little => n - 1 - i,
        };
        out[slot] = w;
    }
}

/// Inverse of [`put_words`].
fn get_words(words: &[u16], n: usize, byte_order: ByteOrder, word_order: WordOrder) -> u64 {
    let mut bits = 0u64;
    for i in 0..n {
        let slot = match word_order {
            WordOrder::Big => i,
            WordOrder::Little => n - 1 - i,
        };
        let mut w = words[slot];
        if byte_order == ByteOrder::Little {
            w = w.swap_bytes();
        }
        bits = (bits << 16) | w as u64;
    }
    bits
}

/// Two bindings (indices into the slice given to [`find_overlaps`]) whose register ranges
/// share at least one register of the same unit id and table. `first < second`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct Overlap {
    /// Index of one binding.
    pub first: usize,
    /// Index of the other binding.
    pub second: usize,
}

/// Every pair of bindings that overlap (same unit id and table, intersecting register
/// ranges), sorted. Used by config validation: an overlap usually means a typo, and two
/// written bindings overlapping would clobber each other.
pub fn find_overlaps(bindings: &[RegisterBinding]) -> Vec<Overlap> {
    let mut order: Vec<usize> = (0..bindings.len()).collect();
    order.sort_by_key(|&i| {
        let b = &bindings[i];
        (b.unit_id, b.table, b.address)
    });
    let mut found = Vec::new();
    for (k, &i) in order.iter().enumerate() {
        let a = &bindings[i];
        for &j in &order[k + 1..] {
            let b = &bindings[j];
            if b.unit_id != a.unit_id
                || b.table != a.table
                || u32::from(b.address) >= a.end_address()
            {
                break;
            }
            found.push(Overlap {
                first: i.min(j),
                second: i.max(j),
            });
        }
    }
    found.sort();
    found
}

#[cfg(test)]
mod tests {
    use super::*;

    fn b(data_type: DataType, bo: ByteOrder, wo: WordOrder) -> RegisterBinding {
        RegisterBinding::new(1, RegisterTable::Holding, 0, data_type).with_order(bo, wo)
    }

    fn enc(binding: &RegisterBinding, v: f64) -> (Vec<u16>, EncodeOutcome) {
        let mut out = [0u16; 4];
        let o = binding.encode(v, &mut out).expect("encode");
        (out[..binding.register_count() as usize].to_vec(), o)
    }

    use ByteOrder::{Big as BB, Little as BL};
    use WordOrder::{Big as WB, Little as WL};

    #[test]
    fn f32_all_four_orders() {
        // 123.456f32 = 0x42F6E979: bytes A=42 B=F6 C=E9 D=79.
        let cases = [
            (BB, WB, [0x42F6, 0xE979]), // ABCD
            (BL, WL, [0x79E9, 0xF642]), // DCBA
            (BL, WB, [0xF642, 0x79E9]), // BADC
            (BB, WL, [0xE979, 0x42F6]), // CDAB
        ];
        for (bo, wo, words) in cases {
            let binding = b(DataType::F32, bo, wo);
            let (got, o) = enc(&binding, 123.456);
            assert_eq!(got, words, "{bo:?}/{wo:?}");
            assert_eq!(o, EncodeOutcome::InRange);
            let back = binding.decode(&words).unwrap();
            assert_eq!(back, 123.456f32 as f64);
        }
    }

    #[test]
    fn u16_and_i16_words() {
        assert_eq!(enc(&b(DataType::U16, BB, WB), 0x1234 as f64).0, [0x1234]);
        assert_eq!(enc(&b(DataType::U16, BL, WB), 0x1234 as f64).0, [0x3412]);
        // Word order is irrelevant for one register.
        assert_eq!(enc(&b(DataType::U16, BB, WL), 0x1234 as f64).0, [0x1234]);
        assert_eq!(enc(&b(DataType::I16, BB, WB), -2.0).0, [0xFFFE]);
        assert_eq!(enc(&b(DataType::I16, BL, WB), -2.0).0, [0xFEFF]);
        assert_eq!(enc(&b(DataType::I16, BB, WB), -32768.0).0, [0x8000]);
        assert_eq!(b(DataType::I16, BB, WB).decode(&[0xFFFE]).unwrap(), -2.0);
        assert_eq!(b(DataType::I16, BL, WB).decode(&[0xFEFF]).unwrap(), -2.0);
        assert_eq!(b(DataType::U16, BB, WB).decode(&[0xFFFE]).unwrap(), 65534.0);
    }

    #[test]
    fn u32_and_i32_words_in_every_order() {
        let v = 0x1234_5678u32 as f64;
        assert_eq!(enc(&b(DataType::U32, BB, WB), v).0, [0x1234, 0x5678]);
        assert_eq!(enc(&b(DataType::U32, BB, WL), v).0, [0x5678, 0x1234]);
        assert_eq!(enc(&b(DataType::U32, BL, WB), v).0, [0x3412, 0x7856]);
        assert_eq!(enc(&b(DataType::U32, BL, WL), v).0, [0x7856, 0x3412]);
        // -100000 = 0xFFFE7960
        assert_eq!(
            enc(&b(DataType::I32, BB, WB), -100_000.0).0,
            [0xFFFE, 0x7960]
        );
        assert_eq!(
            enc(&b(DataType::I32, BB, WL), -100_000.0).0,
            [0x7960, 0xFFFE]
        );
        assert_eq!(
            enc(&b(DataType::I32, BL, WL), -100_000.0).0,
            [0x6079, 0xFEFF]
        );
        for bo in [BB, BL] {
            for wo in [WB, WL] {
                let binding = b(DataType::I32, bo, wo);
                let (w, _) = enc(&binding, -100_000.0);
                assert_eq!(binding.decode(&w).unwrap(), -100_000.0);
                let binding = b(DataType::U32, bo, wo);
                let (w, _) = enc(&binding, v);
                assert_eq!(binding.decode(&w).unwrap(), v);
            }
        }
    }

    #[test]
    fn sixty_four_bit_words() {
        let v = 0x0001_0203_0405_0607u64 as f64;
        assert_eq!(
            enc(&b(DataType::U64, BB, WB), v).0,
            [0x0001, 0x0203, 0x0405, 0x0607]
        );
        assert_eq!(
            enc(&b(DataType::U64, BB, WL), v).0,
            [0x0607, 0x0405, 0x0203, 0x0001]
        );
        assert_eq!(enc(&b(DataType::I64, BB, WB), -1.0).0, [0xFFFF; 4]);
        // 1.0f64 = 0x3FF0_0000_0000_0000
        assert_eq!(enc(&b(DataType::F64, BB, WB), 1.0).0, [0x3FF0, 0, 0, 0]);
        assert_eq!(enc(&b(DataType::F64, BL, WL), 1.0).0, [0, 0, 0, 0xF03F]);
        let binding = b(DataType::I64, BL, WL);
        let (w, _) = enc(&binding, -123_456_789.0);
        assert_eq!(binding.decode(&w).unwrap(), -123_456_789.0);
    }

    #[test]
    fn scale_and_offset() {
        // Temperature in K from a register holding 0.1 °C counts.
        let binding = RegisterBinding::new(1, RegisterTable::Input, 10, DataType::I16)
            .with_scaling(0.1, 273.15);
        let (w, o) = enc(&binding, 293.15); // 20.0 °C -> 200 counts
        assert_eq!(w, [200]);
        assert_eq!(o, EncodeOutcome::InRange);
        assert!((binding.decode(&[200]).unwrap() - 293.15).abs() < 1e-9);
        // -5.0 °C -> -50 counts
        assert_eq!(enc(&binding, 268.15).0, [(-50i16) as u16]);
        // Rounding to nearest count: 20.04 °C -> 200, 20.06 °C -> 201.
        assert_eq!(enc(&binding, 293.19).0, [200]);
        assert_eq!(enc(&binding, 293.21).0, [201]);
        // kPa -> Pa with a negative scale still round-trips.
        let neg = RegisterBinding::new(1, RegisterTable::Holding, 0, DataType::I32)
            .with_scaling(-1000.0, 0.0);
        let (w, _) = enc(&neg, 101_325.0);
        assert_eq!(w, [0xFFFF, 0xFF9B]); // -101 (101.325 rounds to 101)
        assert_eq!(neg.decode(&w).unwrap(), 101_000.0);
    }

    #[test]
    fn clamping_and_nan() {
        let u16b = b(DataType::U16, BB, WB);
        assert_eq!(enc(&u16b, 70_000.0), (vec![0xFFFF], EncodeOutcome::Clamped));
        assert_eq!(enc(&u16b, -1.0), (vec![0x0000], EncodeOutcome::Clamped));
        assert_eq!(enc(&u16b, 65535.4), (vec![0xFFFF], EncodeOutcome::InRange));
        assert_eq!(enc(&u16b, 65535.5), (vec![0xFFFF], EncodeOutcome::Clamped));
        assert_eq!(enc(&u16b, -0.4), (vec![0], EncodeOutcome::InRange));
        let i16b = b(DataType::I16, BB, WB);
        assert_eq!(enc(&i16b, 40_000.0), (vec![0x7FFF], EncodeOutcome::Clamped));
        assert_eq!(
            enc(&i16b, -40_000.0),
            (vec![0x8000], EncodeOutcome::Clamped)
        );
        assert_eq!(
            enc(&i16b, f64::INFINITY),
            (vec![0x7FFF], EncodeOutcome::Clamped)
        );
        let i32b = b(DataType::I32, BB, WB);
        assert_eq!(
            enc(&i32b, 3e9),
            (vec![0x7FFF, 0xFFFF], EncodeOutcome::Clamped)
        );
        let u64b = b(DataType::U64, BB, WB);
        assert_eq!(enc(&u64b, 1e20), (vec![0xFFFF; 4], EncodeOutcome::Clamped));
        let i64b = b(DataType::I64, BB, WB);
        assert_eq!(
            enc(&i64b, 9.3e18),
            (vec![0x7FFF, 0xFFFF, 0xFFFF, 0xFFFF], EncodeOutcome::Clamped)
        );
        let f32b = b(DataType::F32, BB, WB);
        // f32::MAX = 0x7F7FFFFF
        assert_eq!(
            enc(&f32b, 1e39),
            (vec![0x7F7F, 0xFFFF], EncodeOutcome::Clamped)
        );
        assert_eq!(
            enc(&f32b, f64::NEG_INFINITY),
            (vec![0xFF7F, 0xFFFF], EncodeOutcome::Clamped)
        );

        let mut out = [0xAAAAu16; 2];
        assert_eq!(
            f32b.encode(f64::NAN, &mut out),
            Err(EncodeError::NotANumber)
        );
        assert_eq!(out, [0xAAAA; 2], "NaN must leave the buffer untouched");
        assert_eq!(
            u16b.encode(f64::NAN, &mut out),
            Err(EncodeError::NotANumber)
        );
    }

    #[test]
    fn short_buffers_are_errors_not_panics() {
        let f32b = b(DataType::F32, BB, WB);
        let mut one = [0u16; 1];
        assert_eq!(
            f32b.encode(1.0, &mut one),
            Err(EncodeError::BufferTooShort { needed: 2, got: 1 })
        );
        assert_eq!(
            f32b.decode(&[1]),
            Err(DecodeError::BufferTooShort { needed: 2, got: 1 })
        );
    }

    #[test]
    fn float_nan_in_register_decodes_to_nan() {
        let f32b = b(DataType::F32, BB, WB);
        assert!(f32b.decode(&[0x7FC0, 0x0000]).unwrap().is_nan());
    }

    #[test]
    fn resolution_bounds_round_trip_error() {
        let f32b = RegisterBinding::new(1, RegisterTable::Input, 0, DataType::F32);
        let v = 101_325.123_456;
        let mut w = [0u16; 2];
        let _ = f32b.encode(v, &mut w).unwrap();
        let back = f32b.decode(&w).unwrap();
        let res = f32b.resolution(v);
        assert!(res > 0.0 && res < 0.01, "{res}");
        assert!((back - v).abs() <= res / 2.0);
        let i16b =
            RegisterBinding::new(1, RegisterTable::Input, 0, DataType::I16).with_scaling(0.01, 0.0);
        assert_eq!(i16b.resolution(3.0), 0.01);
    }

    #[test]
    fn validate_rejects_bad_bindings() {
        let ok = RegisterBinding::new(1, RegisterTable::Holding, 65534, DataType::F32);
        assert_eq!(ok.validate(), Ok(()));
        let over = RegisterBinding::new(1, RegisterTable::Holding, 65535, DataType::F32);
        assert!(matches!(
            over.validate(),
            Err(BindingError::AddressOverflow { .. })
        ));
        assert!(matches!(
            ok.with_scaling(0.0, 0.0).validate(),
            Err(BindingError::BadScale(_))
        ));
        assert!(matches!(
            ok.with_scaling(1.0, f64::NAN).validate(),
            Err(BindingError::BadOffset(_))
        ));
        // plausibility bounds: inclusive at the limits, either sign
        for s in [MIN_SCALE, -MIN_SCALE, MAX_SCALE, -MAX_SCALE, 0.01, -1e5] {
            assert_eq!(ok.with_scaling(s, 0.0).validate(), Ok(()), "{s}");
        }
        for s in [MIN_SCALE / 2.0, 6.3e-299, MAX_SCALE * 2.0, -1e300] {
            assert_eq!(
                ok.with_scaling(s, 0.0).validate(),
                Err(BindingError::BadScale(s))
            );
        }
        assert_eq!(ok.with_scaling(1.0, -MAX_OFFSET).validate(), Ok(()));
        assert!(matches!(
            ok.with_scaling(1.0, 2e12).validate(),
            Err(BindingError::BadOffset(_))
        ));
    }

    #[test]
    fn overlaps_found_per_unit_and_table() {
        use RegisterTable::{Holding, Input};
        let list = [
            RegisterBinding::new(1, Holding, 0, DataType::F32), // 0..2
            RegisterBinding::new(1, Holding, 2, DataType::U16), // 2..3, adjacent: no overlap
            RegisterBinding::new(1, Holding, 1, DataType::U16), // 1..2 overlaps #0
            RegisterBinding::new(1, Input, 0, DataType::F32),   // other table
            RegisterBinding::new(2, Holding, 0, DataType::F32), // other unit
            RegisterBinding::new(1, Holding, 0, DataType::F64), // 0..4 overlaps #0, #1, #2
            RegisterBinding::new(1, Holding, 4, DataType::U16), // 4..5 adjacent to #5
        ];
        let found = find_overlaps(&list);
        let pairs: Vec<(usize, usize)> = found.iter().map(|o| (o.first, o.second)).collect();
        assert_eq!(pairs, vec![(0, 2), (0, 5), (1, 5), (2, 5)]);
        assert!(find_overlaps(&list[..2]).is_empty());
    }

    fn parse(t: &str) -> Result<RegisterBinding, String> {
        toml::from_str::<RegisterBinding>(t).map_err(|e| e.to_string())
    }

    #[test]
    fn modicon_numbers_of_all_four_tables() {
        use RegisterTable::*;
        assert_eq!(modicon(1), Ok((Coil, 0)));
        assert_eq!(modicon(9_999), Ok((Coil, 9_998)));
        assert_eq!(modicon(10_001), Ok((DiscreteInput, 0)));
        assert_eq!(modicon(10_017), Ok((DiscreteInput, 16)));
        assert_eq!(modicon(100_001), Ok((DiscreteInput, 0)));
        assert_eq!(modicon(30_001), Ok((Input, 0)));
        assert_eq!(modicon(40_004), Ok((Holding, 3)));
        assert!(modicon(0).unwrap_err().contains("1-based"));
        assert!(modicon(10_000).unwrap_err().contains("1-based"));
        assert!(modicon(20_001)
            .unwrap_err()
            .contains("not a Modicon number"));
    }

    #[test]
    fn bits_live_in_bit_tables_and_values_in_registers() {
        let coil = parse("unit_id = 1\nregister = 17\ndata_type = \"bool\"").unwrap();
        assert_eq!((coil.table, coil.address), (RegisterTable::Coil, 16));
        assert!(!coil.address_looks_modicon);
        let di = parse("unit_id = 1\nregister = 10003\ndata_type = \"bool\"").unwrap();
        assert_eq!((di.table, di.address), (RegisterTable::DiscreteInput, 2));
        let di =
            parse("unit_id = 1\ntable = \"discrete_input\"\naddress = 2\ndata_type = \"bool\"")
                .unwrap();
        assert_eq!((di.table, di.address), (RegisterTable::DiscreteInput, 2));
        // the same Modicon-looking warning logic under the protocol key
        let looks =
            parse("unit_id = 1\ntable = \"coil\"\naddress = 10001\ndata_type = \"bool\"").unwrap();
        assert!(looks.address_looks_modicon);
        let e = parse("unit_id = 1\nregister = 40001\ndata_type = \"bool\"").unwrap_err();
        assert!(
            e.contains("data_type = \"bool\" is one bit")
                && e.contains("not in the holding registers"),
            "{e}"
        );
        let e = parse("unit_id = 1\nregister = 10001\ndata_type = \"f32\"").unwrap_err();
        assert!(e.contains("a discrete_input holds one bit"), "{e}");
        // built in code: validate() refuses the mix
        assert_eq!(
            RegisterBinding::new(1, RegisterTable::Coil, 0, DataType::U16).validate(),
            Err(BindingError::TableType {
                table: RegisterTable::Coil,
                data_type: DataType::U16
            })
        );
        assert!(
            RegisterBinding::new(1, RegisterTable::Input, 0, DataType::Bool)
                .validate()
                .is_err()
        );
    }

    #[test]
    fn bool_encodes_one_bit() {
        let c = RegisterBinding::new(1, RegisterTable::Coil, 0, DataType::Bool);
        assert_eq!(c.register_count(), 1);
        assert_eq!(enc(&c, 1.0), (vec![1], EncodeOutcome::InRange));
        assert_eq!(enc(&c, 0.0), (vec![0], EncodeOutcome::InRange));
        assert_eq!(enc(&c, 0.6), (vec![1], EncodeOutcome::InRange));
        assert_eq!(enc(&c, 0.4), (vec![0], EncodeOutcome::InRange));
        assert_eq!(enc(&c, 7.0), (vec![1], EncodeOutcome::Clamped));
        assert_eq!(enc(&c, -1.0), (vec![0], EncodeOutcome::Clamped));
        assert_eq!(c.decode(&[1]).unwrap(), 1.0);
        assert_eq!(c.decode(&[0]).unwrap(), 0.0);
        // an inverted (normally closed) contact: physical = 1 − raw
        let nc = c.with_scaling(-1.0, 1.0);
        assert_eq!(nc.decode(&[0]).unwrap(), 1.0);
        assert_eq!(enc(&nc, 1.0).0, vec![0]);
        let mut out = [5u16];
        assert_eq!(c.encode(f64::NAN, &mut out), Err(EncodeError::NotANumber));
        assert_eq!(out, [5]);
    }

    #[test]
    fn deserializes_from_toml_with_defaults() {
        let b: RegisterBinding = toml::from_str(
            r#"
            unit_id = 3
            table = "input"
            address = 100
            data_type = "f32"
            word_order = "little"
            "#,
        )
        .unwrap();
        assert_eq!(b.unit_id, 3);
        assert_eq!(b.table, RegisterTable::Input);
        assert_eq!(b.data_type, DataType::F32);
        assert_eq!(b.byte_order, ByteOrder::Big);
        assert_eq!(b.word_order, WordOrder::Little);
        assert_eq!((b.scale, b.offset), (1.0, 0.0));
        let bad = toml::from_str::<RegisterBinding>(
            "unit_id = 1\ntable = \"coil\"\naddress = 0\ndata_type = \"u16\"",
        )
        .unwrap_err()
        .to_string();
        assert!(
            bad.contains("a coil holds one bit: use data_type = \"bool\", not \"u16\""),
            "{bad}"
        );
        let unknown = toml::from_str::<RegisterBinding>(
            "unit_id = 1\ntable = \"input\"\naddress = 0\ndata_type = \"u16\"\nscael = 2.0",
        );
        assert!(unknown.is_err());
    }
}
