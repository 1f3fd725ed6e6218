//! The daemon's operator services, off the control thread (tokio tasks):
//! - the status socket (`antisurge status`): a Unix socket in the runtime directory, mode
//!   0660 (the service's group reads it). A client writes one line and reads one JSON line:
//!   `status` → the [`StatusReport`]; `status CYCLE` → the report of a snapshot served
//!   recently (to the HMI or a status client) by its cycle number, so that what a page shows
//!   can be compared with the daemon's own report of the same snapshot;
//!   `op TOKEN WORDS…` → an operator action (see
//!   [`OperatorCommand::parse`]), refused without the right token, recorded in the event log
//!   with what changed;
//! - persistence: the surge counter, safety-on steps and last mode written to the state
//!   directory whenever they change;
//! - `sd_notify STATUS=` with the one-line status every second.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::{UnixListener, UnixStream};

use super::commands::OperatorCommand;
use super::persist::{PersistentState, StateFile};
use super::report::{status_line, StatusReport};
use super::snapshot::{LiveBoard, LiveSnapshot};
use crate::events::event::Event;
use crate::events::EventSender;
use crate::runtime::rt_loop::CycleStats;

/// Everything the operator services read and write.
#[derive(Clone)]
pub struct LiveContext {
    /// The control thread's snapshot.
    pub live: Arc<LiveBoard>,
    /// Operator actions to the control thread (one producer, shared).
    pub commands: Arc<Mutex<rtrb::Producer<OperatorCommand>>>,
    /// Cycle statistics.
    pub stats: Arc<CycleStats>,
    /// Link counters as JSON.
    pub links: Arc<dyn Fn() -> serde_json::Value + Send + Sync>,
    /// The input→link table, built once at start from the signal map
    /// ([`crate::io::signal_map::SignalMap::input_links`]): the report's `inputs`.
    pub inputs: Arc<[crate::io::signal_map::InputLink]>,
    /// Event log.
    pub events: EventSender,
    /// The operator token file.
    pub token_file: PathBuf,
    /// Daemon start.
    pub started: Instant,
    /// The snapshots served last (HMI, status socket), newest at the back.
    pub served: Arc<Mutex<VecDeque<LiveSnapshot>>>,
}

/// How many served snapshots [`LiveContext::report_of`] can find (at the HMI's 2 Hz poll,
/// about two minutes).
pub const SERVED_KEPT: usize = 256;

impl LiveContext {
    /// The current report (None before the first cycle); its snapshot is kept among the
    /// served ones.
    pub fn report(&self) -> Option<StatusReport> {
        let s = self.live.latest()?;
        if let Ok(mut q) = self.served.lock() {
            if q.back().map(|b| b.cycle) != Some(s.cycle) {
                if q.len() == SERVED_KEPT {
                    q.pop_front();
                }
                q.push_back(s);
            }
        }
        Some(self.report_for(&s))
    }

    /// The report of the served snapshot of control cycle `cycle` (None: not served, or no
    /// longer kept). Statistics, links and uptime are today's.
    pub fn report_of(&self, cycle: u64) -> Option<StatusReport> {
        let s = *self.served.lock().ok()?.iter().find(|s| s.cycle == cycle)?;
        Some(self.report_for(&s))
    }

    fn report_for(&self, s: &LiveSnapshot) -> StatusReport {
        let stats = serde_json::to_value(self.stats.report()).unwrap_or_default();
        StatusReport::new(
            s,
            self.started.elapsed().as_secs_f64(),
            stats,
            (self.links)(),
        )
        .with_inputs(&self.inputs, s)
    }

    /// Check the token and hand the action to the control thread; returns what changed.
    pub fn operate(&self, token: &str, words: &[&str], who: &str) -> Result<String, OpError> {
        check_token(&self.token_file, token)?;
        let cmds = OperatorCommand::parse(words).map_err(OpError::Invalid)?;
        let before = self.live.latest().unwrap_or_default();
        {
            let mut tx = self.commands.lock().map_err(|_| OpError::Busy)?;
            if tx.slots() < cmds.len() {
                return Err(OpError::Busy);
            }
            for c in &cmds {
                let _ = tx.push(*c);
            }
        }
        let what = describe_action(&cmds, &before);
        let _ = self.events.send(Event::Note {
            text: format!("operator action ({who}): {what}"),
        });
        tracing::warn!(target: "operator", who, action = %words.join(" "), "operator action: {what}");
        Ok(what)
    }
}

