//! The black box: a fixed-size ring of per-cycle records of the daemon's control loop, written
//! to a file on fail-safe, surge and exit, and replayed by `antisurge replay`.
//!
//! - The control thread fills one [`CycleRecord`] per cycle (the inputs the core saw with their
//!   ages, the operator inputs, the commands, mode, law and its diagnostics) and pushes it into
//!   a lock-free SPSC ring ([`BlackBoxTx::push`]: a copy, no allocation, no lock, never waits;
//!   a full queue drops the record and counts it). The queue holds what the loop produces in
//!   one drain period plus [`TOLERATED_STALL_S`] of recorder stall ([`handoff_capacity`]).
//! - The recorder thread ([`Recorder`]) drains that queue every [`DRAIN_PERIOD_S`] into its own
//!   fixed-size ring of the last [`HISTORY_S`] of cycles and writes it to a file when a cycle reports
//!   fail-safe or a surge (after [`POST_TRIGGER_CYCLES`] more cycles, so the file shows what
//!   followed) and at exit. File I/O never touches the control thread's budget.
//! - Time in a record is the tick's (`deadline_ns`, `wake_ns`, and the `t_s` the core was given,
//!   derived from the tick), never a clock the node reads on its own.
//!
//! # File format
//!
//! Text, one file per dump: a first line `# antisurge-blackbox 1 <JSON header>` ([`Header`]:
//! what the core was built from), a CSV column line, then one CSV row per cycle. Numbers are
//! written with Rust's shortest round-trip formatting (`NaN`, `inf` included), so parsing a row
//! gives back the exact bits the core saw: a replay is bit-exact.

pub mod candump;
pub mod replay;

use crate::control::measurements::{OperatorInputs, RawSensors};
use crate::control::ControllerConfig;
use crate::vocab::signals::{ActuatorCommands, ActuatorId, SensorId, SensorSnapshot, CYCLE_INPUTS};
use crate::vocab::Mode;
use serde::{Deserialize, Serialize};
use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

/// History the recorder keeps, s: the ring holds this many seconds of cycles at the loop's
/// rate ([`history_capacity`]).
pub const HISTORY_S: f64 = 10.0;
/// Records the recorder keeps at the default 1 kHz ([`HISTORY_S`] of cycles). In memory a
/// record takes 344 bytes, plus 160 for the spare transmitters' readings and votes once a
/// cycle has any (3.4 MB, or 5.0 MB with redundant transmitters).
pub const DEFAULT_CAPACITY: usize = 10_000;
/// Cycles recorded after a trigger before the file is written.
pub const POST_TRIGGER_CYCLES: u64 = 2_000;
/// Most trigger dumps per run (the exit dump is always written).
pub const MAX_TRIGGER_DUMPS: usize = 16;
/// How often the recorder drains the control thread → recorder queue, s.
pub const DRAIN_PERIOD_S: f64 = 0.020;
/// The longest stall of the recorder thread the hand-off queue absorbs without dropping a
/// record, s, on top of one [`DRAIN_PERIOD_S`]: a dump of the whole ring to a file (10 000
/// rows, 5.9 MB: under 0.04 s on the development machine, benches/README.md; the rest is room
/// for a slow disk) or the thread being descheduled. A longer stall drops records, counted in
/// the next file's header (`dropped`).
pub const TOLERATED_STALL_S: f64 = 1.0;

/// Records the ring keeps for [`HISTORY_S`] at a control period of `period_ns`.
pub fn history_capacity(period_ns: u64) -> usize {
    records_in(HISTORY_S, period_ns)
}

/// Capacity of the control thread → recorder queue at a control period of `period_ns`,
/// records: what the loop produces in one drain period plus the tolerated stall
/// ([`DRAIN_PERIOD_S`] + [`TOLERATED_STALL_S`]; 1 020 records, 0.7 MB, at 1 kHz).
pub fn handoff_capacity(period_ns: u64) -> usize {
    records_in(DRAIN_PERIOD_S + TOLERATED_STALL_S, period_ns)
}

/// Cycles in `span_s` at `period_ns` (rounded up; at least 1; a zero period counts as 1 ms).
fn records_in(span_s: f64, period_ns: u64) -> usize {
    let period_s = if period_ns == 0 {
        1e-3
    } else {
        period_ns as f64 * 1e-9
    };
    ((span_s / period_s).ceil() as usize).max(1)
}
/// First token of a black-box file.
pub const MAGIC: &str = "# antisurge-blackbox 1 ";

