//! Modbus link tasks: the controller's poll/write loop and the plant node's server.
//!
//! **Controller role** ([`run_controller`]): one [`ModbusClient`] (TCP or RTU) reads every
//! Modbus sensor of the signal map once per link cycle and publishes the values into the
//! [`SensorBoard`], stamped with the monotonic time the response arrived. It then writes the
//! setpoints the control thread computed from those values (waiting for its next cycle, at
//! most one link period) from the [`OutputBoard`], and reads back the command registers
//! configured with `readback`. A failed or timed-out read
//! publishes nothing: the control loop sees its inputs age and goes fail-safe by itself.
//! The link never decides fail-safe; it only keeps trying (the client reconnects with
//! backoff) and reports its state through a [`tokio::sync::watch`] channel
//! ([`LinkMonitor`]).
//!
//! **Plant role** ([`run_plant_server`], [`PlantServer`]): a Modbus TCP server whose register
//! image holds the plant's sensors, re-encoded from the [`SnapshotBoard`] whenever a read
//! request arrives and a newer snapshot exists (so answers are never older than the latest
//! published snapshot). Client writes to actuator registers are published into the
//! [`CommandBoard`] with their arrival time, and as the controller heartbeat into the
//! [`HeartbeatBoard`] (see [`HeartbeatRegister`]).
//!
//! [`SnapshotBoard`]: crate::runtime::handoff::SnapshotBoard
//! [`CommandBoard`]: crate::runtime::handoff::CommandBoard
//! [`HeartbeatBoard`]: crate::runtime::handoff::HeartbeatBoard
//!
//! **Pacing.** Modbus is request/response: every value costs a round trip (≈0.1–1 ms on TCP,
//! tens of ms per request on RTU at 19 200 Bd), so the link rate must be chosen for the bus,
//! not derived from the control rate. The default [`Pacing::Interval`] therefore runs a
//! fixed-rate loop at `poll_rate_hz` (a `tokio::time::interval`, adequate at ≥ 1 ms periods;
//! 50 Hz by default), which samples the sensors at regular instants and needs no coupling to
//! the control thread. [`Pacing::Wakeup`] instead runs one cycle after each control-thread
//! wakeup (rate-limited to `poll_rate_hz`), writing the fresh outputs first and reading the
//! sensors right after, which removes up to one link period of output latency when the
//! control thread runs at or below the link rate.
//!
//! **Output freshness.** Each new output set (new control-thread cycle number) is written
//! once (retried only until the device acknowledges it); sets older than `max_output_age_ms`
//! are never written. If the control thread
//! stops, the writes (and the heartbeat) stop with it, so the plant's heartbeat timeout sees
//! the controller die instead of a link task replaying its last setpoints.

mod commands;
mod config;
mod monitor;
mod plant;
pub mod quality;

pub use config::*;
pub use monitor::*;

pub use plant::{run_plant_server, PlantCounters, PlantCounts, PlantServer};

use std::future::Future;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use tokio::io::unix::AsyncFd;
use tokio::io::Interest;

/// Longest a link back from a failure withholds a fail-safe output set, ns: twice the core's
/// fail-safe exit hysteresis (0.5 s), so a core that resumes is written from its resumed
/// output and a fail-safe that lasts reaches the device.
const RESYNC_FAILSAFE_NS: u64 = 1_000_000_000;
use tokio::time::{Instant, MissedTickBehavior};

use super::client::{ConnectionState, ModbusClient, ModbusError};
use super::plan::{ReadPlan, WritePlan};
use super::register::{RegisterBinding, RegisterTable};
use crate::io::signal_map::SignalMap;
use crate::runtime::handoff::{monotonic_ns, OutputBoard, SensorBoard, Wakeup};
use crate::vocab::signals::{ActuatorId, SensorId};
use crate::vocab::Mode;

/// What starts a controller link cycle.
#[derive(Debug, Clone)]
pub enum Pacing {
    /// A fixed-rate loop at `poll_rate_hz`: read sensors, publish, then write the outputs
    /// computed from them (or the latest after one link period). A cycle that overruns
    /// delays the next tick (no catch-up bursts).
    Interval,
    /// One cycle per control-thread wakeup, at most `poll_rate_hz`: write the fresh outputs,
    /// then read sensors for the next control cycle. Nothing happens while the control
    /// thread is silent. The eventfd must be this task's own: each waiter clears it, and
    /// tokio cannot register one descriptor twice.
    Wakeup(Arc<Wakeup>),
}

