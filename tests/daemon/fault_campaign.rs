//! The fault campaign of issue 12 as a repeatable run against the release binary: each case
//! injects one fault (several times where it is random) and asserts its safe outcome. The
//! cases take about a minute together, so they are `#[ignore]`d in the normal suite;
//! `tests/campaign/run.sh` (and CI) runs them and prints the table of counts that README.md
//! shows ("Fault campaign").

use crate::common;

use antisurge::events::reader::{read_log, EventFilter};
use common::daemon::*;
use common::faults::*;
use std::io::{Read, Write};
use std::net::TcpListener;
use std::path::Path;
use std::process::Child;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// One row of the table: case, injections, safe outcomes, what was seen.
struct Row {
    case: &'static str,
    injected: u32,
    safe: u32,
    seen: String,
}

fn kill9(child: &mut Child) {
    signal(child, libc::SIGKILL);
    let _ = child.wait();
}

fn start_run(dir: &Path, cfg: &Path, notify: Option<&FakeNotify>, secs: &str) -> Child {
    let cfg_s = cfg.display().to_string();
    let args = ["run", "--config", &cfg_s, "--duration-s", secs];
    match notify {
        Some(n) => spawn_notified(dir, &args, n, 2_000_000),
        None => spawn(dir, "run", &args),
    }
}

/// kill -9 at random moments while the controller logs (reloads of a changed status interval,
/// one `config_applied` event each) and rotates (4 KiB files): every
/// restart appends to a log that reads back with at most a torn final line, no invalid line
/// in the middle and no lost `started` event.
fn kill9_storm_during_logging_and_rotation() -> Row {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (cfg, _) = config(dir, "[status]\nlog_interval_s = 0.2\n");
    let text = std::fs::read_to_string(&cfg).expect("cfg");
    std::fs::write(
        &cfg,
        text.replace(
            "fsync = \"always\"",
            "fsync = \"always\"\nmax_bytes = 4096\nkeep_files = 200",
        ),
    )
    .expect("cfg");
    let kills = 12u32;
    let mut safe = 0;
    let mut torn = 0;
    let mut seed = 0x2545_f491_u64;
    for i in 0..kills {
        let mut child = start_run(dir, &cfg, None, "30");
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        std::thread::sleep(Duration::from_millis(400));
        let with = std::fs::read_to_string(&cfg).expect("cfg");
        for k in 0..6 {
            let (a, b) = if k % 2 == 0 {
                ("0.2", "0.3")
            } else {
                ("0.3", "0.2")
            };
            write_atomically(
                &cfg,
                &with.replace(
                    &format!("log_interval_s = {a}"),
                    &format!("log_interval_s = {b}"),
                ),
            );
            signal(&child, libc::SIGHUP);
            std::thread::sleep(Duration::from_millis(60));
        }
        std::thread::sleep(Duration::from_millis(seed % 300));
        kill9(&mut child);
        let (records, stats) =
            read_log(&dir.join("events.jsonl"), &EventFilter::default()).expect("log readable");
        let started = records.iter().filter(|r| r.kind == "started").count();
        torn += u32::from(stats.torn_tail.is_some());
        if stats.invalid_total == 0 && started as u32 == i + 1 {
            safe += 1;
        } else {
            eprintln!("kill {i}: started {started}, invalid {:?}", stats.invalid);
        }
    }
    let files =
        antisurge::events::reader::log_files(&dir.join("events.jsonl")).map_or(0, |f| f.len());
    Row {
        case: "kill -9 storm while logging + rotating (4 KiB files)",
        injected: kills,
        safe,
        seen: format!("log readable after every kill; {torn} torn tails skipped; {files} files"),
    }
}

