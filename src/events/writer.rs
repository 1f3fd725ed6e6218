//! The writer thread: the only owner of the log file.
//!
//! It drains the non-real-time channel (full [`Event`]s from the config task, start/stop …)
//! and every real-time ring ([`RtSender`]), orders each batch by event time, and appends one
//! JSON line per event with a single `write_all` on a file opened with `O_APPEND`. A crash of
//! the process therefore loses nothing already handed to the kernel and can tear at most
//! the line being written; [`FsyncPolicy`] decides what also survives a power cut.
//!
//! On start the writer terminates a torn final line left by a crash (so the next line cannot
//! be glued to it), resumes `seq` after the last valid line of the rotated set, and logs a
//! `note` about the repair. Before a line would push the file past `max_bytes` it rotates:
//! sync, shift `events.jsonl.N` → `.N+1`, rename the live file to `.1`, open a new one, sync
//! the directory.

use std::fs::{self, File, OpenOptions};
use std::io::{ErrorKind, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender, SyncSender, TryRecvError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::config::{EventLogConfig, FsyncPolicy};
use super::error::EventLogError;
use super::event::{DropCause, Event, LineOut};
use super::reader::{existing_log_files, last_valid_seq, rotated_path};
use super::rt_channel::{rt_channel, RtReceiver, RtSender};
use super::timestamp::Timestamp;

/// Longest line the writer emits, newline included. Longer events are split (lists) or have
/// their text fields clipped, so every line stays one small `write`.
pub const MAX_LINE_BYTES: usize = 4096;
/// Text fields are clipped to this many bytes when a line is too long.
const CLIPPED_FIELD_BYTES: usize = 512;
/// At most this many non-real-time messages are taken per batch.
const MAX_BATCH: usize = 4096;
/// While the file cannot be written (unwritable directory, disk full, file-size limit), the
/// writer tries to reopen it this often even when no event comes.
pub const REOPEN_RETRY: Duration = Duration::from_secs(2);

enum Msg {
    Event(Timestamp, Event),
    AddRt(RtReceiver),
    Flush(SyncSender<Result<(), EventLogError>>),
    Shutdown,
}

/// Counters of one writer run, returned by [`EventLog::shutdown`].
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct WriterStats {
    /// `seq` of the first line this run wrote (resumed from the existing log).
    pub first_seq: u64,
    /// `seq` the next line would get.
    pub next_seq: u64,
    /// Lines appended.
    pub lines_written: u64,
    /// Bytes appended (newlines included).
    pub bytes_written: u64,
    /// Rotations performed.
    pub rotations: u64,
    /// `fdatasync` calls on the log file.
    pub syncs: u64,
    /// Failed writes, syncs or rotations.
    pub write_errors: u64,
    /// Real-time events dropped because a ring was full.
    pub rt_dropped: u64,
    /// Whether a torn final line from a previous run was terminated at start.
    pub repaired_torn_tail: bool,
}

/// Handle to a running event log: the writer thread plus the means to feed it.
///
/// Dropping it stops the writer cleanly (drain, sync, join); [`shutdown`](Self::shutdown)
/// does the same and reports.
pub struct EventLog {
    tx: Sender<Msg>,
    thread: Option<JoinHandle<WriterStats>>,
    path: Arc<Path>,
    rt_capacity: usize,
    first_seq: u64,
    writable: Arc<AtomicBool>,
}

/// Cloneable sender for non-real-time producers (config reload task, start/stop, CLI).
/// `send` never blocks (the channel is unbounded) but it allocates: not for the control loop.
#[derive(Clone)]
pub struct EventSender {
    tx: Sender<Msg>,
    path: Arc<Path>,
}

impl EventSender {
    /// Log `event`, stamped now.
    pub fn send(&self, event: Event) -> Result<(), EventLogError> {
        self.send_at(Timestamp::now(), event)
    }

    /// Log `event` with the time it happened.
    pub fn send_at(&self, ts: Timestamp, event: Event) -> Result<(), EventLogError> {
        self.tx
            .send(Msg::Event(ts, event))
            .map_err(|_| EventLogError::Closed {
                path: self.path.to_path_buf(),
            })
    }
}

impl EventLog {
    /// Open (or create) the log, repair a torn tail, resume `seq`, and start the writer
    /// thread. Errors here are the ones worth refusing to start over: the file cannot be
    /// opened, the configuration is invalid.
    pub fn start(config: EventLogConfig) -> Result<EventLog, EventLogError> {
        config.validate()?;
        let path: Arc<Path> = Arc::from(config.path.as_path());
        let dir = parent_dir(&path);
        fs::create_dir_all(&dir).map_err(|e| EventLogError::io(&dir, "create directory", e))?;
        let (file, size, torn) = open_live(&path)?;
        sync_dir(&dir)?;
        let next_seq = resume_seq(&path)?;
        Self::spawn(config, path, dir, Some((file, size, torn)), next_seq)
    }

    /// Like [`start`](Self::start), but a log that cannot be opened (unwritable directory,
    /// disk full, file-size limit) does not stop the caller: the writer runs degraded, counts
    /// the events it loses, retries every [`REOPEN_RETRY`] and resumes (with an
    /// `events_dropped` line) once the file can be written. The audit log is never a start
    /// dependency of the protection. Returns the open error, if any, for the journal; only an
    /// invalid configuration or a failed thread start is an `Err`.
    pub fn start_degraded_ok(
        config: EventLogConfig,
    ) -> Result<(EventLog, Option<EventLogError>), EventLogError> {
        config.validate()?;
        let path: Arc<Path> = Arc::from(config.path.as_path());
        let dir = parent_dir(&path);
        let opened = fs::create_dir_all(&dir)
            .map_err(|e| EventLogError::io(&dir, "create directory", e))
            .and_then(|()| open_live(&path))
            .and_then(|o| sync_dir(&dir).map(|()| o))
            .and_then(|o| resume_seq(&path).map(|seq| (o, seq)));
        match opened {
            Ok((o, seq)) => Ok((Self::spawn(config, path, dir, Some(o), seq)?, None)),
            Err(e) => Ok((Self::spawn(config, path, dir, None, 1)?, Some(e))),
        }
    }

    /// Is the log file currently writable (false while degraded)?
    pub fn writable(&self) -> bool {
        self.writable.load(Ordering::Relaxed)
    }

    fn spawn(
        config: EventLogConfig,
        path: Arc<Path>,
        dir: PathBuf,
        opened: Option<(File, u64, Option<TornRepair>)>,
        next_seq: u64,
    ) -> Result<EventLog, EventLogError> {
        let degraded = opened.is_none();
        let (file, size, torn) = match opened {
            Some((f, size, torn)) => (Some(f), size, torn),
            None => (None, 0, None),
        };
        let writable = Arc::new(AtomicBool::new(!degraded));

        let (tx, rx) = mpsc::channel();
        if let Some(t) = &torn {
            // Goes through the channel like any event, so it gets the next seq.
            let text = format!(
                "previous writer stopped mid-line: {} byte(s) at offset {} of {} were left as an incomplete line and terminated",
                t.bytes,
                t.offset,
                path.display()
            );
            // The receiver is alive: it is still in this function.
            let _ = tx.send(Msg::Event(Timestamp::now(), Event::Note { text }));
        }
        let writer = Writer {
            path: path.to_path_buf(),
            dir,
            fsync: config.fsync,
            max_bytes: config.max_bytes,
            keep_files: config.keep_files,
            poll: config.poll_interval(),
            file,
            size,
            next_seq,
            rings: Vec::new(),
            batch: Vec::new(),
            line: Vec::with_capacity(MAX_LINE_BYTES),
            dirty: false,
            last_sync: Instant::now(),
            lost_to_errors: 0,
            failing: degraded,
            seq_unknown: degraded,
            last_reopen: Instant::now(),
            writable: Arc::clone(&writable),
            stats: WriterStats {
                first_seq: next_seq,
                next_seq,
                repaired_torn_tail: torn.is_some(),
                ..WriterStats::default()
            },
        };
        let thread = std::thread::Builder::new()
            .name("event-log".into())
            .stack_size(crate::runtime::rt_loop::SMALL_THREAD_STACK_BYTES)
            .spawn(move || writer.run(rx))
            .map_err(|e| EventLogError::io(path.to_path_buf(), "start writer thread", e))?;
        Ok(EventLog {
            tx,
            thread: Some(thread),
            path,
            rt_capacity: config.rt_queue_capacity,
            first_seq: next_seq,
            writable,
        })
    }

    /// The live log file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// `seq` of the first line this writer writes (last valid `seq` found at start + 1).
    pub fn first_seq(&self) -> u64 {
        self.first_seq
    }

    /// A sender for non-real-time producers.
    pub fn sender(&self) -> EventSender {
        EventSender {
            tx: self.tx.clone(),
            path: Arc::clone(&self.path),
        }
    }

    /// Log one event from a non-real-time context, stamped now.
    pub fn send(&self, event: Event) -> Result<(), EventLogError> {
        self.sender().send(event)
    }

    /// A new real-time ring (capacity from the configuration) for one producer thread.
    /// Call it during setup: it allocates; the returned sender never does.
    pub fn rt_sender(&self) -> Result<RtSender, EventLogError> {
        self.rt_sender_with_capacity(self.rt_capacity)
    }

    /// Like [`rt_sender`](Self::rt_sender) with an explicit capacity (events).
    pub fn rt_sender_with_capacity(&self, capacity: usize) -> Result<RtSender, EventLogError> {
        let (tx, rx) = rt_channel(capacity);
        self.tx.send(Msg::AddRt(rx)).map_err(|_| self.closed())?;
        Ok(tx)
    }

    /// Write everything queued so far (both channels) and `fdatasync` the file, whatever
    /// the policy. Blocks until done.
    pub fn flush(&self) -> Result<(), EventLogError> {
        let (ack_tx, ack_rx) = mpsc::sync_channel(1);
        self.tx
            .send(Msg::Flush(ack_tx))
            .map_err(|_| self.closed())?;
        ack_rx.recv().map_err(|_| self.closed())?
    }

    /// Drain, sync and stop the writer thread; returns its counters.
    pub fn shutdown(mut self) -> Result<WriterStats, EventLogError> {
        self.stop()
    }

    fn stop(&mut self) -> Result<WriterStats, EventLogError> {
        let Some(thread) = self.thread.take() else {
            return Err(self.closed());
        };
        let _ = self.tx.send(Msg::Shutdown);
        thread.join().map_err(|_| EventLogError::WriterPanicked {
            path: self.path.to_path_buf(),
        })
    }

    fn closed(&self) -> EventLogError {
        EventLogError::Closed {
            path: self.path.to_path_buf(),
        }
    }
}

impl Drop for EventLog {
    fn drop(&mut self) {
        if self.thread.is_some() {
            let _ = self.stop();
        }
    }
}

/// A torn final line found (and terminated) when opening.
struct TornRepair {
    offset: u64,
    bytes: u64,
}

/// `seq` after the last valid line of the rotated set (1 for a new log).
fn resume_seq(path: &Path) -> Result<u64, EventLogError> {
    for f in existing_log_files(path)?.iter().rev() {
        if let Some(seq) = last_valid_seq(f)? {
            return Ok(seq.saturating_add(1));
        }
    }
    Ok(1)
}

fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

fn sync_dir(dir: &Path) -> Result<(), EventLogError> {
    File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(|e| EventLogError::io(dir, "sync directory", e))
}

/// Open the live file for appending (creating it), and if its last byte is not a newline,
/// append one so the torn line stays a separate (invalid) line instead of swallowing the
/// next record.
fn open_live(path: &Path) -> Result<(File, u64, Option<TornRepair>), EventLogError> {
    let file = OpenOptions::new()
        .read(true)
        .append(true)
        .create(true)
        .open(path)
        .map_err(|e| EventLogError::io(path, "open for appending", e))?;
    let mut size = file
        .metadata()
        .map_err(|e| EventLogError::io(path, "stat", e))?
        .len();
    let mut torn = None;
    if size > 0 {
        let mut last = [0u8; 1];
        file.read_exact_at(&mut last, size - 1)
            .map_err(|e| EventLogError::io(path, "read", e))?;
        if last[0] != b'\n' {
            let start = size.saturating_sub(MAX_LINE_BYTES as u64 * 16);
            let mut tail = vec![0u8; (size - start) as usize];
            file.read_exact_at(&mut tail, start)
                .map_err(|e| EventLogError::io(path, "read", e))?;
            let line_start = match tail.iter().rposition(|&b| b == b'\n') {
                Some(i) => start + i as u64 + 1,
                None => start,
            };
            (&file)
                .write_all(b"\n")
                .map_err(|e| EventLogError::io(path, "terminate torn line", e))?;
            torn = Some(TornRepair {
                offset: line_start,
                bytes: size - line_start,
            });
            size += 1;
        }
    }
    Ok((file, size, torn))
}

struct Writer {
    path: PathBuf,
    dir: PathBuf,
    fsync: FsyncPolicy,
    max_bytes: u64,
    keep_files: u32,
    poll: Duration,
    /// `None` after an I/O error: reopened (and repaired) before the next line.
    file: Option<File>,
    size: u64,
    next_seq: u64,
    rings: Vec<RtReceiver>,
    batch: Vec<(Timestamp, Event)>,
    line: Vec<u8>,
    /// Written since the last sync.
    dirty: bool,
    last_sync: Instant,
    /// Events lost to write errors, reported once writing works again.
    lost_to_errors: u64,
    /// In a streak of errors (log the first only).
    failing: bool,
    /// Started degraded: `seq` is resumed from the existing files once they can be read.
    seq_unknown: bool,
    /// Last reopen attempt while no file is open.
    last_reopen: Instant,
    /// Shared with [`EventLog::writable`].
    writable: Arc<AtomicBool>,
    stats: WriterStats,
}

impl Writer {
    fn run(mut self, rx: Receiver<Msg>) -> WriterStats {
        loop {
            let mut control = None;
            match rx.recv_timeout(self.wait_time()) {
                Ok(m) => self.accept(m, &mut control),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
            let mut taken = 0;
            while control.is_none() && taken < MAX_BATCH {
                match rx.try_recv() {
                    Ok(m) => self.accept(m, &mut control),
                    Err(_) => break,
                }
                taken += 1;
            }
            if self.file.is_none() && self.last_reopen.elapsed() >= REOPEN_RETRY {
                // degraded: retry even when nothing is logged, so the status clears
                self.last_reopen = Instant::now();
                if self.ensure_open() {
                    let text =
                        format!("the event log {} can be written again", self.path.display());
                    self.batch.push((Timestamp::now(), Event::Note { text }));
                }
            }
            self.write_pending();
            match control {
                Some(Msg::Flush(ack)) => {
                    let r = self.sync();
                    let _ = ack.send(r);
                }
                Some(Msg::Shutdown) => break,
                _ => self.sync_if_due(),
            }
        }
        // Clean stop: take what is still queued, write, sync.
        loop {
            let mut control = None;
            match rx.try_recv() {
                Ok(m) => self.accept(m, &mut control),
                Err(TryRecvError::Empty | TryRecvError::Disconnected) => break,
            }
            if let Some(Msg::Flush(ack)) = control {
                self.write_pending();
                let _ = ack.send(self.sync());
            }
        }
        self.write_pending();
        if let Err(e) = self.sync() {
            tracing::error!("{e}");
        }
        self.stats.next_seq = self.next_seq;
        self.stats
    }

    fn accept(&mut self, m: Msg, control: &mut Option<Msg>) {
        match m {
            Msg::Event(ts, e) => self.batch.push((ts, e)),
            Msg::AddRt(r) => self.rings.push(r),
            other => *control = Some(other),
        }
    }

    /// How long to wait for a message: the poll period, or less if a sync falls due.
    fn wait_time(&self) -> Duration {
        if self.file.is_none() {
            return self.poll.min(REOPEN_RETRY);
        }
        match self.fsync {
            FsyncPolicy::Interval { interval_ms } if self.dirty => {
                let due = Duration::from_millis(interval_ms);
                due.saturating_sub(self.last_sync.elapsed()).min(self.poll)
            }
            _ => self.poll,
        }
    }

    /// Drain the rings into the batch, sort by event time, write it, then report drops.
    fn write_pending(&mut self) {
        let mut dropped = 0;
        for ring in &mut self.rings {
            dropped += ring.take_dropped();
            while let Some(s) = ring.pop() {
                self.batch.push((s.ts, s.event.into()));
            }
        }
        // Producers that went away and are drained: no more events can come.
        self.rings.retain(|r| !r.is_finished());
        // Stable: equal times keep arrival order.
        self.batch.sort_by_key(|(ts, _)| *ts);
        let mut batch = std::mem::take(&mut self.batch);
        for (ts, event) in batch.drain(..) {
            self.log(ts, &event);
        }
        self.batch = batch;
        if dropped > 0 {
            self.stats.rt_dropped += dropped;
            let ev = Event::EventsDropped {
                count: dropped,
                cause: DropCause::QueueFull,
            };
            self.log(Timestamp::now(), &ev);
        }
    }

    fn log(&mut self, ts: Timestamp, event: &Event) {
        super::journal::record(event);
        if self.lost_to_errors > 0 && self.ensure_open() {
            let notice = Event::EventsDropped {
                count: self.lost_to_errors,
                cause: DropCause::WriteError,
            };
            if self.write_fitted(ts, &notice).is_ok() {
                self.lost_to_errors = 0;
            }
        }
        if self.write_fitted(ts, event).is_err() {
            self.lost_to_errors += 1;
        }
    }

    /// Write `event`, splitting or clipping it first if its line would be too long.
    fn write_fitted(&mut self, ts: Timestamp, event: &Event) -> Result<(), ()> {
        let mut line = std::mem::take(&mut self.line);
        line.clear();
        let fits = self.serialize(&mut line, ts, event) && line.len() < MAX_LINE_BYTES;
        let result = if fits {
            line.push(b'\n');
            self.append(&line)
        } else if let Some((a, b)) = event.split_in_two() {
            let ra = self.write_fitted(ts, &a);
            let rb = self.write_fitted(ts, &b);
            ra.and(rb)
        } else {
            let mut clipped = event.clone();
            let text_clipped = clipped.clip_text(CLIPPED_FIELD_BYTES);
            line.clear();
            if text_clipped
                && self.serialize(&mut line, ts, &clipped)
                && line.len() < MAX_LINE_BYTES
            {
                line.push(b'\n');
                self.append(&line)
            } else {
                let note = Event::Note {
                    text: format!(
                        "a {} event could not be written: its line exceeds {MAX_LINE_BYTES} bytes",
                        event.kind()
                    ),
                };
                line.clear();
                if self.serialize(&mut line, ts, &note) {
                    line.push(b'\n');
                    self.append(&line)
                } else {
                    Err(())
                }
            }
        };
        self.line = line;
        result
    }

    fn serialize(&mut self, out: &mut Vec<u8>, ts: Timestamp, event: &Event) -> bool {
        let rec = LineOut {
            ts,
            seq: self.next_seq,
            event,
        };
        match serde_json::to_writer(&mut *out, &rec) {
            Ok(()) => true,
            Err(e) => {
                tracing::error!("event log: cannot serialize a {} event: {e}", event.kind());
                false
            }
        }
    }

    /// Append one complete line (rotating first if needed).
    fn append(&mut self, line: &[u8]) -> Result<(), ()> {
        if !self.ensure_open() {
            return Err(());
        }
        let len = line.len() as u64;
        if self.size > 0 && self.size + len > self.max_bytes {
            if let Err(e) = self.rotate() {
                self.fail(e);
                return Err(());
            }
        }
        let Some(file) = self.file.as_mut() else {
            return Err(());
        };
        match file.write_all(line) {
            Ok(()) => {
                self.size += len;
                self.next_seq += 1;
                self.dirty = true;
                if self.failing {
                    tracing::warn!(target: "events", "event log {}: writing works again", self.path.display());
                    self.writable.store(true, Ordering::Relaxed);
                }
                self.failing = false;
                self.stats.lines_written += 1;
                self.stats.bytes_written += len;
                if self.fsync == FsyncPolicy::Always {
                    if let Err(e) = self.sync() {
                        self.fail(e);
                    }
                }
                Ok(())
            }
            Err(e) => {
                self.fail(EventLogError::io(&self.path, "append", e));
                Err(())
            }
        }
    }

    /// Make sure a file is open; after an error, reopen and repair a partial line.
    fn ensure_open(&mut self) -> bool {
        if self.file.is_some() {
            return true;
        }
        self.last_reopen = Instant::now();
        match open_live(&self.path) {
            Ok((file, size, _torn)) => {
                if self.seq_unknown {
                    if let Ok(seq) = resume_seq(&self.path) {
                        self.next_seq = self.next_seq.max(seq);
                        self.seq_unknown = false;
                    }
                }
                self.file = Some(file);
                self.size = size;
                true
            }
            Err(e) => {
                self.fail(e);
                false
            }
        }
    }

    fn fail(&mut self, e: EventLogError) {
        self.stats.write_errors += 1;
        if !self.failing {
            tracing::error!("{e}; events are lost until writing works again");
        }
        self.failing = true;
        self.writable.store(false, Ordering::Relaxed);
        self.file = None;
    }

    fn sync(&mut self) -> Result<(), EventLogError> {
        if let Some(file) = &self.file {
            if self.dirty {
                file.sync_data()
                    .map_err(|e| EventLogError::io(&self.path, "sync", e))?;
                self.stats.syncs += 1;
            }
            self.dirty = false;
            self.last_sync = Instant::now();
            Ok(())
        } else if self.ensure_open() {
            Ok(())
        } else {
            Err(EventLogError::Closed {
                path: self.path.clone(),
            })
        }
    }

    fn sync_if_due(&mut self) {
        if let FsyncPolicy::Interval { interval_ms } = self.fsync {
            if self.dirty && self.last_sync.elapsed() >= Duration::from_millis(interval_ms) {
                if let Err(e) = self.sync() {
                    self.fail(e);
                }
            }
        }
    }

    /// events.jsonl → .1 → .2 … (keeping `keep_files`), then a fresh live file.
    fn rotate(&mut self) -> Result<(), EventLogError> {
        if let Some(file) = self.file.take() {
            file.sync_data()
                .map_err(|e| EventLogError::io(&self.path, "sync before rotation", e))?;
            self.stats.syncs += 1;
        }
        if self.keep_files == 0 {
            match fs::remove_file(&self.path) {
                Ok(()) => {}
                Err(e) if e.kind() == ErrorKind::NotFound => {}
                Err(e) => return Err(EventLogError::io(&self.path, "remove for rotation", e)),
            }
        } else {
            for n in (1..self.keep_files).rev() {
                let from = rotated_path(&self.path, n);
                match fs::rename(&from, rotated_path(&self.path, n + 1)) {
                    Ok(()) => {}
                    Err(e) if e.kind() == ErrorKind::NotFound => {}
                    Err(e) => return Err(EventLogError::io(from, "rename for rotation", e)),
                }
            }
            fs::rename(&self.path, rotated_path(&self.path, 1))
                .map_err(|e| EventLogError::io(&self.path, "rename for rotation", e))?;
        }
        let (file, size, _) = open_live(&self.path)?;
        sync_dir(&self.dir)?;
        self.file = Some(file);
        self.size = size;
        self.dirty = false;
        self.last_sync = Instant::now();
        self.stats.rotations += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::event::{ConfigChange, Law, ModeChanged, TripReason};
    use crate::events::reader::{read_log, EventFilter, Record};
    use crate::events::rt_channel::RtEvent;
    use crate::vocab::Mode;

    fn cfg(dir: &Path) -> EventLogConfig {
        EventLogConfig {
            fsync: FsyncPolicy::Never,
            poll_interval_ms: 1,
            ..EventLogConfig::with_path(dir.join("events.jsonl"))
        }
    }

    fn note(text: &str) -> Event {
        Event::Note { text: text.into() }
    }

    fn read(path: &Path) -> (Vec<Record>, crate::events::ReadStats) {
        read_log(path, &EventFilter::default()).expect("read")
    }

    fn texts(records: &[Record]) -> Vec<String> {
        records
            .iter()
            .map(|r| match r.event() {
                Ok(Event::Note { text }) => text,
                other => format!("{other:?}"),
            })
            .collect()
    }

    #[test]
    fn writes_lines_and_resumes_seq_across_restarts() {
        let dir = tempfile::tempdir().expect("tempdir");
        let c = cfg(dir.path());
        let log = EventLog::start(c.clone()).expect("start");
        assert_eq!(log.first_seq(), 1);
        log.send(note("a")).expect("send");
        log.send(note("b")).expect("send");
        let stats = log.shutdown().expect("shutdown");
        assert_eq!(
            (stats.first_seq, stats.next_seq, stats.lines_written),
            (1, 3, 2)
        );

        let log = EventLog::start(c.clone()).expect("restart");
        assert_eq!(log.first_seq(), 3);
        log.send(note("c")).expect("send");
        drop(log); // Drop is a clean stop too.

        let (records, stats) = read(&c.path);
        assert_eq!(records.iter().map(|r| r.seq).collect::<Vec<_>>(), [1, 2, 3]);
        assert_eq!(texts(&records), ["a", "b", "c"]);
        assert!(stats.is_clean(), "{:?}", stats.warnings());
        let raw = fs::read_to_string(&c.path).expect("raw");
        assert!(raw.ends_with('\n'));
        assert_eq!(raw.lines().count(), 3);
    }

    #[test]
    fn torn_tail_is_terminated_noted_and_seq_resumes_after_last_valid() {
        let dir = tempfile::tempdir().expect("tempdir");
        let c = cfg(dir.path());
        let log = EventLog::start(c.clone()).expect("start");
        for i in 0..5 {
            log.send(note(&i.to_string())).expect("send");
        }
        log.shutdown().expect("shutdown");
        // Simulate a crash in the middle of line 6.
        let fragment = r#"{"ts":"2024-05-01T12:00:00.000000Z","seq":6,"ev"#;
        let mut f = OpenOptions::new().append(true).open(&c.path).expect("open");
        f.write_all(fragment.as_bytes()).expect("write");
        drop(f);
        let (_, stats) = read(&c.path);
        assert_eq!(stats.torn_tail.as_ref().map(|t| t.line), Some(6));

        let log = EventLog::start(c.clone()).expect("restart");
        assert_eq!(log.first_seq(), 6, "resume after the last valid line");
        log.send(note("after")).expect("send");
        let ws = log.shutdown().expect("shutdown");
        assert!(ws.repaired_torn_tail);

        let (records, stats) = read(&c.path);
        assert_eq!(
            records.iter().map(|r| r.seq).collect::<Vec<_>>(),
            [1, 2, 3, 4, 5, 6, 7]
        );
        let t = texts(&records);
        assert!(
            t[5].contains("previous writer stopped mid-line"),
            "{}",
            t[5]
        );
        assert!(
            t[5].contains(&format!("{} byte(s)", fragment.len())),
            "{}",
            t[5]
        );
        assert_eq!(t[6], "after");
        assert!(stats.torn_tail.is_none());
        assert_eq!(
            stats.invalid_total, 1,
            "the fragment stays, as an invalid line"
        );
        assert_eq!(stats.invalid[0].line, 6);
        assert_eq!(stats.seq_breaks_total, 0);
    }

    #[test]
    fn rotation_boundaries() {
        let dir = tempfile::tempdir().expect("tempdir");
        let c = EventLogConfig {
            max_bytes: 4096,
            keep_files: 2,
            ..cfg(dir.path())
        };
        let log = EventLog::start(c.clone()).expect("start");
        // Each line is exactly 1024 bytes: 4 fit in 4096, the 5th rotates.
        let ts = Timestamp::parse_rfc3339("2024-05-01T12:00:00Z").expect("ts");
        let probe = serde_json::to_vec(&LineOut {
            ts,
            seq: 1,
            event: &note(""),
        })
        .expect("ser")
        .len()
            + 1;
        let text = "x".repeat(1024 - probe);
        let sender = log.sender();
        for _ in 0..4 {
            sender.send_at(ts, note(&text)).expect("send");
        }
        log.flush().expect("flush");
        assert_eq!(fs::metadata(&c.path).expect("meta").len(), 4096);
        assert!(
            !rotated_path(&c.path, 1).exists(),
            "exactly full: no rotation yet"
        );
        sender.send_at(ts, note(&text)).expect("send");
        log.flush().expect("flush");
        assert_eq!(fs::metadata(&c.path).expect("meta").len(), 1024);
        assert_eq!(
            fs::metadata(rotated_path(&c.path, 1)).expect("meta").len(),
            4096
        );
        // 8 more lines: two more rotations; keep_files = 2 drops the oldest file.
        for _ in 0..8 {
            sender.send_at(ts, note(&text)).expect("send");
        }
        let ws = log.shutdown().expect("shutdown");
        assert_eq!(ws.rotations, 3);
        assert!(!rotated_path(&c.path, 3).exists());
        let (records, stats) = read(&c.path);
        // seq >= 10 lines are one byte longer, so the third rotation comes at seq 12:
        // live: 12, 13; .1: 9..=11; .2: 5..=8; seq 1..=4 rotated away.
        assert_eq!(
            records.iter().map(|r| r.seq).collect::<Vec<_>>(),
            (5..=13).collect::<Vec<_>>()
        );
        assert!(stats.is_clean());
        assert_eq!(stats.files.len(), 3);

        // Restart resumes from the live file.
        let log = EventLog::start(c.clone()).expect("restart");
        assert_eq!(log.first_seq(), 14);
    }

    #[test]
    fn resume_looks_into_rotated_files_when_live_is_empty() {
        let dir = tempfile::tempdir().expect("tempdir");
        let c = cfg(dir.path());
        let log = EventLog::start(c.clone()).expect("start");
        for i in 0..3 {
            log.send(note(&i.to_string())).expect("send");
        }
        log.shutdown().expect("shutdown");
        // A crash right after the rename of a rotation: no live file.
        fs::rename(&c.path, rotated_path(&c.path, 1)).expect("rename");
        let log = EventLog::start(c.clone()).expect("restart");
        assert_eq!(log.first_seq(), 4);
        drop(log);
        // And with an empty live file.
        let log = EventLog::start(c.clone()).expect("restart");
        assert_eq!(log.first_seq(), 4);
    }

    #[test]
    fn keep_zero_discards_on_rotation() {
        let dir = tempfile::tempdir().expect("tempdir");
        let c = EventLogConfig {
            max_bytes: 4096,
            keep_files: 0,
            ..cfg(dir.path())
        };
        let log = EventLog::start(c.clone()).expect("start");
        for _ in 0..100 {
            log.send(note(&"y".repeat(200))).expect("send");
        }
        let ws = log.shutdown().expect("shutdown");
        assert!(ws.rotations > 0);
        assert_eq!(log_dir_names(dir.path()), ["events.jsonl"]);
        let (records, _) = read(&c.path);
        assert_eq!(records.last().map(|r| r.seq), Some(100));
    }

    fn log_dir_names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .expect("dir")
            .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn rt_events_and_drop_reports() {
        let dir = tempfile::tempdir().expect("tempdir");
        let c = cfg(dir.path());
        let log = EventLog::start(c.clone()).expect("start");
        let mut rt = log.rt_sender_with_capacity(4).expect("rt");
        let mut accepted = 0;
        for _ in 0..10 {
            if rt.try_push(ModeChanged {
                from: Mode::Auto,
                to: Mode::Manual,
                cause: None,
            }) {
                accepted += 1;
            }
        }
        let dropped = rt.dropped_total();
        assert_eq!(accepted + dropped, 10);
        log.flush().expect("flush");
        let (records, _) = read(&c.path);
        let kinds: Vec<_> = records.iter().map(|r| r.kind.as_str()).collect();
        assert_eq!(
            kinds.iter().filter(|k| **k == "mode_changed").count() as u64,
            accepted
        );
        if dropped > 0 {
            match records.last().map(|r| r.event()) {
                Some(Ok(Event::EventsDropped { count, cause })) => {
                    assert_eq!(count, dropped);
                    assert_eq!(cause, DropCause::QueueFull);
                }
                other => panic!("expected events_dropped last, got {other:?}"),
            }
        }
        // After the writer stops, the producer sees it.
        assert!(!rt.is_closed());
        drop(log);
        assert!(rt.is_closed());
    }

    #[test]
    fn batch_is_ordered_by_event_time() {
        let dir = tempfile::tempdir().expect("tempdir");
        let c = EventLogConfig {
            poll_interval_ms: 1000,
            ..cfg(dir.path())
        };
        let log = EventLog::start(c.clone()).expect("start");
        let mut rt = log.rt_sender().expect("rt");
        let t = |us| Timestamp::from_unix_micros(us);
        // RT event at t=2 pushed first, non-RT events at t=1 and t=3: one batch on flush.
        assert!(rt.try_push_at(
            t(2),
            RtEvent::RecycleTrip(crate::events::RecycleTrip {
                reason: TripReason::External,
                cause: None,
                criterion: None,
            })
        ));
        let s = log.sender();
        s.send_at(t(3), note("late")).expect("send");
        s.send_at(t(1), note("early")).expect("send");
        log.flush().expect("flush");
        let (records, _) = read(&c.path);
        let kinds: Vec<_> = records.iter().map(|r| r.kind.as_str()).collect();
        assert_eq!(kinds, ["note", "recycle_trip", "note"]);
        assert_eq!(records.iter().map(|r| r.seq).collect::<Vec<_>>(), [1, 2, 3]);
        assert_eq!(texts(&records)[0], "early");
    }

    #[test]
    fn oversized_events_are_split_or_clipped() {
        let dir = tempfile::tempdir().expect("tempdir");
        let c = cfg(dir.path());
        let log = EventLog::start(c.clone()).expect("start");
        let diff: Vec<ConfigChange> = (0..200)
            .map(|i| ConfigChange {
                key: format!("section.key_{i:03}"),
                old: Some(i.to_string()),
                new: Some((i + 1).to_string()),
            })
            .collect();
        log.send(Event::ConfigApplied {
            file: "/etc/antisurge.toml".into(),
            diff: diff.clone(),
        })
        .expect("send");
        log.send(note(&"z".repeat(10_000))).expect("send");
        log.send(Event::started(
            Path::new("/etc/antisurge.toml"),
            Law::RecyclePi,
        ))
        .expect("send");
        log.shutdown().expect("shutdown");

        let raw = fs::read_to_string(&c.path).expect("raw");
        assert!(raw.lines().all(|l| l.len() < MAX_LINE_BYTES));
        let (records, stats) = read(&c.path);
        assert!(stats.is_clean());
        let mut keys = Vec::new();
        let mut parts = 0;
        for r in &records {
            if let Ok(Event::ConfigApplied { diff, .. }) = r.event() {
                parts += 1;
                keys.extend(diff.into_iter().map(|d| d.key));
            }
        }
        assert!(parts >= 2, "diff split over several lines");
        assert_eq!(keys, diff.iter().map(|d| d.key.clone()).collect::<Vec<_>>());
        let n = records.len();
        match records[n - 2].event() {
            Ok(Event::Note { text }) => {
                assert!(text.len() <= CLIPPED_FIELD_BYTES);
                assert!(text.starts_with("zzz") && text.ends_with('…'));
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(records[n - 1].kind, "started");
    }

    #[test]
    fn fsync_policies_count_syncs() {
        for (policy, expect_per_line) in [(FsyncPolicy::Always, true), (FsyncPolicy::Never, false)]
        {
            let dir = tempfile::tempdir().expect("tempdir");
            let c = EventLogConfig {
                fsync: policy,
                ..cfg(dir.path())
            };
            let log = EventLog::start(c).expect("start");
            for i in 0..20 {
                log.send(note(&i.to_string())).expect("send");
            }
            let ws = log.shutdown().expect("shutdown");
            assert_eq!(ws.lines_written, 20);
            if expect_per_line {
                assert!(ws.syncs >= 20, "{ws:?}");
            } else {
                assert_eq!(ws.syncs, 1, "only the shutdown sync: {ws:?}");
            }
        }
        // Interval: a sync happens without any further traffic once the interval passed.
        let dir = tempfile::tempdir().expect("tempdir");
        let c = EventLogConfig {
            fsync: FsyncPolicy::Interval { interval_ms: 20 },
            poll_interval_ms: 1000,
            ..cfg(dir.path())
        };
        let log = EventLog::start(c).expect("start");
        log.send(note("x")).expect("send");
        std::thread::sleep(Duration::from_millis(150));
        let ws = log.shutdown().expect("shutdown");
        assert_eq!(
            ws.syncs, 1,
            "interval sync, and nothing dirty at shutdown: {ws:?}"
        );
    }

    #[test]
    fn start_names_the_path_on_error() {
        let dir = tempfile::tempdir().expect("tempdir");
        let blocker = dir.path().join("file");
        fs::write(&blocker, "").expect("write");
        let c = cfg(&blocker.join("sub")); // parent is a regular file
        match EventLog::start(c) {
            Err(e @ EventLogError::Io { .. }) => {
                assert!(
                    e.to_string().contains(&blocker.display().to_string()),
                    "{e}"
                );
            }
            Err(e) => panic!("unexpected error {e}"),
            Ok(_) => panic!("started under a regular file"),
        }
    }

    #[test]
    fn degraded_start_runs_counts_losses_and_recovers_by_itself() {
        let dir = tempfile::tempdir().expect("tempdir");
        let blocker = dir.path().join("logs");
        fs::write(&blocker, "").expect("write"); // the log directory is a regular file
        let c = cfg(&blocker);
        let path = c.path.clone();
        let (log, err) = EventLog::start_degraded_ok(c).expect("degraded start is not an error");
        assert!(err.is_some());
        assert!(!log.writable());
        log.send(Event::Note {
            text: "lost".into(),
        })
        .expect("send");
        std::thread::sleep(Duration::from_millis(100));
        // the operator fixes the directory; the writer retries without any new event
        fs::remove_file(&blocker).expect("rm");
        fs::create_dir(&blocker).expect("mkdir");
        let t0 = Instant::now();
        while !log.writable() && t0.elapsed() < REOPEN_RETRY * 3 {
            std::thread::sleep(Duration::from_millis(50));
        }
        assert!(
            log.writable(),
            "not writable again after {:?}",
            t0.elapsed()
        );
        log.send(Event::Note {
            text: "kept".into(),
        })
        .expect("send");
        let stats = log.shutdown().expect("shutdown");
        assert!(stats.write_errors >= 1);
        let raw = fs::read_to_string(&path).expect("log");
        assert!(raw.contains("can be written again"), "{raw}");
        assert!(raw.contains("\"events_dropped\""), "{raw}");
        assert!(raw.contains("kept") && !raw.contains("\"lost\""), "{raw}");
    }

    #[test]
    fn sender_reports_closed_writer() {
        let dir = tempfile::tempdir().expect("tempdir");
        let log = EventLog::start(cfg(dir.path())).expect("start");
        let s = log.sender();
        drop(log);
        assert!(matches!(
            s.send(note("x")),
            Err(EventLogError::Closed { .. })
        ));
    }
}
