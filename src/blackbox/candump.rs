//! Import of `candump -l` logs (can-utils) into a black-box [`Recording`], so that
//! `antisurge replay --candump LOG` runs the control core over traffic captured on a skid.
//!
//! The frames go through the daemon's own receive path: the one signal map's CAN bindings and
//! the DBC build the [`BusCodec`], and [`RxHandler::controller`] decodes sensor frames (DLC, CRC,
//! alive counter, units) onto a [`SensorBoard`] exactly as the daemon's CAN task does. The
//! control cycle is rebuilt on a fixed tick of the configured period starting one period
//! after the first frame: at each tick the board's snapshot gives the values and ages the core
//! would have seen. Actuator frames and the controller heartbeat on the same bus (what the
//! controller that was running commanded) are decoded by [`RxHandler::plant`] and become the
//! record's commands and mode, for comparison with the replay.
//!
//! Log format, one frame a line (`candump -l` / `candump -L`):
//! `(1700000000.123456) can0 123#0011223344556677`: time in seconds, interface, identifier
//! (3 hex digits: 11 bit; 8 hex digits: 29 bit), `#`, payload in hex. Remote frames
//! (`123#R`), CAN FD frames (`123##<flags><data>`) and error frames (identifier with the
//! `CAN_ERR_FLAG` 0x20000000) are counted and skipped, as the bus task skips them.

use super::{CycleRecord, Header, Recording};
use crate::control::measurements::OperatorInputs;
use crate::io::can::bus::{BusCodec, CanCounters, CanCountersSnapshot, RxHandler};
use crate::io::can::dbc::FrameId;
use crate::runtime::handoff::{CommandBoard, HeartbeatBoard, SensorBoard};
use crate::vocab::signals::{ActuatorCommands, ActuatorId};
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;

/// Error flag of a SocketCAN identifier (linux/can.h `CAN_ERR_FLAG`).
const CAN_ERR_FLAG: u32 = 0x2000_0000;
/// Arrival times are shifted by this so that no frame arrives at 0 ns (the boards' "never").
const TIME_ORIGIN_NS: u64 = 1_000_000_000;

/// What a log line holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LoggedKind {
    /// A classic data frame.
    Data {
        /// Identifier.
        id: FrameId,
        /// Payload (≤ 8 bytes).
        data: Vec<u8>,
    },
    /// A remote (RTR) frame.
    Remote,
    /// A CAN FD frame.
    Fd,
    /// An error frame.
    Error,
}

/// One frame of a `candump -l` log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LoggedFrame {
    /// Reception time, ns since the epoch of the log (as printed).
    pub t_ns: u64,
    /// Interface name (`can0`).
    pub interface: String,
    /// The frame.
    pub kind: LoggedKind,
    /// Line in the log (1-based).
    pub line: usize,
}

/// Errors reading or importing a `candump -l` log; each names the file and, for a bad line,
/// the line.
#[derive(Debug, thiserror::Error)]
pub enum CandumpError {
    /// The file cannot be read.
    #[error("{path}: {error}")]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        error: std::io::Error,
    },
    /// A line that is not a `candump -l` frame.
    #[error("{path}:{line}: {message} (expected `(seconds.micros) can0 123#00112233`, as `candump -l` writes)")]
    Line {
        /// File.
        path: PathBuf,
        /// Line (1-based).
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// Nothing to replay.
    #[error("{path}: {message}")]
    Empty {
        /// File.
        path: PathBuf,
        /// What is missing.
        message: String,
    },
}

fn parse_time_ns(s: &str) -> Option<u64> {
    let (secs, frac) = s.split_once('.').unwrap_or((s, ""));
    if secs.is_empty() || frac.len() > 9 || !frac.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let secs: u64 = secs.parse().ok()?;
    let mut frac_ns: u64 = if frac.is_empty() {
        0
    } else {
        frac.parse().ok()?
    };
    for _ in frac.len()..9 {
        frac_ns *= 10;
    }
    secs.checked_mul(1_000_000_000)?.checked_add(frac_ns)
}

fn parse_hex_bytes(s: &str) -> Option<Vec<u8>> {
    if !s.len().is_multiple_of(2) {
        return None;
    }
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(s.get(i..i + 2)?, 16).ok())
        .collect()
}

