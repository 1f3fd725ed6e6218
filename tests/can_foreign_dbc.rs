//! A foreign-style DBC (tests/fixtures/foreign_skid/skid_foreign.dbc: valve signals in %,
//! pressures in bar, speed in rpm, a 29-bit Motorola message, a 16-bit watchdog counter
//! message named its own way): units are checked against each bound quantity and converted
//! to SI, bytes on the wire are the device's.

mod common;

use antisurge::io::can::{CanCodec, CanDatabase, FrameId, SignalBinding};
use antisurge::signals::{ActuatorCommands, ActuatorId, SensorId, SensorSnapshot};

fn db() -> CanDatabase {
    CanDatabase::from_file(common::root().join("tests/fixtures/foreign_skid/skid_foreign.dbc"))
        .expect("foreign DBC parses")
}

fn bindings() -> Vec<SignalBinding> {
    vec![
        SignalBinding::actuator(
            ActuatorId::RecycleValve,
            "VLV_Command",
            "RecycleValveSetpoint",
        ),
        SignalBinding::actuator(
            ActuatorId::DriveTorque,
            "VLV_Command",
            "DriveTorqueSetpoint",
        ),
        SignalBinding::sensor(SensorId::PSuction, "SKID_Process", "SuctionPressure"),
        SignalBinding::sensor(SensorId::PDischarge, "SKID_Process", "DischargePressure"),
        SignalBinding::sensor(SensorId::ShaftSpeed, "SKID_Process", "Speed"),
        SignalBinding::sensor(SensorId::OrificeDp, "SKID_Process", "OrificeDp"),
        SignalBinding::sensor(
            SensorId::RecycleValvePosition,
            "SKID_Status",
            "RecycleValvePos",
        ),
        SignalBinding::sensor(SensorId::TSuction, "SKID_Status", "SuctionTemp"),
    ]
}

#[test]
fn percent_signal_bound_to_a_fraction_converts() {
    let codec = CanCodec::new(&db(), &bindings()).expect("bindings fit");
    let m = codec.message_index("VLV_Command").expect("message");
    let mut c = ActuatorCommands::default();
    c.set(ActuatorId::RecycleValve, 0.375);
    c.set(ActuatorId::DriveTorque, -120.0);
    let e = codec.encode(m, &c, 0).expect("encode");
    // 37.50 % = 3750 = 0x0EA6, Intel; -120 N·m = 0xFF88
    assert_eq!(&e.data[..4], &[0xA6, 0x0E, 0x88, 0xFF]);
    let d = codec
        .decode(FrameId::Standard(256), &e.data[..8])
        .expect("decode");
    let v = d
        .get(antisurge::io::can::SignalTarget::Actuator(
            ActuatorId::RecycleValve,
        ))
        .expect("valve");
    assert!((v - 0.375).abs() < 1e-12, "{v}");
}

#[test]
fn extended_motorola_frame_in_bar_and_rpm_decodes_to_si() {
    let codec = CanCodec::new(&db(), &bindings()).expect("bindings fit");
    let id = FrameId::Extended(0x18FF_1020);
    // Motorola 16-bit words: 1.013 bar = 1013, 12.5 bar = 12500, 9000 rpm = 18000 × 0.5,
    // 25.00 kPa = 2500
    let mut data = [0u8; 8];
    for (k, w) in [1013u16, 12_500, 18_000, 2_500].iter().enumerate() {
        data[2 * k..2 * k + 2].copy_from_slice(&w.to_be_bytes());
    }
    let d = codec.decode(id, &data).expect("decode");
    let g = |s| {
        d.get(antisurge::io::can::SignalTarget::Sensor(s))
            .expect("value")
    };
    assert!((g(SensorId::PSuction) - 101_300.0).abs() < 1e-6);
    assert!((g(SensorId::PDischarge) - 1_250_000.0).abs() < 1e-6);
    assert!((g(SensorId::ShaftSpeed) - 9000.0 * std::f64::consts::PI / 30.0).abs() < 1e-9);
    assert!((g(SensorId::OrificeDp) - 25_000.0).abs() < 1e-6);
    // and the sensor side encodes back to the same bytes (the plant node's view)
    let mut s = SensorSnapshot::default();
    s.set(SensorId::PSuction, 101_300.0);
    s.set(SensorId::PDischarge, 1_250_000.0);
    s.set(SensorId::ShaftSpeed, 9000.0 * std::f64::consts::PI / 30.0);
    s.set(SensorId::OrificeDp, 25_000.0);
    let m = codec.message_index("SKID_Process").expect("message");
    let e = codec.encode(m, &s, 0).expect("encode");
    assert_eq!(e.id, id);
    assert_eq!(e.data, data);
}

#[test]
fn a_bar_signal_bound_to_a_valve_is_refused_naming_the_signal() {
    let mut b = bindings();
    b[0] = SignalBinding::actuator(ActuatorId::RecycleValve, "SKID_Process", "SuctionPressure");
    b.remove(2);
    let e = CanCodec::new(&db(), &b).expect_err("bar is no fraction");
    let text = e.to_string();
    assert!(text.contains("SKID_Process.SuctionPressure"), "{text}");
    assert!(text.contains("\"bar\""), "{text}");
    assert!(text.contains("fraction"), "{text}");
    // and the shipped DBC's units all fit their targets
    let shipped = CanDatabase::from_file(common::root().join("config/skid.dbc")).expect("dbc");
    CanCodec::new(&shipped, &antisurge::io::can::codec::skid_bindings())
        .expect("shipped units fit");
}
