//! Plant file loading: any text through `PlantCase::from_text` (TOML, schema, model
//! validation, compressor map fit), from memory (the same checks as `load`). Must return a
//! plant or a located error, never panic.
#![no_main]
use std::path::Path;

use antisurge::sim::case::PlantCase;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    // a relative map table is looked up beside the file: the repository's config/plants/
    let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/plants/fuzz.toml"));
    let _ = PlantCase::from_text(text, path);
});