/// Parse one non-empty, non-comment line.
fn parse_line(text: &str, line: usize) -> Result<LoggedFrame, String> {
    let mut tokens = text.split_whitespace();
    let time = tokens.next().ok_or("empty line")?;
    let time = time
        .strip_prefix('(')
        .and_then(|t| t.strip_suffix(')'))
        .ok_or_else(|| format!("`{time}`: the time must be in parentheses"))?;
    let t_ns = parse_time_ns(time).ok_or_else(|| format!("`{time}`: not a time in seconds"))?;
    let interface = tokens.next().ok_or("no interface")?.to_string();
    let frame = tokens.next().ok_or("no frame")?;
    // `candump -L -x` may append a direction flag (R/T); anything more is not a frame line
    if let Some(extra) = tokens.next() {
        if !(extra == "R" || extra == "T") || tokens.next().is_some() {
            return Err(format!("`{extra}`: unexpected text after the frame"));
        }
    }
    let (id_hex, rest) = frame
        .split_once('#')
        .ok_or_else(|| format!("`{frame}`: no `#` between identifier and data"))?;
    let id_raw = u32::from_str_radix(id_hex, 16)
        .map_err(|_| format!("`{id_hex}`: the identifier is not hexadecimal"))?;
    let kind = if rest.starts_with('#') {
        LoggedKind::Fd
    } else if rest.starts_with('R') || rest.starts_with('r') {
        LoggedKind::Remote
    } else if id_hex.len() == 8 && id_raw & CAN_ERR_FLAG != 0 {
        LoggedKind::Error
    } else {
        let data = parse_hex_bytes(rest)
            .ok_or_else(|| format!("`{rest}`: the data is not an even number of hex digits"))?;
        if data.len() > 8 {
            return Err(format!(
                "{} data bytes: a classic CAN frame carries at most 8",
                data.len()
            ));
        }
        let id = match id_hex.len() {
            3 if id_raw <= 0x7FF => FrameId::Standard(id_raw as u16),
            8 if id_raw <= 0x1FFF_FFFF => FrameId::Extended(id_raw),
            _ => {
                return Err(format!(
                    "`{id_hex}`: an identifier has 3 (11-bit) or 8 (29-bit) hex digits"
                ))
            }
        };
        LoggedKind::Data { id, data }
    };
    Ok(LoggedFrame {
        t_ns,
        interface,
        kind,
        line,
    })
}

/// Parse the text of a `candump -l` log. Empty lines and lines starting with `#` are skipped;
/// any other line that is not a frame is an error naming its line.
pub fn parse(text: &str, path: &Path) -> Result<Vec<LoggedFrame>, CandumpError> {
    let mut out = Vec::new();
    for (i, l) in text.lines().enumerate() {
        let l = l.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        out.push(parse_line(l, i + 1).map_err(|message| CandumpError::Line {
            path: path.to_path_buf(),
            line: i + 1,
            message,
        })?);
    }
    Ok(out)
}

/// Read and parse a `candump -l` log file.
pub fn read(path: &Path) -> Result<Vec<LoggedFrame>, CandumpError> {
    let text = std::fs::read_to_string(path).map_err(|error| CandumpError::Io {
        path: path.to_path_buf(),
        error,
    })?;
    parse(&text, path)
}

/// What the import did with the log's frames.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportStats {
    /// Lines holding a frame.
    pub frames: usize,
    /// Frames of other interfaces than the one selected.
    pub other_interface: usize,
    /// Interface imported.
    pub interface: String,
    /// Receive counters of the sensor side (as the daemon's CAN task counts them).
    pub sensor_side: CanCountersSnapshot,
    /// Receive counters of the command side (actuator frames and heartbeat).
    pub command_side: CanCountersSnapshot,
    /// Log time span, s.
    pub span_s: f64,
}

/// A log turned into a recording.
#[derive(Debug, Clone)]
pub struct Import {
    /// One record per control tick; commands and mode are those seen on the bus (NaN / 0 where
    /// none was seen yet).
    pub recording: Recording,
    /// Counts.
    pub stats: ImportStats,
}

