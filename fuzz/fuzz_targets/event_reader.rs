//! The event reader: any bytes as an event log (torn tails, overlong lines, bad JSON,
//! sequence breaks) through `read_bytes` (the line handling of `read_files`, from memory),
//! every record's event decoded; and the first line as a `--since` argument. Never a panic.
#![no_main]
use std::path::Path;

use antisurge::events::reader::{parse_since, read_bytes, EventFilter};
use antisurge::events::Timestamp;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let stats = read_bytes(data, Path::new("events.jsonl"), &EventFilter::default(), |_, record| {
        let _ = record.event();
        Ok(())
    })
    .expect("reading from memory");
    assert!(stats.invalid.len() as u64 <= stats.invalid_total);
    if let Some(first) = data.split(|&b| b == b'\n').next() {
        if let Ok(t) = std::str::from_utf8(first) {
            let _ = parse_since(t, Timestamp::now());
        }
    }
});
