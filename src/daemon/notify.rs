//! systemd notification: READY=1 after the first healthy control cycle, WATCHDOG=1 only
//! while the control thread keeps running cycles (its [`Health`] counter advances), STOPPING=1
//! at shutdown. Outside systemd (`NOTIFY_SOCKET` unset) every call is a no-op.
//!
//! The watchdog is fed from its own thread ([`spawn_watchdog`]), which reads nothing but the
//! control loop's [`Health`]: a slow config load, a reload or a busy I/O task can never delay
//! a `WATCHDOG=1`, and only a stuck control loop stops them (issue 12, item 1).

use crate::node::control::Health;
use sd_notify::NotifyState;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// Feeds systemd from the control loop's health.
#[derive(Debug)]
pub struct Notifier {
    ready: bool,
    watchdog: Option<Duration>,
    last_cycles: u64,
    last_ping: Instant,
}

impl Default for Notifier {
    fn default() -> Self {
        Notifier::new()
    }
}

impl Notifier {
    /// A notifier; reads `WATCHDOG_USEC` from the environment.
    pub fn new() -> Notifier {
        Notifier {
            ready: false,
            watchdog: sd_notify::watchdog_enabled(),
            last_cycles: 0,
            last_ping: Instant::now(),
        }
    }

    /// Call periodically (every ~100 ms).
    pub fn tick(&mut self, health: &Health) {
        let cycles = health.cycles.load(Ordering::Relaxed);
        let healthy = health.healthy_cycles.load(Ordering::Relaxed);
        if !self.ready && healthy > 0 {
            self.ready = true;
            let _ = sd_notify::notify(&[
                NotifyState::Ready,
                NotifyState::Status("control loop running, inputs healthy"),
            ]);
            tracing::info!(target: "antisurge", "first healthy control cycle: ready");
        }
        if let Some(wd) = self.watchdog {
            // ping every quarter of the watchdog period (so the gap between two pings stays
            // well under half of it), and only if the control thread advanced
            if cycles > self.last_cycles && self.last_ping.elapsed() >= wd / 4 {
                let _ = sd_notify::notify(&[NotifyState::Watchdog]);
                self.last_ping = Instant::now();
            }
        }
        self.last_cycles = cycles;
    }

    /// Tell systemd we are stopping.
    pub fn stopping(&self) {
        let _ = sd_notify::notify(&[NotifyState::Stopping]);
    }
}

/// Period of the watchdog thread's health check.
pub const WATCHDOG_TICK: Duration = Duration::from_millis(50);

/// Start the watchdog thread: every [`WATCHDOG_TICK`] it reads `health` and notifies systemd,
/// until `stop` is set (then it sends STOPPING=1 and ends).
pub fn spawn_watchdog(
    health: std::sync::Arc<Health>,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("antisurge-wd".into())
        .stack_size(crate::runtime::rt_loop::SMALL_THREAD_STACK_BYTES)
        .spawn(move || {
            let mut n = Notifier::new();
            while !stop.load(Ordering::Relaxed) {
                n.tick(&health);
                std::thread::sleep(WATCHDOG_TICK);
            }
            n.stopping();
        })
}

/// Peak resident memory of this process, KiB (`getrusage`).
pub fn max_rss_kib() -> u64 {
    // SAFETY: getrusage writes the struct we pass.
    unsafe {
        let mut ru: libc::rusage = std::mem::zeroed();
        if libc::getrusage(libc::RUSAGE_SELF, &mut ru) == 0 {
            ru.ru_maxrss as u64
        } else {
            0
        }
    }
}
