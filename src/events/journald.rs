//! The daemon's log lines to systemd-journald over its native protocol, with every
//! structured field under its own name (issue 25, item 7).
//!
//! Each tracing event is one datagram to journald's socket: `KEY=value\n` per field, or, for a
//! value holding a line break, `KEY\n`, the value's length as a little-endian u64, the value
//! and `\n` (systemd's "Native Journal Protocol"). Field names are the tracing field names
//! upper-cased, with no prefix: `input = "p_discharge"` is `INPUT=p_discharge`, which
//! `journalctl -u antisurge INPUT=p_discharge` matches (the `tracing-journald` layer used
//! before prefixed them, `F_INPUT`, so the documented match found nothing). Besides the
//! event's fields: `MESSAGE`, `PRIORITY` (error 3, warn 4, info 5 "notice", debug 6, trace 7: as before),
//! `TARGET` (the tracing target: `event`, `config`, `rt` …), `CODE_FILE`, `CODE_LINE` and
//! `SYSLOG_IDENTIFIER=antisurge`. Span fields are not sent.
//!
//! The socket is `/run/systemd/journal/socket`; the environment variable
//! `ANTISURGE_JOURNAL_SOCKET` names another one. It exists for the tests, which bind a datagram
//! socket in a temporary directory and read what the daemon sends (`tests/daemon/journal_fields.rs`);
//! a deployment has no reason to set it.

use std::io;
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::layer::{Context, Layer};

/// journald's native socket.
pub const JOURNAL_SOCKET: &str = "/run/systemd/journal/socket";

/// The environment variable that points the journal writer at another socket (tests).
pub const JOURNAL_SOCKET_ENV: &str = "ANTISURGE_JOURNAL_SOCKET";

/// The longest value sent, bytes (a longer one is cut, with `…` at the end): one datagram
/// stays well under the socket's send buffer.
pub const MAX_VALUE_BYTES: usize = 16 * 1024;

/// The socket the journal writer sends to: [`JOURNAL_SOCKET_ENV`] if set, else
/// [`JOURNAL_SOCKET`].
pub fn socket_path() -> PathBuf {
    std::env::var_os(JOURNAL_SOCKET_ENV)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(JOURNAL_SOCKET))
}

/// A tracing layer writing each event to journald.
#[derive(Debug)]
pub struct JournalLayer {
    socket: UnixDatagram,
    path: PathBuf,
    identifier: String,
}

impl JournalLayer {
    /// A writer to the journal socket at `path`; fails if nothing listens there.
    pub fn connect(path: &Path) -> io::Result<JournalLayer> {
        // a connected probe proves a listener; the writer itself sends to the path each time
        // (journald restarting re-creates its socket)
        UnixDatagram::unbound()?.connect(path)?;
        Ok(JournalLayer {
            socket: UnixDatagram::unbound()?,
            path: path.to_path_buf(),
            identifier: "antisurge".into(),
        })
    }
}

/// The journal field name of a tracing field: upper-case ASCII letters, digits and `_`,
/// not starting with `_` (journald's trusted fields) or a digit, at most 64 bytes.
pub fn field_name(name: &str) -> String {
    let mut out: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_uppercase()
            } else {
                '_'
            }
        })
        .collect();
    while out.starts_with('_') {
        out.remove(0);
    }
    if out.is_empty() || out.starts_with(|c: char| c.is_ascii_digit()) {
        out.insert_str(0, "FIELD_");
    }
    out.truncate(64);
    out
}

/// Append one field in the native protocol's form.
pub fn put_field(buf: &mut Vec<u8>, key: &str, value: &[u8]) {
    let value = if value.len() > MAX_VALUE_BYTES {
        let mut end = MAX_VALUE_BYTES;
        while end > 0 && (value[end] & 0xC0) == 0x80 {
            end -= 1; // not inside a UTF-8 sequence
        }
        &value[..end]
    } else {
        value
    };
    buf.extend_from_slice(key.as_bytes());
    if value.contains(&b'\n') {
        buf.push(b'\n');
        buf.extend_from_slice(&(value.len() as u64).to_le_bytes());
        buf.extend_from_slice(value);
    } else {
        buf.push(b'=');
        buf.extend_from_slice(value);
    }
    buf.push(b'\n');
}

fn priority(level: &Level) -> &'static [u8] {
    match *level {
        Level::ERROR => b"3",
        Level::WARN => b"4",
        Level::INFO => b"5",
        Level::DEBUG => b"6",
        _ => b"7",
    }
}

struct Fields<'a> {
    buf: &'a mut Vec<u8>,
}

impl Visit for Fields<'_> {
    fn record_str(&mut self, field: &Field, value: &str) {
        put_field(self.buf, &field_name(field.name()), value.as_bytes());
    }

    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        put_field(
            self.buf,
            &field_name(field.name()),
            format!("{value:?}").as_bytes(),
        );
    }
}

impl<S: Subscriber> Layer<S> for JournalLayer {
    fn on_event(&self, event: &Event<'_>, _ctx: Context<'_, S>) {
        let meta = event.metadata();
        let mut buf = Vec::with_capacity(256);
        put_field(&mut buf, "PRIORITY", priority(meta.level()));
        put_field(&mut buf, "SYSLOG_IDENTIFIER", self.identifier.as_bytes());
        put_field(&mut buf, "TARGET", meta.target().as_bytes());
        if let Some(f) = meta.file() {
            put_field(&mut buf, "CODE_FILE", f.as_bytes());
        }
        if let Some(l) = meta.line() {
            put_field(&mut buf, "CODE_LINE", l.to_string().as_bytes());
        }
        // the event's own fields, `message` as MESSAGE
        event.record(&mut Fields { buf: &mut buf });
        // nowhere to report a failed send: journald gone is not the controller's problem
        let _ = self.socket.send_to(&buf, &self.path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_names_follow_journald_rules() {
        assert_eq!(field_name("input"), "INPUT");
        assert_eq!(field_name("age_ms"), "AGE_MS");
        assert_eq!(field_name("_trusted"), "TRUSTED");
        assert_eq!(field_name("r#type"), "R_TYPE");
        assert_eq!(field_name("9lives"), "FIELD_9LIVES");
        assert_eq!(field_name(&"x".repeat(100)).len(), 64);
    }

    #[test]
    fn a_value_with_a_line_break_takes_the_binary_form() {
        let mut b = Vec::new();
        put_field(&mut b, "A", b"1");
        put_field(&mut b, "M", b"x\ny");
        let mut want = b"A=1\nM\n".to_vec();
        want.extend_from_slice(&3u64.to_le_bytes());
        want.extend_from_slice(b"x\ny\n");
        assert_eq!(b, want);
    }
}
