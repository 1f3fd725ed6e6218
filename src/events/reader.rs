//! Reading the log back: the rotated set oldest → newest, one [`Record`] per valid line,
//! with everything unusual (torn final line, invalid lines, sequence breaks) collected in
//! [`ReadStats`] as warnings rather than errors — after an incident the reader must show
//! whatever survived.

use std::fmt;
use std::fs::{self, File};
use std::io::{BufRead, BufReader, ErrorKind, Read};
use std::path::{Path, PathBuf};

use serde::de::{Deserialize, Deserializer, MapAccess, Visitor};
use serde_json::Value;

use super::error::EventLogError;
use super::event::Event;
use super::timestamp::Timestamp;

/// At most this many invalid lines / sequence breaks are kept with details; the rest are
/// only counted.
pub const MAX_REPORTED: usize = 100;

/// One valid line of the log.
#[derive(Debug, Clone, PartialEq)]
pub struct Record {
    /// 1-based line number in its file.
    pub line: u64,
    /// When the event happened.
    pub ts: Timestamp,
    /// Sequence number (monotonic across rotations and writer restarts).
    pub seq: u64,
    /// The `"event"` kind, e.g. `surge_detected`. Kinds unknown to this build are kept.
    pub kind: String,
    /// The remaining fields in file order.
    pub fields: Vec<(String, Value)>,
    /// The line exactly as stored (without the newline).
    pub raw: String,
}

impl Record {
    /// The typed event (fails for kinds or fields this build does not know).
    pub fn event(&self) -> Result<Event, serde_json::Error> {
        serde_json::from_str(&self.raw)
    }
}

/// A line in the middle of the log that is not a valid record.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InvalidLine {
    /// File holding it.
    pub file: PathBuf,
    /// 1-based line number.
    pub line: u64,
    /// What is wrong.
    pub message: String,
    /// The start of the line (≤ 80 characters, lossy UTF-8), to recognise it.
    pub excerpt: String,
}

/// The final line of the newest file was incomplete: the writer stopped in the middle of
/// writing it (crash, power loss). It is skipped.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TornTail {
    /// File holding it (the newest of the set).
    pub file: PathBuf,
    /// 1-based line number.
    pub line: u64,
    /// Its length in bytes (without a newline, if one was there).
    pub bytes: u64,
    /// Whether it at least ended with a newline (then it was complete but not valid JSON).
    pub terminated: bool,
}

/// Consecutive valid records whose `seq` does not go up by exactly one: events missing in
/// between, or a writer that started without seeing the previous files.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SeqBreak {
    /// File holding the later record.
    pub file: PathBuf,
    /// Its line number.
    pub line: u64,
    /// `seq` of the record before.
    pub previous: u64,
    /// `seq` found.
    pub found: u64,
}

/// What a read saw besides the records themselves.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReadStats {
    /// Files read, oldest first.
    pub files: Vec<PathBuf>,
    /// Valid records read (before filtering).
    pub records: u64,
    /// Records that passed the filter.
    pub matched: u64,
    /// Smallest and largest `seq` seen in file order (first and last record).
    pub first_seq: Option<u64>,
    /// `seq` of the last valid record.
    pub last_seq: Option<u64>,
    /// Invalid lines (first [`MAX_REPORTED`]).
    pub invalid: Vec<InvalidLine>,
    /// All invalid lines, counted.
    pub invalid_total: u64,
    /// The skipped torn final line, if any.
    pub torn_tail: Option<TornTail>,
    /// Sequence breaks (first [`MAX_REPORTED`]).
    pub seq_breaks: Vec<SeqBreak>,
    /// All sequence breaks, counted.
    pub seq_breaks_total: u64,
}

impl ReadStats {
    /// No invalid line, no torn tail, no sequence break.
    pub fn is_clean(&self) -> bool {
        self.invalid_total == 0 && self.torn_tail.is_none() && self.seq_breaks_total == 0
    }

