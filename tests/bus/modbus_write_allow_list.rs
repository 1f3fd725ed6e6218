//! Regression test of issue 12, item 8: the plant node's Modbus server let any client write
//! actuator setpoints and forge the controller's heartbeat (a third client closed the valve;
//! forged heartbeats pulled the devices out of their fail-safe after the controller died).
//! Now only clients in `allow_writes_from` (default 127.0.0.1 and ::1) may write; others get
//! exception 0x01 and nothing changes. The "other client" here connects from 127.0.0.2.

use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use antisurge::io::modbus::{HeartbeatRegister, ModbusServerConfig, PlantServer};
use antisurge::io::signal_map::SignalMap;
use antisurge::runtime::handoff::{CommandBoard, HeartbeatBoard, SnapshotBoard};
use antisurge::vocab::signals::ActuatorId;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpSocket;

/// Write Single Register (0x06) of `word` at `address`, unit 1, from `from`; the answer.
async fn write_register(from: [u8; 4], to: SocketAddr, address: u16, word: u16) -> Vec<u8> {
    let socket = TcpSocket::new_v4().expect("socket");
    socket
        .bind(SocketAddr::from((from, 0)))
        .expect("bind the client address");
    let mut s = socket.connect(to).await.expect("connect");
    let [ah, al] = address.to_be_bytes();
    let [wh, wl] = word.to_be_bytes();
    s.write_all(&[0, 7, 0, 0, 0, 6, 1, 0x06, ah, al, wh, wl])
        .await
        .expect("write");
    let mut buf = vec![0u8; 64];
    let n = tokio::time::timeout(Duration::from_secs(2), s.read(&mut buf))
        .await
        .expect("an answer within 2 s")
        .expect("read");
    buf.truncate(n);
    buf
}

#[tokio::test]
async fn a_client_not_allowed_cannot_write_actuators_or_the_heartbeat() {
    let (map, _): (SignalMap, String) =
        antisurge::config::toml_file::load(Path::new("config/signals_modbus.toml"))
            .expect("signal map");
    let hb = HeartbeatRegister {
        unit_id: 1,
        address: 300,
    };
    let cfg = ModbusServerConfig {
        listen: "127.0.0.1:0".parse().unwrap(),
        heartbeat_register: Some(hb),
        ..ModbusServerConfig::default()
    };
    assert!(cfg.may_write("127.0.0.1".parse().unwrap()));
    assert!(cfg.may_write("::ffff:127.0.0.1".parse().unwrap()));
    assert!(!cfg.may_write("127.0.0.2".parse().unwrap()));
    let commands: Arc<CommandBoard> = Arc::default();
    let heartbeat: Arc<HeartbeatBoard> = Arc::default();
    let snapshots: Arc<SnapshotBoard> = Arc::default();
    let server = PlantServer::bind(
        &cfg,
        &map,
        snapshots,
        Arc::clone(&commands),
        Arc::clone(&heartbeat),
    )
    .await
    .expect("bind");
    let addr = server.local_addr();
    let counters = server.counters();
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(server.run(async move {
        let _ = rx.await;
    }));

    // recycle_valve: holding 102, u16, scale 1e-4; 1000 = 10 % open
    let answer = write_register([127, 0, 0, 2], addr, 102, 1000).await;
    assert_eq!(
        &answer[7..],
        &[0x86, 0x01],
        "exception 0x01 expected: {answer:02x?}"
    );
    // heartbeat block (mode word first)
    let answer = write_register([127, 0, 0, 2], addr, 300, 2).await;
    assert_eq!(&answer[7..], &[0x86, 0x01], "{answer:02x?}");
    assert_eq!(
        commands.get(ActuatorId::RecycleValve).1,
        0,
        "a refused write reached the command board"
    );
    assert!(
        heartbeat.latest().is_none(),
        "a refused write counted as heartbeat"
    );
    let c = counters.snapshot();
    assert_eq!((c.refused_writes, c.writes, c.heartbeats), (2, 0, 0));

    // the same write from the allowed loopback client is applied
    let answer = write_register([127, 0, 0, 1], addr, 102, 1000).await;
    assert_eq!(&answer[7..], &[0x06, 0, 102, 0x03, 0xE8], "{answer:02x?}");
    let (v, t_ns) = commands.get(ActuatorId::RecycleValve);
    assert!(t_ns > 0 && (v - 0.1).abs() < 1e-9, "{v} at {t_ns}");
    assert_eq!(counters.snapshot().refused_writes, 2);

    let _ = tx.send(());
    task.await.expect("join").expect("server ran cleanly");
}

