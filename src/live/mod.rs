//! What the operator sees and does on a running controller.
//!
//! - [`snapshot`]: the live state, published by the control thread each cycle (lock-free).
//! - [`commands`]: operator actions handed to the control thread (wait-free ring).
//! - [`persist`]: surge counter, safety-on steps and last mode kept across restarts.
//! - [`server`]: the status socket (`antisurge status`) and the operator actions on it.
//! - [`metrics`]: the Prometheus/OpenMetrics endpoint.
//! - [`hmi`]: the web HMI; [`tls`]: its HTTPS.

pub mod commands;
pub mod dcs;
pub mod hmi;
pub mod metrics;
pub mod persist;
pub mod report;
pub mod server;
pub mod snapshot;
pub mod tls;

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use crate::daemon::config::StatusSection;

/// The operator token file when `status.operator_token_file` is not set (created by
/// `deploy/install.sh`: random, root:antisurge, mode 0640).
pub const DEFAULT_TOKEN_FILE: &str = "/etc/antisurge/operator.token";

/// Where the status socket is: `status.socket` (relative: under `$RUNTIME_DIRECTORY`, else
/// `./out/`), default `status.sock`.
pub fn socket_path(status: &StatusSection) -> PathBuf {
    let p = status
        .socket
        .clone()
        .unwrap_or_else(|| PathBuf::from("status.sock"));
    if p.is_absolute() {
        return p;
    }
    match std::env::var_os("RUNTIME_DIRECTORY") {
        Some(d) => PathBuf::from(d).join(p),
        None => Path::new("out").join(p),
    }
}

/// The socket an operator's `antisurge status` talks to when not told: the installed
/// service's (`/run/antisurge/status.sock`) if it exists, else `./out/status.sock`.
pub fn default_client_socket() -> PathBuf {
    let installed = Path::new("/run/antisurge/status.sock");
    if installed.exists() {
        installed.to_path_buf()
    } else {
        socket_path(&StatusSection::default())
    }
}

/// The state directory: `status.state_dir`, else `$STATE_DIRECTORY`, else `./out/state`.
pub fn state_dir(status: &StatusSection) -> PathBuf {
    if let Some(d) = &status.state_dir {
        return d.clone();
    }
    match std::env::var_os("STATE_DIRECTORY") {
        Some(d) => PathBuf::from(d),
        None => Path::new("out").join("state"),
    }
}

/// What the daemon needs before the control thread starts.
pub struct LiveSetup {
    /// The snapshot board.
    pub board: Arc<snapshot::LiveBoard>,
    /// Producer of operator actions.
    pub tx: rtrb::Producer<commands::OperatorCommand>,
    /// Consumer (for the control node).
    pub rx: Option<rtrb::Consumer<commands::OperatorCommand>>,
    /// The state file and what it held at start.
    pub state: persist::StateFile,
    /// State restored at start.
    pub kept: persist::PersistentState,
    /// Status socket path.
    pub socket: PathBuf,
    /// Operator token file.
    pub token_file: PathBuf,
}

/// Read the kept state and make the boards. An unreadable state file is reported and the
/// counters start from zero (the controller must start anyway).
pub fn prepare(status: &StatusSection) -> LiveSetup {
    let (tx, rx) = rtrb::RingBuffer::new(16);
    let state = persist::StateFile::in_dir(&state_dir(status));
    let kept = match state.load() {
        Ok(Some(k)) => {
            tracing::info!(target: "status", "restored from {}: surge counter {}, safety-on {} step(s), {}",
                state.path().display(), k.surge_count, k.safety_on_count, if k.auto { "auto" } else { "manual" });
            k
        }
        Ok(None) => persist::PersistentState {
            auto: true,
            ..Default::default()
        },
        Err(e) => {
            tracing::error!(target: "status", "{e}");
            persist::PersistentState {
                auto: true,
                ..Default::default()
            }
        }
    };
    LiveSetup {
        board: Arc::new(snapshot::LiveBoard::default()),
        tx,
        rx: Some(rx),
        state,
        kept,
        socket: socket_path(status),
        token_file: crate::daemon::config::tls::token_file(status),
    }
}

/// The HMI's listener and TLS acceptor (None: the HMI is off). Beyond loopback only with TLS
/// and a usable token file (the rules `check-config` applies, checked again here).
fn hmi_listener(
    status: &StatusSection,
) -> Result<
    Option<(
        tokio::net::TcpListener,
        std::net::SocketAddr,
        Option<tokio_rustls::TlsAcceptor>,
    )>,
    String,
