//! The fixed-deadline loop: a dedicated thread that sleeps to absolute deadlines with
//! `clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)` (tokio timers resolve only to 1 ms and
//! cannot pace a 1 kHz loop), asks for SCHED_FIFO, CPU affinity and locked memory when
//! permitted, and records wake-up jitter, compute time, overruns and input age in lock-free
//! histograms.

use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Real-time settings of a loop.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RtSettings {
    /// Cycle rate, Hz.
    #[serde(default = "d_rate")]
    pub rate_hz: f64,
    /// SCHED_FIFO priority (1–99); `None`: normal scheduling.
    #[serde(default = "d_prio")]
    pub priority: Option<i32>,
    /// CPU to pin the thread to; `None`: no affinity.
    #[serde(default)]
    pub cpu: Option<usize>,
    /// Lock all memory (mlockall) so page faults cannot stall a cycle.
    #[serde(default = "d_true")]
    pub lock_memory: bool,
}

fn d_rate() -> f64 {
    1000.0
}
fn d_prio() -> Option<i32> {
    Some(80)
}
fn d_true() -> bool {
    true
}

impl Default for RtSettings {
    fn default() -> Self {
        RtSettings {
            rate_hz: d_rate(),
            priority: d_prio(),
            cpu: None,
            lock_memory: true,
        }
    }
}

impl RtSettings {
    /// Period, ns.
    pub fn period_ns(&self) -> u64 {
        (1e9 / self.rate_hz).round() as u64
    }

    /// SCHED_FIFO priority of the bus I/O threads: they carry the loop's inputs and outputs,
    /// so they must not starve behind ordinary processes, but they stay below the loop
    /// (10 below `priority`, at least 1). `None` when the loop itself runs unprioritised.
    pub fn io_priority(&self) -> Option<i32> {
        self.priority.map(|p| (p - IO_PRIORITY_BELOW_LOOP).max(1))
    }
}

/// Stack of each bus I/O thread, bytes.
pub const IO_THREAD_STACK_BYTES: usize = 512 * 1024;

/// Stack of the control thread, bytes: the 256 KiB it prefaults plus room. With locked memory
/// (mlockall) every thread's whole stack is resident, so the daemon's threads are sized
/// instead of taking Rust's default 2 MiB each (issue 25: 10 MiB of the 36 MiB RSS). The
/// deepest stack measured in a run without locking (touched pages) was under 100 KiB.
pub const CONTROL_THREAD_STACK_BYTES: usize = 1024 * 1024;

/// Stack of the daemon's worker threads that parse, format or simulate (in-process plant,
/// black-box recorder, trace writer), bytes.
pub const WORKER_THREAD_STACK_BYTES: usize = 512 * 1024;

/// Stack of the daemon's small service threads (watchdog, event-log writer), bytes.
pub const SMALL_THREAD_STACK_BYTES: usize = 256 * 1024;

/// How far the I/O threads' priority sits below the control loop's.
pub const IO_PRIORITY_BELOW_LOOP: i32 = 10;

/// Ask for SCHED_FIFO at `priority` for the calling thread.
pub fn set_current_thread_fifo(priority: i32) -> Result<i32, String> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: sched_setscheduler reads the param struct we pass for the calling thread (0).
    let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if r == 0 {
        Ok(priority)
    } else {
        Err(std::io::Error::last_os_error().to_string())
    }
}

/// A tokio runtime for bus I/O whose threads run at the settings' I/O priority when the OS
/// grants it (see [`RtSettings::io_priority`]); what was granted is logged once.
pub fn io_runtime(s: &RtSettings, name: &str) -> std::io::Result<tokio::runtime::Runtime> {
    let prio = s.io_priority();
    let logged = std::sync::Arc::new(AtomicBool::new(false));
    let label = name.to_string();
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .thread_name(name)
        // with locked memory (mlockall) every thread's whole stack is resident: the bus tasks
        // need far less than tokio's default 2 MiB
        .thread_stack_size(IO_THREAD_STACK_BYTES)
        .on_thread_start(move || {
            if let Some(p) = prio {
                let got = set_current_thread_fifo(p);
                if !logged.swap(true, Ordering::Relaxed) {
                    match got {
                        Ok(p) => tracing::info!(target: "rt", "{label} threads: SCHED_FIFO priority {p}"),
                        Err(e) => tracing::info!(target: "rt", "{label} threads: normal scheduling (SCHED_FIFO refused: {e})"),
                    }
                }
            }
        })
        .build()
}

