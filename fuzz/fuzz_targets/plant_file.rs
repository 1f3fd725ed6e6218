//! Plant file loading: any text through `PlantDescription::load` (TOML, schema, model
//! validation, compressor map fit). Must return a plant or a located error, never panic.
#![no_main]
#[path = "../scratch.rs"]
mod scratch;

use antisurge::plant::file::PlantDescription;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = scratch::write("plant.toml", data);
    let _ = PlantDescription::load(&path);
});