> {
    let Some(addr) = hmi::listen_addr(status.hmi_listen.as_deref(), status.tls.is_some())? else {
        return Ok(None);
    };
    if !addr.ip().is_loopback() {
        let file = crate::daemon::config::tls::token_file(status);
        if let Some(why) = crate::daemon::config::tls::token_file_problem(&file) {
            return Err(format!("not serving on {addr} beyond loopback: {why}"));
        }
    }
    let tls = match &status.tls {
        Some(t) => Some(tls::acceptor(t).map_err(|e| e.to_string())?),
        None => None,
    };
    let l = std::net::TcpListener::bind(addr)
        .and_then(|l| l.set_nonblocking(true).map(|()| l))
        .and_then(tokio::net::TcpListener::from_std)
        .map_err(|e| format!("{addr}: {e}"))?;
    Ok(Some((l, addr, tls)))
}

/// Start the status socket, the metrics endpoint and the persistence task on `tasks`;
/// returns the shared context.
#[allow(clippy::too_many_arguments)]
pub fn spawn(
    status: &StatusSection,
    map: hmi::MapLines,
    events_path: PathBuf,
    setup: LiveSetup,
    stats: Arc<crate::runtime::rt_loop::CycleStats>,
    links: Arc<dyn Fn() -> serde_json::Value + Send + Sync>,
    events: crate::events::EventSender,
    shutdown: tokio::sync::watch::Receiver<bool>,
    tasks: &mut tokio::task::JoinSet<()>,
) -> server::LiveContext {
    let ctx = server::LiveContext {
        live: setup.board,
        commands: Arc::new(Mutex::new(setup.tx)),
        stats,
        links,
        events,
        token_file: setup.token_file,
        started: std::time::Instant::now(),
        served: Arc::default(),
    };
    match server::bind_status_socket(&setup.socket) {
        Ok(l) => {
            tracing::info!(target: "status", "status socket {}", setup.socket.display());
            tasks.spawn(server::serve_status_socket(
                ctx.clone(),
                l,
                shutdown.clone(),
            ));
        }
        Err(e) => tracing::error!(target: "status",
            "no status socket at {}: {e}; `antisurge status` will not answer", setup.socket.display()),
    }
    match metrics::listen_addr(
        status.metrics_listen.as_deref(),
        status.metrics_allow_remote,
    ) {
        Ok(Some(addr)) => match std::net::TcpListener::bind(addr)
            .and_then(|l| l.set_nonblocking(true).map(|()| l))
            .and_then(tokio::net::TcpListener::from_std)
        {
            Ok(l) => {
                tracing::info!(target: "status", "metrics on http://{addr}/metrics");
                tasks.spawn(metrics::serve(
                    l,
                    Arc::clone(&ctx.live),
                    Arc::clone(&ctx.stats),
                    shutdown.clone(),
                ));
            }
            Err(e) => tracing::error!(target: "status", "no metrics endpoint on {addr}: {e}"),
        },
        Ok(None) => {}
        Err(e) => tracing::error!(target: "status", "no metrics endpoint: {e}"),
    }
    match hmi_listener(status) {
        Ok(Some((l, addr, tls))) => {
            let scheme = if tls.is_some() { "https" } else { "http" };
            tracing::info!(target: "status", "web HMI on {scheme}://{addr}/");
            let h = hmi::Hmi {
                ctx: ctx.clone(),
                map_json: serde_json::to_string(&map).unwrap_or_default(),
                events_path,
            };
            tasks.spawn(hmi::serve(l, h, tls, shutdown.clone()));
        }
        Ok(None) => {}
        Err(e) => tracing::error!(target: "status", "no web HMI: {e}"),
    }
    if let Some(text) = status
        .modbus_listen
        .as_deref()
        .filter(|t| !t.trim().is_empty())
    {
        match text
            .trim()
            .parse::<std::net::SocketAddr>()
            .map_err(|e| e.to_string())
            .and_then(|a| std::net::TcpListener::bind(a).map_err(|e| e.to_string()))
            .and_then(|l| {
                l.set_nonblocking(true)
                    .map(|()| l)
                    .map_err(|e| e.to_string())
            })
            .and_then(|l| tokio::net::TcpListener::from_std(l).map_err(|e| e.to_string()))
        {
            Ok(l) => {
                let limits = dcs::limits(status);
                tracing::info!(target: "status", "Modbus block for the DCS on {text} (unit 1, input registers 0-15; at most {} connections, idle time-out {:?}, {} requests/s each)",
                    limits.max_connections, limits.idle_timeout, limits.max_requests_per_s);
                tasks.spawn(dcs::serve(
                    l,
                    Arc::clone(&ctx.live),
                    limits,
                    ctx.events.clone(),
                    shutdown.clone(),
                ));
            }
            Err(e) => {
                tracing::error!(target: "status", "no Modbus block for the DCS on {text}: {e}")
            }
        }
    }
    tasks.spawn(server::keep_state(
        ctx.clone(),
        setup.state,
        setup.kept,
        shutdown,
    ));
    ctx
}
