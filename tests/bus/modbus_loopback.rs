//! Client ↔ server loopback tests over 127.0.0.1 (and a pseudo-terminal for RTU):
//! round trips, timeouts, reconnect with backoff, exceptions.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use antisurge::io::modbus::{
    lock_image, spawn_rtu_server, spawn_tcp_server, ByteOrder, ClientConfig, ConnectionState,
    DataType, ExceptionCode, ModbusClient, ModbusError, ReadPlan, RegisterBinding, RegisterImage,
    RegisterTable, ResponseMode, RtuConfig, SharedImage, TransportConfig, WordOrder, WritePlan,
};
use antisurge::vocab::signals::{SensorId, SensorSnapshot};
use tokio::net::TcpListener;

const LOCALHOST: &str = "127.0.0.1:0";

/// Sensor bindings with a mix of types, orders, scalings, tables and units.
fn sensor_bindings() -> Vec<(SensorId, RegisterBinding)> {
    use DataType::*;
    use RegisterTable::{Holding, Input};
    vec![
        // Unit 1 input registers 0..9: one contiguous block.
        (
            SensorId::PSuction,
            RegisterBinding::new(1, Input, 0, F32), // Pa, ABCD
        ),
        (
            SensorId::PDischarge,
            RegisterBinding::new(1, Input, 2, F32).with_order(ByteOrder::Big, WordOrder::Little),
        ),
        (
            SensorId::ShaftSpeed,
            RegisterBinding::new(1, Input, 4, U32).with_scaling(0.001, 0.0), // mrad/s counts
        ),
        (
            SensorId::OrificeDp,
            RegisterBinding::new(1, Input, 6, I16).with_scaling(1.0, 0.0), // Pa
        ),
        (
            SensorId::TSuction,
            RegisterBinding::new(1, Input, 7, I16).with_scaling(0.1, 273.15), // 0.1 °C -> K
        ),
        (
            SensorId::ThrustPosition,
            RegisterBinding::new(1, Input, 8, I32)
                .with_order(ByteOrder::Little, WordOrder::Little)
                .with_scaling(1e-9, 0.0), // nm -> m
        ),
        // Unit 1 holding registers, separate block.
        (
            SensorId::RecycleValvePosition,
            RegisterBinding::new(1, Holding, 200, U16).with_scaling(1e-4, 0.0),
        ),
        // Unit 2: another device behind the same gateway.
        (
            SensorId::ThrottlePosition,
            RegisterBinding::new(2, Input, 0, F32).with_order(ByteOrder::Little, WordOrder::Big),
        ),
    ]
}

fn sensor_values() -> Vec<f64> {
    vec![
        101_325.0,    // p_suction, Pa
        245_678.9,    // p_discharge, Pa
        1_234.567,    // shaft speed, rad/s
        -1_234.0,     // orifice dp, Pa (negative: reverse flow)
        293.65,       // t_suction, K
        -0.000_123_4, // thrust position, m
        0.4321,       // recycle valve, fraction
        0.75,         // throttle, fraction
    ]
}

/// Actuator setpoints: holding registers 100.. on unit 1, contiguous.
fn actuator_bindings() -> Vec<RegisterBinding> {
    use DataType::*;
    use RegisterTable::Holding;
    vec![
        RegisterBinding::new(1, Holding, 100, F32), // drive torque, N·m
        RegisterBinding::new(1, Holding, 102, U16).with_scaling(1e-4, 0.0), // recycle valve
        RegisterBinding::new(1, Holding, 103, I32).with_scaling(1e-9, 0.0), // tip clearance, m
        RegisterBinding::new(1, Holding, 105, U16).with_scaling(1e-4, 0.0), // throttle
    ]
}

fn plant_image() -> SharedImage {
    let mut image = RegisterImage::new();
    for (_, b) in sensor_bindings() {
        image.map_binding(&b);
    }
    for b in actuator_bindings() {
        image.map_binding(&b);
    }
    for ((_, b), v) in sensor_bindings().iter().zip(sensor_values()) {
        let _ = image.set_value(b, v).expect("encode sensor");
    }
    image.into_shared()
}

fn tcp_config(
    addr: SocketAddr,
    timeout_ms: u64,
    backoff_initial_ms: u64,
    backoff_max_ms: u64,
) -> ClientConfig {
    ClientConfig {
        transport: TransportConfig::Tcp { address: addr },
        timeout_ms,
        backoff_initial_ms,
        backoff_max_ms,
    }
}