/// What the thread obtained from the OS (for the log: "says in the log what it got when not").
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct RtGranted {
    /// SCHED_FIFO at this priority, or the error.
    pub scheduler: Option<Result<i32, String>>,
    /// Pinned to this CPU, or the error.
    pub affinity: Option<Result<usize, String>>,
    /// Memory locked, or the error.
    pub memory_locked: Option<Result<(), String>>,
}

impl std::fmt::Display for RtGranted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.scheduler {
            Some(Ok(p)) => write!(f, "SCHED_FIFO priority {p}")?,
            Some(Err(e)) => write!(f, "normal scheduling (SCHED_FIFO refused: {e})")?,
            None => write!(f, "normal scheduling (not requested)")?,
        }
        match &self.affinity {
            Some(Ok(c)) => write!(f, ", pinned to CPU {c}")?,
            Some(Err(e)) => write!(f, ", not pinned ({e})")?,
            None => {}
        }
        match &self.memory_locked {
            Some(Ok(())) => write!(f, ", memory locked"),
            Some(Err(e)) => write!(f, ", memory not locked ({e})"),
            None => Ok(()),
        }
    }
}

/// Number of CPUs a `cpu_set_t` can name (`CPU_SETSIZE`).
pub const CPU_SET_BITS: usize = 8 * std::mem::size_of::<libc::cpu_set_t>();

/// CPUs configured on this machine (`sysconf(_SC_NPROCESSORS_CONF)`), at most
/// [`CPU_SET_BITS`]: the valid range of `[cycle] cpu` is `0..configured_cpus()`.
pub fn configured_cpus() -> usize {
    // SAFETY: sysconf only reads a system value.
    let n = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_CONF) };
    (n.max(1) as usize).min(CPU_SET_BITS)
}

/// Apply the settings to the calling thread.
pub fn setup_current_thread(s: &RtSettings) -> RtGranted {
    let mut g = RtGranted::default();
    if s.lock_memory {
        // SAFETY: mlockall only changes the process's paging; flags are valid constants.
        let r = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
        g.memory_locked = Some(if r == 0 {
            Ok(())
        } else {
            Err(std::io::Error::last_os_error().to_string())
        });
        prefault_stack();
    }
    if let Some(cpu) = s.cpu.filter(|&c| c >= CPU_SET_BITS) {
        g.affinity = Some(Err(format!(
            "CPU {cpu} is beyond the {CPU_SET_BITS} CPUs a cpu_set_t holds; not pinned"
        )));
    }
    if let Some(cpu) = s.cpu.filter(|&c| c < CPU_SET_BITS) {
        // SAFETY: a zeroed cpu_set_t is valid; CPU_SET writes within it (cpu < CPU_SET_BITS,
        // checked above: a larger index panics inside CPU_SET); sched_setaffinity reads it.
        let r = unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_SET(cpu, &mut set);
            libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
        };
        g.affinity = Some(if r == 0 {
            Ok(cpu)
        } else {
            Err(std::io::Error::last_os_error().to_string())
        });
    }
    if let Some(p) = s.priority {
        g.scheduler = Some(set_current_thread_fifo(p));
    }
    g
}

#[inline(never)]
fn prefault_stack() {
    // touch 256 KiB of stack so the first cycles do not fault it in
    let mut buf = [0u8; 256 * 1024];
    std::hint::black_box(&mut buf);
}

/// Sleep until `deadline_ns` (absolute, CLOCK_MONOTONIC), across signals.
pub(crate) fn sleep_until(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: clock_nanosleep reads `ts`; the remaining-time pointer may be null with
        // TIMER_ABSTIME.
        let r = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if r != libc::EINTR {
            return;
        }
    }
}

/// Number of histogram buckets: 1 µs wide below 1 ms, 10 µs wide from 1 ms to 10 ms, then one
/// overflow bucket.
const BUCKETS: usize = 1000 + 900 + 1;

/// A lock-free latency histogram in microseconds.
#[derive(Debug)]
pub struct Histogram {
    buckets: [AtomicU64; BUCKETS],
    count: AtomicU64,
    max_ns: AtomicU64,
}

