//! Modbus register codec: a binding drawn from the input (unit, table, address, data type,
//! byte and word order, scale, offset) decodes arbitrary register words and encodes
//! arbitrary values. Invalid or implausible bindings are refused by `validate` (as config
//! refuses them); valid ones must never panic, and an encoded in-range value must decode to
//! itself within half a resolution plus the f64 rounding of `raw × scale + offset`.
#![no_main]
use antisurge::io::modbus::register::{
    ByteOrder, DataType, EncodeOutcome, RegisterBinding, RegisterTable, WordOrder,
};
use libfuzzer_sys::fuzz_target;

const TYPES: [DataType; 8] = [
    DataType::U16,
    DataType::I16,
    DataType::U32,
    DataType::I32,
    DataType::F32,
    DataType::U64,
    DataType::I64,
    DataType::F64,
];

fuzz_target!(|data: &[u8]| {
    if data.len() < 22 {
        return;
    }
    let f = |i: usize| f64::from_le_bytes(data[i..i + 8].try_into().unwrap());
    let b = RegisterBinding {
        unit_id: data[0],
        table: if data[1] & 1 == 0 {
            RegisterTable::Holding
        } else {
            RegisterTable::Input
        },
        address: u16::from_le_bytes([data[2], data[3]]),
        data_type: TYPES[usize::from(data[4]) % TYPES.len()],
        byte_order: if data[5] & 1 == 0 {
            ByteOrder::Big
        } else {
            ByteOrder::Little
        },
        word_order: if data[5] & 2 == 0 {
            WordOrder::Big
        } else {
            WordOrder::Little
        },
        scale: f(6),
        offset: f(14),
        unit: None,
        address_looks_modicon: false,
    };
    if b.validate().is_err() {
        return;
    }
    let rest = &data[22..];
    let words: Vec<u16> = rest
        .chunks_exact(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect();
    let _ = b.decode(&words);
    if rest.len() >= 8 {
        let value = f64::from_le_bytes(rest[..8].try_into().unwrap());
        let mut out = [0u16; 4];
        let n = usize::from(b.data_type.register_count());
        let _ = b.encode(value, &mut out[..n.saturating_sub(usize::from(rest[0] & 1))]);
        if let Ok(EncodeOutcome::InRange) = b.encode(value, &mut out[..n]) {
            let back = b.decode(&out[..n]).expect("decode of an encoded value");
            // the documented bound (half a resolution plus the f64 rounding of
            // `raw × scale + offset`, tests/fuzz_regressions.rs) with a factor 2 of margin
            let tol = b.resolution(value).abs()
                + 8.0 * f64::EPSILON * (b.offset.abs() + value.abs());
            assert!(
                !value.is_finite() || !back.is_finite() || (back - value).abs() <= tol || !tol.is_finite(),
                "{b:?}: {value} encoded and decoded to {back}"
            );
        }
    }
});
