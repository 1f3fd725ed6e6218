//! What every field link (CAN interface, Modbus connection) reports, in one vocabulary, and
//! the state→event wiring written once.
//!
//! A transport task keeps its own socket, retry and backoff, and tells a
//! [`FieldLinkReporter`] what happened: link state changes ([`BusState`]) and faults
//! ([`FaultCategory`] with a cause in words). The reporter drops repeats and turns every
//! transition into one `bus_state` or `field_fault` event, one journal line and the active
//! fault word ([`FieldLinkReporter::faults`]) that status shows; the same faults go to the
//! daemon's [`FieldFaults`] handle, for the fault word on the wire.

use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;

use super::FieldFaults;
use crate::events::event::{BusState, Event};
use crate::vocab::faults::{FaultCategory, FaultSet, FieldLinkKind};

/// Where a reporter's events go (the daemon's event sender, or a test's vector).
pub type EventSink = Arc<dyn Fn(Event) + Send + Sync>;

/// Where the links' reports go: the event sink and the field-fault handle. The daemon builds
/// one and hands it to every link task, which makes its reporters from it.
#[derive(Clone)]
pub struct LinkReports {
    /// Events.
    pub sink: EventSink,
    /// The fault word on the wire, and the links down.
    pub faults: Arc<FieldFaults>,
}

impl LinkReports {
    /// A reporter for `link` (e.g. `can0`, `modbus:10.0.0.5:502`).
    pub fn reporter(&self, link: impl Into<String>) -> FieldLinkReporter {
        FieldLinkReporter::new(link, Arc::clone(&self.sink), Arc::clone(&self.faults))
    }
}

/// Reports one link's transitions (see the module documentation).
pub struct FieldLinkReporter {
    link: String,
    sink: EventSink,
    last: Option<BusState>,
    faults: Arc<AtomicU32>,
    causes: [Option<String>; FaultCategory::ALL.len()],
    /// Where active faults go for the fault word on the wire (`None`: nowhere, tests, tools).
    field: Option<Arc<FieldFaults>>,
    /// Whether the link is down now (as told to [`FieldFaults::link_down`]).
    down: bool,
}

impl Drop for FieldLinkReporter {
    fn drop(&mut self) {
        if let Some(field) = &self.field {
            for c in FaultSet(self.faults.load(Ordering::Relaxed)).categories() {
                field.clear(c);
            }
            if self.down {
                field.link_down(FieldLinkKind::of_link_name(&self.link), false);
            }
        }
    }
}

impl std::fmt::Debug for FieldLinkReporter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FieldLinkReporter")
            .field("link", &self.link)
            .field("last", &self.last)
            .field("faults", &self.faults.load(Ordering::Relaxed))
            .finish()
    }
}

impl FieldLinkReporter {
    /// A reporter for `link` (e.g. `can0`, `modbus:10.0.0.5:502`) sending to `sink`, its
    /// faults counted in `field`.
    pub fn new(
        link: impl Into<String>,
        sink: EventSink,
        field: Arc<FieldFaults>,
    ) -> FieldLinkReporter {
        let mut r = FieldLinkReporter::detached(link, sink);
        r.field = Some(field);
        r
    }

    /// A reporter whose faults stay out of the fault word on the wire (tests, tools).
    pub fn detached(link: impl Into<String>, sink: EventSink) -> FieldLinkReporter {
        FieldLinkReporter {
            link: link.into(),
            sink,
            last: None,
            faults: Arc::new(AtomicU32::new(0)),
            causes: Default::default(),
            field: None,
            down: false,
        }
    }

    /// The link's name.
    pub fn link(&self) -> &str {
        &self.link
    }

    /// The active fault word, shared (for status).
    pub fn faults(&self) -> Arc<AtomicU32> {
        Arc::clone(&self.faults)
    }

    /// A state change: one `bus_state` event and one journal line when it differs from the
    /// last one; `detail` says why, in words. A link going down also raises
    /// [`FaultCategory::FieldLinkDown`]; coming up clears it.
    pub fn state(&mut self, state: BusState, detail: &str) {
        if self.last == Some(state) {
            return;
        }
        self.last = Some(state);
        match state {
            BusState::Up => {
                tracing::info!(target: "field", link = %self.link, "link up {detail}")
            }
            _ => tracing::warn!(target: "field", link = %self.link, ?state, "link {detail}"),
        }
        (self.sink)(Event::BusState {
            interface: self.link.clone(),
            state,
        });
        // reconnecting is still down: the link stays the root of its stale inputs until it
        // is up again
        let down = matches!(
            state,
            BusState::Down | BusState::BusOff | BusState::Reconnecting
        );
        let was_down = self.down;
        if let Some(field) = self.field.as_ref().filter(|_| down != was_down) {
            // the root cause the control thread names when the inputs this link carries go
            // stale ("Modbus link down", not "p_suction stale")
            field.link_down(FieldLinkKind::of_link_name(&self.link), down);
        }
        self.down = down;
        if down && (!was_down || state != BusState::Reconnecting) {
            self.fault(FaultCategory::FieldLinkDown, true, detail);
        } else if state == BusState::Up {
            self.fault(FaultCategory::FieldLinkDown, false, "link up");
        }
    }