/// The sensors of one planned read request (a contiguous range of one unit and table), so
/// each group gets the arrival time of its own response and an exception spoils only it.
#[derive(Debug)]
struct SensorGroup {
    plan: ReadPlan,
    /// Sensor and transmitter slot (0 = `a`, the `[sensors]` binding; 1, 2 = `[vote]`'s).
    ids: Vec<(SensorId, usize)>,
    values: Vec<f64>,
}

/// What happened during one cycle.
#[derive(Debug, Default)]
struct Outcome {
    /// At least one exchange got a normal answer.
    answered: bool,
    /// First exception answer.
    exception: Option<ExceptionInfo>,
    /// A link failure (including a backoff wait) ended an operation.
    link_failed: bool,
    /// A write was attempted: `Some(None)` acknowledged, `Some(Some(_))` failed.
    write: Option<Option<WriteFailure>>,
}

/// Whether a request's outcome is a latency sample: an answer (normal or exception), or a
/// timeout, counted with the time waited (a lower bound of its latency, so that the p99 does
/// not hide a device that answers after the timeout). A refused connection or a reset is no
/// latency.
fn counts_for_latency<T>(r: &Result<T, ModbusError>) -> bool {
    match r {
        Ok(_) => true,
        Err(e) => ExceptionInfo::of(e).is_some() || matches!(e, ModbusError::Timeout { .. }),
    }
}

/// The controller link's state between cycles.
struct Controller {
    client: ModbusClient,
    groups: Vec<SensorGroup>,
    write_plan: WritePlan,
    actuators: Vec<ActuatorId>,
    /// Values for `write_plan` (actuators, then the heartbeat bindings).
    write_values: Vec<f64>,
    /// Bits of the last acknowledged value per actuator (`write_on_change_only`).
    acknowledged: Vec<u64>,
    /// Whether `acknowledged` reflects the device (false after any failure).
    acknowledged_valid: bool,
    heartbeat: bool,
    alive: u8,
    /// The map's watchdog contract, written after the actuators (and legacy block).
    watchdog: Option<super::watchdog::ModbusWatchdog>,
    watchdog_writer: super::watchdog::WatchdogWriter,
    /// Index of the first watchdog value in `write_values`.
    watchdog_at: usize,
    /// Writes failing since (monotonic ns) and why.
    write_failing: Option<(u64, WriteFailure)>,
    write_fault_ns: u64,
    change_only: bool,
    max_output_age_ns: u64,
    /// Control cycle number of the last output set written in full.
    last_written_cycle: Option<u64>,
    /// After a link failure: nothing is written until the control thread has published an
    /// output set computed from the first values read after the failure. `Some(None)`: no
    /// values read yet; `Some(Some(k))`: values read while output set `k` was the latest, so
    /// set `k + 2` is the first computed after them. (The sets published while the link was
    /// down were computed without inputs: a 3-s outage wrote the fail-safe 100 % onto a valve
    /// measured at 4 % first thing after the resume.)
    resync: Option<Option<u64>>,
    /// When the first values after the failure were read (monotonic ns).
    resync_read_ns: u64,
    last_cause: FailureCause,
    sensors: Arc<SensorBoard>,
    outputs: Arc<OutputBoard>,
    monitor: Arc<LinkMonitor>,
    /// Achieved poll period and answer latency.
    quality: quality::QualityWindow,
    /// Actuators whose command register is read back: (index in `actuators`, plan, value).
    readbacks: Vec<(usize, ReadPlan, [f64; 1])>,
    /// When the next read-back is due (monotonic ns).
    next_readback_ns: u64,
    /// The link period, ns: the longest a write waits for the output set computed from the
    /// values just read.
    period_ns: u64,
    /// When this cycle's read published its values (monotonic ns; 0: nothing published).
    read_done_ns: u64,
    /// Fired after each read that published values (`cycle_trigger = "reads"`).
    trigger: Option<Arc<crate::runtime::trigger::CycleTrigger>>,
    /// What this task does of the link: all of it, or one side of `command_connection = "own"`.
    role: Role,
    /// Shared by the two tasks of `command_connection = "own"`.
    split: Option<Arc<commands::Split>>,
}

