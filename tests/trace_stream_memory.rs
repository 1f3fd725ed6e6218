//! Memory of a long `antisurge sim --out` run is bounded by streaming (issue 25): an hour of
//! simulated time at the default rates (1 kHz control, a trace row every 5 ms: 720 001 rows,
//! 196 MB if kept) streams to `trace.csv` with a peak of heap bytes in use far below the
//! trace, no larger than a 5-minute run's, and no allocation in the second half of the run.
//! One test in this binary: the heap figures are the whole process's.

mod common;

use antisurge::control::LawId;
use antisurge::sim::stream::{ENVELOPE_BUCKETS, PICTURE_ROWS};
use antisurge::sim::trace::TraceRow;
use antisurge::sim::{self, SimOptions};
use common::peak_alloc::{self, Peak};

#[global_allocator]
static GLOBAL: Peak = Peak;

const MIB: usize = 1 << 20;

fn scenario(duration_s: f64) -> antisurge::scenario::Scenario {
    common::scenario_text(&format!(
        r#"
name = "long-hold"
description = "throttle closure at 5 s, then held"
duration_s = {duration_s}
[initial]
throttle = 0.6
[[event]]
at_s = 0.0
noise = {{ sensors = ["p_discharge", "p_suction"], amplitude = 2000.0, distribution = "uniform" }}
[[event]]
at_s = 5.0
ramp = {{ signal = "throttle", to = 0.2, over_s = 2.0 }}
"#
    ))
}

/// Stream a run of `duration_s` into a fresh directory and draw nothing but build what the
/// pictures are drawn from; returns (peak heap bytes above the start, rows written,
/// allocations in the second half of the control loop, trace file bytes).
fn streamed_run(duration_s: f64) -> (usize, u64, u64, u64) {
    let desc = common::plant("kvangardsnes2009_recycle");
    let sc = scenario(duration_s);
    let dir = tempfile::tempdir().expect("tmp");
    let model = sim::control_model(&desc);
    let mut half: Option<u64> = None;
    let mut second_half_allocs = u64::MAX;
    let base = peak_alloc::in_use();
    peak_alloc::reset_peak();
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
                half = Some(peak_alloc::allocations());
            }
            if frac == 1.0 {
                second_half_allocs = peak_alloc::allocations() - half.unwrap_or(0);
            }
        },
        &mut |_, _| {},
    )
    .expect("run");
    let map = trace.pictures.map_rows();
    let series = trace.pictures.series_rows();
    assert!(map.len() <= PICTURE_ROWS + 1 && series.len() <= 2 * ENVELOPE_BUCKETS + 2);
    let peak = peak_alloc::peak().saturating_sub(base);
    assert!(summary.stable, "{}", summary.verdict);
    let bytes = std::fs::metadata(&trace.path).expect("trace").len();
    (peak, trace.rows, second_half_allocs, bytes)
}

#[test]
fn an_hour_streams_in_bounded_heap() {
    let (peak_5min, rows_5min, _, _) = streamed_run(300.0);
    let (peak_hour, rows_hour, allocs, bytes) = streamed_run(3600.0);
    assert_eq!((rows_5min, rows_hour), (60_001, 720_001));
    let kept = rows_hour as usize * std::mem::size_of::<TraceRow>();
    // what is kept: the picture's rows and envelope (2 rows a bucket) and the envelope's rows
    // for the time series, the file's and the settle log's buffers, the run's own state
    let bound = (PICTURE_ROWS + 4 * ENVELOPE_BUCKETS) * std::mem::size_of::<TraceRow>() + 2 * MIB;
    eprintln!(
        "peak heap above start: 5 min {:.2} MiB, 1 h {:.2} MiB (bound {:.1} MiB; the kept \
         trace would be {:.0} MiB; trace.csv {:.0} MiB); allocations in the second half: {allocs}",
        peak_5min as f64 / MIB as f64,
        peak_hour as f64 / MIB as f64,
        bound as f64 / MIB as f64,
        kept as f64 / MIB as f64,
        bytes as f64 / MIB as f64,
    );
    assert!(peak_hour < bound, "peak {peak_hour} B ≥ bound {bound} B");
    assert!(kept > 10 * bound, "the test would not tell a kept trace");
    assert!(
        peak_hour <= peak_5min + MIB / 4,
        "the peak grows with the run: 5 min {peak_5min} B, 1 h {peak_hour} B"
    );
    assert_eq!(allocs, 0, "the control/plant step of a streamed run allocates");
}
