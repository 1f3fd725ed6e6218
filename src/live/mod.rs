//! What the operator sees and does on a running controller.
//!
//! - [`snapshot`]: the live state, published by the control thread each cycle (lock-free).
//! - [`commands`]: operator actions handed to the control thread (wait-free ring).
//! - [`persist`]: surge counter, safety-on steps and last mode kept across restarts.
//! - [`server`]: the status socket (`antisurge status`) and the operator actions on it.
//! - [`metrics`]: the Prometheus/OpenMetrics endpoint.
//! - [`hmi`]: the web HMI; [`tls`]: its HTTPS.
//! - [`station`]: the ordinary-priority runtime every operator surface is served on, and its
//!   bounded HTTP serving; [`guard`]: wrong-token limits and the `Host`/`Origin` check.
//!
//! Every configured surface is bound (or taken from systemd socket activation) by
//! [`prepare`], before the control thread starts: a surface that cannot be bound (another
//! process holds the port) stops the start with [`SurfaceError`], exit status
//! [`EX_UNAVAILABLE`]. A squatter never receives the operator's requests.

pub mod commands;
pub mod dcs;
pub mod guard;
pub mod hmi;
pub mod metrics;
pub mod persist;
pub mod report;
pub mod server;
pub mod settings;
pub mod snapshot;
pub mod station;
pub mod tls;
pub mod tls_settings;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use crate::live::settings::StatusSection;

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
    /// The surfaces' listeners, bound.
    pub bound: Bound,
}

/// Exit status of `antisurge run` when an operator surface cannot be bound (`EX_UNAVAILABLE`
/// of sysexits.h): another process holds the address. The service unit restarts on it (every
/// second, each attempt logging the holder's address), so the controller starts as soon as
/// the port is free; with the shipped `.socket` units systemd holds the ports from boot and
/// no other process can take them.
pub const EX_UNAVAILABLE: u8 = 69;

/// An operator surface that cannot be served: the daemon does not start.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct SurfaceError(pub String);

/// Which controller this is: shown on the HMI's page and in every status answer, so that a
/// second controller's page is not mistaken for this one.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Identity {
    /// The machine's name (machine or plant file).
    pub machine: String,
    /// The computer's host name.
    pub host: String,
    /// The controller's instance: its configuration file.
    pub instance: String,
    /// The daemon's process id.
    pub pid: u32,
}

impl Identity {
    /// The identity of a daemon running `machine` from the configuration file `config`.
    pub fn new(machine: &str, config: &Path) -> Identity {
        Identity {
            machine: machine.to_string(),
            host: guard::host_name(),
            instance: config.display().to_string(),
            pid: std::process::id(),
        }
    }
}

static IDENTITY: OnceLock<Identity> = OnceLock::new();

/// This daemon's identity (empty before [`prepare`]).
pub fn identity() -> Identity {
    IDENTITY.get().cloned().unwrap_or_default()
}

/// The operator surfaces' listeners (std sockets, non-blocking; made tokio listeners on the
/// station runtime).
#[derive(Default)]
pub struct Bound {
    status_socket: Option<std::os::unix::net::UnixListener>,
    metrics: Option<(std::net::TcpListener, SocketAddr)>,
    hmi: Option<(
        std::net::TcpListener,
        SocketAddr,
        Option<tokio_rustls::TlsAcceptor>,
    )>,
    dcs: Option<(std::net::TcpListener, String)>,
}

impl std::fmt::Debug for Bound {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bound")
            .field("status_socket", &self.status_socket.is_some())
            .field("metrics", &self.metrics.as_ref().map(|m| m.1))
            .field("hmi", &self.hmi.as_ref().map(|h| (h.1, h.2.is_some())))
            .field("dcs", &self.dcs.as_ref().map(|d| &d.1))
            .finish()
    }
}

impl std::fmt::Debug for LiveSetup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveSetup")
            .field("socket", &self.socket)
            .field("token_file", &self.token_file)
            .field("bound", &self.bound)
            .finish_non_exhaustive()
    }
}

/// Listening sockets handed over by systemd (socket activation: `LISTEN_FDS` for this
/// process), by their local address.
fn activated_listeners() -> Vec<(SocketAddr, std::net::TcpListener)> {
    use std::os::fd::FromRawFd;
    let Ok(fds) = sd_notify::listen_fds() else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for fd in fds {
        // SAFETY: systemd passed this descriptor to us (LISTEN_PID is ours); nothing else
        // owns it. A descriptor that is not a TCP listener is closed when dropped.
        let l = unsafe { std::net::TcpListener::from_raw_fd(fd) };
        match l.local_addr() {
            Ok(a) => out.push((a, l)),
            Err(e) => {
                tracing::warn!(target: "status", "socket activation: descriptor {fd} is not a TCP listener ({e}); ignored")
            }
        }
    }
    out
}

