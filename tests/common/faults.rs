//! Helpers for the fault tests against the `antisurge` binary (issue 12): a config for the
//! in-process plant in a temporary directory, a fake systemd notification socket, and runs
//! with piped output and resource limits. Used by tests/daemon/daemon_faults.rs and the fault
//! campaign (tests/daemon/fault_campaign.rs).

use super::daemon::shipped;
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// A config for the in-process plant, with its plant file copied into `dir` (so the test can
/// replace it) and `extra` appended.
pub fn config(dir: &Path, extra: &str) -> (PathBuf, String) {
    let plant = plant_file(dir);
    std::fs::create_dir_all(dir.join("plants")).expect("plants dir");
    for d in ["maps", "scenarios"] {
        // the plant file names its maps relative to itself; scenarios are looked up beside it
        if !dir.join(d).exists() {
            std::os::unix::fs::symlink(super::root().join("config").join(d), dir.join(d))
                .expect("link");
        }
    }
    std::fs::copy(shipped("plants/kvangardsnes2009_recycle.toml"), &plant).expect("copy plant");
    let text = format!(
        r#"[plant]
file = "{plant}"
[control]
law = "recycle-pi"
[cycle]
rate_hz = 200.0
lock_memory = false
[event_log]
path = "{events}"
fsync = "always"
[simulation]
scenario = "hold"
{extra}"#,
        plant = plant.display(),
        events = dir.join("events.jsonl").display(),
    );
    let path = dir.join("antisurge.toml");
    std::fs::write(&path, &text).expect("write config");
    (path, text)
}

pub fn plant_file(dir: &Path) -> PathBuf {
    dir.join("plants").join("plant.toml")
}

pub fn events(dir: &Path) -> String {
    std::fs::read_to_string(dir.join("events.jsonl")).unwrap_or_default()
}

pub fn mkfifo(p: &Path) {
    let c = std::ffi::CString::new(p.to_str().expect("utf-8")).expect("cstr");
    // SAFETY: mkfifo on a path in our temporary directory.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
}

/// A fake systemd notification socket: every datagram with its arrival time.
pub struct FakeNotify {
    /// Socket path (`NOTIFY_SOCKET`).
    pub path: PathBuf,
    /// Datagrams with arrival times.
    pub got: Arc<Mutex<Vec<(Instant, String)>>>,
}

impl FakeNotify {
    pub fn new(dir: &Path) -> FakeNotify {
        let path = dir.join("notify.sock");
        let sock = UnixDatagram::bind(&path).expect("bind notify socket");
        sock.set_read_timeout(Some(Duration::from_millis(100)))
            .expect("timeout");
        let got = Arc::new(Mutex::new(Vec::new()));
        let g = Arc::clone(&got);
        std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            loop {
                match sock.recv(&mut buf) {
                    Ok(n) => g
                        .lock()
                        .expect("lock")
                        .push((Instant::now(), String::from_utf8_lossy(&buf[..n]).into())),
                    Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                    Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                    Err(_) => return,
                }
            }
        });
        FakeNotify { path, got }
    }

    pub fn watchdog_times(&self) -> Vec<Instant> {
        self.got
            .lock()
            .expect("lock")
            .iter()
            .filter(|(_, m)| m.lines().any(|l| l == "WATCHDOG=1"))
            .map(|(t, _)| *t)
            .collect()
    }
}

pub fn spawn_notified(
    dir: &Path,
    args: &[&str],
    notify: &FakeNotify,
    wd_usec: u64,
) -> std::process::Child {
    let log = std::fs::File::create(dir.join("run.log")).expect("log file");
    std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
        // (the test's own status socket, the HMI and metrics off: the default ports are one
        // per machine, and a daemon that cannot bind them does not start)
        .envs(super::daemon::own_surfaces(dir, args))
        .args(args)
        .env("ANTISURGE_LOG", "info")
        .env_remove("LOGS_DIRECTORY")
        .env_remove("WATCHDOG_PID")
        .env("NOTIFY_SOCKET", &notify.path)
        .env("WATCHDOG_USEC", wd_usec.to_string())
        .stdout(std::process::Stdio::from(log.try_clone().expect("clone")))
        .stderr(std::process::Stdio::from(log))
        .spawn()
        .expect("spawn antisurge")
}

/// `antisurge run` with piped output (not a file: a file-size limit would cut it).
pub fn run_piped(cfg: &Path, secs: &str, fsize_limit: Option<u64>) -> std::process::Output {
    use std::os::unix::process::CommandExt;
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"));
    let args = [
        "run",
        "--config",
        cfg.to_str().expect("utf-8"),
        "--duration-s",
        secs,
    ];
    // (the test's own status socket, the HMI and metrics off: the default ports are one per
    // machine, and a daemon that cannot bind them does not start)
    let dir = cfg.parent().expect("the config's directory");
    cmd.envs(super::daemon::own_surfaces(dir, &args))
        .args(args)
        .env("ANTISURGE_LOG", "info")
        .env_remove("LOGS_DIRECTORY")
        .env_remove("NOTIFY_SOCKET");
    if let Some(limit) = fsize_limit {
        // SAFETY: setrlimit is async-signal-safe; it only lowers this child's own limit.
        unsafe {
            cmd.pre_exec(move || {
                let r = libc::rlimit {
                    rlim_cur: limit,
                    rlim_max: limit,
                };
                if libc::setrlimit(libc::RLIMIT_FSIZE, &r) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    }
    cmd.output().expect("run antisurge")
}
