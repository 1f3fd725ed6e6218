//! What a run keeps of its trace when the trace streams to `trace.csv` (`antisurge sim`): a
//! bounded picture of it for the map and the time series ([`PictureTrace`]), and what the
//! summary needs of the trace's end ([`TailStats`]). Neither grows with the run's length beyond
//! fixed bounds, except the settle log, which goes to an unnamed file beside the trace.

use super::trace::TraceRow;
use std::borrow::Cow;
use std::collections::VecDeque;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Rows the picture keeps exactly: a run of up to this many trace rows (82 s at the default
/// 5-ms trace period) is drawn from every row, as the whole trace was. A longer run keeps the
/// rows the map takes of a whole trace (at most [`crate::sim::trace::MAX_TRAJ_POINTS`], 5.4 MB),
/// and the min/max envelope of at most [`ENVELOPE_BUCKETS`] time buckets for the time series.
/// 16 384 rows are 4.5 MB.
pub const PICTURE_ROWS: usize = 1 << 14;

/// Most envelope buckets of a long run's time series (2 rows each): when full, neighbours merge
/// and the bucket doubles, so there are never fewer than half. Half of it, 2 048, is still two
/// buckets per bucket of the time series' own min/max thinning (1 000 across the plot width),
/// so no oscillation envelope is lost.
pub const ENVELOPE_BUCKETS: usize = 1 << 12;

/// Number of columns of a [`TraceRow`].
const COLS: usize = 33;

/// Per column: the smallest and the largest value of a stretch of rows, and which came first.
/// NaN is ignored unless every value of the column is NaN.
#[derive(Debug, Clone, Copy)]
struct Envelope {
    lo: [f64; COLS],
    hi: [f64; COLS],
    /// Bit i: column i's smallest value came no later than its largest.
    lo_first: u64,
    rows: usize,
}

/// Whether `a` (earlier) is kept as the smaller of `a` and `b` (NaN loses).
fn earlier_is_lower(a: f64, b: f64) -> bool {
    !a.is_nan() && (b.is_nan() || a <= b)
}

/// Whether `a` (earlier) is kept as the larger of `a` and `b` (NaN loses).
fn earlier_is_higher(a: f64, b: f64) -> bool {
    !a.is_nan() && (b.is_nan() || a >= b)
}

impl Envelope {
    fn of(r: &TraceRow) -> Envelope {
        let v = r.values();
        Envelope {
            lo: v,
            hi: v,
            lo_first: u64::MAX,
            rows: 1,
        }
    }

    /// `self` followed by `later`.
    fn merge(&mut self, later: &Envelope) {
        for i in 0..COLS {
            let lo_here = earlier_is_lower(self.lo[i], later.lo[i]);
            let hi_here = earlier_is_higher(self.hi[i], later.hi[i]);
            let bit = 1u64 << i;
            let first = match (lo_here, hi_here) {
                (true, true) => self.lo_first & bit != 0,
                (false, false) => later.lo_first & bit != 0,
                // the smallest value in the earlier stretch, the largest in the later
                (true, false) => true,
                (false, true) => false,
            };
            if !lo_here {
                self.lo[i] = later.lo[i];
            }
            if !hi_here {
                self.hi[i] = later.hi[i];
            }
            if first {
                self.lo_first |= bit;
            } else {
                self.lo_first &= !bit;
            }
        }
        self.rows += later.rows;
    }

    /// The stretch as rows: per column its extremes in the order they came (the time column's
    /// are the stretch's first and last times). One row for a stretch of one row.
    fn rows(&self, out: &mut Vec<TraceRow>) {
        if self.rows == 1 {
            out.push(TraceRow::from_values(self.lo));
            return;
        }
        let mut a = [0.0; COLS];
        let mut b = [0.0; COLS];
        for i in 0..COLS {
            if self.lo_first & (1u64 << i) != 0 {
                (a[i], b[i]) = (self.lo[i], self.hi[i]);
            } else {
                (a[i], b[i]) = (self.hi[i], self.lo[i]);
            }
        }
        out.push(TraceRow::from_values(a));
        out.push(TraceRow::from_values(b));
    }
}

/// The envelope of a long run: closed buckets of `per_bucket` rows and the one being filled.
#[derive(Debug)]
struct Envelopes {
    buckets: Vec<Envelope>,
    open: Option<Envelope>,
    per_bucket: usize,
}

impl Envelopes {
    /// No bucket yet; buckets of `per_bucket` rows.
    fn new(per_bucket: usize) -> Envelopes {
        Envelopes {
            buckets: Vec::with_capacity(ENVELOPE_BUCKETS),
            open: None,
            per_bucket: per_bucket.max(2),
        }
    }

    /// The envelope of `rows` (all rows of the run so far), in half the most buckets.
    fn of(rows: &[TraceRow]) -> Envelopes {
        let mut e = Envelopes::new(rows.len().div_ceil(ENVELOPE_BUCKETS / 2));
        for r in rows {
            e.push(r);
        }
        e
    }

    fn push(&mut self, r: &TraceRow) {
        let one = Envelope::of(r);
        let open = match &mut self.open {
            Some(o) => {
                o.merge(&one);
                o
            }
            None => self.open.insert(one),
        };
        if open.rows < self.per_bucket {
            return;
        }
        let closed = *open;
        self.open = None;
        if self.buckets.len() == ENVELOPE_BUCKETS {
            // neighbours merge: half as many buckets of twice the rows
            for k in 0..ENVELOPE_BUCKETS / 2 {
                let mut m = self.buckets[2 * k];
                m.merge(&self.buckets[2 * k + 1]);
                self.buckets[k] = m;
            }
            self.buckets.truncate(ENVELOPE_BUCKETS / 2);
            self.per_bucket *= 2;
        }
        self.buckets.push(closed);
    }

    fn rows(&self) -> Vec<TraceRow> {
        let mut out = Vec::with_capacity(2 * (self.buckets.len() + 1));
        for b in self.buckets.iter().chain(self.open.iter()) {
            b.rows(&mut out);
        }
        out
    }
}

/// What the pictures of a streamed run are drawn from, in bounded memory: every row of a run of
/// up to [`PICTURE_ROWS`] rows (the pictures are then those of the whole trace); beyond, real
/// rows at an even stride for the map's trajectory (for a run of known length, the very rows
/// the map takes of the whole trace: the same map), and the per-column min/max envelope of
/// time buckets for the time series (the oscillation envelope, peaks and mode changes survive;
/// the time series thin to min/max per pixel column anyway).
#[derive(Debug)]
pub struct PictureTrace {
    /// Every `every`-th row of the run, then the run's last row if it is not one of them.
    sample: Vec<TraceRow>,
    /// Most `every`-th rows kept: one more and every other one is dropped, `every` doubles.
    sample_cap: usize,
    every: usize,
    /// Whether the sample's last row is the run's last row and not an `every`-th one.
    tentative: bool,
    /// Rows seen.
    n: usize,
    envelope: Option<Envelopes>,
}

impl Default for PictureTrace {
    fn default() -> Self {
        Self::new()
    }
}

impl PictureTrace {
    /// An empty picture of a run of unknown length, its row store reserved (no allocation as
    /// rows come until the first thinning, and one then).
    pub fn new() -> Self {
        PictureTrace {
            sample: Vec::with_capacity(PICTURE_ROWS + 1),
            ..Self::new_empty()
        }
    }

    fn new_empty() -> Self {
        PictureTrace {
            sample: Vec::new(),
            sample_cap: PICTURE_ROWS,
            every: 1,
            tentative: false,
            n: 0,
            envelope: None,
        }
    }

    /// An empty picture of a run of `rows` rows, everything reserved: the map's rows are those
    /// `plot::map_svg` takes of the whole trace, the envelope's buckets are sized to
    /// the run (rows beyond `rows` are thinned as in [`PictureTrace::new`]).
    pub fn with_rows(rows: usize) -> Self {
        if rows <= PICTURE_ROWS {
            return PictureTrace {
                sample: Vec::with_capacity(rows + 1),
                ..Self::new_empty()
            };
        }
        let every = rows.div_ceil(crate::sim::trace::MAX_TRAJ_POINTS).max(1);
        let sample_cap = rows.div_ceil(every);
        PictureTrace {
            sample: Vec::with_capacity(sample_cap + 1),
            sample_cap,
            every,
            tentative: false,
            n: 0,
            envelope: Some(Envelopes::new(rows.div_ceil(ENVELOPE_BUCKETS))),
        }
    }

    /// Add the run's next row.
    pub fn push(&mut self, r: &TraceRow) {
        let i = self.n;
        self.n += 1;
        if self.tentative {
            self.sample.pop();
            self.tentative = false;
        }
        if self.envelope.is_none() && self.sample.len() == self.sample_cap {
            // the first thinning: until now every row was kept
            self.envelope = Some(Envelopes::of(&self.sample));
        }
        if let Some(e) = &mut self.envelope {
            e.push(r);
        }
        if i.is_multiple_of(self.every) && self.sample.len() == self.sample_cap {
            let mut k = 0;
            self.sample.retain(|_| {
                k += 1;
                (k - 1) % 2 == 0
            });
            self.every *= 2;
        }
        // a row off the stride is kept until the next one comes: the run's last row
        self.tentative = !i.is_multiple_of(self.every);
        self.sample.push(*r);
    }

    /// Rows seen.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Whether no row came.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Whether every row is kept (the pictures are those of the whole trace).
    pub fn is_exact(&self) -> bool {
        self.envelope.is_none()
    }

    /// Rows for the map (`plot::map_svg_sampled`): real rows at an even stride, the
    /// last row of the run included.
    pub fn map_rows(&self) -> &[TraceRow] {
        &self.sample
    }

    /// Rows for the time series: every row, or the envelope rows of a long run.
    pub fn series_rows(&self) -> Cow<'_, [TraceRow]> {
        match &self.envelope {
            None => Cow::Borrowed(&self.sample),
            Some(e) => Cow::Owned(e.rows()),
        }
    }
}

