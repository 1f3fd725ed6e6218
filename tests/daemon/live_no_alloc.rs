//! Issue 11: the control node's cycle, with the live snapshot published every cycle and the
//! status report, the metrics exposition and the HMI's status read concurrently at a high
//! rate from another thread, allocates nothing (counting allocator, per thread) — the readers
//! only read the lock-free board.

use crate::common;

use antisurge::control::core::{ControlCore, CoreSettings};
use antisurge::control::LawId;
use antisurge::live::snapshot::LiveBoard;
use antisurge::node::control::{ControlNode, ControlWiring, Health};
use antisurge::runtime::handoff::{monotonic_ns, OutputBoard, SensorBoard, Wakeup};
use antisurge::runtime::rt_loop::{CycleStats, Tick};
use antisurge::vocab::signals::SensorId;
use common::counting_alloc::allocations;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

#[test]
fn control_node_cycle_with_live_snapshot_allocates_nothing_while_polled() {
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
    let sensors = Arc::new(SensorBoard::default());
    let outputs = Arc::new(OutputBoard::default());
    let stats = Arc::new(CycleStats::default());
    let (_tx, updates) = rtrb::RingBuffer::new(4);
    let (retired, _retired_rx) = rtrb::RingBuffer::new(4);
    let op = antisurge::control::measurements::OperatorInputs {
        speed_setpoint_rad_s: desc.file.drive.nominal_speed_rad_s,
        throttle_demand: f64::NAN,
        flow_setpoint_kg_s: f64::NAN,
        recycle_manual: f64::NAN,
    };
    let mut node = ControlNode::new(
        core,
        op,
        ControlWiring {
            sensors: Arc::clone(&sensors),
            outputs: Arc::clone(&outputs),
            wake: Arc::new(Wakeup::new().expect("eventfd")),
            updates,
            retired,
            events: None,
            health: Arc::new(Health::default()),
            stats: Arc::clone(&stats),
            field: Arc::new(antisurge::io::link::FieldFaults::default()),
        },
        1_000_000,
    );
    let live = Arc::new(LiveBoard::default());
    let (mut cmd_tx, cmd_rx) = rtrb::RingBuffer::new(16);
    node.attach_live(Arc::clone(&live), cmd_rx);

    // readers: status report, metrics exposition and the status line, as fast as they go
    let stop = Arc::new(AtomicBool::new(false));
    let reads_so_far = Arc::new(AtomicU64::new(0));
    let reader = {
        let (live, stats, stop) = (Arc::clone(&live), Arc::clone(&stats), Arc::clone(&stop));
        let reads_so_far = Arc::clone(&reads_so_far);
        std::thread::spawn(move || {
            let mut reads = 0u64;
            while !stop.load(Ordering::Relaxed) {
                if let Some(s) = live.latest() {
                    let r = antisurge::live::report::StatusReport::new(
                        &s,
                        0.0,
                        serde_json::Value::Null,
                        serde_json::Value::Null,
                    );
                    std::hint::black_box(antisurge::live::report::human(&r));
                    std::hint::black_box(antisurge::live::metrics::render(&live, &stats));
                    reads += 1;
                    reads_so_far.store(reads, Ordering::Relaxed);
                }
            }
            reads
        })
    };

    let mut plant_inputs = inputs;
    let t0 = monotonic_ns();
    let mut counted = 0;
    for k in 0..3000u64 {
        let now = t0 + k * 1_000_000;
        for id in SensorId::ALL {
            sensors.publish(id, plant.sensors().get(id), now);
        }
        if k == 10 {
            // on a loaded machine the reader thread may not have been scheduled yet: the
            // counted cycles start once it reads concurrently
            let t = std::time::Instant::now();
            while reads_so_far.load(Ordering::Relaxed) == 0 {
                assert!(
                    t.elapsed() < std::time::Duration::from_secs(10),
                    "the reader never ran"
                );
                std::thread::yield_now();
            }
        }
        if k == 1500 {
            // an operator action through the ring mid-run (manual, then back to auto)
            let _ = cmd_tx.push(antisurge::live::commands::OperatorCommand::SetAuto(false));
        }
        if k == 2000 {
            let _ = cmd_tx.push(antisurge::live::commands::OperatorCommand::SetAuto(true));
        }
        let tick = Tick {
            cycle: k,
            deadline_ns: now,
            wake_ns: now,
        };
        let before = allocations();
        node.cycle(tick);
        let after = allocations();
        if k >= 10 {
            assert_eq!(after, before, "allocation in cycle {k}");
            counted += 1;
        }
        plant_inputs.commands = outputs.latest().expect("outputs").commands;
        plant_inputs.throttle_process = (inputs.throttle_process - 1e-4 * k as f64).max(0.45);
        plant.step(&plant_inputs, 1e-3);
    }
    stop.store(true, Ordering::Relaxed);
    let reads = reader.join().expect("reader");
    assert!(reads > 10, "the readers ran only {reads} times");
    assert_eq!(counted, 2990);
    let s = live.latest().expect("snapshot");
    assert_eq!(s.cycle, 2999);
    assert!(s.deviation_pct.is_finite(), "{s:?}");
}
