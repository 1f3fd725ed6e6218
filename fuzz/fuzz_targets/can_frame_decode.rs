//! CAN frame decode: any identifier and payload (0–64 bytes) against the shipped skid DBC
//! and the skid's signal bindings. Decoding must return values or an error, never panic.
#![no_main]
use std::sync::OnceLock;

use antisurge::io::can::codec::{skid_bindings, CanCodec};
use antisurge::io::can::dbc::{CanDatabase, FrameId};
use libfuzzer_sys::fuzz_target;

/// The codec and the identifiers of the DBC's messages.
fn codec() -> &'static (CanCodec, Vec<FrameId>) {
    static CODEC: OnceLock<(CanCodec, Vec<FrameId>)> = OnceLock::new();
    CODEC.get_or_init(|| {
        let db = CanDatabase::from_file(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/skid.dbc"))
            .expect("config/skid.dbc");
        let ids = db.messages().iter().map(|m| m.id()).collect();
        (CanCodec::new(&db, &skid_bindings()).expect("skid bindings"), ids)
    })
}

fuzz_target!(|data: &[u8]| {
    let (codec, ids) = codec();
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    let payload = &rest[..rest.len().min(64)];
    // the first byte picks a known message (so most inputs reach the signal unpacking, the
    // length and CRC checks) or, past the list, an arbitrary identifier
    let id = match ids.get(usize::from(pick) % (ids.len() + 1)) {
        Some(id) => *id,
        None if payload.len() >= 4 => {
            let raw = u32::from_le_bytes([payload[0], payload[1], payload[2], payload[3]]);
            if raw & 0x8000_0000 != 0 {
                FrameId::Extended(raw & 0x1FFF_FFFF)
            } else {
                FrameId::Standard((raw & 0x7FF) as u16)
            }
        }
        None => return,
    };
    if let Ok(decoded) = codec.decode(id, payload) {
        assert!(decoded.values().len() <= 64);
    }
});