/// One control cycle as the core saw and answered it. Plain data, `Copy`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleRecord {
    /// Cycle number of the tick (from 0).
    pub cycle: u64,
    /// The tick's deadline, monotonic ns.
    pub deadline_ns: u64,
    /// When the thread woke for it, monotonic ns.
    pub wake_ns: u64,
    /// The time the core was given, s (from the tick).
    pub t_s: f64,
    /// Inputs with their ages.
    pub raw: RawSensors,
    /// Operator inputs.
    pub op: OperatorInputs,
    /// Commands the core produced.
    pub commands: ActuatorCommands,
    /// Mode after the cycle.
    pub mode: Mode,
    /// Law code.
    pub law: u8,
    /// Law diagnostic.
    pub law_diagnostic: f64,
    /// The law's own torque, N·m.
    pub law_torque_nm: f64,
    /// Flow the laws used, kg/s.
    pub m_used_kg_s: f64,
    /// Observer estimate, kg/s.
    pub m_observer_kg_s: f64,
    /// Flow from the observer because the transmitter failed.
    pub flow_fallback: bool,
    /// A surge (or flow reversal) started this cycle.
    pub surge_started: bool,
    /// Configuration updates applied so far (a change means the settings changed here).
    pub updates_applied: u64,
    /// The voted value of each measurement with redundant transmitters, in
    /// [`VOTABLE`](crate::control::vote::VOTABLE) order (NaN: not voted, or no valid one).
    pub voted: [f64; crate::control::vote::VOTABLE.len()],
}

/// What the control core was built from: enough for `antisurge replay` to build it again.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// antisurge version that wrote the file.
    pub version: String,
    /// The daemon's main config file.
    pub config: PathBuf,
    /// Law at start.
    pub law: String,
    /// Automatic mode requested at start.
    pub auto: bool,
    /// Initial torque of the speed loop, N·m.
    pub initial_torque_nm: f64,
    /// Control period, ns.
    pub period_ns: u64,
    /// Controller settings at start.
    pub controller: ControllerConfig,
    /// Why the file was written (`fail_safe`, `surge`, `exit`); set by the recorder.
    #[serde(default)]
    pub reason: String,
    /// Records the control thread could not hand over (ring full) before this dump.
    #[serde(default)]
    pub dropped: u64,
}

/// Black-box errors.
#[derive(Debug, thiserror::Error)]
pub enum BlackBoxError {
    /// File system.
    #[error("{path}: {source}")]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// Not a black-box file, or a damaged line.
    #[error("{path}:{line}: {message}")]
    Format {
        /// File.
        path: PathBuf,
        /// Line (1-based).
        line: usize,
        /// What is wrong.
        message: String,
    },
}

/// The control thread's end: push one record per cycle.
pub struct BlackBoxTx {
    tx: rtrb::Producer<CycleRecord>,
    dropped: Arc<AtomicU64>,
}

