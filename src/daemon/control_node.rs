//! The body of the daemon's control thread: one [`ControlNode::cycle`] per deadline.
//!
//! Per cycle, without allocating, locking or doing I/O:
//! 1. take a live update (hot reload, law or mode change) from the lock-free update ring and
//!    swap it in at this cycle boundary: the new law and settings were built off this thread
//!    ([`ControlCore::prepare`]), the swap ([`ControlCore::commit`]) neither allocates nor
//!    frees, and the replaced parts go back on the retired ring to be dropped elsewhere;
//! 2. snapshot the [`SensorBoard`] with the age of every input;
//! 3. run the [`ControlCore`] (supervision, observer fallback, fail-safe, law, speed loop);
//! 4. publish the setpoints on the [`OutputBoard`] and wake the bus tasks;
//! 5. queue what changed (mode, fallback, surge, recycle trip, overruns) on the event ring and
//!    update the [`Health`] the watchdog task reads.

use crate::control::core::{ControlCore, CoreSettings, Mode, Reconfiguration};
use crate::control::law::{LawEvent, LawId};
use crate::control::measurements::{OperatorInputs, RawSensors};
use crate::events::event::{
    FallbackEntered, FallbackLeft, FallbackReason, LawChanged, Mode as EvMode, ModeChanged,
    RecycleTrip, Replacement, SafetyOnShift, SurgeDetected, TripReason,
};
use crate::events::{OverrunReporter, RtSender};
use crate::runtime::handoff::{OutputBoard, Outputs, SensorBoard, Wakeup};
use crate::runtime::rt_loop::{CycleStats, Tick};
use crate::signals::{ActuatorCommands, SensorId};
use crate::surge::Detection;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Heartbeat mode code sent after shutdown (the DBC's `Mode` value 4).
pub const MODE_SHUTDOWN: u8 = 4;

/// A change the configuration task hands to the control thread, fully built off it:
/// moving it through the ring and committing it allocate nothing.
#[derive(Debug)]
pub struct ControlUpdate {
    /// The law and controller settings, built by [`ControlCore::prepare`].
    pub reconf: Reconfiguration,
    /// Input limits and fail-safe opening.
    pub settings: CoreSettings,
    /// Automatic (true) or manual mode.
    pub auto: bool,
    /// Operator setpoints.
    pub op: OperatorInputs,
}

/// What the control thread tells the rest of the daemon, lock-free.
#[derive(Debug, Default)]
pub struct Health {
    /// Cycles run.
    pub cycles: AtomicU64,
    /// Cycles whose inputs were healthy (auto or manual mode).
    pub healthy_cycles: AtomicU64,
    /// Mode code of the last cycle.
    pub mode: AtomicU64,
    /// Updates applied.
    pub updates_applied: AtomicU64,
    /// Updates the core refused (validated off-thread first, so this should stay 0).
    pub updates_refused: AtomicU64,
    /// Surge cycles detected.
    pub surges: AtomicU64,
}

impl Health {
    /// Mode of the last cycle.
    pub fn mode(&self) -> Mode {
        match self.mode.load(Ordering::Relaxed) {
            1 => Mode::Manual,
            2 => Mode::Auto,
            3 => Mode::FailSafe,
            _ => Mode::Init,
        }
    }
}

/// The control thread's state.
pub struct ControlNode {
    core: ControlCore,
    op: OperatorInputs,
    sensors: Arc<SensorBoard>,
    outputs: Arc<OutputBoard>,
    wake: Arc<Wakeup>,
    updates: rtrb::Consumer<ControlUpdate>,
    retired: rtrb::Producer<Reconfiguration>,
    events: Option<RtSender>,
    overruns: OverrunReporter,
    health: Arc<Health>,
    stats: Arc<CycleStats>,
    period_ns: u64,
    t0_ns: u64,
    prev_mode: Mode,
    prev_law: LawId,
    fallback_since_ns: Option<u64>,
    surges: u64,
}

fn ev_mode(m: Mode) -> EvMode {
    match m {
        Mode::Init => EvMode::Init,
        Mode::Manual => EvMode::Manual,
        Mode::Auto => EvMode::Auto,
        Mode::FailSafe => EvMode::FailSafe,
    }
}

/// Fault bits of the heartbeat: bit i set when sensor i is not usable.
/// The fault word on the wire: the shared categories of [`crate::faults`].
fn fault_bits(
    v: &crate::control::supervisor::Validity,
    s: &crate::control::supervisor::Supervisor,
) -> u32 {
    crate::faults::FaultSet::from_validity(v, s).0
}

/// Boards and channels a control node is wired to.
pub struct ControlWiring {
    /// Inputs from the bus tasks (or the in-process plant).
    pub sensors: Arc<SensorBoard>,
    /// Setpoints to the bus tasks.
    pub outputs: Arc<OutputBoard>,
    /// Wakes the sending tasks after each publish.
    pub wake: Arc<Wakeup>,
    /// Live updates from the configuration task.
    pub updates: rtrb::Consumer<ControlUpdate>,
    /// Replaced parts going back to the configuration task, which drops them.
    pub retired: rtrb::Producer<Reconfiguration>,
    /// Event ring (None: no event log).
    pub events: Option<RtSender>,
    /// Shared health.
    pub health: Arc<Health>,
    /// Shared cycle statistics.
    pub stats: Arc<CycleStats>,
}

impl ControlNode {
    /// A node around a core; `period_ns` is the cycle period.
    pub fn new(core: ControlCore, op: OperatorInputs, w: ControlWiring, period_ns: u64) -> Self {
        let prev_law = core.law();
        ControlNode {
            core,
            op,
            sensors: w.sensors,
            outputs: w.outputs,
            wake: w.wake,
            updates: w.updates,
            retired: w.retired,
            events: w.events,
            overruns: OverrunReporter::new(Duration::from_secs(10), Instant::now()),
            health: w.health,
            stats: w.stats,
            period_ns,
            t0_ns: crate::runtime::handoff::monotonic_ns(),
            prev_mode: Mode::Init,
            prev_law,
            fallback_since_ns: None,
            surges: 0,
        }
    }

    /// The core (tests, reports).
    pub fn core(&self) -> &ControlCore {
        &self.core
    }

    fn push(&mut self, e: impl Into<crate::events::RtEvent>) {
        if let Some(tx) = &mut self.events {
            tx.try_push(e);
        }
    }

    fn apply_updates(&mut self) {
        // one update per cycle, and only with room to hand the old parts back: nothing is
        // ever freed on this thread (an update waits a cycle otherwise)
        if self.retired.slots() == 0 {
            return;
        }
        if let Ok(u) = self.updates.pop() {
            let old = self.core.commit(u.reconf);
            self.core.set_settings(u.settings);
            self.core.request_auto(u.auto);
            self.op = u.op;
            self.health.updates_applied.fetch_add(1, Ordering::Relaxed);
            if let Err(rtrb::PushError::Full(old)) = self.retired.push(old) {
                // unreachable (a slot was checked above); never free on this thread
                #[allow(clippy::forget_non_drop)]
                std::mem::forget(old);
            }
        }
    }

    /// One cycle at `tick`.
    pub fn cycle(&mut self, tick: Tick) {
        self.apply_updates();
        let now = tick.wake_ns;
        let (values, age_s) = self.sensors.snapshot(now);
        let raw = RawSensors { values, age_s };
        let oldest = [
            SensorId::PSuction,
            SensorId::PDischarge,
            SensorId::ShaftSpeed,
        ]
        .iter()
        .map(|s| age_s[s.index()])
        .fold(0.0f64, f64::max);
        if oldest.is_finite() {
            self.stats.input_age.record((oldest * 1e9) as u64);
        }
        let t_s = now.saturating_sub(self.t0_ns) as f64 * 1e-9;
        let out = self.core.cycle(t_s, &raw, &self.op);
        self.outputs.publish(&Outputs {
            commands: out.commands,
            mode: out.mode.code(),
            law: out.law.code(),
            faults: fault_bits(&out.validity, &self.core.settings().supervisor),
            cycle: tick.cycle,
            t_ns: now,
        });
        self.wake.signal();

        // bookkeeping and events (all fixed-size, allocation-free)
        self.health.cycles.fetch_add(1, Ordering::Relaxed);
        self.health
            .mode
            .store(u64::from(out.mode.code()), Ordering::Relaxed);
        if matches!(out.mode, Mode::Auto | Mode::Manual) {
            self.health.healthy_cycles.fetch_add(1, Ordering::Relaxed);
        }
        if out.mode != self.prev_mode {
            self.push(ModeChanged {
                from: ev_mode(self.prev_mode),
                to: ev_mode(out.mode),
            });
            self.prev_mode = out.mode;
        }
        if out.law != self.prev_law {
            self.push(LawChanged {
                from: self.prev_law,
                to: out.law,
            });
            self.prev_law = out.law;
        }
        let fallback = out.measurements.flow_fallback;
        match (fallback, self.fallback_since_ns) {
            (true, None) => {
                let reason = match out.validity.fault[SensorId::OrificeDp.index()] {
                    crate::control::supervisor::InputFault::Nan => FallbackReason::Nan,
                    crate::control::supervisor::InputFault::OutOfRange => {
                        FallbackReason::OutOfRange
                    }
                    _ => FallbackReason::Stale,
                };
                self.push(FallbackEntered {
                    input: SensorId::OrificeDp,
                    reason,
                    replaced_by: Replacement::Observer,
                });
                self.fallback_since_ns = Some(now);
            }
            (false, Some(since)) => {
                self.push(FallbackLeft {
                    input: SensorId::OrificeDp,
                    replaced_by: Replacement::Observer,
                    duration_ms: now.saturating_sub(since) / 1_000_000,
                });
                self.fallback_since_ns = None;
            }
            _ => {}
        }
        if matches!(
            out.surge,
            Detection::SurgeStarted | Detection::ReversalStarted
        ) {
            self.surges += 1;
            self.health.surges.store(self.surges, Ordering::Relaxed);
            let det = self.core.detector();
            self.push(SurgeDetected {
                surge_count_total: self.surges,
                frequency_hz: det.frequency_hz,
                min_flow_kg_s: out.measurements.m_kg_s,
                flow_reversal: matches!(out.surge, Detection::ReversalStarted),
            });
        }
        match out.law_event {
            Some(LawEvent::RecycleTrip { .. }) => self.push(RecycleTrip {
                reason: TripReason::FastApproach,
            }),
            Some(LawEvent::SafetyOnShift {
                total_margin,
                count,
            }) => self.push(SafetyOnShift {
                margin_pct: f64::NAN,
                total_margin_pct: 100.0 * total_margin,
                count,
            }),
            None => {}
        }
        let lateness = tick.wake_ns.saturating_sub(tick.deadline_ns);
        let instant = Instant::now();
        let ev = if lateness > self.period_ns / 2 {
            self.overruns.record(lateness / 1000, instant)
        } else {
            self.overruns.poll(instant)
        };
        if let Some(e) = ev {
            self.push(e);
        }
    }

    /// Command the safe state and publish it with the shutdown mode code (SIGTERM/SIGINT).
    pub fn shutdown(&mut self, cycle: u64) -> ActuatorCommands {
        let cmd = self.core.safe_state();
        self.outputs.publish(&Outputs {
            commands: cmd,
            mode: MODE_SHUTDOWN,
            law: self.core.law().code(),
            faults: 0,
            cycle,
            t_ns: crate::runtime::handoff::monotonic_ns(),
        });
        self.wake.signal();
        self.push(ModeChanged {
            from: ev_mode(self.prev_mode),
            to: EvMode::Shutdown,
        });
        cmd
    }
}
