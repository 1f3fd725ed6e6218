//! The simulation loop.

use super::stream::{PictureTrace, TailStats};
use super::summary::{
    verdict, ActuatorPeaks, ClosestApproach, FlowFallback, FlowSourceReport, Health,
    LawEventCounts, ModeEpisode, Summary,
};
use super::trace::{CsvTraceWriter, TraceRow};
use super::trace_handoff::{TraceHandoff, WrittenTrace};
use crate::control::core::{ControlCore, CoreSettings};
use crate::control::law::api::LawEvent;
use crate::control::measurements::{OperatorInputs, RawSensors};
use crate::control::supervisor::{InputFault, InputLimits};
use crate::control::LawId;
use crate::plant::file::PlantDescription;
use crate::plant::{PlantError, PlantInputs, SimPlant};
use crate::scenario::ScenarioState;
use crate::scenario::{NoiseSource, Scenario, SensorState, Timeline};
use crate::sim::case::PlantCase;
use crate::surge::{DetectorConfig, SurgeDetector};
use crate::vocab::signals::ActuatorCommands;
use crate::vocab::signals::{ActuatorId, SensorId, SensorSnapshot};
use crate::vocab::Mode;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimOptions {
    /// The surge law.
    pub law: LawId,
    /// Call the progress callback every this many control periods.
    pub progress_every: usize,
    /// Loop delay, control periods: a command computed from the sensors of period k acts from
    /// period k + delay on (0: at once, the ideal sampled loop). Models bus transfers and the
    /// drive's response, to check a tuning's delay margin.
    pub loop_delay_periods: usize,
    /// Extra random delay of 0..=this many periods per command (deterministic sequence); the
    /// plant applies the newest command that has arrived.
    pub loop_delay_jitter_periods: usize,
}

impl Default for SimOptions {
    fn default() -> Self {
        SimOptions {
            law: LawId::None,
            progress_every: 2000,
            loop_delay_periods: 0,
            loop_delay_jitter_periods: 0,
        }
    }
}

/// Commands on their way to the plant (the loop delay of [`SimOptions`]).
struct InFlight {
    /// (period it arrives, period it was computed, commands).
    queue: std::collections::VecDeque<(usize, usize, ActuatorCommands)>,
    applied: ActuatorCommands,
    applied_from: usize,
    rng: u64,
}

impl InFlight {
    fn new() -> Self {
        InFlight {
            queue: std::collections::VecDeque::with_capacity(64),
            applied: ActuatorCommands::default(),
            applied_from: 0,
            rng: 0x9E37_79B9_7F4A_7C15,
        }
    }

    /// Send `commands` computed in period `k`; return what the plant applies in period `k`.
    fn pass(&mut self, k: usize, commands: ActuatorCommands, o: &SimOptions) -> ActuatorCommands {
        if o.loop_delay_periods == 0 && o.loop_delay_jitter_periods == 0 {
            return commands;
        }
        let mut d = o.loop_delay_periods;
        if o.loop_delay_jitter_periods > 0 {
            // xorshift64: a fixed sequence, so runs repeat exactly
            self.rng ^= self.rng << 13;
            self.rng ^= self.rng >> 7;
            self.rng ^= self.rng << 17;
            d += (self.rng % (o.loop_delay_jitter_periods as u64 + 1)) as usize;
        }
        self.queue.push_back((k + d, k, commands));
        // the newest command that has arrived
        let mut i = 0;
        while i < self.queue.len() {
            match self.queue.get(i) {
                Some(&(arrive, from, c)) if arrive <= k => {
                    if from >= self.applied_from {
                        self.applied = c;
                        self.applied_from = from;
                    }
                    self.queue.remove(i);
                }
                _ => i += 1,
            }
        }
        self.applied
    }
}

/// What the operator (or the DCS) asks for at a scenario instant, the speed setpoint scaled
/// to the machine's nominal speed: the one mapping from a scenario to the control core's
/// operator inputs (sim, bench matrix, campaign).
pub fn operator_inputs(st: &ScenarioState, nominal_speed_rad_s: f64) -> OperatorInputs {
    OperatorInputs {
        speed_setpoint_rad_s: nominal_speed_rad_s * st.speed_setpoint,
        throttle_demand: st.throttle,
        flow_setpoint_kg_s: st.flow_setpoint_kg_s,
        recycle_manual: st.recycle_manual,
    }
}