/// How far back the tail of the trace is kept, s: the longest window [`TailStats`] looks at
/// (the steadiness window of the verdict, at most 3 s).
pub const TAIL_S: f64 = 3.0;

/// Bytes of the settle log held before they are written to its file.
const SETTLE_BUFFER_BYTES: usize = 1 << 16;

/// (time, true flow) of every row from the scenario's last event on, for the settle time: the
/// last time the flow was outside the band around its final value, which is known only at the
/// end. 16 bytes a row, written to a file that has no name (created in the output directory
/// and unlinked at once, so nothing is left behind), read back once at the end.
struct SettleFile {
    file: std::fs::File,
    buf: Vec<u8>,
    written: u64,
    error: Option<std::io::Error>,
}

impl SettleFile {
    fn create(dir: &Path) -> std::io::Result<SettleFile> {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let path = dir.join(format!(
            ".antisurge-settle-{}-{nanos}.tmp",
            std::process::id()
        ));
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(true)
            .open(&path)?;
        std::fs::remove_file(&path)?;
        Ok(SettleFile {
            file,
            buf: Vec::with_capacity(SETTLE_BUFFER_BYTES),
            written: 0,
            error: None,
        })
    }

    fn push(&mut self, t_s: f64, m_kg_s: f64) {
        self.buf.extend_from_slice(&t_s.to_le_bytes());
        self.buf.extend_from_slice(&m_kg_s.to_le_bytes());
        if self.buf.len() + 16 > SETTLE_BUFFER_BYTES {
            if self.error.is_none() {
                match self.file.write_all(&self.buf) {
                    Ok(()) => self.written += self.buf.len() as u64,
                    Err(e) => self.error = Some(e),
                }
            }
            self.buf.clear();
        }
    }

