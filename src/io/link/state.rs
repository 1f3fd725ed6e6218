//! The one link-state type every field link publishes (CAN interface, Modbus connection).
//!
//! A link is idle until it first opens, then up, degraded (passing traffic, with trouble the
//! transport names: a CAN controller's error-warning or error-passive state, a Modbus device's
//! exception answers), down (with the reconnect attempt awaited, its backoff and the cause the
//! transport names), or stopped. The transports differ only in the two words they fill in:
//! `D`, what a degraded link reports, and `C`, why a link is down. The status name, the event
//! a change makes and the display are written once, here.

use std::fmt;

/// What a degraded link reports (a CAN error state, a Modbus exception).
pub trait Degradation: fmt::Display + Copy {
    /// The link's state name in the status while degraded: `up` where traffic passes as usual
    /// (a CAN controller's error states), or a word of its own (`exception`).
    fn status_name(&self) -> &'static str;
}

/// Why a link is down.
pub trait DownReason: fmt::Display + Copy {
    /// Whether this is a CAN bus-off (the event log names it apart).
    fn is_bus_off(&self) -> bool {
        false
    }
}

/// The state of a field link (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LinkState<D, C> {
    /// Not opened or not exchanged with yet.
    Idle,
    /// Passing traffic normally.
    Up,
    /// Passing traffic, with trouble (see [`Degradation`]).
    Degraded(D),
    /// Down: the transport is closed and reconnects with backoff. A failure reads
    /// `Down { attempt: 0, .. }` (just failed), then `Down { attempt: 1, .. }`, `2`, … while
    /// reconnecting fails, then `Up`.
    Down {
        /// The reconnect attempt awaited since the link was last up (0: none scheduled yet).
        attempt: u32,
        /// The wait before that attempt, ms.
        backoff_ms: u64,
        /// The last failure.
        cause: C,
    },
    /// The link's task ended (shutdown).
    Stopped,
}

impl<D: Degradation, C: DownReason> LinkState<D, C> {
    /// Down just now, no reconnect scheduled yet.
    pub fn down(cause: C) -> LinkState<D, C> {
        LinkState::Down {
            attempt: 0,
            backoff_ms: 0,
            cause,
        }
    }

    /// Whether the link passes traffic (up or degraded).
    pub fn is_up(&self) -> bool {
        matches!(self, LinkState::Up | LinkState::Degraded(_))
    }

    /// Whether the link is down (closed, reconnecting).
    pub fn is_down(&self) -> bool {
        matches!(self, LinkState::Down { .. })
    }

    /// The state's name in the status and on the HMI: `idle`, `up`, the degradation's own
    /// name, `down`, `stopped`.
    pub fn status_name(&self) -> &'static str {
        match self {
            LinkState::Idle => "idle",
            LinkState::Up => "up",
            LinkState::Degraded(d) => d.status_name(),
            LinkState::Down { .. } => "down",
            LinkState::Stopped => "stopped",
        }
    }

    /// The event-log vocabulary for this state, one entry per outage: `bus_off` or `down`
    /// when the link fails, `reconnecting` at the first attempt (later attempts give `None`),
    /// `up`. `None` for idle and stopped, which the daemon logs itself. A degraded link counts
    /// as up: it still passes traffic.
    pub fn to_event(&self) -> Option<crate::events::event::BusState> {
        use crate::events::event::BusState as E;
        match self {
            LinkState::Idle | LinkState::Stopped => None,
            LinkState::Up | LinkState::Degraded(_) => Some(E::Up),
            LinkState::Down {
                attempt: 0, cause, ..
            } if cause.is_bus_off() => Some(E::BusOff),
            LinkState::Down { attempt: 0, .. } => Some(E::Down),
            LinkState::Down { attempt: 1, .. } => Some(E::Reconnecting),
            LinkState::Down { .. } => None,
        }
    }
}

impl<D: Degradation, C: DownReason> fmt::Display for LinkState<D, C> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LinkState::Idle => f.write_str("starting"),
            LinkState::Up => f.write_str("up"),
            LinkState::Degraded(d) => write!(f, "up, {d}"),
            LinkState::Down {
                attempt: 0, cause, ..
            } => write!(f, "down: {cause}"),
            LinkState::Down {
                attempt,
                backoff_ms,
                cause,
            } => write!(
                f,
                "reconnect attempt {attempt} in {backoff_ms} ms (down: {cause})"
            ),
            LinkState::Stopped => f.write_str("stopped"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::event::BusState as E;

    #[derive(Debug, Clone, Copy, PartialEq)]
    struct Busy;
    impl fmt::Display for Busy {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str("busy")
        }
    }
    impl Degradation for Busy {
        fn status_name(&self) -> &'static str {
            "exception"
        }
    }
    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Cause {
        Gone,
        BusOff,
    }
    impl fmt::Display for Cause {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str(match self {
                Cause::Gone => "gone",
                Cause::BusOff => "bus-off",
            })
        }
    }
    impl DownReason for Cause {
        fn is_bus_off(&self) -> bool {
            *self == Cause::BusOff
        }
    }
    type S = LinkState<Busy, Cause>;

    #[test]
    fn an_outage_is_one_down_one_reconnecting_and_one_up_in_the_event_log() {
        let outage = [
            S::Up,
            S::down(Cause::Gone),
            S::Down {
                attempt: 1,
                backoff_ms: 100,
                cause: Cause::Gone,
            },
            S::Down {
                attempt: 2,
                backoff_ms: 200,
                cause: Cause::Gone,
            },
            S::Up,
        ];
        let events: Vec<_> = outage.iter().filter_map(S::to_event).collect();
        assert_eq!(events, [E::Up, E::Down, E::Reconnecting, E::Up]);
        assert_eq!(S::down(Cause::BusOff).to_event(), Some(E::BusOff));
        assert_eq!(S::Idle.to_event(), None);
        assert_eq!(S::Stopped.to_event(), None);
        assert_eq!(S::Degraded(Busy).to_event(), Some(E::Up));
    }

    #[test]
    fn names_and_words() {
        assert_eq!(S::Degraded(Busy).status_name(), "exception");
        assert!(S::Degraded(Busy).is_up() && !S::Degraded(Busy).is_down());
        let d = S::Down {
            attempt: 3,
            backoff_ms: 400,
            cause: Cause::Gone,
        };
        assert!(d.is_down() && !d.is_up());
        assert_eq!(d.status_name(), "down");
        assert_eq!(d.to_string(), "reconnect attempt 3 in 400 ms (down: gone)");
        assert_eq!(S::down(Cause::BusOff).to_string(), "down: bus-off");
        assert_eq!(S::Degraded(Busy).to_string(), "up, busy");
        assert_eq!(S::Idle.status_name(), "idle");
        assert_eq!(S::Stopped.status_name(), "stopped");
    }
}
