//! A control node wired to fresh hand-off boards, without a bus, a thread or an event log:
//! the tests drive its cycles by hand (reconfiguration, allocation and bumpless tests).

use antisurge::control::core::{ControlCore, Reconfiguration};
use antisurge::control::measurements::OperatorInputs;
use antisurge::node::control::{ControlNode, ControlUpdate, ControlWiring, Health};
use antisurge::plant::{PlantInputs, SimPlant};
use antisurge::runtime::handoff::{OutputBoard, SensorBoard, Wakeup};
use antisurge::runtime::rt_loop::CycleStats;
use antisurge::sim::case::PlantCase;
use std::sync::Arc;

/// The simulated plant at its file's initial operating point (throttle, recycle valve, feed)
/// and the inputs that hold it there.
pub fn plant_at_initial_point(desc: &PlantCase) -> (SimPlant, PlantInputs) {
    let init = desc.file.initial;
    let inputs = PlantInputs {
        throttle_process: init.throttle,
        recycle_manual: init.recycle_valve,
        feed: init.feed,
        ..PlantInputs::default()
    };
    (SimPlant::new(desc, &inputs).expect("plant"), inputs)
}

/// The node and the test's ends of its wiring.
pub struct BareNode {
    pub node: ControlNode,
    /// Where the test publishes sensor values.
    pub sensors: Arc<SensorBoard>,
    /// Where the node's commands appear.
    pub outputs: Arc<OutputBoard>,
    pub health: Arc<Health>,
    pub stats: Arc<CycleStats>,
    /// The field faults the node reads each cycle (as the daemon's link tasks raise them).
    pub field: Arc<antisurge::io::link::FieldFaults>,
    /// Reconfigurations sent to the node (applied at its next cycle boundary).
    pub updates: rtrb::Producer<ControlUpdate>,
    /// What the node retired, to be dropped off its thread.
    pub retired: rtrb::Consumer<Reconfiguration>,
}

/// A node around `core` with a cycle period of `period_ns`.
pub fn bare_node(core: ControlCore, op: OperatorInputs, period_ns: u64) -> BareNode {
    bare_node_with_events(core, op, period_ns, None)
}

/// The same, its events going to `events` (an event log's real-time sender).
pub fn bare_node_with_events(
    core: ControlCore,
    op: OperatorInputs,
    period_ns: u64,
    events: Option<antisurge::events::RtSender>,
) -> BareNode {
    let sensors = Arc::new(SensorBoard::default());
    let outputs = Arc::new(OutputBoard::default());
    let health = Arc::new(Health::default());
    let stats = Arc::new(CycleStats::default());
    let (updates, updates_rx) = rtrb::RingBuffer::<ControlUpdate>::new(4);
    let (retired_tx, retired) = rtrb::RingBuffer::new(8);
    let field = Arc::new(antisurge::io::link::FieldFaults::default());
    let node = ControlNode::new(
        core,
        op,
        ControlWiring {
            sensors: Arc::clone(&sensors),
            outputs: Arc::clone(&outputs),
            wake: Arc::new(Wakeup::new().expect("eventfd")),
            updates: updates_rx,
            retired: retired_tx,
            events,
            health: Arc::clone(&health),
            stats: Arc::clone(&stats),
            field: Arc::clone(&field),
        },
        period_ns,
    );
    BareNode {
        node,
        sensors,
        outputs,
        health,
        stats,
        field,
        updates,
        retired,
    }
}
