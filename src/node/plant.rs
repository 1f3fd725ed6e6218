//! The simulated skid in real time: the body of the plant node's thread
//! (`antisurge plant`, and the in-process plant of `antisurge run`).
//!
//! Each step applies the setpoints last received from the controller, advances the plant by
//! one scenario period and publishes the field readings. Like real field devices, it watches
//! the controller's heartbeat: when none arrived for `heartbeat_timeout_ms`, the valve
//! positioner fails open (recycle valve 100 %), the drive falls back to its own speed
//! governor at the last speed setpoint, the thrust bearing centres (clearance change 0) and
//! the close-coupled valve goes neutral. The scenario clock starts with the first heartbeat,
//! so a HIL run and an in-process `antisurge sim` of the same scenario start alike.

use crate::control::speed_loop::SpeedLoop;
use crate::plant::file::PlantDescription;
use crate::runtime::handoff::{
    CommandBoard, HeartbeatBoard, OutputBoard, SensorBoard, SnapshotBoard, Wakeup,
};
use crate::sim::summary::DeviceWatchdogTrip;
use crate::sim::trace_handoff::{TraceHandoff, TraceWriter};
use crate::sim::{ControllerView, PlantRun, SimResult};
use crate::vocab::signals::{ActuatorCommands, ActuatorId, SensorId};
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

/// Where the plant takes the controller's setpoints and heartbeat from.
#[derive(Clone)]
pub enum CommandSource {
    /// From bus tasks (CAN or Modbus server).
    Bus {
        /// Received setpoints.
        commands: Arc<CommandBoard>,
        /// Received heartbeat.
        heartbeat: Arc<HeartbeatBoard>,
    },
    /// Straight from the in-process control thread.
    InProcess(Arc<OutputBoard>),
}

/// Where the plant publishes its readings.
#[derive(Clone)]
pub enum SensorSink {
    /// To bus tasks: a snapshot plus a wakeup.
    Bus {
        /// Latest snapshot.
        snapshots: Arc<SnapshotBoard>,
        /// Wakes the sending task.
        wake: Arc<Wakeup>,
    },
    /// Straight into the in-process control thread's sensor board.
    InProcess(Arc<SensorBoard>),
}

/// Plant status, lock-free, for the runtime and tests.
#[derive(Debug, Default)]
pub struct PlantStatus {
    /// Scenario steps done.
    pub steps: AtomicU64,
    /// The field devices are in their own fail-safe (controller heartbeat lost).
    pub field_failsafe: AtomicBool,
    /// How often the field fail-safe was entered.
    pub failsafe_entries: AtomicU64,
    /// Heartbeat age at the last fail-safe entry, µs.
    pub failsafe_entry_age_us: AtomicU64,
    /// The scenario has ended.
    pub finished: AtomicBool,
    /// First fail-safe entry: plant time, s (f64 bits; valid once `failsafe_entries` ≥ 1).
    first_trip_t_bits: AtomicU64,
    /// First fail-safe entry: plant time of the last heartbeat change before it, s (f64 bits).
    first_trip_last_beat_t_bits: AtomicU64,
    /// First fail-safe entry: Unix time of that last heartbeat change, s (f64 bits).
    first_trip_last_beat_unix_bits: AtomicU64,
    /// First fail-safe entry: heartbeat age, µs.
    first_trip_age_us: AtomicU64,
}

impl PlantStatus {
    /// The device watchdog's first trip (None while the field devices never failed safe):
    /// when, and after which last heartbeat change, for the summary and the journal.
    pub fn device_watchdog(&self) -> Option<DeviceWatchdogTrip> {
        if self.failsafe_entries.load(Ordering::Acquire) == 0 {
            return None;
        }
        let f = |a: &AtomicU64| f64::from_bits(a.load(Ordering::Relaxed));
        Some(DeviceWatchdogTrip {
            failsafe_t_s: f(&self.first_trip_t_bits),
            last_beat_t_s: f(&self.first_trip_last_beat_t_bits),
            last_beat_unix_s: f(&self.first_trip_last_beat_unix_bits),
            age_s: self.first_trip_age_us.load(Ordering::Relaxed) as f64 * 1e-6,
        })
    }
}

/// The plant node.
pub struct PlantNode<'a> {
    run: PlantRun<'a>,
    src: CommandSource,
    sink: SensorSink,
    hb_timeout_ns: u64,
    governor: SpeedLoop,
    nominal_speed_rad_s: f64,
    last: ActuatorCommands,
    started: bool,
    k: usize,
    hold_after_end: bool,
    status: Arc<PlantStatus>,
    /// Arrival time of the last heartbeat change the device watchdog saw (monotonic ns).
    last_hb_ns: u64,
    /// Plant time of the step that first saw it, s.
    last_beat_t_s: f64,
    /// Snapshots published so far (the plant's sample clock, in periods).
    samples: u64,
}