impl BlackBoxTx {
    /// Hand a record to the recorder: a copy into a preallocated ring; never blocks or
    /// allocates. A full ring drops the record (counted, reported in the file header).
    #[inline]
    pub fn push(&mut self, r: CycleRecord) {
        if self.tx.push(r).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The control thread → recorder queue for a control period of `period_ns`, sized by
/// [`handoff_capacity`].
fn handoff(period_ns: u64) -> (BlackBoxTx, rtrb::Consumer<CycleRecord>) {
    let (tx, rx) = rtrb::RingBuffer::new(handoff_capacity(period_ns));
    let dropped = Arc::new(AtomicU64::new(0));
    (BlackBoxTx { tx, dropped }, rx)
}

/// The recorder thread.
pub struct Recorder {
    handle: std::thread::JoinHandle<Vec<PathBuf>>,
    stop: Arc<AtomicBool>,
}

impl Recorder {
    /// Start a recorder writing into `dir` (created when the first file is written).
    pub fn start(
        dir: PathBuf,
        header: Header,
        capacity: usize,
    ) -> std::io::Result<(BlackBoxTx, Recorder)> {
        let (tx, rx) = handoff(header.period_ns);
        let dropped = Arc::clone(&tx.dropped);
        let stop = Arc::new(AtomicBool::new(false));
        let st = Arc::clone(&stop);
        let handle = std::thread::Builder::new()
            .name("antisurge-bbox".into())
            .stack_size(crate::runtime::rt_loop::WORKER_THREAD_STACK_BYTES)
            .spawn(move || recorder_loop(rx, dir, header, capacity.max(1), &st, &dropped))?;
        Ok((tx, Recorder { handle, stop }))
    }

    /// Drain what is left, write the exit file, stop; returns every file written.
    pub fn finish(self) -> Vec<PathBuf> {
        self.stop.store(true, Ordering::Release);
        self.handle.join().unwrap_or_default()
    }
}

/// A record as the ring keeps it: a [`CycleRecord`] without the spare transmitters' readings
/// and votes ([`Spares`]), which only cycles that have them store.
#[derive(Debug, Clone, Copy)]
struct Kept {
    cycle: u64,
    deadline_ns: u64,
    wake_ns: u64,
    t_s: f64,
    values: SensorSnapshot,
    age_s: [f64; SensorId::COUNT],
    /// The cycle inputs' sender clock ([`RawSensors::sender_clock_s`]), s.
    sender_clock_s: f64,
    /// The cycle inputs' sample numbers ([`RawSensors::sample_seq`], in
    /// [`CYCLE_INPUTS`](crate::vocab::signals::CYCLE_INPUTS) order): all the core reads of them.
    cycle_seq: [u64; CYCLE_INPUTS.len()],
    op: OperatorInputs,
    commands: ActuatorCommands,
    mode: Mode,
    law: u8,
    flow_fallback: bool,
    surge_started: bool,
    law_diagnostic: f64,
    law_torque_nm: f64,
    m_used_kg_s: f64,
    m_observer_kg_s: f64,
    updates_applied: u64,
}

/// The part of a record the file holds for the measurements that can take a vote: transmitters
/// `b` and `c` with their ages, and the vote, in [`VOTABLE`](crate::control::vote::VOTABLE)
/// order. (A [`SpareReadings`](crate::control::measurements::SpareReadings) has room for every
/// sensor; the file, and so the ring, only the votable ones.)
#[derive(Debug, Clone, Copy, PartialEq)]
struct Spares {
    values: [[f64; 2]; crate::control::vote::VOTABLE.len()],
    age_s: [[f64; 2]; crate::control::vote::VOTABLE.len()],
    voted: [f64; crate::control::vote::VOTABLE.len()],
}

impl Spares {
    /// No spare transmitter, no vote: what a record without them reads back as.
    const NONE: Spares = Spares {
        values: [[f64::NAN; 2]; crate::control::vote::VOTABLE.len()],
        age_s: [[f64::INFINITY; 2]; crate::control::vote::VOTABLE.len()],
        voted: [f64::NAN; crate::control::vote::VOTABLE.len()],
    };

    fn of(r: &CycleRecord) -> Spares {
        let mut s = Spares::NONE;
        for (k, id) in crate::control::vote::VOTABLE.into_iter().enumerate() {
            for slot in 1..=2 {
                let (v, age) = r.raw.spare.get(id, slot);
                s.values[k][slot - 1] = v;
                s.age_s[k][slot - 1] = age;
            }
        }
        s.voted = r.voted;
        s
    }

    /// Whether the file would show anything but "none" (NaN values and votes, ∞ ages: every
    /// NaN is written `NaN`, so this is exact for the file).
    fn any(&self) -> bool {
        self.values.iter().flatten().any(|v| !v.is_nan())
            || self.age_s.iter().flatten().any(|a| *a != f64::INFINITY)
            || self.voted.iter().any(|v| !v.is_nan())
    }
}

impl Kept {
    fn of(r: &CycleRecord) -> Kept {
        Kept {
            cycle: r.cycle,
            deadline_ns: r.deadline_ns,
            wake_ns: r.wake_ns,
            t_s: r.t_s,
            values: r.raw.values,
            age_s: r.raw.age_s,
            sender_clock_s: r.raw.sender_clock_s(),
            cycle_seq: CYCLE_INPUTS.map(|id| r.raw.sample_seq[id.index()]),
            op: r.op,
            commands: r.commands,
            mode: r.mode,
            law: r.law,
            flow_fallback: r.flow_fallback,
            surge_started: r.surge_started,
            law_diagnostic: r.law_diagnostic,
            law_torque_nm: r.law_torque_nm,
            m_used_kg_s: r.m_used_kg_s,
            m_observer_kg_s: r.m_observer_kg_s,
            updates_applied: r.updates_applied,
        }
    }

    /// The record again, as the file holds it (spares of the votable measurements only).
    fn record(&self, s: &Spares) -> CycleRecord {
        let mut spare = crate::control::measurements::SpareReadings::NONE;
        for (k, id) in crate::control::vote::VOTABLE.into_iter().enumerate() {
            for slot in 1..=2 {
                spare.set(id, slot, s.values[k][slot - 1], s.age_s[k][slot - 1]);
            }
        }
        CycleRecord {
            cycle: self.cycle,
            deadline_ns: self.deadline_ns,
            wake_ns: self.wake_ns,
            t_s: self.t_s,
            raw: RawSensors {
                values: self.values,
                age_s: self.age_s,
                spare,
                sample_clock_s: cycle_clocks(self.sender_clock_s),
                sample_seq: cycle_seqs(self.cycle_seq),
            },
            op: self.op,
            commands: self.commands,
            mode: self.mode,
            law: self.law,
            law_diagnostic: self.law_diagnostic,
            law_torque_nm: self.law_torque_nm,
            m_used_kg_s: self.m_used_kg_s,
            m_observer_kg_s: self.m_observer_kg_s,
            flow_fallback: self.flow_fallback,
            surge_started: self.surge_started,
            updates_applied: self.updates_applied,
            voted: s.voted,
        }
    }
}

/// Fixed-size ring of records (oldest overwritten). The spare transmitters' part is a parallel
/// ring allocated (on the recorder thread) by the first record that has any: a controller
/// without redundant transmitters keeps 344 bytes a cycle instead of 504.
struct Ring {
    buf: Vec<Kept>,
    spares: Option<Vec<Spares>>,
    capacity: usize,
    next: usize,
    full: bool,
}

impl Ring {
    fn new(capacity: usize) -> Ring {
        let capacity = capacity.max(1);
        Ring {
            buf: Vec::with_capacity(capacity),
            spares: None,
            capacity,
            next: 0,
            full: false,
        }
    }

    fn push(&mut self, r: &CycleRecord) {
        let kept = Kept::of(r);
        let s = Spares::of(r);
        if self.spares.is_none() && s.any() {
            // the records so far had none
            let mut v = Vec::with_capacity(self.capacity);
            v.resize(self.buf.len(), Spares::NONE);
            self.spares = Some(v);
        }
        if self.buf.len() < self.capacity {
            self.buf.push(kept);
            if let Some(v) = &mut self.spares {
                v.push(s);
            }
        } else {
            self.buf[self.next] = kept;
            if let Some(v) = &mut self.spares {
                v[self.next] = s;
            }
            self.full = true;
        }
        self.next = (self.next + 1) % self.capacity;
    }

    fn in_order(&self) -> impl Iterator<Item = CycleRecord> + '_ {
        let order = if self.full {
            (self.next..self.buf.len()).chain(0..self.next)
        } else {
            (0..self.buf.len()).chain(0..0)
        };
        order.map(|i| {
            let s = self.spares.as_ref().map_or(&Spares::NONE, |v| &v[i]);
            self.buf[i].record(s)
        })
    }

    fn last_cycle(&self) -> Option<u64> {
        if self.buf.is_empty() {
            None
        } else {
            let i = (self.next + self.capacity - 1) % self.capacity;
            Some(self.buf[i].cycle)
        }
    }
}

fn recorder_loop(
    mut rx: rtrb::Consumer<CycleRecord>,
    dir: PathBuf,
    mut header: Header,
    capacity: usize,
    stop: &AtomicBool,
    dropped: &AtomicU64,
) -> Vec<PathBuf> {
    let mut ring = Ring::new(capacity);
    let mut written = Vec::new();
    let mut trigger_dumps = 0usize;
    let mut pending: Option<(u64, &'static str)> = None;
    let mut last_dump_cycle: Option<u64> = None;
    let mut prev_mode = Mode::Init;
    let dump = |ring: &Ring, reason: &str, header: &mut Header, written: &mut Vec<PathBuf>| {
        let Some(last) = ring.last_cycle() else {
            return;
        };
        header.reason = reason.to_string();
        header.dropped = dropped.load(Ordering::Relaxed);
        let path = dir.join(format!("blackbox-{reason}-cycle{last}.csv"));
        match write_records(&path, header, ring.in_order()) {
            Ok(()) => {
                tracing::info!(target: "blackbox", "black box ({reason}) written to {}", path.display());
                written.push(path);
            }
            Err(e) => tracing::warn!(target: "blackbox", "cannot write the black box: {e}"),
        }
    };
    loop {
        let stopping = stop.load(Ordering::Acquire);
        while let Ok(r) = rx.pop() {
            let failsafe = r.mode == Mode::FailSafe;
            let entered_failsafe = failsafe && prev_mode != r.mode;
            prev_mode = r.mode;
            let quiet = last_dump_cycle.is_none_or(|c| r.cycle >= c + capacity as u64);
            if pending.is_none() && trigger_dumps < MAX_TRIGGER_DUMPS && quiet {
                if entered_failsafe {
                    pending = Some((r.cycle + POST_TRIGGER_CYCLES, "fail_safe"));
                } else if r.surge_started {
                    pending = Some((r.cycle + POST_TRIGGER_CYCLES, "surge"));
                }
            }
            ring.push(&r);
            if let Some((at, reason)) = pending {
                if r.cycle >= at {
                    dump(&ring, reason, &mut header, &mut written);
                    trigger_dumps += 1;
                    last_dump_cycle = Some(r.cycle);
                    pending = None;
                }
            }
        }
        if stopping {
            if let Some((_, reason)) = pending {
                dump(&ring, reason, &mut header, &mut written);
            }
            dump(&ring, "exit", &mut header, &mut written);
            return written;
        }
        std::thread::sleep(std::time::Duration::from_secs_f64(DRAIN_PERIOD_S));
    }
}

/// The sender clocks of a record read back: the cycle's ([`RawSensors::sender_clock_s`]) on
/// each cycle input, which is all the core reads of them, so a replay integrates over the
/// same intervals as the live cycle did.
fn cycle_clocks(sender_clock_s: f64) -> [f64; SensorId::COUNT] {
    let mut c = [f64::NAN; SensorId::COUNT];
    for id in crate::vocab::signals::CYCLE_INPUTS {
        c[id.index()] = sender_clock_s;
    }
    c
}

/// The sample numbers of a record read back: those of the cycle inputs, which is all the core
/// reads of them (0, unnumbered, for the others), so a replay holds the same cycles as the
/// live core did.
fn cycle_seqs(cycle_seq: [u64; CYCLE_INPUTS.len()]) -> [u64; SensorId::COUNT] {
    let mut q = [0u64; SensorId::COUNT];
    for (id, n) in CYCLE_INPUTS.into_iter().zip(cycle_seq) {
        q[id.index()] = n;
    }
    q
}

/// CSV columns of a record (after the header line).
pub fn columns() -> Vec<String> {
    let mut c: Vec<String> = ["cycle", "deadline_ns", "wake_ns", "t_s"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    for id in SensorId::ALL {
        c.push(format!("in_{}", id.name()));
    }
    for id in SensorId::ALL {
        c.push(format!("age_s_{}", id.name()));
    }
    c.push("sender_clock_s".into());
    for id in CYCLE_INPUTS {
        c.push(format!("seq_{}", id.name()));
    }
    // redundant transmitters b and c of the measurements that can take a vote, and the vote
    for id in crate::control::vote::VOTABLE {
        for t in ["b", "c"] {
            c.push(format!("in_{}_{t}", id.name()));
            c.push(format!("age_s_{}_{t}", id.name()));
        }
        c.push(format!("vote_{}", id.name()));
    }
    for k in [
        "op_speed_setpoint_rad_s",
        "op_throttle_demand",
        "op_flow_setpoint_kg_s",
        "op_recycle_manual",
    ] {
        c.push(k.into());
    }
    for id in ActuatorId::ALL {
        c.push(format!("cmd_{}", id.name()));
    }
    for k in [
        "mode",
        "law",
        "law_diagnostic",
        "law_torque_nm",
        "m_used_kg_s",
        "m_observer_kg_s",
        "flow_fallback",
        "surge_started",
        "updates_applied",
    ] {
        c.push(k.into());
    }
    c
}

fn write_row(w: &mut impl Write, r: &CycleRecord) -> std::io::Result<()> {
    write!(w, "{},{},{},{}", r.cycle, r.deadline_ns, r.wake_ns, r.t_s)?;
    for v in r.raw.values.values {
        write!(w, ",{v}")?;
    }
    for v in r.raw.age_s {
        write!(w, ",{v}")?;
    }
    write!(w, ",{}", r.raw.sender_clock_s())?;
    for id in CYCLE_INPUTS {
        write!(w, ",{}", r.raw.sample_seq[id.index()])?;
    }
    for (k, id) in crate::control::vote::VOTABLE.into_iter().enumerate() {
        for slot in 1..=2 {
            let (v, age) = r.raw.spare.get(id, slot);
            write!(w, ",{v},{age}")?;
        }
        write!(w, ",{}", r.voted[k])?;
    }
    let o = &r.op;
    write!(
        w,
        ",{},{},{},{}",
        o.speed_setpoint_rad_s, o.throttle_demand, o.flow_setpoint_kg_s, o.recycle_manual
    )?;
    for v in r.commands.values {
        write!(w, ",{v}")?;
    }
    writeln!(
        w,
        ",{},{},{},{},{},{},{},{},{}",
        r.mode.code(),
        r.law,
        r.law_diagnostic,
        r.law_torque_nm,
        r.m_used_kg_s,
        r.m_observer_kg_s,
        u8::from(r.flow_fallback),
        u8::from(r.surge_started),
        r.updates_applied
    )
}

/// Write a black-box file.
pub fn write_file<'a>(
    path: &Path,
    header: &Header,
    records: impl Iterator<Item = &'a CycleRecord>,
) -> Result<(), BlackBoxError> {
    write_records(path, header, records.copied())
}

fn write_records(
    path: &Path,
    header: &Header,
    records: impl Iterator<Item = CycleRecord>,
) -> Result<(), BlackBoxError> {
    let io = |source| BlackBoxError::Io {
        path: path.to_path_buf(),
        source,
    };
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d).map_err(io)?;
    }
    let f = std::fs::File::create(path).map_err(io)?;
    let mut w = std::io::BufWriter::new(f);
    let json = serde_json::to_string(header).map_err(|e| io(std::io::Error::other(e)))?;
    writeln!(w, "{MAGIC}{json}").map_err(io)?;
    writeln!(w, "{}", columns().join(",")).map_err(io)?;
    for r in records {
        write_row(&mut w, &r).map_err(io)?;
    }
    w.flush().map_err(io)
}