/// Errors of a run.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The plant cannot start.
    #[error(transparent)]
    Plant(#[from] PlantError),
    /// The law cannot run on this plant.
    #[error(transparent)]
    Law(#[from] crate::control::law::api::LawError),
    /// A law named in the scenario does not exist.
    #[error("scenario `{scenario}`: {message}")]
    Scenario {
        /// Scenario name.
        scenario: String,
        /// What is wrong.
        message: String,
    },
    /// The streamed trace could not be written.
    #[error("{}: {source}", path.display())]
    Output {
        /// The file or directory.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
}

/// A finished run.
#[derive(Debug, Clone)]
pub struct SimResult {
    /// Trace rows.
    pub trace: Vec<TraceRow>,
    /// Summary.
    pub summary: Summary,
}

/// Apply scenario faults and noise to the plant's readings; returns raw sensors with ages and
/// sample numbers (`seq`: each transmitter's count of samples; a stale one sends none).
fn field_readings(
    t_s: f64,
    clean: &SensorSnapshot,
    faults: &[SensorState; SensorId::COUNT],
    noise: &[(f64, crate::scenario::Distribution); SensorId::COUNT],
    frozen: &mut SensorSnapshot,
    seq: &mut [u64; SensorId::COUNT],
    rng: &mut NoiseSource,
) -> RawSensors {
    let mut raw = RawSensors::fresh(*clean);
    for id in SensorId::ALL {
        let i = id.index();
        if !matches!(faults[i], SensorState::Stale { .. }) {
            seq[i] += 1;
        }
        raw.sample_seq[i] = seq[i];
        match faults[i] {
            SensorState::Ok => {
                let (amp, dist) = noise[i];
                let v = clean.values[i] + rng.sample(amp, dist);
                raw.values.values[i] = v;
                frozen.values[i] = v;
            }
            SensorState::Stale { since_s } => {
                raw.values.values[i] = frozen.values[i];
                raw.age_s[i] = t_s - since_s;
            }
            SensorState::Nan => raw.values.values[i] = f64::NAN,
            SensorState::Value(v) => raw.values.values[i] = v,
        }
    }
    raw
}

/// The most trace rows reserved at the start of a run kept in memory (about 80 s at the 5-ms
/// trace period); a longer trace grows as it is written. (Was 1 M rows: the longest allowed
/// scenario reserved, and under `mlockall` locked, 761 MB at start; issue 25.) A streamed run
/// ([`PlantRun::stream_to`], `antisurge sim`) keeps no trace at all.
pub const TRACE_PREALLOC_ROWS: usize = 1 << 14;

/// Where a run's trace rows go.
enum TraceSink {
    /// Kept whole in memory, returned in [`SimResult::trace`] (library runs, tests, campaign).
    Memory(Vec<TraceRow>),
    /// Written to `trace.csv` as they come, with a bounded picture of them.
    Stream(Box<StreamSink>),
    /// Handed to a writer thread that writes them to `trace.csv` (a plant stepped in real
    /// time: [`PlantRun::handing_trace_to`]).
    Handoff(TraceHandoff),
    /// Not kept.
    Off,
}

/// A streamed trace: the CSV writer and the picture.
struct StreamSink {
    csv: CsvTraceWriter<std::fs::File>,
    path: PathBuf,
    pictures: PictureTrace,
}

/// What a streamed run leaves besides its files: the rows its pictures are drawn from.
#[derive(Debug)]
pub struct StreamedTrace {
    /// The trace file written.
    pub path: PathBuf,
    /// Rows written to it.
    pub rows: u64,
    /// The bounded picture of the trace.
    pub pictures: PictureTrace,
}

/// The plant side of a run: the simulated plant under a scenario timeline, with field
/// readings (noise, faults), scoring of the true state (surge detection, margins, actuator
/// peaks, recycle energy) and the trace. `sim::run` pairs it with a control core in the same
/// loop; the plant node (`antisurge plant`) steps it in real time with setpoints from a bus.
pub struct PlantRun<'a> {
    desc: &'a PlantDescription,
    scenario: &'a Scenario,
    timeline: Timeline<'a>,
    inputs: PlantInputs,
    plant: SimPlant,
    detector: SurgeDetector,
    rng: NoiseSource,
    frozen: SensorSnapshot,
    /// Samples each transmitter has sent ([`RawSensors::sample_seq`]).
    sample_seq: [u64; SensorId::COUNT],
    peaks: ActuatorPeaks,
    min_flow: f64,
    min_margin: f64,
    recycle_energy: f64,
    last_recycle_pos: f64,
    law_events: LawEventCounts,
    trace: TraceSink,
    tail: TailStats,
    trace_every: usize,
    surge_margin: Box<dyn Fn(f64, f64) -> f64 + Send + 'a>,
    wall: Instant,
    health: HealthRecord,
}

/// Per-cycle bookkeeping for the verdict (fail-safe, saturation, plausibility, closest
/// approach, flow fallbacks).
struct HealthRecord {
    /// Plausible ranges of p_suction, p_discharge, ω (the controller's input limits).
    limits: [Option<InputLimits>; 3],
    /// Observed (min, max) of those three states.
    seen: [(f64, f64); 3],
    nonfinite_at_s: Option<f64>,
    cycles: u64,
    failsafe_cycles: u64,
    saturated_cycles: u64,
    failsafe_episodes: Vec<ModeEpisode>,
    approach: ClosestApproach,
    flow_source: FlowSourceReport,
    drive_tripped: bool,
    torque_limits_nm: (f64, f64),
    /// Surge cycles and reversals counted before the last event started (or, if a surge was
    /// running then, before it stopped).
    surge_before: Option<(u32, u32)>,
    /// When surge counting for the verdict started, s.
    counted_from_s: f64,
}

impl HealthRecord {
    fn new(limits: [Option<InputLimits>; 3], from_s: f64, torque_limits_nm: (f64, f64)) -> Self {
        HealthRecord {
            limits,
            seen: [(f64::INFINITY, f64::NEG_INFINITY); 3],
            nonfinite_at_s: None,
            cycles: 0,
            failsafe_cycles: 0,
            saturated_cycles: 0,
            failsafe_episodes: Vec::new(),
            approach: ClosestApproach {
                from_s,
                min_flow_kg_s: f64::INFINITY,
                min_flow_at_s: f64::NAN,
                min_surge_margin: f64::INFINITY,
                min_surge_margin_at_s: f64::NAN,
                min_throughput_kg_s: f64::INFINITY,
            },
            flow_source: FlowSourceReport {
                configured: "unknown (controller on the bus)".into(),
                fallbacks: Vec::new(),
            },
            drive_tripped: false,
            torque_limits_nm,
            surge_before: None,
            counted_from_s: f64::NAN,
        }
    }

    fn fault_words(f: InputFault) -> &'static str {
        match f {
            InputFault::None => "transmitter healthy",
            InputFault::Nan => "flow transmitter gives no value",
            InputFault::OutOfRange => "flow transmitter out of range",
            InputFault::Stale => "flow transmitter stale",
            InputFault::Frozen => {
                "flow transmitter (orifice_dp) frozen: no change while the pressures moved"
            }
            InputFault::Drift => {
                "flow transmitter (orifice_dp) drifting or biased: disagrees with the observer and the speed-line flow"
            }
        }
    }

    fn record(
        &mut self,
        t_s: f64,
        truth: &crate::plant::PlantTruth,
        margin: f64,
        c: &ActuatorCommands,
        view: &ControllerView,
    ) {
        self.cycles += 1;
        let states = [truth.p_suction_pa, truth.p_discharge_pa, truth.omega_rad_s];
        for (i, v) in states.into_iter().enumerate() {
            if v.is_finite() {
                self.seen[i].0 = self.seen[i].0.min(v);
                self.seen[i].1 = self.seen[i].1.max(v);
            } else if self.nonfinite_at_s.is_none() {
                self.nonfinite_at_s = Some(t_s);
            }
        }
        if !truth.m_kg_s.is_finite() && self.nonfinite_at_s.is_none() {
            self.nonfinite_at_s = Some(t_s);
        }
        // fail-safe episodes (mode code of the core)
        let failsafe = view.mode == f64::from(Mode::FailSafe.code());
        let open = self
            .failsafe_episodes
            .last()
            .is_some_and(|e| e.to_s.is_none());
        if failsafe {
            self.failsafe_cycles += 1;
            if !open {
                self.failsafe_episodes.push(ModeEpisode {
                    from_s: t_s,
                    to_s: None,
                });
            }
        } else if open {
            if let Some(e) = self.failsafe_episodes.last_mut() {
                e.to_s = Some(t_s);
            }
        }
        // saturation of the law's torque: the total command at a drive limit while the law
        // drives the torque (a tripped drive ignores commands)
        let tq = c.get(ActuatorId::DriveTorque);
        let law_drives_torque = view.law_torque_nm.is_finite() && view.law_torque_nm != 0.0;
        if law_drives_torque && tq.is_finite() && !self.drive_tripped {
            let (lo, hi) = self.torque_limits_nm;
            let tol = 1e-6 * hi.abs().max(1.0);
            if tq >= hi - tol || tq <= lo + tol {
                self.saturated_cycles += 1;
            }
        }
        // closest approach during and after the last event
        let a = &mut self.approach;
        if t_s >= a.from_s {
            if truth.m_kg_s < a.min_flow_kg_s {
                a.min_flow_kg_s = truth.m_kg_s;
                a.min_flow_at_s = t_s;
            }
            if margin.is_finite() && margin < a.min_surge_margin {
                a.min_surge_margin = margin;
                a.min_surge_margin_at_s = t_s;
            }
            if truth.throttle_flow_kg_s.is_finite() {
                a.min_throughput_kg_s = a.min_throughput_kg_s.min(truth.throttle_flow_kg_s);
            }
        }
        // flow fallbacks to the observer
        let fb = &mut self.flow_source.fallbacks;
        let open = fb.last().is_some_and(|f| f.to_s.is_none());
        if view.flow_fallback {
            if !open {
                fb.push(FlowFallback {
                    from_s: t_s,
                    to_s: None,
                    cause: Self::fault_words(view.orifice_fault).to_string(),
                    observer_max_error_kg_s: 0.0,
                    observer_max_error_fraction: 0.0,
                });
            }
            if let Some(f) = fb.last_mut() {
                let err = view.m_used_kg_s - truth.m_kg_s;
                if err.is_finite() && err.abs() > f.observer_max_error_kg_s.abs() {
                    f.observer_max_error_kg_s = err;
                    f.observer_max_error_fraction = err / truth.m_kg_s.abs().max(1e-9);
                }
            }
        } else if open {
            if let Some(f) = fb.last_mut() {
                f.to_s = Some(t_s);
            }
        }
    }

    /// States outside their plausible range, in words.
    fn implausible(&self) -> Vec<String> {
        let mut out = Vec::new();
        if let Some(t) = self.nonfinite_at_s {
            out.push(format!("states not finite from {t:.2} s (solver diverged)"));
        }
        let names = ["suction pressure", "discharge pressure", "speed"];
        let units = ["Pa", "Pa", "rad/s"];
        for i in 0..3 {
            let Some(lim) = self.limits[i] else { continue };
            let (lo, hi) = self.seen[i];
            if hi > lim.max {
                out.push(format!(
                    "{} out of range (max {:.4e} {}, plausible ≤ {:.4e})",
                    names[i], hi, units[i], lim.max
                ));
            } else if lo < lim.min {
                out.push(format!(
                    "{} out of range (min {:.4e} {}, plausible ≥ {:.4e})",
                    names[i], lo, units[i], lim.min
                ));
            }
        }
        out
    }
}