impl<'a> PlantNode<'a> {
    /// A node for `run`, wired to `src`/`sink`.
    pub fn new(
        desc: &'a PlantDescription,
        run: PlantRun<'a>,
        src: CommandSource,
        sink: SensorSink,
        heartbeat_timeout_ms: f64,
        hold_after_end: bool,
        status: Arc<PlantStatus>,
    ) -> Self {
        let d = desc.file.drive;
        let t0 = run.plant().truth().load_torque_nm;
        PlantNode {
            run,
            src,
            sink,
            hb_timeout_ns: (heartbeat_timeout_ms * 1e6) as u64,
            governor: SpeedLoop::new(
                d.speed_kp_nm_s_rad,
                d.speed_ki_nm_rad,
                (d.min_torque_nm, d.rated_torque_nm),
                t0,
            ),
            nominal_speed_rad_s: d.nominal_speed_rad_s,
            last: ActuatorCommands::default(),
            started: false,
            k: 0,
            hold_after_end,
            status,
            last_hb_ns: 0,
            last_beat_t_s: 0.0,
            samples: 0,
        }
    }

    /// The plant side of the run.
    pub fn run(&self) -> &PlantRun<'a> {
        &self.run
    }

    /// Setpoints and the heartbeat's arrival time (0: never).
    fn received(&self) -> (ActuatorCommands, u64) {
        match &self.src {
            CommandSource::Bus {
                commands,
                heartbeat,
            } => {
                let mut c = ActuatorCommands::default();
                for id in ActuatorId::ALL {
                    c.set(id, commands.get(id).0);
                }
                (c, heartbeat.latest().map_or(0, |h| h.t_ns))
            }
            CommandSource::InProcess(outputs) => match outputs.latest() {
                Some(o) => (o.commands, o.t_ns),
                None => (ActuatorCommands::default(), 0),
            },
        }
    }

    /// Publish the readings `raw` of a step at `now_ns` (monotonic), sampled at `sample_ns` on
    /// the plant's own clock.
    fn publish(&self, now_ns: u64, sample_ns: u64, raw: &crate::control::measurements::RawSensors) {
        match &self.sink {
            SensorSink::Bus { snapshots, wake } => {
                // a failed (frozen) transmitter sends no valid value: NaN goes out as "not
                // available" on CAN, and the controller's supervisor rejects that input
                let mut values = raw.values;
                for id in SensorId::ALL {
                    if raw.age_s[id.index()] > 0.0 {
                        values.set(id, f64::NAN);
                    }
                }
                snapshots.publish(&values, self.k as u64, sample_ns);
                wake.signal();
            }
            SensorSink::InProcess(board) => {
                for id in SensorId::ALL {
                    // a stale (frozen) transmitter stops updating: its arrival time stays old
                    if raw.age_s[id.index()] == 0.0 {
                        board.publish_sampled(id, raw.values.get(id), now_ns, sample_ns);
                    }
                }
            }
        }
    }

    /// One step at `now_ns`. Returns false when the scenario is over (and not held).
    pub fn step(&mut self, now_ns: u64) -> bool {
        let dt = self.run.dt_s();
        // sampled on the plant's own clock, one period per step (waiting for the first
        // heartbeat included): a step its host delayed still comes one period after the last
        // (RawSensors::sample_clock_s; the CAN sender counts it, plant_send_loop)
        let sample_ns = (self.samples as f64 * dt * 1e9).round() as u64;
        self.samples += 1;
        let (received, hb_ns) = self.received();
        let alive = hb_ns > 0 && now_ns.saturating_sub(hb_ns) <= self.hb_timeout_ns;
        if !self.started {
            // before the controller's first heartbeat: publish the initial steady state
            let (_, raw) = self.run.sense(0.0);
            self.publish(now_ns, sample_ns, &raw);
            if !alive {
                return true;
            }
            self.started = true;
        }
        let n = self.run.n_steps();
        let at_end = self.k >= n;
        let t = self.k.min(n) as f64 * dt;
        let (st, raw) = self.run.sense(t);
        self.publish(now_ns, sample_ns, &raw);
        if hb_ns != self.last_hb_ns {
            // the device watchdog saw the heartbeat change in this step
            self.last_hb_ns = hb_ns;
            self.last_beat_t_s = t;
        }

        let omega = self.run.plant().truth().omega_rad_s;
        let was_failsafe = self.status.field_failsafe.load(Ordering::Relaxed);
        let mut cmd = received;
        if alive {
            if was_failsafe {
                self.status.field_failsafe.store(false, Ordering::Relaxed);
            }
            let torque = cmd.get(ActuatorId::DriveTorque);
            if torque.is_finite() {
                // keep the drive's own governor tracking, for a bumpless take-over
                self.governor
                    .track(torque, self.nominal_speed_rad_s * st.speed_setpoint, omega);
            } else {
                // the controller does not command torque (it does not own the drive's speed
                // loop): the drive's own governor keeps speed
                let t = self.governor.update(
                    self.nominal_speed_rad_s * st.speed_setpoint,
                    omega,
                    0.0,
                    dt,
                );
                cmd.set(ActuatorId::DriveTorque, t);
            }
        } else {
            if !was_failsafe {
                let age_us = now_ns.saturating_sub(hb_ns) / 1000;
                if self.status.failsafe_entries.load(Ordering::Relaxed) == 0 {
                    let s = &self.status;
                    // the beat's wall-clock time, so a test can set it against its kill
                    let unix_s = std::time::SystemTime::now()
                        .duration_since(std::time::UNIX_EPOCH)
                        .map_or(0.0, |d| d.as_secs_f64())
                        - age_us as f64 * 1e-6;
                    s.first_trip_t_bits.store(t.to_bits(), Ordering::Relaxed);
                    s.first_trip_last_beat_t_bits
                        .store(self.last_beat_t_s.to_bits(), Ordering::Relaxed);
                    s.first_trip_last_beat_unix_bits
                        .store(unix_s.to_bits(), Ordering::Relaxed);
                    s.first_trip_age_us.store(age_us, Ordering::Relaxed);
                }
                self.status.field_failsafe.store(true, Ordering::Relaxed);
                self.status.failsafe_entries.fetch_add(1, Ordering::Release);
                self.status
                    .failsafe_entry_age_us
                    .store(age_us, Ordering::Relaxed);
            }
            cmd = self.field_failsafe(omega, st.speed_setpoint, dt);
        }
        self.last = cmd;
        if at_end {
            self.status.finished.store(true, Ordering::Relaxed);
            if !self.hold_after_end {
                return false;
            }
            self.run.advance(&st, &cmd, dt);
            return true;
        }
        self.run
            .record(self.k, t, dt, &raw, &cmd, &ControllerView::UNKNOWN);
        self.run.advance(&st, &cmd, dt);
        self.k += 1;
        self.status.steps.store(self.k as u64, Ordering::Relaxed);
        true
    }

    /// The field devices' own safe state (no controller).
    fn field_failsafe(&mut self, omega: f64, speed_fraction: f64, dt: f64) -> ActuatorCommands {
        let mut c = ActuatorCommands::default();
        c.set(ActuatorId::RecycleValve, 1.0);
        c.set(ActuatorId::TipClearance, 0.0);
        c.set(ActuatorId::CloseCoupledValve, 0.0);
        let torque =
            self.governor
                .update(self.nominal_speed_rad_s * speed_fraction, omega, 0.0, dt);
        c.set(ActuatorId::DriveTorque, torque);
        c
    }

    /// Last setpoints applied.
    pub fn last_commands(&self) -> ActuatorCommands {
        self.last
    }

    /// Result so far.
    pub fn result(&self, law: &str) -> SimResult {
        self.run.finish(law)
    }

    /// End the run's trace handoff ([`PlantRun::close_handoff`]): the writer thread writes
    /// the last rows and ends. The rows dropped, `None` if the trace is not handed over.
    pub fn close_trace(&mut self) -> Option<u64> {
        self.run.close_handoff()
    }

    /// The result of a run whose trace went to a writer thread ([`PlantRun::finish_written`]).
    pub fn result_written(
        &self,
        law: &str,
        written: &crate::sim::trace_handoff::WrittenTrace,
    ) -> Result<SimResult, crate::sim::SimError> {
        self.run.finish_written(law, written)
    }
}

