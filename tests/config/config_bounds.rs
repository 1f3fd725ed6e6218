//! Issue 12, item 10: bounds on what the loaders and readers accept: scenario length (the
//! trace's memory follows from it), environment-variable nesting (a deep one overflowed the
//! stack), and event-log line length (a 1 GiB line cost 1 GB in `antisurge events` and the
//! start-up scan).

use crate::common;

use antisurge::daemon::config::load_with_env;
use antisurge::events::{read_log, EventFilter};
use antisurge::scenario::{Scenario, MAX_DURATION_S};
use std::io::Write;

#[test]
fn a_scenario_longer_than_a_day_is_refused_with_its_key() {
    let dir = tempfile::tempdir().expect("tmp");
    let p = dir.path().join("soak.toml");
    std::fs::write(&p, "name = 'soak'\ndescription = 'd'\nduration_s = 1e7\n").expect("write");
    let e = Scenario::load(&p).expect_err("1e7 s accepted");
    assert_eq!(e.key, "duration_s", "{e}");
    assert!(e.message.contains(&format!("{MAX_DURATION_S}")), "{e}");
    assert_eq!(e.line, 3, "{e}");
}

#[test]
fn a_deeply_nested_environment_variable_is_ignored_not_a_stack_overflow() {
    let main = common::root().join("config/antisurge.toml");
    let deep = format!("ANTISURGE_{}X", "A__".repeat(200_000));
    let vars = vec![(deep, "1".to_string())];
    let loaded = load_with_env(&main, &vars).expect("the shipped config still loads");
    assert!(loaded
        .layers
        .iter()
        .all(|l| l.path.to_str() != Some("environment")));
}

#[test]
fn an_oversized_event_log_line_is_skipped_in_bounded_memory() {
    let dir = tempfile::tempdir().expect("tmp");
    let p = dir.path().join("events.jsonl");
    let mut f = std::fs::File::create(&p).expect("create");
    writeln!(
        f,
        r#"{{"ts":"2026-11-25T06:00:00Z","seq":1,"event":"stopped","reason":"a"}}"#
    )
    .unwrap();
    let chunk = vec![b'x'; 1 << 20];
    for _ in 0..64 {
        f.write_all(&chunk).unwrap(); // one 64 MiB line
    }
    writeln!(f).unwrap();
    writeln!(
        f,
        r#"{{"ts":"2026-11-25T06:00:01Z","seq":2,"event":"stopped","reason":"b"}}"#
    )
    .unwrap();
    drop(f);
    let (records, stats) = read_log(&p, &EventFilter::default()).expect("read");
    assert_eq!(records.len(), 2, "{stats:?}");
    assert_eq!(stats.invalid_total, 1);
    assert!(
        stats.invalid[0].message.contains("longer than"),
        "{:?}",
        stats.invalid
    );
}