/// What one link task does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    /// Reads, writes and read-backs on one connection.
    Both,
    /// The reads of `command_connection = "own"`; reports the link's state for both.
    Reads,
    /// The commands and read-backs of `command_connection = "own"`, on their own connection.
    Commands,
}

/// The link's one trigger bit ([`crate::runtime::trigger::CycleTrigger::arm`]): a read.
const READ_TRIGGER_BIT: u32 = 1;

/// How often the command registers with `readback` are read back, ns: 100 ms, a third of the
/// 300 ms within which another writer must be found (issue 23), so the first or second
/// read-back after a foreign write finds it.
const READBACK_PERIOD_NS: u64 = 100_000_000;

impl Controller {
    fn new(
        cfg: &ModbusLinkConfig,
        map: &SignalMap,
        sensors: Arc<SensorBoard>,
        outputs: Arc<OutputBoard>,
        monitor: Arc<LinkMonitor>,
    ) -> Result<Controller, LinkError> {
        cfg.validate()?;
        check_map(map, cfg.heartbeat_register.as_ref())?;
        let mut sensor_bindings: Vec<((SensorId, usize), RegisterBinding)> = map
            .modbus_sensors()
            .into_iter()
            .map(|(id, b)| ((id, 0), b))
            .collect();
        sensor_bindings.extend(
            map.modbus_spares()
                .into_iter()
                .map(|(id, slot, b)| ((id, slot), b)),
        );
        let all: Vec<RegisterBinding> = sensor_bindings.iter().map(|(_, b)| *b).collect();
        let full = ReadPlan::new(&all)?;
        let mut groups = Vec::with_capacity(full.requests().len());
        for req in full.requests() {
            let members = full.members(req);
            let bindings: Vec<RegisterBinding> = members.iter().map(|&i| all[i]).collect();
            let ids: Vec<(SensorId, usize)> =
                members.iter().map(|&i| sensor_bindings[i].0).collect();
            let plan = ReadPlan::new(&bindings)?;
            debug_assert_eq!(plan.requests().len(), 1);
            groups.push(SensorGroup {
                values: vec![f64::NAN; ids.len()],
                plan,
                ids,
            });
        }
        let actuator_bindings = map.modbus_actuators();
        let actuators: Vec<ActuatorId> = actuator_bindings.iter().map(|(id, _)| *id).collect();
        let mut readbacks = Vec::new();
        for (k, (id, b)) in actuator_bindings.iter().enumerate() {
            if map.feedback.get(id).is_some_and(|l| l.readback) && b.table == RegisterTable::Holding
            {
                readbacks.push((k, ReadPlan::new(&[*b])?, [f64::NAN]));
            }
        }
        let mut writes: Vec<RegisterBinding> = actuator_bindings.iter().map(|(_, b)| *b).collect();
        if let Some(hb) = &cfg.heartbeat_register {
            writes.extend(hb.bindings());
        }
        let watchdog_at = writes.len();
        let watchdog = map.watchdog.modbus;
        if let Some(wd) = &watchdog {
            writes.extend(wd.parts().iter().map(|(_, b)| *b));
        }
        let write_plan = if cfg.merge_writes {
            WritePlan::new(&writes)?
        } else {
            WritePlan::separate(&writes)?
        };
        Ok(Controller {
            client: ModbusClient::new(cfg.client.clone())?,
            groups,
            write_values: vec![f64::NAN; write_plan.len()],
            write_plan,
            acknowledged: vec![0; actuators.len()],
            acknowledged_valid: false,
            actuators,
            heartbeat: cfg.heartbeat_register.is_some(),
            alive: 0,
            watchdog,
            watchdog_writer: Default::default(),
            watchdog_at,
            write_failing: None,
            write_fault_ns: cfg.write_fault_timeout_ms.saturating_mul(1_000_000),
            change_only: cfg.write_on_change_only,
            max_output_age_ns: cfg.max_output_age_ms.saturating_mul(1_000_000),
            last_written_cycle: None,
            resync: None,
            resync_read_ns: 0,
            last_cause: FailureCause::Connect,
            sensors,
            outputs,
            monitor,
            quality: quality::QualityWindow::default(),
            readbacks,
            next_readback_ns: 0,
            period_ns: u64::try_from(cfg.period().as_nanos()).unwrap_or(u64::MAX),
            read_done_ns: 0,
            trigger: None,
            role: Role::Both,
            split: None,
        })
    }

