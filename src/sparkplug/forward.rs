//! Events for the host: the event log followed as it grows (the same file the HMI's event
//! list reads), and the store-and-forward queue that keeps them, bounded and in the state
//! directory, while the broker is away, to be replayed in order on reconnect.

use std::collections::VecDeque;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// One event of the log as the host gets it.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct HostEvent {
    /// The event log's sequence number.
    pub seq: u64,
    /// Its time, ms since the Unix epoch (0: unreadable).
    pub ts_ms: u64,
    /// Its kind (`mode_changed`, `recycle_trip`, `surge_detected`, `fallback_entered` …).
    pub kind: String,
    /// Its cause in words, when it has one.
    pub cause: String,
    /// The whole log line (JSON).
    pub json: String,
}

impl HostEvent {
    /// Parse one log line (None: not an event line).
    pub fn parse(line: &str) -> Option<HostEvent> {
        let v: serde_json::Value = serde_json::from_str(line).ok()?;
        let seq = v.get("seq")?.as_u64()?;
        let kind = v.get("event")?.as_str()?.to_string();
        let ts_ms = v
            .get("ts")
            .and_then(|t| t.as_str())
            .and_then(|t| crate::events::Timestamp::parse_rfc3339(t).ok())
            .and_then(|t| {
                t.to_system_time()
                    .duration_since(std::time::UNIX_EPOCH)
                    .ok()
            })
            .map_or(0, |d| d.as_millis() as u64);
        let cause = match v.get("cause") {
            Some(c) => match serde_json::from_value::<crate::events::cause::Cause>(c.clone()) {
                Ok(c) => c.describe(),
                Err(_) => c.to_string(),
            },
            None => ["reason", "text", "why"]
                .iter()
                .find_map(|k| v.get(*k).and_then(|x| x.as_str()).map(str::to_string))
                .unwrap_or_default(),
        };
        Some(HostEvent {
            seq,
            ts_ms,
            kind,
            cause,
            json: line.to_string(),
        })
    }
}

/// Follows the event log file: each [`LogFollower::poll`] returns the complete lines written
/// since the last one, events with a `seq` above the last returned (a rotation starts the
/// new file from its beginning; `seq` continues across rotations and restarts).
#[derive(Debug)]
pub struct LogFollower {
    path: PathBuf,
    offset: u64,
    last_seq: Option<u64>,
    partial: Vec<u8>,
}

impl LogFollower {
    /// Follow `path` from its current end (what is already there is not sent), or from the
    /// event after `after_seq` if given (what the host already has).
    pub fn new(path: &Path, after_seq: Option<u64>) -> LogFollower {
        let offset = match after_seq {
            Some(_) => 0,
            None => std::fs::metadata(path).map_or(0, |m| m.len()),
        };
        LogFollower {
            path: path.to_path_buf(),
            offset,
            last_seq: after_seq,
            partial: Vec::new(),
        }
    }

    /// The `seq` of the last event returned.
    pub fn last_seq(&self) -> Option<u64> {
        self.last_seq
    }

    /// New events, oldest first (I/O errors: none this time).
    pub fn poll(&mut self) -> Vec<HostEvent> {
        let Ok(mut f) = std::fs::File::open(&self.path) else {
            return Vec::new();
        };
        let len = f.metadata().map_or(0, |m| m.len());
        if len < self.offset {
            // rotated or truncated: the new file from its start
            self.offset = 0;
            self.partial.clear();
        }
        if len == self.offset || f.seek(SeekFrom::Start(self.offset)).is_err() {
            return Vec::new();
        }
        let mut buf = Vec::new();
        let Ok(n) = f.take(4 << 20).read_to_end(&mut buf) else {
            return Vec::new();
        };
        self.offset += n as u64;
        self.partial.extend_from_slice(&buf);
        let mut out = Vec::new();
        let mut start = 0;
        while let Some(k) = self.partial[start..].iter().position(|&b| b == b'\n') {
            let line = String::from_utf8_lossy(&self.partial[start..start + k]).into_owned();
            start += k + 1;
            if let Some(e) = HostEvent::parse(line.trim()) {
                if self.last_seq.is_none_or(|s| e.seq > s) {
                    self.last_seq = Some(e.seq);
                    out.push(e);
                }
            }
        }
        self.partial.drain(..start);
        out
    }
}

/// The store-and-forward queue: events not yet acknowledged by the broker, oldest first,
/// at most `capacity` (the oldest are dropped and counted when full), mirrored to a JSON
/// Lines file in the state directory so that a restart does not lose them.
#[derive(Debug)]
pub struct Spool {
    path: PathBuf,
    capacity: usize,
    queue: VecDeque<HostEvent>,
    /// Events dropped because the queue was full.
    pub dropped: u64,
    dirty: bool,
}

