//! What every field link (CAN interface, Modbus connection) shares: the face it shows the
//! daemon ([`FieldLink`]), the one state type ([`LinkState`]), the one counters type
//! ([`LinkTraffic`], declared with [`link_counters!`]), the one retry strategy
//! ([`Backoff`]), the reporter that turns its transitions into events, journal lines and fault
//! bits ([`FieldLinkReporter`]), and the field-fault handle those bits go to
//! ([`FieldFaults`]), created once by the daemon and passed in (no process-wide state: two
//! daemons, or two tests, in one process share nothing).

mod backoff;
mod counters;
mod faults;
mod field_link;
mod reporter;
mod state;

pub use backoff::Backoff;
pub(crate) use counters::link_counters;
pub use counters::LinkTraffic;
pub use faults::FieldFaults;
pub use field_link::{FieldLink, FieldLinks};
pub use reporter::{EventSink, FieldLinkReporter, LinkReports};
pub use state::{Degradation, DownReason, LinkState};
