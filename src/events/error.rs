//! The one error type of the event log. Every variant that touches a file names it.

use std::io;
use std::path::PathBuf;

/// Errors of the event-log writer, reader and configuration.
#[derive(Debug, thiserror::Error)]
pub enum EventLogError {
    /// A file-system operation on `path` failed.
    #[error("event log {}: cannot {action}: {source}", .path.display())]
    Io {
        /// File or directory concerned.
        path: PathBuf,
        /// What was being done, e.g. `open for appending`.
        action: &'static str,
        /// The OS error.
        #[source]
        source: io::Error,
    },
    /// Neither the log file nor any rotated file exists.
    #[error("no event log at {} (nor any rotated {}.N)", .path.display(), .path.display())]
    NotFound {
        /// The log path asked for.
        path: PathBuf,
    },
    /// The `[event_log]` configuration is unusable.
    #[error("event log configuration: {0}")]
    Config(String),
    /// An `[event_log]` key has an unusable value.
    #[error("event log configuration: {message}")]
    Setting {
        /// The key within `[event_log]` (`max_bytes`, `fsync_interval_ms`).
        key: &'static str,
        /// What is wrong with it.
        message: String,
    },
    /// A time given on the command line (e.g. `--since`) is not understood.
    #[error("invalid time {text:?}: {reason}")]
    Time {
        /// What was given.
        text: String,
        /// Why it was refused and what is accepted.
        reason: String,
    },
    /// The writer thread has stopped, so the event cannot be logged.
    #[error("event log writer for {} has stopped", .path.display())]
    Closed {
        /// The log path.
        path: PathBuf,
    },
    /// The writer thread panicked.
    #[error("event log writer thread for {} panicked", .path.display())]
    WriterPanicked {
        /// The log path.
        path: PathBuf,
    },
    /// Writing the listing to the output (terminal, pipe) failed.
    #[error("cannot write event listing: {0}")]
    Output(#[source] io::Error),
}

impl EventLogError {
    /// Shorthand for [`EventLogError::Io`].
    pub(crate) fn io(path: impl Into<PathBuf>, action: &'static str, source: io::Error) -> Self {
        EventLogError::Io {
            path: path.into(),
            action,
            source,
        }
    }
}
