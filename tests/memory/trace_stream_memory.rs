//! Memory of a long `antisurge sim --out` run is bounded by streaming (issue 25): an hour of
//! simulated time at the default rates (1 kHz control, a trace row every 5 ms: 720 001 rows,
//! 196 MB if kept) streams to `trace.csv` with a peak of heap bytes in use far below the
//! trace, no larger than a 10-minute run's (but for the map's few more rows), and no
//! allocation in the second half of the run.
//! One test in this binary: the heap figures are the whole process's.

use crate::common;

use antisurge::control::LawId;
use antisurge::plot::MAX_TRAJ_POINTS;
use antisurge::sim::stream::ENVELOPE_BUCKETS;
use antisurge::sim::trace::TraceRow;
use antisurge::sim::{self, SimOptions};
use common::counting_alloc;

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
    /// Rows kept for the map.
    map_rows: usize,
    /// Allocations in the second half of the control loop.
    second_half_allocs: u64,
    /// Size of trace.csv.
    file_bytes: u64,
}

/// Stream a run of `duration_s` into a fresh directory and build the rows the pictures are
/// drawn from (the pictures themselves are the binary's).
fn streamed_run(duration_s: f64) -> Seen {
    // (the process-wide figures: the other memory test of the binary waits)
    let _alone = counting_alloc::process_exclusive();
    let desc = common::plant("kvangardsnes2009_recycle");
    let sc = scenario(duration_s);
    let dir = tempfile::tempdir().expect("tmp");
    let model = sim::control_model(&desc);
    let mut half: Option<u64> = None;
    let mut second_half_allocs = u64::MAX;
    let base = counting_alloc::in_use();
    counting_alloc::reset_peak();
    let (summary, trace) = sim::run_streamed(
        &desc,
        model,
        &sc,
        SimOptions {
            law: LawId::RecyclePi,
            ..SimOptions::default()
        },
        dir.path(),
        &mut |frac| {
            // progress(1.0) comes right after the loop's last step
            if frac >= 0.5 && half.is_none() {
                half = Some(counting_alloc::process_allocations());
            }
            if frac == 1.0 {
                second_half_allocs = counting_alloc::process_allocations() - half.unwrap_or(0);
            }
        },
        &mut |_, _| {},
    )
    .expect("run");
    let map = trace.pictures.map_rows();
    let series = trace.pictures.series_rows();
    assert!(map.len() <= MAX_TRAJ_POINTS + 1 && series.len() <= 2 * ENVELOPE_BUCKETS + 2);
    let seen = Seen {
        peak: counting_alloc::peak().saturating_sub(base),
        rows: trace.rows,
        map_rows: map.len(),
        second_half_allocs,
        file_bytes: std::fs::metadata(&trace.path).expect("trace").len(),
    };
    assert!(summary.stable, "{}", summary.verdict);
    seen
}

#[test]
fn an_hour_streams_in_bounded_heap() {
    let row = std::mem::size_of::<TraceRow>();
    let short = streamed_run(600.0);
    let hour = streamed_run(3600.0);
    assert_eq!((short.rows, hour.rows), (120_001, 720_001));
    let kept = hour.rows as usize * row;
    // what is kept: the map's rows, the envelope (2 rows a bucket) and its rows for the time
    // series (9.4 MiB); the file's and the settle log's buffers, the control core and the
    // plant (2 MiB measured)
    let bound = (MAX_TRAJ_POINTS + 4 * ENVELOPE_BUCKETS) * row + 4 * MIB;
    eprintln!(
        "peak heap above start: 10 min {:.2} MiB, 1 h {:.2} MiB (bound {:.1} MiB; the kept \
         trace would be {:.0} MiB; trace.csv {:.0} MiB); allocations in the second half of \
         the hour: {}",
        short.peak as f64 / MIB as f64,
        hour.peak as f64 / MIB as f64,
        bound as f64 / MIB as f64,
        kept as f64 / MIB as f64,
        hour.file_bytes as f64 / MIB as f64,
        hour.second_half_allocs,
    );
    assert!(hour.peak < bound, "peak {} B ≥ bound {bound} B", hour.peak);
    assert!(kept > 10 * bound, "the test would not tell a kept trace");
    // the map keeps a few more rows of the longer run (its stride is ⌈rows / 20 000⌉)
    let more_map = hour.map_rows.saturating_sub(short.map_rows) * row;
    assert!(
        hour.peak <= short.peak + more_map + MIB / 4,
        "the peak grows with the run: 10 min {} B, 1 h {} B",
        short.peak,
        hour.peak
    );
    assert_eq!(
        hour.second_half_allocs, 0,
        "the control/plant step of a streamed run allocates"
    );
}