fn assert_close(b: &RegisterBinding, got: f64, want: f64) {
    let tol = b.resolution(want) / 2.0 + 1e-9 * want.abs().max(1.0);
    assert!(
        (got - want).abs() <= tol,
        "{b:?}: got {got}, want {want} (tolerance {tol})"
    );
}

/// Retry `read` until it succeeds or `limit` passes, sleeping through backoffs.
async fn read_until_ok(
    client: &mut ModbusClient,
    plan: &ReadPlan,
    out: &mut [f64],
    limit: Duration,
) -> Result<(), ModbusError> {
    let deadline = Instant::now() + limit;
    loop {
        match client.read(plan, out).await {
            Ok(()) => return Ok(()),
            Err(e) if Instant::now() >= deadline => return Err(e),
            Err(_) => tokio::time::sleep(client.retry_in().max(Duration::from_millis(1))).await,
        }
    }
}

#[tokio::test]
async fn tcp_round_trip_sensors_and_actuators() {
    let image = plant_image();
    let server = spawn_tcp_server(LOCALHOST.parse().unwrap(), image.clone())
        .await
        .expect("bind");
    let mut client = ModbusClient::new(tcp_config(server.local_addr(), 500, 50, 500)).unwrap();

    let sensors = sensor_bindings();
    let bindings: Vec<_> = sensors.iter().map(|(_, b)| *b).collect();
    let ids: Vec<_> = sensors.iter().map(|(id, _)| *id).collect();
    let plan = ReadPlan::new(&bindings).unwrap();
    // Contiguous registers are grouped: unit 1 input 0..10, unit 1 holding 200, unit 2 input 0..2.
    let reqs: Vec<_> = plan
        .requests()
        .iter()
        .map(|r| (r.unit_id, r.table, r.address, r.count))
        .collect();
    assert_eq!(
        reqs,
        vec![
            (1, RegisterTable::Holding, 200, 1),
            (1, RegisterTable::Input, 0, 10),
            (2, RegisterTable::Input, 0, 2),
        ]
    );

    let mut values = vec![0.0; plan.len()];
    client.read(&plan, &mut values).await.expect("read");
    for ((b, got), want) in bindings.iter().zip(&values).zip(sensor_values()) {
        assert_close(b, *got, want);
    }
    assert_eq!(client.counters().requests, 3);
    assert_eq!(client.state(), ConnectionState::Connected);

    // Same through the snapshot helper.
    let mut snap = SensorSnapshot::default();
    client
        .read_sensors(&plan, &ids, &mut snap)
        .await
        .expect("read sensors");
    assert_close(&bindings[4], snap.get(SensorId::TSuction), 293.65);
    assert_close(
        &bindings[5],
        snap.get(SensorId::ThrustPosition),
        -0.000_123_4,
    );

    // Writes: all four actuators sit in holding 100..106, one request when all are present.
    let act = actuator_bindings();
    let wplan = WritePlan::new(&act).unwrap();
    assert_eq!(wplan.requests().len(), 1);
    let setpoints = [1_500.25, 0.3333, 0.000_050_1, 0.9];
    let report = client.write(&wplan, &setpoints).await.expect("write");
    assert_eq!(
        (
            report.requests,
            report.written,
            report.skipped_nan,
            report.clamped
        ),
        (1, 4, 0, 0)
    );
    {
        let img = lock_image(&image);
        for (b, want) in act.iter().zip(setpoints) {
            assert_close(b, img.value(b).unwrap(), want);
        }
        assert_eq!(img.client_writes(), 1);
    }

    // NaN = not commanded: that register keeps its value and the write splits around it.
    let report = client
        .write(&wplan, &[2_000.0, f64::NAN, -0.000_01, 7.0])
        .await
        .expect("write with NaN");
    assert_eq!(
        (
            report.requests,
            report.written,
            report.skipped_nan,
            report.clamped
        ),
        (2, 3, 1, 1)
    );
    let img = lock_image(&image);
    assert_close(&act[0], img.value(&act[0]).unwrap(), 2_000.0);
    assert_close(&act[1], img.value(&act[1]).unwrap(), 0.3333); // unchanged
    assert_close(&act[2], img.value(&act[2]).unwrap(), -0.000_01);
    assert_close(&act[3], img.value(&act[3]).unwrap(), 6.5535); // clamped at u16::MAX × 1e-4
    assert_eq!(client.counters().clamped_values, 1);
}

