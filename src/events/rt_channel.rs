//! The real-time hand-off: how the 1 kHz control thread emits events without allocating,
//! locking or doing I/O.
//!
//! The control thread owns an [`RtSender`], the producer half of a wait-free single-producer
//! single-consumer ring buffer (`rtrb`) of fixed-size, `Copy` [`RtEvent`]s, each stamped with
//! the wall-clock time of the push. If the ring is full the event is dropped and a shared
//! atomic counter is incremented; the writer thread turns that count into an
//! `events_dropped` line. [`OverrunReporter`] rate-limits deadline-overrun reports in the
//! same allocation-free way.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::event::{
    DeadlineOverrun, Event, FallbackEntered, FallbackLeft, LawChanged, ModeChanged, RecycleTrip,
    SafetyOnShift, SurgeCounter, SurgeDetected, Transmitter,
};
use super::timestamp::Timestamp;

/// The events the control thread can emit: the kinds whose data is fixed-size.
///
/// `Copy`, no heap data; converts into [`Event`] on the writer side.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RtEvent {
    /// See [`Event::SurgeDetected`].
    SurgeDetected(SurgeDetected),
    /// See [`Event::SurgeCounter`].
    SurgeCounter(SurgeCounter),
    /// See [`Event::SafetyOnShift`].
    SafetyOnShift(SafetyOnShift),
    /// See [`Event::ModeChanged`].
    ModeChanged(ModeChanged),
    /// See [`Event::LawChanged`].
    LawChanged(LawChanged),
    /// See [`Event::FallbackEntered`].
    FallbackEntered(FallbackEntered),
    /// See [`Event::FallbackLeft`].
    FallbackLeft(FallbackLeft),
    /// See [`Event::DeadlineOverrun`].
    DeadlineOverrun(DeadlineOverrun),
    /// See [`Event::RecycleTrip`].
    RecycleTrip(RecycleTrip),
    /// See [`Event::Transmitter`].
    Transmitter(Transmitter),
}

impl From<RtEvent> for Event {
    fn from(e: RtEvent) -> Event {
        match e {
            RtEvent::SurgeDetected(p) => Event::SurgeDetected(p),
            RtEvent::SurgeCounter(p) => Event::SurgeCounter(p),
            RtEvent::SafetyOnShift(p) => Event::SafetyOnShift(p),
            RtEvent::ModeChanged(p) => Event::ModeChanged(p),
            RtEvent::LawChanged(p) => Event::LawChanged(p),
            RtEvent::FallbackEntered(p) => Event::FallbackEntered(p),
            RtEvent::FallbackLeft(p) => Event::FallbackLeft(p),
            RtEvent::DeadlineOverrun(p) => Event::DeadlineOverrun(p),
            RtEvent::RecycleTrip(p) => Event::RecycleTrip(p),
            RtEvent::Transmitter(p) => Event::Transmitter(p),
        }
    }
}

macro_rules! rt_from {
    ($($t:ident),*) => {$(
        impl From<$t> for RtEvent {
            fn from(p: $t) -> RtEvent {
                RtEvent::$t(p)
            }
        }
    )*};
}
rt_from!(
    SurgeDetected,
    SurgeCounter,
    SafetyOnShift,
    ModeChanged,
    LawChanged,
    FallbackEntered,
    FallbackLeft,
    DeadlineOverrun,
    RecycleTrip,
    Transmitter
);

/// An [`RtEvent`] with the time it happened.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Stamped {
    pub(crate) ts: Timestamp,
    pub(crate) event: RtEvent,
}

/// Producer half, owned by the control thread. Every method is wait-free and
/// allocation-free.
pub struct RtSender {
    producer: rtrb::Producer<Stamped>,
    dropped_pending: Arc<AtomicU64>,
    dropped_total: u64,
}

/// Consumer half, owned by the writer thread.
pub(crate) struct RtReceiver {
    consumer: rtrb::Consumer<Stamped>,
    dropped_pending: Arc<AtomicU64>,
}

