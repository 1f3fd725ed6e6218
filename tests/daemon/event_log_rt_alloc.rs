//! The real-time push path must not allocate: a counting global allocator counts the
//! allocations made by the current thread between two points.

use crate::common;

use common::counting_alloc::allocations;

use std::hint::black_box;
use std::time::{Duration, Instant};

use antisurge::events::{
    read_log, DeadlineOverrun, Event, EventFilter, EventLog, EventLogConfig, FallbackEntered,
    FallbackLeft, FallbackReason, FsyncPolicy, Law, LawChanged, ModeChanged, OverrunReporter,
    RecycleTrip, Replacement, RtEvent, SafetyOnShift, SurgeCounter, SurgeDetected, Timestamp,
    TripReason,
};
use antisurge::vocab::signals::SensorId;
use antisurge::vocab::Mode;

#[test]
fn the_counter_sees_allocations() {
    let before = allocations();
    let v = black_box(vec![1u8; 64]);
    let s = black_box(String::from("x")) + "y";
    let after = allocations();
    drop((v, s));
    assert!(after - before >= 2, "counting allocator is not counting");
}

fn all_rt_events(i: u64) -> [RtEvent; 9] {
    [
        SurgeDetected {
            surge_count_total: i,
            frequency_hz: 9.5,
            min_flow_kg_s: -0.3,
            flow_reversal: true,
        }
        .into(),
        SurgeCounter {
            previous_count: i,
            count: 0,
        }
        .into(),
        SafetyOnShift {
            margin_pct: 2.0,
            total_margin_pct: 4.0,
            count: 2,
        }
        .into(),
        ModeChanged {
            from: Mode::Auto,
            to: Mode::FailSafe,
            cause: None,
        }
        .into(),
        LawChanged {
            from: Law::RecyclePi,
            to: Law::DriveTorque,
        }
        .into(),
        FallbackEntered {
            input: SensorId::OrificeDp,
            reason: FallbackReason::BusOff,
            replaced_by: Replacement::Observer,
            vs_observer_pct: None,
            vs_speed_line_pct: None,
        }
        .into(),
        FallbackLeft {
            input: SensorId::OrificeDp,
            replaced_by: Replacement::Observer,
            duration_ms: i,
        }
        .into(),
        DeadlineOverrun {
            count: 1,
            worst_lateness_us: 50,
            window_s: 1.0,
        }
        .into(),
        RecycleTrip {
            reason: TripReason::SurgeDetected,
            cause: None,
            criterion: Some(antisurge::control::law::api::TripCause::ThrottleClosure),
        }
        .into(),
    ]
}

#[test]
fn rt_push_path_does_not_allocate() {
    let dir = tempfile::tempdir().expect("tempdir");
    let log = EventLog::start(EventLogConfig {
        fsync: FsyncPolicy::Never,
        poll_interval_ms: 1,
        ..EventLogConfig::with_path(dir.path().join("events.jsonl"))
    })
    .expect("start");
    // Setup may allocate; a small ring makes the drop path run too.
    let mut rt = log.rt_sender_with_capacity(32).expect("rt");
    let t0 = Instant::now();
    let mut overruns = OverrunReporter::new(Duration::from_millis(1), t0);
    let mut pushed = 0u64;
    let mut attempts = 0u64;

    let before = allocations();
    for i in 0..20_000u64 {
        for ev in all_rt_events(i) {
            attempts += 1;
            pushed += u64::from(rt.try_push(ev));
        }
        let now = t0 + Duration::from_micros(i * 1000);
        if let Some(ev) = overruns.record(i % 300, now) {
            attempts += 1;
            pushed += u64::from(rt.try_push_at(Timestamp::now(), ev));
        }
        if let Some(ev) = overruns.poll(now) {
            attempts += 1;
            pushed += u64::from(rt.try_push(ev));
        }
        black_box((rt.free_slots(), rt.is_closed(), rt.dropped_total()));
    }
    let after = allocations();
    assert_eq!(after - before, 0, "the real-time path allocated");

    // And the events arrived: pushed + dropped account for every attempt, and the log
    // holds the pushed ones plus events_dropped lines summing to the drops.
    let dropped = rt.dropped_total();
    assert_eq!(pushed + dropped, attempts);
    assert!(
        dropped > 0,
        "the 32-slot ring never filled: drop path not exercised"
    );
    log.flush().expect("flush");
    let (records, stats) =
        read_log(&dir.path().join("events.jsonl"), &EventFilter::default()).expect("read");
    assert!(stats.is_clean(), "{:?}", stats.warnings());
    let mut logged_drops = 0;
    let mut rt_lines = 0;
    for r in &records {
        match r.event().expect("typed") {
            Event::EventsDropped { count, .. } => logged_drops += count,
            _ => rt_lines += 1,
        }
    }
    assert_eq!(rt_lines, pushed);
    assert_eq!(logged_drops, dropped);
}