/// One request PDU (unit 1) from `from`; the answer's PDU.
async fn request(from: [u8; 4], to: SocketAddr, pdu: &[u8]) -> Vec<u8> {
    let socket = TcpSocket::new_v4().expect("socket");
    socket
        .bind(SocketAddr::from((from, 0)))
        .expect("bind the client address");
    let mut s = socket.connect(to).await.expect("connect");
    let mut frame = vec![0, 9, 0, 0, 0, (pdu.len() + 1) as u8, 1];
    frame.extend_from_slice(pdu);
    s.write_all(&frame).await.expect("write");
    let mut buf = vec![0u8; 64];
    let n = tokio::time::timeout(Duration::from_secs(2), s.read(&mut buf))
        .await
        .expect("an answer within 2 s")
        .expect("read");
    buf[7..n].to_vec()
}

/// Coils are writes too: a device watchdog watching a toggle coil cannot be fed by a client
/// outside `allow_writes_from` (write single coil 0x05 and write multiple coils 0x0F refused
/// with exception 1); the controller's flip of the coil is a heartbeat.
#[tokio::test]
async fn a_client_not_allowed_cannot_flip_the_watchdog_coil() {
    let (map, _): (SignalMap, String) = antisurge::config::toml_file::load(Path::new(
        "tests/fixtures/foreign_skid/modbus_map_coils.toml",
    ))
    .expect("signal map");
    let cfg = ModbusServerConfig {
        listen: "127.0.0.1:0".parse().unwrap(),
        ..ModbusServerConfig::default()
    };
    let heartbeat: Arc<HeartbeatBoard> = Arc::default();
    let server = PlantServer::bind(
        &cfg,
        &map,
        Arc::default(),
        Arc::default(),
        Arc::clone(&heartbeat),
    )
    .await
    .expect("bind");
    let addr = server.local_addr();
    let counters = server.counters();
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(server.run(async move {
        let _ = rx.await;
    }));

    // coil 00001 = address 0: ON is FF00
    let single = [0x05, 0, 0, 0xFF, 0x00];
    let multiple = [0x0F, 0, 0, 0, 1, 1, 0x01];
    assert_eq!(request([127, 0, 0, 2], addr, &single).await, [0x85, 0x01]);
    assert_eq!(request([127, 0, 0, 2], addr, &multiple).await, [0x8F, 0x01]);
    assert!(
        heartbeat.latest().is_none(),
        "a refused coil write fed the watchdog"
    );
    assert_eq!(counters.snapshot().refused_writes, 2);
    // reading the coil back is allowed: still off
    assert_eq!(
        request([127, 0, 0, 2], addr, &[0x01, 0, 0, 0, 1]).await,
        [0x01, 0x01, 0x00]
    );

    // the controller (loopback) flips it: applied, and a sign of life
    assert_eq!(request([127, 0, 0, 1], addr, &single).await, single);
    assert!(heartbeat.latest().is_some(), "the coil flip is a heartbeat");
    assert_eq!(
        request([127, 0, 0, 1], addr, &[0x01, 0, 0, 0, 1]).await,
        [0x01, 0x01, 0x01]
    );
    // a coil the device does not have: exception 2
    assert_eq!(
        request([127, 0, 0, 1], addr, &[0x05, 0, 7, 0xFF, 0x00]).await,
        [0x85, 0x02]
    );

    let _ = tx.send(());
    task.await.expect("join").expect("server ran cleanly");
}
