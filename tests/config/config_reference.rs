//! The config reference cannot drift: every key of the daemon's schema is shown in
//! `config/antisurge.toml` (commented-out examples count) within its section, every key shown
//! there exists in the schema, and the file itself loads.
//!
//! The key set comes from a fully populated [`DaemonConfig`] (every optional section and key
//! set) serialized to TOML. The struct literals below list every field without `..`, so a new
//! field does not compile here until it is given a value — and then this test asks for its
//! line in the reference.

use crate::common;

use antisurge::daemon::config::tls::TlsSection;
use antisurge::daemon::config::{
    load_with_env, BusSection, ControlSection, DaemonConfig, InputSection, PlantSection,
    ReloadSection, SimulationSection, SparkplugSection, StartMode, StatusSection, Transport,
};
use antisurge::events::{EventLogConfig, FsyncPolicy};
use antisurge::io::can::bus::CanBusConfig;
use antisurge::io::modbus::{
    ClientConfig, HeartbeatRegister, ModbusLinkConfig, ModbusServerConfig, TransportConfig,
};
use antisurge::runtime::rt_loop::RtSettings;
use antisurge::vocab::signals::SensorId;
use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;

fn populated() -> DaemonConfig {
    let mut inputs = BTreeMap::new();
    inputs.insert(
        SensorId::PSuction,
        InputSection {
            min: 1.0e4,
            max: 1.2e7,
            timeout_ms: 50.0,
        },
    );
    let mut controller = toml::Table::new();
    let mut recycle_pi = toml::Table::new();
    let mut pi = toml::Table::new();
    pi.insert("kp_per_map_flow".into(), toml::Value::Float(10.0));
    recycle_pi.insert("pi".into(), toml::Value::Table(pi));
    controller.insert("recycle_pi".into(), toml::Value::Table(recycle_pi));
    let hb = HeartbeatRegister {
        unit_id: 1,
        address: 300,
    };
    DaemonConfig {
        plant: Some(PlantSection {
            file: PathBuf::from("plants/kvangardsnes2009_recycle.toml"),
        }),
        machine: Some(antisurge::daemon::config_machine::MachineSection {
            file: PathBuf::from("machines/vendor_example.toml"),
        }),
        control: ControlSection {
            law: "recycle-pi".into(),
            mode: StartMode::Auto,
            speed_setpoint_rad_s: Some(1000.0),
            flow_setpoint_kg_s: Some(12.0),
            failsafe_recycle_opening_pct: 100.0,
            startup_grace_ms: 1000.0,
        },
        cycle: RtSettings {
            rate_hz: 1000.0,
            priority: Some(80),
            cpu: Some(1),
            lock_memory: true,
        },
        inputs,
        bus: BusSection {
            transport: Transport::Field,
            signal_map: Some(PathBuf::from("signals.toml")),
            can: Some(CanBusConfig {
                interface: "can0".into(),
                dbc: PathBuf::from("skid.dbc"),
                heartbeat_period_ms: 10,
                heartbeat_timeout_ms: 100,
                reconnect_backoff_initial_ms: 50,
                reconnect_backoff_max_ms: 2000,
                tx_on_change_only: false,
                bitrate_bps: Some(1_000_000),
                max_load_pct: 70,
                not_available: antisurge::io::can::bus::NotAvailable::J1939,
                heartbeat: Some(antisurge::io::can::HeartbeatConfig {
                    message: "CTRL_Heartbeat".into(),
                    counter: Some("AliveCounter".into()),
                    mode: Some("Mode".into()),
                    law: Some("ActiveLaw".into()),
                    faults: Some("Faults".into()),
                }),
                frame_ids: [(
                    "CTRL_ActuatorCmd1".to_string(),
                    antisurge::io::can::dbc::FrameIdOverride::Id(0x18FF_1234),
                )]
                .into(),
                cycle_trigger: antisurge::io::can::bus::CycleTriggerSpec::Inputs,
            }),
            modbus: Some(ModbusLinkConfig {
                client: ClientConfig {
                    transport: TransportConfig::Tcp {
                        address: "192.168.0.10:502".parse().expect("address"),
                    },
                    timeout_ms: 100,
                    backoff_initial_ms: 100,
                    backoff_max_ms: 5000,
                },
                poll_rate_hz: 50.0,
                write_on_change_only: false,
                max_output_age_ms: 100,
                heartbeat_register: Some(hb),
                merge_writes: false,
                write_fault_timeout_ms: 500,
                cycle_trigger: antisurge::io::modbus::link::ModbusCycleTrigger::Reads,
                command_connection: antisurge::io::modbus::CommandConnection::Own,
            }),
        },
        controller,
        event_log: EventLogConfig {
            path: PathBuf::from("events.jsonl"),
            fsync: FsyncPolicy::Interval { interval_ms: 200 },
            max_bytes: 16 * 1024 * 1024,
            keep_files: 8,
            rt_queue_capacity: 1024,
            poll_interval_ms: 20,
        },
        simulation: SimulationSection {
            scenario: "throttle-closure".into(),
            out_dir: Some(PathBuf::from("out/plant")),
            heartbeat_timeout_ms: 100.0,
            hold_after_end: true,
            modbus_server: Some(ModbusServerConfig {
                listen: "127.0.0.1:5020".parse().expect("listen"),
                heartbeat_register: Some(hb),
                allow_writes_from: vec![
                    "127.0.0.1".parse().expect("ip"),
                    "::1".parse().expect("ip"),
                ],
            }),
        },
        status: StatusSection {
            log_interval_s: 10.0,
            stats_file: Some(PathBuf::from("cycle_stats.json")),
            socket: Some(PathBuf::from("status.sock")),
            state_dir: Some(PathBuf::from("/var/lib/antisurge")),
            metrics_listen: Some("127.0.0.1:9650".into()),
            metrics_allow_remote: false,
            hmi_listen: Some("127.0.0.1:9651".into()),
            tls: Some(TlsSection {
                cert_file: PathBuf::from("tls/hmi.crt"),
                key_file: PathBuf::from("tls/hmi.key"),
            }),
            modbus_listen: Some("0.0.0.0:502".into()),
            modbus_max_connections: Some(64),
            modbus_idle_timeout_s: 30.0,
            modbus_max_requests_per_s: 20.0,
            operator_token_file: Some(PathBuf::from("/etc/antisurge/operator.token")),
        },
        reload: ReloadSection {
            watch_files: false,
            settle_ms: 1000.0,
        },
        sparkplug: SparkplugSection {
            enabled: false,
            broker: "127.0.0.1:1883".into(),
            group_id: "antisurge".into(),
            edge_node_id: "skid-1".into(),
            client_id: Some("antisurge-antisurge-skid-1".into()),
            keep_alive_s: 5,
            publish_interval_ms: 100,
            deadband_pct: 0.5,
            deadbands_pct: [("Deviation".to_string(), 0.1)].into(),
            commands_enabled: false,
            username: Some("skid-1".into()),
            password_file: Some(PathBuf::from("/etc/antisurge/mqtt.password")),
            ca_file: Some(PathBuf::from("tls/broker-ca.crt")),
            store_forward_events: 10_000,
        },
    }
}

