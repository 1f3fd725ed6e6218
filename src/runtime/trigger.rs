//! Inputs drive the cycle: the control thread runs when its sensor frames have arrived, with
//! the fixed deadline as fallback.
//!
//! A controller on a free-running clock uses each sample up to one period after it arrived
//! (on vcan: 0.1–0.9 ms of a 1-ms period, depending on the phase between the sender's clock and
//! ours). Here the bus task that decodes the *trigger* messages (`[bus.can] cycle_trigger`)
//! calls [`CycleTrigger::note`] after publishing their values; once every trigger message of
//! the set has arrived the trigger *fires*: it counts, stamps the arrival time and wakes the
//! control thread, which waits in [`run_triggered`] on a futex with an absolute
//! `CLOCK_MONOTONIC` timeout (its fallback deadline). Nothing blocks the bus task (an atomic
//! `fetch_or`, a store and a `FUTEX_WAKE`), nothing allocates on either side, and the control
//! thread never waits for a lock the bus task holds.
//!
//! The schedule ([`run_triggered`]), with `P` the configured period:
//! - a fire runs a cycle at once (its `Tick::deadline_ns` is the arrival time), unless that
//!   would break the rate: not sooner than `P/2` after the previous cycle that ran on a fire
//!   ([`MIN_SPACING`]), and not more than one period ahead of the configured rate over any
//!   stretch (a credit of one cycle, which lets the loop shift its phase onto the inputs once,
//!   e.g. after a fallback). A fire that comes too early waits for its slot; fires that come
//!   while it waits are merged into it (a flood of trigger frames runs the loop at the
//!   configured rate, no faster);
//! - a deadline cycle holds no slot: it ran because the inputs were late, and the late inputs
//!   it did not have run at once when they come. (A Modbus device that answers in 5–20 ms
//!   delivers a 100-Hz link's reads 10–20 ms apart; holding each late read P/2 behind the
//!   deadline cycle that went before it delayed the recycle trip by up to 5 ms of a fast
//!   machine's 60–80 ms from throttle step to flow reversal.) Deadline cycles come at most one
//!   per `P + P/4` after a fire, so with the fires' own bound the loop runs at most
//!   1.8 × `rate_hz` (a fire every `P + P/4 + ε`, each after a deadline cycle);
//! - no fire for `P + P/4` after the previous cycle ([`LATE_TOLERANCE`]): the cycle runs on its
//!   deadline, and while the inputs stay away it keeps the fixed grid of `P` (today's
//!   behaviour). The input freshness checks of the core then decide fail-safe exactly as
//!   before: this module only decides *when* a cycle runs, never what it does;
//! - the credit comes back: the rate may exceed the configured one by at most
//!   [`DRIFT_ALLOWANCE`] (1/32 of the period per cycle, ≈ 3 %). A sender at exactly the
//!   configured rate leaves no slack otherwise, so a credit spent once (a burst of sets after
//!   the sender stalled) would hold every later cycle behind its inputs for good; with it the
//!   loop is back on the arrivals within 32 cycles, and it also follows a sender whose clock
//!   runs fast. A sustained flood runs the loop at most ≈ 3 % above `rate_hz`.
//!
//! The command leaves as before: the control thread publishes its outputs and signals the
//! bus task's eventfd, and the bus task writes the frame (read → update → write within one
//! wake-up chain, as in ros2_control, but the socket stays with the task that owns its
//! lifecycle: reconnects, error frames, link state). The control thread does no socket I/O,
//! so a full device queue or a link going down can never stall or fail a cycle. The hop costs
//! little: sensor frame to actuator frame on vcan in the HIL VM is p99 148 µs (docs/benchmarks.md,
//! *Real-time figures*), well inside the period.
//!
//! The laws see the measured time between cycles as `dt` (the core derives it from the tick's
//! wake time; it lies between `P/2` and `P + P/4` unless a cycle overran), and a cycle that
//! finds no new sample holds its outputs (the core's same-sample rule), so the discretisation
//! stays honest whether a cycle ran on a fire or on its deadline.