    /// Every (t, m) in order.
    fn for_each(&self, mut f: impl FnMut(f64, f64)) -> std::io::Result<()> {
        use std::os::unix::fs::FileExt;
        if let Some(e) = &self.error {
            return Err(std::io::Error::new(e.kind(), e.to_string()));
        }
        let mut each = |bytes: &[u8]| {
            for rec in bytes.chunks_exact(16) {
                let (t, m) = rec.split_at(8);
                let word = |b: &[u8]| f64::from_le_bytes(b.try_into().unwrap_or([0; 8]));
                f(word(t), word(m));
            }
        };
        let mut chunk = vec![0u8; SETTLE_BUFFER_BYTES];
        let mut at = 0u64;
        while at < self.written {
            let n = (self.written - at).min(SETTLE_BUFFER_BYTES as u64) as usize;
            self.file.read_exact_at(&mut chunk[..n], at)?;
            each(&chunk[..n]);
            at += n as u64;
        }
        each(&self.buf);
        Ok(())
    }
}

/// The end of a run's trace and what the summary judges from it, collected row by row: the
/// last row, (time, flow) of the last [`TAIL_S`] seconds (whether the run ended steady, and
/// the final flow the settle time is measured against), and, for a streamed run, the settle
/// log. A run that keeps its whole trace in memory reads the settle rows from it instead.
pub struct TailStats {
    last: Option<TraceRow>,
    tail: VecDeque<(f64, f64)>,
    /// Rows from this time on go to the settle log (the scenario's last event).
    t_event_s: f64,
    settle: Option<SettleFile>,
}

