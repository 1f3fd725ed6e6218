//! Input freshness defaults follow the bus (issue 10): inputs polled over Modbus get a
//! default timeout of three poll periods, so a device answering at the poll rate (or a
//! 100 ms blip within the failure hold) does not enter fail-safe; an explicit
//! `[inputs.<sensor>] timeout_ms` still wins, and the in-process bus keeps the 50 ms default.

use crate::common;

use antisurge::control::core::CoreSettings;
use antisurge::daemon::config::{load_with_env, Loaded};
use antisurge::vocab::signals::SensorId;

fn shipped(rel: &str) -> String {
    common::root()
        .join("config")
        .join(rel)
        .display()
        .to_string()
}

fn load(text: &str) -> (tempfile::TempDir, Loaded) {
    let tmp = tempfile::tempdir().expect("tempdir");
    let main = tmp.path().join("antisurge.toml");
    std::fs::write(&main, text).expect("write");
    let l = load_with_env(&main, &[]).unwrap_or_else(|p| panic!("refused: {p:?}"));
    (tmp, l)
}

fn modbus_config(poll_rate_hz: f64) -> String {
    format!(
        r#"[plant]
file = "{plant}"
[control]
law = "recycle-pi"
[cycle]
rate_hz = 50.0
lock_memory = false
[inputs.p_discharge]
min = 1.0e4
max = 1.2e7
timeout_ms = 500.0
[bus]
transport = "field"
signal_map = "{map}"
[bus.modbus]
poll_rate_hz = {poll_rate_hz}
[bus.modbus.client]
timeout_ms = 100
transport = {{ kind = "tcp", address = "127.0.0.1:5020" }}
"#,
        plant = shipped("plants/kvangardsnes2009_recycle.toml"),
        map = shipped("signals_modbus.toml"),
    )
}

fn timeout_s(l: &Loaded, id: SensorId) -> f64 {
    l.core.supervisor.limits[id.index()]
        .unwrap_or_else(|| panic!("{id:?} not supervised"))
        .timeout_s
}

#[test]
fn modbus_inputs_default_to_three_poll_periods() {
    for (rate, expect_s) in [(50.0, 0.06), (10.0, 0.3)] {
        let (_tmp, l) = load(&modbus_config(rate));
        for id in [
            SensorId::PSuction,
            SensorId::ShaftSpeed,
            SensorId::OrificeDp,
            SensorId::RecycleValvePosition,
        ] {
            let t = timeout_s(&l, id);
            assert!(
                (t - expect_s).abs() < 1e-9,
                "{id:?} at {rate} Hz: timeout {t} s, expected {expect_s} s"
            );
        }
        // an explicit timeout is the operator's: kept
        let t = timeout_s(&l, SensorId::PDischarge);
        assert!((t - 0.5).abs() < 1e-9, "explicit p_discharge timeout {t}");
    }
}

#[test]
fn a_fast_poll_never_shortens_the_default_and_in_process_keeps_it() {
    // 1 kHz: 3 ms would be shorter than the 50 ms default, which stays
    let (_tmp, l) = load(&modbus_config(1000.0));
    let default = CoreSettings::defaults_for(&l.model).supervisor.limits
        [SensorId::PSuction.index()]
    .expect("limits")
    .timeout_s;
    assert!((timeout_s(&l, SensorId::PSuction) - default).abs() < 1e-12);
    let (_tmp, l) = load(&format!(
        "[plant]\nfile = \"{}\"\n[control]\nlaw = \"recycle-pi\"\n",
        shipped("plants/kvangardsnes2009_recycle.toml")
    ));
    assert!((timeout_s(&l, SensorId::PSuction) - default).abs() < 1e-12);
    assert!((default - 0.05).abs() < 1e-12, "{default}");
}
