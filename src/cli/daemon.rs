//! `antisurge run`, `antisurge plant`, `antisurge check-config`, `antisurge events`.

use antisurge::daemon::{config, plant_service, service};
use antisurge::events::{
    log_files, parse_time_arg, print_events, EventFilter, PrintFormat, Timestamp,
};
use anyhow::{anyhow, Result};
use std::path::{Path, PathBuf};

/// Where the config file is when none is given.
pub fn default_config() -> PathBuf {
    if let Ok(dir) = std::env::var("ANTISURGE_CONFIG_DIR") {
        return Path::new(&dir).join("antisurge.toml");
    }
    let local = PathBuf::from("config/antisurge.toml");
    if local.is_file() {
        return local;
    }
    PathBuf::from("/etc/antisurge/antisurge.toml")
}

/// Logging: journald under systemd, readable text on a terminal. `RUST_LOG` or
/// `ANTISURGE_LOG` filter (default `info`).
pub fn init_logging() {
    use tracing_subscriber::prelude::*;
    let filter = std::env::var("ANTISURGE_LOG")
        .ok()
        .or_else(|| std::env::var("RUST_LOG").ok())
        .unwrap_or_else(|| "info".into());
    let filter = tracing_subscriber::EnvFilter::try_new(filter)
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let under_systemd = std::env::var_os("JOURNAL_STREAM").is_some();
    if under_systemd {
        // journald's native protocol, fields unprefixed (INPUT=…): antisurge::events::journald
        let socket = antisurge::events::journald::socket_path();
        if let Ok(j) = antisurge::events::journald::JournalLayer::connect(&socket) {
            let _ = tracing_subscriber::registry()
                .with(filter)
                .with(j)
                .try_init();
            return;
        }
    }
    let _ = tracing_subscriber::registry()
        .with(filter)
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                // colours for a terminal only: a log file or pipe gets plain text
                .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
                .with_target(true),
        )
        .try_init();
}

/// `antisurge run`.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Config file (default: ./config/antisurge.toml, else /etc/antisurge/antisurge.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Stop after this many seconds (tests and benchmarks).
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// In-process plant: write its trace and summary here at exit.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Run the controller service.
pub fn run(args: &RunArgs) -> Result<()> {
    limit_malloc_arenas();
    init_logging();
    service::run(&service::RunOptions {
        config: args.config.clone().unwrap_or_else(default_config),
        duration_s: args.duration_s,
        out_dir: args.out.clone(),
    })
}

/// Two malloc arenas for the daemon, before its threads start (issue 25: memory). glibc gives
/// every thread that allocates an arena of its own (132 KiB each once touched, locked under
/// mlockall); the daemon's allocating threads are a handful of service threads whose
/// allocations are small and rare (the control thread allocates nothing), so two arenas carry
/// them without contention worth a megabyte of locked memory.
fn limit_malloc_arenas() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets a tuning parameter of glibc's allocator; called before the
    // daemon's threads start.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, 2);
    }
}

/// `antisurge plant`.
#[derive(Debug, clap::Args)]
pub struct PlantArgs {
    /// Config file (the controller's; uses [plant], [bus] and [simulation]).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Scenario name or file (default: simulation.scenario).
    #[arg(long)]
    pub scenario: Option<String>,
    /// Output directory for trace.csv and summary.json.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Run the plant node.
pub fn plant(args: &PlantArgs) -> Result<()> {
    init_logging();
    plant_service::run(&plant_service::PlantOptions {
        config: args.config.clone().unwrap_or_else(default_config),
        scenario: args.scenario.clone(),
        out_dir: args.out.clone(),
    })
}

/// `antisurge check-config`.
#[derive(Debug, clap::Args)]
pub struct CheckArgs {
    /// Config file (default: ./config/antisurge.toml, else /etc/antisurge/antisurge.toml).
    pub file: Option<PathBuf>,
    /// Print the effective merged configuration with the source of every value (file:line,
    /// conf.d file, environment variable, plant file, default).
    #[arg(long)]
    pub print: bool,
    /// Also check the files against the configuration the daemon runs (its
    /// `running-config.json`, beside the status socket): show the difference and refuse keys
    /// the running files set and the new ones do not (a file cut off while being written).
    /// The shipped unit's `systemctl reload` runs this.
    #[arg(long)]
    pub against_running: bool,
    /// With `--against-running`: the daemon's record, if not the one beside the socket.
    #[arg(long, value_name = "RECORD", requires = "against_running")]
    pub running_record: Option<PathBuf>,
}

/// Where `--against-running` finds the daemon's record when not told.
fn running_record(l: &config::Loaded, given: &Path) -> PathBuf {
    use config::running::{RunningConfig, FILE_NAME};
    if !given.as_os_str().is_empty() {
        return given.to_path_buf();
    }
    let installed = Path::new("/run/antisurge").join(FILE_NAME);
    if std::env::var_os("RUNTIME_DIRECTORY").is_none() && installed.exists() {
        return installed;
    }
    RunningConfig::path_beside(&antisurge::live::socket_path(&l.config.status))
}

/// `--against-running`: print the difference; the problems that refuse the files.
fn against_running(l: &config::Loaded, given: &Path) -> Vec<config::Problem> {
    use config::running::{format_diff, RunningConfig};
    let path = running_record(l, given);
    let running = match RunningConfig::load(&path) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("warning: no running configuration to compare with ({e}); the files were checked alone");
            return Vec::new();
        }
    };
    let diff = running.diff(l);
    if diff.is_empty() {
        println!(
            "against the running configuration ({}, pid {}): no key changes",
            path.display(),
            running.pid
        );
    } else {
        println!(
            "against the running configuration ({}, pid {}):\n{}",
            path.display(),
            running.pid,
            format_diff(&diff).trim_end()
        );
    }
    running.incomplete(l)
}