/// Every leaf key path of a table (`bus.can.interface`, `bus.modbus.client.transport.kind`).
fn leaves(t: &toml::Table, prefix: &str, out: &mut BTreeSet<String>) {
    for (k, v) in t {
        let path = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match v {
            toml::Value::Table(inner) => leaves(inner, &path, out),
            _ => {
                out.insert(path);
            }
        }
    }
}

/// The schema's keys, with the map sections written generically: `inputs.*.min`, and
/// `controller` as one key (its keys are the plant files' `[controller]` schema: any may be
/// overridden, the reference shows an example).
fn schema_keys() -> BTreeSet<String> {
    let table = toml::Table::try_from(populated()).expect("serialize the schema");
    let mut all = BTreeSet::new();
    leaves(&table, "", &mut all);
    all.into_iter()
        .map(|k| {
            let parts: Vec<&str> = k.split('.').collect();
            match parts[0] {
                "inputs" => format!("inputs.*.{}", parts[2..].join(".")),
                "controller" => "controller".into(),
                _ => k,
            }
        })
        .collect()
}

/// The reference's sections: header (commented or not) → its lines, comment marks stripped.
fn sections(text: &str) -> Vec<(String, Vec<String>)> {
    let mut out: Vec<(String, Vec<String>)> = vec![(String::new(), Vec::new())];
    for raw in text.lines() {
        let line = raw.trim_start_matches(|c: char| c == '#' || c.is_whitespace());
        if let Some(h) = header(line) {
            out.push((h, Vec::new()));
        } else if let Some(last) = out.last_mut() {
            last.1.push(line.to_string());
        }
    }
    out
}

/// `[a.b]` (with an optional trailing comment) → `a.b`.
fn header(line: &str) -> Option<String> {
    let rest = line.strip_prefix('[')?;
    let (name, after) = rest.split_once(']')?;
    let after = after.trim();
    let ok = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_' || c == '.')
        && (after.is_empty() || after.starts_with('#'));
    ok.then(|| name.to_string())
}

/// Does `line` set `key` (`key = …` at its start)?
fn sets(line: &str, key: &str) -> bool {
    line.strip_prefix(key)
        .is_some_and(|r| r.trim_start().starts_with('='))
}

/// Does `line` mention `key = ` anywhere (inline tables)?
fn mentions(line: &str, key: &str) -> bool {
    line.match_indices(key).any(|(i, _)| {
        let before = line[..i].chars().next_back();
        let boundary = before.is_none_or(|c| !(c.is_ascii_alphanumeric() || c == '_'));
        boundary && line[i + key.len()..].trim_start().starts_with('=')
    })
}

