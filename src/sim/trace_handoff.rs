//! The trace of a plant stepped in real time (the in-process plant of `antisurge run --out`,
//! the plant node `antisurge plant`) streamed to `trace.csv` as the run goes (issue 25): the
//! plant thread hands each row to a writer thread over a bounded wait-free queue
//! ([`TraceHandoff::push`]: no file I/O, no allocation, no lock, never blocks); the writer
//! thread, of ordinary priority, writes the rows with [`CsvTraceWriter`] (the bytes of
//! `antisurge sim --out`), flushes whole lines at least every [`FLUSH_PERIOD_S`], and keeps
//! the run's settle log ([`TailStats`]). A row that finds the queue full is dropped and
//! counted, never waited for; the count is in [`WrittenTrace::dropped`].
//!
//! Memory is the queue, the file's buffer and the settle log's buffer, whatever the run's
//! length; a kill mid-run leaves a `trace.csv` of whole lines up to the last flush.

use super::stream::TailStats;
use super::trace::{CsvTraceWriter, TraceRow};
use super::SimError;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Trace time the queue holds, s: a writer held up this long (a slow disk, a loaded
/// machine) loses no row. 2 s at the default 5-ms trace period are 401 rows, 106 kB.
pub const HANDOFF_S: f64 = 2.0;

/// How often the writer thread takes the rows waiting in the queue, s: 20 ms, a hundredth of
/// [`HANDOFF_S`], so the queue is nearly empty between two wake-ups.
pub const POLL_S: f64 = 0.02;

/// Longest time rows wait in the file's buffer, s: a kill mid-run loses at most this much of
/// the trace (and whatever the queue held). Half a second: "at least once a second" with room
/// for a late wake-up.
pub const FLUSH_PERIOD_S: f64 = 0.5;

/// Shortest time between two warnings of dropped rows, s: a writer that stays behind is told
/// about without flooding the log.
pub const WARN_PERIOD_S: f64 = 10.0;

/// Counters shared by the two ends.
#[derive(Debug, Default)]
struct Shared {
    /// Rows handed to the queue.
    pushed: AtomicU64,
    /// Rows dropped because the queue was full.
    dropped: AtomicU64,
    /// Rows the writer took from the queue.
    taken: AtomicU64,
}

/// The plant thread's end: hands rows to the writer thread.
pub struct TraceHandoff {
    tx: rtrb::Producer<TraceRow>,
    pushed: u64,
    dropped: u64,
    shared: Arc<Shared>,
}

impl TraceHandoff {
    /// Hand `r` to the writer, or count it dropped if the queue is full. Wait-free: one copy
    /// into a preallocated slot and two atomic stores.
    pub fn push(&mut self, r: &TraceRow) {
        if self.tx.push(*r).is_ok() {
            self.pushed += 1;
            self.shared.pushed.store(self.pushed, Ordering::Release);
        } else {
            self.dropped += 1;
            self.shared.dropped.store(self.dropped, Ordering::Release);
        }
    }

    /// Rows dropped so far (the queue was full).
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

impl std::fmt::Debug for TraceHandoff {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TraceHandoff")
            .field("pushed", &self.pushed)
            .field("dropped", &self.dropped)
            .finish()
    }
}

/// What the writer thread leaves when the run is over.
pub struct WrittenTrace {
    /// The trace file.
    pub path: PathBuf,
    /// Rows written to it.
    pub rows: u64,
    /// Rows the plant thread dropped because the queue was full (0 on a healthy run).
    pub dropped: u64,
    /// The end of the trace and its settle log, for the summary
    /// ([`super::PlantRun::finish_written`]).
    pub tail: TailStats,
}

/// The writer thread's end.
pub struct TraceWriter {
    handle: std::thread::JoinHandle<Result<(u64, TailStats), std::io::Error>>,
    shared: Arc<Shared>,
    path: PathBuf,
}

impl TraceWriter {
    /// Start writing `dir/trace.csv` (the directory created if needed) on a thread of its
    /// own; the handoff goes to the plant thread's run
    /// ([`super::PlantRun::handing_trace_to`]). `volumetric`: the map's flow coordinate is
    /// inlet volume flow (the file's last column); `trace_period_s` sizes the queue
    /// ([`HANDOFF_S`]) and the tail; `t_last_event_s`: the scenario's last event, from which
    /// the settle log is kept (in an unnamed file in `dir`).
    ///
    /// Spawn it from a thread of ordinary priority (it inherits its scheduling policy), not
    /// from the real-time plant thread.
    pub fn start(
        dir: &Path,
        volumetric: bool,
        trace_period_s: f64,
        t_last_event_s: f64,
    ) -> Result<(TraceHandoff, TraceWriter), SimError> {
        let mut tail = TailStats::new(t_last_event_s, trace_period_s);
        let (file, path) = super::stream::open_trace(dir, &mut tail)?;
        let cap = queue_rows(trace_period_s);
        let (tx, rx) = rtrb::RingBuffer::new(cap);
        let shared = Arc::new(Shared::default());
        let csv = CsvTraceWriter::new(file, volumetric);
        let sh = Arc::clone(&shared);
        let handle = std::thread::Builder::new()
            .name("antisurge-trace".into())
            // sized like the daemon's other workers: under mlockall a whole stack is resident
            .stack_size(crate::runtime::rt_loop::WORKER_THREAD_STACK_BYTES)
            .spawn(move || write_rows(rx, cap, csv, tail, &sh))
            .map_err(|source| SimError::Output {
                path: path.clone(),
                source,
            })?;
        Ok((
            TraceHandoff {
                tx,
                pushed: 0,
                dropped: 0,
                shared: Arc::clone(&shared),
            },
            TraceWriter {
                handle,
                shared,
                path,
            },
        ))
    }

    /// Rows handed over and not yet taken by the writer.
    pub fn backlog(&self) -> u64 {
        let taken = self.shared.taken.load(Ordering::Acquire);
        self.shared
            .pushed
            .load(Ordering::Acquire)
            .saturating_sub(taken)
    }

    /// Rows dropped so far.
    pub fn dropped(&self) -> u64 {
        self.shared.dropped.load(Ordering::Acquire)
    }

    /// The trace file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Wait for the writer to write every row handed over and close the file. Call it once
    /// the handoff is dropped (the plant's run is over), else it waits for that.
    pub fn finish(self) -> Result<WrittenTrace, SimError> {
        let out = self.handle.join().unwrap_or_else(|_| {
            Err(std::io::Error::other(
                "the trace writer thread panicked".to_string(),
            ))
        });
        let (rows, tail) = out.map_err(|source| SimError::Output {
            path: self.path.clone(),
            source,
        })?;
        Ok(WrittenTrace {
            path: self.path,
            rows,
            dropped: self.shared.dropped.load(Ordering::Acquire),
            tail,
        })
    }
}

/// Rows the queue holds: [`HANDOFF_S`] of trace, at least 64.
fn queue_rows(trace_period_s: f64) -> usize {
    ((HANDOFF_S / trace_period_s.max(1e-6)).ceil() as usize + 1).clamp(64, 1 << 16)
}

/// The writer thread: take the rows as they come until the handoff is dropped and the queue
/// is empty; flush every [`FLUSH_PERIOD_S`]; sleep [`POLL_S`] between two takes unless a
/// quarter of the queue (`cap` rows) or more came (a writer that fell behind catches up at
/// once). Returns the rows written and the tail.
fn write_rows(
    mut rx: rtrb::Consumer<TraceRow>,
    cap: usize,
    mut csv: CsvTraceWriter<std::fs::File>,
    mut tail: TailStats,
    shared: &Shared,
) -> Result<(u64, TailStats), std::io::Error> {
    let flush_every = Duration::from_secs_f64(FLUSH_PERIOD_S);
    let poll = Duration::from_secs_f64(POLL_S);
    let warn_every = Duration::from_secs_f64(WARN_PERIOD_S);
    let mut last_flush = Instant::now();
    let mut taken = 0u64;
    let mut dropped_seen = 0u64;
    let mut last_warning: Option<Instant> = None;
    loop {
        // abandoned before the drain: every row pushed is in the queue now
        let over = rx.is_abandoned();
        let before = taken;
        while let Ok(r) = rx.pop() {
            csv.push(&r);
            tail.push(&r);
            taken += 1;
        }
        shared.taken.store(taken, Ordering::Release);
        let dropped = shared.dropped.load(Ordering::Acquire);
        // a warning when rows are dropped, at most every WARN_PERIOD_S
        if dropped > dropped_seen && last_warning.is_none_or(|t| t.elapsed() >= warn_every) {
            tracing::warn!(target: "plant", "trace.csv: {dropped} trace rows dropped so far (the writer fell behind the plant by more than {HANDOFF_S} s); the trace has gaps");
            dropped_seen = dropped;
            last_warning = Some(Instant::now());
        }
        if over {
            break;
        }
        if last_flush.elapsed() >= flush_every {
            csv.flush();
            last_flush = Instant::now();
        }
        if taken - before < cap as u64 / 4 {
            std::thread::sleep(poll);
        }
    }
    let rows = csv.rows();
    csv.finish()?;
    Ok((rows, tail))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::trace::write_csv;

    fn row(k: usize) -> TraceRow {
        let mut v = [0.0; 33];
        for (i, x) in v.iter_mut().enumerate() {
            *x = (k * 33 + i) as f64 * 1.234_567_891e-3 - 7.0;
        }
        v[0] = k as f64 * 0.005;
        v[5] = f64::NAN;
        TraceRow::from_values(v)
    }

    #[test]
    fn handed_rows_are_the_bytes_of_the_whole_trace() {
        let dir = tempfile::tempdir().expect("tmp");
        let rows: Vec<TraceRow> = (0..3000).map(row).collect();
        let (mut h, w) = TraceWriter::start(dir.path(), true, 0.005, 1.0).expect("start");
        for (k, r) in rows.iter().enumerate() {
            h.push(r);
            if k % 100 == 0 {
                // the test's own pace: let the writer catch up (the queue holds 401 rows)
                while w.backlog() > 0 {
                    std::thread::yield_now();
                }
            }
        }
        drop(h);
        let written = w.finish().expect("finish");
        assert_eq!((written.rows, written.dropped), (3000, 0));
        let mut whole = Vec::new();
        write_csv(&mut whole, &rows, true).expect("write");
        assert_eq!(
            std::fs::read(dir.path().join("trace.csv")).expect("read"),
            whole
        );
        let bits = |r: Option<TraceRow>| r.map(|r| r.values().map(f64::to_bits));
        assert_eq!(bits(written.tail.last()), bits(rows.last().copied()));
    }

    #[test]
    fn a_full_queue_drops_and_counts_without_blocking() {
        let dir = tempfile::tempdir().expect("tmp");
        let (mut h, w) = TraceWriter::start(dir.path(), false, 0.005, 1.0).expect("start");
        let cap = queue_rows(0.005) as u64;
        assert_eq!(cap, 401);
        // far more rows than the queue holds, faster than a writer that wakes every 20 ms
        // takes them: the pushes return at once, the excess is counted
        let n = 200 * cap;
        for k in 0..n as usize {
            h.push(&row(k));
        }
        assert!(h.dropped() > 0 && h.dropped() < n, "{}", h.dropped());
        let dropped = h.dropped();
        assert_eq!(w.dropped(), dropped);
        drop(h);
        let written = w.finish().expect("finish");
        assert_eq!(written.dropped, dropped);
        assert_eq!(written.rows + written.dropped, n);
        let text = std::fs::read_to_string(dir.path().join("trace.csv")).expect("read");
        assert_eq!(text.lines().count() as u64, written.rows + 1);
    }

    #[test]
    fn rows_reach_the_file_in_whole_lines_while_the_run_goes_on() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("trace.csv");
        let (mut h, w) = TraceWriter::start(dir.path(), false, 0.005, 1.0).expect("start");
        // a few rows, far fewer than the file's buffer holds: only the periodic flush
        // writes them while the handoff is alive
        for k in 0..10 {
            h.push(&row(k));
        }
        let t0 = Instant::now();
        let text = loop {
            let text = std::fs::read_to_string(&path).expect("read");
            if text.lines().count() == 11 {
                break text;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(60),
                "never flushed: {text:?}"
            );
            std::thread::sleep(Duration::from_millis(20));
        };
        assert!(text.ends_with('\n'), "whole lines only");
        drop(h);
        assert_eq!(w.finish().expect("finish").rows, 10);
    }

    #[test]
    fn the_writer_ends_when_the_handoff_is_dropped() {
        let dir = tempfile::tempdir().expect("tmp");
        let (h, w) = TraceWriter::start(dir.path(), false, 0.005, 1.0).expect("start");
        drop(h);
        let written = w.finish().expect("finish");
        assert_eq!((written.rows, written.dropped), (0, 0));
        let text = std::fs::read_to_string(dir.path().join("trace.csv")).expect("read");
        assert_eq!(text.lines().count(), 1, "the header");
        // no settle file left behind
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .expect("dir")
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("trace.csv")]);
    }
}
