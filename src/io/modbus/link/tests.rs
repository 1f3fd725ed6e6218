//! The controller link's tests.

use super::*;
use crate::io::modbus::client::ClientConfig;
use crate::io::modbus::register::DataType;
use crate::io::signal_map::Binding;

#[test]
fn link_config_from_toml_with_defaults() {
    let c: ModbusLinkConfig = toml::from_str(
        r#"
        heartbeat_register = { unit_id = 1, address = 300 }
        [client]
        timeout_ms = 40
        transport = { kind = "tcp", address = "10.0.0.5:502" }
        "#,
    )
    .unwrap();
    assert_eq!(c.poll_rate_hz, 50.0);
    assert!(!c.write_on_change_only);
    assert_eq!(c.max_output_age_ms, 500);
    assert_eq!(c.client.timeout_ms, 40);
    assert_eq!(c.client.backoff_max_ms, 5000);
    assert_eq!(
        c.heartbeat_register,
        Some(HeartbeatRegister {
            unit_id: 1,
            address: 300
        })
    );
    assert_eq!(c.period(), Duration::from_millis(20));
    assert!(c.validate().is_ok());

    let rtu: ModbusLinkConfig = toml::from_str(
        "poll_rate_hz = 10\nwrite_on_change_only = true\n\
         [client]\ntransport = { kind = \"rtu\", path = \"/dev/ttyUSB0\", baud = 19200 }\n",
    )
    .unwrap();
    assert!(rtu.write_on_change_only && rtu.validate().is_ok());

    for bad in [
        "pol_rate_hz = 5\n[client]\ntransport = { kind = \"tcp\", address = \"1.2.3.4:502\" }",
        "heartbeat_register = { unit_id = 1, address = 3, table = \"input\" }\n\
         [client]\ntransport = { kind = \"tcp\", address = \"1.2.3.4:502\" }",
    ] {
        assert!(toml::from_str::<ModbusLinkConfig>(bad).is_err(), "{bad}");
    }
}

#[test]
fn link_config_validation() {
    let mut c = ModbusLinkConfig::new(ClientConfig::tcp("127.0.0.1:502".parse().unwrap()));
    assert!(c.validate().is_ok());
    for rate in [0.0, -1.0, f64::NAN, 1000.5] {
        c.poll_rate_hz = rate;
        assert!(
            matches!(c.validate(), Err(LinkError::Invalid { .. })),
            "{rate}"
        );
    }
    c.poll_rate_hz = 1000.0;
    assert!(c.validate().is_ok());
    c.max_output_age_ms = 0;
    assert!(c.validate().is_err());
    c.max_output_age_ms = 1;
    c.heartbeat_register = Some(HeartbeatRegister {
        unit_id: 1,
        address: 65533,
    });
    assert!(c.validate().is_err());
    c.heartbeat_register = Some(HeartbeatRegister {
        unit_id: 1,
        address: 65532,
    });
    assert!(c.validate().is_ok());
    c.command_connection = CommandConnection::Own;
    assert!(c.validate().is_ok());
    c.client.timeout_ms = 0;
    assert!(matches!(c.validate(), Err(LinkError::Client(_))));
    // a second connection needs TCP: an RTU line carries one request at a time
    let mut rtu = c.clone();
    rtu.client.timeout_ms = 100;
    rtu.client.transport = super::super::client::TransportConfig::Rtu(
        super::super::client::RtuConfig::new("/dev/ttyUSB0", 19200),
    );
    assert!(matches!(
        rtu.validate(),
        Err(LinkError::Invalid {
            key: "command_connection",
            ..
        })
    ));
    rtu.command_connection = CommandConnection::Shared;
    assert!(rtu.validate().is_ok());
}

#[test]
fn server_config_defaults() {
    let s: ModbusServerConfig = toml::from_str("").unwrap();
    assert_eq!(s, ModbusServerConfig::default());
    assert_eq!(s.listen.port(), 5020);
    assert!(toml::from_str::<ModbusServerConfig>("listn = \"0.0.0.0:502\"").is_err());
}

#[test]
fn heartbeat_words_round_trip_through_bindings() {
    let hb = HeartbeatRegister {
        unit_id: 3,
        address: 10,
    };
    let w = HeartbeatWords {
        mode: 3,
        alive: 255,
        law: 7,
        faults: 0xdead_beef,
    };
    let words = w.encode();
    assert_eq!(words, [0x03ff, 7, 0xdead, 0xbeef]);
    assert_eq!(HeartbeatWords::decode(&words), w);
    // The controller writes the block through the bindings: same words on the wire.
    let b = hb.bindings();
    let mut wire = [0u16; 4];
    let _ = b[0].encode(f64::from(words[0]), &mut wire[0..1]).unwrap();
    let _ = b[1].encode(f64::from(words[1]), &mut wire[1..2]).unwrap();
    let _ = b[2].encode(f64::from(w.faults), &mut wire[2..4]).unwrap();
    assert_eq!(wire, words);
    assert!(hb.touched_by(3, 13, 1));
    assert!(hb.touched_by(3, 0, 11));
    assert!(!hb.touched_by(3, 14, 2));
    assert!(!hb.touched_by(3, 0, 10));
    assert!(!hb.touched_by(2, 10, 4));
}

#[test]
fn heartbeat_block_must_not_overlap_signals() {
    let mut map = SignalMap::default();
    map.actuators.insert(
        ActuatorId::RecycleValve,
        Binding::Modbus(RegisterBinding::new(
            1,
            RegisterTable::Holding,
            102,
            DataType::F32,
        )),
    );
    let at = |address| HeartbeatRegister {
        unit_id: 1,
        address,
    };
    assert!(check_map(&map, Some(&at(104))).is_ok());
    assert!(check_map(&map, Some(&at(99))).is_err());
    let e = check_map(&map, Some(&at(103))).unwrap_err();
    assert!(e.to_string().contains("holding register 102"), "{e}");
    // Same address on another unit is fine.
    assert!(check_map(
        &map,
        Some(&HeartbeatRegister {
            unit_id: 2,
            address: 102
        })
    )
    .is_ok());
}