impl TailStats {
    /// Statistics of a run whose last event is at `t_event_s`; `trace_period_s` sizes the tail.
    pub fn new(t_event_s: f64, trace_period_s: f64) -> Self {
        let rows = (TAIL_S / trace_period_s.max(1e-6)).ceil() as usize + 2;
        TailStats {
            last: None,
            tail: VecDeque::with_capacity(rows.min(1 << 20)),
            t_event_s,
            settle: None,
        }
    }

    /// Keep the settle log in an unnamed file in `dir` (a streamed run).
    pub fn log_settle_in(&mut self, dir: &Path) -> std::io::Result<()> {
        self.settle = Some(SettleFile::create(dir)?);
        Ok(())
    }

    /// Add the run's next row.
    pub fn push(&mut self, r: &TraceRow) {
        self.last = Some(*r);
        while self.tail.front().is_some_and(|&(t, _)| t < r.t_s - TAIL_S) {
            self.tail.pop_front();
        }
        self.tail.push_back((r.t_s, r.m_kg_s));
        if r.t_s >= self.t_event_s {
            if let Some(s) = &mut self.settle {
                s.push(r.t_s, r.m_kg_s);
            }
        }
    }

    /// The last row.
    pub fn last(&self) -> Option<TraceRow> {
        self.last
    }

    /// Flows of the last `window_s` (at most [`TAIL_S`]) before the last row, in order.
    fn window(&self, window_s: f64) -> impl Iterator<Item = f64> + '_ {
        let t_last = self.last.map_or(f64::NAN, |r| r.t_s);
        self.tail
            .iter()
            .filter(move |(t, _)| *t >= t_last - window_s)
            .map(|&(_, m)| m)
    }

    /// [`super::summary::is_steady`] of the whole trace, from the tail.
    pub fn is_steady(&self, window_s: f64, rel: f64, abs_floor: f64) -> bool {
        debug_assert!(window_s <= TAIL_S);
        self.last.is_some() && super::summary::steady_window(self.window(window_s), rel, abs_floor)
    }

    /// [`super::summary::settle_time`] of the whole trace: the rows from the last event on
    /// come from the settle log, or from `rows` (the whole trace) when there is none.
    pub fn settle_time(
        &self,
        rows: &[TraceRow],
        rel: f64,
        abs_floor: f64,
    ) -> std::io::Result<Option<f64>> {
        let Some(last) = self.last else {
            return Ok(None);
        };
        let mut settle = super::summary::Settle::new(
            self.window(super::summary::SETTLE_FINAL_WINDOW_S),
            self.t_event_s,
            rel,
            abs_floor,
        );
        match &self.settle {
            Some(log) => log.for_each(|t, m| settle.row(t, m))?,
            None => rows
                .iter()
                .filter(|r| r.t_s >= self.t_event_s)
                .for_each(|r| settle.row(r.t_s, r.m_kg_s)),
        }
        Ok(settle.finish(last.t_s))
    }
}