    /// Read back the command registers with `readback` (every [`READBACK_PERIOD_NS`]) and
    /// report a value this controller did not write.
    async fn read_back(&mut self, out: &mut Outcome) {
        if self.readbacks.is_empty() {
            return;
        }
        let now = monotonic_ns();
        if now < self.next_readback_ns {
            return;
        }
        self.next_readback_ns = now + READBACK_PERIOD_NS;
        let mut found = None;
        for i in 0..self.readbacks.len() {
            let (k, plan, value) = &mut self.readbacks[i];
            let k = *k;
            match self.client.read(plan, value).await {
                Ok(()) => {
                    out.answered = true;
                    let bits = self.acknowledged[k];
                    if !self.acknowledged_valid || f64::from_bits(bits).is_nan() {
                        continue;
                    }
                    let written = f64::from_bits(bits);
                    let b = plan.bindings()[0];
                    // one register step of the encoding, and a hair for the decode's rounding
                    let tol = 1.01 * b.resolution(written) + 1e-12 * written.abs().max(1.0);
                    if (value[0] - written).abs() > tol {
                        found = Some(AnotherWriter {
                            actuator: self.actuators[k],
                            unit_id: b.unit_id,
                            address: b.address,
                            read: value[0],
                            written,
                        });
                    }
                }
                Err(e) => {
                    if self.note_error(&e, out) {
                        return;
                    }
                }
            }
        }
        self.monitor.set_another_writer(found);
    }

    /// Nothing to read and nothing to write.
    fn is_idle(&self) -> bool {
        self.groups.is_empty() && self.write_plan.is_empty()
    }

    /// Note a failed operation; returns whether it was a link failure.
    fn note_error(&mut self, e: &ModbusError, out: &mut Outcome) -> bool {
        if let Some(x) = ExceptionInfo::of(e) {
            out.exception.get_or_insert(x);
            return false;
        }
        if let Some(cause) = FailureCause::of(e) {
            self.last_cause = cause;
        }
        if !e.is_link_failure() {
            // Only a length mismatch remains: a planning bug, not a device answer.
            tracing::error!(target: "modbus", error = %e, "link: inconsistent request plan");
        }
        out.link_failed = true;
        true
    }

    /// One read of every sensor group; publishes what was answered.
    async fn read(&mut self, out: &mut Outcome) {
        if self.groups.is_empty() {
            // a write-only link reads nothing to resync on (the command side of
            // `command_connection = "own"` resyncs on the read side's reads instead)
            if self.role != Role::Commands {
                self.resync = None;
            }
            return;
        }
        let c = &self.monitor.counters;
        LinkCounters::add(&c.polls, 1);
        let mut all_ok = true;
        let mut published = 0u64;
        let latest_cycle = self.outputs.latest().map_or(0, |o| o.cycle);
        for k in 0..self.groups.len() {
            let g = &mut self.groups[k];
            let sent_ns = monotonic_ns();
            let result = self.client.read(&g.plan, &mut g.values).await;
            let t_ns = monotonic_ns();
            if counts_for_latency(&result) {
                self.quality.answered(sent_ns, t_ns);
            }
            match result {
                Ok(()) => {
                    for ((id, slot), v) in g.ids.iter().zip(&g.values) {
                        self.sensors.publish_transmitter(*id, *slot, *v, t_ns);
                    }
                    published += g.ids.len() as u64;
                    out.answered = true;
                    if self.resync == Some(None) {
                        self.resync = Some(Some(latest_cycle));
                        self.resync_read_ns = t_ns;
                    }
                }
                Err(e) => {
                    all_ok = false;
                    if self.note_error(&e, out) {
                        break;
                    }
                }
            }
        }
        self.read_done_ns = if published > 0 { monotonic_ns() } else { 0 };
        if let (Some(t), true) = (&self.trigger, published > 0) {
            t.note(READ_TRIGGER_BIT, self.read_done_ns);
        }
        if let (Some(sp), true) = (&self.split, published > 0) {
            sp.read_done_ns.store(self.read_done_ns, Ordering::Release);
        }
        let c = &self.monitor.counters;
        LinkCounters::add(&c.values_published, published);
        if all_ok {
            LinkCounters::add(&c.polls_ok, 1);
            self.quality.poll_answered(monotonic_ns());
        }
    }

