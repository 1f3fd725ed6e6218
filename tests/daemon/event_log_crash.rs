//! kill -9 during heavy event logging, repeated.
//!
//! The test binary re-runs itself (`current_exe()`) with `CHILD_ENV` set and `--exact
//! event_log_crash::crash_child` (its name in the grouped test binary), which works under both `cargo test` and `cargo nextest run` (both run
//! libtest binaries with these arguments). The child logs as fast as it can until the
//! parent SIGKILLs it at a pseudo-random moment; the parent then checks what is on disk.

use std::fs::{self, OpenOptions};
use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use antisurge::events::{
    read_log, ConfigChange, DeadlineOverrun, Event, EventFilter, EventLog, EventLogConfig,
    FallbackEntered, FallbackReason, FsyncPolicy, ModeChanged, ReadStats, Record, Replacement,
    SurgeDetected,
};
use antisurge::vocab::signals::SensorId;
use antisurge::vocab::Mode;

/// This module's test `f` as libtest names it (for `--exact`).
fn own_test_name(f: &str) -> String {
    crate::common::own_test_name(module_path!(), f)
}

const CHILD_ENV: &str = "ANTISURGE_EVENT_LOG_CRASH_CHILD";
const FSYNC_ENV: &str = "ANTISURGE_EVENT_LOG_CRASH_FSYNC";
/// Small files so rotation (and kills during rotation) happen often.
const MAX_BYTES: u64 = 64 * 1024;
const KEEP_FILES: u32 = 4;
/// What the parent appends to simulate a write torn by a power cut.
/// What the child prints once it is writing.
const READY: &str = "CHILD-READY";
const FRAGMENT: &str = r#"{"ts":"2031-01-01T00:00:00.000000Z","seq":"#;

fn config(path: &Path, fsync: FsyncPolicy) -> EventLogConfig {
    EventLogConfig {
        fsync,
        max_bytes: MAX_BYTES,
        keep_files: KEEP_FILES,
        rt_queue_capacity: 256,
        poll_interval_ms: 1,
        ..EventLogConfig::with_path(path)
    }
}

/// The child: only does work when re-executed by the parent.
#[test]
fn crash_child() {
    let Some(path) = std::env::var_os(CHILD_ENV) else {
        return;
    };
    let fsync = match std::env::var(FSYNC_ENV).as_deref() {
        Ok("always") => FsyncPolicy::Always,
        _ => FsyncPolicy::Never,
    };
    let log = EventLog::start(config(Path::new(&path), fsync)).expect("child: start");
    let mut rt = log.rt_sender().expect("child: rt sender");
    let tx = log.sender();
    tx.send(Event::started(
        Path::new("/etc/antisurge.toml"),
        antisurge::events::Law::RecyclePi,
    ))
    .expect("child: send");
    for k in 0..100 {
        tx.send(Event::Note {
            text: format!("warm-up {k}"),
        })
        .expect("child: send");
    }
    log.flush().expect("child: flush");
    println!("{READY}");
    std::io::stdout().flush().expect("child: stdout");
    let mut i: u64 = 0;
    loop {
        i += 1;
        // Real-time path until the ring is full …
        let pushed = rt.try_push(SurgeDetected {
            surge_count_total: i,
            frequency_hz: 8.0 + (i % 7) as f64,
            min_flow_kg_s: -0.1 * (i % 5) as f64,
            flow_reversal: i.is_multiple_of(2),
        }) && rt.try_push(ModeChanged {
            from: Mode::Auto,
            to: Mode::Manual,
            cause: None,
        }) && rt.try_push(FallbackEntered {
            input: SensorId::OrificeDp,
            reason: FallbackReason::Stale,
            replaced_by: Replacement::Observer,
            vs_observer_pct: None,
            vs_speed_line_pct: None,
        }) && rt.try_push(DeadlineOverrun {
            count: i,
            worst_lateness_us: i % 1000,
            window_s: 1.0,
        });
        // … then a non-real-time event with heap data, and a breath for the writer.
        if !pushed {
            tx.send(Event::ConfigApplied {
                file: "/etc/antisurge.toml".into(),
                diff: vec![ConfigChange {
                    key: "control.recycle.kp".into(),
                    old: Some(i.to_string()),
                    new: Some((i + 1).to_string()),
                }],
            })
            .expect("child: send");
            std::thread::sleep(Duration::from_micros(200));
        }
    }
}

/// Small xorshift: the kill moments vary from run to run, and the seed is printed.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

fn newest_file(stats: &ReadStats) -> Option<&PathBuf> {
    stats.files.last()
}

/// The first bytes of the torn tail `stats` reports, as the reader's excerpt would show them.
fn torn_start(stats: &ReadStats) -> Option<String> {
    let t = stats.torn_tail.as_ref()?;
    let bytes = fs::read(&t.file).expect("read newest");
    let end = bytes.len() - usize::from(t.terminated);
    let start = end - t.bytes as usize;
    let text = String::from_utf8_lossy(&bytes[start..end]);
    Some(text.chars().take(40).collect())
}

