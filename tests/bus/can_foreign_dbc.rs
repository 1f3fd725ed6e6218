//! A foreign-style DBC (tests/fixtures/foreign_skid/skid_foreign.dbc: valve signals in %,
//! pressures in bar, speed in rpm, a 29-bit Motorola message, a 16-bit watchdog counter
//! message named its own way): units are checked against each bound quantity and converted
//! to SI, bytes on the wire are the device's.

use crate::common;

use antisurge::io::can::{CanCodec, CanDatabase, FrameId, SignalBinding};
use antisurge::vocab::signals::{ActuatorCommands, ActuatorId, SensorId, SensorSnapshot};

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

/// The heartbeat named in config (`[bus.can.heartbeat]`): the skid's own 16-bit watchdog
/// counter message, no mode, law or fault signals. Bytes on the wire: the counter as a
/// little-endian u16 in a 2-byte frame, +1 per heartbeat, wrapping 65535 → 0; the plant side
/// of the same DBC takes it as a heartbeat and sees a repeated frame as a stuck sender.
#[test]
fn heartbeat_from_config_is_the_skids_16_bit_counter_on_the_wire() {
    use antisurge::io::can::bus::{BusCodec, CanCounters, HeartbeatTx, RxHandler, RxOutcome};
    use antisurge::io::can::HeartbeatConfig;
    use antisurge::runtime::handoff::{CommandBoard, HeartbeatBoard, Outputs};
    use socketcan::EmbeddedFrame;
    use std::sync::Arc;

    let cfg = antisurge::io::can::bus::CanBusConfig {
        heartbeat: Some(HeartbeatConfig {
            message: "DCS_Watchdog".into(),
            counter: Some("WdCounter".into()),
            mode: None,
            law: None,
            faults: None,
        }),
        ..antisurge::io::can::bus::CanBusConfig::new("vcan0", "skid_foreign.dbc")
    };
    let codec = BusCodec::with_heartbeat(&db(), &bindings(), &cfg.heartbeat_names())
        .expect("heartbeat fits the foreign DBC");
    assert_eq!(codec.heartbeat.frame_id(), FrameId::Standard(257));
    assert_eq!(codec.heartbeat.dlc(), 2);
    assert_eq!(codec.heartbeat.alive_bits(), Some(16));
    let mut tx = HeartbeatTx::new(&codec.heartbeat).expect("tx");
    let outputs = |cycle: u64| Outputs {
        commands: Default::default(),
        mode: antisurge::vocab::Mode::Auto,
        law: 1,
        faults: 0x0000_0101,
        cycle,
        t_ns: cycle,
    };
    let mut frames = Vec::new();
    for k in 0..65_538u64 {
        let f = tx.next_frame(Some(&outputs(k))).expect("heartbeat");
        let expect = ((k & 0xFFFF) as u16).to_le_bytes();
        assert_eq!(f.data(), &expect, "heartbeat {k}");
        if !(3..65_535).contains(&k) {
            frames.push(f);
        }
    }
    // 65535 → 0 → 1 at the wrap
    let tail: Vec<&[u8]> = frames[3..].iter().map(|f| f.data()).collect();
    assert_eq!(tail, [&[0xFF, 0xFF][..], &[0, 0][..], &[1, 0][..]]);
    // the same cycle again is withheld (a heartbeat vouches for a running control loop)
    assert!(tx.next_frame(Some(&outputs(65_537))).is_none());

    // Plant side: the frame is the heartbeat; a repeated counter is a stuck sender.
    let codec = Arc::new(codec);
    let board = Arc::new(HeartbeatBoard::default());
    let counters = Arc::new(CanCounters::default());
    let mut rx = RxHandler::plant(
        Arc::clone(&codec),
        Arc::new(CommandBoard::default()),
        Arc::clone(&board),
        Arc::clone(&counters),
    );
    let id = FrameId::Standard(257);
    assert_eq!(
        rx.handle_data(id, frames[0].data(), 10),
        RxOutcome::Published
    );
    assert_eq!(
        rx.handle_data(id, frames[1].data(), 20),
        RxOutcome::Published
    );
    assert!(matches!(
        rx.handle_data(id, frames[1].data(), 30),
        RxOutcome::Rejected(_)
    ));
    let seen = board.latest().expect("heartbeat seen");
    assert_eq!((seen.alive, seen.t_ns), (1, 20));
    assert_eq!(counters.snapshot().alive_repeated, 1);

    // A mode signal the DBC does not have is refused, naming it.
    let e = BusCodec::with_heartbeat(
        &db(),
        &bindings(),
        &antisurge::io::can::HeartbeatNames {
            mode: Some("Mode"),
            ..cfg.heartbeat_names()
        },
    )
    .expect_err("no Mode signal in DCS_Watchdog");
    assert_eq!(
        e.to_string(),
        "message DCS_Watchdog, signal Mode: no such signal"
    );
}