use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};

use super::handoff::monotonic_ns;
use super::rt_loop::{sleep_until, CycleStats, Tick};

/// Minimum spacing between two cycles, as a fraction of the period (1/2).
pub const MIN_SPACING: (u64, u64) = (1, 2);
/// How long after `P` the fallback deadline waits for a fire, as a fraction of the period
/// (1/4).
pub const LATE_TOLERANCE: (u64, u64) = (1, 4);
/// How far the rate may exceed the configured one (to win back the credit and follow a fast
/// sender clock), fraction of the period per cycle (1/32).
pub const DRIFT_ALLOWANCE: (u64, u64) = (1, 32);

fn frac(period_ns: u64, (num, den): (u64, u64)) -> u64 {
    period_ns * num / den
}

/// The wake signal from the bus task that receives the trigger messages to the control thread.
///
/// One writer ([`CycleTrigger::note`], the bus task), one waiter (the control thread in
/// [`run_triggered`]). Up to 32 trigger messages (one bit each).
#[derive(Debug, Default)]
pub struct CycleTrigger {
    /// Bits of the trigger messages that arrived since the trigger last fired.
    arrived: AtomicU32,
    /// The bits that make the set complete; 0 while not armed.
    required: AtomicU32,
    /// Futex word: how many times the trigger fired (wraps).
    fired: AtomicU32,
    /// Arrival time of the frame that completed the set, monotonic ns.
    fired_ns: AtomicU64,
    /// Whether a bus task armed the trigger (else the loop runs on its deadline only).
    armed: AtomicBool,
}

impl CycleTrigger {
    /// A trigger not armed yet.
    pub fn new() -> CycleTrigger {
        CycleTrigger::default()
    }

    /// Arm with the set of `required` bits (one per trigger message; 0 disarms). Called by
    /// the bus task when it starts.
    pub fn arm(&self, required: u32) {
        self.arrived.store(0, Ordering::Relaxed);
        self.required.store(required, Ordering::Relaxed);
        self.armed.store(required != 0, Ordering::Release);
    }

    /// Whether a bus task armed the trigger.
    pub fn is_armed(&self) -> bool {
        self.armed.load(Ordering::Acquire)
    }

    /// A trigger message (`bit`) arrived at `t_ns`, its values already published. Fires when
    /// this completes the set. Never blocks; one caller (the bus task).
    #[inline]
    pub fn note(&self, bit: u32, t_ns: u64) {
        let required = self.required.load(Ordering::Relaxed);
        if required == 0 || bit & required == 0 {
            return;
        }
        let all = self.arrived.fetch_or(bit, Ordering::Relaxed) | bit;
        if all & required == required {
            self.arrived.store(0, Ordering::Relaxed);
            self.fire(t_ns);
        }
    }

    /// Fire now: the inputs of a cycle arrived at `t_ns` (monotonic). Wakes the control thread.
    #[inline]
    pub fn fire(&self, t_ns: u64) {
        self.fired_ns.store(t_ns, Ordering::Relaxed);
        self.fired.fetch_add(1, Ordering::Release);
        futex_wake(&self.fired);
    }

    /// How many times the trigger fired (wraps).
    #[inline]
    pub fn count(&self) -> u32 {
        self.fired.load(Ordering::Acquire)
    }

    /// Arrival time of the last fire, monotonic ns (0: never).
    #[inline]
    pub fn last_fire_ns(&self) -> u64 {
        self.fired_ns.load(Ordering::Relaxed)
    }

    /// Wait until the count differs from `seen` (`true`) or `until_ns` (monotonic) passed
    /// (`false`).
    fn wait(&self, seen: u32, until_ns: u64) -> bool {
        loop {
            if self.count() != seen {
                return true;
            }
            if monotonic_ns() >= until_ns {
                return false;
            }
            futex_wait_until(&self.fired, seen, until_ns);
        }
    }
}