    /// Write the latest output set if it is new and fresh.
    async fn write(&mut self, out: &mut Outcome) {
        if self.write_plan.is_empty() {
            return;
        }
        let Some(o) = self.outputs.latest() else {
            return;
        };
        if self.last_written_cycle == Some(o.cycle) {
            return;
        }
        // ... and while the core still holds fail-safe on those first values (it leaves it
        // after its exit hysteresis, then resumes from the measured valve position), at most
        // RESYNC_FAILSAFE_NS: a fail-safe that lasts is written
        match self.resync {
            Some(Some(k))
                if o.cycle >= k.saturating_add(2)
                    && (o.mode != Mode::FailSafe
                        || monotonic_ns().saturating_sub(self.resync_read_ns)
                            >= RESYNC_FAILSAFE_NS) =>
            {
                self.resync = None
            }
            Some(_) => return,
            None => {}
        }
        let c = &self.monitor.counters;
        if monotonic_ns().saturating_sub(o.t_ns) > self.max_output_age_ns {
            LinkCounters::add(&c.writes_stale, 1);
            return;
        }
        let mut unchanged = 0u64;
        for (k, id) in self.actuators.iter().enumerate() {
            let v = o.commands.get(*id);
            self.write_values[k] = if self.change_only
                && self.acknowledged_valid
                && !v.is_nan()
                && v.to_bits() == self.acknowledged[k]
            {
                unchanged += 1;
                f64::NAN
            } else {
                v
            };
        }
        if self.heartbeat {
            let n = self.actuators.len();
            self.alive = self.alive.wrapping_add(1);
            let w = HeartbeatWords {
                mode: o.mode.code(),
                alive: self.alive,
                law: o.law,
                faults: o.faults,
            }
            .encode();
            self.write_values[n] = f64::from(w[0]);
            self.write_values[n + 1] = f64::from(w[1]);
            self.write_values[n + 2] = f64::from(o.faults);
        }
        // whether this set carries a beat the device sees: the legacy heartbeat block, or the
        // watchdog contract's counter when it is not withheld
        let mut beat = self.heartbeat;
        if let Some(wd) = &self.watchdog {
            // Writes failing for longer than write_fault_timeout_ms: the counter stands
            // still, so the device's own watchdog takes it to its safe state.
            let withheld = self
                .write_failing
                .is_some_and(|(t0, _)| monotonic_ns().saturating_sub(t0) >= self.write_fault_ns);
            if withheld {
                LinkCounters::add(&c.watchdog_withheld, 1);
            } else {
                beat = true;
            }
            let at = self.watchdog_at;
            self.watchdog_writer.values(
                wd,
                o.mode.code(),
                o.law,
                o.faults,
                !withheld,
                &mut self.write_values[at..],
            );
        }
        LinkCounters::add(&c.setpoints_unchanged, unchanged);
        if self.write_values.iter().all(|v| v.is_nan()) {
            // Nothing commanded or nothing changed: this set is done.
            self.last_written_cycle = Some(o.cycle);
            return;
        }
        LinkCounters::add(&c.writes, 1);
        let sent_ns = monotonic_ns();
        let result = self
            .client
            .write(&self.write_plan, &self.write_values)
            .await;
        if counts_for_latency(&result) {
            self.quality.answered(sent_ns, monotonic_ns());
        }
        match result {
            Ok(report) => {
                out.write = Some(None);
                let c = &self.monitor.counters;
                LinkCounters::add(&c.writes_ok, 1);
                if beat {
                    LinkCounters::add(&c.heartbeats, 1);
                }
                out.answered |= report.requests > 0;
                self.last_written_cycle = Some(o.cycle);
                if !self.acknowledged_valid {
                    // Start from the device's view: what this write carried. Setpoints
                    // left out as NaN stay unknown, so keep them distinct from any value.
                    self.acknowledged.fill(f64::NAN.to_bits());
                }
                for (k, v) in self.write_values[..self.actuators.len()].iter().enumerate() {
                    if !v.is_nan() {
                        self.acknowledged[k] = v.to_bits();
                    }
                }
                self.acknowledged_valid = true;
            }
            Err(e) => {
                self.acknowledged_valid = false;
                LinkCounters::add(&self.monitor.counters.write_failures, 1);
                let failure = match ExceptionInfo::of(&e) {
                    Some(x) => WriteFailure::Exception(x),
                    None => WriteFailure::Link(FailureCause::of(&e).unwrap_or(self.last_cause)),
                };
                out.write = Some(Some(failure));
                if let WriteFailure::Exception(_) = failure {
                    // The set was delivered and refused: retrying it unchanged would be
                    // refused again. The next output set is tried afresh.
                    self.last_written_cycle = Some(o.cycle);
                }
                self.note_error(&e, out);
            }
        }
    }

