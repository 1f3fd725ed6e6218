//! Inputs the fuzz targets in `fuzz/` found failing, kept as tests (issue 12).

use antisurge::io::modbus::register::{
    BindingError, ByteOrder, DataType, EncodeOutcome, RegisterBinding, RegisterTable, WordOrder,
    MAX_OFFSET, MAX_SCALE, MIN_SCALE,
};

/// `modbus_register_codec`, crash-9a1fa71b: a subnormal scale (5.4e-312) passed `validate`,
/// and an in-range value (1.6e-297) encoded to i64 decoded to 0: the round trip the codec
/// promises (within half a resolution) failed. Subnormal scales are refused now.
#[test]
fn subnormal_scale_is_refused() {
    let b = RegisterBinding {
        unit_id: 60,
        table: RegisterTable::Input,
        address: 0,
        data_type: DataType::I64,
        byte_order: ByteOrder::Little,
        word_order: WordOrder::Little,
        scale: 5.432226334406e-312,
        offset: 3.326468099824247e-294,
        unit: None,
        address_looks_modicon: false,
    };
    assert!(matches!(b.validate(), Err(BindingError::BadScale(_))));
    // the smallest plausible scale is accepted (f64::MIN_POSITIVE, accepted after the first
    // fix, is refused since the second: see `implausible_scale_is_refused`)
    let ok = RegisterBinding {
        scale: MIN_SCALE,
        ..b
    };
    assert!(ok.validate().is_ok());
}

/// The binding `modbus_register_codec` builds from an input (same layout as the target).
fn binding_of(data: &[u8]) -> RegisterBinding {
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
    let f = |i: usize| f64::from_le_bytes(data[i..i + 8].try_into().unwrap());
    RegisterBinding {
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
    }
}

/// Round trip `value` through `b`; the error and the documented bound (half a resolution plus
/// the f64 rounding of `raw × scale + offset`).
fn round_trip(b: &RegisterBinding, value: f64) -> (f64, f64) {
    let n = usize::from(b.data_type.register_count());
    let mut out = [0u16; 4];
    assert_eq!(b.encode(value, &mut out[..n]), Ok(EncodeOutcome::InRange));
    let back = b.decode(&out[..n]).unwrap();
    let bound = b.resolution(value) / 2.0 + 4.0 * f64::EPSILON * (b.offset.abs() + value.abs());
    ((back - value).abs(), bound)
}

/// `modbus_register_codec`, the second finding (open after the first pass): an `f64` binding
/// with scale 6.3e-299 and offset 4.6e-299 round-tripped 7.6e-307 off by 1e-8 relative: the
/// value is 10⁻⁸ of the offset, so only the offset's precision survives `raw × scale + offset`.
/// Such a scale is no device's: scales outside 1e-12..=1e12 and offsets beyond ±1e12 are
/// refused by `validate` (the check config runs), and the target only exercises what it
/// accepts, with the f64 rounding of the offset in its tolerance.
#[test]
fn implausible_scale_is_refused() {
    let input = "3c000000ffffffffffffffff04020000ff000000ff0100f7fc0000036100006d07ffffb50000";
    let data: Vec<u8> = (0..input.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&input[i..i + 2], 16).unwrap())
        .collect();
    let b = binding_of(&data);
    assert_eq!(b.data_type, DataType::F64);
    assert!((b.scale - 6.27e-299).abs() < 1e-301, "{}", b.scale);
    assert_eq!(b.validate(), Err(BindingError::BadScale(b.scale)));
    assert!(b
        .validate()
        .unwrap_err()
        .to_string()
        .contains("1e-12..=1e12"));
    // the same shape at the plausible limits round-trips within the documented bound
    let value = f64::from_le_bytes(data[22..30].try_into().unwrap());
    for (scale, offset) in [
        (MIN_SCALE, 0.74 * MIN_SCALE),
        (MIN_SCALE, MAX_OFFSET),
        (-MAX_SCALE, -MAX_OFFSET),
        (1.0, MAX_OFFSET),
    ] {
        let p = RegisterBinding { scale, offset, ..b };
        assert_eq!(p.validate(), Ok(()));
        for v in [value, 1e-3 * offset, 0.3, -7.5e4] {
            let (err, bound) = round_trip(&p, v);
            assert!(err <= bound, "{p:?}: {v} off by {err} > {bound}");
        }
    }
}

/// `event_reader` (CI, 2026-11-28): a `--since` argument whose byte 19 falls inside a
/// multi-byte character panicked in the slicing of the time parser; it is an error now.
#[test]
fn a_since_argument_torn_at_byte_19_is_an_error() {
    let input = b"`2afri~ca/asmara\x063\xc2\x92\x1a";
    let text = std::str::from_utf8(input).expect("the crash input is UTF-8");
    let now = antisurge::events::Timestamp::now();
    assert!(antisurge::events::reader::parse_since(text, now).is_err());
}