/// Check a config; exit status 78 (EX_CONFIG) on errors.
pub fn check(args: &CheckArgs) -> Result<std::process::ExitCode> {
    let file = args.file.clone().unwrap_or_else(default_config);
    let loaded = config::load(&file).and_then(|l| {
        if !args.against_running {
            return Ok(l);
        }
        let given = args.running_record.clone().unwrap_or_default();
        let p = against_running(&l, &given);
        if p.is_empty() {
            Ok(l)
        } else {
            Err(p)
        }
    });
    match loaded {
        Ok(l) => {
            for w in &l.warnings {
                eprintln!("{w}");
            }
            // the machine check: an ESD (drive trip) on the simulated skid, if there is one
            if let (Some(p), true) = (&l.plant, l.model.has_recycle_valve()) {
                let margin_pct = match l.controller.recycle_pi.control_line {
                    antisurge::control::surge_control_line::ControlLineForm::Margin {
                        margin_pct,
                        ..
                    } => margin_pct,
                    _ => 10.0,
                };
                // a bound trip contact acts after its read, one cycle and the valve write:
                // over Modbus up to a poll period each way, else (CAN, in-process) one cycle
                let esd = antisurge::vocab::signals::SensorId::EsdInput;
                let contact_latency_s = l.signal_map.sensors.contains_key(&esd).then(|| {
                    let polled = l
                        .signal_map
                        .modbus_sensors()
                        .iter()
                        .any(|(id, _)| *id == esd);
                    let poll_s = match (&l.config.bus.modbus, polled) {
                        (Some(m), true) => 2.0 / m.poll_rate_hz,
                        _ => 0.0,
                    };
                    poll_s + 1.0 / l.config.cycle.rate_hz
                });
                match antisurge::sim::bench::esd_stroke_warning_as_wired(
                    p,
                    margin_pct,
                    contact_latency_s,
                ) {
                    Ok(Some(w)) => eprintln!("warning: {}: {w}", p.path.display()),
                    Ok(None) => {}
                    Err(e) => eprintln!("warning: ESD stroke check not run: {e}"),
                }
            }
            if args.print {
                print!("{}", antisurge::daemon::config_print::print_effective(&l));
            }
            let layers: Vec<String> = l
                .layers
                .iter()
                .map(|x| x.path.display().to_string())
                .collect();
            println!(
                "{}: OK (machine {}, law {}, transport {:?}, {} Hz; layers: {})",
                file.display(),
                l.machine.name,
                l.law,
                l.config.bus.transport,
                l.config.cycle.rate_hz,
                layers.join(", ")
            );
            Ok(std::process::ExitCode::SUCCESS)
        }
        Err(problems) => {
            for p in &problems {
                eprintln!("{p}");
            }
            let n = problems.iter().filter(|p| !p.warning).count();
            eprintln!(
                "{}: {n} error(s); the configuration was not accepted",
                file.display()
            );
            Ok(std::process::ExitCode::from(antisurge::config::EX_CONFIG))
        }
    }
}

/// `antisurge reload`: what the shipped unit's `systemctl reload` runs.
#[derive(Debug, clap::Args)]
pub struct ReloadArgs {
    /// Config file (default: ./config/antisurge.toml, else /etc/antisurge/antisurge.toml).
    pub file: Option<PathBuf>,
    /// The daemon's process id (the unit passes `$MAINPID`; default: the pid in its
    /// `running-config.json`).
    #[arg(long)]
    pub pid: Option<i32>,
    /// Apply even if the daemon's dry run finds that the new settings would step the
    /// recycle valve by more than the bumpless limit (2 % of stroke). Every other check
    /// still refuses.
    #[arg(long = "override")]
    pub override_step: bool,
    /// The daemon's record, if not the one beside the status socket.
    #[arg(long, value_name = "RECORD")]
    pub running_record: Option<PathBuf>,
    /// How long to wait for the daemon's answer, s.
    #[arg(long, default_value_t = 20.0)]
    pub timeout_s: f64,
}