    /// Wait until the control thread has published an output set computed from the values
    /// this cycle's read published (its wake time is later), at most one link period after
    /// the read; then the write carries the answer to these values, not to the previous
    /// read's. Without the wait, every command reached the device one link cycle (a read and a
    /// write, 25–40 ms on a gateway answering in 5–20 ms) later than it could.
    async fn await_outputs_on_read(&mut self) {
        if self.read_done_ns == 0 || self.write_plan.is_empty() {
            return;
        }
        let deadline = self.read_done_ns.saturating_add(self.period_ns);
        loop {
            if self
                .outputs
                .latest()
                .is_some_and(|o| o.t_ns >= self.read_done_ns)
            {
                return;
            }
            let now = monotonic_ns();
            if now >= deadline {
                return;
            }
            // (tokio's timer ticks in ms: the wait ends within 1 ms of the control cycle)
            tokio::time::sleep(Duration::from_nanos((deadline - now).min(1_000_000))).await;
        }
    }

    /// One link cycle. `write_first`: outputs before sensors (wakeup pacing). Otherwise the
    /// sensors are read, the write carries the output set computed from them (see
    /// [`Self::await_outputs_on_read`]), and the command registers are read back after the
    /// write: a read-back sees this controller's last write unless another master wrote since.
    async fn cycle(&mut self, write_first: bool) -> Outcome {
        let mut out = Outcome::default();
        if write_first {
            self.write(&mut out).await;
            if !out.link_failed {
                self.read(&mut out).await;
            }
            if !out.link_failed {
                self.read_back(&mut out).await;
            }
        } else {
            self.read(&mut out).await;
            if !out.link_failed {
                self.await_outputs_on_read().await;
                self.write(&mut out).await;
            }
            if !out.link_failed {
                self.read_back(&mut out).await;
            }
        }
        out
    }