    /// Human-readable warnings, one per line, for stderr.
    pub fn warnings(&self) -> Vec<String> {
        let mut w = Vec::new();
        for l in &self.invalid {
            w.push(format!(
                "{}:{}: invalid line skipped ({}): {}",
                l.file.display(),
                l.line,
                l.message,
                l.excerpt
            ));
        }
        if self.invalid_total > self.invalid.len() as u64 {
            w.push(format!(
                "… and {} more invalid lines",
                self.invalid_total - self.invalid.len() as u64
            ));
        }
        for b in &self.seq_breaks {
            w.push(format!(
                "{}:{}: seq jumps from {} to {} ({})",
                b.file.display(),
                b.line,
                b.previous,
                b.found,
                if b.found > b.previous {
                    format!("{} events missing", b.found - b.previous - 1)
                } else {
                    "sequence went backwards: writer restarted without its history".to_string()
                }
            ));
        }
        if self.seq_breaks_total > self.seq_breaks.len() as u64 {
            w.push(format!(
                "… and {} more seq breaks",
                self.seq_breaks_total - self.seq_breaks.len() as u64
            ));
        }
        if let Some(t) = &self.torn_tail {
            w.push(format!(
                "{}:{}: torn final line ({} bytes{}) skipped: the writer stopped while writing it",
                t.file.display(),
                t.line,
                t.bytes,
                if t.terminated {
                    ", not valid JSON"
                } else {
                    ", no newline"
                }
            ));
        }
        w
    }
}

/// Which records to show.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct EventFilter {
    /// Only records at or after this time.
    pub since: Option<Timestamp>,
    /// Only records at or before this time.
    pub until: Option<Timestamp>,
    /// Only records of these kinds (`surge_detected`, …); empty: every kind.
    pub kinds: Vec<String>,
}

impl EventFilter {
    /// A filter from a `--since` argument (see [`parse_since`]), relative to `now`.
    pub fn since_arg(text: &str, now: Timestamp) -> Result<EventFilter, EventLogError> {
        Ok(EventFilter {
            since: Some(parse_since(text, now)?),
            ..EventFilter::default()
        })
    }

    /// Whether `record` passes.
    pub fn matches(&self, record: &Record) -> bool {
        self.since.is_none_or(|s| record.ts >= s)
            && self.until.is_none_or(|u| record.ts <= u)
            && (self.kinds.is_empty() || self.kinds.contains(&record.kind))
    }
}

/// Parse a `--since`/`--until` argument in the machine's time zone with
/// [`super::timestamp::parse_time`] (the one parser: printed forms, RFC 3339, ages, `today`).
pub fn parse_since(text: &str, now: Timestamp) -> Result<Timestamp, EventLogError> {
    parse_time_arg(text, now, false)
}

/// [`parse_since`] with the zone chosen: UTC (`--utc`) or the machine's.
pub fn parse_time_arg(text: &str, now: Timestamp, utc: bool) -> Result<Timestamp, EventLogError> {
    super::timestamp::parse_time(text, now, &super::timestamp::zone(utc)).map_err(|reason| {
        EventLogError::Time {
            text: text.to_string(),
            reason,
        }
    })
}

/// `path.N` for the N-th rotated file.
pub(crate) fn rotated_path(path: &Path, n: u32) -> PathBuf {
    let mut s = path.as_os_str().to_owned();
    s.push(format!(".{n}"));
    PathBuf::from(s)
}

/// The files of the log at `path`, oldest first: `path.K` … `path.2`, `path.1`, `path`.
/// Rotated files are found by listing the directory, so gaps and a changed `keep_files`
/// are handled. Errors with [`EventLogError::NotFound`] if none exists.
pub fn log_files(path: &Path) -> Result<Vec<PathBuf>, EventLogError> {
    let files = existing_log_files(path)?;
    if files.is_empty() {
        return Err(EventLogError::NotFound {
            path: path.to_path_buf(),
        });
    }
    Ok(files)
}

/// Like [`log_files`] but an absent log is an empty list.
pub(crate) fn existing_log_files(path: &Path) -> Result<Vec<PathBuf>, EventLogError> {
    let name = match path.file_name().and_then(|n| n.to_str()) {
        Some(n) => n,
        None => {
            return Err(EventLogError::Config(format!(
                "{} does not name a UTF-8 file",
                path.display()
            )))
        }
    };
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let mut numbered: Vec<u32> = Vec::new();
    let entries = match fs::read_dir(&dir) {
        Ok(e) => e,
        Err(e) if e.kind() == ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(EventLogError::io(dir, "list directory", e)),
    };
    for entry in entries {
        let entry = entry.map_err(|e| EventLogError::io(&dir, "list directory", e))?;
        let file_name = entry.file_name();
        let Some(f) = file_name.to_str() else {
            continue;
        };
        let Some(suffix) = f.strip_prefix(name).and_then(|s| s.strip_prefix('.')) else {
            continue;
        };
        if !suffix.is_empty() && suffix.bytes().all(|b| b.is_ascii_digit()) {
            if let Ok(n) = suffix.parse::<u32>() {
                if n > 0 {
                    numbered.push(n);
                }
            }
        }
    }
    numbered.sort_unstable_by(|a, b| b.cmp(a));
    numbered.dedup();
    let mut files: Vec<PathBuf> = numbered
        .into_iter()
        .map(|n| rotated_path(path, n))
        .collect();
    if path.is_file() {
        files.push(path.to_path_buf());
    }
    Ok(files)
}

