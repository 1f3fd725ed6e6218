//! Scenario loading: any text through `Scenario::from_text` (TOML, schema, bounds on duration,
//! period and events), from memory (the same checks as `load`). Must return a scenario or a
//! located error, never panic.
#![no_main]
use std::path::Path;

use antisurge::scenario::Scenario;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(s) = Scenario::from_text(text, Path::new("scenario.toml")) {
        assert!(s.file.duration_s > 0.0 && s.file.duration_s.is_finite());
    }
});