/// Start writing a plant node's trace to `dir/trace.csv` as the run goes: the writer thread
/// ([`TraceWriter`]) and the handoff for the plant's run ([`PlantRun::handing_trace_to`]). Call
/// it from a thread of ordinary priority, before the plant thread starts.
pub fn start_trace(
    desc: &PlantDescription,
    scenario: &crate::scenario::Scenario,
    dir: &Path,
) -> Result<(TraceHandoff, TraceWriter), crate::sim::SimError> {
    let volumetric =
        desc.map.flow_coordinate == crate::physics::compressor_map::FlowCoordinate::InletVolumeM3S;
    TraceWriter::start(
        dir,
        volumetric,
        crate::sim::runner::trace_period_s(scenario),
        scenario.last_event_s(),
    )
}

/// After the plant's loop: end the trace handoff, wait for the writer to write the last rows,
/// log the rows written and dropped, and return the result (its summary with the dropped
/// count).
pub fn finish_trace(
    node: &mut PlantNode<'_>,
    writer: TraceWriter,
    law: &str,
) -> Result<SimResult, crate::sim::SimError> {
    node.close_trace();
    let written = writer.finish()?;
    if written.dropped > 0 {
        tracing::warn!(target: "plant", "{}: {} trace rows written, {} dropped (the trace writer fell behind; the trace has gaps)", written.path.display(), written.rows, written.dropped);
    } else {
        tracing::info!(target: "plant", "{}: {} trace rows written, 0 dropped", written.path.display(), written.rows);
    }
    node.result_written(law, &written)
}