/// A JSON object keeping its keys in file order.
struct OrderedObject(Vec<(String, Value)>);

impl<'de> Deserialize<'de> for OrderedObject {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = OrderedObject;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a JSON object")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<OrderedObject, A::Error> {
                let mut v = Vec::with_capacity(map.size_hint().unwrap_or(8));
                while let Some(entry) = map.next_entry::<String, Value>()? {
                    v.push(entry);
                }
                Ok(OrderedObject(v))
            }
        }
        d.deserialize_map(V)
    }
}

/// Parse one line (without its newline) into a record.
pub(crate) fn parse_line(bytes: &[u8], line: u64) -> Result<Record, String> {
    let text = std::str::from_utf8(bytes).map_err(|e| format!("not UTF-8: {e}"))?;
    if text.trim().is_empty() {
        return Err("empty line".into());
    }
    let OrderedObject(mut fields) =
        serde_json::from_str(text).map_err(|e| format!("not a JSON object: {e}"))?;
    let mut take = |key: &str| {
        fields
            .iter()
            .position(|(k, _)| k == key)
            .map(|i| fields.remove(i).1)
    };
    let ts = match take("ts") {
        Some(Value::String(s)) => {
            Timestamp::parse_rfc3339(&s).map_err(|e| format!("bad \"ts\": {e}"))?
        }
        _ => return Err("missing \"ts\" string".into()),
    };
    let seq = take("seq")
        .and_then(|v| v.as_u64())
        .ok_or("missing or non-integer \"seq\"")?;
    let kind = match take("event") {
        Some(Value::String(s)) => s,
        _ => return Err("missing \"event\" string".into()),
    };
    Ok(Record {
        line,
        ts,
        seq,
        kind,
        fields,
        raw: text.to_string(),
    })
}

fn excerpt(bytes: &[u8]) -> String {
    let s = String::from_utf8_lossy(bytes);
    let mut out: String = s.chars().take(80).collect();
    if s.chars().nth(80).is_some() {
        out.push('…');
    }
    out
}

/// Read `files` (oldest first, as from [`log_files`]) and call `on_record` for every valid
/// record that passes `filter`. A file that has disappeared since it was listed (rotated
/// away by a running writer) is skipped.
///
/// The final line of the last file is treated as torn if it has no newline or is not a
/// valid record: it is skipped and reported in [`ReadStats::torn_tail`]. Invalid lines
/// anywhere else are skipped and reported with file and line number. Only failing to open
/// or read a file, or `on_record` failing, is an error.
pub fn read_files(
    files: &[PathBuf],
    filter: &EventFilter,
    mut on_record: impl FnMut(&Path, &Record) -> Result<(), EventLogError>,
) -> Result<ReadStats, EventLogError> {
    let mut stats = ReadStats {
        files: files.to_vec(),
        ..ReadStats::default()
    };
    let mut buf = Vec::with_capacity(1024);
    for (index, path) in files.iter().enumerate() {
        let newest = index + 1 == files.len();
        let file = match File::open(path) {
            Ok(f) => f,
            // Rotated away by a live writer since the listing: nothing left to read there.
            Err(e) if e.kind() == ErrorKind::NotFound => continue,
            Err(e) => return Err(EventLogError::io(path, "open for reading", e)),
        };
        let mut reader = BufReader::with_capacity(64 * 1024, file);
        read_records(
            &mut reader,
            path,
            newest,
            filter,
            &mut stats,
            &mut buf,
            &mut on_record,
        )?;
    }
    Ok(stats)
}