/// The event log on a full disk (`/dev/full`: every write is ENOSPC), and under a 400-byte
/// file-size limit (EFBIG instead of SIGXFSZ): the controller runs its whole duration and
/// exits 0, saying so in the journal.
fn disk_full_and_file_size_limit() -> Vec<Row> {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (cfg, text) = config(dir, "");
    let events = dir.join("events.jsonl").display().to_string();
    std::os::unix::fs::symlink("/dev/full", dir.join("full.jsonl")).expect("symlink");
    let full = dir.join("full.jsonl").display().to_string();
    std::fs::write(&cfg, text.replace(&events, &full)).expect("cfg");
    let mut rows = Vec::new();
    let (mut safe, mut seen) = (0, String::new());
    for _ in 0..2 {
        let out = run_piped(&cfg, "2", None);
        let err = String::from_utf8_lossy(&out.stderr);
        if out.status.code() == Some(0) && err.contains("control thread at 200 Hz") {
            safe += 1;
            seen = if err.contains("No space left") || err.contains("DEGRADED") {
                "runs to the end, exit 0; journal: No space left / DEGRADED".into()
            } else {
                "runs to the end, exit 0".into()
            };
        } else {
            eprintln!("disk full: {:?}\n{err}", out.status);
        }
    }
    rows.push(Row {
        case: "disk full (event log on /dev/full)",
        injected: 2,
        safe,
        seen,
    });
    std::fs::write(&cfg, &text).expect("cfg");
    let mut safe = 0;
    for _ in 0..2 {
        let _ = std::fs::remove_file(dir.join("events.jsonl"));
        let out = run_piped(&cfg, "2", Some(400));
        let err = String::from_utf8_lossy(&out.stderr);
        if out.status.code() == Some(0) && err.contains("File too large") {
            safe += 1;
        } else {
            eprintln!("ulimit -f: {:?}\n{err}", out.status);
        }
    }
    rows.push(Row {
        case: "file-size limit (ulimit -f 400 bytes)",
        injected: 2,
        safe,
        seen: "no SIGXFSZ; EFBIG counted, runs to the end, exit 0".into(),
    });
    let blocked = dir.join("not-a-dir/events.jsonl").display().to_string();
    std::fs::write(dir.join("not-a-dir"), "x").expect("file");
    std::fs::write(&cfg, text.replace(&events, &blocked)).expect("cfg");
    let mut safe = 0;
    for _ in 0..2 {
        let out = run_piped(&cfg, "2", None);
        let err = String::from_utf8_lossy(&out.stderr);
        if out.status.code() == Some(0) && err.contains("event log DEGRADED") {
            safe += 1;
        } else {
            eprintln!("unwritable: {:?}\n{err}", out.status);
        }
    }
    rows.push(Row {
        case: "event-log directory unusable at start",
        injected: 2,
        safe,
        seen: "controller runs; journal: event log DEGRADED; exit 0".into(),
    });
    rows
}

/// Bad config files at start: a FIFO as plant file, `/dev/zero`, a 128 MiB config, a
/// half-written config. Every command ends with EX_CONFIG (78) within 3 s.
fn bad_files_at_start() -> Row {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (cfg, text) = config(dir, "");
    let plant = plant_file(dir);
    let plant_text = std::fs::read_to_string(&plant).expect("plant");
    let mut injected = 0;
    let mut safe = 0;
    let mut worst = Duration::ZERO;
    let mut check = |what: &str| {
        for cmd in ["check-config", "run"] {
            injected += 1;
            let t0 = Instant::now();
            let cfg_s = cfg.to_str().expect("utf-8");
            let args: &[&str] = if cmd == "run" {
                &[cmd, "--config", cfg_s]
            } else {
                &[cmd, cfg_s]
            };
            let out = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
                .args(args)
                .env_remove("NOTIFY_SOCKET")
                .output()
                .expect("spawn");
            let dt = t0.elapsed();
            worst = worst.max(dt);
            if out.status.code() == Some(78) && dt < Duration::from_secs(3) {
                safe += 1;
            } else {
                eprintln!("{what} / {cmd}: {:?} in {dt:?}", out.status);
            }
        }
    };
    std::fs::remove_file(&plant).expect("rm");
    mkfifo(&plant);
    check("FIFO plant file");
    std::fs::remove_file(&plant).expect("rm");
    std::os::unix::fs::symlink("/dev/zero", &plant).expect("symlink");
    check("/dev/zero plant file");
    std::fs::remove_file(&plant).expect("rm");
    std::fs::write(&plant, &plant_text).expect("plant");
    {
        let mut f = std::fs::File::create(&cfg).expect("cfg");
        f.write_all(text.as_bytes()).expect("w");
        let pad = format!("# {}\n", "x".repeat(1022));
        for _ in 0..(128 * 1024) {
            f.write_all(pad.as_bytes()).expect("w");
        }
    }
    check("128 MiB config");
    std::fs::write(&cfg, &text[..text.len() / 2]).expect("half");
    check("half-written config");
    Row {
        case: "FIFO / /dev/zero / 128 MiB / half-written config at start",
        injected,
        safe,
        seen: format!(
            "exit 78 (EX_CONFIG) each, slowest {:.2} s",
            worst.as_secs_f64()
        ),
    }
}

