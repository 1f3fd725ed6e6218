//! Issue 25, item 2: a half-written configuration file is never applied.
//!
//! A running daemon's config is cut at 10 pseudo-random byte offsets (fixed seed, printed),
//! then at the start of the line of each (a cut there parses: the keys after it are just
//! missing, and were applied as defaults before issue 25); each is SIGHUPed: 0 applied,
//! 20 `config_rejected` events. `check-config
//! --against-running` (what the shipped unit's `systemctl reload` runs) refuses each cut
//! file too and names a missing key. Then the whole file with one gain changed is applied,
//! and `check-config --against-running` shows that change.

use crate::common;

use common::daemon::{count, embedded_config, logs, signal, spawn, until, wait, write_atomically};
use std::path::Path;
use std::process::Command;
use std::time::Duration;

fn check_against_running(cfg: &Path, record: &Path) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .arg("check-config")
        .args(["--against-running", "--running-record"])
        .arg(record)
        .arg(cfg)
        .env_remove("RUNTIME_DIRECTORY")
        .output()
        .expect("check-config");
    (
        out.status.code().unwrap_or(-1),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

/// `check-config --against-running FILE` as the unit runs it, with the record found beside
/// the status socket (`status.socket` is absolute in these configs).
fn check_against_running_as_the_unit(cfg: &Path, dir: &Path) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(["check-config", "--against-running"])
        .arg(cfg)
        .env("RUNTIME_DIRECTORY", dir)
        .output()
        .expect("check-config");
    (
        out.status.code().unwrap_or(-1),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

#[test]
fn a_config_cut_anywhere_is_refused() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let events = dir.join("events.jsonl");
    // the last line sets a key: a cut anywhere loses at least part of a key
    let full = embedded_config(
        dir,
        "throttle-closure",
        "failsafe_recycle_opening_pct = 100.0\n",
        "[reload]\nwatch_files = false\n[controller.recycle_pi.pi]\nkp_per_map_flow = KP\n",
    );
    let cfg = dir.join("antisurge.toml");
    let whole = full.replace("KP", "10.0");
    std::fs::write(&cfg, &whole).expect("write");
    let record = dir.join("running-config.json");
    let cfg_s = cfg.display().to_string();
    let mut d = spawn(dir, "run", &["run", "--config", &cfg_s]);
    until(dir, "the running-config record", || record.is_file());
    // the unit's form (`--against-running FILE`) checks FILE, not FILE as the record
    let (code, text) = check_against_running_as_the_unit(&cfg, dir);
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("no key changes"), "{text}");
    until(dir, "the started event", || count(&events, "started") == 1);

    // 10 offsets from a fixed-seed xorshift (reproducible; printed for the record)
    let mut x: u64 = 0x2545_F491_4F6C_DD1D;
    let mut offsets = Vec::new();
    for _ in 0..10 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        offsets.push((x % whole.len() as u64) as usize);
    }
    // ...and the same cuts moved back to the start of their line: these files parse (the
    // keys after the cut are simply missing), which is what was applied before issue 25
    let line_starts: Vec<usize> = offsets
        .iter()
        .map(|&at| whole[..at].rfind('\n').map_or(0, |i| i + 1))
        .collect();
    println!(
        "cut offsets (of {} bytes): {offsets:?}; at line starts: {line_starts:?}",
        whole.len()
    );
    offsets.extend(&line_starts);
    let mut refused_by_check = 0;
    for (i, &at) in offsets.iter().enumerate() {
        let cut = &whole.as_bytes()[..at];
        let cut = String::from_utf8_lossy(cut).into_owned();
        write_atomically(&cfg, &cut);
        let (code, text) = check_against_running(&cfg, &record);
        assert_ne!(
            code, 0,
            "check-config accepted the file cut at {at}:\n{text}"
        );
        refused_by_check += 1;
        signal(&d, libc::SIGHUP);
        until(dir, &format!("refusal {} (cut at {at})", i + 1), || {
            count(&events, "config_rejected") == i + 1
        });
        assert_eq!(count(&events, "config_applied"), 0, "cut at {at} applied");
    }
    assert_eq!(refused_by_check, 20);
    let log = std::fs::read_to_string(&events).expect("events");
    let missing = log
        .lines()
        .filter(|l| l.contains("config_rejected") && l.contains("missing from the new files"))
        .count();
    println!("refusals naming missing keys: {missing} of 20");
    assert!(
        missing >= 5,
        "the line-start cuts parse; their keys are missing:\n{log}"
    );

    // the whole file, one gain changed: shown by check-config, applied on SIGHUP
    let changed = full.replace("KP", "12.0");
    write_atomically(&cfg, &changed);
    let (code, text) = check_against_running(&cfg, &record);
    assert_eq!(code, 0, "{text}");
    assert!(
        text.contains("~ controller.recycle_pi.pi.kp_per_map_flow: 10.0 -> 12.0"),
        "{text}"
    );
    signal(&d, libc::SIGHUP);
    until(dir, "the applied reload", || {
        count(&events, "config_applied") == 1
    });
    assert_eq!(count(&events, "config_rejected"), 20);
    // the record is rewritten after the event is logged: wait for it (the order of two
    // writes of the daemon, not a time)
    until(dir, "the record follows the applied reload", || {
        std::fs::read_to_string(&record).is_ok_and(|rec| rec.contains("12.0"))
    });

    signal(&d, libc::SIGTERM);
    let st = wait(&mut d, Duration::from_secs(30), "controller", dir);
    assert!(st.success(), "controller exit {st:?}:\n{}", logs(dir));
}