    /// Raise (`active`) or clear a fault with its cause. Repeats (same state and cause) are
    /// dropped; a raised fault with a new cause is reported again.
    pub fn fault(&mut self, fault: FaultCategory, active: bool, cause: &str) {
        let i = usize::from(fault.code());
        let was = FaultSet(self.faults.load(Ordering::Relaxed)).has(fault);
        if active && was && self.causes[i].as_deref() == Some(cause) {
            return;
        }
        if !active && !was {
            return;
        }
        if active {
            if let Some(field) = self.field.as_ref().filter(|_| !was) {
                field.raise(fault);
            }
            self.faults.fetch_or(fault.bit(), Ordering::Relaxed);
            self.causes[i] = Some(cause.to_string());
            tracing::error!(target: "field", link = %self.link, fault = fault.name(), "{}: {cause}", fault.describe());
        } else {
            if let Some(field) = &self.field {
                field.clear(fault);
            }
            self.faults.fetch_and(!fault.bit(), Ordering::Relaxed);
            self.causes[i] = None;
            tracing::info!(target: "field", link = %self.link, fault = fault.name(), "cleared: {cause}");
        }
        (self.sink)(Event::FieldFault {
            link: self.link.clone(),
            fault,
            active,
            cause: cause.to_string(),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    fn reporter() -> (FieldLinkReporter, Arc<Mutex<Vec<Event>>>) {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let s = Arc::clone(&seen);
        let r =
            FieldLinkReporter::detached("modbus:x", Arc::new(move |e| s.lock().unwrap().push(e)));
        (r, seen)
    }

    #[test]
    fn transitions_become_events_once() {
        let (mut r, seen) = reporter();
        r.state(BusState::Up, "");
        r.state(BusState::Up, "");
        r.state(BusState::Down, "connection refused");
        r.state(BusState::Down, "connection refused");
        r.state(BusState::Up, "");
        let kinds: Vec<String> = seen
            .lock()
            .unwrap()
            .iter()
            .map(|e| match e {
                Event::BusState { state, .. } => format!("{state:?}"),
                Event::FieldFault { fault, active, .. } => format!("{}={active}", fault.name()),
                other => other.kind().to_string(),
            })
            .collect();
        assert_eq!(
            kinds,
            [
                "Up",
                "Down",
                "field_link_down=true",
                "Up",
                "field_link_down=false"
            ]
        );
        assert_eq!(r.faults().load(Ordering::Relaxed), 0);
    }

    #[test]
    fn the_handle_counts_the_reporters_faults_and_a_dropped_reporter_clears_them() {
        let field = Arc::new(FieldFaults::default());
        let mut a = FieldLinkReporter::new("can0", Arc::new(|_| {}), Arc::clone(&field));
        let mut b = FieldLinkReporter::new("modbus:x", Arc::new(|_| {}), Arc::clone(&field));
        a.state(BusState::Down, "interface down");
        b.fault(FaultCategory::FieldWriteFailed, true, "exception 2");
        assert_eq!(field.down_link(), Some(FieldLinkKind::Can));
        assert_eq!(
            field.word(),
            FaultCategory::FieldLinkDown.bit() | FaultCategory::FieldWriteFailed.bit()
        );
        drop(a);
        assert_eq!(
            field.down_link(),
            None,
            "a reporter gone takes its link down with it"
        );
        assert_eq!(field.word(), FaultCategory::FieldWriteFailed.bit());
        b.fault(FaultCategory::FieldWriteFailed, false, "written");
        assert_eq!(field.word(), 0);
        let (mut d, _) = reporter();
        d.fault(FaultCategory::FieldWriteFailed, true, "exception 2");
        assert_eq!(field.word(), 0, "a detached reporter counts nowhere");
    }

    #[test]
    fn a_reconnecting_link_stays_down_and_the_root_of_its_stale_inputs() {
        let field = Arc::new(FieldFaults::default());
        let mut r = FieldLinkReporter::new("can0", Arc::new(|_| {}), Arc::clone(&field));
        r.state(BusState::Up, "");
        r.state(BusState::Down, "down: receive failed");
        r.state(BusState::Reconnecting, "reconnect attempt 1 in 50 ms");
        assert_eq!(field.down_link(), Some(FieldLinkKind::Can));
        assert_eq!(field.word(), FaultCategory::FieldLinkDown.bit());
        r.state(BusState::Up, "");
        assert_eq!(field.down_link(), None);
        assert_eq!(field.word(), 0);
    }

    #[test]
    fn fault_with_new_cause_is_reported_again() {
        let (mut r, seen) = reporter();
        r.fault(FaultCategory::FieldWriteFailed, true, "exception 2");
        r.fault(FaultCategory::FieldWriteFailed, true, "exception 2");
        r.fault(FaultCategory::FieldWriteFailed, true, "timeout");
        assert_eq!(
            r.faults().load(Ordering::Relaxed),
            FaultCategory::FieldWriteFailed.bit()
        );
        r.fault(FaultCategory::FieldWriteFailed, false, "acknowledged");
        r.fault(FaultCategory::FieldWriteFailed, false, "acknowledged");
        assert_eq!(seen.lock().unwrap().len(), 2 + 1);
    }
}
