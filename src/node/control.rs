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

use crate::control::core::{ControlCore, CoreSettings, CycleOutput, Reconfiguration};
use crate::control::law::api::{LawEvent, LawId};
use crate::control::measurements::{OperatorInputs, RawSensors};
use crate::events::cause::{Cause, CauseKind};
use crate::events::event::{
    FallbackEntered, FallbackLeft, FallbackReason, LawChanged, ModeChanged, RecycleTrip,
    Replacement, SafetyOnShift, SurgeCounter, SurgeDetected, TripReason,
};
use crate::events::{OverrunReporter, RtSender};
use crate::runtime::handoff::{OutputBoard, Outputs, SensorBoard, Wakeup};
use crate::runtime::rt_loop::{CycleStats, Tick};
use crate::surge::Detection;
use crate::vocab::signals::{ActuatorCommands, SensorId};
use crate::vocab::Mode;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

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
    /// Operator acknowledgements so far (the field tasks clear latched faults on a change).
    pub acknowledgements: AtomicU64,
}

impl Health {
    /// Mode of the last cycle.
    pub fn mode(&self) -> Mode {
        u8::try_from(self.mode.load(Ordering::Relaxed))
            .ok()
            .and_then(Mode::from_code)
            .unwrap_or(Mode::Init)
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
    field: Arc<crate::io::link::FieldFaults>,
    /// The field fault word read at the start of this cycle.
    field_word: u32,
    period_ns: u64,
    t0_ns: u64,
    prev_mode: Mode,
    prev_law: LawId,
    fallback_since_ns: Option<u64>,
    surges: u64,
    live: Option<Arc<crate::live::snapshot::LiveBoard>>,
    commands: Option<rtrb::Consumer<crate::live::commands::OperatorCommand>>,
    /// Cause of the last mode change (kept current while in fail-safe).
    cause: Option<Cause>,
    /// Sensors that ever delivered a value (a fault lamp is lit for those and the needed ones).
    seen: u32,
    /// The ESD / drive-trip input held the recycle valve open in the previous cycle.
    esd_active: bool,
    blackbox: Option<crate::blackbox::BlackBoxTx>,
    /// Per sensor, the kinds of field link that carry it (bits of `1 << FieldLinkKind::code`;
    /// `u8::MAX`: not told, any link): a link down roots only the inputs it carries.
    input_links: [u8; SensorId::COUNT],
    /// What stands in for the flow element during the current fallback.
    fallback_replacement: Replacement,
    /// Each redundant transmitter's state as last reported (events on a change).
    transmitters: [[crate::control::vote::TransmitterState; crate::control::vote::MAX_TRANSMITTERS];
        crate::control::vote::VOTABLE.len()],
}

/// Fault bits of the heartbeat: bit i set when sensor i is not usable.
/// The fault word on the wire: the shared categories of [`crate::faults`].
fn fault_bits(
    v: &crate::control::supervisor::Validity,
    s: &crate::control::supervisor::Supervisor,
) -> u32 {
    v.fault_set(s).0
}

/// Fault lamps of the live snapshot: bit i set when sensor i is not usable (the wire's fault
/// word is [`fault_bits`], by category).
fn sensor_lamp_bits(v: &crate::control::supervisor::Validity) -> u32 {
    let mut bits = 0u32;
    for id in SensorId::ALL {
        if !v.ok(id) {
            bits |= 1 << id.index();
        }
    }
    bits
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
    /// The field faults the link tasks raise (read each cycle: the fault word on the wire,
    /// the link named as the root of stale inputs, the slow-link policy).
    pub field: Arc<crate::io::link::FieldFaults>,
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
            field: w.field,
            field_word: 0,
            period_ns,
            t0_ns: u64::MAX, // set from the first tick: time comes from the ticks only
            prev_mode: Mode::Init,
            prev_law,
            fallback_since_ns: None,
            surges: 0,
            live: None,
            commands: None,
            cause: None,
            seen: 0,
            esd_active: false,
            blackbox: None,
            input_links: [u8::MAX; SensorId::COUNT],
            fallback_replacement: Replacement::Observer,
            // a transmitter is taken as healthy until the first report says otherwise
            transmitters: [[crate::control::vote::TransmitterState::Healthy;
                crate::control::vote::MAX_TRANSMITTERS];
                crate::control::vote::VOTABLE.len()],
        }
    }

    /// Publish the live snapshot on `live` every cycle and take operator actions from
    /// `commands` (status socket, HMI).
    pub fn attach_live(
        &mut self,
        live: Arc<crate::live::snapshot::LiveBoard>,
        commands: rtrb::Consumer<crate::live::commands::OperatorCommand>,
    ) {
        self.live = Some(live);
        self.commands = Some(commands);
    }

    /// Restore the state kept across restarts (before the first cycle): surge counter,
    /// safety-on steps, and manual mode if the operator had chosen it (the manual station
    /// then starts from the valve's measured position).
    pub fn restore(&mut self, s: &crate::live::persist::PersistentState) {
        self.surges = s.surge_count;
        self.health.surges.store(s.surge_count, Ordering::Relaxed);
        self.core.restore_safety_on(s.safety_on_count);
        if !s.auto {
            self.core.request_auto(false);
        }
    }

    fn apply_operator_commands(&mut self) {
        use crate::live::commands::OperatorCommand as C;
        let Some(rx) = &mut self.commands else {
            return;
        };
        while let Ok(c) = rx.pop() {
            match c {
                C::SetAuto(a) => self.core.request_auto(a),
                C::ManualOutput(u) => self.core.set_manual_output(u),
                C::ResetSurgeCounter => {
                    let previous = self.surges;
                    self.surges = 0;
                    self.health.surges.store(0, Ordering::Relaxed);
                    if let Some(tx) = &mut self.events {
                        tx.try_push(SurgeCounter {
                            previous_count: previous,
                            count: 0,
                        });
                    }
                }
                C::Acknowledge => {
                    self.health.acknowledgements.fetch_add(1, Ordering::Relaxed);
                    if matches!(self.prev_mode, Mode::Auto | Mode::Manual) {
                        self.cause = None;
                    }
                }
            }
        }
    }

    /// Why the mode is what it is after this cycle.
    fn cause_now(&self, out: &CycleOutput, raw: &RawSensors, from: Mode) -> Cause {
        match out.mode {
            Mode::FailSafe | Mode::Init => {
                let sup = &self.core.settings().supervisor;
                let v = &out.validity;
                let needs_flow = self.core.law() != LawId::None && self.core.auto_requested();
                let cause =
                    Cause::of_unusable_inputs(v, &raw.values.values, &raw.age_s, sup, needs_flow)
                        .or_else(|| {
                            Cause::of_unusable_inputs(v, &raw.values.values, &raw.age_s, sup, true)
                        })
                        .unwrap_or(Cause::of(CauseKind::InputFault));
                // a link that is down is the root of the inputs it carries going stale
                let carried_by = cause.input.map_or(u8::MAX, |i| self.input_links[i.index()]);
                cause.rooted_in_link(self.field.down_link_among(carried_by))
            }
            Mode::Auto | Mode::Manual if matches!(from, Mode::Init | Mode::FailSafe) => {
                Cause::of(CauseKind::InputsHealthy)
            }
            Mode::Auto | Mode::Manual => Cause::of(CauseKind::Operator),
            // the core never reports shutdown (the daemon's stop does, see `shutdown`)
            Mode::Shutdown => Cause::of(CauseKind::Shutdown),
        }
    }

    fn publish_live(&mut self, out: &CycleOutput, raw: &RawSensors, cycle: u64, t_ns: u64) {
        use crate::live::snapshot::{FlowSourceNow, LiveSnapshot};
        if self.live.is_none() {
            return;
        }
        // an input the supervisor does not use is no lamp (as in the fault word), e.g. the
        // simulated plant's ESD contact when the controller has none bound
        let sup = &self.core.settings().supervisor;
        for id in SensorId::ALL {
            if raw.values.get(id).is_finite() && sup.limits[id.index()].is_some() {
                self.seen |= 1 << id.index();
            }
        }
        let needed = [
            SensorId::PSuction,
            SensorId::PDischarge,
            SensorId::ShaftSpeed,
            SensorId::OrificeDp,
        ]
        .iter()
        .filter(|id| sup.limits[id.index()].is_some())
        .fold(self.seen, |b, id| b | 1 << id.index());
        let Some(live) = &self.live else {
            return;
        };
        let m = &out.measurements;
        let (q, r) = (m.flow_map, m.pressure_ratio);
        let model = self.core.model();
        // the degraded policy's shift acts on the law's flow (core::law_measurements): the
        // control and trip lines it acts on are that much further right
        let widen = 1.0 + self.core.margin_shift().now;
        let (surge_line, control_line, trip_line, shift) = match self.core.control_line() {
            Some((scl, trip)) => {
                let j = scl.surge_line().flow_at_ratio(r);
                (
                    j,
                    widen * scl.flow_at_ratio(r),
                    widen * (1.0 + trip) * j,
                    scl.shift,
                )
            }
            None => {
                let j = model
                    .map
                    .as_ref()
                    .map_or(f64::NAN, |m| m.surge_line.flow_at_ratio(r));
                (j, f64::NAN, f64::NAN, 0.0)
            }
        };
        let (safety_on, trips) = self.core.safety_on_and_trips();
        // the process values the cycle used (NaN where it had none: a skid without the
        // transmitter, or one that failed its checks): the pressures from its measurements;
        // the Δp voted where redundant, else the reading that passed supervision; the suction
        // temperature only when measured (the nominal one the cycle falls back to is no
        // measurement)
        let v = &out.validity;
        let orifice_dp_pa = if !v.ok(SensorId::OrificeDp) {
            f64::NAN
        } else {
            match self.core.vote().of(SensorId::OrificeDp) {
                Some(vote) => vote.value,
                None => raw.values.get(SensorId::OrificeDp),
            }
        };
        let t_suction_k = if v.ok(SensorId::TSuction) {
            m.t_suction_k
        } else {
            f64::NAN
        };
        let flow_source = if !m.m_kg_s.is_finite() {
            FlowSourceNow::None
        } else if m.flow_fallback && !m.m_observer_kg_s.is_finite() {
            FlowSourceNow::SpeedLineFallback
        } else if m.flow_fallback {
            FlowSourceNow::ObserverFallback
        } else if self.core.config().flow_source == crate::control::config::FlowSource::Observer {
            FlowSourceNow::Observer
        } else {
            FlowSourceNow::Orifice
        };
        live.publish(&LiveSnapshot {
            cycle,
            t_ns,
            mode: out.mode,
            law: out.law,
            flow_source,
            fault_bits: sensor_lamp_bits(&out.validity) & needed,
            field_faults: self.field_word,
            cause: self.cause,
            flow_map: q,
            pressure_ratio: r,
            m_kg_s: m.m_kg_s,
            omega_rad_s: m.omega_rad_s,
            p_suction_pa: m.p_suction_pa,
            p_discharge_pa: m.p_discharge_pa,
            orifice_dp_pa,
            t_suction_k,
            surge_line_flow: surge_line,
            control_line_flow: control_line,
            trip_line_flow: trip_line,
            // the one definition of the deviation: % of control-line flow, positive = safe
            deviation_pct: 100.0 * (q - control_line) / control_line,
            surge_margin_pct: 100.0 * model.surge_margin(q, r),
            safety_on_shift_pct: 100.0 * shift,
            safety_on_count: safety_on,
            surge_count: self.surges,
            trip_count: u64::from(trips),
            valve_output: out
                .commands
                .get(crate::vocab::signals::ActuatorId::RecycleValve),
            valve_position: m.recycle_position,
            manual_output: self.core.manual_output(),
            auto_requested: self.core.auto_requested(),
            votes: crate::live::snapshot::VoteLamps {
                votes: self.core.vote().status(),
                shift: self.core.margin_shift(),
            },
        });
    }

    /// The kinds of field link that carry each sensor (from the input->link table built at
    /// start, [`crate::daemon::field::input_link_kinds`]): a cause is rooted in a link only when that
    /// link carries the input (with CAN and Modbus, the CAN link down is not the root of a
    /// Modbus input's fault).
    pub fn with_input_links(mut self, kinds: [u8; SensorId::COUNT]) -> Self {
        self.input_links = kinds;
        self
    }

    /// Record every cycle into the black box (`crate::blackbox`): one copy per cycle into a
    /// lock-free ring; the recorder thread does the file I/O.
    pub fn with_black_box(mut self, tx: crate::blackbox::BlackBoxTx) -> Self {
        self.blackbox = Some(tx);
        self
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
        self.apply_operator_commands();
        let now = tick.wake_ns;
        let raw = self.sensors.raw(now);
        let oldest = crate::vocab::signals::CYCLE_INPUTS
            .iter()
            .map(|s| raw.age_s[s.index()])
            .fold(0.0f64, f64::max);
        if oldest.is_finite() {
            self.stats.input_age.record((oldest * 1e9) as u64);
        }
        if self.t0_ns == u64::MAX {
            // the run's time origin: one period before the first deadline (from the tick)
            self.t0_ns = tick.deadline_ns.saturating_sub(self.period_ns);
        }
        let t_s = now.saturating_sub(self.t0_ns) as f64 * 1e-9;
        // the field faults of this cycle; the slow-link policy: a field link slow but alive
        // widens the control line
        self.field_word = self.field.word();
        let slow = self.field_word & crate::vocab::faults::FaultCategory::FieldLinkSlow.bit();
        self.core.set_link_slow(slow != 0);
        let out = self.core.cycle(t_s, &raw, &self.op);
        if let Some(bb) = &mut self.blackbox {
            let m = &out.measurements;
            bb.push(crate::blackbox::CycleRecord {
                cycle: tick.cycle,
                deadline_ns: tick.deadline_ns,
                wake_ns: tick.wake_ns,
                t_s,
                raw,
                op: self.op,
                commands: out.commands,
                mode: out.mode,
                law: out.law.code(),
                law_diagnostic: out.law_diagnostic,
                law_torque_nm: out.law_torque_nm,
                m_used_kg_s: m.m_kg_s,
                m_observer_kg_s: m.m_observer_kg_s,
                flow_fallback: m.flow_fallback,
                surge_started: matches!(
                    out.surge,
                    Detection::SurgeStarted | Detection::ReversalStarted
                ),
                updates_applied: self.health.updates_applied.load(Ordering::Relaxed),
                voted: self.core.vote().status().map(
                    |v| {
                        if v.bound > 0 {
                            v.value
                        } else {
                            f64::NAN
                        }
                    },
                ),
            });
        }
        self.outputs.publish(&Outputs {
            commands: out.commands,
            mode: out.mode,
            law: out.law.code(),
            // the input faults of this cycle and the field faults of the link tasks
            faults: fault_bits(&out.validity, &self.core.settings().supervisor)
                | self.core.vote().fault_set().0
                | self.field_word,
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
            let cause = self.cause_now(&out, &raw, self.prev_mode);
            self.cause = Some(cause);
            self.push(ModeChanged {
                from: self.prev_mode,
                to: out.mode,
                cause: Some(cause),
            });
            self.prev_mode = out.mode;
        } else if out.mode == Mode::FailSafe {
            // keep the shown cause current (another input may fail, the value moves)
            self.cause = Some(self.cause_now(&out, &raw, out.mode));
        }
        if out.mode != Mode::Init {
            self.report_transmitters();
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
                let reason = crate::events::cause::fallback_reason(
                    out.validity.fault[SensorId::OrificeDp.index()],
                )
                .unwrap_or(FallbackReason::Stale);
                // the drift check says by how much the transmitter is off, % of surge-line flow
                let v = self.core.dp_drift_check().verdict();
                let pct = |x: f64| {
                    (reason == FallbackReason::Drift && x.is_finite()).then_some(100.0 * x)
                };
                let replaced_by = if out.measurements.m_observer_kg_s.is_finite() {
                    Replacement::Observer
                } else {
                    Replacement::SpeedLine
                };
                self.fallback_replacement = replaced_by;
                self.push(FallbackEntered {
                    input: SensorId::OrificeDp,
                    reason,
                    replaced_by,
                    vs_observer_pct: pct(v.vs_observer),
                    vs_speed_line_pct: pct(v.vs_speed_line),
                });
                self.fallback_since_ns = Some(now);
            }
            (false, Some(since)) => {
                self.push(FallbackLeft {
                    input: SensorId::OrificeDp,
                    replaced_by: self.fallback_replacement,
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
        if out.esd_active != self.esd_active {
            self.esd_active = out.esd_active;
            if out.esd_active {
                // the hard-wired ESD / drive-trip contact opened the valve at full speed
                let mut cause = Cause::of(CauseKind::EsdInput);
                cause.input = Some(SensorId::EsdInput);
                cause.value = Some(raw.values.get(SensorId::EsdInput));
                self.push(RecycleTrip {
                    reason: TripReason::External,
                    cause: Some(cause),
                    criterion: None,
                });
            }
        }
        match out.law_event {
            Some(LawEvent::RecycleTrip {
                cause: criterion, ..
            }) => {
                let m = &out.measurements;
                let margin = self.core.model().surge_margin(m.flow_map, m.pressure_ratio);
                let trip = self.core.control_line().map(|(_, t)| 100.0 * t);
                let mut cause = Cause::of(CauseKind::SurgeMargin);
                cause.value = Some(100.0 * margin).filter(|v| v.is_finite());
                cause.min = trip;
                self.push(RecycleTrip {
                    reason: TripReason::FastApproach,
                    cause: Some(cause),
                    criterion: Some(criterion),
                })
            }
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
        self.publish_live(&out, &raw, tick.cycle, now);
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

    /// Report every redundant transmitter whose state changed (voted out and by which
    /// check, deviating, healthy again). Allocation-free.
    fn report_transmitters(&mut self) {
        let votes = self.core.vote().status();
        for (k, v) in votes.iter().enumerate() {
            if v.bound == 0 {
                continue;
            }
            for slot in 0..usize::from(v.bound) {
                let st = v.states[slot];
                if st == self.transmitters[k][slot] {
                    continue;
                }
                self.transmitters[k][slot] = st;
                if let Some(e) = crate::events::Transmitter::of(v, slot) {
                    self.push(e);
                }
            }
        }
    }

    /// Command the safe state and publish it with the shutdown mode code (SIGTERM/SIGINT).
    pub fn shutdown(&mut self, cycle: u64) -> ActuatorCommands {
        let cmd = self.core.safe_state();
        self.outputs.publish(&Outputs {
            commands: cmd,
            mode: Mode::Shutdown,
            law: self.core.law().code(),
            faults: 0,
            cycle,
            t_ns: crate::runtime::handoff::monotonic_ns(),
        });
        self.wake.signal();
        self.push(ModeChanged {
            from: self.prev_mode,
            to: Mode::Shutdown,
            cause: Some(Cause::of(CauseKind::Shutdown)),
        });
        cmd
    }
}
