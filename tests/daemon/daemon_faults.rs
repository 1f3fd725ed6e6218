//! Faults from the campaign of issue 12, end to end against the `antisurge` binary:
//! bad config files must neither starve the systemd watchdog nor be applied half-written,
//! and a config error ends every command with EX_CONFIG (78), which the unit's
//! `RestartPreventExitStatus=` turns into "stop restarting".

use crate::common;

use common::daemon::*;
use common::faults::*;
use std::io::Write;
use std::time::Duration;

/// Issue 12, item 1: a FIFO as plant file, `/dev/zero`, a 128 MiB config and a SIGHUP storm
/// during reloads; the gap between two `WATCHDOG=1` stays under half of `WatchdogSec`, every
/// bad file is rejected with its cause and control goes on.
#[test]
fn bad_config_files_on_reload_never_starve_the_watchdog() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (cfg, _) = config(dir, "");
    let plant = plant_file(dir);
    let notify = FakeNotify::new(dir);
    let wd = Duration::from_secs(2);
    let cfg_s = cfg.display().to_string();
    let mut ctl = spawn_notified(
        dir,
        &["run", "--config", &cfg_s, "--duration-s", "10"],
        &notify,
        wd.as_micros() as u64,
    );
    std::thread::sleep(Duration::from_millis(2000));
    // the plant file becomes a FIFO nobody writes to
    std::fs::remove_file(&plant).expect("rm plant");
    mkfifo(&plant);
    signal(&ctl, libc::SIGHUP);
    std::thread::sleep(Duration::from_millis(1500));
    // ...then /dev/zero
    std::fs::remove_file(&plant).expect("rm fifo");
    std::os::unix::fs::symlink("/dev/zero", &plant).expect("symlink");
    signal(&ctl, libc::SIGHUP);
    std::thread::sleep(Duration::from_millis(1500));
    // ...then the main file is 128 MiB (sparse)
    let big = dir.join("big.tmp");
    std::fs::File::create(&big)
        .expect("big")
        .set_len(128 << 20)
        .expect("set_len");
    std::fs::rename(&big, &cfg).expect("rename");
    signal(&ctl, libc::SIGHUP);
    std::thread::sleep(Duration::from_millis(1000));
    // ...and a SIGHUP storm
    for _ in 0..30 {
        signal(&ctl, libc::SIGHUP);
        std::thread::sleep(Duration::from_millis(20));
    }
    let st = wait(&mut ctl, Duration::from_secs(20), "controller", dir);
    let log = events(dir);
    let ctx = format!("{log}\n{}", logs(dir));
    assert!(st.success(), "controller exit {st:?}:\n{ctx}");

    let pings = notify.watchdog_times();
    assert!(pings.len() >= 8, "{} WATCHDOG=1 only:\n{ctx}", pings.len());
    let worst = pings
        .windows(2)
        .map(|w| w[1] - w[0])
        .max()
        .expect("two pings");
    eprintln!(
        "worst gap between WATCHDOG=1: {worst:?} over {} pings",
        pings.len()
    );
    assert!(
        worst < wd / 2,
        "gap of {worst:?} between WATCHDOG=1 (WatchdogSec {wd:?}):\n{ctx}"
    );
    let rejected: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("\"config_rejected\""))
        .collect();
    for cause in ["FIFO", "character device", "limit"] {
        assert!(
            rejected.iter().any(|l| l.contains(cause)),
            "no rejection naming `{cause}`:\n{ctx}"
        );
    }
    assert!(!log.contains("\"config_applied\""), "{ctx}");
    assert!(log.contains("\"stopped\""), "{ctx}");
}

/// Issue 12, item 2: a file written in two halves 0.5 s apart (the first half valid TOML that
/// drops the gain overrides) is never applied; the complete file is, once.
#[test]
fn a_file_written_in_two_halves_is_never_applied_half() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let gains = "[controller.recycle_pi.pi]\nkp_per_map_flow = KP\nki_per_map_flow_s = 24.0\n";
    let (cfg, base) = config(
        dir,
        &format!(
            "[reload]\nwatch_files = true\n{}",
            gains.replace("KP", "10.0")
        ),
    );
    let cfg_s = cfg.display().to_string();
    let mut ctl = spawn(
        dir,
        "run",
        &["run", "--config", &cfg_s, "--duration-s", "7"],
    );
    std::thread::sleep(Duration::from_millis(2500));
    let full = base.replace("kp_per_map_flow = 10.0", "kp_per_map_flow = 12.0");
    let cut = full.find("[controller.recycle_pi.pi]").expect("section");
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .truncate(true)
        .open(&cfg)
        .expect("open");
    f.write_all(&full.as_bytes()[..cut]).expect("first half");
    f.flush().expect("flush");
    std::thread::sleep(Duration::from_millis(500));
    f.write_all(&full.as_bytes()[cut..]).expect("second half");
    drop(f);
    let st = wait(&mut ctl, Duration::from_secs(20), "controller", dir);
    let log = events(dir);
    let ctx = format!("{log}\n{}", logs(dir));
    assert!(st.success(), "controller exit {st:?}:\n{ctx}");
    let applied: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("\"config_applied\""))
        .collect();
    assert_eq!(applied.len(), 1, "{ctx}");
    assert!(applied[0].contains("kp_per_map_flow"), "{ctx}");
    assert!(applied[0].contains("12.0"), "{ctx}");
    assert!(!applied[0].contains("ki_per_map_flow_s"), "{ctx}");
}