/// The issue-324 scenario: the device answers after the client gave up. The late answer must
/// never be taken for the answer to a later request.
#[tokio::test]
async fn late_answer_after_timeout_is_never_mistaken_for_a_new_one() {
    let image = plant_image();
    let server = spawn_tcp_server(LOCALHOST.parse().unwrap(), image.clone())
        .await
        .unwrap();
    let timeout_ms = 100;
    let mut client =
        ModbusClient::new(tcp_config(server.local_addr(), timeout_ms, 20, 200)).unwrap();
    let b = RegisterBinding::new(1, RegisterTable::Input, 0, DataType::F32);
    let plan = ReadPlan::new(&[b]).unwrap();
    let mut v = [0.0];
    client.read(&plan, &mut v).await.unwrap();
    assert_eq!(v[0], 101_325.0);

    // The server now answers 300 ms late, with the value it had when asked (101325).
    lock_image(&image).set_response_mode(ResponseMode::Delay(Duration::from_millis(300)));
    let t0 = Instant::now();
    let err = client.read(&plan, &mut v).await.unwrap_err();
    let took = t0.elapsed();
    assert!(
        matches!(
            err,
            ModbusError::Timeout {
                unit_id: 1,
                timeout_ms: 100
            }
        ),
        "{err:?}"
    );
    assert!(err.is_link_failure());
    assert!(v[0].is_nan(), "a failed read must not leave stale values");
    // not before the timeout (load can only make it later; that it did not wait for the
    // 300-ms answer is the Timeout error and the NaN above, not a wall-clock bound)
    assert!(
        took >= Duration::from_millis(timeout_ms - 5),
        "timeout took {took:?}"
    );
    assert_eq!(client.counters().timeouts, 1);
    assert!(matches!(
        client.state(),
        ConnectionState::Broken {
            consecutive_failures: 1,
            backoff_ms: 20
        }
    ));

    // Device recovers with a new value; the old answer (101325) is still in flight.
    {
        let mut img = lock_image(&image);
        img.set_response_mode(ResponseMode::Normal);
        let _ = img.set_value(&b, 99_000.0).unwrap();
    }
    read_until_ok(&mut client, &plan, &mut v, Duration::from_secs(2))
        .await
        .unwrap();
    assert_eq!(v[0], 99_000.0);
    assert_eq!(client.counters().reconnects, 1);

    // Keep reading until well after the late answer went out: every read must see the new
    // value and no exchange may fail (a desynchronised context would show mismatches).
    let until = Instant::now() + Duration::from_millis(400);
    let mut reads = 0;
    while Instant::now() < until {
        client.read(&plan, &mut v).await.unwrap();
        assert_eq!(v[0], 99_000.0);
        reads += 1;
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(reads > 5);
    let c = client.counters();
    assert_eq!(
        (
            c.timeouts,
            c.protocol_errors,
            c.transport_errors,
            c.reconnects
        ),
        (1, 0, 0, 1)
    );
}

/// A peer that accepts TCP connections and never answers.
#[tokio::test]
async fn silent_peer_times_out_within_deadline() {
    let listener = TcpListener::bind(LOCALHOST).await.unwrap();
    let addr = listener.local_addr().unwrap();
    let hold = tokio::spawn(async move {
        let mut held = Vec::new();
        while let Ok((s, _)) = listener.accept().await {
            held.push(s); // keep it open, never reply
        }
    });
    let mut client = ModbusClient::new(tcp_config(addr, 50, 10, 100)).unwrap();
    let plan = ReadPlan::new(&[RegisterBinding::new(
        1,
        RegisterTable::Holding,
        0,
        DataType::U16,
    )])
    .unwrap();
    let mut v = [0.0];
    for attempt in 0..2 {
        tokio::time::sleep(client.retry_in()).await;
        let t0 = Instant::now();
        let err = client.read(&plan, &mut v).await.unwrap_err();
        let took = t0.elapsed();
        assert!(
            matches!(err, ModbusError::Timeout { .. }),
            "attempt {attempt}: {err:?}"
        );
        // the peer never answers: returning at all is the deadline at work (a busy machine
        // may return late, so no wall-clock upper bound); never before the 50-ms timeout
        assert!(
            took >= Duration::from_millis(45),
            "attempt {attempt}: {took:?}"
        );
    }
    let c = client.counters();
    assert_eq!((c.timeouts, c.connect_attempts, c.reconnects), (2, 2, 1));
    hold.abort();
}

/// Silent mode of the server: the connection stays open but nothing comes back.
#[tokio::test]
async fn server_silent_mode_then_recovery() {
    let image = plant_image();
    let server = spawn_tcp_server(LOCALHOST.parse().unwrap(), image.clone())
        .await
        .unwrap();
    let mut client = ModbusClient::new(tcp_config(server.local_addr(), 60, 10, 100)).unwrap();
    let act = actuator_bindings();
    let wplan = WritePlan::new(&act).unwrap();
    lock_image(&image).set_response_mode(ResponseMode::Silent);
    let err = client
        .write(&wplan, &[1.0, 0.5, 0.0, 0.5])
        .await
        .unwrap_err();
    assert!(matches!(err, ModbusError::Timeout { .. }), "{err:?}");
    // Silent means not processed either.
    assert_eq!(lock_image(&image).client_writes(), 0);
    lock_image(&image).set_response_mode(ResponseMode::Normal);
    tokio::time::sleep(client.retry_in()).await;
    let report = client.write(&wplan, &[1.0, 0.5, 0.0, 0.5]).await.unwrap();
    assert_eq!(report.written, 4);
    assert_close(&act[1], lock_image(&image).value(&act[1]).unwrap(), 0.5);
}

#[tokio::test]
async fn server_disconnect_backoff_grows_then_reconnects() {
    let image = plant_image();
    let server = spawn_tcp_server(LOCALHOST.parse().unwrap(), image.clone())
        .await
        .unwrap();
    let addr = server.local_addr();
    let (initial, max) = (20, 80);
    let mut client = ModbusClient::new(tcp_config(addr, 200, initial, max)).unwrap();
    let b = RegisterBinding::new(1, RegisterTable::Input, 0, DataType::F32);
    let plan = ReadPlan::new(&[b]).unwrap();
    let mut v = [0.0];
    client.read(&plan, &mut v).await.unwrap();

    // Server goes away: listener closed, connections dropped (give the connection tasks a
    // moment to see the cancellation so the next request cannot still be served).
    server.shutdown().await;
    tokio::time::sleep(Duration::from_millis(50)).await;
    let err = client.read(&plan, &mut v).await.unwrap_err();
    assert!(
        matches!(err, ModbusError::Transport(_)),
        "first failure should be a transport error, got {err:?}"
    );

    // Keep polling like a control loop (every 2 ms) and watch the backoff after each failure.
    let mut backoffs = Vec::new();
    let mut backoff_errors = 0;
    let t0 = Instant::now();
    backoffs.push(match client.state() {
        ConnectionState::Broken { backoff_ms, .. } => backoff_ms,
        s => panic!("unexpected state {s:?}"),
    });
    while t0.elapsed() < Duration::from_millis(400) {
        match client.read(&plan, &mut v).await {
            Err(ModbusError::Backoff { retry_in_ms }) => {
                assert!(retry_in_ms <= max);
                backoff_errors += 1;
            }
            Err(ModbusError::Connect(_)) => match client.state() {
                ConnectionState::Broken { backoff_ms, .. } => backoffs.push(backoff_ms),
                s => panic!("unexpected state {s:?}"),
            },
            other => panic!("unexpected {other:?}"),
        }
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    // 20 + 40 + 80 + 80 + ... ms: at least 4 failures in 400 ms, doubling up to the cap.
    assert!(backoffs.len() >= 4, "{backoffs:?}");
    assert_eq!(&backoffs[..4], &[20, 40, 80, 80], "{backoffs:?}");
    assert!(backoffs.iter().all(|&b| b <= max));
    assert!(
        backoff_errors > 20,
        "backoff must gate attempts ({backoff_errors})"
    );
    let c = client.counters();
    assert_eq!(c.connect_failures as usize, backoffs.len() - 1);

    // Server back on the same address, with a changed value.
    let _ = lock_image(&image).set_value(&b, 12_345.0).unwrap();
    let server = spawn_tcp_server(addr, image.clone()).await.expect("rebind");
    read_until_ok(&mut client, &plan, &mut v, Duration::from_secs(2))
        .await
        .unwrap();
    assert_eq!(v[0], 12_345.0);
    assert_eq!(client.state(), ConnectionState::Connected);
    assert_eq!(client.counters().reconnects, 1);

    // After a good exchange the backoff starts over from the initial value.
    server.shutdown().await;
    tokio::time::sleep(Duration::from_millis(50)).await;
    let _ = client.read(&plan, &mut v).await.unwrap_err();
    assert!(matches!(
        client.state(),
        ConnectionState::Broken {
            consecutive_failures: 1,
            backoff_ms: 20
        }
    ));
}

#[tokio::test]
async fn connect_refused_is_a_typed_connect_error() {
    let addr = {
        let l = TcpListener::bind(LOCALHOST).await.unwrap();
        l.local_addr().unwrap()
    }; // listener dropped: nothing listens there now
    let mut client = ModbusClient::new(tcp_config(addr, 100, 1000, 1000)).unwrap();
    let plan = ReadPlan::new(&[RegisterBinding::new(
        1,
        RegisterTable::Holding,
        0,
        DataType::U16,
    )])
    .unwrap();
    let mut v = [0.0];
    let err = client.read(&plan, &mut v).await.unwrap_err();
    assert!(matches!(err, ModbusError::Connect(_)), "{err:?}");
    // Within the 1 s backoff no further attempt is made.
    let err = client.read(&plan, &mut v).await.unwrap_err();
    assert!(
        matches!(err, ModbusError::Backoff { retry_in_ms } if retry_in_ms > 900),
        "{err:?}"
    );
    assert_eq!(client.counters().connect_attempts, 1);
}

#[tokio::test]
async fn exception_for_unmapped_address_keeps_connection() {
    let image = plant_image();
    let server = spawn_tcp_server(LOCALHOST.parse().unwrap(), image.clone())
        .await
        .unwrap();
    let mut client = ModbusClient::new(tcp_config(server.local_addr(), 200, 20, 200)).unwrap();
    let good = RegisterBinding::new(1, RegisterTable::Input, 0, DataType::F32);
    let unmapped = RegisterBinding::new(1, RegisterTable::Input, 500, DataType::U16);
    let no_unit = RegisterBinding::new(9, RegisterTable::Input, 0, DataType::U16);

    // A plan mixing a good and an unmapped request: the good value still arrives.
    let plan = ReadPlan::new(&[good, unmapped]).unwrap();
    let mut v = [0.0; 2];
    let err = client.read(&plan, &mut v).await.unwrap_err();
    match &err {
        &ModbusError::Exception {
            unit_id,
            function,
            address,
            code,
        } => {
            assert_eq!((unit_id, function, address), (1, 0x04, 500));
            assert_eq!(code, ExceptionCode::IllegalDataAddress);
        }
        e => panic!("expected exception, got {e:?}"),
    }
    assert!(err.is_exception() && !err.is_link_failure());
    assert_eq!(v[0], 101_325.0);
    assert!(v[1].is_nan());

    // Writing an unmapped or read-only-in-image address: exception; mapped neighbours unaffected.
    let wplan = WritePlan::new(&[RegisterBinding::new(
        1,
        RegisterTable::Holding,
        300,
        DataType::U16,
    )])
    .unwrap();
    let err = client.write(&wplan, &[1.0]).await.unwrap_err();
    assert!(
        matches!(
            err,
            // one register: write single register (0x06)
            ModbusError::Exception {
                function: 0x06,
                code: ExceptionCode::IllegalDataAddress,
                ..
            }
        ),
        "{err:?}"
    );

    // Unknown unit behind the TCP "gateway".
    let plan9 = ReadPlan::new(&[no_unit]).unwrap();
    let mut v9 = [0.0];
    let err = client.read(&plan9, &mut v9).await.unwrap_err();
    assert!(
        matches!(
            err,
            ModbusError::Exception {
                unit_id: 9,
                code: ExceptionCode::GatewayTargetDevice,
                ..
            }
        ),
        "{err:?}"
    );

    // Same connection throughout.
    let good_plan = ReadPlan::new(&[good]).unwrap();
    let mut g = [0.0];
    client.read(&good_plan, &mut g).await.unwrap();
    assert_eq!(g[0], 101_325.0);
    let c = client.counters();
    assert_eq!(
        (c.connect_attempts, c.reconnects, c.exceptions, c.timeouts),
        (1, 0, 3, 0)
    );
    assert_eq!(client.state(), ConnectionState::Connected);
}

#[tokio::test]
async fn rtu_round_trip_over_pseudo_terminal() {
    use tokio_serial::SerialPort as _;
    // Master end for the server; the client opens the slave end by path like a real port.
    // `slave` stays open for the whole test so the master never sees a hang-up.
    let (master, slave) = tokio_serial::SerialStream::pair().expect("pseudo-terminal pair");
    let path = slave.name().expect("pty slave path");
    let image = plant_image();
    let _server = spawn_rtu_server(master, image.clone());

    let mut rtu = RtuConfig::new(path, 115_200);
    rtu.parity = antisurge::io::modbus::Parity::None;
    rtu.stop_bits = 2;
    // TIOCEXCL is a property of the tty, and the test's own `slave` fd keeps this one alive
    // across the client's reopen: an exclusive reopen would fail with EBUSY for non-root.
    rtu.exclusive = false;
    let mut client = ModbusClient::new(ClientConfig {
        transport: TransportConfig::Rtu(rtu),
        timeout_ms: 300,
        backoff_initial_ms: 10,
        backoff_max_ms: 50,
    })
    .unwrap();

    let sensors = sensor_bindings();
    let bindings: Vec<_> = sensors.iter().map(|(_, b)| *b).collect();
    let plan = ReadPlan::new(&bindings).unwrap();
    let mut values = vec![0.0; plan.len()];
    client.read(&plan, &mut values).await.expect("rtu read");
    for ((b, got), want) in bindings.iter().zip(&values).zip(sensor_values()) {
        assert_close(b, *got, want);
    }

    let act = actuator_bindings();
    let wplan = WritePlan::new(&act).unwrap();
    let setpoints = [-250.5, 0.125, 0.000_002, 0.5];
    client.write(&wplan, &setpoints).await.expect("rtu write");
    {
        let img = lock_image(&image);
        for (b, want) in act.iter().zip(setpoints) {
            assert_close(b, img.value(b).unwrap(), want);
        }
    }

    // Exceptions work over RTU too and keep the port open.
    let unmapped = ReadPlan::new(&[RegisterBinding::new(
        1,
        RegisterTable::Holding,
        999,
        DataType::U16,
    )])
    .unwrap();
    let mut v = [0.0];
    let err = client.read(&unmapped, &mut v).await.unwrap_err();
    assert!(
        matches!(
            err,
            ModbusError::Exception {
                code: ExceptionCode::IllegalDataAddress,
                ..
            }
        ),
        "{err:?}"
    );

    // A unit id nobody answers on the bus: timeout, the port is reopened, later reads work.
    let absent = ReadPlan::new(&[RegisterBinding::new(
        7,
        RegisterTable::Input,
        0,
        DataType::U16,
    )])
    .unwrap();
    let err = client.read(&absent, &mut v).await.unwrap_err();
    assert!(
        matches!(err, ModbusError::Timeout { unit_id: 7, .. }),
        "{err:?}"
    );
    read_until_ok(&mut client, &plan, &mut values, Duration::from_secs(2))
        .await
        .unwrap();
    assert_close(&bindings[0], values[0], 101_325.0);
    let c = client.counters();
    assert_eq!((c.exceptions, c.timeouts, c.reconnects), (1, 1, 1));
    drop(slave);
}

/// A caller that drops a read mid-exchange (its own deadline, `select!`) must not leave the
/// answer in flight on a connection that is then reused.
#[tokio::test]
async fn cancelled_read_does_not_poison_the_connection() {
    let image = plant_image();
    let server = spawn_tcp_server(LOCALHOST.parse().unwrap(), image.clone())
        .await
        .unwrap();
    let mut client = ModbusClient::new(tcp_config(server.local_addr(), 1000, 20, 200)).unwrap();
    let b = RegisterBinding::new(1, RegisterTable::Input, 0, DataType::F32);
    let plan = ReadPlan::new(&[b]).unwrap();
    let mut v = [0.0];
    client.read(&plan, &mut v).await.unwrap();

    lock_image(&image).set_response_mode(ResponseMode::Delay(Duration::from_millis(200)));
    let cancelled =
        tokio::time::timeout(Duration::from_millis(50), client.read(&plan, &mut v)).await;
    assert!(
        cancelled.is_err(),
        "the read should still have been waiting"
    );
    {
        let mut img = lock_image(&image);
        img.set_response_mode(ResponseMode::Normal);
        let _ = img.set_value(&b, 77_000.0).unwrap();
    }
    client
        .read(&plan, &mut v)
        .await
        .expect("read after cancellation");
    assert_eq!(v[0], 77_000.0);
    let c = client.counters();
    assert_eq!(
        (c.cancelled, c.reconnects, c.protocol_errors, c.timeouts),
        (1, 1, 0, 0)
    );
}
