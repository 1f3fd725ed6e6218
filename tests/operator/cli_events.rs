//! Issue 24, item 6: `antisurge events` takes back what it prints. `--since "$(antisurge
//! events | tail -1 | cut -c1-16)"`, ages (`--since 5min`), `--until`, `--kind`, and
//! `--follow` printing what is appended.

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use antisurge::events::Timestamp;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_antisurge"))
}

fn line(seq: u64, ago_s: u64, kind: &str, text: &str) -> String {
    let now_us = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .expect("clock")
        .as_micros() as i64;
    let ts = Timestamp::from_unix_micros(now_us - (ago_s as i64) * 1_000_000);
    format!(r#"{{"ts":"{ts}","seq":{seq},"event":"{kind}","text":"{text}"}}"#)
}

fn events(file: &Path, args: &[&str]) -> Vec<String> {
    let out = bin()
        .arg("events")
        .arg("--file")
        .arg(file)
        .args(args)
        .output()
        .expect("events");
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(str::to_string)
        .collect()
}

fn texts(lines: &[String]) -> Vec<String> {
    lines
        .iter()
        .filter_map(|l| l.split("text=").nth(1).map(|t| t.trim().to_string()))
        .collect()
}

#[test]
fn since_takes_the_printed_time_ages_until_and_kind() {
    let tmp = tempfile::tempdir().expect("tmp");
    let f = tmp.path().join("events.jsonl");
    // two days, two hours, ten minutes, three minutes and one minute ago
    let text = [
        line(1, 2 * 86_400, "note", "two-days"),
        line(2, 2 * 3600, "note", "two-hours"),
        line(3, 600, "note", "ten-min"),
        line(4, 180, "surge_note", "three-min"),
        line(5, 60, "note", "one-min"),
    ]
    .join("\n")
        + "\n";
    std::fs::write(&f, text).expect("write");

    let all = events(&f, &[]);
    assert_eq!(texts(&all).len(), 5, "{all:#?}");
    // what the operator does: the minute of the last line, as printed
    let last = all.last().expect("a line");
    let cut: String = last.chars().take(16).collect();
    let from_last = events(&f, &["--since", &cut]);
    assert!(
        texts(&from_last).contains(&"one-min".to_string()),
        "--since {cut:?}: {from_last:#?}"
    );
    assert!(!texts(&from_last).contains(&"ten-min".to_string()));
    // the same in UTC
    let all_utc = events(&f, &["--utc"]);
    let cut_utc: String = all_utc.last().expect("line").chars().take(16).collect();
    let utc = events(&f, &["--utc", "--since", &cut_utc]);
    assert!(texts(&utc).contains(&"one-min".to_string()), "{utc:#?}");

    assert_eq!(
        texts(&events(&f, &["--since", "5min"])),
        ["three-min", "one-min"]
    );
    assert_eq!(
        texts(&events(&f, &["--since", "1h", "--until", "2min"])),
        ["ten-min", "three-min"]
    );
    assert_eq!(
        texts(&events(&f, &["--until", "yesterday"])),
        ["two-days"],
        "yesterday's midnight"
    );
    assert_eq!(texts(&events(&f, &["--kind", "surge_note"])), ["three-min"]);
    assert_eq!(
        texts(&events(
            &f,
            &["--kind", "surge_note,note", "--since", "15min"]
        )),
        ["ten-min", "three-min", "one-min"]
    );
    let out = bin()
        .args(["events", "--file"])
        .arg(&f)
        .args(["--since", "half past nine"])
        .output()
        .expect("events");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("half past nine") && err.contains("5min"),
        "{err}"
    );
}

#[test]
fn follow_prints_what_is_appended() {
    let tmp = tempfile::tempdir().expect("tmp");
    let f = tmp.path().join("events.jsonl");
    std::fs::write(&f, line(1, 10, "note", "before") + "\n").expect("write");
    let mut child = bin()
        .args(["events", "--follow", "--kind", "note", "--file"])
        .arg(&f)
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn");
    let (tx, rx) = std::sync::mpsc::channel();
    let stdout = child.stdout.take().expect("stdout");
    std::thread::spawn(move || {
        for l in BufReader::new(stdout).lines() {
            let Ok(l) = l else { break };
            if tx.send(l).is_err() {
                break;
            }
        }
    });
    let first = rx
        .recv_timeout(Duration::from_secs(30))
        .expect("the listing");
    assert!(first.contains("before"), "{first}");
    {
        let mut a = std::fs::OpenOptions::new()
            .append(true)
            .open(&f)
            .expect("open");
        // a line of another kind, then a line written in two pieces
        writeln!(a, "{}", line(2, 0, "other", "skipped")).expect("append");
        let l = line(3, 0, "note", "after");
        let (x, y) = l.split_at(20);
        write!(a, "{x}").expect("append");
        a.flush().expect("flush");
        std::thread::sleep(Duration::from_millis(600));
        writeln!(a, "{y}").expect("append");
    }
    let next = rx
        .recv_timeout(Duration::from_secs(30))
        .expect("the appended event");
    let _ = child.kill();
    let _ = child.wait();
    assert!(next.contains("after"), "{next}");
}
