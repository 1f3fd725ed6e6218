//! Scenario loading: any text through `Scenario::load` (TOML, schema, bounds on duration,
//! period and events). Must return a scenario or a located error, never panic.
#![no_main]
#[path = "../scratch.rs"]
mod scratch;

use antisurge::scenario::Scenario;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = scratch::write("scenario.toml", data);
    if let Ok(s) = Scenario::load(&path) {
        assert!(s.file.duration_s > 0.0 && s.file.duration_s.is_finite());
    }
});