/// Read one log's `bytes` from memory as the newest (only) file of a set, `path` naming it
/// in reports: the same line handling as [`read_files`] (the fuzz target `event_reader`
/// reads from memory through here, no file per input).
pub fn read_bytes(
    bytes: &[u8],
    path: &Path,
    filter: &EventFilter,
    mut on_record: impl FnMut(&Path, &Record) -> Result<(), EventLogError>,
) -> Result<ReadStats, EventLogError> {
    let mut stats = ReadStats {
        files: vec![path.to_path_buf()],
        ..ReadStats::default()
    };
    let mut buf = Vec::with_capacity(1024);
    let mut reader = bytes;
    read_records(
        &mut reader,
        path,
        true,
        filter,
        &mut stats,
        &mut buf,
        &mut on_record,
    )?;
    Ok(stats)
}

/// The records of one file from `reader` (see [`read_files`]; `newest`: its last line may
/// be a torn tail).
fn read_records<R: BufRead>(
    reader: &mut R,
    path: &Path,
    newest: bool,
    filter: &EventFilter,
    stats: &mut ReadStats,
    buf: &mut Vec<u8>,
    on_record: &mut impl FnMut(&Path, &Record) -> Result<(), EventLogError>,
) -> Result<(), EventLogError> {
    let mut line_no = 0u64;
    loop {
        buf.clear();
        // at most MAX_READ_LINE_BYTES per line are kept in memory (a 1 GiB line cost 1 GB)
        let n = (&mut *reader)
            .take(MAX_READ_LINE_BYTES as u64 + 1)
            .read_until(b'\n', buf)
            .map_err(|e| EventLogError::io(path, "read", e))?;
        if n == 0 {
            break;
        }
        line_no += 1;
        if n > MAX_READ_LINE_BYTES && buf.last() != Some(&b'\n') {
            let skipped = skip_line(reader).map_err(|e| EventLogError::io(path, "read", e))?;
            let total = n as u64 + skipped;
            stats.note_invalid(
                path,
                line_no,
                &format!("line of {total} bytes, longer than {MAX_READ_LINE_BYTES}: skipped"),
                &buf[..64],
            );
            continue;
        }
        let terminated = buf.last() == Some(&b'\n');
        let content = if terminated { &buf[..n - 1] } else { &buf[..] };
        let last_line = !terminated
            || reader
                .fill_buf()
                .map_err(|e| EventLogError::io(path, "read", e))?
                .is_empty();
        let parsed = parse_line(content, line_no);
        if newest && last_line && (!terminated || parsed.is_err()) {
            stats.torn_tail = Some(TornTail {
                file: path.to_path_buf(),
                line: line_no,
                bytes: content.len() as u64,
                terminated,
            });
            continue;
        }
        let record = match (parsed, terminated) {
            (Ok(r), true) => r,
            (Ok(_), false) => {
                stats.note_invalid(
                    path,
                    line_no,
                    "no newline at end of a rotated file",
                    content,
                );
                continue;
            }
            (Err(message), _) => {
                stats.note_invalid(path, line_no, &message, content);
                continue;
            }
        };
        stats.records += 1;
        if let Some(prev) = stats.last_seq {
            if record.seq != prev.wrapping_add(1) {
                stats.seq_breaks_total += 1;
                if stats.seq_breaks.len() < MAX_REPORTED {
                    stats.seq_breaks.push(SeqBreak {
                        file: path.to_path_buf(),
                        line: line_no,
                        previous: prev,
                        found: record.seq,
                    });
                }
            }
        }
        stats.first_seq.get_or_insert(record.seq);
        stats.last_seq = Some(record.seq);
        if filter.matches(&record) {
            stats.matched += 1;
            on_record(path, &record)?;
        }
    }
    Ok(())
}

impl ReadStats {
    fn note_invalid(&mut self, path: &Path, line: u64, message: &str, content: &[u8]) {
        self.invalid_total += 1;
        if self.invalid.len() < MAX_REPORTED {
            self.invalid.push(InvalidLine {
                file: path.to_path_buf(),
                line,
                message: message.to_string(),
                excerpt: excerpt(content),
            });
        }
    }
}

/// Read the whole log at `path` (rotated set included) into memory. Convenient for tests
/// and small logs; the CLI streams with [`read_files`] instead.
pub fn read_log(
    path: &Path,
    filter: &EventFilter,
) -> Result<(Vec<Record>, ReadStats), EventLogError> {
    let files = log_files(path)?;
    let mut out = Vec::new();
    let stats = read_files(&files, filter, |_, r| {
        out.push(r.clone());
        Ok(())
    })?;
    Ok((out, stats))
}