/// What the controller side reports for the trace (NaN where unknown, e.g. over a bus).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControllerView {
    /// Flow from the orifice, kg/s.
    pub m_measured_kg_s: f64,
    /// Observer estimate, kg/s.
    pub m_observer_kg_s: f64,
    /// Flow the law used, kg/s.
    pub m_used_kg_s: f64,
    /// Mode code.
    pub mode: f64,
    /// Law diagnostic.
    pub law_diagnostic: f64,
    /// Whether the flow came from the observer because the transmitter failed.
    pub flow_fallback: bool,
    /// The flow transmitter's fault as the supervisor saw it.
    pub orifice_fault: InputFault,
    /// The law's own torque command (on top of the speed loop), N·m; NaN if none.
    pub law_torque_nm: f64,
}

impl ControllerView {
    /// Nothing known about the controller's internals.
    pub const UNKNOWN: ControllerView = ControllerView {
        m_measured_kg_s: f64::NAN,
        m_observer_kg_s: f64::NAN,
        m_used_kg_s: f64::NAN,
        mode: f64::NAN,
        law_diagnostic: f64::NAN,
        flow_fallback: false,
        orifice_fault: InputFault::None,
        law_torque_nm: f64::NAN,
    };
}

impl ControllerView {
    /// What the trace records of one control cycle's output.
    pub fn of(out: &crate::control::core::CycleOutput) -> ControllerView {
        let m = &out.measurements;
        ControllerView {
            m_measured_kg_s: m.m_measured_kg_s,
            m_observer_kg_s: m.m_observer_kg_s,
            m_used_kg_s: m.m_kg_s,
            mode: f64::from(out.mode.code()),
            law_diagnostic: out.law_diagnostic,
            flow_fallback: m.flow_fallback,
            orifice_fault: out.validity.fault[SensorId::OrificeDp.index()],
            law_torque_nm: out.law_torque_nm,
        }
    }
}

