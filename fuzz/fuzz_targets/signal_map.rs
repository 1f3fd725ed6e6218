//! Signal-map loading: any text parsed as the signal map, then its checks and the derived
//! CAN and Modbus binding lists. Never a panic.
#![no_main]
use std::path::Path;

use antisurge::config::toml_file::parse;
use antisurge::io::signal_map::SignalMap;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(map) = parse::<SignalMap>(text, Path::new("signals.toml")) {
        let _ = map.check();
        let _ = map.can_bindings();
        let sensors = map.modbus_sensors().into_iter().map(|(_, b)| b);
        for b in sensors.chain(map.modbus_actuators().into_iter().map(|(_, b)| b)) {
            let _ = b.validate();
        }
    }
});