/// Check the files against the running configuration, SIGHUP the daemon and wait for its
/// answer (`reload-result.json` beside its record): exit 0 when it applied them (or nothing
/// changed), 78 (EX_CONFIG) when the check or the daemon refused them (the reason printed),
/// 69 (EX_UNAVAILABLE) when no daemon runs, 75 (EX_TEMPFAIL) when it did not answer in time.
pub fn reload(args: &ReloadArgs) -> Result<std::process::ExitCode> {
    use antisurge::daemon::reload_trial::{Verdict, OVERRIDE_FILE, VERDICT_FILE};
    use std::process::ExitCode;
    let file = args.file.clone().unwrap_or_else(default_config);
    let given = args.running_record.clone().unwrap_or_default();
    let loaded = config::load(&file).and_then(|l| {
        let p = against_running(&l, &given);
        if p.is_empty() {
            Ok(l)
        } else {
            Err(p)
        }
    });
    let l = match loaded {
        Ok(l) => l,
        Err(problems) => {
            for p in &problems {
                eprintln!("{p}");
            }
            eprintln!(
                "{}: not reloaded; the running configuration stays",
                file.display()
            );
            return Ok(ExitCode::from(antisurge::config::EX_CONFIG));
        }
    };
    let record = running_record(&l, &given);
    let verdict_file = record.with_file_name(VERDICT_FILE);
    let pid = match args.pid {
        Some(p) => p,
        None => match config::running::RunningConfig::load(&record) {
            Ok(r) => r.pid as i32,
            Err(e) => {
                eprintln!(
                    "no running daemon found ({}: {e}); give --pid",
                    record.display()
                );
                return Ok(ExitCode::from(69));
            }
        },
    };
    let before = Verdict::load(&verdict_file).filter(|v| v.pid as i32 == pid);
    if args.override_step {
        let o = record.with_file_name(OVERRIDE_FILE);
        std::fs::write(&o, "antisurge reload --override\n")
            .map_err(|e| anyhow!("cannot write {}: {e}", o.display()))?;
    }
    // SAFETY: kill(2) with a pid and a signal number; no memory is shared
    if unsafe { libc::kill(pid, libc::SIGHUP) } != 0 {
        eprintln!(
            "cannot signal the daemon (pid {pid}): {}",
            std::io::Error::last_os_error()
        );
        return Ok(ExitCode::from(69));
    }
    let seq0 = before.map_or(0, |v| v.seq);
    let t0 = std::time::Instant::now();
    loop {
        if let Some(v) =
            Verdict::load(&verdict_file).filter(|v| v.pid as i32 == pid && v.seq > seq0)
        {
            let over = if v.overridden {
                " (valve-step dry run overridden)"
            } else {
                ""
            };
            return Ok(if v.ok() {
                println!("reload {}{over}: {}", v.outcome, v.message);
                ExitCode::SUCCESS
            } else {
                eprintln!("reload refused by the daemon{over}:\n{}", v.message);
                ExitCode::from(antisurge::config::EX_CONFIG)
            });
        }
        if t0.elapsed().as_secs_f64() > args.timeout_s {
            eprintln!(
                "the daemon (pid {pid}) did not answer within {} s ({}); see `journalctl -u antisurge`",
                args.timeout_s,
                verdict_file.display()
            );
            return Ok(ExitCode::from(75));
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// `antisurge events`.
#[derive(Debug, clap::Args)]
pub struct EventsArgs {
    /// Only events at or after this time: what `antisurge events` prints, whole or cut
    /// (`2026-11-27 23:33`, `23:33`), RFC 3339 (`2026-11-27T22:33:00Z`), an age (`5min`,
    /// `10m`, `2h`, `1d`), `today` or `yesterday`. Local time unless --utc.
    #[arg(long)]
    pub since: Option<String>,
    /// Only events at or before this time (the same forms as --since).
    #[arg(long)]
    pub until: Option<String>,
    /// Only events of these kinds (`surge_detected`, `mode_changed`, …; repeat or separate
    /// with commas).
    #[arg(long, value_delimiter = ',')]
    pub kind: Vec<String>,
    /// Keep printing events as they are written (Ctrl-C ends; with --until, ends there).
    #[arg(long, short = 'f')]
    pub follow: bool,
    /// The event log (default: event_log.path of the config).
    #[arg(long)]
    pub file: Option<PathBuf>,
    /// Config file to take the event log path from.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print the stored JSON lines.
    #[arg(long)]
    pub json: bool,
    /// Times in UTC instead of local time (printed and typed).
    #[arg(long)]
    pub utc: bool,
}

/// Where the installed service writes its event log (systemd `LogsDirectory=antisurge`).
const INSTALLED_LOG_DIR: &str = "/var/log/antisurge";

/// Print the event log.
pub fn events(args: &EventsArgs) -> Result<()> {
    let path = match &args.file {
        Some(p) => p.clone(),
        None => {
            let cfg = args.config.clone().unwrap_or_else(default_config);
            // an operator's shell has no $LOGS_DIRECTORY: the installed service's log is
            // /var/log/antisurge/<name>, not ./out/<name>
            let installed = |p: PathBuf| match p.file_name() {
                Some(name) if !p.exists() && Path::new(INSTALLED_LOG_DIR).join(name).exists() => {
                    Path::new(INSTALLED_LOG_DIR).join(name)
                }
                _ => p,
            };
            let fallback = Path::new(INSTALLED_LOG_DIR).join("events.jsonl");
            match config::load(&cfg) {
                Ok(l) => installed(l.config.event_log.path.clone()),
                Err(_) if args.config.is_none() && fallback.exists() => fallback,
                Err(p) => {
                    return Err(anyhow!(
                        "cannot find the event log from {} (use --file):\n{}",
                        cfg.display(),
                        service::format_problems(&p)
                    ))
                }
            }
        }
    };
    let now = Timestamp::now();
    let time = |t: &Option<String>| {
        t.as_deref()
            .map(|t| parse_time_arg(t, now, args.utc))
            .transpose()
            .map_err(|e| anyhow!("{e}"))
    };
    let filter = EventFilter {
        since: time(&args.since)?,
        until: time(&args.until)?,
        kinds: args.kind.iter().map(|k| k.trim().to_string()).collect(),
    };
    let files = log_files(&path).map_err(|e| anyhow!("{e}"))?;
    let format = if args.json {
        PrintFormat::Json
    } else if args.utc {
        PrintFormat::PrettyUtc
    } else {
        PrintFormat::Pretty
    };
    let stdout = std::io::stdout();
    // where a follower goes on: the newest file's length before the listing (what the
    // listing did not see is printed by the first follow step)
    let start = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
    let stats =
        print_events(&mut stdout.lock(), &files, &filter, format).map_err(|e| anyhow!("{e}"))?;
    for w in stats.warnings() {
        eprintln!("warning: {w}");
    }
    if args.follow {
        follow(&path, start, &filter, format, stats.last_seq)?;
    }
    Ok(())
}

/// How often `--follow` looks for new events: a quarter second is immediate to a person.
const FOLLOW_POLL: std::time::Duration = std::time::Duration::from_millis(250);

/// Print the events appended to `path` from byte `offset` on, as they come, until the
/// filter's `until` has passed (or forever). A rotation (new file) is followed from its
/// start; records already printed (by `seq`) are not printed again.
fn follow(
    path: &Path,
    mut offset: u64,
    filter: &EventFilter,
    format: PrintFormat,
    mut last_seq: Option<u64>,
) -> Result<()> {
    use std::io::Write as _;
    use std::os::unix::fs::MetadataExt;
    let mut ino = std::fs::metadata(path).map(|m| m.ino()).ok();
    let mut line = String::new();
    loop {
        let now_ino = std::fs::metadata(path).map(|m| m.ino()).ok();
        if now_ino != ino {
            // rotated: the new file from its start
            ino = now_ino;
            offset = 0;
        }
        let (records, next) = antisurge::events::reader::records_since(path, offset);
        offset = next;
        let mut out = std::io::stdout().lock();
        for r in &records {
            if last_seq.is_some_and(|s| r.seq <= s) {
                continue;
            }
            last_seq = Some(r.seq);
            if !filter.matches(r) {
                continue;
            }
            line.clear();
            match format {
                PrintFormat::Json => line.push_str(&r.raw),
                PrintFormat::Pretty => antisurge::events::format_pretty(&mut line, r, false),
                PrintFormat::PrettyUtc => antisurge::events::format_pretty(&mut line, r, true),
            }
            line.push('\n');
            if out
                .write_all(line.as_bytes())
                .and_then(|()| out.flush())
                .is_err()
            {
                // the reader went away (a pipe closed): done
                return Ok(());
            }
        }
        drop(out);
        if filter.until.is_some_and(|u| Timestamp::now() > u) {
            return Ok(());
        }
        std::thread::sleep(FOLLOW_POLL);
    }
}