/// A connected ring buffer of `capacity` events (at least 1).
pub(crate) fn rt_channel(capacity: usize) -> (RtSender, RtReceiver) {
    let (producer, consumer) = rtrb::RingBuffer::new(capacity.max(1));
    let dropped = Arc::new(AtomicU64::new(0));
    (
        RtSender {
            producer,
            dropped_pending: Arc::clone(&dropped),
            dropped_total: 0,
        },
        RtReceiver {
            consumer,
            dropped_pending: dropped,
        },
    )
}

impl RtSender {
    /// Queue `event` stamped with the current time. Never blocks: returns `false` and counts
    /// a drop if the ring is full (the writer later logs an `events_dropped` line).
    #[inline]
    pub fn try_push(&mut self, event: impl Into<RtEvent>) -> bool {
        self.try_push_at(Timestamp::now(), event.into())
    }

    /// Queue `event` with an explicit time (e.g. the cycle's start time).
    #[inline]
    pub fn try_push_at(&mut self, ts: Timestamp, event: RtEvent) -> bool {
        match self.producer.push(Stamped { ts, event }) {
            Ok(()) => true,
            Err(_) => {
                self.dropped_pending.fetch_add(1, Ordering::Relaxed);
                self.dropped_total += 1;
                false
            }
        }
    }

    /// Events this sender has dropped because the ring was full, since it was created.
    pub fn dropped_total(&self) -> u64 {
        self.dropped_total
    }

    /// Free slots right now.
    pub fn free_slots(&self) -> usize {
        self.producer.slots()
    }

    /// Whether the writer has gone away (pushes then only fill the ring and count drops).
    pub fn is_closed(&self) -> bool {
        self.producer.is_abandoned()
    }
}

impl RtReceiver {
    /// Next queued event, if any.
    pub(crate) fn pop(&mut self) -> Option<Stamped> {
        self.consumer.pop().ok()
    }

    /// Drops counted since the previous call.
    pub(crate) fn take_dropped(&self) -> u64 {
        self.dropped_pending.swap(0, Ordering::Relaxed)
    }

    /// The producer is gone and nothing is left to read.
    pub(crate) fn is_finished(&self) -> bool {
        self.consumer.is_abandoned() && self.consumer.is_empty()
    }
}

/// Rate limiter for deadline overruns, kept by the control thread.
///
/// Counting every late cycle as an event would flood the log exactly when the machine is
/// struggling. The reporter counts overruns and yields a [`DeadlineOverrun`] event at most
/// once per `window`: the first overrun after a quiet window is reported at once, later ones
/// are summarized (count, worst lateness) when the window has passed. Call
/// [`record`](Self::record) for each late cycle and [`poll`](Self::poll) on the others so a
/// pending summary goes out even if the overruns stop.
#[derive(Debug, Clone, Copy)]
pub struct OverrunReporter {
    window: Duration,
    last_report: Instant,
    reported_once: bool,
    count: u64,
    worst_lateness_us: u64,
}

impl OverrunReporter {
    /// A reporter that emits at most once per `window`, counting from `now`.
    pub fn new(window: Duration, now: Instant) -> Self {
        OverrunReporter {
            window,
            last_report: now,
            reported_once: false,
            count: 0,
            worst_lateness_us: 0,
        }
    }

    /// Count one late cycle; returns the summary to push if one is due.
    #[inline]
    pub fn record(&mut self, lateness_us: u64, now: Instant) -> Option<RtEvent> {
        self.count += 1;
        self.worst_lateness_us = self.worst_lateness_us.max(lateness_us);
        self.poll(now)
    }

    /// Returns the pending summary if the window has passed (or nothing was reported yet).
    #[inline]
    pub fn poll(&mut self, now: Instant) -> Option<RtEvent> {
        if self.count == 0 {
            return None;
        }
        let since = now.saturating_duration_since(self.last_report);
        if self.reported_once && since < self.window {
            return None;
        }
        let ev = DeadlineOverrun {
            count: self.count,
            worst_lateness_us: self.worst_lateness_us,
            window_s: since.as_secs_f64(),
        };
        self.count = 0;
        self.worst_lateness_us = 0;
        self.last_report = now;
        self.reported_once = true;
        Some(RtEvent::DeadlineOverrun(ev))
    }