    /// Counters and state after a cycle that took `elapsed`.
    fn finish(&mut self, out: &Outcome, elapsed: Duration, period: Duration) {
        let c = &self.monitor.counters;
        if self.role != Role::Commands {
            // the link cycle and its quality are the reads' (the command side writes when
            // there is something to write, at no period of its own)
            LinkCounters::add(&c.cycles, 1);
            if elapsed > period {
                LinkCounters::add(&c.overruns, 1);
            }
            let us = u64::try_from(elapsed.as_micros()).unwrap_or(u64::MAX);
            c.last_cycle_us.store(us, Ordering::Relaxed);
            c.max_cycle_us.fetch_max(us, Ordering::Relaxed);
            let q = self.quality.quality(monotonic_ns());
            c.poll_period_us.store(q.poll_period_us, Ordering::Relaxed);
            c.latency_p50_us.store(q.latency_p50_us, Ordering::Relaxed);
            c.latency_p99_us.store(q.latency_p99_us, Ordering::Relaxed);
        }
        self.mirror_client_counters();
        if out.link_failed {
            self.acknowledged_valid = false;
            self.resync = Some(None);
            if let Some(sp) = &self.split {
                if self.role == Role::Commands {
                    sp.note_command_failure(monotonic_ns());
                }
            }
        }
        let now = monotonic_ns();
        if self.role != Role::Reads {
            match out.write {
                Some(None) => self.write_failing = None,
                Some(Some(f)) => {
                    self.write_failing.get_or_insert((now, f));
                }
                None => {}
            }
            if out.link_failed && out.write.is_none() && self.write_failing.is_none() {
                // The link is down: writes cannot reach the device either.
                self.write_failing = Some((now, WriteFailure::Link(self.last_cause)));
            }
            self.monitor.set_writes(match self.write_failing {
                None => WriteHealth::Ok,
                Some((t0, cause)) => WriteHealth::Failing {
                    cause,
                    safe_state: now.saturating_sub(t0) >= self.write_fault_ns,
                },
            });
        }
        let new = match self.client.state() {
            ConnectionState::Broken {
                consecutive_failures,
                backoff_ms,
            } => LinkState::Down {
                attempt: consecutive_failures,
                backoff_ms,
                cause: self.last_cause,
            },
            ConnectionState::Connected => match (out.exception, out.answered) {
                (Some(x), _) => LinkState::Degraded(x),
                (None, true) => LinkState::Up,
                (None, false) => return,
            },
            ConnectionState::Idle => return,
        };
        match (self.role, &self.split) {
            (Role::Commands, Some(sp)) => {
                // the read side reports the link: it carries this connection's failure
                sp.set_commands_down(match new {
                    LinkState::Down { .. } => Some(new),
                    _ => None,
                });
            }
            (Role::Reads, Some(sp)) => match (new, sp.commands_down()) {
                (LinkState::Down { .. }, _) | (_, None) => self.monitor.set_state(new),
                (_, Some(down)) => self.monitor.set_state(down),
            },
            _ => self.monitor.set_state(new),
        }
    }

    /// Copy the client's counters into the shared atomics.
    fn mirror_client_counters(&self) {
        let c = &self.monitor.counters;
        let mut k = self.client.counters();
        match (self.role, &self.split) {
            (Role::Commands, Some(sp)) => {
                // the read side mirrors the sum of both connections
                sp.set_command_counters(k);
                return;
            }
            (Role::Reads, Some(sp)) => k = commands::add_counters(k, sp.command_counters()),
            _ => {}
        }
        for (slot, v) in [
            (&c.requests, k.requests),
            (&c.timeouts, k.timeouts),
            (&c.exceptions, k.exceptions),
            (&c.transport_errors, k.transport_errors),
            (&c.protocol_errors, k.protocol_errors),
            (&c.connect_attempts, k.connect_attempts),
            (&c.connect_failures, k.connect_failures),
            (&c.reconnects, k.reconnects),
            (&c.clamped_values, k.clamped_values),
        ] {
            slot.store(v, Ordering::Relaxed);
        }
    }
}

/// Run the controller side of the Modbus link until `shutdown` completes.
///
/// Reads every Modbus sensor of `map` each cycle (requests grouped by unit, table and
/// contiguous range) and publishes the values into `sensors` with the monotonic arrival time
/// of their response; writes the latest new output set of `outputs` (NaN setpoints are
/// skipped: the device keeps its last value) and the heartbeat block if configured. Link
/// failures and exceptions never stop the task: the client reconnects with backoff and the
/// state goes to `monitor`. Returns at once (Ok, state [`LinkState::Stopped`]) if there is
/// nothing to read or write: no Modbus signal in `map` and no heartbeat block.
///
/// Errors: invalid configuration or map, or (wakeup pacing) a failure to register the
/// eventfd with the runtime.
pub async fn run_controller(
    cfg: &ModbusLinkConfig,
    map: &SignalMap,
    sensors: Arc<SensorBoard>,
    outputs: Arc<OutputBoard>,
    pacing: Pacing,
    monitor: Arc<LinkMonitor>,
    shutdown: impl Future<Output = ()>,
) -> Result<(), LinkError> {
    run_controller_triggering(cfg, map, sensors, outputs, pacing, monitor, None, shutdown).await
}