/// Reloads of a half-written config and a SIGHUP storm (200 signals, 5 ms apart) on a
/// running controller: it keeps running, never applies the bad file, and the gap between
/// `WATCHDOG=1` notifications stays under 1 s (half of WatchdogSec = 2 s).
fn sighup_storm_and_half_written_reload() -> Row {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let (cfg, text) = config(dir, "");
    let notify = FakeNotify::new(dir);
    let mut child = start_run(dir, &cfg, Some(&notify), "8");
    std::thread::sleep(Duration::from_millis(1500));
    let hups = 200u32;
    for i in 0..hups {
        if i == 50 {
            std::fs::write(&cfg, &text[..text.len() / 2]).expect("half");
        }
        if i == 150 {
            std::fs::write(&cfg, &text).expect("whole");
        }
        signal(&child, libc::SIGHUP);
        std::thread::sleep(Duration::from_millis(5));
    }
    let status = wait(&mut child, Duration::from_secs(20), "run", dir);
    let times = notify.watchdog_times();
    let gap = times
        .windows(2)
        .map(|w| w[1] - w[0])
        .max()
        .unwrap_or(Duration::MAX);
    let log = logs(dir);
    let ok = status.code() == Some(0) && gap < Duration::from_secs(1) && times.len() > 10;
    if !ok {
        eprintln!(
            "SIGHUP storm: {status:?}, gap {gap:?}, {} pings\n{log}",
            times.len()
        );
    }
    Row {
        case: "SIGHUP storm (200 × 5 ms) with a half-written file",
        injected: hups,
        safe: if ok { hups } else { 0 },
        seen: format!(
            "kept running, exit 0; longest WATCHDOG=1 gap {:.2} s",
            gap.as_secs_f64()
        ),
    }
}

/// How the fake Modbus server misbehaves.
#[derive(Clone, Copy, Debug)]
enum Misbehaviour {
    /// Every request answered with exception 0x04.
    Exception,
    /// Random bytes.
    Garbage,
    /// A response one register short.
    WrongLength,
    /// Reads, never answers.
    Hang,
    /// Well-formed answers whose floats are NaN.
    NaN,
}