/// Why an operator action was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OpError {
    /// No or wrong token.
    #[error("unauthorized: {0}")]
    Unauthorized(String),
    /// The words are not an action.
    #[error("{0}")]
    Invalid(String),
    /// The control thread has not taken the previous actions yet.
    #[error("busy: the control thread has not taken the previous action yet; try again")]
    Busy,
}

/// Compare `given` with the token in `file` (first line, trimmed). No file, an empty file or
/// a file others may read: every action is refused.
pub fn check_token(file: &Path, given: &str) -> Result<(), OpError> {
    use std::os::unix::fs::MetadataExt;
    let meta = std::fs::metadata(file).map_err(|e| {
        OpError::Unauthorized(format!(
            "operator actions are disabled: cannot read the token file {} ({e})",
            file.display()
        ))
    })?;
    if let Some(why) = crate::live::tls_settings::token_file_unsafe(file) {
        return Err(OpError::Unauthorized(format!(
            "operator actions are disabled: {why}"
        )));
    }
    if meta.mode() & 0o004 != 0 {
        return Err(OpError::Unauthorized(format!(
            "operator actions are disabled: {} is readable by everyone (chmod 0640)",
            file.display()
        )));
    }
    let text = std::fs::read_to_string(file)
        .map_err(|e| OpError::Unauthorized(format!("cannot read {}: {e}", file.display())))?;
    let want = text.lines().next().unwrap_or("").trim();
    if want.is_empty() {
        return Err(OpError::Unauthorized(format!(
            "operator actions are disabled: {} is empty",
            file.display()
        )));
    }
    // compare without an early exit on the first differing byte
    let (a, b) = (want.as_bytes(), given.trim().as_bytes());
    let diff = a
        .iter()
        .zip(b.iter())
        .fold(a.len() ^ b.len(), |d, (x, y)| d | usize::from(x ^ y));
    if diff == 0 {
        Ok(())
    } else {
        Err(OpError::Unauthorized("wrong operator token".into()))
    }
}

fn describe_action(cmds: &[OperatorCommand], before: &LiveSnapshot) -> String {
    let pct = |x: f64| {
        if x.is_finite() {
            format!("{:.1} %", 100.0 * x)
        } else {
            "unset".into()
        }
    };
    cmds.iter()
        .map(|c| match c {
            OperatorCommand::SetAuto(true) => format!(
                "mode {} → auto",
                if before.auto_requested {
                    "auto"
                } else {
                    "manual"
                }
            ),
            OperatorCommand::SetAuto(false) => format!(
                "mode {} → manual (output {})",
                if before.auto_requested {
                    "auto"
                } else {
                    "manual"
                },
                pct(before.valve_output)
            ),
            OperatorCommand::ManualOutput(u) => {
                format!("manual output {} → {}", pct(before.manual_output), pct(*u))
            }
            OperatorCommand::ResetSurgeCounter => {
                format!("surge counter {} → 0", before.surge_count)
            }
            OperatorCommand::Acknowledge => format!(
                "acknowledged: {}",
                before
                    .cause
                    .map(|c| c.describe())
                    .unwrap_or_else(|| "nothing to acknowledge".into())
            ),
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// Bind the status socket (replacing a stale one) with mode 0660.
pub fn bind_status_socket(path: &Path) -> std::io::Result<UnixListener> {
    use std::os::unix::fs::PermissionsExt;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    if path.exists() {
        // a socket left by a killed daemon; a live daemon would still answer on it
        if std::os::unix::net::UnixStream::connect(path).is_ok() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::AddrInUse,
                format!("another daemon answers on {}", path.display()),
            ));
        }
        std::fs::remove_file(path)?;
    }
    let l = UnixListener::bind(path)?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660))?;
    Ok(l)
}

/// A status answer with the daemon's identity (`station`: machine, host, instance).
fn with_identity(mut v: serde_json::Value) -> serde_json::Value {
    if let Some(o) = v.as_object_mut() {
        o.insert(
            "station".into(),
            serde_json::to_value(super::identity()).unwrap_or_default(),
        );
    }
    v
}