impl<'a> PlantRun<'a> {
    /// Start the plant at the scenario's initial state.
    pub fn new(desc: &'a PlantDescription, scenario: &'a Scenario) -> Result<Self, SimError> {
        Self::build(desc, scenario, None)
    }

    /// [`PlantRun::new`] with the trace rows handed to a writer thread as they come instead of
    /// kept ([`super::trace_handoff::TraceWriter`]): for a plant stepped in real time, whose
    /// thread must not write files. No trace store is reserved. [`PlantRun::close_handoff`]
    /// ends the handoff, [`PlantRun::finish_written`] makes the result with the writer's
    /// settle log.
    pub fn handing_trace_to(
        desc: &'a PlantDescription,
        scenario: &'a Scenario,
        handoff: TraceHandoff,
    ) -> Result<Self, SimError> {
        Self::build(desc, scenario, Some(TraceSink::Handoff(handoff)))
    }

    fn build(
        desc: &'a PlantDescription,
        scenario: &'a Scenario,
        trace: Option<TraceSink>,
    ) -> Result<Self, SimError> {
        let init = desc.file.initial;
        let timeline = Timeline::new(scenario, init.throttle, init.recycle_valve, init.feed);
        let st0 = timeline.initial();
        let inputs = PlantInputs {
            throttle_process: st0.throttle,
            recycle_manual: st0.recycle_manual,
            feed: st0.feed,
            ..PlantInputs::default()
        };
        let plant = SimPlant::new(desc, &inputs)?;
        // the plant side scores against the machine only (surge margin, supervisor limits);
        // the controller settings are not read here
        let model = crate::control::model::ControlModel::from_machine(
            &desc.machine(),
            crate::control::ControllerConfig::default(),
        );
        let t0_torque = plant.truth().load_torque_nm;
        let dt = scenario.file.control_period_s;
        let n_steps = (scenario.file.duration_s / dt).round() as usize;
        let trace_every = trace_every(scenario);
        let frozen = plant.sensors();
        let last_recycle_pos = plant.truth().recycle_valve_position;
        let sup = CoreSettings::defaults_for(&model).supervisor;
        let last_event_start_s = scenario.actions.iter().map(|(t, _)| *t).fold(0.0, f64::max);
        let health = HealthRecord::new(
            [
                sup.limits[SensorId::PSuction.index()],
                sup.limits[SensorId::PDischarge.index()],
                sup.limits[SensorId::ShaftSpeed.index()],
            ],
            last_event_start_s,
            (
                desc.file.drive.min_torque_nm,
                desc.file.drive.rated_torque_nm,
            ),
        );
        Ok(PlantRun {
            desc,
            scenario,
            timeline,
            inputs,
            plant,
            detector: SurgeDetector::new(DetectorConfig::default()),
            rng: NoiseSource::new(scenario.file.seed),
            frozen,
            sample_seq: [0; SensorId::COUNT],
            peaks: ActuatorPeaks {
                drive_torque_rating_nm: desc.file.drive.rated_torque_nm,
                nominal_load_torque_nm: t0_torque,
                ccv_rating: desc.file.spool.map_or(f64::NAN, |s| s.ccv_max),
                tip_clearance_nominal_m: desc
                    .file
                    .thrust_rating
                    .map_or(f64::NAN, |t| t.nominal_clearance_m),
                thrust_force_rating_n: desc.file.thrust_rating.map_or(f64::NAN, |t| t.force_max_n),
                thrust_slew_rating_n_s: desc
                    .file
                    .thrust_rating
                    .map_or(f64::NAN, |t| t.slew_max_n_s),
                drive_torque_cmd_range_nm: (f64::INFINITY, f64::NEG_INFINITY),
                ..Default::default()
            },
            min_flow: f64::INFINITY,
            min_margin: f64::INFINITY,
            recycle_energy: 0.0,
            last_recycle_pos,
            law_events: LawEventCounts::default(),
            // preallocation bounded (TRACE_PREALLOC_ROWS); a longer trace grows as it is
            // written, so a day-long scenario does not lock its whole trace at start
            trace: trace.unwrap_or_else(|| {
                TraceSink::Memory(Vec::with_capacity(
                    (n_steps / trace_every + 2).min(TRACE_PREALLOC_ROWS),
                ))
            }),
            tail: TailStats::new(scenario.last_event_s(), trace_every as f64 * dt),
            trace_every,
            surge_margin: Box::new(move |q, r| model.surge_margin(q, r)),
            wall: Instant::now(),
            health,
        })
    }

