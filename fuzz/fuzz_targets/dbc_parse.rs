//! DBC parse: any text through the DBC loader (can-dbc plus our layout checks). Parsing
//! must return a database or a located error, never panic.
#![no_main]
use antisurge::io::can::dbc::CanDatabase;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(db) = CanDatabase::parse(text, "fuzz.dbc") {
        for m in db.messages() {
            let _ = db.message_by_id(m.id());
            let _ = m.guard();
        }
    }
});