/// A device without a "not available" value (`bus.can.not_available = "none"`): no frame
/// until every bound command was computed, a command that stops being computed repeats the
/// last number sent (never 0x8000 = −32768 N·m or 0xFFFF = 655.35 %), and a data signal left
/// unbound is refused naming it. The J1939 convention for comparison.
#[test]
fn a_device_without_not_available_never_gets_a_command_it_was_not_given() {
    use antisurge::io::can::bus::{FrameEncoder, NotAvailable};
    use socketcan::EmbeddedFrame;
    use std::time::Duration;

    let ms = 1_000_000u64;
    let codec = CanCodec::new(&db(), &bindings()).expect("bindings fit");
    let vlv = codec.message_index("VLV_Command").expect("message");
    let enc = |na| {
        FrameEncoder::with_not_available(&codec, &[vlv], false, Duration::from_millis(50), na)
            .expect("encoder")
    };
    let mut none = enc(NotAvailable::None);
    let mut j1939 = enc(NotAvailable::J1939);
    let mut c = ActuatorCommands::default();
    c.set(ActuatorId::RecycleValve, 0.375);
    c.set(ActuatorId::DriveTorque, f64::NAN);
    assert!(
        none.encode(0, &c, 0).is_none(),
        "torque never computed: nothing sent"
    );
    let f = j1939.encode(0, &c, 0).expect("J1939 frame");
    assert_eq!(f.data()[..4], [0xA6, 0x0E, 0x00, 0x80], "J1939: torque n/a");
    // VLV_Command runs at 10 ms (GenMsgCycleTime)
    c.set(ActuatorId::DriveTorque, -120.0);
    let f = none.encode(0, &c, 10 * ms).expect("both computed");
    assert_eq!(f.data(), &[0xA6, 0x0E, 0x88, 0xFF, 0, 0, 0, 0]);
    c.set(ActuatorId::RecycleValve, 0.5);
    c.set(ActuatorId::DriveTorque, f64::NAN);
    let f = none.encode(0, &c, 20 * ms).expect("frame");
    assert_eq!(
        f.data()[..4],
        [0x88, 0x13, 0x88, 0xFF],
        "50.00 % and the last torque sent"
    );
    let f = j1939.encode(0, &c, 10 * ms).expect("frame");
    assert_eq!(f.data()[..4], [0x88, 0x13, 0x00, 0x80]);

    // an unbound data signal: refused without a "not available" value, n/a with J1939
    let mut b = bindings();
    b.retain(|x| x.signal != "DriveTorqueSetpoint");
    let codec = CanCodec::new(&db(), &b).expect("bindings fit");
    let vlv = codec.message_index("VLV_Command").expect("message");
    let e = FrameEncoder::with_not_available(
        &codec,
        &[vlv],
        false,
        Duration::from_millis(50),
        NotAvailable::None,
    )
    .expect_err("unbound torque");
    assert!(
        e.to_string().contains("VLV_Command.DriveTorqueSetpoint"),
        "{e}"
    );
    let mut j = FrameEncoder::with_not_available(
        &codec,
        &[vlv],
        false,
        Duration::from_millis(50),
        NotAvailable::J1939,
    )
    .expect("J1939 fills it");
    c.set(ActuatorId::RecycleValve, 0.375);
    let f = j.encode(0, &c, 0).expect("frame");
    assert_eq!(f.data()[..4], [0xA6, 0x0E, 0x00, 0x80]);
}