/// Turn logged frames into per-cycle records on a tick of `header.period_ns`, through the
/// daemon's receive path built from `codec` (the signal map's CAN bindings on the DBC).
/// `interface`: only frames of this interface (default: the first frame's). `op`: the
/// operator inputs of every record (the configured setpoints).
pub fn import(
    frames: &[LoggedFrame],
    codec: Arc<BusCodec>,
    header: Header,
    op: OperatorInputs,
    interface: Option<&str>,
    path: &Path,
) -> Result<Import, CandumpError> {
    let empty = |message: String| CandumpError::Empty {
        path: path.to_path_buf(),
        message,
    };
    let interface = interface
        .map(str::to_string)
        .or_else(|| frames.first().map(|f| f.interface.clone()))
        .ok_or_else(|| empty("the log holds no frames".into()))?;
    let mine: Vec<&LoggedFrame> = frames.iter().filter(|f| f.interface == interface).collect();
    let (Some(first), Some(last)) = (mine.first(), mine.last()) else {
        return Err(empty(format!("the log holds no frames of {interface}")));
    };
    if mine.windows(2).any(|w| w[1].t_ns < w[0].t_ns) {
        let bad = mine
            .windows(2)
            .find(|w| w[1].t_ns < w[0].t_ns)
            .map_or(0, |w| w[1].line);
        return Err(CandumpError::Line {
            path: path.to_path_buf(),
            line: bad,
            message: "time runs backwards".into(),
        });
    }
    let mut header = header;
    header.reason = "candump -l log".into();
    let period = header.period_ns.max(1);
    let t_first = first.t_ns;
    let arrival = |f: &LoggedFrame| f.t_ns - t_first + TIME_ORIGIN_NS;
    let sensors = Arc::new(SensorBoard::default());
    let commands = Arc::new(CommandBoard::default());
    let heartbeat = Arc::new(HeartbeatBoard::default());
    let (sc, cc) = (
        Arc::new(CanCounters::default()),
        Arc::new(CanCounters::default()),
    );
    let mut sensor_rx = RxHandler::controller(Arc::clone(&codec), Arc::clone(&sensors), sc.clone());
    let mut command_rx = RxHandler::plant(
        codec,
        Arc::clone(&commands),
        Arc::clone(&heartbeat),
        cc.clone(),
    );
    let end = arrival(last);
    let mut records = Vec::new();
    let mut next = 0usize;
    let mut k: u64 = 1;
    loop {
        // the daemon's time origin is one period before the first deadline
        let wake_ns = TIME_ORIGIN_NS + k * period;
        while let Some(f) = mine.get(next).filter(|f| arrival(f) <= wake_ns) {
            let t = arrival(f);
            for (rx, c) in [(&mut sensor_rx, &sc), (&mut command_rx, &cc)] {
                c.rx_frames.fetch_add(1, Relaxed);
                match &f.kind {
                    LoggedKind::Data { id, data } => {
                        rx.handle_data(*id, data, t);
                    }
                    LoggedKind::Remote => {
                        c.remote_frames.fetch_add(1, Relaxed);
                    }
                    LoggedKind::Fd => {
                        c.fd_frames.fetch_add(1, Relaxed);
                    }
                    LoggedKind::Error => {
                        c.error_frames.fetch_add(1, Relaxed);
                    }
                }
            }
            next += 1;
        }
        let raw = sensors.raw(wake_ns);
        let mut cmd = ActuatorCommands::default();
        for id in ActuatorId::ALL {
            cmd.set(id, commands.get(id).0);
        }
        let hb = heartbeat.latest();
        records.push(CycleRecord {
            cycle: k - 1,
            deadline_ns: wake_ns,
            wake_ns,
            t_s: (k * period) as f64 * 1e-9,
            raw,
            op,
            commands: cmd,
            mode: hb.map_or(crate::vocab::Mode::Init, |h| h.mode),
            law: hb.map_or(0, |h| h.law),
            law_diagnostic: f64::NAN,
            law_torque_nm: f64::NAN,
            m_used_kg_s: f64::NAN,
            m_observer_kg_s: f64::NAN,
            flow_fallback: false,
            surge_started: false,
            updates_applied: 0,
            voted: [f64::NAN; crate::control::vote::VOTABLE.len()],
        });
        if wake_ns >= end {
            break;
        }
        k += 1;
    }
    Ok(Import {
        recording: Recording { header, records },
        stats: ImportStats {
            frames: frames.len(),
            other_interface: frames.len() - mine.len(),
            interface,
            sensor_side: sc.snapshot(),
            command_side: cc.snapshot(),
            span_s: (last.t_ns - t_first) as f64 * 1e-9,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(l: &str) -> Result<LoggedFrame, String> {
        parse_line(l, 7)
    }

    #[test]
    fn lines_of_candump_l_parse() {
        let f = one("(1700000000.000250) can0 101#0011223344556677").expect("frame");
        assert_eq!(f.t_ns, 1_700_000_000_000_250_000);
        assert_eq!(f.interface, "can0");
        assert_eq!(
            f.kind,
            LoggedKind::Data {
                id: FrameId::Standard(0x101),
                data: vec![0, 0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77]
            }
        );
        let e = one("(1.5) vcan1 18FF0102#AB R").expect("extended");
        assert_eq!(e.t_ns, 1_500_000_000);
        assert_eq!(
            e.kind,
            LoggedKind::Data {
                id: FrameId::Extended(0x18FF_0102),
                data: vec![0xAB]
            }
        );
        assert_eq!(one("(2.0) can0 123#R").unwrap().kind, LoggedKind::Remote);
        assert_eq!(one("(2.0) can0 123##1AABB").unwrap().kind, LoggedKind::Fd);
        assert_eq!(
            one("(2.0) can0 20000004#0004000000000000").unwrap().kind,
            LoggedKind::Error
        );
        assert_eq!(
            one("(2.0) can0 123#").unwrap().kind,
            LoggedKind::Data {
                id: FrameId::Standard(0x123),
                data: vec![]
            }
        );
    }

    #[test]
    fn bad_lines_say_what_is_wrong() {
        for (l, want) in [
            ("1.0 can0 123#00", "parentheses"),
            ("(x) can0 123#00", "not a time"),
            ("(1.0) can0 123:00", "no `#`"),
            ("(1.0) can0 12G#00", "not hexadecimal"),
            ("(1.0) can0 123#001", "even number"),
            ("(1.0) can0 1234#00", "3 (11-bit) or 8 (29-bit)"),
            ("(1.0) can0 123#001122334455667788", "at most 8"),
            ("(1.0) can0 123#00 extra", "unexpected text"),
        ] {
            let e = one(l).expect_err(l);
            assert!(e.contains(want), "{l}: {e}");
        }
        let e = parse(
            "\n# comment\n(1.0) can0 123#00\nbroken\n",
            Path::new("x.log"),
        )
        .expect_err("line 4 is broken");
        let msg = e.to_string();
        assert!(msg.starts_with("x.log:4: "), "{msg}");
    }
}