/// Open `dir/trace.csv` for a streamed trace (the directory created) and move `tail`'s settle
/// log into `dir`: the one start of `sim --out` and of the daemon's handed-off trace.
pub(crate) fn open_trace(
    dir: &Path,
    tail: &mut TailStats,
) -> Result<(std::fs::File, PathBuf), super::SimError> {
    let err = |path: &Path| {
        let path = path.to_path_buf();
        move |source| super::SimError::Output { path, source }
    };
    std::fs::create_dir_all(dir).map_err(err(dir))?;
    let path = dir.join("trace.csv");
    let file = std::fs::File::create(&path).map_err(err(&path))?;
    tail.log_settle_in(dir).map_err(err(dir))?;
    Ok((file, path))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::summary::{is_steady, settle_time};

    /// A surging flow (2 Hz, growing), a one-row spike of the valve command at 100 s, a
    /// fail-safe stretch of 0.1 s at 150 s, a NaN column.
    fn row(k: usize) -> TraceRow {
        let t = k as f64 * 0.005;
        TraceRow {
            t_s: t,
            m_kg_s: 10.0 + (1.0 + t / 100.0) * (2.0 * std::f64::consts::PI * 2.0 * t).sin(),
            cmd_recycle_valve: if k == 20_000 { 1.0 } else { 0.2 },
            mode: if (150.0..150.1).contains(&t) {
                3.0
            } else {
                2.0
            },
            law_diagnostic: f64::NAN,
            p_discharge_pa: 4e6 - t,
            ..Default::default()
        }
    }

    #[test]
    fn a_short_run_keeps_every_row() {
        let mut p = PictureTrace::new();
        let rows: Vec<TraceRow> = (0..PICTURE_ROWS).map(row).collect();
        for r in &rows {
            p.push(r);
        }
        assert!(p.is_exact());
        let bits = |rows: &[TraceRow]| -> Vec<[u64; COLS]> {
            rows.iter().map(|r| r.values().map(f64::to_bits)).collect()
        };
        assert_eq!(bits(p.map_rows()), bits(&rows));
        assert_eq!(bits(&p.series_rows()), bits(&rows));
    }

    #[test]
    fn a_long_run_keeps_bounded_rows_with_envelope_peaks_and_mode_changes() {
        let n = 200_001; // 1 000 s
        let mut p = PictureTrace::new();
        let cap = p.sample.capacity();
        for k in 0..n {
            p.push(&row(k));
            assert!(p.sample.len() <= PICTURE_ROWS + 1);
        }
        assert_eq!(p.sample.capacity(), cap, "the sample never grew");
        assert!(p.every > 1);
        assert!(!p.is_exact());
        let map = p.map_rows();
        assert!(map.len() > PICTURE_ROWS / 2 && map.len() <= PICTURE_ROWS + 1);
        assert_eq!(map[0].t_s, 0.0);
        assert_eq!(map[map.len() - 1].t_s, row(n - 1).t_s);
        assert!(map.windows(2).all(|w| w[0].t_s < w[1].t_s));
        let s = p.series_rows();
        assert!(s.len() >= ENVELOPE_BUCKETS && s.len() <= 2 * ENVELOPE_BUCKETS + 2);
        assert!(s.windows(2).all(|w| w[0].t_s <= w[1].t_s), "time order");
        assert_eq!((s[0].t_s, s[s.len() - 1].t_s), (0.0, row(n - 1).t_s));
        // the envelope: the extremes of every 10-s stretch survive
        let all: Vec<TraceRow> = (0..n).map(row).collect();
        for w in 0..100 {
            let (a, b) = (w as f64 * 10.0, (w + 1) as f64 * 10.0);
            let ext = |rows: &[TraceRow]| {
                rows.iter()
                    .filter(|r| r.t_s >= a && r.t_s < b)
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| {
                        (lo.min(r.m_kg_s), hi.max(r.m_kg_s))
                    })
            };
            let (lo, hi) = ext(&all);
            let (tlo, thi) = ext(&s);
            // bucket edges may move an extreme into the neighbouring stretch
            assert!(
                (tlo - lo).abs() < 0.05 && (thi - hi).abs() < 0.05,
                "{w}: {tlo} {lo}"
            );
        }
        // a one-row spike and a 0.1-s fail-safe stretch survive
        assert!(s.iter().any(|r| r.cmd_recycle_valve == 1.0));
        let fs: Vec<f64> = s.iter().filter(|r| r.mode == 3.0).map(|r| r.t_s).collect();
        assert!(
            !fs.is_empty() && fs.iter().all(|t| (149.3..150.8).contains(t)),
            "{fs:?}"
        );
        // a column with no value stays without
        assert!(s.iter().all(|r| r.law_diagnostic.is_nan()));
        // a falling pressure falls in the envelope rows too
        assert!(s
            .windows(2)
            .all(|w| w[1].p_discharge_pa <= w[0].p_discharge_pa));
    }

    #[test]
    fn a_run_of_known_length_keeps_the_rows_the_map_takes_of_the_whole_trace() {
        for n in [
            100,
            PICTURE_ROWS,
            PICTURE_ROWS + 1,
            20_000,
            20_001,
            120_001,
            720_001,
        ] {
            let mut p = PictureTrace::with_rows(n);
            let cap = p.sample.capacity();
            for k in 0..n {
                p.push(&row(k));
            }
            assert_eq!(p.sample.capacity(), cap, "{n}: the sample never grew");
            // what map_svg takes of the whole trace
            let stride = n.div_ceil(crate::sim::trace::MAX_TRAJ_POINTS).max(1);
            let mut taken: Vec<usize> = (0..n).step_by(stride).collect();
            if (n - 1) % stride != 0 {
                taken.push(n - 1);
            }
            let kept: Vec<f64> = p.map_rows().iter().map(|r| r.t_s).collect();
            let want: Vec<f64> = taken.iter().map(|&k| row(k).t_s).collect();
            assert_eq!(kept, want, "{n}");
            assert_eq!(p.is_exact(), n <= PICTURE_ROWS, "{n}");
            let s = p.series_rows();
            let most = if p.is_exact() {
                n
            } else {
                2 * ENVELOPE_BUCKETS + 2
            };
            assert!(s.len() <= most, "{n}: {}", s.len());
            assert_eq!(s[s.len() - 1].t_s, row(n - 1).t_s);
        }
    }

    #[test]
    fn tail_statistics_match_the_whole_trace() {
        let dir = std::env::temp_dir();
        for (f, end) in [
            (
                (|t: f64| 5.0 + 2.0 * (-t).exp()) as fn(f64) -> f64,
                20.0_f64,
            ),
            (|t: f64| 5.0 + (3.0 * t).sin(), 20.0),
            (|t: f64| if t < 12.0 { 3.0 } else { 3.5 }, 30.0),
        ] {
            let rows: Vec<TraceRow> = (0..=(end / 0.005) as usize)
                .map(|k| TraceRow {
                    t_s: k as f64 * 0.005,
                    m_kg_s: f(k as f64 * 0.005),
                    ..Default::default()
                })
                .collect();
            let mut kept = TailStats::new(1.0, 0.005);
            let mut logged = TailStats::new(1.0, 0.005);
            logged.log_settle_in(&dir).expect("settle log");
            for r in &rows {
                kept.push(r);
                logged.push(r);
            }
            let window = (0.25 * end).clamp(1.0, 3.0);
            assert_eq!(
                kept.is_steady(window, 0.02, 1e-4),
                is_steady(&rows, window, 0.02, 1e-4)
            );
            let whole = settle_time(&rows, 1.0, 0.02, 1e-4);
            assert_eq!(kept.settle_time(&rows, 0.02, 1e-4).expect("kept"), whole);
            assert_eq!(logged.settle_time(&[], 0.02, 1e-4).expect("logged"), whole);
            assert!(logged.tail.len() <= (TAIL_S / 0.005) as usize + 2);
        }
    }
}