async fn answer(ctx: &LiveContext, stream: UnixStream) -> std::io::Result<()> {
    let who = match stream.peer_cred() {
        Ok(c) => format!("uid {} via the status socket", c.uid()),
        Err(_) => "status socket".into(),
    };
    let (rd, mut wr) = stream.into_split();
    let mut line = String::new();
    let mut rd = BufReader::new(rd);
    tokio::time::timeout(Duration::from_secs(2), rd.read_line(&mut line))
        .await
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::TimedOut, "no request"))??;
    let words: Vec<&str> = line.split_whitespace().collect();
    let reply = match words.as_slice() {
        ["status"] | [] => match ctx.report() {
            Some(r) => with_identity(serde_json::to_value(r).unwrap_or_default()),
            None => serde_json::json!({"error": "no control cycle has run yet"}),
        },
        ["status", cycle] => match cycle.parse::<u64>().map(|c| (c, ctx.report_of(c))) {
            Ok((_, Some(r))) => with_identity(serde_json::to_value(r).unwrap_or_default()),
            Ok((c, None)) => serde_json::json!({"error": format!(
                "the snapshot of cycle {c} was not served or is no longer kept (the last {SERVED_KEPT} served are)"
            )}),
            Err(_) => serde_json::json!({"error": format!("`{cycle}` is not a cycle number")}),
        },
        ["op", token, rest @ ..] => match ctx.operate(token, rest, &who) {
            Ok(what) => serde_json::json!({"ok": what}),
            Err(e) => serde_json::json!({"error": e.to_string()}),
        },
        _ => serde_json::json!({"error": format!("unknown request `{}`", line.trim())}),
    };
    wr.write_all((reply.to_string() + "\n").as_bytes()).await?;
    wr.shutdown().await
}

/// Serve the status socket until `shutdown`.
pub async fn serve_status_socket(
    ctx: LiveContext,
    listener: UnixListener,
    mut shutdown: tokio::sync::watch::Receiver<bool>,
) {
    loop {
        tokio::select! {
            r = listener.accept() => match r {
                Ok((stream, _)) => {
                    let ctx = ctx.clone();
                    tokio::spawn(async move {
                        if let Err(e) = answer(&ctx, stream).await {
                            tracing::debug!(target: "status", "status socket client: {e}");
                        }
                    });
                }
                Err(e) => {
                    tracing::warn!(target: "status", "status socket: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
            },
            _ = shutdown.changed() => break,
        }
    }
}

/// Keep the state file current and `STATUS=` fresh until `shutdown`.
pub async fn keep_state(
    ctx: LiveContext,
    file: StateFile,
    mut kept: PersistentState,
    mut shutdown: tokio::sync::watch::Receiver<bool>,
) {
    let mut tick = tokio::time::interval(Duration::from_millis(50));
    let mut last_notify = Instant::now() - Duration::from_secs(10);
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = shutdown.changed() => break,
        }
        let Some(s) = ctx.live.latest() else { continue };
        let now = PersistentState {
            surge_count: s.surge_count,
            safety_on_count: s.safety_on_count,
            auto: s.auto_requested,
            manual_output: s.manual_output.is_finite().then_some(s.manual_output),
        };
        if now != kept {
            let f = file.clone();
            match tokio::task::spawn_blocking(move || f.store(&now)).await {
                Ok(Ok(())) => kept = now,
                Ok(Err(e)) => tracing::error!(target: "status", "cannot keep the state: {e}"),
                Err(e) => tracing::error!(target: "status", "cannot keep the state: {e}"),
            }
        }
        if last_notify.elapsed() >= Duration::from_secs(1) {
            last_notify = Instant::now();
            let line = status_line(&s);
            let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(&line)]);
        }
    }
}

/// Ask a running daemon over its status socket: `request` is one line (`status`, or
/// `op TOKEN WORDS…`); returns the JSON reply.
pub fn request(socket: &Path, request: &str) -> std::io::Result<serde_json::Value> {
    use std::io::{BufRead, Write};
    let mut s = std::os::unix::net::UnixStream::connect(socket)?;
    s.set_read_timeout(Some(Duration::from_secs(5)))?;
    s.write_all(format!("{request}\n").as_bytes())?;
    let mut line = String::new();
    std::io::BufReader::new(s).read_line(&mut line)?;
    serde_json::from_str(&line).map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    #[test]
    fn token_checks() {
        let dir = tempfile::tempdir().expect("tmp");
        let f = dir.path().join("operator.token");
        assert!(matches!(
            check_token(&f, "x"),
            Err(OpError::Unauthorized(m)) if m.contains("disabled")
        ));
        std::fs::write(&f, "s3cret\n").expect("write");
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o644)).expect("chmod");
        assert!(check_token(&f, "s3cret").is_err(), "world-readable token");
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o642)).expect("chmod");
        assert!(
            matches!(check_token(&f, "s3cret"), Err(OpError::Unauthorized(m)) if m.contains("writable by everyone")),
            "a token file others may write"
        );
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o660)).expect("chmod");
        assert!(check_token(&f, "s3cret").is_err(), "group-writable token");
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o640)).expect("chmod");
        assert_eq!(check_token(&f, "s3cret"), Ok(()));
        assert!(check_token(&f, "s3cre").is_err());
        assert!(check_token(&f, "").is_err());
    }
}