/// A TCP server on 127.0.0.1 answering every Modbus request per `how`, until `stop`.
fn fake_server(how: Misbehaviour, stop: Arc<AtomicBool>) -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    listener.set_nonblocking(true).expect("nonblocking");
    let port = listener.local_addr().expect("addr").port();
    std::thread::spawn(move || {
        let mut n = 0u64;
        while !stop.load(Ordering::Relaxed) {
            let Ok((mut s, _)) = listener.accept() else {
                std::thread::sleep(Duration::from_millis(5));
                continue;
            };
            let stop = Arc::clone(&stop);
            std::thread::spawn(move || {
                let _ = s.set_read_timeout(Some(Duration::from_millis(200)));
                let mut req = [0u8; 260];
                while !stop.load(Ordering::Relaxed) {
                    let k = match s.read(&mut req) {
                        Ok(0) => return,
                        Ok(k) => k,
                        Err(_) => continue,
                    };
                    if k < 8 {
                        continue;
                    }
                    n = n.wrapping_mul(6364136223846793005).wrapping_add(1);
                    let (tid, unit, fc) = ([req[0], req[1]], req[6], req[7]);
                    let pdu: Vec<u8> = match how {
                        Misbehaviour::Hang => continue,
                        Misbehaviour::Exception => vec![fc | 0x80, 0x04],
                        Misbehaviour::Garbage => {
                            let bytes: Vec<u8> =
                                (0..(n % 40 + 1)).map(|i| (n >> (i % 56)) as u8).collect();
                            let _ = s.write_all(&bytes);
                            continue;
                        }
                        Misbehaviour::WrongLength | Misbehaviour::NaN => {
                            let qty = u16::from_be_bytes([req[10], req[11]]);
                            if fc == 0x03 || fc == 0x04 {
                                let mut words: Vec<u8> = Vec::new();
                                for i in 0..qty {
                                    // 0x7FC0 0x0000 is a big-endian f32 NaN
                                    words.extend(if i % 2 == 0 { [0x7F, 0xC0] } else { [0, 0] });
                                }
                                if matches!(how, Misbehaviour::WrongLength) {
                                    words.truncate(words.len().saturating_sub(2));
                                }
                                let mut p = vec![fc, words.len() as u8];
                                p.extend(words);
                                p
                            } else {
                                req[7..k.min(12)].to_vec()
                            }
                        }
                    };
                    let mut adu = vec![tid[0], tid[1], 0, 0];
                    adu.extend(((pdu.len() + 1) as u16).to_be_bytes());
                    adu.push(unit);
                    adu.extend(pdu);
                    let _ = s.write_all(&adu);
                }
            });
        }
    });
    port
}

/// A controller on Modbus TCP against a misbehaving device: it must not crash, must go to
/// fail-safe (the inputs are never valid) and say so, and must exit 0 at the end.
fn misbehaving_modbus_servers() -> Row {
    let modes = [
        Misbehaviour::Exception,
        Misbehaviour::Garbage,
        Misbehaviour::WrongLength,
        Misbehaviour::Hang,
        Misbehaviour::NaN,
    ];
    let mut safe = 0;
    for how in modes {
        let tmp = tempfile::tempdir().expect("tmp");
        let dir = tmp.path();
        let stop = Arc::new(AtomicBool::new(false));
        let port = fake_server(how, Arc::clone(&stop));
        let (cfg, _) = config(
            dir,
            &format!(
                r#"[bus]
transport = "field"
signal_map = "{map}"
[bus.modbus]
poll_rate_hz = 50.0
[bus.modbus.client]
timeout_ms = 100
transport = {{ kind = "tcp", address = "127.0.0.1:{port}" }}
"#,
                map = shipped("signals_modbus.toml"),
            ),
        );
        let out = run_piped(&cfg, "3", None);
        stop.store(true, Ordering::Relaxed);
        let err = String::from_utf8_lossy(&out.stderr);
        let log = std::fs::read_to_string(dir.join("events.jsonl")).unwrap_or_default();
        let fail_safe = log.contains("\"to\":\"fail_safe\"")
            || err.contains("fail_safe")
            || err.contains("FAIL-SAFE")
            || err.contains("fail-safe");
        use std::os::unix::process::ExitStatusExt;
        if out.status.code() == Some(0) && out.status.signal().is_none() && fail_safe {
            safe += 1;
        } else {
            eprintln!(
                "{how:?}: {:?}, fail-safe seen {fail_safe}\n{err}\n{log}",
                out.status
            );
        }
    }
    Row {
        case: "Modbus device: exception, garbage, wrong length, hang, NaN",
        injected: modes.len() as u32,
        safe,
        seen: "fail-safe, no crash, exit 0 each".into(),
    }
}