impl Default for Histogram {
    fn default() -> Self {
        Histogram {
            buckets: std::array::from_fn(|_| AtomicU64::new(0)),
            count: AtomicU64::new(0),
            max_ns: AtomicU64::new(0),
        }
    }
}

fn bucket_of(ns: u64) -> usize {
    let us = ns / 1000;
    if us < 1000 {
        us as usize
    } else if us < 10_000 {
        1000 + ((us - 1000) / 10) as usize
    } else {
        BUCKETS - 1
    }
}

fn bucket_upper_us(b: usize) -> f64 {
    if b < 1000 {
        (b + 1) as f64
    } else if b < BUCKETS - 1 {
        1000.0 + ((b - 1000) as f64 + 1.0) * 10.0
    } else {
        f64::INFINITY
    }
}

impl Histogram {
    /// Record one sample, ns (lock-free).
    #[inline]
    pub fn record(&self, ns: u64) {
        self.buckets[bucket_of(ns)].fetch_add(1, Ordering::Relaxed);
        self.count.fetch_add(1, Ordering::Relaxed);
        self.max_ns.fetch_max(ns, Ordering::Relaxed);
    }

    /// Samples recorded.
    pub fn count(&self) -> u64 {
        self.count.load(Ordering::Relaxed)
    }

    /// Largest sample, µs.
    pub fn max_us(&self) -> f64 {
        self.max_ns.load(Ordering::Relaxed) as f64 / 1000.0
    }

    /// Upper bound of the bucket holding quantile `q` (0..1), µs (bucket resolution: 1 µs
    /// below 1 ms, 10 µs above).
    pub fn quantile_us(&self, q: f64) -> f64 {
        let n = self.count();
        if n == 0 {
            return f64::NAN;
        }
        let target = ((q * n as f64).ceil() as u64).max(1);
        let mut acc = 0;
        for (b, c) in self.buckets.iter().enumerate() {
            acc += c.load(Ordering::Relaxed);
            if acc >= target {
                return bucket_upper_us(b).min(self.max_us());
            }
        }
        self.max_us()
    }

    /// Summary for reports.
    pub fn summary(&self) -> LatencySummary {
        LatencySummary {
            samples: self.count(),
            p50_us: self.quantile_us(0.5),
            p99_us: self.quantile_us(0.99),
            p999_us: self.quantile_us(0.999),
            max_us: self.max_us(),
        }
    }
}

/// Percentiles of a histogram.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LatencySummary {
    /// Samples.
    pub samples: u64,
    /// Median, µs.
    pub p50_us: f64,
    /// 99th percentile, µs.
    pub p99_us: f64,
    /// 99.9th percentile, µs.
    pub p999_us: f64,
    /// Largest, µs.
    pub max_us: f64,
}

/// Per-cycle statistics, written by the loop, read by anyone (lock-free).
#[derive(Debug, Default)]
pub struct CycleStats {
    /// Wake-up lateness after the deadline.
    pub wake_jitter: Histogram,
    /// Compute time of the cycle body.
    pub compute: Histogram,
    /// Age of the oldest essential input at the start of the cycle.
    pub input_age: Histogram,
    /// Cycles run.
    pub cycles: AtomicU64,
    /// Cycles that ended after the next deadline.
    pub overruns: AtomicU64,
    /// Deadlines skipped because of overruns.
    pub skipped: AtomicU64,
    /// Cycles started by the arrival of their inputs ([`super::trigger`]).
    pub by_input: AtomicU64,
    /// Cycles started by the fixed deadline (no trigger, or the inputs were late or absent).
    pub by_deadline: AtomicU64,
}

/// Summary of the statistics.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CycleReport {
    /// Cycles run.
    pub cycles: u64,
    /// Overruns.
    pub overruns: u64,
    /// Skipped deadlines.
    pub skipped: u64,
    /// Cycles started by the arrival of their inputs.
    pub cycles_by_input: u64,
    /// Cycles started by the fixed deadline.
    pub cycles_by_deadline: u64,
    /// Wake-up jitter.
    pub wake_jitter: LatencySummary,
    /// Compute time.
    pub compute: LatencySummary,
    /// Input age.
    pub input_age: LatencySummary,
}

