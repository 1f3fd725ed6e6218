//! `[event_log]` configuration: where the file lives, how often it is fsynced, and how it
//! rotates.
//!
//! ```toml
//! [event_log]
//! path = "events.jsonl"     # relative: under $LOGS_DIRECTORY (systemd), else ./out/
//! fsync = "interval"          # "always" | "interval" | "never"
//! fsync_interval_ms = 200     # only with fsync = "interval"
//! max_bytes = 16777216        # rotate before the file would grow past this
//! keep_files = 8              # rotated files kept: events.jsonl.1 … .8
//! rt_queue_capacity = 1024    # events the control thread can queue before drops
//! poll_interval_ms = 20       # how often the writer looks at the real-time queue
//! ```

use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::error::EventLogError;
use super::writer::MAX_LINE_BYTES;

/// When the writer calls `fdatasync` on the log file.
///
/// Lines reach the kernel with one `write` each whatever the policy, so a crash of the
/// process loses nothing already written; the policy only decides what survives a power
/// cut or kernel crash. Rotation and clean shutdown always sync.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FsyncPolicy {
    /// After every line: nothing acknowledged is lost, at the cost of one sync per event.
    Always,
    /// At most every `interval_ms` milliseconds, and only if something was written.
    Interval {
        /// Minimum time between two syncs, ms.
        interval_ms: u64,
    },
    /// Never (except at rotation and clean shutdown); leave it to the kernel.
    Never,
}

/// Configuration of the event log. Deserializes from the `[event_log]` table with the keys
/// shown in the module documentation; every key has a default.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "RawConfig", into = "RawConfig")]
pub struct EventLogConfig {
    /// The live log file; rotated files get `.1`, `.2` … appended.
    pub path: PathBuf,
    /// Sync policy.
    pub fsync: FsyncPolicy,
    /// Rotate before the live file would exceed this many bytes (≥ 4096).
    pub max_bytes: u64,
    /// How many rotated files to keep (0: delete the live file's content at rotation).
    pub keep_files: u32,
    /// Capacity of each real-time ring buffer, events.
    pub rt_queue_capacity: usize,
    /// How often the writer drains the real-time queues when nothing else wakes it, ms.
    pub poll_interval_ms: u64,
}

impl Default for EventLogConfig {
    fn default() -> Self {
        EventLogConfig {
            // relative, so the daemon puts it under `$LOGS_DIRECTORY` (systemd's
            // `LogsDirectory=antisurge`: /var/log/antisurge), else under ./out/
            path: PathBuf::from("events.jsonl"),
            fsync: FsyncPolicy::Interval { interval_ms: 200 },
            max_bytes: 16 * 1024 * 1024,
            keep_files: 8,
            rt_queue_capacity: 1024,
            poll_interval_ms: 20,
        }
    }
}

impl EventLogConfig {
    /// Defaults with another path (handy for tests and tools).
    pub fn with_path(path: impl Into<PathBuf>) -> Self {
        EventLogConfig {
            path: path.into(),
            ..EventLogConfig::default()
        }
    }

    /// Check value ranges. Called by [`EventLog::start`](super::EventLog::start) and by
    /// deserialization.
    pub fn validate(&self) -> Result<(), EventLogError> {
        let bad = |key: &'static str, message: String| Err(EventLogError::Setting { key, message });
        if self.path.as_os_str().is_empty() || self.path.file_name().is_none() {
            return bad("path", format!("path {:?} does not name a file", self.path));
        }
        if self.max_bytes < MAX_LINE_BYTES as u64 {
            return bad(
                "max_bytes",
                format!(
                    "max_bytes = {} is below the longest line ({MAX_LINE_BYTES} bytes)",
                    self.max_bytes
                ),
            );
        }
        if self.keep_files > 999 {
            return bad(
                "keep_files",
                format!("keep_files = {} is above 999", self.keep_files),
            );
        }
        if !(1..=1 << 20).contains(&self.rt_queue_capacity) {
            return bad(
                "rt_queue_capacity",
                format!(
                    "rt_queue_capacity = {} must be 1 ..= 1048576",
                    self.rt_queue_capacity
                ),
            );
        }
        if !(1..=1000).contains(&self.poll_interval_ms) {
            return bad(
                "poll_interval_ms",
                format!(
                    "poll_interval_ms = {} must be 1 ..= 1000",
                    self.poll_interval_ms
                ),
            );
        }
        if let FsyncPolicy::Interval { interval_ms: 0 } = self.fsync {
            return bad(
                "fsync_interval_ms",
                "fsync_interval_ms = 0: use fsync = \"always\" instead".into(),
            );
        }
        Ok(())
    }

    /// The typed error of an `[event_log]` table whose values are refused (`None` if the
    /// table is accepted or its error is not about a value: an unknown key, a wrong type).
    /// Deserialization reports such an error as text only; this gives it back with its key.
    pub fn setting_error(table: &toml::Table) -> Option<EventLogError> {
        let raw: RawConfig = toml::Value::Table(table.clone()).try_into().ok()?;
        EventLogConfig::try_from(raw).err()
    }