/// The newest `n` valid records of the log at `path` (newest last), reading at most
/// `max_bytes` from the end of the newest file (and, if that holds fewer than `n`, from the
/// end of `path.1`): a bounded read whatever the log's size, for a page that polls. A line
/// cut by the window's start, a torn last line and invalid lines are skipped.
pub fn tail_records(path: &Path, max_bytes: u64, n: usize) -> Vec<Record> {
    let mut out = tail_of_file(path, max_bytes, n);
    if out.len() < n {
        let mut older = tail_of_file(&rotated_path(path, 1), max_bytes, n - out.len());
        older.append(&mut out);
        out = older;
    }
    out
}

fn tail_of_file(path: &Path, max_bytes: u64, n: usize) -> Vec<Record> {
    use std::io::{Seek, SeekFrom};
    let Ok(mut f) = File::open(path) else {
        return Vec::new();
    };
    let len = f.metadata().map(|m| m.len()).unwrap_or(0);
    let start = len.saturating_sub(max_bytes);
    if f.seek(SeekFrom::Start(start)).is_err() {
        return Vec::new();
    }
    let mut bytes = Vec::with_capacity((len - start) as usize);
    if f.take(max_bytes).read_to_end(&mut bytes).is_err() {
        return Vec::new();
    }
    let mut lines: Vec<&[u8]> = bytes.split(|&b| b == b'\n').collect();
    // the last piece is empty (a final newline) or a line still being written
    lines.pop();
    if start > 0 && !lines.is_empty() {
        // the window began inside a line
        lines.remove(0);
    }
    let mut out: Vec<Record> = lines
        .iter()
        .rev()
        .filter_map(|l| parse_line(l, 0).ok())
        .take(n)
        .collect();
    out.reverse();
    out
}

/// The records appended to the log at `path` since byte `offset` of its newest file, and
/// the offset to read from next (`antisurge events --follow`). A partial last line is left
/// for the next call; a file that shrank (rotated, repaired) is read again from its start.
pub fn records_since(path: &Path, offset: u64) -> (Vec<Record>, u64) {
    use std::io::{Seek, SeekFrom};
    let Ok(mut f) = File::open(path) else {
        return (Vec::new(), 0);
    };
    let len = f.metadata().map(|m| m.len()).unwrap_or(0);
    let from = if len < offset { 0 } else { offset };
    if f.seek(SeekFrom::Start(from)).is_err() {
        return (Vec::new(), from);
    }
    let mut bytes = Vec::new();
    // at most 16 MiB per call: a follower catches up over a few calls
    if f.take(16 << 20).read_to_end(&mut bytes).is_err() {
        return (Vec::new(), from);
    }
    let complete = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
    let out = bytes[..complete]
        .split(|&b| b == b'\n')
        .filter(|l| !l.is_empty())
        .filter_map(|l| parse_line(l, 0).ok())
        .collect();
    (out, from + complete as u64)
}

/// Longest event-log line the readers keep in memory, bytes (the writer's lines are at most
/// [`crate::events::MAX_LINE_BYTES`]); longer lines are skipped and reported as invalid.
pub const MAX_READ_LINE_BYTES: usize = 64 * 1024;

/// The start-up scan looks at most this far back from the end of a file for the last `seq`.
pub const MAX_SEQ_SCAN_BYTES: u64 = 16 << 20;

/// Consume the rest of a line (through its newline) without keeping it; returns the bytes.
fn skip_line(reader: &mut impl BufRead) -> std::io::Result<u64> {
    let mut skipped = 0u64;
    loop {
        let chunk = reader.fill_buf()?;
        if chunk.is_empty() {
            return Ok(skipped);
        }
        match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => {
                reader.consume(i + 1);
                return Ok(skipped + i as u64 + 1);
            }
            None => {
                let n = chunk.len();
                reader.consume(n);
                skipped += n as u64;
            }
        }
    }
}