/// A recycle-only skid whose DBC carries a drive-torque signal in the valve's message: with
/// the default `not_available = "dbc"` and a DBC that declares no J1939 network, the torque
/// signal carries the DBC's start value (`GenSigStartValue`), never all ones (−32 768 N·m on
/// a device that is not J1939); without a start value the config is refused naming the
/// signal; a DBC that declares J1939 gets the J1939 pattern.
#[test]
fn an_unbound_signal_carries_the_dbcs_start_value_unless_the_dbc_says_j1939() {
    use antisurge::io::can::bus::{FrameEncoder, NotAvailable};
    use socketcan::EmbeddedFrame;
    use std::time::Duration;

    let text = std::fs::read_to_string(
        common::root().join("tests/fixtures/foreign_skid/skid_foreign.dbc"),
    )
    .expect("dbc");
    // the device's own "no torque request": raw 0x1234 (4660 N·m would be absurd as a
    // command, which is what makes it recognisable on the bytes)
    let with_start = format!(
        "{text}\nBA_DEF_ SG_  \"GenSigStartValue\" FLOAT -3.4E+038 3.4E+038;\nBA_DEF_DEF_  \"GenSigStartValue\" 0;\nBA_ \"GenSigStartValue\" SG_ 256 DriveTorqueSetpoint 4660;\n"
    );
    let recycle_only: Vec<SignalBinding> = bindings()
        .into_iter()
        .filter(|b| b.signal != "DriveTorqueSetpoint")
        .collect();
    let encoder = |dbc: &str| {
        let db = CanDatabase::parse(dbc, "skid_foreign.dbc").expect("parses");
        let codec = CanCodec::new(&db, &recycle_only).expect("bindings fit");
        let vlv = codec.message_index("VLV_Command").expect("message");
        FrameEncoder::with_not_available(
            &codec,
            &[vlv],
            false,
            Duration::from_millis(50),
            NotAvailable::default(),
        )
    };
    let mut c = ActuatorCommands::default();
    c.set(ActuatorId::RecycleValve, 0.375);

    let f = encoder(&with_start)
        .expect("start value given")
        .encode(0, &c, 0)
        .expect("frame");
    // valve 37.50 % = 3750 = 0x0EA6 (Intel), torque: the start value 0x1234, not 0x8000
    assert_eq!(f.data()[..4], [0xA6, 0x0E, 0x34, 0x12], "{:02X?}", f.data());

    // no start value and no J1939 declaration: refused, naming the signal and the fixes
    let e = encoder(&text).expect_err("no start value");
    let msg = e.to_string();
    assert!(msg.contains("VLV_Command.DriveTorqueSetpoint"), "{msg}");
    assert!(msg.contains("GenSigStartValue"), "{msg}");

    // the same DBC declaring a J1939 network: the J1939 pattern
    let j1939 = format!(
        "{text}\nBA_DEF_  \"ProtocolType\" STRING ;\nBA_DEF_DEF_  \"ProtocolType\" \"\";\nBA_ \"ProtocolType\" \"J1939\";\n"
    );
    let f = encoder(&j1939)
        .expect("J1939 fills it")
        .encode(0, &c, 0)
        .expect("frame");
    assert_eq!(f.data()[..4], [0xA6, 0x0E, 0x00, 0x80]);
}