/// Issue 12, items 1 and 11: a FIFO or `/dev/zero` at start, or any invalid config, ends
/// `run`, `plant` and `check-config` at once with EX_CONFIG (78), not 1 or 2.
#[test]
fn config_errors_exit_78_at_once_in_every_command() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (cfg, _) = config(dir, "");
    let plant = plant_file(dir);
    std::fs::remove_file(&plant).expect("rm plant");
    mkfifo(&plant);
    let cfg_s = cfg.display().to_string();
    for args in [
        vec!["run", "--config", &cfg_s, "--duration-s", "5"],
        vec!["plant", "--config", &cfg_s],
        vec!["check-config", &cfg_s],
        vec!["run", "--config", "/dev/zero", "--duration-s", "5"],
    ] {
        let mut child = spawn(dir, "cmd", &args);
        // (`wait` fails the test after 10 s: a refusal, not a read that never ends; no
        // tighter wall-clock bound, a busy machine must not fail it)
        let st = wait(&mut child, Duration::from_secs(10), "command", dir);
        let ctx = logs(dir);
        assert_eq!(st.code(), Some(78), "{args:?}:\n{ctx}");
        assert!(
            ctx.contains("FIFO") || ctx.contains("character device"),
            "{args:?}:\n{ctx}"
        );
    }
    // [cycle] cpu out of range: refused, not an abort in CPU_SET at start
    std::fs::remove_file(&plant).expect("rm fifo");
    let (cfg, _) = config(dir, "");
    let text = std::fs::read_to_string(&cfg).expect("read");
    std::fs::write(
        &cfg,
        text.replace("lock_memory = false", "lock_memory = false\ncpu = 5000"),
    )
    .expect("write");
    let mut child = spawn(
        dir,
        "cmd",
        &["run", "--config", &cfg_s, "--duration-s", "5"],
    );
    let st = wait(&mut child, Duration::from_secs(10), "run", dir);
    let ctx = logs(dir);
    assert_eq!(st.code(), Some(78), "{ctx}");
    assert!(ctx.contains("cycle.cpu"), "{ctx}");
}

/// Issue 12, items 6 and 7: an event log that cannot be opened at start, or a file-size limit
/// the log runs into, leave the controller running (it used to refuse to start, or die of
/// SIGXFSZ at every restart); the journal says the log is degraded.
#[test]
fn unwritable_log_dir_and_file_size_limit_do_not_stop_the_controller() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (cfg, text) = config(dir, "");
    // the log's directory is a regular file: cannot be created, cannot be opened
    std::fs::write(dir.join("not-a-dir"), "x").expect("file");
    let events = dir.join("events.jsonl").display().to_string();
    let blocked = dir.join("not-a-dir/events.jsonl").display().to_string();
    std::fs::write(&cfg, text.replace(&events, &blocked)).expect("write");
    let out = run_piped(&cfg, "3", None);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{err}");
    assert!(err.contains("event log DEGRADED"), "{err}");
    assert!(err.contains("control thread at 200 Hz"), "{err}");

    // a 400-byte file-size limit: the log fills it, then writes fail with EFBIG
    std::fs::write(&cfg, &text).expect("write");
    let out = run_piped(&cfg, "3", Some(400));
    let err = String::from_utf8_lossy(&out.stderr);
    use std::os::unix::process::ExitStatusExt;
    assert_eq!(out.status.signal(), None, "killed by a signal:\n{err}");
    assert_eq!(out.status.code(), Some(0), "{err}");
    let size = std::fs::metadata(dir.join("events.jsonl"))
        .expect("log")
        .len();
    assert!(size <= 400, "{size} bytes");
    assert!(err.contains("File too large"), "{err}");
}