    /// Overruns counted but not yet reported.
    pub fn pending(&self) -> u64 {
        self.count
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::event::TripReason;
    use crate::vocab::Mode;

    #[test]
    fn rt_event_is_small_and_copy() {
        fn is_copy<T: Copy>() {}
        is_copy::<RtEvent>();
        is_copy::<Stamped>();
        // a mode change carries its cause (input, fault, value, limits, age): 120 bytes at most,
        // so the default 1024-slot ring stays about 130 KiB, allocated once at start
        assert!(
            std::mem::size_of::<RtEvent>() <= 120,
            "{}",
            std::mem::size_of::<RtEvent>()
        );
        assert!(
            std::mem::size_of::<Stamped>() <= 136,
            "{}",
            std::mem::size_of::<Stamped>()
        );
    }

    #[test]
    fn full_ring_drops_and_counts() {
        let (mut tx, mut rx) = rt_channel(2);
        let ev = RecycleTrip {
            reason: TripReason::Operator,
            cause: None,
            criterion: None,
        };
        assert!(tx.try_push(ev));
        assert!(tx.try_push(ev));
        assert!(!tx.try_push(ev));
        assert!(!tx.try_push(ev));
        assert_eq!(tx.dropped_total(), 2);
        assert_eq!(rx.take_dropped(), 2);
        assert_eq!(rx.take_dropped(), 0, "take resets the pending count");
        assert!(rx.pop().is_some());
        assert!(tx.try_push(ev), "space again after a pop");
        assert_eq!(tx.dropped_total(), 2);
    }

    #[test]
    fn order_and_timestamps_are_kept() {
        let (mut tx, mut rx) = rt_channel(8);
        for (i, to) in [Mode::Manual, Mode::Auto, Mode::FailSafe]
            .into_iter()
            .enumerate()
        {
            let ev = ModeChanged {
                from: Mode::Init,
                to,
                cause: None,
            };
            assert!(tx.try_push_at(Timestamp::from_unix_micros(i as i64), ev.into()));
        }
        let got: Vec<_> = std::iter::from_fn(|| rx.pop()).collect();
        assert_eq!(got.len(), 3);
        for (i, s) in got.iter().enumerate() {
            assert_eq!(s.ts.unix_micros(), i as i64);
        }
        assert!(matches!(
            got[2].event,
            RtEvent::ModeChanged(ModeChanged {
                to: Mode::FailSafe,
                ..
            })
        ));
    }

    #[test]
    fn closed_when_receiver_dropped() {
        let (tx, rx) = rt_channel(4);
        assert!(!tx.is_closed());
        drop(rx);
        assert!(tx.is_closed());
        let (tx, rx) = rt_channel(4);
        assert!(!rx.is_finished());
        drop(tx);
        assert!(rx.is_finished());
    }

    #[test]
    fn overrun_reporter_rate_limits() {
        let t0 = Instant::now();
        let ms = |n: u64| t0 + Duration::from_millis(n);
        let mut r = OverrunReporter::new(Duration::from_secs(1), t0);
        assert_eq!(r.poll(ms(5)), None, "nothing to report");
        // First overrun is reported at once.
        match r.record(120, ms(10)) {
            Some(RtEvent::DeadlineOverrun(d)) => {
                assert_eq!(d.count, 1);
                assert_eq!(d.worst_lateness_us, 120);
                assert!((d.window_s - 0.010).abs() < 1e-9);
            }
            other => panic!("{other:?}"),
        }
        // Within the window: accumulate.
        assert_eq!(r.record(50, ms(100)), None);
        assert_eq!(r.record(900, ms(200)), None);
        assert_eq!(r.record(30, ms(300)), None);
        assert_eq!(r.poll(ms(900)), None);
        assert_eq!(r.pending(), 3);
        // Window over: the summary goes out from poll even without a new overrun.
        match r.poll(ms(1010)) {
            Some(RtEvent::DeadlineOverrun(d)) => {
                assert_eq!(d.count, 3);
                assert_eq!(d.worst_lateness_us, 900);
                assert!((d.window_s - 1.0).abs() < 1e-9);
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(r.pending(), 0);
        assert_eq!(r.poll(ms(5000)), None);
        // After a long quiet period the next overrun is reported at once again.
        assert!(r.record(10, ms(6000)).is_some());
    }
}
