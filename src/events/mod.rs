//! The append-only JSON Lines event log: what happened, for the operator and the controls
//! engineer reading it after an incident.
//!
//! - [`event`]: the [`Event`] kinds and their payloads; one JSON object per line,
//!   `{"ts":"<RFC 3339 UTC µs>","seq":N,"event":"<kind>",…fields}`.
//! - [`rt_channel`]: [`RtSender`], the wait-free, allocation-free path for the control thread
//!   ([`RtEvent`], [`OverrunReporter`]).
//! - [`writer`]: [`EventLog`], the writer thread owning the file (append, fsync policy,
//!   rotation, torn-tail repair, `seq` resume); [`EventSender`] for non-real-time producers.
//! - [`reader`] and [`print`](mod@print): read the rotated set back, report torn and invalid lines,
//!   filter by time, print for terminals ([`print_events`]).
//! - [`config`]: [`EventLogConfig`], the `[event_log]` table.
//! - [`journal`]: the events' journal lines; [`journald`]: the native-protocol writer.
//! - [`timestamp`]: [`Timestamp`], RFC 3339 UTC formatting and parsing, and [`timestamp::parse_time`],
//!   the one parser of the times an operator types (jiff + humantime).

pub mod cause;
pub mod config;
pub mod error;
pub mod event;
pub mod journal;
pub mod journald;
pub mod print;
pub mod reader;
pub mod rt_channel;
pub mod timestamp;
pub mod writer;

pub use config::{EventLogConfig, FsyncPolicy};
pub use error::EventLogError;
pub use event::{
    BusState, ConfigChange, DeadlineOverrun, DropCause, Event, FallbackEntered, FallbackLeft,
    FallbackReason, Law, LawChanged, ModeChanged, RecycleTrip, Replacement, SafetyOnShift,
    SurgeCounter, SurgeDetected, Transmitter, TripReason,
};
pub use print::{format_pretty, print_events, PrintFormat};
pub use reader::{
    log_files, parse_since, parse_time_arg, read_files, read_log, EventFilter, InvalidLine,
    ReadStats, Record, SeqBreak, TornTail,
};
pub use rt_channel::{OverrunReporter, RtEvent, RtSender};
pub use timestamp::Timestamp;
pub use writer::{EventLog, EventSender, WriterStats, MAX_LINE_BYTES};