impl CycleStats {
    /// Report.
    pub fn report(&self) -> CycleReport {
        CycleReport {
            cycles: self.cycles.load(Ordering::Relaxed),
            overruns: self.overruns.load(Ordering::Relaxed),
            skipped: self.skipped.load(Ordering::Relaxed),
            cycles_by_input: self.by_input.load(Ordering::Relaxed),
            cycles_by_deadline: self.by_deadline.load(Ordering::Relaxed),
            wake_jitter: self.wake_jitter.summary(),
            compute: self.compute.summary(),
            input_age: self.input_age.summary(),
        }
    }
}

/// Timing of one cycle handed to the body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tick {
    /// Cycle number from 0.
    pub cycle: u64,
    /// The time this cycle was scheduled for, monotonic ns: its deadline, or, in a loop driven
    /// by its inputs ([`super::trigger::run_triggered`]), the arrival of the inputs.
    pub deadline_ns: u64,
    /// When the thread actually woke, monotonic ns.
    pub wake_ns: u64,
}

/// Run `body` every period until `stop` is set (checked each cycle). The first deadline is one
/// period from now. A cycle that ends past the next deadline counts an overrun; deadlines that
/// already passed are skipped (no catch-up burst). Returns the number of cycles run.
pub fn run_periodic(
    period_ns: u64,
    stop: &AtomicBool,
    stats: &CycleStats,
    mut body: impl FnMut(Tick) -> bool,
) -> u64 {
    let mut deadline = super::handoff::monotonic_ns() + period_ns;
    let mut cycle = 0u64;
    while !stop.load(Ordering::Relaxed) {
        sleep_until(deadline);
        let wake = super::handoff::monotonic_ns();
        stats.wake_jitter.record(wake.saturating_sub(deadline));
        let keep_going = body(Tick {
            cycle,
            deadline_ns: deadline,
            wake_ns: wake,
        });
        let done = super::handoff::monotonic_ns();
        stats.compute.record(done.saturating_sub(wake));
        stats.cycles.fetch_add(1, Ordering::Relaxed);
        stats.by_deadline.fetch_add(1, Ordering::Relaxed);
        cycle += 1;
        deadline += period_ns;
        if done > deadline {
            stats.overruns.fetch_add(1, Ordering::Relaxed);
            // skip the deadlines that already passed
            let behind = (done - deadline) / period_ns + 1;
            deadline += behind * period_ns;
            stats.skipped.fetch_add(behind, Ordering::Relaxed);
        }
        if !keep_going {
            break;
        }
    }
    cycle
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_quantiles() {
        let h = Histogram::default();
        for us in 1..=1000u64 {
            h.record(us * 1000 - 500);
        }
        assert_eq!(h.count(), 1000);
        assert!(
            (h.quantile_us(0.5) - 500.0).abs() <= 1.0,
            "{}",
            h.quantile_us(0.5)
        );
        assert!((h.quantile_us(0.99) - 990.0).abs() <= 1.0);
        h.record(5_000_000);
        assert!((h.max_us() - 5000.0).abs() < 1e-9);
        assert!(h.quantile_us(1.0) >= 5000.0 - 10.0);
    }

    #[test]
    fn periodic_loop_keeps_its_period_and_counts_overruns() {
        let stats = CycleStats::default();
        let stop = AtomicBool::new(false);
        let start = super::super::handoff::monotonic_ns();
        let n = run_periodic(2_000_000, &stop, &stats, |t| {
            if t.cycle == 10 {
                // one cycle overruns by ~3 periods
                std::thread::sleep(std::time::Duration::from_millis(7));
            }
            t.cycle < 49
        });
        let elapsed = super::super::handoff::monotonic_ns() - start;
        assert_eq!(n, 50);
        // the forced 7-ms cycle overruns; a loaded machine may add another late wake-up
        assert!(stats.overruns.load(Ordering::Relaxed) >= 1);
        assert!(stats.skipped.load(Ordering::Relaxed) >= 3);
        // 50 cycles + ~3 skipped at 2 ms: ~106 ms, generous bounds for a loaded machine
        assert!(elapsed > 90_000_000 && elapsed < 400_000_000, "{elapsed}");
    }

    #[test]
    fn setup_reports_what_it_got() {
        let g = setup_current_thread(&RtSettings {
            rate_hz: 1000.0,
            priority: None,
            cpu: Some(0),
            lock_memory: false,
        });
        assert_eq!(g.affinity, Some(Ok(0)));
        assert!(g.scheduler.is_none());
        let s = g.to_string();
        assert!(s.contains("pinned to CPU 0"), "{s}");
    }
}
