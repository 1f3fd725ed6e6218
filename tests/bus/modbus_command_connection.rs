//! `bus.modbus.command_connection`: with `"own"` the link's commands travel on a second TCP
//! connection and never wait behind a read; with `"shared"` (the default) every request goes
//! on one connection, one after the other. Checked against a device written here that answers
//! reads slowly (150 ms) and writes at once, serving each connection's requests in order (as
//! gateways do): the order of arrivals and answers it records, never a wall-clock duration.

use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use antisurge::io::modbus::{
    run_controller, ClientConfig, CommandConnection, DataType, LinkMonitor, ModbusLinkConfig,
    Pacing, RegisterBinding, RegisterTable, TransportConfig,
};
use antisurge::io::signal_map::{Binding, SignalMap};
use antisurge::runtime::handoff::{monotonic_ns, OutputBoard, Outputs, SensorBoard};
use antisurge::vocab::signals::{ActuatorCommands, ActuatorId, SensorId};
use tokio_modbus::{ExceptionCode, Request, Response, SlaveRequest};

/// What the device saw, in order: (connection, what).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Seen {
    ReadArrived(usize),
    ReadAnswered(usize),
    WriteArrived(usize),
}

type Log = Arc<Mutex<Vec<Seen>>>;

#[derive(Clone)]
struct Device {
    conn: usize,
    log: Log,
}

/// The read's answer time: long against the write's, so that on one connection a write must
/// wait for it and on two it need not.
const READ_ANSWER: Duration = Duration::from_millis(150);

type Answer = Pin<Box<dyn Future<Output = Result<Option<Response>, ExceptionCode>> + Send>>;

impl tokio_modbus::server::Service for Device {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = Answer;

    fn call(&self, req: Self::Request) -> Self::Future {
        let (conn, log) = (self.conn, Arc::clone(&self.log));
        match req.request {
            Request::ReadInputRegisters(_, n) => {
                log.lock().unwrap().push(Seen::ReadArrived(conn));
                Box::pin(async move {
                    tokio::time::sleep(READ_ANSWER).await;
                    log.lock().unwrap().push(Seen::ReadAnswered(conn));
                    Ok(Some(Response::ReadInputRegisters(vec![
                        0x4000;
                        usize::from(n)
                    ])))
                })
            }
            Request::WriteSingleRegister(a, w) => {
                log.lock().unwrap().push(Seen::WriteArrived(conn));
                Box::pin(std::future::ready(Ok(Some(Response::WriteSingleRegister(
                    a, w,
                )))))
            }
            _ => Box::pin(std::future::ready(Err(ExceptionCode::IllegalFunction))),
        }
    }
}

async fn serve(log: Log) -> SocketAddr {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let addr = listener.local_addr().expect("addr");
    let next = Arc::new(AtomicUsize::new(0));
    tokio::spawn(async move {
        let server = tokio_modbus::server::tcp::Server::new(listener);
        let on_connected = move |stream: tokio::net::TcpStream, _peer: SocketAddr| {
            let device = Device {
                conn: next.fetch_add(1, Ordering::Relaxed),
                log: Arc::clone(&log),
            };
            async move { Ok(Some((device, stream))) }
        };
        let _ = server.serve(&on_connected, |_e| {}).await;
    });
    addr
}

fn map() -> SignalMap {
    let mut m = SignalMap::default();
    m.sensors.insert(
        SensorId::PSuction,
        Binding::Modbus(RegisterBinding::new(
            1,
            RegisterTable::Input,
            0,
            DataType::U16,
        )),
    );
    m.actuators.insert(
        ActuatorId::RecycleValve,
        Binding::Modbus(
            RegisterBinding::new(1, RegisterTable::Holding, 100, DataType::U16)
                .with_scaling(1e-4, 0.0),
        ),
    );
    assert!(m.check().is_empty());
    m
}

