//! Config loading, all layers: the input is a main file, then (after a line `%%`) lines of
//! `NAME=value` environment variables (`ANTISURGE_…__…`). `load_text_with_env` (the checks of
//! `load_with_env`, the main file from memory) must return a loaded config or located
//! problems, never panic, however deep or long the keys.
#![no_main]
use std::path::Path;

use antisurge::daemon::config::load_text_with_env;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let (main, env) = text.split_once("\n%%\n").unwrap_or((&text, ""));
    let vars: Vec<(String, String)> = env
        .lines()
        .filter_map(|l| l.split_once('='))
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    // a directory with no conf.d/: the input is the only file layer
    let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/fuzz_targets/antisurge.toml"));
    match load_text_with_env(path, main, &vars) {
        Ok(_) => {}
        Err(problems) => assert!(!problems.is_empty(), "an error with no problem listed"),
    }
});
