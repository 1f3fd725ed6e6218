//! Issue 26: the Sparkplug B edge node never holds what the control cycle needs.
//!
//! The control node's cycle runs (snapshot published every cycle, events to the event log,
//! operator commands through the ring) while a real edge node (`antisurge::sparkplug::spawn`)
//! is connected to a broker that accepts it and then never acknowledges anything: the node's
//! QoS-1 births and events stay in flight, its publish path is stuck. Meanwhile the test holds
//! the locks the node's publish and command paths take (the operator-command producer, the
//! served-snapshot queue) for the whole run, as a node stuck inside one would. Asserted:
//! - every cycle completes (a cycle that needed one of those locks would never return: the
//!   run is joined with a generous liveness bound, which detects a deadlock, not a speed);
//! - zero allocations on the control thread in every counted cycle (counting allocator);
//! - the node was live and reading the cycle's snapshot (its NBIRTH and NDATA reached the
//!   broker, NDATA after the cycle started);
//! - the events the cycle raised meanwhile reached the event log (the node follows the file,
//!   it is not on the cycle's event path).

use crate::common;

use antisurge::control::core::{ControlCore, CoreSettings};
use antisurge::control::LawId;
use antisurge::daemon::config::SparkplugSection;
use antisurge::events::{EventLog, EventLogConfig};
use antisurge::live::server::LiveContext;
use antisurge::live::snapshot::LiveBoard;
use antisurge::node::control::ControlNode;
use antisurge::runtime::handoff::monotonic_ns;
use antisurge::runtime::rt_loop::Tick;
use antisurge::sparkplug::catalogue::Ranges;
use antisurge::sparkplug::EdgeInputs;
use antisurge::vocab::signals::SensorId;
use common::counting_alloc::allocations;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// What the stuck broker received.
#[derive(Default)]
struct Received {
    bytes: Mutex<Vec<u8>>,
    /// Bytes received before the cycle started.
    at_cycle_start: AtomicUsize,
}

impl Received {
    fn count(&self, needle: &[u8], from: usize) -> usize {
        let b = self.bytes.lock().unwrap();
        b.get(from..)
            .unwrap_or(&[])
            .windows(needle.len())
            .filter(|w| *w == needle)
            .count()
    }
}

/// A broker that answers CONNECT with CONNACK and then reads everything and acknowledges
/// nothing (no PUBACK, no SUBACK, no PINGRESP).
async fn stuck_broker(listener: tokio::net::TcpListener, rx: Arc<Received>) {
    loop {
        let Ok((mut s, _)) = listener.accept().await else {
            return;
        };
        let rx = Arc::clone(&rx);
        tokio::spawn(async move {
            let mut buf = [0u8; 4096];
            let mut acked = false;
            loop {
                match s.read(&mut buf).await {
                    Ok(0) | Err(_) => return,
                    Ok(n) => {
                        rx.bytes.lock().unwrap().extend_from_slice(&buf[..n]);
                        if !acked && buf[0] >> 4 == 1 {
                            // CONNACK: session present 0, return code 0 (accepted)
                            let _ = s.write_all(&[0x20, 0x02, 0x00, 0x00]).await;
                            acked = true;
                        }
                    }
                }
            }
        });
    }
}