/// Issue 25, item 6 (first part): a reload whose input range refuses what the transmitter
/// reads now (legal, no unit explains it: only a warning statically) is refused against the
/// live inputs instead of putting the controller into fail-safe.
#[test]
fn a_range_that_refuses_the_live_reading_is_not_applied() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let events = dir.join("events.jsonl");
    let base = embedded_config(
        dir,
        "throttle-closure",
        "",
        "[inputs.p_discharge]\nmin = 1.0e4\nmax = MAX\ntimeout_ms = 200.0\n",
    );
    let cfg = dir.join("antisurge.toml");
    std::fs::write(&cfg, base.replace("MAX", "1.2e7")).expect("write");
    let cfg_s = cfg.display().to_string();
    let mut d = spawn(dir, "run", &["run", "--config", &cfg_s]);
    until(dir, "auto", || {
        std::fs::read_to_string(&events)
            .unwrap_or_default()
            .contains("\"to\":\"auto\"")
    });
    // 0.101 bar absolute at most: below any discharge pressure, and no unit explains it
    write_atomically(&cfg, &base.replace("MAX", "1.01e4"));
    signal(&d, libc::SIGHUP);
    until(dir, "the refusal", || {
        count(&events, "config_rejected") == 1
    });
    let log = std::fs::read_to_string(&events).expect("events");
    let rejected = log
        .lines()
        .find(|l| l.contains("config_rejected"))
        .expect("rejected");
    assert!(
        rejected.contains("inputs.p_discharge.max") && rejected.contains("fail-safe"),
        "{rejected}"
    );
    assert_eq!(count(&events, "config_applied"), 0, "{log}");
    // a range that holds the reading is applied
    write_atomically(&cfg, &base.replace("MAX", "1.1e7"));
    signal(&d, libc::SIGHUP);
    until(dir, "the applied reload", || {
        count(&events, "config_applied") == 1
    });
    let log = std::fs::read_to_string(&events).expect("events");
    assert!(!log.contains("\"to\":\"fail_safe\""), "{log}");
    signal(&d, libc::SIGTERM);
    let st = wait(&mut d, Duration::from_secs(30), "controller", dir);
    assert!(st.success(), "controller exit {st:?}:\n{}", logs(dir));
}
