//! The event reader: any bytes as an event log file (torn tails, overlong lines, bad JSON,
//! sequence breaks), every record's event decoded; and the first line as a `--since`
//! argument. Never a panic.
#![no_main]
#[path = "../scratch.rs"]
mod scratch;

use antisurge::events::reader::{parse_since, read_files, EventFilter};
use antisurge::events::Timestamp;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = scratch::write("events.jsonl", data);
    let stats = read_files(&[path], &EventFilter::default(), |_, record| {
        let _ = record.event();
        Ok(())
    })
    .expect("reading a readable file");
    assert!(stats.invalid.len() as u64 <= stats.invalid_total);
    if let Some(first) = data.split(|&b| b == b'\n').next() {
        if let Ok(t) = std::str::from_utf8(first) {
            let _ = parse_since(t, Timestamp::now());
        }
    }
});