    /// The writer's idle wake-up period.
    pub(crate) fn poll_interval(&self) -> Duration {
        Duration::from_millis(self.poll_interval_ms)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
enum FsyncMode {
    Always,
    Interval,
    Never,
}

/// The flat file representation; the public struct folds `fsync` + `fsync_interval_ms`
/// into [`FsyncPolicy`].
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
struct RawConfig {
    path: PathBuf,
    fsync: FsyncMode,
    #[serde(skip_serializing_if = "Option::is_none")]
    fsync_interval_ms: Option<u64>,
    max_bytes: u64,
    keep_files: u32,
    rt_queue_capacity: usize,
    poll_interval_ms: u64,
}

impl Default for RawConfig {
    fn default() -> Self {
        // No interval unless given, so `fsync = "always"` alone is not a contradiction.
        let mut raw = RawConfig::from(EventLogConfig::default());
        raw.fsync_interval_ms = None;
        raw
    }
}

impl From<EventLogConfig> for RawConfig {
    fn from(c: EventLogConfig) -> Self {
        let (fsync, fsync_interval_ms) = match c.fsync {
            FsyncPolicy::Always => (FsyncMode::Always, None),
            FsyncPolicy::Interval { interval_ms } => (FsyncMode::Interval, Some(interval_ms)),
            FsyncPolicy::Never => (FsyncMode::Never, None),
        };
        RawConfig {
            path: c.path,
            fsync,
            fsync_interval_ms,
            max_bytes: c.max_bytes,
            keep_files: c.keep_files,
            rt_queue_capacity: c.rt_queue_capacity,
            poll_interval_ms: c.poll_interval_ms,
        }
    }
}

impl TryFrom<RawConfig> for EventLogConfig {
    type Error = EventLogError;
    fn try_from(r: RawConfig) -> Result<Self, EventLogError> {
        const DEFAULT_INTERVAL_MS: u64 = 200;
        let fsync = match (r.fsync, r.fsync_interval_ms) {
            (FsyncMode::Always, None) => FsyncPolicy::Always,
            (FsyncMode::Never, None) => FsyncPolicy::Never,
            (FsyncMode::Interval, ms) => FsyncPolicy::Interval {
                interval_ms: ms.unwrap_or(DEFAULT_INTERVAL_MS),
            },
            (mode, Some(_)) => {
                return Err(EventLogError::Setting {
                    key: "fsync_interval_ms",
                    message: format!(
                        "fsync_interval_ms only applies to fsync = \"interval\", not {mode:?}"
                    ),
                })
            }
        };
        let c = EventLogConfig {
            path: r.path,
            fsync,
            max_bytes: r.max_bytes,
            keep_files: r.keep_files,
            rt_queue_capacity: r.rt_queue_capacity,
            poll_interval_ms: r.poll_interval_ms,
        };
        c.validate()?;
        Ok(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<EventLogConfig, toml::de::Error> {
        toml::from_str(text)
    }

    #[test]
    fn empty_table_gives_defaults() {
        assert_eq!(parse("").expect("empty"), EventLogConfig::default());
    }

    #[test]
    fn all_keys() {
        let c = parse(
            r#"
            path = "/tmp/x/events.jsonl"
            fsync = "interval"
            fsync_interval_ms = 50
            max_bytes = 65536
            keep_files = 3
            rt_queue_capacity = 64
            poll_interval_ms = 5
            "#,
        )
        .expect("valid");
        assert_eq!(c.path, PathBuf::from("/tmp/x/events.jsonl"));
        assert_eq!(c.fsync, FsyncPolicy::Interval { interval_ms: 50 });
        assert_eq!(c.max_bytes, 65536);
        assert_eq!(c.keep_files, 3);
        assert_eq!(c.rt_queue_capacity, 64);
        assert_eq!(c.poll_interval_ms, 5);
    }

    #[test]
    fn fsync_modes() {
        assert_eq!(
            parse(r#"fsync = "always""#).expect("always").fsync,
            FsyncPolicy::Always
        );
        assert_eq!(
            parse(r#"fsync = "never""#).expect("never").fsync,
            FsyncPolicy::Never
        );
        assert_eq!(
            parse(r#"fsync = "interval""#).expect("interval").fsync,
            FsyncPolicy::Interval { interval_ms: 200 }
        );
    }

    #[test]
    fn rejects_bad_values() {
        for bad in [
            r#"fsync = "sometimes""#,
            r#"fsync = "always"
               fsync_interval_ms = 10"#,
            r#"fsync_interval_ms = 0"#,
            "max_bytes = 100",
            "keep_files = 5000",
            "rt_queue_capacity = 0",
            "poll_interval_ms = 0",
            "max_byte = 100000",
            r#"path = """#,
        ] {
            assert!(parse(bad).is_err(), "accepted: {bad}");
        }
    }

    #[test]
    fn serializes_back_to_the_same_config() {
        let c = EventLogConfig {
            fsync: FsyncPolicy::Always,
            ..EventLogConfig::with_path("/a/b.jsonl")
        };
        let text = toml::to_string(&c).expect("serialize");
        assert!(text.contains("fsync = \"always\""), "{text}");
        assert!(!text.contains("fsync_interval_ms"), "{text}");
        assert_eq!(parse(&text).expect("reparse"), c);
    }
}
