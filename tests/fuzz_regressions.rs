//! Inputs the fuzz targets in `fuzz/` found failing, kept as tests (issue 12).

use antisurge::io::modbus::register::{
    BindingError, ByteOrder, DataType, RegisterBinding, RegisterTable, WordOrder,
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
    // the smallest normal scale is still accepted
    let ok = RegisterBinding {
        scale: f64::MIN_POSITIVE,
        ..b
    };
    assert!(ok.validate().is_ok());
}