/// [`run_controller`], firing `trigger` after every read that published values (the control
/// cycle runs on them at once: `cycle_trigger = "reads"`).
#[allow(clippy::too_many_arguments)] // the boards and handles of one link task
pub async fn run_controller_triggering(
    cfg: &ModbusLinkConfig,
    map: &SignalMap,
    sensors: Arc<SensorBoard>,
    outputs: Arc<OutputBoard>,
    pacing: Pacing,
    monitor: Arc<LinkMonitor>,
    trigger: Option<Arc<crate::runtime::trigger::CycleTrigger>>,
    shutdown: impl Future<Output = ()>,
) -> Result<(), LinkError> {
    let own = cfg.command_connection == CommandConnection::Own;
    let (sensors_c, outputs_c) = (Arc::clone(&sensors), Arc::clone(&outputs));
    let mut ctl = Controller::new(cfg, map, sensors, outputs, Arc::clone(&monitor))?;
    if let Some(t) = &trigger {
        t.arm(READ_TRIGGER_BIT);
    }
    ctl.trigger = trigger;
    if ctl.is_idle() {
        tracing::debug!(target: "modbus", "link: no Modbus signals in the map, nothing to do");
        monitor.set_state(LinkState::Stopped);
        return Ok(());
    }
    let period = cfg.period();
    tokio::pin!(shutdown);
    let mut commands = None;
    let result = match pacing {
        Pacing::Interval if own && !ctl.groups.is_empty() && !ctl.write_plan.is_empty() => {
            let second = Controller::new(cfg, map, sensors_c, outputs_c, Arc::clone(&monitor))?;
            let mut cmd = commands::split(&mut ctl, second);
            tokio::select! {
                biased;
                () = &mut shutdown => {}
                () = poll_at_interval(&mut ctl, period) => {}
                () = commands::run(&mut cmd, period) => {}
            }
            commands = Some(cmd);
            Ok(())
        }
        Pacing::Interval => {
            tokio::select! {
                biased;
                () = &mut shutdown => {}
                () = poll_at_interval(&mut ctl, period) => {}
            }
            Ok(())
        }
        Pacing::Wakeup(wake) => run_on_wakeup(&mut ctl, &wake, period, &mut shutdown).await,
    };
    if let Some(mut cmd) = commands {
        cmd.client.disconnect().await;
        cmd.mirror_client_counters();
    }
    ctl.client.disconnect().await;
    ctl.mirror_client_counters();
    monitor.set_state(LinkState::Stopped);
    result
}

/// The link's cycles at `period` (never returns; the caller selects it against shutdown).
async fn poll_at_interval(ctl: &mut Controller, period: Duration) {
    let mut ticker = tokio::time::interval(period);
    ticker.set_missed_tick_behavior(MissedTickBehavior::Delay);
    loop {
        ticker.tick().await;
        let start = Instant::now();
        let out = ctl.cycle(false).await;
        ctl.finish(&out, start.elapsed(), period);
    }
}

async fn run_on_wakeup<S: Future<Output = ()> + Unpin>(
    ctl: &mut Controller,
    wake: &Wakeup,
    period: Duration,
    shutdown: &mut S,
) -> Result<(), LinkError> {
    // SAFETY: the descriptor is owned by `wake`, which this function borrows for longer than
    // `fd` lives, and a `Wakeup` never replaces or closes its eventfd while it exists.
    let fd =
        unsafe { AsyncFd::register_with_interest(wake.fd(), Interest::READABLE) }.map_err(|e| {
            LinkError::Io {
                context: "registering the wakeup eventfd",
                source: e.into(),
            }
        })?;
    let mut next_allowed = Instant::now();
    loop {
        tokio::select! {
            biased;
            () = &mut *shutdown => return Ok(()),
            ready = fd.readable() => {
                let mut guard = ready.map_err(|source| LinkError::Io {
                    context: "waiting on the wakeup eventfd",
                    source,
                })?;
                // Drain first, then clear readiness: a signal in between re-arms the fd.
                wake.clear();
                guard.clear_ready();
            }
        }
        if Instant::now() < next_allowed {
            tokio::select! {
                biased;
                () = &mut *shutdown => return Ok(()),
                () = tokio::time::sleep_until(next_allowed) => {}
            }
        }
        let start = Instant::now();
        next_allowed = start + period;
        let out = tokio::select! {
            biased;
            () = &mut *shutdown => return Ok(()),
            out = ctl.cycle(true) => out,
        };
        ctl.finish(&out, start.elapsed(), period);
    }
}

#[cfg(test)]
mod tests;
