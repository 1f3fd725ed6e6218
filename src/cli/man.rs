//! `antisurge man`: manual pages generated from the command-line definition, one per command
//! (`antisurge.1`, `antisurge-run.1`, …), each with the sections clap cannot know: FILES,
//! EXIT STATUS, ENVIRONMENT and SIGNALS, written from what the code does (the exit codes of
//! `main` and `cli::daemon`, the signal handling of the daemon's service loop, the paths of
//! `cli::locate`, `live` and the event log).

use anyhow::{Context, Result};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Arguments of `antisurge man`.
#[derive(Debug, clap::Args)]
pub struct ManArgs {
    /// Write every page (`antisurge.1` and one `antisurge-<command>.1` per command) into this
    /// directory instead of printing the top-level page.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

/// One entry of a section: a tagged paragraph (`.TP`).
type Entry = (&'static str, &'static str);

/// The hand-written sections of one page.
struct Sections {
    files: Vec<Entry>,
    exit_status: Vec<Entry>,
    environment: Vec<Entry>,
    signals: Vec<Entry>,
}

const CONFIG: Entry = (
    "/etc/antisurge/antisurge.toml",
    "The configuration when no file is given and ./config/antisurge.toml does not exist \
     ($ANTISURGE_CONFIG_DIR/antisurge.toml when that is set). Every key with its unit and \
     default is in the shipped file.",
);
const CONF_D: Entry = (
    "/etc/antisurge/conf.d/*.toml",
    "Drop-ins merged over the main file in file-name order, before the environment layer.",
);
const CONFIG_DIR: Entry = (
    "/etc/antisurge/{plants,maps,scenarios,machines}/",
    "Plant, map, scenario and machine files, found in $ANTISURGE_CONFIG_DIR, ./config, the \
     config/ directory next to the executable, or /etc/antisurge; without any of them the \
     copies built into the binary are used.",
);
const DAEMON_FILES: Entry = (
    "/etc/antisurge/{plants,maps,scenarios,machines}/",
    "Plant, map, scenario and machine files the configuration names ([plant] file, \
     [machine] file, ...), relative to the main configuration file.",
);
const SIGNAL_MAP: Entry = (
    "/etc/antisurge/signals.toml, /etc/antisurge/skid.dbc",
    "The signal map (each sensor and actuator bound to a CAN signal or a Modbus register) \
     and the CAN database, named by [bus] signal_map and [bus.can] dbc.",
);
const TOKEN: Entry = (
    "/etc/antisurge/operator.token",
    "The operator token (root:antisurge, mode 0640). Operator actions need it; a file that \
     others may write stops the daemon's start with exit status 78.",
);
const SOCKET: Entry = (
    "/run/antisurge/status.sock",
    "The daemon's status socket ($RUNTIME_DIRECTORY/status.sock under systemd, \
     ./out/status.sock from a checkout), with running-config.json (what the daemon runs) \
     and reload-result.json (its answer to the last reload) beside it.",
);
const STATE: Entry = (
    "/var/lib/antisurge/state.json",
    "Surge counter, safety-on steps and the last auto/manual choice, kept across restarts \
     ($STATE_DIRECTORY, else ./out/state); also the Sparkplug B bdSeq and event spool.",
);
const EVENTS: Entry = (
    "/var/log/antisurge/events.jsonl",
    "The event log, JSON Lines, rotated as events.jsonl.1 ... ([event_log] path: relative \
     paths under $LOGS_DIRECTORY, else ./out/).",
);
const BLACKBOX: Entry = (
    "/var/log/antisurge/blackbox/blackbox-<reason>-cycle<N>.csv",
    "Black-box recordings of the last 10 s of control cycles, written after a fail-safe or a \
     surge and at exit; antisurge replay reads them.",
);
const OUT: Entry = (
    "out/<plant>-<scenario>-<law>/",
    "Default output directory (trace.csv, summary.json, map.svg, timeseries.svg); \
     $TMPDIR/antisurge-out/ when the current directory is not writable.",
);

const EXIT_OK: Entry = ("0", "Success.");
const EXIT_OTHER: Entry = (
    "2",
    "Any other error (a file that cannot be read or written, a bad argument), with the \
     error on standard error.",
);
const EXIT_CONFIG: Entry = (
    "78",
    "EX_CONFIG: the configuration (or a plant, scenario or machine file it names) is \
     invalid; every error names its file, line and key. The service unit does not restart \
     on it (RestartPreventExitStatus=78).",
);

const ENV_CONFIG_DIR: Entry = (
    "ANTISURGE_CONFIG_DIR",
    "Directory of antisurge.toml and the plant, map and scenario files, used when no file \
     is given.",
);
const ENV_LAYER: Entry = (
    "ANTISURGE_<SECTION>__<KEY>",
    "Overrides one configuration key after the files, e.g. ANTISURGE_CONTROL__LAW=drive-torque \
     (nested sections with further double underscores).",
);
const ENV_LOG: Entry = (
    "ANTISURGE_LOG, RUST_LOG",
    "Log filter (tracing EnvFilter syntax), ANTISURGE_LOG first; default info. Under \
     systemd (JOURNAL_STREAM set) the log goes to the journal with structured fields, \
     else to standard error.",
);
const ENV_SYSTEMD: Entry = (
    "RUNTIME_DIRECTORY, STATE_DIRECTORY, LOGS_DIRECTORY",
    "Set by the service unit: where the status socket, the kept state and the event log \
     go; without them ./out/.",
);
const ENV_NOTIFY: Entry = (
    "NOTIFY_SOCKET, LISTEN_FDS, LISTEN_PID",
    "systemd notification (READY=1, WATCHDOG=1, STATUS=) and the listening sockets of the \
     shipped .socket units for the HMI and metrics.",
);
const ENV_TMPDIR: Entry = (
    "TMPDIR",
    "Where the output goes when the current directory is not writable, and where the \
     built-in plants and scenarios are unpacked.",
);
const ENV_SOCKET: Entry = (
    "ANTISURGE_STATUS__SOCKET",
    "The daemon's status socket when --socket is not given.",
);

const SIG_DEFAULT: Entry = (
    "SIGINT, SIGTERM",
    "Not handled: the command ends at once (it commands nothing on a machine).",
);

fn sections(command: &str) -> Sections {
    let none = Vec::new;
    match command {
        "run" => Sections {
            files: vec![
                CONFIG,
                CONF_D,
                SIGNAL_MAP,
                DAEMON_FILES,
                TOKEN,
                SOCKET,
                STATE,
                EVENTS,
                BLACKBOX,
            ],
            exit_status: vec![
                ("0", "Stopped by SIGTERM or SIGINT (after commanding the safe state), or after --duration-s."),
                EXIT_CONFIG,
                ("69", "EX_UNAVAILABLE: another process holds the address of an operator surface (the web HMI, metrics, the DCS block): nothing was commanded. The unit restarts on it every second, so the controller starts once the port is free."),
                EXIT_OTHER,
            ],
            environment: vec![ENV_CONFIG_DIR, ENV_LAYER, ENV_LOG, ENV_SYSTEMD, ENV_NOTIFY],
            signals: vec![
                ("SIGTERM, SIGINT", "Stop: the controller commands the safe state (recycle valve open, thrust centred, torque held), writes the stopped event and the black box, and exits 0. The unit allows 5 s before SIGKILL."),
                ("SIGHUP", "Reload the configuration: read the files off the control loop, check them, try them against the live inputs and in a dry run of the recycle valve's command, then apply them at a cycle boundary without a bump, or refuse them and keep the running configuration (config_applied or config_rejected event). antisurge reload sends it and waits for the answer."),
                ("SIGXFSZ", "Ignored: a write past a file-size limit fails with EFBIG, which the event log counts like a full disk."),
                ("SIGABRT", "Not handled: the systemd watchdog sends it when the control loop stops reporting (WatchdogSec=2s), for a core dump before the restart."),
            ],
        },
        "plant" => Sections {
            files: vec![CONFIG, CONF_D, SIGNAL_MAP, DAEMON_FILES],
            exit_status: vec![EXIT_OK, EXIT_CONFIG, EXIT_OTHER],
            environment: vec![ENV_CONFIG_DIR, ENV_LAYER, ENV_LOG],
            signals: vec![(
                "SIGTERM, SIGINT",
                "End the run before the scenario's end: the trace and summary written so far are completed and the node exits 0.",
            )],
        },
        "check-config" => Sections {
            files: vec![CONFIG, CONF_D, SIGNAL_MAP, DAEMON_FILES, TOKEN, SOCKET],
            exit_status: vec![
                ("0", "The configuration is valid (warnings are printed and do not fail)."),
                ("78", "EX_CONFIG: errors (each with file, line, key and a hint), or with --against-running a key the running files set is missing from the new ones."),
                EXIT_OTHER,
            ],
            environment: vec![ENV_CONFIG_DIR, ENV_LAYER, ("RUNTIME_DIRECTORY", "With --against-running: where the daemon's running-config.json is looked for.")],
            signals: vec![SIG_DEFAULT],
        },
        "reload" => Sections {
            files: vec![CONFIG, CONF_D, SOCKET],
            exit_status: vec![
                ("0", "The daemon applied the files (or nothing changed)."),
                ("78", "EX_CONFIG: the check or the daemon refused the files; the reason is printed."),
                ("69", "EX_UNAVAILABLE: no daemon runs (no pid, or it cannot be signalled)."),
                ("75", "EX_TEMPFAIL: the daemon did not answer in time (--timeout-s)."),
                EXIT_OTHER,
            ],
            environment: vec![ENV_CONFIG_DIR, ENV_LAYER, ("RUNTIME_DIRECTORY", "Where the daemon's running-config.json is looked for.")],
            signals: vec![
                ("SIGHUP", "Sent to the daemon (its pid from --pid or running-config.json) after the files passed the check."),
                SIG_DEFAULT,
            ],
        },
        "events" => Sections {
            files: vec![EVENTS, CONFIG],
            exit_status: vec![EXIT_OK, EXIT_CONFIG, EXIT_OTHER],
            environment: vec![ENV_CONFIG_DIR, ENV_LAYER, ("LOGS_DIRECTORY", "Where a relative event-log path is resolved.")],
            signals: vec![("SIGINT, SIGTERM", "End --follow (default action).")],
        },
        "status" => Sections {
            files: vec![SOCKET],
            exit_status: vec![EXIT_OK, ("2", "No daemon answers on the socket, or another error.")],
            environment: vec![ENV_SOCKET],
            signals: vec![SIG_DEFAULT],
        },
        "operate" => Sections {
            files: vec![TOKEN, SOCKET],
            exit_status: vec![EXIT_OK, ("2", "The daemon refused the action (the reason is printed), the token file cannot be read, no daemon answers, or another error.")],
            environment: vec![ENV_SOCKET],
            signals: vec![SIG_DEFAULT],
        },
        "sim" | "table" | "bench-matrix" | "campaign" => Sections {
            files: vec![CONFIG_DIR, OUT],
            exit_status: vec![
                ("0", "The simulation ran, whatever its verdict (STABLE, UNSTABLE or SURGE is printed and in summary.json)."),
                EXIT_CONFIG,
                EXIT_OTHER,
            ],
            environment: vec![ENV_CONFIG_DIR, ENV_TMPDIR],
            signals: vec![SIG_DEFAULT],
        },
        "replay" => Sections {
            files: vec![BLACKBOX, CONFIG, CONFIG_DIR, ("out/replay-<file name>/", "Default output directory (commands.csv, map.svg, timeseries.svg).")],
            exit_status: vec![
                ("0", "Replayed; with the recorded settings every command came out bit for bit."),
                ("1", "With the recorded settings, a replayed command differs from the recorded one."),
                EXIT_CONFIG,
                EXIT_OTHER,
            ],
            environment: vec![ENV_CONFIG_DIR, ENV_LAYER, ENV_TMPDIR],
            signals: vec![SIG_DEFAULT],
        },
        "plot" => Sections {
            files: vec![CONFIG_DIR],
            exit_status: vec![EXIT_OK, EXIT_OTHER],
            environment: vec![ENV_CONFIG_DIR],
            signals: vec![SIG_DEFAULT],
        },
        "fleet-sim" => Sections {
            files: none(),
            exit_status: vec![EXIT_OK, EXIT_OTHER],
            environment: none(),
            signals: vec![SIG_DEFAULT],
        },
        "completions" | "man" => Sections {
            files: none(),
            exit_status: vec![EXIT_OK, EXIT_OTHER],
            environment: none(),
            signals: vec![SIG_DEFAULT],
        },
        // the top-level page: a summary of all of them
        _ => Sections {
            files: vec![CONFIG, CONF_D, SIGNAL_MAP, CONFIG_DIR, TOKEN, SOCKET, STATE, EVENTS, BLACKBOX],
            exit_status: vec![
                EXIT_OK,
                ("1", "antisurge replay: a replayed command differs from the recorded one."),
                EXIT_OTHER,
                ("69", "EX_UNAVAILABLE: antisurge run cannot bind an operator surface; antisurge reload finds no daemon."),
                ("75", "EX_TEMPFAIL: antisurge reload got no answer in time."),
                ("78", "EX_CONFIG: an invalid configuration, in every command that reads one."),
            ],
            environment: vec![ENV_CONFIG_DIR, ENV_LAYER, ENV_LOG, ENV_SYSTEMD, ENV_NOTIFY, ENV_TMPDIR, ENV_SOCKET],
            signals: vec![
                ("SIGTERM, SIGINT", "antisurge run commands the safe state, then exits 0; antisurge plant ends its run."),
                ("SIGHUP", "antisurge run reloads its configuration (see antisurge-run(1) and antisurge-reload(1))."),
            ],
        },
    }
}

/// Escape text for roff: backslashes, hyphens (so they stay ASCII hyphens) and a leading
/// dot or quote, which would start a request.
fn esc(text: &str) -> String {
    let s = text.replace('\\', "\\e").replace('-', "\\-");
    if s.starts_with('.') || s.starts_with('\'') {
        format!("\\&{s}")
    } else {
        s
    }
}

fn section(out: &mut String, title: &str, entries: &[Entry]) {
    out.push_str(&format!(".SH \"{title}\"\n"));
    if entries.is_empty() {
        out.push_str("None.\n");
    }
    for (tag, text) in entries {
        out.push_str(&format!(".TP\n\\fB{}\\fR\n{}\n", esc(tag), esc(text)));
    }
}

/// The hand-written sections of the page of `command` (`""` for the top-level page), as roff.
pub fn extra_sections(command: &str, subcommands: &[String]) -> String {
    let s = sections(command);
    let mut out = String::new();
    section(&mut out, "FILES", &s.files);
    section(&mut out, "EXIT STATUS", &s.exit_status);
    section(&mut out, "ENVIRONMENT", &s.environment);
    section(&mut out, "SIGNALS", &s.signals);
    let see_also: Vec<String> = if command.is_empty() {
        subcommands
            .iter()
            .map(|c| format!("\\fBantisurge\\-{}\\fR(1)", esc(c)))
            .collect()
    } else {
        vec!["\\fBantisurge\\fR(1)".to_string()]
    };
    out.push_str(".SH \"SEE ALSO\"\n");
    out.push_str(&see_also.join(", "));
    out.push_str("\n.PP\nThe documentation in /usr/share/doc/antisurge/ (README.md and docs/).\n");
    out
}

/// Render one page: clap's sections, then the hand-written ones.
fn render(
    cmd: &clap::Command,
    command: &str,
    subcommands: &[String],
    w: &mut dyn Write,
) -> Result<()> {
    clap_mangen::Man::new(cmd.clone()).render(w)?;
    w.write_all(extra_sections(command, subcommands).as_bytes())?;
    Ok(())
}

/// `antisurge man`: print the top-level page, or write every page into `--out DIR`.
pub fn run(mut cmd: clap::Command, args: &ManArgs) -> Result<()> {
    cmd = cmd.disable_help_subcommand(true);
    cmd.build();
    let subs: Vec<clap::Command> = cmd
        .get_subcommands()
        .filter(|s| !s.is_hide_set())
        .cloned()
        .collect();
    let names: Vec<String> = subs.iter().map(|s| s.get_name().to_string()).collect();
    match &args.out {
        None => render(&cmd, "", &names, &mut std::io::stdout().lock()),
        Some(dir) => {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            write_page(dir, &cmd, "", &names)?;
            for sub in &subs {
                write_page(dir, sub, sub.get_name(), &names)?;
            }
            Ok(())
        }
    }
}

fn write_page(dir: &Path, cmd: &clap::Command, command: &str, names: &[String]) -> Result<()> {
    let file = dir.join(clap_mangen::Man::new(cmd.clone()).get_filename());
    let mut buf = Vec::new();
    render(cmd, command, names, &mut buf)?;
    std::fs::write(&file, buf).with_context(|| format!("cannot write {}", file.display()))?;
    println!("{}", file.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_page_has_the_four_sections() {
        for c in [
            "",
            "run",
            "plant",
            "check-config",
            "reload",
            "events",
            "status",
            "operate",
            "sim",
            "replay",
            "plot",
            "fleet-sim",
            "man",
        ] {
            let s = sections(c);
            assert!(!s.exit_status.is_empty(), "{c}: no EXIT STATUS");
            assert!(!s.signals.is_empty(), "{c}: no SIGNALS");
        }
    }

    #[test]
    fn roff_escapes_hyphens_and_leading_dots() {
        assert_eq!(esc("--out"), "\\-\\-out");
        assert_eq!(esc(".hidden"), "\\&.hidden");
        assert_eq!(esc("a\\b"), "a\\eb");
    }
}