    /// Keep no trace rows (scores and health are still kept): for a run whose trace is never
    /// written, such as the daemon's in-process plant without an output directory.
    pub fn without_trace(mut self) -> Self {
        self.trace = TraceSink::Off;
        self.trace_every = usize::MAX;
        self
    }

    /// Stream the trace to `dir/trace.csv` (created, the directory too) as the run goes
    /// instead of keeping it: memory bounded whatever the run's length (the summary comes from
    /// running statistics, the pictures from a bounded [`PictureTrace`], the settle time from
    /// a log in an unnamed file in `dir`). `volumetric`: the map's flow coordinate is inlet
    /// volume flow (the file's last column). [`PlantRun::close_trace`] finishes the file.
    pub fn stream_to(mut self, dir: &Path, volumetric: bool) -> Result<Self, SimError> {
        let (file, path) = super::stream::open_trace(dir, &mut self.tail)?;
        self.trace = TraceSink::Stream(Box::new(StreamSink {
            csv: CsvTraceWriter::new(file, volumetric),
            path,
            // the rows of the whole run: n_steps + 1 steps, one row every trace_every
            pictures: PictureTrace::with_rows(self.n_steps() / self.trace_every + 1),
        }));
        Ok(self)
    }

    /// End the handoff of [`PlantRun::handing_trace_to`] (the writer thread then writes the last
    /// rows and ends): the rows dropped because its queue was full. `None` for a run whose
    /// trace is not handed over.
    pub fn close_handoff(&mut self) -> Option<u64> {
        match std::mem::replace(&mut self.trace, TraceSink::Off) {
            TraceSink::Handoff(h) => Some(h.dropped()),
            other => {
                self.trace = other;
                None
            }
        }
    }

    /// The result of a run whose trace was handed to a writer thread
    /// ([`PlantRun::handing_trace_to`]), labelled with the law's name: the settle time from the
    /// writer's settle log, the rows it dropped in the summary.
    pub fn finish_written(&self, law: &str, written: &WrittenTrace) -> Result<SimResult, SimError> {
        let (mut result, error) = self.summarize_with(law, Some(&written.tail));
        match error {
            Some(SimError::Output { source, .. }) => {
                return Err(SimError::Output {
                    path: written.path.clone(),
                    source,
                })
            }
            Some(e) => return Err(e),
            None => {}
        }
        result.summary.trace_rows_dropped = Some(written.dropped);
        Ok(result)
    }

    /// Finish a streamed trace ([`PlantRun::stream_to`]): the file flushed, and what the
    /// pictures are drawn from. `None` for a run whose trace is not streamed.
    pub fn close_trace(&mut self) -> Result<Option<StreamedTrace>, SimError> {
        let TraceSink::Stream(s) = std::mem::replace(&mut self.trace, TraceSink::Off) else {
            return Ok(None);
        };
        let StreamSink {
            csv,
            path,
            pictures,
        } = *s;
        let rows = csv.rows();
        let file = csv.finish().map_err(|source| SimError::Output {
            path: path.clone(),
            source,
        })?;
        drop(file);
        Ok(Some(StreamedTrace {
            path,
            rows,
            pictures,
        }))
    }

    /// The plant.
    pub fn plant(&self) -> &SimPlant {
        &self.plant
    }

    /// The scenario.
    pub fn scenario(&self) -> &Scenario {
        self.scenario
    }

    /// Control period of the scenario, s.
    pub fn dt_s(&self) -> f64 {
        self.scenario.file.control_period_s
    }

    /// Number of steps of the scenario.
    pub fn n_steps(&self) -> usize {
        (self.scenario.file.duration_s / self.dt_s()).round() as usize
    }

    /// Name the controller's configured flow source (for the summary).
    pub fn set_flow_source(&mut self, name: &str) {
        self.health.flow_source.configured = name.to_string();
    }

    /// Scenario state at `t_s` and the field readings (noise, faults) of the plant now.
    pub fn sense(&mut self, t_s: f64) -> (ScenarioState, RawSensors) {
        let st = self.timeline.state_at(t_s);
        self.health.drive_tripped = st.drive_tripped;
        let mut clean = self.plant.sensors();
        // the drive-trip / ESD contact of the skid: closed while the drive is tripped
        clean.set(SensorId::EsdInput, f64::from(u8::from(st.drive_tripped)));
        let raw = field_readings(
            t_s,
            &clean,
            &st.faults,
            &st.noise,
            &mut self.frozen,
            &mut self.sample_seq,
            &mut self.rng,
        );
        (st, raw)
    }

    /// Count a law event (for the summary).
    pub fn count_law_event(&mut self, e: LawEvent) {
        match e {
            LawEvent::RecycleTrip { .. } => self.law_events.recycle_trips += 1,
            LawEvent::SafetyOnShift {
                total_margin,
                count: _,
            } => {
                self.law_events.safety_on_shifts += 1;
                self.law_events.safety_on_total_margin = total_margin;
            }
        }
    }

