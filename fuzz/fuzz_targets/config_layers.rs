//! Config loading, all layers: the input is a main file, then (after a line `%%`) lines of
//! `NAME=value` environment variables (`ANTISURGE_…__…`). `load_with_env` must return a
//! loaded config or located problems, never panic, however deep or long the keys.
#![no_main]
#[path = "../scratch.rs"]
mod scratch;

use antisurge::daemon::config::load_with_env;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let (main, env) = text.split_once("\n%%\n").unwrap_or((&text, ""));
    let vars: Vec<(String, String)> = env
        .lines()
        .filter_map(|l| l.split_once('='))
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    let path = scratch::write("antisurge.toml", main.as_bytes());
    match load_with_env(&path, &vars) {
        Ok(_) => {}
        Err(problems) => assert!(!problems.is_empty(), "an error with no problem listed"),
    }
});