/// Is the schema key shown in the reference, in its section?
fn documented(secs: &[(String, Vec<String>)], key: &str) -> bool {
    if key == "controller" {
        return secs.iter().any(|(h, _)| h.starts_with("controller."));
    }
    let parts: Vec<&str> = key.split('.').collect();
    for split in (1..parts.len()).rev() {
        let head = parts[..split].join(".");
        let rest = &parts[split..];
        let matching = secs.iter().filter(|(h, _)| {
            if let Some(generic) = head.strip_prefix("inputs.*") {
                h.starts_with("inputs.") && generic.is_empty()
            } else {
                *h == head
            }
        });
        for (_, lines) in matching {
            if lines
                .iter()
                .any(|l| sets(l, rest[0]) && rest[1..].iter().all(|k| mentions(l, k)))
            {
                return true;
            }
        }
    }
    false
}

fn reference() -> (PathBuf, String) {
    let p = common::root().join("config/antisurge.toml");
    let text = std::fs::read_to_string(&p).expect("config/antisurge.toml");
    (p, text)
}

#[test]
fn every_schema_key_is_in_the_reference() {
    let (_, text) = reference();
    let secs = sections(&text);
    let keys = schema_keys();
    assert!(keys.len() > 40, "{keys:?}");
    for must in [
        "bus.can.interface",
        "bus.modbus.client.transport.kind",
        "bus.modbus.heartbeat_register.address",
        "simulation.modbus_server.listen",
        "status.stats_file",
        "cycle.cpu",
        "inputs.*.timeout_ms",
        "event_log.fsync_interval_ms",
        "controller",
    ] {
        assert!(keys.contains(must), "{must} not in {keys:?}");
    }
    let missing: Vec<&String> = keys.iter().filter(|k| !documented(&secs, k)).collect();
    assert!(
        missing.is_empty(),
        "config/antisurge.toml does not show these keys (add them, commented out if optional):\n  {}",
        missing
            .iter()
            .map(|s| s.as_str())
            .collect::<Vec<_>>()
            .join("\n  ")
    );
}

#[test]
fn every_key_in_the_reference_is_in_the_schema() {
    let (_, text) = reference();
    let keys = schema_keys();
    let known = |path: &str| {
        let generic = match path.strip_prefix("inputs.") {
            Some(rest) => match rest.split_once('.') {
                Some((_, leaf)) => format!("inputs.*.{leaf}"),
                None => "inputs.*".into(),
            },
            None => path.to_string(),
        };
        keys.iter()
            .any(|k| *k == generic || k.starts_with(&format!("{generic}.")))
    };
    let mut stale = Vec::new();
    for (h, lines) in sections(&text) {
        if h.is_empty() || h == "controller" || h.starts_with("controller.") {
            continue;
        }
        for l in &lines {
            let Some((k, _)) = l.split_once('=') else {
                continue;
            };
            let k = k.trim();
            let is_key = !k.is_empty()
                && k.chars()
                    .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
            if is_key && !known(&format!("{h}.{k}")) {
                stale.push(format!("[{h}] {k}"));
            }
        }
        if !known(&h) {
            stale.push(format!("[{h}]"));
        }
    }
    assert!(
        stale.is_empty(),
        "config/antisurge.toml shows keys the schema does not have:\n  {}",
        stale.join("\n  ")
    );
}

#[test]
fn the_populated_schema_round_trips() {
    let cfg = populated();
    let text = toml::to_string(&cfg).expect("serialize");
    let back: DaemonConfig = toml::from_str(&text).expect("deserialize");
    assert_eq!(back, cfg, "{text}");
}

#[test]
fn the_reference_loads() {
    let (p, _) = reference();
    let l = load_with_env(&p, &[]).unwrap_or_else(|problems| {
        panic!(
            "{} refused:\n{}",
            p.display(),
            problems
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join("\n")
        )
    });
    assert!(
        l.warnings.is_empty(),
        "the reference shows warnings: {:?}",
        l.warnings
    );
}

#[test]
fn the_check_notices_a_key_missing_from_the_reference() {
    let (_, text) = reference();
    // drop the stats_file example and the [bus.can] interface line
    let cut: String = text
        .lines()
        .filter(|l| !l.contains("stats_file") && !l.starts_with("interface"))
        .map(|l| format!("{l}\n"))
        .collect();
    let secs = sections(&cut);
    assert!(!documented(&secs, "status.stats_file"));
    assert!(!documented(&secs, "bus.can.interface"));
    assert!(documented(&secs, "bus.can.dbc"));
    // a key shown in the wrong section does not count
    assert!(!documented(
        &sections("[cycle]\ninterface = \"can0\"\n"),
        "bus.can.interface"
    ));
    // inline tables count, key by key
    let secs = sections("# [bus.modbus]\n# heartbeat_register = { unit_id = 1 }\n");
    assert!(documented(&secs, "bus.modbus.heartbeat_register.unit_id"));
    assert!(!documented(&secs, "bus.modbus.heartbeat_register.address"));
}