/// Bind `addr` for `what`, or take it from the activated sockets. Refuses with a message
/// that names the address and says another process holds it.
fn bind_surface(
    what: &str,
    key: &str,
    addr: SocketAddr,
    activated: &mut Vec<(SocketAddr, std::net::TcpListener)>,
) -> Result<std::net::TcpListener, SurfaceError> {
    let l = match activated.iter().position(|(a, _)| *a == addr) {
        Some(i) => {
            tracing::info!(target: "status", "{what} on {addr}: socket from systemd (socket activation)");
            activated.swap_remove(i).1
        }
        None => std::net::TcpListener::bind(addr).map_err(|e| {
            let who = if e.kind() == std::io::ErrorKind::AddrInUse {
                "another process holds it (a second controller, or a process squatting the port to receive the operator's requests)".to_string()
            } else {
                e.to_string()
            };
            SurfaceError(format!(
                "cannot serve the {what} on {addr} ({key}): {who}; the controller does not start with an operator surface it cannot bind. Stop that process (`ss -ltnp 'sport = :{port}'` shows it), choose another address, set {key} = \"\" to turn the {what} off, or let systemd hold the port (antisurge-{short}.socket)",
                port = addr.port(),
                short = if key.ends_with("hmi_listen") { "hmi" } else { "metrics" },
            ))
        })?,
    };
    l.set_nonblocking(true)
        .map_err(|e| SurfaceError(format!("{what} on {addr}: {e}")))?;
    Ok(l)
}

/// Bind every configured operator surface (see the module documentation).
fn bind_all(status: &StatusSection, socket: &Path) -> Result<Bound, SurfaceError> {
    let mut activated = activated_listeners();
    let mut b = Bound::default();
    match metrics::listen_addr(
        status.metrics_listen.as_deref(),
        status.metrics_allow_remote,
    ) {
        Ok(Some(addr)) => {
            let l = bind_surface(
                "metrics endpoint",
                "status.metrics_listen",
                addr,
                &mut activated,
            )?;
            b.metrics = Some((l, addr));
        }
        Ok(None) => {}
        Err(e) => return Err(SurfaceError(format!("no metrics endpoint: {e}"))),
    }
    if let Some(addr) = hmi::listen_addr(status.hmi_listen.as_deref(), status.tls.is_some())
        .map_err(|e| SurfaceError(format!("no web HMI: {e}")))?
    {
        if !addr.ip().is_loopback() {
            let file = crate::live::tls_settings::token_file(status);
            if let Some(why) = crate::live::tls_settings::token_file_problem(&file) {
                return Err(SurfaceError(format!(
                    "not serving the web HMI on {addr} beyond loopback: {why}"
                )));
            }
        }
        let tls = match &status.tls {
            Some(t) => Some(tls::acceptor(t).map_err(|e| SurfaceError(e.to_string()))?),
            None => None,
        };
        let l = bind_surface("web HMI", "status.hmi_listen", addr, &mut activated)?;
        b.hmi = Some((l, addr, tls));
    }
    if let Some(text) = status
        .modbus_listen
        .as_deref()
        .filter(|t| !t.trim().is_empty())
    {
        let addr: SocketAddr = text.trim().parse().map_err(|e| {
            SurfaceError(format!(
                "status.modbus_listen `{text}`: {e} (expected host:port)"
            ))
        })?;
        let l = bind_surface(
            "Modbus block for the DCS",
            "status.modbus_listen",
            addr,
            &mut activated,
        )?;
        b.dcs = Some((l, text.trim().to_string()));
    }
    for (a, _) in &activated {
        tracing::warn!(target: "status", "socket activation: {a} is not a configured operator surface; closed");
    }
    b.status_socket = Some(
        server::bind_status_socket(socket)
            .and_then(|l| l.into_std())
            .map_err(|e| {
                SurfaceError(format!(
                    "cannot serve the status socket {}: {e}; the controller does not start with an operator surface it cannot bind",
                    socket.display()
                ))
            })?,
    );
    Ok(b)
}