fn futex_wake(word: &AtomicU32) {
    // SAFETY: FUTEX_WAKE on a valid, aligned u32 owned by `word`; the other arguments are
    // ignored for this operation.
    unsafe {
        libc::syscall(
            libc::SYS_futex,
            word.as_ptr(),
            libc::FUTEX_WAKE | libc::FUTEX_PRIVATE_FLAG,
            1,
            std::ptr::null::<libc::timespec>(),
            std::ptr::null::<u32>(),
            0,
        );
    }
}

/// Sleep while `*word == expected`, at most until `until_ns` (absolute, CLOCK_MONOTONIC).
/// Returns on a wake, a changed value, a signal or the timeout; the caller re-checks.
fn futex_wait_until(word: &AtomicU32, expected: u32, until_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (until_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (until_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: FUTEX_WAIT_BITSET reads the u32 at `word` and the timespec we pass (absolute
    // CLOCK_MONOTONIC time for this operation); both outlive the call.
    unsafe {
        libc::syscall(
            libc::SYS_futex,
            word.as_ptr(),
            libc::FUTEX_WAIT_BITSET | libc::FUTEX_PRIVATE_FLAG,
            expected,
            &ts as *const libc::timespec,
            std::ptr::null::<u32>(),
            libc::FUTEX_BITSET_MATCH_ANY,
        );
    }
}

/// Run `body` when `trigger` fires, or on the fallback deadline, until `stop` is set (see the
/// module docs for the schedule). Each cycle counts in `stats` as `by_input` or
/// `by_deadline`; wake jitter is measured from the fire (or the slot the rate allowed it) or
/// from the deadline. Returns the number of cycles run.
pub fn run_triggered(
    period_ns: u64,
    trigger: &CycleTrigger,
    stop: &AtomicBool,
    stats: &CycleStats,
    mut body: impl FnMut(Tick) -> bool,
) -> u64 {
    let min_spacing = frac(period_ns, MIN_SPACING);
    let late = frac(period_ns, LATE_TOLERANCE);
    let drift = frac(period_ns, DRIFT_ALLOWANCE);
    let start = monotonic_ns();
    let mut seen = trigger.count();
    // theoretical time of the next cycle at the configured rate; a fire may run one period
    // ahead of it (the credit that lets the phase move onto the inputs)
    let mut tat = start;
    // the previous cycle that ran on a fire (deadline cycles hold no slot)
    let mut last_fire_ns: Option<u64> = None;
    let mut deadline = start + period_ns;
    let mut cycle = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let fired = trigger.wait(seen, deadline);
        let due = if fired {
            let mut earliest = tat.saturating_sub(period_ns);
            if let Some(last) = last_fire_ns {
                earliest = earliest.max(last + min_spacing);
            }
            let due = trigger.last_fire_ns().max(earliest);
            if monotonic_ns() < due {
                // too early for the rate (a flood, or a phase shift already spent): wait for
                // the slot; fires meanwhile are merged into this cycle
                sleep_until(due);
            }
            seen = trigger.count();
            due
        } else {
            deadline
        };
        let wake = monotonic_ns();
        stats.wake_jitter.record(wake.saturating_sub(due));
        let keep_going = body(Tick {
            cycle,
            deadline_ns: due,
            wake_ns: wake,
        });
        let done = monotonic_ns();
        stats.compute.record(done.saturating_sub(wake));
        stats.cycles.fetch_add(1, Ordering::Relaxed);
        if fired {
            stats.by_input.fetch_add(1, Ordering::Relaxed);
        } else {
            stats.by_deadline.fetch_add(1, Ordering::Relaxed);
        }
        cycle += 1;
        if fired {
            last_fire_ns = Some(due);
            tat = tat.saturating_sub(drift).max(due) + period_ns;
        }
        // the fallback: a period and a tolerance after a fire; after a deadline cycle, the
        // fixed grid (the configured rate while the inputs stay away)
        deadline = if fired {
            due + period_ns + late
        } else {
            deadline + period_ns
        };
        if done > due + period_ns {
            stats.overruns.fetch_add(1, Ordering::Relaxed);
        }
        if done > deadline {
            // skip the deadlines that already passed (no catch-up burst)
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
    use std::sync::Arc;
    use std::time::Duration;

    #[test]
    fn the_set_fires_once_complete_and_starts_again() {
        let t = CycleTrigger::new();
        t.note(0b01, 5); // not armed: nothing
        assert_eq!(t.count(), 0);
        t.arm(0b11);
        assert!(t.is_armed());
        t.note(0b01, 10);
        assert_eq!(t.count(), 0, "half the set");
        t.note(0b01, 11);
        assert_eq!(t.count(), 0, "the same message again");
        t.note(0b100, 12);
        assert_eq!(t.count(), 0, "not a trigger message");
        t.note(0b10, 13);
        assert_eq!((t.count(), t.last_fire_ns()), (1, 13));
        // a lost frame of the next set: the set completes with the next one
        t.note(0b10, 20);
        t.note(0b10, 21);
        assert_eq!(t.count(), 1);
        t.note(0b01, 22);
        assert_eq!((t.count(), t.last_fire_ns()), (2, 22));
        t.arm(0);
        assert!(!t.is_armed());
        t.note(0b11, 30);
        assert_eq!(t.count(), 2);
    }

    #[test]
    fn a_waiter_wakes_on_a_fire_before_its_deadline() {
        let t = Arc::new(CycleTrigger::new());
        t.arm(1);
        let seen = t.count();
        let f = Arc::clone(&t);
        let h = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(20));
            f.note(1, monotonic_ns());
        });
        let t0 = monotonic_ns();
        assert!(t.wait(seen, t0 + 10_000_000_000), "woken by the fire");
        let waited = monotonic_ns() - t0;
        assert!(waited < 5_000_000_000, "{waited} ns");
        h.join().expect("firing thread");
        // and without a fire the deadline ends the wait
        let t1 = monotonic_ns();
        assert!(!t.wait(t.count(), t1 + 20_000_000));
        assert!(monotonic_ns() >= t1 + 20_000_000);
    }

    /// One recorded cycle: its tick and whether it ran on a fire.
    #[derive(Debug, Clone, Copy)]
    struct Seen {
        tick: Tick,
        by_input: bool,
    }

    /// Run the loop of period `period_ns` on `trigger` until `done`; every cycle's tick and
    /// whether it ran on a fire (from the `by_input` count, taken on the next cycle and, for
    /// the last, from the totals).
    fn record(
        period_ns: u64,
        trigger: &CycleTrigger,
        stats: &CycleStats,
        done: &AtomicBool,
        capacity: usize,
    ) -> Vec<Seen> {
        let stop = AtomicBool::new(false);
        let mut seen: Vec<Seen> = Vec::with_capacity(capacity);
        let mut inputs_before = 0;
        run_triggered(period_ns, trigger, &stop, stats, |tick| {
            let inputs = stats.by_input.load(Ordering::Relaxed);
            if let Some(prev) = seen.last_mut() {
                prev.by_input = inputs > inputs_before;
            }
            inputs_before = inputs;
            seen.push(Seen {
                tick,
                by_input: false,
            });
            !done.load(Ordering::Relaxed)
        });
        let total_inputs = stats.by_input.load(Ordering::Relaxed);
        if let Some(last) = seen.last_mut() {
            last.by_input = total_inputs > inputs_before;
        }
        seen
    }

    /// The sender's phases, monotonic ns: fires every `P` (offset from our start), then
    /// silence, then a flood of fires every `P/20`.
    #[test]
    fn inputs_drive_the_cycle_the_deadline_takes_over_and_a_flood_keeps_the_rate() {
        const P: u64 = 2_000_000;
        let trigger = Arc::new(CycleTrigger::new());
        trigger.arm(0b11);
        let stats = CycleStats::default();
        let phases = Arc::new([AtomicU64::new(0), AtomicU64::new(0), AtomicU64::new(0)]);
        let done = Arc::new(AtomicBool::new(false));
        let stamps = Arc::new(std::sync::Mutex::new(Vec::with_capacity(200)));
        let (t, ph, d) = (Arc::clone(&trigger), Arc::clone(&phases), Arc::clone(&done));
        let st = Arc::clone(&stamps);
        let sender = std::thread::spawn(move || {
            // phase 1: 150 regular sets, two frames each, 0.7 P after our loop's phase
            let mut at = monotonic_ns() + P / 3;
            ph[0].store(at, Ordering::Relaxed);
            // (like the plant node's loop, a set whose slot passed while the sender was held up
            // by the loaded machine is skipped, not sent in a burst)
            for _ in 0..150 {
                sleep_until(at);
                t.note(0b01, monotonic_ns());
                let complete = monotonic_ns();
                t.note(0b10, complete);
                st.lock().expect("stamps").push(complete);
                at += P;
                while at < monotonic_ns() {
                    at += P;
                }
            }
            // phase 2: silence for 40 periods
            ph[1].store(at, Ordering::Relaxed);
            at += 40 * P;
            // phase 3: a flood, one complete set every P/20 for 60 periods
            ph[2].store(at, Ordering::Relaxed);
            for _ in 0..60 * 20 {
                sleep_until(at);
                t.note(0b11, monotonic_ns());
                at += P / 20;
            }
            d.store(true, Ordering::Relaxed);
        });
        let seen = record(P, &trigger, &stats, &done, 1000);
        sender.join().expect("sender");
        let [p1, p2, p3] = [0, 1, 2].map(|i| phases[i].load(Ordering::Relaxed));
        let within = |a: u64, b: u64| -> Vec<Seen> {
            seen.iter()
                .filter(|s| s.tick.deadline_ns >= a && s.tick.deadline_ns < b)
                .copied()
                .collect()
        };

        // 1. regular inputs: after the first few sets (the phase moves onto the inputs once)
        //    every cycle runs on its inputs: one cycle per set, scheduled at the arrival of the
        //    set (not held back to a slot of its own)
        let regular = within(p1 + 5 * P, p2);
        assert!(regular.len() >= 140, "{} cycles in phase 1", regular.len());
        let on_input = regular.iter().filter(|s| s.by_input).count();
        // measured against the sets the sender delivered in that window: on a loaded machine
        // the sender itself misses slots (it skips them, as the plant node does), and a
        // cycle whose set never came rightly runs on its deadline
        let stamps = stamps.lock().expect("stamps");
        let delivered = stamps
            .iter()
            .filter(|&&t| t >= p1 + 5 * P && t < p2)
            .count();
        assert!(
            on_input * 100 >= delivered.min(regular.len()) * 95,
            "{on_input} of {} cycles ran on their inputs ({delivered} sets delivered)",
            regular.len()
        );
        let at_arrival = regular
            .iter()
            .filter(|s| s.by_input && stamps.contains(&s.tick.deadline_ns))
            .count();
        assert!(
            at_arrival * 10 >= on_input * 8,
            "{at_arrival} of {on_input} cycles scheduled at the arrival of their inputs"
        );

        // 2. silence: after a period and a quarter the deadline takes over, then the fixed grid
        let quiet = within(p2, p3);
        let by_deadline: Vec<_> = quiet.iter().filter(|s| !s.by_input).collect();
        assert!(
            by_deadline.len() >= 35 && by_deadline.len() <= 41,
            "{} deadline cycles in 40 silent periods",
            by_deadline.len()
        );
        for w in by_deadline.windows(2) {
            let step = w[1].tick.deadline_ns - w[0].tick.deadline_ns;
            // exactly one period, or whole periods skipped after an overrun
            assert!(step >= P && step % P == 0, "deadline step {step} ns");
        }
        let last_input = regular.last().expect("phase 1").tick.deadline_ns;
        assert_eq!(
            by_deadline[0].tick.deadline_ns - last_input,
            P + P / 4,
            "first fallback a period and a quarter after the last input"
        );

        // 3. a flood: never two cycles on fires closer than P/2, and the fires' cycles no
        //    faster than the configured rate (one cycle of credit, and the 1/32 drift
        //    allowance); a deadline cycle (a sender stalled by the loaded machine) holds no slot
        let flood = within(p3, p3 + 60 * P);
        assert!(flood.len() >= 40, "{} cycles in the flood", flood.len());
        let fires: Vec<_> = flood.iter().filter(|s| s.by_input).collect();
        for w in fires.windows(2) {
            let step = w[1].tick.deadline_ns - w[0].tick.deadline_ns;
            assert!(step >= P / 2, "two cycles {step} ns apart");
        }
        let span = flood.last().expect("flood").tick.deadline_ns - flood[0].tick.deadline_ns;
        let allowed = span as f64 / (P as f64 * (1.0 - 1.0 / 32.0)) + 2.0;
        assert!(
            (fires.len() as f64) <= allowed + 1.0,
            "{} cycles on fires in {span} ns: faster than the rate",
            fires.len()
        );
        // the flood drives the cycles (a sender stalled for more than 1.25 P by the loaded
        // machine lets a deadline through now and then)
        let on_deadline: Vec<_> = flood
            .iter()
            .filter(|s| !s.by_input)
            .map(|s| s.tick.deadline_ns - p3)
            .collect();
        assert!(
            on_deadline.len() * 10 <= flood.len(),
            "on the deadline in the flood at {on_deadline:?} ns into it"
        );
    }

    /// Inputs slower than the configured rate (a Modbus device answering in 5–20 ms behind a
    /// 100-Hz link): every read comes after the deadline cycle that stood in for it, and runs
    /// at its arrival, not `P/2` after that deadline cycle.
    #[test]
    fn a_late_input_runs_at_once_after_the_deadline_cycle_that_stood_in_for_it() {
        const P: u64 = 20_000_000;
        let trigger = Arc::new(CycleTrigger::new());
        trigger.arm(0b1);
        let stats = CycleStats::default();
        let done = Arc::new(AtomicBool::new(false));
        let stamps = Arc::new(std::sync::Mutex::new(Vec::with_capacity(40)));
        let (t, d, st) = (Arc::clone(&trigger), Arc::clone(&done), Arc::clone(&stamps));
        let sender = std::thread::spawn(move || {
            // a set every 1.6 P: the deadline cycle comes 1.25 P after each, the next set
            // 0.35 P after that
            let mut at = monotonic_ns() + P / 3;
            for _ in 0..30 {
                sleep_until(at);
                let now = monotonic_ns();
                t.note(0b1, now);
                st.lock().expect("stamps").push(now);
                at += P * 8 / 5;
            }
            d.store(true, Ordering::Relaxed);
        });
        let seen = record(P, &trigger, &stats, &done, 200);
        sender.join().expect("sender");
        let stamps = stamps.lock().expect("stamps");
        // each fire that follows a deadline cycle closer than P/2 is scheduled at its own
        // arrival (the schedule's times, not the wall clock: a loaded machine moves both)
        let mut after_deadline = 0;
        for w in seen.windows(2) {
            let (before, fire) = (w[0], w[1]);
            let gap = fire
                .tick
                .deadline_ns
                .saturating_sub(before.tick.deadline_ns);
            if !before.by_input && fire.by_input && gap < P / 2 {
                after_deadline += 1;
            }
            if !before.by_input && fire.by_input {
                assert!(
                    stamps.contains(&fire.tick.deadline_ns),
                    "a fire {gap} ns after a deadline cycle was held back to {} ns",
                    fire.tick.deadline_ns
                );
            }
        }
        // (held to P/2 after the deadline cycle, none would run closer than that)
        assert!(
            after_deadline > 0,
            "no input ran within P/2 of a deadline cycle"
        );
    }
}