    /// Score the true state at step `k` (time `t_s`, step `dt_s`) under `commands`, and add a
    /// trace row every trace period.
    pub fn record(
        &mut self,
        k: usize,
        t_s: f64,
        dt_s: f64,
        raw: &RawSensors,
        c: &ActuatorCommands,
        view: &ControllerView,
    ) {
        let truth = self.plant.truth();
        // surge counts from the last event on; a surge already running then (a rescue
        // scenario) counts from the moment it stopped
        if self.health.surge_before.is_none()
            && t_s >= self.health.approach.from_s
            && !self.detector.in_surge()
        {
            self.health.surge_before = Some((self.detector.surge_cycles, self.detector.reversals));
            self.health.counted_from_s = t_s;
        }
        self.detector.update(t_s, dt_s, truth.m_kg_s);
        self.min_flow = self.min_flow.min(truth.m_kg_s);
        let margin = (self.surge_margin)(truth.flow_map, truth.pressure_ratio());
        if margin.is_finite() {
            self.min_margin = self.min_margin.min(margin);
        }
        if truth.recycle_flow_kg_s > 0.0 {
            let head = self
                .desc
                .file
                .gas
                .polytropic_head_j_kg(truth.t_suction_k, truth.pressure_ratio());
            self.recycle_energy += truth.recycle_flow_kg_s * head * dt_s;
        }
        let peaks = &mut self.peaks;
        let absmax = |a: &mut f64, v: f64| {
            if v.is_finite() {
                *a = a.max(v.abs())
            }
        };
        absmax(
            &mut peaks.drive_torque_cmd_nm,
            c.get(ActuatorId::DriveTorque),
        );
        absmax(&mut peaks.drive_torque_nm, truth.drive_torque_nm);
        absmax(&mut peaks.law_drive_torque_nm, view.law_torque_nm);
        let tq = c.get(ActuatorId::DriveTorque);
        if tq.is_finite() {
            let r = &mut peaks.drive_torque_cmd_range_nm;
            *r = (r.0.min(tq), r.1.max(tq));
        }
        absmax(
            &mut peaks.recycle_valve_opening,
            c.get(ActuatorId::RecycleValve),
        );
        absmax(&mut peaks.ccv, c.get(ActuatorId::CloseCoupledValve));
        absmax(
            &mut peaks.tip_clearance_cmd_m,
            c.get(ActuatorId::TipClearance),
        );
        absmax(&mut peaks.tip_clearance_m, truth.tip_clearance_m);
        absmax(&mut peaks.thrust_force_n, truth.thrust_force_n);
        absmax(&mut peaks.thrust_slew_n_s, truth.thrust_slew_n_s);
        if k > 0 && truth.recycle_valve_position.is_finite() && dt_s > 0.0 {
            let rate = (self.last_recycle_pos - truth.recycle_valve_position) / dt_s;
            peaks.recycle_valve_closing_rate_per_s =
                peaks.recycle_valve_closing_rate_per_s.max(rate);
        }
        self.last_recycle_pos = truth.recycle_valve_position;
        self.health.record(t_s, &truth, margin, c, view);

        if k.is_multiple_of(self.trace_every) {
            let row = TraceRow {
                t_s,
                m_kg_s: truth.m_kg_s,
                flow_map: truth.flow_map,
                p_suction_pa: truth.p_suction_pa,
                p_discharge_pa: truth.p_discharge_pa,
                pressure_ratio: truth.pressure_ratio(),
                omega_rad_s: truth.omega_rad_s,
                recycle_flow_kg_s: truth.recycle_flow_kg_s,
                throttle_flow_kg_s: truth.throttle_flow_kg_s,
                feed_flow_kg_s: truth.feed_flow_kg_s,
                recycle_valve_position: truth.recycle_valve_position,
                throttle_position: truth.throttle_position,
                drive_torque_nm: truth.drive_torque_nm,
                load_torque_nm: truth.load_torque_nm,
                ccv: truth.ccv,
                tip_clearance_m: truth.tip_clearance_m,
                thrust_force_n: truth.thrust_force_n,
                thrust_slew_n_s: truth.thrust_slew_n_s,
                surge_margin: margin,
                meas_p_suction_pa: raw.values.get(SensorId::PSuction),
                meas_p_discharge_pa: raw.values.get(SensorId::PDischarge),
                meas_omega_rad_s: raw.values.get(SensorId::ShaftSpeed),
                meas_orifice_dp_pa: raw.values.get(SensorId::OrificeDp),
                meas_m_kg_s: view.m_measured_kg_s,
                est_m_kg_s: view.m_observer_kg_s,
                used_m_kg_s: view.m_used_kg_s,
                cmd_drive_torque_nm: c.get(ActuatorId::DriveTorque),
                cmd_recycle_valve: c.get(ActuatorId::RecycleValve),
                cmd_ccv: c.get(ActuatorId::CloseCoupledValve),
                cmd_throttle: c.get(ActuatorId::Throttle),
                cmd_tip_clearance_m: c.get(ActuatorId::TipClearance),
                mode: view.mode,
                law_diagnostic: view.law_diagnostic,
            };
            self.tail.push(&row);
            match &mut self.trace {
                TraceSink::Memory(rows) => rows.push(row),
                TraceSink::Stream(s) => {
                    s.csv.push(&row);
                    s.pictures.push(&row);
                }
                TraceSink::Handoff(h) => h.push(&row),
                TraceSink::Off => {}
            }
        }
    }

    /// Advance the plant by `dt_s` under the scenario state `st` and `commands` (NaN: the
    /// actuator is not driven by the controller).
    pub fn advance(&mut self, st: &ScenarioState, commands: &ActuatorCommands, dt_s: f64) {
        self.inputs.commands = *commands;
        self.inputs.throttle_process = st.throttle;
        self.inputs.recycle_manual = st.recycle_manual;
        self.inputs.feed = st.feed;
        self.inputs.downstream = st.downstream;
        self.inputs.drive_tripped = st.drive_tripped;
        self.plant.step(&self.inputs, dt_s);
    }