/// Run the link for `reads` read answers against the device, the control thread's outputs
/// published every 5 ms (a new set each time); return what the device saw.
async fn run(connection: CommandConnection, reads: usize) -> Vec<Seen> {
    let log: Log = Arc::default();
    let addr = serve(Arc::clone(&log)).await;
    let mut cfg = ModbusLinkConfig::new(ClientConfig {
        transport: TransportConfig::Tcp { address: addr },
        timeout_ms: 1000,
        backoff_initial_ms: 20,
        backoff_max_ms: 80,
    });
    cfg.poll_rate_hz = 50.0;
    cfg.command_connection = connection;
    let sensors: Arc<SensorBoard> = Arc::default();
    let outputs: Arc<OutputBoard> = Arc::default();
    let monitor = Arc::new(LinkMonitor::new());
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let link = {
        let (sensors, outputs, monitor) = (sensors, Arc::clone(&outputs), monitor);
        tokio::spawn(async move {
            let stop = async move {
                let _ = stop_rx.await;
            };
            run_controller(
                &cfg,
                &map(),
                sensors,
                outputs,
                Pacing::Interval,
                monitor,
                stop,
            )
            .await
        })
    };
    let mut cycle = 0u64;
    loop {
        let answered = log
            .lock()
            .unwrap()
            .iter()
            .filter(|s| matches!(s, Seen::ReadAnswered(_)))
            .count();
        if answered >= reads {
            break;
        }
        cycle += 1;
        let mut c = ActuatorCommands::default();
        c.set(ActuatorId::RecycleValve, 0.2 + 1e-3 * (cycle % 100) as f64);
        outputs.publish(&Outputs {
            commands: c,
            mode: antisurge::vocab::Mode::Auto,
            law: 1,
            faults: 0,
            cycle,
            t_ns: monotonic_ns(),
        });
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let _ = stop_tx.send(());
    link.await.expect("join").expect("link ran");
    let seen = log.lock().unwrap().clone();
    seen
}

/// Writes that arrived while a read was in flight (arrived, not yet answered), and the
/// connections reads and writes came on.
fn overlap(seen: &[Seen]) -> (usize, Vec<usize>, Vec<usize>) {
    let mut in_flight = 0i32;
    let mut during = 0;
    let (mut read_conns, mut write_conns) = (Vec::new(), Vec::new());
    for s in seen {
        match *s {
            Seen::ReadArrived(c) => {
                in_flight += 1;
                read_conns.push(c);
            }
            Seen::ReadAnswered(_) => in_flight -= 1,
            Seen::WriteArrived(c) => {
                write_conns.push(c);
                if in_flight > 0 {
                    during += 1;
                }
            }
        }
    }
    read_conns.dedup();
    write_conns.dedup();
    (during, read_conns, write_conns)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn own_command_connection_writes_while_a_read_is_in_flight() {
    let seen = run(CommandConnection::Own, 4).await;
    let (during, reads, writes) = overlap(&seen);
    eprintln!("own: {} events, {during} writes during a read; read connections {reads:?}, write connections {writes:?}", seen.len());
    assert_eq!(reads.len(), 1, "reads on one connection: {seen:?}");
    assert_eq!(writes.len(), 1, "writes on one connection: {seen:?}");
    assert_ne!(
        reads[0], writes[0],
        "commands on their own connection: {seen:?}"
    );
    // a read takes 150 ms and new outputs come every 5 ms: the command side writes them (once
    // per link period, 20 ms, when no read came since) while the read is in flight
    assert!(during >= 4, "writes waited behind the reads: {seen:?}");
    // ... and not at the rate outputs are published (every 5 ms): at most one per read plus
    // one per link period (4 reads of 150 ms: 30 periods, with room for the first connects)
    let writes_n = seen
        .iter()
        .filter(|s| matches!(s, Seen::WriteArrived(_)))
        .count();
    assert!(writes_n <= 4 + 36, "{writes_n} writes: {seen:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shared_connection_serialises_commands_behind_reads() {
    let seen = run(CommandConnection::Shared, 4).await;
    let (during, reads, writes) = overlap(&seen);
    eprintln!("shared: {} events, {during} writes during a read; read connections {reads:?}, write connections {writes:?}", seen.len());
    assert_eq!(reads, writes, "one connection for everything: {seen:?}");
    assert_eq!(during, 0, "{seen:?}");
    assert!(
        seen.iter().any(|s| matches!(s, Seen::WriteArrived(_))),
        "{seen:?}"
    );
}