impl Spool {
    /// The queue in `state_dir/sparkplug-spool.jsonl`, with what a previous run left there.
    pub fn open(state_dir: &Path, capacity: usize) -> Spool {
        let path = state_dir.join("sparkplug-spool.jsonl");
        let mut queue: VecDeque<HostEvent> = std::fs::read_to_string(&path)
            .unwrap_or_default()
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect();
        let capacity = capacity.max(1);
        let mut dropped = 0;
        while queue.len() > capacity {
            queue.pop_front();
            dropped += 1;
        }
        Spool {
            path,
            capacity,
            queue,
            dropped,
            dirty: false,
        }
    }

    /// Queued events.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    /// Whether nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    /// The last queued event's log `seq`.
    pub fn last_seq(&self) -> Option<u64> {
        self.queue.back().map(|e| e.seq)
    }

    /// Queue at the back (newest).
    pub fn push(&mut self, e: HostEvent) {
        if self.queue.len() == self.capacity {
            self.queue.pop_front();
            self.dropped += 1;
        }
        self.queue.push_back(e);
        self.dirty = true;
    }

    /// Put back at the front, in order (published but not acknowledged when the link
    /// dropped).
    pub fn requeue_front(&mut self, events: Vec<HostEvent>) {
        for e in events.into_iter().rev() {
            if self.queue.len() == self.capacity {
                self.dropped += 1;
                continue;
            }
            self.queue.push_front(e);
        }
        self.dirty = true;
    }

    /// Take the oldest.
    pub fn pop(&mut self) -> Option<HostEvent> {
        let e = self.queue.pop_front();
        self.dirty |= e.is_some();
        e
    }

    /// Write the file if the queue changed since the last write.
    pub fn sync(&mut self) -> std::io::Result<()> {
        if !self.dirty {
            return Ok(());
        }
        if let Some(d) = self.path.parent() {
            std::fs::create_dir_all(d)?;
        }
        let mut text = String::new();
        for e in &self.queue {
            text.push_str(&serde_json::to_string(e).unwrap_or_default());
            text.push('\n');
        }
        let tmp = self.path.with_extension("tmp");
        std::fs::write(&tmp, text)?;
        std::fs::rename(&tmp, &self.path)?;
        self.dirty = false;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn line(seq: u64, kind: &str) -> String {
        format!(
            r#"{{"ts":"2026-11-28T04:00:00.000001Z","seq":{seq},"event":"{kind}","reason":"r{seq}"}}"#
        )
    }

    #[test]
    fn follows_the_log_line_by_line_across_partial_writes_and_rotation() {
        let dir = tempfile::tempdir().expect("tmp");
        let p = dir.path().join("events.jsonl");
        std::fs::write(&p, line(1, "started") + "\n").expect("write");
        // from the end: the existing line is not sent
        let mut f = LogFollower::new(&p, None);
        assert!(f.poll().is_empty());
        let mut w = std::fs::OpenOptions::new()
            .append(true)
            .open(&p)
            .expect("open");
        write!(
            w,
            "{}\n{}",
            line(2, "mode_changed"),
            &line(3, "surge_detected")[..20]
        )
        .expect("w");
        let got = f.poll();
        assert_eq!(got.len(), 1);
        assert_eq!(
            (got[0].seq, got[0].kind.as_str(), got[0].cause.as_str()),
            (2, "mode_changed", "r2")
        );
        assert!(got[0].ts_ms > 1_700_000_000_000);
        writeln!(w, "{}", &line(3, "surge_detected")[20..]).expect("w");
        assert_eq!(f.poll().iter().map(|e| e.seq).collect::<Vec<_>>(), [3]);
        // rotation: a new, shorter file; seq continues
        std::fs::write(&p, line(4, "stopped") + "\n").expect("write");
        assert_eq!(f.poll().iter().map(|e| e.seq).collect::<Vec<_>>(), [4]);
        // from a known seq: what the host does not have yet
        std::fs::write(
            &p,
            [line(4, "a"), line(5, "b"), line(6, "c")].join("\n") + "\n",
        )
        .expect("w");
        let mut f = LogFollower::new(&p, Some(4));
        assert_eq!(f.poll().iter().map(|e| e.seq).collect::<Vec<_>>(), [5, 6]);
        assert_eq!(f.last_seq(), Some(6));
    }

    #[test]
    fn the_spool_is_bounded_ordered_and_survives_a_restart() {
        let dir = tempfile::tempdir().expect("tmp");
        let ev = |s: u64| HostEvent::parse(&line(s, "x")).expect("event");
        let mut q = Spool::open(dir.path(), 3);
        for s in 1..=4 {
            q.push(ev(s));
        }
        assert_eq!((q.len(), q.dropped), (3, 1));
        let first = q.pop().expect("2");
        assert_eq!(first.seq, 2);
        q.requeue_front(vec![first]);
        q.sync().expect("sync");
        let mut again = Spool::open(dir.path(), 3);
        let order: Vec<u64> = std::iter::from_fn(|| again.pop()).map(|e| e.seq).collect();
        assert_eq!(order, [2, 3, 4]);
        again.sync().expect("sync");
        assert!(Spool::open(dir.path(), 3).is_empty());
    }
}