#[test]
fn the_cycle_never_waits_on_a_node_whose_broker_acknowledges_nothing() {
    let dir = tempfile::tempdir().expect("tmp");
    let desc = common::plant("kvangardsnes2009_recycle");
    let (mut plant, inputs) = common::node::plant_at_initial_point(&desc);
    let model = antisurge::sim::control_model(&desc);
    let settings = CoreSettings::defaults_for(&model);
    let cfg = model.controller.clone();
    let core = ControlCore::new(
        model,
        cfg,
        settings,
        LawId::RecyclePi,
        plant.truth().load_torque_nm,
    )
    .expect("core");

    let events_path = dir.path().join("events.jsonl");
    let log = EventLog::start(EventLogConfig::with_path(&events_path)).expect("event log");
    let op = antisurge::control::measurements::OperatorInputs {
        speed_setpoint_rad_s: desc.file.drive.nominal_speed_rad_s,
        throttle_demand: f64::NAN,
        flow_setpoint_kg_s: f64::NAN,
        recycle_manual: f64::NAN,
    };
    let common::node::BareNode {
        mut node,
        sensors,
        outputs,
        stats,
        updates: _updates,
        retired: _retired,
        health: _health,
        field: _field,
    } = common::node::bare_node_with_events(
        core,
        op,
        1_000_000,
        Some(log.rt_sender().expect("rt sender")),
    );
    let live = Arc::new(LiveBoard::default());
    let (cmd_tx, cmd_rx) = rtrb::RingBuffer::new(16);
    node.attach_live(Arc::clone(&live), cmd_rx);
    let ctx = LiveContext {
        live: Arc::clone(&live),
        commands: Arc::new(Mutex::new(cmd_tx)),
        stats: Arc::clone(&stats),
        links: Arc::new(|| serde_json::json!({})),
        inputs: Arc::new([]),
        events: log.sender(),
        token_file: dir.path().join("no-token"),
        started: Instant::now(),
        served: Arc::default(),
    };
    let (commands, served) = (Arc::clone(&ctx.commands), Arc::clone(&ctx.served));

    // the node, on its own runtime, against the stuck broker
    let received = Arc::new(Received::default());
    let stop = Arc::new(AtomicBool::new(false));
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<()>();
    let node_thread = {
        let (received, stop) = (Arc::clone(&received), Arc::clone(&stop));
        let state_dir = dir.path().join("state");
        let events_path = events_path.clone();
        std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(1)
                .enable_all()
                .build()
                .expect("runtime");
            rt.block_on(async move {
                let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
                    .await
                    .expect("bind port 0");
                let port = listener.local_addr().expect("addr").port();
                tokio::spawn(stuck_broker(listener, Arc::clone(&received)));
                let cfg = SparkplugSection {
                    enabled: true,
                    broker: format!("127.0.0.1:{port}"),
                    publish_interval_ms: 10,
                    ..SparkplugSection::default()
                };
                let (shutdown_tx, shutdown_rx) = tokio::sync::watch::channel(false);
                let mut tasks = tokio::task::JoinSet::new();
                antisurge::sparkplug::spawn(
                    &cfg,
                    EdgeInputs {
                        ctx,
                        ranges: Ranges {
                            flow: (0.0, 50.0),
                            ratio: (1.0, 4.0),
                            speed: (0.0, 2000.0),
                        },
                        state_dir,
                        events_path,
                    },
                    shutdown_rx,
                    &mut tasks,
                )
                .expect("node starts");
                let _ = ready_tx.send(());
                while !stop.load(Ordering::Relaxed) {
                    tokio::time::sleep(Duration::from_millis(10)).await;
                }
                let _ = shutdown_tx.send(true);
                // a node stuck on its broker need not finish: the runtime is dropped
                tasks.abort_all();
            });
        })
    };
    ready_rx
        .recv_timeout(Duration::from_secs(30))
        .expect("the node started");

    // the control thread: first cycles until the node has published its births from them
    let (done_tx, done_rx) = std::sync::mpsc::channel::<(u64, u64)>();
    let cycle_thread = {
        let received = Arc::clone(&received);
        let (commands, served) = (Arc::clone(&commands), Arc::clone(&served));
        std::thread::spawn(move || {
            let mut plant_inputs = inputs;
            let t0 = monotonic_ns();
            let mut k = 0u64;
            let mut run = |node: &mut ControlNode, k: &mut u64, count: bool| -> u64 {
                let now = t0 + *k * 1_000_000;
                for id in SensorId::ALL {
                    sensors.publish(id, plant.sensors().get(id), now);
                }
                let tick = Tick {
                    cycle: *k,
                    deadline_ns: now,
                    wake_ns: now,
                };
                let before = allocations();
                node.cycle(tick);
                let n = allocations() - before;
                *k += 1;
                plant_inputs.commands = outputs.latest().expect("outputs").commands;
                plant.step(&plant_inputs, 1e-3);
                if count {
                    n
                } else {
                    0
                }
            };
            // warm-up until the node has connected and published its NBIRTH (it reads the
            // first snapshot for it); bounded so that a node that never publishes fails below
            let warm = Instant::now();
            while received.count(b"NBIRTH", 0) == 0 && warm.elapsed() < Duration::from_secs(20) {
                run(&mut node, &mut k, false);
                std::thread::sleep(Duration::from_millis(1));
            }
            received
                .at_cycle_start
                .store(received.bytes.lock().unwrap().len(), Ordering::Relaxed);
            // what a node stuck inside its publish or command path would hold
            let _commands_held = commands.lock().unwrap();
            let _served_held = served.lock().unwrap();
            let mut allocs = 0u64;
            let mut counted = 0u64;
            for j in 0..3000u64 {
                allocs += run(&mut node, &mut k, true);
                counted += 1;
                if j % 100 == 0 {
                    // paced a little, so that the node polls the snapshot between cycles
                    std::thread::sleep(Duration::from_millis(1));
                }
            }
            let _ = done_tx.send((counted, allocs));
            node
        })
    };
    // liveness: a cycle blocked on the node never sends; this bound detects a deadlock only
    let (counted, allocs) = done_rx
        .recv_timeout(Duration::from_secs(300))
        .expect("the control cycles completed while the node was stuck");
    let node = cycle_thread.join().expect("cycle thread");
    assert_eq!(counted, 3000);
    assert_eq!(
        allocs, 0,
        "allocations on the control thread over 3000 cycles"
    );
    let s = live.latest().expect("snapshot");
    assert!(s.cycle >= 3000, "{}", s.cycle);

    // the node was live: births reached the broker, and data after the cycle started
    assert!(
        received.count(b"NBIRTH", 0) >= 1,
        "no NBIRTH reached the broker"
    );
    let from = received.at_cycle_start.load(Ordering::Relaxed);
    let deadline = Instant::now() + Duration::from_secs(20);
    while received.count(b"NDATA", from) == 0 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(
        received.count(b"NDATA", from) >= 1,
        "no NDATA while the cycle ran: the node was not reading the snapshot"
    );
    stop.store(true, Ordering::Relaxed);
    node_thread.join().expect("node thread");
    drop(node);
    drop(log);
    // the cycle's own events went to the log (its first mode change, init → auto)
    let text = std::fs::read_to_string(&events_path).expect("event log");
    assert!(
        text.lines()
            .any(|l| l.contains("\"event\":\"mode_changed\"")),
        "{text}"
    );
}