/// Read the kept state, make the boards and bind the operator surfaces. An unreadable state
/// file is reported and the counters start from zero (the controller must start anyway); a
/// surface that cannot be bound, or an unsafe operator token file, is a [`SurfaceError`].
pub fn prepare(status: &StatusSection, identity: Identity) -> Result<LiveSetup, SurfaceError> {
    let _ = IDENTITY.set(identity);
    let token_file = crate::live::tls_settings::token_file(status);
    if let Some(why) = crate::live::tls_settings::token_file_unsafe(&token_file) {
        return Err(SurfaceError(why));
    }
    let socket = socket_path(status);
    let bound = bind_all(status, &socket)?;
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
    Ok(LiveSetup {
        board: Arc::new(snapshot::LiveBoard::default()),
        tx,
        rx: Some(rx),
        state,
        kept,
        socket,
        token_file,
        bound,
    })
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
    inputs: Vec<crate::io::signal_map::InputLink>,
    events: crate::events::EventSender,
    shutdown: tokio::sync::watch::Receiver<bool>,
    tasks: &mut tokio::task::JoinSet<()>,
) -> server::LiveContext {
    let ctx = server::LiveContext {
        live: setup.board,
        commands: Arc::new(Mutex::new(setup.tx)),
        stats,
        links,
        inputs: inputs.into(),
        events,
        token_file: setup.token_file,
        started: std::time::Instant::now(),
        served: Arc::default(),
    };
    let station = match station::handle() {
        Ok(h) => h,
        Err(e) => {
            // cannot happen short of thread exhaustion: serve on the caller's runtime rather
            // than not at all, and say so
            tracing::error!(target: "status", "{e}; the operator surfaces run on the I/O runtime");
            tokio::runtime::Handle::current()
        }
    };
    let _entered = station.enter();
    let Bound {
        status_socket,
        metrics: metrics_l,
        hmi: hmi_l,
        dcs: dcs_l,
    } = setup.bound;
    if let Some(l) = status_socket.and_then(|l| tokio::net::UnixListener::from_std(l).ok()) {
        tracing::info!(target: "status", "status socket {}", setup.socket.display());
        tasks.spawn_on(
            server::serve_status_socket(ctx.clone(), l, shutdown.clone()),
            &station,
        );
    }
    if let Some((l, addr)) = metrics_l {
        match tokio::net::TcpListener::from_std(l) {
            Ok(l) => {
                tracing::info!(target: "status", "metrics on http://{addr}/metrics");
                tasks.spawn_on(
                    metrics::serve(
                        l,
                        Arc::clone(&ctx.live),
                        Arc::clone(&ctx.stats),
                        shutdown.clone(),
                    ),
                    &station,
                );
            }
            Err(e) => tracing::error!(target: "status", "no metrics endpoint on {addr}: {e}"),
        }
    }
    if let Some((l, addr, tls)) = hmi_l {
        match tokio::net::TcpListener::from_std(l) {
            Ok(l) => {
                let scheme = if tls.is_some() { "https" } else { "http" };
                tracing::info!(target: "status", "web HMI on {scheme}://{addr}/");
                let h = hmi::Hmi {
                    ctx: ctx.clone(),
                    map_json: serde_json::to_string(&map).unwrap_or_default(),
                    events_path,
                    identity: identity(),
                    guard: Arc::default(),
                    events_cache: Arc::default(),
                    trends: Arc::default(),
                };
                tasks.spawn_on(hmi::serve(l, h, tls, shutdown.clone()), &station);
            }
            Err(e) => tracing::error!(target: "status", "no web HMI on {addr}: {e}"),
        }
    }
    if let Some((l, text)) = dcs_l {
        match tokio::net::TcpListener::from_std(l) {
            Ok(l) => {
                let limits = dcs::limits(status);
                tracing::info!(target: "status", "Modbus block for the DCS on {text} (unit 1, input registers 0-15; at most {} connections, idle time-out {:?}, {} requests/s each)",
                    limits.max_connections, limits.idle_timeout, limits.max_requests_per_s);
                tasks.spawn_on(
                    dcs::serve(
                        l,
                        Arc::clone(&ctx.live),
                        limits,
                        ctx.events.clone(),
                        shutdown.clone(),
                    ),
                    &station,
                );
            }
            Err(e) => {
                tracing::error!(target: "status", "no Modbus block for the DCS on {text}: {e}")
            }
        }
    }
    tasks.spawn_on(
        server::keep_state(ctx.clone(), setup.state, setup.kept, shutdown),
        &station,
    );
    ctx
}