    /// The result so far, labelled with the law's name. Its trace is empty when the trace is
    /// streamed or not kept. An error only if a streamed run's settle log cannot be read back.
    pub fn try_finish(&self, law: &str) -> Result<SimResult, SimError> {
        match self.summarize(law) {
            (r, None) => Ok(r),
            (_, Some(e)) => Err(e),
        }
    }

    /// The result so far, labelled with the law's name: [`PlantRun::try_finish`] for a run
    /// whose trace is kept in memory or not at all, which cannot fail (a streamed run whose
    /// settle log cannot be read back gets no settle time).
    pub fn finish(&self, law: &str) -> SimResult {
        self.summarize(law).0
    }

    fn summarize(&self, law: &str) -> (SimResult, Option<SimError>) {
        self.summarize_with(law, None)
    }

    /// The result; the settle time from `written` (a trace handed to a writer thread), else
    /// from the run's own tail and trace.
    fn summarize_with(
        &self,
        law: &str,
        written: Option<&TailStats>,
    ) -> (SimResult, Option<SimError>) {
        let wall_s = self.wall.elapsed().as_secs_f64();
        let trace: &[TraceRow] = match &self.trace {
            TraceSink::Memory(rows) => rows,
            _ => &[],
        };
        let last = self.tail.last().unwrap_or_default();
        let duration = self.tail.last().map_or(0.0, |r| r.t_s);
        let window = (0.25 * duration).clamp(1.0, 3.0);
        let steady = self.tail.is_steady(window, 0.02, 1e-4) && !self.detector.in_surge();
        let h = &self.health;
        let cycles = h.cycles.max(1) as f64;
        let failsafe_fraction = h.failsafe_cycles as f64 / cycles;
        let torque_saturation_fraction = h.saturated_cycles as f64 / cycles;
        let implausible = h.implausible();
        let surge_frequency_hz = self
            .detector
            .frequency_hz
            .is_finite()
            .then_some(self.detector.frequency_hz);
        let (cycles_before, reversals_before) = h.surge_before.unwrap_or((0, 0));
        let (stable, mut verdict_words) = verdict(&Health {
            surge_cycles: self.detector.surge_cycles - cycles_before,
            surge_frequency_hz,
            flow_reversals: self.detector.reversals - reversals_before,
            steady,
            failsafe_fraction,
            torque_saturation_fraction,
            implausible: &implausible,
        });
        if stable && (cycles_before > 0 || reversals_before > 0) {
            verdict_words = if h.counted_from_s > h.approach.from_s + 1e-9 {
                format!(
                    "STABLE — the surge running at the last event ({:.2} s) stopped at {:.2} s, \
                     none after ({} cycles in all)",
                    h.approach.from_s, h.counted_from_s, cycles_before
                )
            } else {
                format!(
                    "STABLE — no surge from {:.2} s (the last event); {} surge cycles before",
                    h.approach.from_s, cycles_before
                )
            };
        }
        let mut peaks = self.peaks;
        if !peaks.drive_torque_cmd_range_nm.0.is_finite() {
            peaks.drive_torque_cmd_range_nm = (f64::NAN, f64::NAN);
        }
        let mut error = None;
        let settle = if stable {
            written
                .unwrap_or(&self.tail)
                .settle_time(trace, 0.02, 1e-4)
                .unwrap_or_else(|source| {
                    error = Some(SimError::Output {
                        path: match &self.trace {
                            TraceSink::Stream(s) => s.path.clone(),
                            _ => PathBuf::new(),
                        },
                        source,
                    });
                    None
                })
        } else {
            None
        };
        let summary = Summary {
            plant: self.desc.name().to_string(),
            scenario: self.scenario.name().to_string(),
            law: law.to_string(),
            duration_s: duration,
            stable,
            verdict: verdict_words,
            failsafe_fraction,
            failsafe_episodes: h.failsafe_episodes.clone(),
            torque_saturation_fraction,
            implausible,
            closest_approach: h.approach,
            flow_source: h.flow_source.clone(),
            flow_reversal: self.detector.reversals > 0,
            flow_reversals: self.detector.reversals,
            surge_cycles: self.detector.surge_cycles,
            surge_frequency_hz,
            min_flow_kg_s: self.min_flow,
            final_flow_kg_s: last.m_kg_s,
            final_pressure_ratio: last.pressure_ratio,
            min_surge_margin: self.min_margin,
            final_surge_margin: last.surge_margin,
            settle_time_s: settle,
            recycle_energy_j: self.recycle_energy,
            actuator_peaks: peaks,
            law_events: self.law_events,
            wall_time_s: wall_s,
            realtime_factor: duration / wall_s.max(1e-9),
            field_failsafe_entries: None,
            device_watchdog: None,
            trace_rows_dropped: None,
        };
        (
            SimResult {
                trace: trace.to_vec(),
                summary,
            },
            error,
        )
    }
}

/// Control steps between two trace rows of `scenario` (its trace period rounded to whole
/// control periods, at least one).
fn trace_every(scenario: &Scenario) -> usize {
    ((scenario.file.trace_period_s / scenario.file.control_period_s).round() as usize).max(1)
}

/// Time between two trace rows of `scenario`, s: its trace period rounded to whole control
/// periods.
pub fn trace_period_s(scenario: &Scenario) -> f64 {
    trace_every(scenario) as f64 * scenario.file.control_period_s
}