/// CPU stress: the controller at 1 kHz for 20 s while every core is kept busy (`stress-ng
/// --cpu N` where installed, CI installs it; else N busy-loop threads here). The loop keeps
/// control: at least 95 % of the cycles run, overruns are counted (stats file) and stay under
/// 1 % of them, nothing fails safe, exit 0.
fn cpu_stress() -> Row {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let stats = dir.join("stats.json");
    let (cfg, text) = config(
        dir,
        &format!("[status]\nstats_file = \"{}\"\n", stats.display()),
    );
    std::fs::write(&cfg, text.replace("rate_hz = 200.0", "rate_hz = 1000.0")).expect("cfg");
    let secs = 20.0;
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let stop = Arc::new(AtomicBool::new(false));
    let mut busy = Vec::new();
    let stress_ng = std::process::Command::new("stress-ng")
        .args(["--cpu", &cores.to_string(), "--timeout", "30s", "--quiet"])
        .spawn()
        .ok();
    let how = if stress_ng.is_some() {
        format!("stress-ng --cpu {cores}")
    } else {
        for _ in 0..cores {
            let stop = Arc::clone(&stop);
            busy.push(std::thread::spawn(move || {
                let mut x = 0u64;
                while !stop.load(Ordering::Relaxed) {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            }));
        }
        format!("{cores} busy-loop threads (no stress-ng)")
    };
    std::thread::sleep(Duration::from_millis(500));
    let out = run_piped(&cfg, &secs.to_string(), None);
    stop.store(true, Ordering::Relaxed);
    for b in busy {
        let _ = b.join();
    }
    if let Some(mut s) = stress_ng {
        signal(&s, libc::SIGTERM);
        let _ = s.wait();
    }
    let log = events(dir);
    let report: serde_json::Value = std::fs::read_to_string(&stats)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or_default();
    let cycles = report["cycles"].as_u64().unwrap_or(0);
    let overruns = report["overruns"].as_u64().unwrap_or(u64::MAX);
    let expected = (secs * 1000.0) as u64;
    let fail_safe = log.contains("\"to\":\"fail_safe\"");
    let ok = out.status.code() == Some(0)
        && cycles * 100 >= expected * 95
        && overruns.saturating_mul(100) < cycles
        && !fail_safe;
    if !ok {
        eprintln!(
            "cpu stress: {:?}, {cycles} cycles, {overruns} overruns, fail-safe {fail_safe}\n{}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        );
    }
    Row {
        case: "CPU stress (1 kHz loop, 20 s, every core busy)",
        injected: 1,
        safe: u32::from(ok),
        seen: format!(
            "{how}: {cycles} cycles, {overruns} overruns counted, no fail-safe{}",
            if fail_safe { " VIOLATED" } else { "" }
        ),
    }
}

#[test]
#[ignore = "the fault campaign (about a minute): tests/campaign/run.sh"]
fn fault_campaign() {
    let t0 = Instant::now();
    let mut rows = vec![kill9_storm_during_logging_and_rotation()];
    rows.extend(disk_full_and_file_size_limit());
    rows.push(bad_files_at_start());
    rows.push(sighup_storm_and_half_written_reload());
    rows.push(misbehaving_modbus_servers());
    rows.push(cpu_stress());
    println!("\n| Fault | Injected | Safe outcome | Seen |\n|---|---|---|---|");
    for r in &rows {
        println!("| {} | {} | {} | {} |", r.case, r.injected, r.safe, r.seen);
    }
    println!("\ncampaign took {:.0} s", t0.elapsed().as_secs_f64());
    let failed: Vec<&str> = rows
        .iter()
        .filter(|r| r.safe != r.injected)
        .map(|r| r.case)
        .collect();
    assert!(
        failed.is_empty(),
        "cases without their safe outcome: {failed:?}"
    );
}