/// `seq` of the last valid, newline-terminated record in `path`, reading from the end.
/// `Ok(None)` if the file is missing or holds no valid record.
pub(crate) fn last_valid_seq(path: &Path) -> Result<Option<u64>, EventLogError> {
    use std::os::unix::fs::FileExt;
    let file = match File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(EventLogError::io(path, "open for reading", e)),
    };
    let len = file
        .metadata()
        .map_err(|e| EventLogError::io(path, "stat", e))?
        .len();
    let mut window: u64 = 64 * 1024;
    let mut buf = Vec::new();
    loop {
        let start = len.saturating_sub(window);
        buf.resize((len - start) as usize, 0);
        file.read_exact_at(&mut buf, start)
            .map_err(|e| EventLogError::io(path, "read", e))?;
        // Only newline-terminated lines count; the first piece may be cut unless at 0.
        if let Some(end) = buf.iter().rposition(|&b| b == b'\n') {
            let mut pieces = buf[..end].split(|&b| b == b'\n').rev().peekable();
            while let Some(piece) = pieces.next() {
                let is_first_piece = pieces.peek().is_none();
                if is_first_piece && start > 0 {
                    break;
                }
                if let Ok(r) = parse_line(piece, 0) {
                    return Ok(Some(r.seq));
                }
            }
        }
        if start == 0 || window >= MAX_SEQ_SCAN_BYTES {
            // nothing valid in the last MAX_SEQ_SCAN_BYTES: start a new sequence
            return Ok(None);
        }
        window = window.saturating_mul(4).min(MAX_SEQ_SCAN_BYTES);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn line(seq: u64, ts_us: i64) -> String {
        format!(
            r#"{{"ts":"{}","seq":{seq},"event":"note","text":"n{seq}"}}"#,
            Timestamp::from_unix_micros(ts_us)
        )
    }

    fn write(path: &Path, content: &str) {
        let mut f = File::create(path).expect("create");
        f.write_all(content.as_bytes()).expect("write");
    }

    fn read_all(path: &Path) -> (Vec<Record>, ReadStats) {
        read_log(path, &EventFilter::default()).expect("read")
    }

    #[test]
    fn parses_fields_in_file_order() {
        let text = r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":7,"event":"surge_detected","surge_count_total":3,"frequency_hz":8.5,"min_flow_kg_s":-0.4,"flow_reversal":true}"#;
        let r = parse_line(text.as_bytes(), 1).expect("valid");
        assert_eq!(r.seq, 7);
        assert_eq!(r.kind, "surge_detected");
        let keys: Vec<_> = r.fields.iter().map(|(k, _)| k.as_str()).collect();
        assert_eq!(
            keys,
            [
                "surge_count_total",
                "frequency_hz",
                "min_flow_kg_s",
                "flow_reversal"
            ]
        );
        assert!(matches!(r.event(), Ok(Event::SurgeDetected(_))));
    }

    #[test]
    fn rejects_lines_missing_the_envelope() {
        for bad in [
            "",
            "   ",
            "[1,2]",
            r#"{"seq":1,"event":"note"}"#,
            r#"{"ts":"yesterday","seq":1,"event":"note"}"#,
            r#"{"ts":"2024-05-01T12:34:56Z","seq":-1,"event":"note"}"#,
            r#"{"ts":"2024-05-01T12:34:56Z","seq":1}"#,
            r#"{"ts":"2024-05-01T12:34:56Z","seq":1,"event":"note""#,
        ] {
            assert!(parse_line(bad.as_bytes(), 1).is_err(), "accepted {bad:?}");
        }
        assert!(parse_line(b"\xff\xfe", 1).is_err());
    }

    #[test]
    fn unknown_kinds_are_records_not_errors() {
        let r = parse_line(
            br#"{"ts":"2024-05-01T12:34:56Z","seq":1,"event":"from_the_future","x":1}"#,
            1,
        )
        .expect("valid envelope");
        assert_eq!(r.kind, "from_the_future");
        assert!(r.event().is_err());
    }

    #[test]
    fn files_are_ordered_oldest_first_with_gaps() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("events.jsonl");
        for name in [
            "events.jsonl",
            "events.jsonl.1",
            "events.jsonl.10",
            "events.jsonl.2",
            "events.jsonl.x",
            "events.jsonl.0",
            "events.jsonl.1.tmp",
            "other.jsonl.3",
        ] {
            write(&dir.path().join(name), "");
        }
        let files = log_files(&p).expect("files");
        let names: Vec<_> = files
            .iter()
            .map(|f| {
                f.file_name()
                    .and_then(|n| n.to_str())
                    .unwrap_or("?")
                    .to_string()
            })
            .collect();
        assert_eq!(
            names,
            [
                "events.jsonl.10",
                "events.jsonl.2",
                "events.jsonl.1",
                "events.jsonl"
            ]
        );
        assert!(matches!(
            log_files(&dir.path().join("none.jsonl")),
            Err(EventLogError::NotFound { .. })
        ));
        assert!(matches!(
            log_files(&dir.path().join("no_dir/none.jsonl")),
            Err(EventLogError::NotFound { .. })
        ));
    }

    #[test]
    fn reads_rotated_set_in_order_and_checks_seq() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("events.jsonl");
        write(
            &rotated_path(&p, 2),
            &format!("{}\n{}\n", line(1, 10), line(2, 20)),
        );
        write(&rotated_path(&p, 1), &format!("{}\n", line(3, 30)));
        write(&p, &format!("{}\n{}\n", line(4, 40), line(6, 60)));
        let (records, stats) = read_all(&p);
        let seqs: Vec<_> = records.iter().map(|r| r.seq).collect();
        assert_eq!(seqs, [1, 2, 3, 4, 6]);
        assert_eq!(stats.records, 5);
        assert_eq!(stats.first_seq, Some(1));
        assert_eq!(stats.last_seq, Some(6));
        assert_eq!(stats.seq_breaks_total, 1);
        assert_eq!(
            stats.seq_breaks[0],
            SeqBreak {
                file: p.clone(),
                line: 2,
                previous: 4,
                found: 6
            }
        );
        assert!(stats.torn_tail.is_none());
        assert!(stats
            .warnings()
            .iter()
            .any(|w| w.contains("1 events missing")));
    }

    #[test]
    fn torn_tail_without_newline_is_skipped_and_reported() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("events.jsonl");
        let torn = r#"{"ts":"2024-05-01T12:34:56.1234"#;
        write(&p, &format!("{}\n{}\n{torn}", line(1, 1), line(2, 2)));
        let (records, stats) = read_all(&p);
        assert_eq!(records.len(), 2);
        assert_eq!(
            stats.torn_tail,
            Some(TornTail {
                file: p.clone(),
                line: 3,
                bytes: torn.len() as u64,
                terminated: false
            })
        );
        assert_eq!(stats.invalid_total, 0);
        assert!(!stats.is_clean());
        assert!(stats
            .warnings()
            .iter()
            .any(|w| w.contains("torn final line")));
    }

    #[test]
    fn complete_json_without_newline_is_still_torn() {
        // The '\n' is part of the single write; without it the write did not finish.
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("events.jsonl");
        write(&p, &format!("{}\n{}", line(1, 1), line(2, 2)));
        let (records, stats) = read_all(&p);
        assert_eq!(records.len(), 1);
        assert_eq!(
            stats.torn_tail.map(|t| (t.line, t.terminated)),
            Some((2, false))
        );
    }

    #[test]
    fn invalid_terminated_final_line_is_torn_but_middle_ones_are_invalid() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("events.jsonl");
        write(
            &p,
            &format!("{}\n{{garbage\n{}\n\0\0\0\n", line(1, 1), line(2, 2)),
        );
        let (records, stats) = read_all(&p);
        assert_eq!(records.len(), 2);
        assert_eq!(stats.invalid_total, 1);
        assert_eq!(stats.invalid[0].line, 2);
        assert_eq!(stats.invalid[0].file, p);
        assert_eq!(stats.invalid[0].excerpt, "{garbage");
        let torn = stats.torn_tail.clone().expect("NUL tail is torn");
        assert_eq!((torn.line, torn.bytes, torn.terminated), (4, 3, true));
        assert!(stats.warnings()[0].contains("events.jsonl:2: invalid line"));
    }

    #[test]
    fn torn_line_in_an_older_file_is_invalid_not_torn() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("events.jsonl");
        write(&rotated_path(&p, 1), &format!("{}\n{{\"ts\":", line(1, 1)));
        write(&p, &format!("{}\n", line(2, 2)));
        let (records, stats) = read_all(&p);
        assert_eq!(records.len(), 2);
        assert!(stats.torn_tail.is_none());
        assert_eq!(stats.invalid_total, 1);
        assert_eq!(stats.invalid[0].file, rotated_path(&p, 1));
    }

    #[test]
    fn since_filter_applies_but_seq_check_sees_everything() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("events.jsonl");
        write(
            &p,
            &format!(
                "{}\n{}\n{}\n",
                line(1, 1_000),
                line(2, 2_000),
                line(3, 3_000)
            ),
        );
        let filter = EventFilter {
            since: Some(Timestamp::from_unix_micros(2_000)),
            ..EventFilter::default()
        };
        let (records, stats) = read_log(&p, &filter).expect("read");
        assert_eq!(records.iter().map(|r| r.seq).collect::<Vec<_>>(), [2, 3]);
        assert_eq!((stats.records, stats.matched), (3, 2));
        assert!(stats.is_clean());
    }

    #[test]
    fn since_parsing() {
        let now = Timestamp::parse_rfc3339("2024-05-01T12:00:00Z").expect("now");
        let at = |s: &str| parse_since(s, now).map(|t| t.to_string());
        assert_eq!(at("10m").expect("10m"), "2024-05-01T11:50:00.000000Z");
        assert_eq!(at("2h").expect("2h"), "2024-05-01T10:00:00.000000Z");
        assert_eq!(at("1d").expect("1d"), "2024-04-30T12:00:00.000000Z");
        assert_eq!(at("1w").expect("1w"), "2024-04-24T12:00:00.000000Z");
        assert_eq!(at("90s").expect("90s"), "2024-05-01T11:58:30.000000Z");
        assert_eq!(at("1h30m").expect("1h30m"), "2024-05-01T10:30:00.000000Z");
        assert_eq!(at(" 5m ").expect("trimmed"), "2024-05-01T11:55:00.000000Z");
        assert_eq!(at("5min").expect("5min"), "2024-05-01T11:55:00.000000Z");
        assert_eq!(
            at("2024-05-01T09:00:00+02:00").expect("rfc3339"),
            "2024-05-01T07:00:00.000000Z"
        );
        for bad in ["", "10", "m", "10x", "-5m", "1h30", "2024-13-01"] {
            match parse_since(bad, now) {
                Err(EventLogError::Time { text, .. }) => assert_eq!(text, bad),
                other => panic!("{bad:?}: {other:?}"),
            }
        }
        assert!(parse_since("99999999999999999999d", now).is_err());
    }

    #[test]
    fn until_and_kind_filters() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("events.jsonl");
        write(
            &p,
            &format!(
                "{}\n{}\n{}\n",
                line(1, 1_000),
                line(2, 2_000),
                line(3, 3_000)
            ),
        );
        let filter = EventFilter {
            until: Some(Timestamp::from_unix_micros(2_000)),
            ..EventFilter::default()
        };
        let (records, _) = read_log(&p, &filter).expect("read");
        assert_eq!(records.iter().map(|r| r.seq).collect::<Vec<_>>(), [1, 2]);
        let kind = records[0].kind.clone();
        let none = EventFilter {
            kinds: vec!["no_such_kind".into()],
            ..EventFilter::default()
        };
        assert!(read_log(&p, &none).expect("read").0.is_empty());
        let some = EventFilter {
            kinds: vec![kind],
            ..EventFilter::default()
        };
        assert_eq!(read_log(&p, &some).expect("read").0.len(), 3);
    }

    #[test]
    fn the_tail_is_bounded_and_skips_a_torn_line() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("events.jsonl");
        let mut text = String::new();
        for k in 1..=2000u64 {
            text += &line(k, k as i64 * 1000);
            text.push('\n');
        }
        // a torn line in the middle and a half-written last line
        text += "{\"ts\":\"2024-05-01T";
        text.push('\n');
        text += &line(2001, 2_001_000);
        text.push('\n');
        text += "{\"ts\":\"2024";
        write(&p, &text);
        let tail = tail_records(&p, 4096, 30);
        assert_eq!(tail.last().map(|r| r.seq), Some(2001));
        assert!(tail.len() > 5 && tail.len() <= 30, "{}", tail.len());
        assert!(tail.windows(2).all(|w| w[0].seq < w[1].seq));
        // follow: the half line is left for later
        let (recs, off) = records_since(&p, 0);
        assert_eq!(recs.len(), 2001);
        let (more, off2) = records_since(&p, off);
        assert!(more.is_empty());
        assert_eq!(off, off2);
    }

    #[test]
    fn last_valid_seq_skips_torn_and_invalid_tails() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("events.jsonl");
        assert_eq!(last_valid_seq(&p).expect("missing"), None);
        write(&p, "");
        assert_eq!(last_valid_seq(&p).expect("empty"), None);
        write(
            &p,
            &format!("{}\n{}\n{{junk\n{}", line(4, 1), line(5, 2), line(6, 3)),
        );
        assert_eq!(last_valid_seq(&p).expect("read"), Some(5));
        // A long invalid tail forces the backwards window to grow.
        let junk = "x".repeat(200 * 1024);
        write(&p, &format!("{}\n{junk}\n{junk}\n", line(9, 1)));
        assert_eq!(last_valid_seq(&p).expect("read"), Some(9));
    }
}
