//! Memory of a long run of a plant stepped in real time with its trace streamed to
//! `trace.csv` (`antisurge run --out`, `antisurge plant`; issue 25): an hour of plant time at
//! the default rates (1 kHz steps, a trace row every 5 ms: 720 001 rows, 181 MiB if kept, as
//! the daemon's in-process plant kept them until exit) goes through the writer thread with a
//! peak of heap bytes in use far below the trace, no larger than a 10-minute run's, no row
//! dropped, and no allocation in the second half of a run (plant thread and writer alike;
//! counted on the 10-minute run, which ends long before the test harness's own notice of a
//! test running for over 60 s, which allocates).
//! The node is stepped on a made-up clock, as fast as it goes (paced to the writer).
//! One test in this binary: the heap figures are the whole process's.

use crate::common;

use antisurge::node::plant::{finish_trace, start_trace};
use antisurge::runtime::handoff::OutputBoard;
use antisurge::sim::trace::TraceRow;
use antisurge::sim::PlantRun;
use common::counting_alloc;
use common::plant_node::{drive, keep_up, node};
use std::sync::Arc;

const MIB: usize = 1 << 20;

fn scenario(duration_s: f64) -> antisurge::scenario::Scenario {
    common::long_hold_scenario(duration_s)
}

/// What [`streamed_run`] saw.
struct Seen {
    /// Peak heap bytes in use above those at the start.
    peak: usize,
    /// Trace rows written.
    rows: u64,
    /// Trace rows dropped.
    dropped: u64,
    /// Allocations in the second half of the run.
    second_half_allocs: u64,
    /// Size of trace.csv.
    file_bytes: u64,
}

/// Step a plant node over a scenario of `duration_s`, its trace streamed into a fresh
/// directory, and finish it as the daemon does.
fn streamed_run(duration_s: f64) -> Seen {
    // (the process-wide figures: the other memory test of the binary waits)
    let _alone = counting_alloc::process_exclusive();
    let desc = common::plant("kvangardsnes2009_recycle");
    let sc = scenario(duration_s);
    let dir = tempfile::tempdir().expect("tmp");
    let dt = sc.file.control_period_s;
    let half_steps = (duration_s / dt / 2.0) as u64;
    let base = counting_alloc::in_use();
    counting_alloc::reset_peak();
    let outputs = Arc::new(OutputBoard::default());
    let (handoff, writer) = start_trace(&desc, &sc, dir.path()).expect("trace");
    let run = PlantRun::handing_trace_to(&desc, &sc, handoff).expect("run");
    let mut node = node(&desc, run, &outputs);
    let mut steps = 0u64;
    let mut at_half = 0u64;
    drive(&mut node, &outputs, dt, || {
        steps += 1;
        if steps == half_steps {
            at_half = counting_alloc::process_allocations();
        }
        keep_up(|| writer.backlog());
    });
    let second_half_allocs = counting_alloc::process_allocations() - at_half;
    let path = writer.path().to_path_buf();
    let result = finish_trace(&mut node, writer, "recycle-pi").expect("finish");
    let seen = Seen {
        peak: counting_alloc::peak().saturating_sub(base),
        rows: std::fs::read_to_string(&path)
            .expect("trace")
            .lines()
            .count() as u64
            - 1,
        dropped: result.summary.trace_rows_dropped.expect("dropped count"),
        second_half_allocs,
        file_bytes: std::fs::metadata(&path).expect("trace").len(),
    };
    assert!(result.trace.is_empty());
    assert!(result.summary.stable, "{}", result.summary.verdict);
    seen
}

#[test]
fn an_hour_of_real_time_plant_streams_in_bounded_heap() {
    let row = std::mem::size_of::<TraceRow>();
    let short = streamed_run(600.0);
    let hour = streamed_run(3600.0);
    assert_eq!((short.rows, hour.rows), (120_000, 720_000));
    assert_eq!((short.dropped, hour.dropped), (0, 0));
    let kept = hour.rows as usize * row;
    // what is held: the writer's queue (2 s of rows, 106 kB), the file's and the settle log's
    // buffers (64 KiB each), the tail (3 s of (t, flow)), the plant and the node
    let bound = MIB;
    eprintln!(
        "peak heap above start: 10 min {:.3} MiB, 1 h {:.3} MiB (bound {:.1} MiB; the kept \
         trace would be {:.0} MiB; trace.csv {:.0} MiB); allocations in the second half: \
         10 min {}, 1 h {} (the test harness's notice at 60 s among them)",
        short.peak as f64 / MIB as f64,
        hour.peak as f64 / MIB as f64,
        bound as f64 / MIB as f64,
        kept as f64 / MIB as f64,
        hour.file_bytes as f64 / MIB as f64,
        short.second_half_allocs,
        hour.second_half_allocs,
    );
    assert!(hour.peak < bound, "peak {} B ≥ bound {bound} B", hour.peak);
    assert!(kept > 50 * bound, "the test would not tell a kept trace");
    assert!(
        hour.peak <= short.peak + MIB / 16,
        "the peak grows with the run: 10 min {} B, 1 h {} B",
        short.peak,
        hour.peak
    );
    assert_eq!(
        short.second_half_allocs, 0,
        "the plant step or the trace writer allocates"
    );
}
