//! A plant node (the in-process plant of `antisurge run`, the body of `antisurge plant`)
//! stepped by hand on a made-up clock, with a made-up controller: the trace tests drive it
//! as fast as it goes instead of in real time.

use antisurge::node::plant::{CommandSource, PlantNode, PlantStatus, SensorSink};
use antisurge::plant::file::PlantDescription;
use antisurge::runtime::handoff::{OutputBoard, Outputs, SensorBoard};
use antisurge::sim::PlantRun;
use antisurge::vocab::signals::{ActuatorCommands, ActuatorId};
use std::sync::Arc;

/// A node for `run` whose commands come from `outputs` (heartbeat timeout 200 ms, not held at
/// the scenario's end).
pub fn node<'a>(
    desc: &'a PlantDescription,
    run: PlantRun<'a>,
    outputs: &Arc<OutputBoard>,
) -> PlantNode<'a> {
    PlantNode::new(
        desc,
        run,
        CommandSource::InProcess(Arc::clone(outputs)),
        SensorSink::InProcess(Arc::new(SensorBoard::default())),
        200.0,
        false,
        Arc::new(PlantStatus::default()),
    )
}

/// Step `node` over its whole scenario, one step per `period_s` of the made-up clock, with
/// fresh commands from `outputs` every step: the recycle valve 12 % open, 60 % from the
/// throttle closure of the shipped scenarios on (5 s), which keeps the recycle plant out of
/// surge. `between` runs after every step (a test's pacing).
pub fn drive(
    node: &mut PlantNode<'_>,
    outputs: &OutputBoard,
    period_s: f64,
    mut between: impl FnMut(),
) {
    let period_ns = (period_s * 1e9).round() as u64;
    let mut k = 0u64;
    loop {
        let now_ns = period_ns * (k + 1);
        let mut commands = ActuatorCommands::default();
        let t = k as f64 * period_s;
        commands.set(ActuatorId::RecycleValve, if t < 5.0 { 0.12 } else { 0.6 });
        outputs.publish(&Outputs {
            commands,
            mode: antisurge::vocab::Mode::Auto,
            law: 0,
            faults: 0,
            cycle: k,
            t_ns: now_ns,
        });
        if !node.step(now_ns) {
            break;
        }
        between();
        k += 1;
    }
}

/// Pacing for [`drive`] with a streamed trace: when the writer thread is more than 300 rows
/// behind (of the 401 its queue holds at the default 5-ms trace period), wait until it is
/// within 100 (the node itself never waits; a test that wants every row must not outrun the
/// writer). `backlog`: the writer's
/// [`antisurge::sim::trace_handoff::TraceWriter::backlog`].
pub fn keep_up(backlog: impl Fn() -> u64) {
    if backlog() > 300 {
        while backlog() > 100 {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
    }
}
