//! What every field link (CAN interface, Modbus connection) shares: the one retry strategy
//! ([`Backoff`]), the reporter that turns its transitions into events, journal lines and fault
//! bits ([`FieldLinkReporter`]), and the field-fault handle those bits go to
//! ([`FieldFaults`]), created once by the daemon and passed in (no process-wide state: two
//! daemons, or two tests, in one process share nothing).

mod backoff;
mod faults;
mod reporter;

pub use backoff::Backoff;
pub use faults::FieldFaults;
pub use reporter::{EventSink, FieldLinkReporter, LinkReports};