/// Run a scenario on a plant with a law. `progress` receives the completed fraction.
pub fn run(
    desc: &PlantCase,
    scenario: &Scenario,
    options: SimOptions,
    progress: &mut dyn FnMut(f64),
) -> Result<SimResult, SimError> {
    run_with(desc, scenario, options, progress, &mut |_, _| {})
}

/// [`run`], calling `before_cycle(t_s, core)` before every control cycle: what an operator or
/// the daemon does to a running controller (hot reload, law switch) can be replayed at an
/// exact time.
pub fn run_with(
    desc: &PlantCase,
    scenario: &Scenario,
    options: SimOptions,
    progress: &mut dyn FnMut(f64),
    before_cycle: &mut dyn FnMut(f64, &mut ControlCore),
) -> Result<SimResult, SimError> {
    run_with_model(
        desc,
        crate::sim::control_model(desc),
        scenario,
        options,
        progress,
        before_cycle,
    )
}

/// [`run_with`] with the controller's model given separately from the simulated plant: a
/// machine description (`antisurge sim --machine`) the controller runs on while the plant file
/// simulates the skid. The model's `controller` settings are the controller's defaults.
pub fn run_with_model(
    desc: &PlantDescription,
    model: crate::control::model::ControlModel,
    scenario: &Scenario,
    options: SimOptions,
    progress: &mut dyn FnMut(f64),
    before_cycle: &mut dyn FnMut(f64, &mut ControlCore),
) -> Result<SimResult, SimError> {
    let mut pr = PlantRun::new(desc, scenario)?;
    let law = drive(&mut pr, model, scenario, options, progress, before_cycle)?;
    let mut result = pr.finish(law.name());
    result.summary.duration_s = scenario.file.duration_s;
    Ok(result)
}

/// [`run_with_model`] with the trace streamed to `dir/trace.csv` as the run goes
/// ([`PlantRun::stream_to`]; the bytes [`super::output::write_data`] writes of a kept trace):
/// the run's memory does not grow with its length. Returns the summary and what the pictures
/// are drawn from. On error the partial trace file is removed.
pub fn run_streamed(
    desc: &PlantDescription,
    model: crate::control::model::ControlModel,
    scenario: &Scenario,
    options: SimOptions,
    dir: &Path,
    progress: &mut dyn FnMut(f64),
    before_cycle: &mut dyn FnMut(f64, &mut ControlCore),
) -> Result<(super::Summary, StreamedTrace), SimError> {
    let volumetric =
        desc.map.flow_coordinate == crate::physics::compressor_map::FlowCoordinate::InletVolumeM3S;
    let mut pr = PlantRun::new(desc, scenario)?.stream_to(dir, volumetric)?;
    let run = drive(&mut pr, model, scenario, options, progress, before_cycle)
        .and_then(|law| pr.try_finish(law.name()))
        .and_then(|r| Ok((r.summary, pr.close_trace()?)));
    match run {
        Ok((mut summary, Some(trace))) => {
            summary.duration_s = scenario.file.duration_s;
            Ok((summary, trace))
        }
        Ok((_, None)) => unreachable!("a streamed run has a streamed trace"),
        Err(e) => {
            let _ = pr.close_trace();
            let _ = std::fs::remove_file(dir.join("trace.csv"));
            Err(e)
        }
    }
}

/// Run the control core against `pr` over the whole scenario; returns the law it ended with.
fn drive(
    pr: &mut PlantRun<'_>,
    model: crate::control::model::ControlModel,
    scenario: &Scenario,
    options: SimOptions,
    progress: &mut dyn FnMut(f64),
    before_cycle: &mut dyn FnMut(f64, &mut ControlCore),
) -> Result<LawId, SimError> {
    let settings = CoreSettings::defaults_for(&model);
    let nominal_speed = model.drive.nominal_speed_rad_s;
    let t0_torque = pr.plant().truth().load_torque_nm;
    let config = model.controller.clone();
    let flow_source = serde_json::to_value(config.flow_source)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default();
    pr.set_flow_source(&flow_source);
    let mut core = ControlCore::new(model, config, settings, options.law, t0_torque)?;
    let law_ids: Vec<LawId> = scenario
        .law_names
        .iter()
        .map(|n| {
            LawId::parse_sim(n).map_err(|e| SimError::Scenario {
                scenario: scenario.name().to_string(),
                message: e.to_string(),
            })
        })
        .collect::<Result<_, _>>()?;

    let dt = pr.dt_s();
    let n_steps = pr.n_steps();
    let mut in_flight = InFlight::new();
    for k in 0..=n_steps {
        let t = k as f64 * dt;
        let (st, raw) = pr.sense(t);
        if let Some(i) = st.law_request {
            // the daemon's transactional path: build off the cycle, swap in at its boundary
            if law_ids[i] != core.law() {
                let r = ControlCore::prepare(core.model(), core.config().clone(), law_ids[i])?;
                let _replaced = core.commit(r);
            }
        }
        if let Some(auto) = st.mode_request {
            core.request_auto(auto);
        }
        let op = operator_inputs(&st, nominal_speed);
        before_cycle(t, &mut core);
        let out = core.cycle(t, &raw, &op);
        if let Some(e) = out.law_event {
            pr.count_law_event(e);
        }
        let view = ControllerView::of(&out);
        pr.record(k, t, dt, &raw, &out.commands, &view);
        if k == n_steps {
            break;
        }
        let applied = in_flight.pass(k, out.commands, &options);
        pr.advance(&st, &applied, dt);
        if options.progress_every > 0 && k.is_multiple_of(options.progress_every) {
            progress(k as f64 / n_steps as f64);
        }
    }
    progress(1.0);
    Ok(core.law())
}
