//! Rate-limited panic reports (issue 12, item 9): a panic that repeats per request (tokio-modbus
//! 0.17's request decoder panicked on one 13-byte frame, 206 bytes of log each time) must not
//! flood the journal. [`install`] puts a panic hook in front of the default one: at most
//! `max_per_window` reports per `window` are printed (the default hook's message and
//! location); the rest are counted, and the next report printed says how many were suppressed.
//! A panic still unwinds or aborts as before; only its report is limited.
//!
//! [`RateLimit`] is the decision alone (atomics, no lock, no allocation), tested with a
//! synthetic clock.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// Reports printed per window by the daemon's hook.
pub const MAX_REPORTS_PER_WINDOW: u32 = 5;
/// The window of [`MAX_REPORTS_PER_WINDOW`].
pub const REPORT_WINDOW: Duration = Duration::from_secs(60);

/// Whether a report is printed; if so, how many were suppressed since the last printed one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admit {
    /// Print it; `suppressed` reports were dropped before it.
    Print {
        /// Reports dropped since the last printed one.
        suppressed: u64,
    },
    /// Drop it (counted).
    Suppress,
}

/// At most `max` admissions per fixed window of `window_ns`, the rest counted.
#[derive(Debug)]
pub struct RateLimit {
    max: u32,
    window_ns: u64,
    window_start_ns: AtomicU64,
    in_window: AtomicU32,
    suppressed: AtomicU64,
}

impl RateLimit {
    /// A limit of `max` per `window`.
    pub const fn new(max: u32, window: Duration) -> RateLimit {
        RateLimit {
            max,
            window_ns: window.as_nanos() as u64,
            window_start_ns: AtomicU64::new(0),
            in_window: AtomicU32::new(0),
            suppressed: AtomicU64::new(0),
        }
    }

    /// Decide for a report at `now_ns` (any monotonic clock, ns).
    pub fn admit(&self, now_ns: u64) -> Admit {
        let start = self.window_start_ns.load(Ordering::Acquire);
        if now_ns.saturating_sub(start) >= self.window_ns
            && self
                .window_start_ns
                .compare_exchange(start, now_ns, Ordering::AcqRel, Ordering::Acquire)
                .is_ok()
        {
            self.in_window.store(0, Ordering::Release);
        }
        if self.in_window.fetch_add(1, Ordering::AcqRel) < self.max {
            Admit::Print {
                suppressed: self.suppressed.swap(0, Ordering::AcqRel),
            }
        } else {
            self.suppressed.fetch_add(1, Ordering::AcqRel);
            Admit::Suppress
        }
    }

    /// Reports dropped and not yet mentioned.
    pub fn pending_suppressed(&self) -> u64 {
        self.suppressed.load(Ordering::Acquire)
    }
}

/// Install the rate-limited hook (once; later calls do nothing): at most `max_per_window`
/// panic reports per `window` on stderr (the journal under systemd).
pub fn install(max_per_window: u32, window: Duration) {
    static INSTALLED: OnceLock<()> = OnceLock::new();
    INSTALLED.get_or_init(|| {
        let limit = RateLimit::new(max_per_window, window);
        let epoch = Instant::now();
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            // + window: the first report opens a window at once
            let now_ns = epoch.elapsed().as_nanos() as u64 + limit.window_ns;
            match limit.admit(now_ns) {
                Admit::Print { suppressed } => {
                    if suppressed > 0 {
                        eprintln!(
                            "antisurge: {suppressed} further panic reports suppressed (at most \
                             {max_per_window} per {} s)",
                            window.as_secs_f64()
                        );
                    }
                    default(info);
                }
                Admit::Suppress => {}
            }
        }));
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: u64 = 1_000_000_000;

    #[test]
    fn at_most_max_per_window_then_the_count_of_the_suppressed() {
        let l = RateLimit::new(3, Duration::from_secs(10));
        let t0 = 100 * S;
        let got: Vec<Admit> = (0..10).map(|i| l.admit(t0 + i * S / 10)).collect();
        assert_eq!(&got[..3], &[Admit::Print { suppressed: 0 }; 3]);
        assert!(got[3..].iter().all(|a| *a == Admit::Suppress), "{got:?}");
        assert_eq!(l.pending_suppressed(), 7);
        // still inside the window: suppressed
        assert_eq!(l.admit(t0 + 9 * S), Admit::Suppress);
        // a new window: printed, with the count of what was dropped
        assert_eq!(l.admit(t0 + 10 * S), Admit::Print { suppressed: 8 });
        assert_eq!(l.admit(t0 + 10 * S + 1), Admit::Print { suppressed: 0 });
        assert_eq!(l.pending_suppressed(), 0);
    }

    #[test]
    fn concurrent_reports_never_exceed_the_limit() {
        let l = RateLimit::new(5, Duration::from_secs(3600));
        // the window opened by a first report (opening it is a single winner's CAS)
        assert_eq!(l.admit(3600 * S), Admit::Print { suppressed: 0 });
        let printed = AtomicU32::new(1);
        std::thread::scope(|s| {
            for _ in 0..4 {
                s.spawn(|| {
                    for _ in 0..1000 {
                        if let Admit::Print { .. } = l.admit(3600 * S) {
                            printed.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                });
            }
        });
        assert_eq!(printed.load(Ordering::Relaxed), 5);
        assert_eq!(l.pending_suppressed(), 3996);
    }
}