/// Everything the log on disk must satisfy after any crash.
/// `allowed` holds the starts of torn lines seen (or injected) earlier: once a restart
/// terminated them they are invalid lines in the middle of the log, legitimately.
fn check_log(path: &Path, round: usize, allowed: &[String]) -> (Vec<Record>, ReadStats) {
    let (records, stats) = read_log(path, &EventFilter::default()).expect("read after kill");
    assert!(!records.is_empty(), "round {round}: nothing was logged");
    // Valid lines only, except torn lines of earlier rounds.
    assert_eq!(stats.invalid_total as usize, stats.invalid.len());
    for bad in &stats.invalid {
        assert!(
            allowed.iter().any(|a| bad.excerpt.starts_with(a.as_str())),
            "round {round}: a line the writer wrote is invalid: {bad:?}"
        );
    }
    // seq strictly increasing by one, within files and across rotations and restarts.
    assert!(
        stats.seq_breaks.is_empty(),
        "round {round}: seq breaks {:?}",
        stats.seq_breaks
    );
    for w in records.windows(2) {
        assert_eq!(w[1].seq, w[0].seq + 1, "round {round}");
    }
    // Every record also parses as a typed event.
    for r in &records {
        r.event()
            .unwrap_or_else(|e| panic!("round {round}: {} does not parse: {e}", r.raw));
    }
    // A torn tail is reported exactly when the newest file does not end in a newline or
    // ends in an invalid line.
    if let Some(newest) = newest_file(&stats) {
        let bytes = fs::read(newest).expect("read newest");
        if !bytes.is_empty() && bytes.last() != Some(&b'\n') {
            assert!(
                stats.torn_tail.is_some(),
                "round {round}: unterminated tail not reported"
            );
        }
    }
    (records, stats)
}

fn run_child(path: &Path, fsync: &str, kill_after: Duration) {
    let exe = std::env::current_exe().expect("current_exe");
    let mut child = Command::new(exe)
        .args([
            "--exact",
            &own_test_name("crash_child"),
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_ENV, path)
        .env(FSYNC_ENV, fsync)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn child");
    // Wait until the child has written its warm-up, then let it run a little longer.
    let stdout = child.stdout.take().expect("stdout");
    let ready = BufReader::new(stdout)
        .lines()
        .map_while(Result::ok)
        .any(|l| l.contains(READY));
    if !ready {
        let status = child.wait().expect("reap");
        let mut err = String::new();
        if let Some(mut e) = child.stderr.take() {
            let _ = e.read_to_string(&mut err);
        }
        panic!("child exited before it was ready ({status}): {err}");
    }
    std::thread::sleep(kill_after);
    child.kill().expect("SIGKILL"); // std sends SIGKILL on Unix
    let status = child.wait().expect("reap");
    assert!(!status.success(), "child should have died from the signal");
}

#[test]
fn kill_9_during_heavy_logging_loses_and_corrupts_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("events.jsonl");
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(1)
        | 1;
    eprintln!("kill-9 test seed {seed}");
    let mut rng = Rng(seed);
    let mut torn_seen = 0;
    let mut max_files = 0;
    let mut allowed: Vec<String> = Vec::new();
    let rounds = 12;
    for round in 0..rounds {
        let fsync = if round % 2 == 0 { "never" } else { "always" };
        let kill_after = Duration::from_millis(5 + rng.next() % 60);
        run_child(&path, fsync, kill_after);

        let (records, stats) = check_log(&path, round, &allowed);
        let natural_torn = stats.torn_tail.clone();
        if let Some(t) = torn_start(&stats) {
            torn_seen += 1;
            allowed.push(t);
        }
        max_files = max_files.max(stats.files.len());
        let last = stats.last_seq.expect("records exist");
        eprintln!(
            "round {round}: fsync={fsync} killed after {kill_after:?}: last seq {last}, torn tail {:?}",
            stats.torn_tail.as_ref().map(|t| t.bytes)
        );
        assert_eq!(records.last().map(|r| r.seq), Some(last));

        // Every third round, also simulate a write torn by a power cut.
        let injected = round % 3 == 1;
        if injected {
            let mut f = OpenOptions::new()
                .create(true)
                .append(true)
                .open(&path)
                .expect("open live");
            f.write_all(FRAGMENT.as_bytes()).expect("inject");
            drop(f);
            let (_, s) = read_log(&path, &EventFilter::default()).expect("read");
            let t = s.torn_tail.clone().expect("injected tail is reported");
            let glued = natural_torn
                .as_ref()
                .filter(|n| !n.terminated && n.file == path)
                .map_or(0, |n| n.bytes);
            assert_eq!(t.bytes, FRAGMENT.len() as u64 + glued);
            assert_eq!(
                s.last_seq,
                Some(last),
                "a torn tail changes nothing before it"
            );
            allowed.extend(torn_start(&s));
        }

        // The next writer resumes right after the last valid line.
        let log = EventLog::start(config(&path, FsyncPolicy::Never)).expect("restart");
        assert_eq!(log.first_seq(), last + 1, "round {round}: seq resume");
        log.send(Event::Note {
            text: format!("parent check after round {round}"),
        })
        .expect("send");
        let ws = log.shutdown().expect("shutdown");
        let (records, stats) = check_log(&path, round, &allowed);
        assert!(
            stats.torn_tail.is_none(),
            "round {round}: repaired on start"
        );
        let tail: Vec<_> = records.iter().rev().take(2).collect();
        match tail[0].event() {
            Ok(Event::Note { text }) => {
                assert_eq!(text, format!("parent check after round {round}"))
            }
            other => panic!("round {round}: {other:?}"),
        }
        if ws.repaired_torn_tail {
            match tail[1].event() {
                Ok(Event::Note { text }) => assert!(text.contains("stopped mid-line"), "{text}"),
                other => panic!("round {round}: {other:?}"),
            }
            assert_eq!((tail[1].seq, tail[0].seq), (last + 1, last + 2));
        } else {
            assert!(!injected, "round {round}: injected tail not repaired");
            assert_eq!(tail[0].seq, last + 1);
        }
    }
    eprintln!("{rounds} rounds; torn tails from the kills themselves: {torn_seen}; most files in the set: {max_files}");
    assert!(max_files > 1, "rotation never happened under load");
}