/// A black-box file read back.
#[derive(Debug, Clone)]
pub struct Recording {
    /// Header.
    pub header: Header,
    /// Records, oldest first.
    pub records: Vec<CycleRecord>,
}

/// Read a black-box file.
pub fn read_file(path: &Path) -> Result<Recording, BlackBoxError> {
    let f = std::fs::File::open(path).map_err(|source| BlackBoxError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let fmt = |line: usize, message: String| BlackBoxError::Format {
        path: path.to_path_buf(),
        line,
        message,
    };
    let mut lines = std::io::BufReader::new(f).lines();
    let first = lines
        .next()
        .ok_or_else(|| fmt(1, "empty file".into()))?
        .map_err(|e| fmt(1, e.to_string()))?;
    let json = first.strip_prefix(MAGIC).ok_or_else(|| {
        fmt(
            1,
            format!("not a black-box file (expected `{}`)", MAGIC.trim()),
        )
    })?;
    let header: Header = serde_json::from_str(json).map_err(|e| fmt(1, format!("header: {e}")))?;
    let cols = columns();
    let second = lines
        .next()
        .ok_or_else(|| fmt(2, "no column line".into()))?
        .map_err(|e| fmt(2, e.to_string()))?;
    if second != cols.join(",") {
        return Err(fmt(
            2,
            "the columns differ from this version's (written by another antisurge version?)".into(),
        ));
    }
    let mut records = Vec::new();
    for (i, line) in lines.enumerate() {
        let n = i + 3;
        let line = line.map_err(|e| fmt(n, e.to_string()))?;
        if line.is_empty() {
            continue;
        }
        records.push(parse_row(&line, cols.len()).map_err(|m| fmt(n, m))?);
    }
    Ok(Recording { header, records })
}

fn parse_row(line: &str, n_cols: usize) -> Result<CycleRecord, String> {
    let f: Vec<&str> = line.split(',').collect();
    if f.len() != n_cols {
        return Err(format!("{} fields, expected {n_cols}", f.len()));
    }
    let mut it = f.into_iter();
    let mut next = || it.next().unwrap_or("");
    let u = |s: &str| s.parse::<u64>().map_err(|e| format!("`{s}`: {e}"));
    let x = |s: &str| s.parse::<f64>().map_err(|e| format!("`{s}`: {e}"));
    let cycle = u(next())?;
    let deadline_ns = u(next())?;
    let wake_ns = u(next())?;
    let t_s = x(next())?;
    let mut values = SensorSnapshot::default();
    for v in values.values.iter_mut() {
        *v = x(next())?;
    }
    let mut age_s = [0.0; SensorId::COUNT];
    for v in age_s.iter_mut() {
        *v = x(next())?;
    }
    let sample_clock_s = cycle_clocks(x(next())?);
    let mut cycle_seq = [0u64; CYCLE_INPUTS.len()];
    for n in cycle_seq.iter_mut() {
        *n = u(next())?;
    }
    let sample_seq = cycle_seqs(cycle_seq);
    let mut spare = crate::control::measurements::SpareReadings::NONE;
    let mut voted = [f64::NAN; crate::control::vote::VOTABLE.len()];
    for (k, id) in crate::control::vote::VOTABLE.into_iter().enumerate() {
        for slot in 1..=2 {
            let v = x(next())?;
            let age = x(next())?;
            spare.set(id, slot, v, age);
        }
        voted[k] = x(next())?;
    }
    let op = OperatorInputs {
        speed_setpoint_rad_s: x(next())?,
        throttle_demand: x(next())?,
        flow_setpoint_kg_s: x(next())?,
        recycle_manual: x(next())?,
    };
    let mut commands = ActuatorCommands::default();
    for v in commands.values.iter_mut() {
        *v = x(next())?;
    }
    let small = |s: &str| s.parse::<u8>().map_err(|e| format!("`{s}`: {e}"));
    Ok(CycleRecord {
        cycle,
        deadline_ns,
        wake_ns,
        t_s,
        raw: RawSensors {
            values,
            age_s,
            spare,
            sample_clock_s,
            sample_seq,
        },
        op,
        commands,
        mode: {
            let code = small(next())?;
            Mode::from_code(code).ok_or_else(|| format!("`{code}`: no such mode"))?
        },
        law: small(next())?,
        law_diagnostic: x(next())?,
        law_torque_nm: x(next())?,
        m_used_kg_s: x(next())?,
        m_observer_kg_s: x(next())?,
        flow_fallback: small(next())? != 0,
        surge_started: small(next())? != 0,
        updates_applied: u(next())?,
        voted,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(k: u64) -> CycleRecord {
        let mut raw = RawSensors::missing();
        raw.values.values[0] = 101_325.123_456_79 + k as f64 * 1e-7;
        raw.values.values[1] = -0.0;
        raw.age_s[0] = 1.0 / 3.0;
        raw.sample_seq[CYCLE_INPUTS[1].index()] = 3 * k + 1;
        let mut commands = ActuatorCommands::default();
        commands.values[0] = std::f64::consts::PI * k as f64;
        CycleRecord {
            cycle: k,
            deadline_ns: 1_000_000 * k,
            wake_ns: 1_000_000 * k + 12_345,
            t_s: 1e-3 * k as f64 + 1.234_5e-5,
            raw,
            op: OperatorInputs {
                speed_setpoint_rad_s: 2513.3,
                throttle_demand: f64::NAN,
                flow_setpoint_kg_s: f64::NAN,
                recycle_manual: 0.0,
            },
            commands,
            mode: Mode::Auto,
            law: 1,
            law_diagnostic: f64::NAN,
            law_torque_nm: -3.5e-310, // subnormal
            m_used_kg_s: 8.8,
            m_observer_kg_s: f64::INFINITY,
            flow_fallback: k.is_multiple_of(2),
            surge_started: false,
            updates_applied: 0,
            voted: [f64::NAN, 1.5, f64::NAN, 0.25 + k as f64],
        }
    }

    fn header() -> Header {
        Header {
            version: "test".into(),
            config: "x.toml".into(),
            law: "recycle-pi".into(),
            auto: true,
            initial_torque_nm: 400.0,
            period_ns: 1_000_000,
            controller: ControllerConfig::default(),
            reason: String::new(),
            dropped: 0,
        }
    }

    fn same_bits(a: &CycleRecord, b: &CycleRecord) -> bool {
        let bits = |r: &CycleRecord| {
            let mut v: Vec<u64> = vec![r.cycle, r.deadline_ns, r.wake_ns, r.t_s.to_bits()];
            v.extend(r.raw.values.values.iter().map(|x| x.to_bits()));
            v.extend(r.raw.age_s.iter().map(|x| x.to_bits()));
            v.extend(r.raw.sample_seq);
            v.extend(r.commands.values.iter().map(|x| x.to_bits()));
            v.push(r.law_torque_nm.to_bits());
            v
        };
        bits(a) == bits(b)
    }

    #[test]
    fn a_file_round_trips_bit_for_bit() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("bb.csv");
        let recs: Vec<CycleRecord> = (0..50).map(record).collect();
        write_file(&path, &header(), recs.iter()).expect("write");
        let back = read_file(&path).expect("read");
        assert_eq!(back.header, header());
        assert_eq!(back.records.len(), 50);
        for (a, b) in recs.iter().zip(&back.records) {
            // NaN != NaN, so compare bits of everything that is not NaN by construction
            assert!(same_bits(a, b), "{a:?}\n{b:?}");
            assert_eq!(a.flow_fallback, b.flow_fallback);
        }
    }

    #[test]
    fn ring_keeps_the_last_records_in_order() {
        let mut ring = Ring::new(4);
        for k in 0..10 {
            ring.push(&record(k));
        }
        assert_eq!(ring.last_cycle(), Some(9));
        let cycles: Vec<u64> = ring.in_order().map(|r| r.cycle).collect();
        assert_eq!(cycles, vec![6, 7, 8, 9]);
    }

    /// A record of a controller without redundant transmitters: no spare, no vote.
    fn plain(k: u64) -> CycleRecord {
        let mut r = record(k);
        r.voted = [f64::NAN; crate::control::vote::VOTABLE.len()];
        r
    }

    /// A record with the spare transmitters of the votable measurements set.
    fn with_spares(k: u64) -> CycleRecord {
        let mut r = record(k);
        for (n, id) in crate::control::vote::VOTABLE.into_iter().enumerate() {
            r.raw
                .spare
                .set(id, 1, 1e5 + k as f64 + n as f64, 1e-3 * n as f64);
        }
        r
    }

    #[test]
    fn the_ring_writes_the_file_the_records_make() {
        // records without spares, then with: the ring keeps the spares' part only from the
        // first record that has one, and the file is byte for byte the one the records make
        let recs: Vec<CycleRecord> = (0..30)
            .map(|k| if k < 12 { plain(k) } else { with_spares(k) })
            .collect();
        for cap in [8, 20, 50] {
            let mut ring = Ring::new(cap);
            for r in &recs[..11] {
                ring.push(r);
            }
            assert!(ring.spares.is_none(), "no spare seen yet: none kept");
            for r in &recs[11..] {
                ring.push(r);
            }
            assert!(ring.spares.is_some());
            let dir = tempfile::tempdir().expect("tmp");
            let (a, b) = (dir.path().join("a.csv"), dir.path().join("b.csv"));
            write_records(&a, &header(), ring.in_order()).expect("write");
            let tail = &recs[recs.len().saturating_sub(cap)..];
            write_file(&b, &header(), tail.iter()).expect("write");
            let (a, b) = (std::fs::read(&a).expect("a"), std::fs::read(&b).expect("b"));
            assert_eq!(a, b, "capacity {cap}");
        }
        // and the part of a record without spares is what the file says for none
        assert!(!Spares::of(&plain(1)).any());
        assert!(Spares::of(&with_spares(1)).any());
        assert!(Spares::of(&record(1)).any(), "a vote alone is kept");
        let mut voted_only = plain(1);
        voted_only.voted[2] = 3.0;
        assert!(Spares::of(&voted_only).any());
    }

    #[test]
    fn the_ring_keeps_the_documented_bytes_a_cycle() {
        // HISTORY_S and DEFAULT_CAPACITY's documentation (and the memory figures in docs/benchmarks.md)
        assert_eq!(std::mem::size_of::<Kept>(), 344);
        assert_eq!(std::mem::size_of::<Spares>(), 160);
    }

    #[test]
    fn the_ring_spans_its_history_in_seconds() {
        assert_eq!(history_capacity(1_000_000), DEFAULT_CAPACITY);
        assert_eq!(history_capacity(1_000_000) as f64 * 1e-3, HISTORY_S);
        assert_eq!(history_capacity(2_000_000), 5_000);
        assert_eq!(history_capacity(250_000), 40_000);
    }

    #[test]
    fn the_handoff_queue_absorbs_the_documented_stall() {
        // the recorder drains every DRAIN_PERIOD_S; while it stalls TOLERATED_STALL_S (a dump,
        // descheduling) on top, the loop keeps pushing: nothing may be dropped. Pushed here
        // with no reader at all, at the loop rates the config allows around the default.
        for period_ns in [100_000u64, 250_000, 1_000_000, 2_000_000, 10_000_000] {
            let (mut tx, _rx) = handoff(period_ns);
            let produced =
                ((DRAIN_PERIOD_S + TOLERATED_STALL_S) / (period_ns as f64 * 1e-9)).ceil() as u64;
            for k in 0..produced {
                tx.push(record(k));
            }
            assert_eq!(
                tx.dropped.load(Ordering::Relaxed),
                0,
                "period {period_ns} ns: {produced} records in a drain period and the stall"
            );
            // beyond it, records are dropped and counted, never waited for
            let room = tx.tx.slots() as u64;
            for k in 0..room + 3 {
                tx.push(record(produced + k));
            }
            assert_eq!(tx.dropped.load(Ordering::Relaxed), 3);
        }
        // at 1 kHz: about a second, not the 4 s (2.7 MB) of the old fixed 4 096 records
        assert_eq!(handoff_capacity(1_000_000), 1_020);
    }

    #[test]
    fn recorder_writes_on_fail_safe_and_at_exit() {
        let dir = tempfile::tempdir().expect("tmp");
        let (mut tx, rec) =
            Recorder::start(dir.path().to_path_buf(), header(), 100).expect("start");
        for k in 0..3000 {
            let mut r = record(k);
            r.mode = if k >= 500 { Mode::FailSafe } else { Mode::Auto };
            tx.push(r);
            if k % 1000 == 999 {
                std::thread::sleep(std::time::Duration::from_millis(60));
            }
        }
        std::thread::sleep(std::time::Duration::from_millis(60));
        let files = rec.finish();
        let names: Vec<String> = files
            .iter()
            .map(|p| {
                p.file_name()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned()
            })
            .collect();
        assert_eq!(
            names,
            vec![
                "blackbox-fail_safe-cycle2500.csv",
                "blackbox-exit-cycle2999.csv"
            ],
            "{names:?}"
        );
        let r = read_file(&files[0]).expect("read");
        assert_eq!(r.header.reason, "fail_safe");
        assert_eq!(r.records.len(), 100);
        assert_eq!(r.records.last().map(|r| r.cycle), Some(2500));
    }
}
