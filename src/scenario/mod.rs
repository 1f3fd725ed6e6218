//! Scenarios: a timeline of events (`config/scenarios/*.toml`) that drives the process side of a
//! simulation: throttle and feed changes, speed setpoint ramps, drive trips, sensor noise and
//! transmitter failures, operator law/mode changes.
//!
//! Evaluation is allocation-free: [`Timeline::state_at`] walks pre-sorted events.

use crate::config::FileError;
use crate::vocab::signals::SensorId;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Longest scenario, s (one day). The in-memory trace grows with the duration (1e7 s used to
/// abort allocating 528 GB); soak tests longer than this run as consecutive scenarios.
pub const MAX_DURATION_S: f64 = 86_400.0;

/// Process quantities an event can change.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Signal {
    /// Throttle opening, fraction 0..1.
    Throttle,
    /// Feed as a fraction of nominal (mass-flow feed) or feed-valve opening.
    Feed,
    /// Speed setpoint as a fraction of the nominal speed.
    SpeedSetpoint,
    /// Downstream header pressure as a fraction of nominal.
    DownstreamPressure,
    /// Mass-flow setpoint for flow-tracking laws, kg/s.
    FlowSetpointKgS,
    /// Recycle valve opening from the manual station, fraction.
    RecycleManual,
}

/// Linear change of a signal.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ramp {
    /// What changes.
    pub signal: Signal,
    /// Final value.
    pub to: f64,
    /// Duration, s (> 0).
    pub over_s: f64,
}

/// Instant change of a signal.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Step {
    /// What changes.
    pub signal: Signal,
    /// New value.
    pub to: f64,
}

/// Noise distribution.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Distribution {
    /// Uniform on [−amplitude, +amplitude] ("zero mean white noise with an amplitude of 5000 Pa",
    /// seed 000 §6.3, read literally).
    #[default]
    Uniform,
    /// Gaussian with standard deviation = amplitude.
    Gaussian,
}

/// White measurement noise on sensors.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Noise {
    /// Sensors affected.
    pub sensors: Vec<SensorId>,
    /// Amplitude in each sensor's SI unit (Pa for pressures); 0 switches the noise off.
    pub amplitude: f64,
    /// Distribution.
    #[serde(default)]
    pub distribution: Distribution,
}

/// How a transmitter fails.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// Stops updating (the reading goes stale; a bus would stop sending it).
    Stale,
    /// Reports NaN (an invalid reading, e.g. a failed A/D conversion).
    Nan,
    /// Reports a fixed value (e.g. 0 for a broken loop, or a saturated 21 mA reading).
    Value,
    /// Back to normal.
    Restore,
}

/// A transmitter failure (or its repair).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorFault {
    /// Which sensor.
    pub sensor: SensorId,
    /// How it fails.
    pub fault: FaultKind,
    /// The value reported by `fault = "value"`, sensor SI unit.
    #[serde(default)]
    pub value: f64,
}

/// One timeline entry: at `at_s`, exactly one action.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Event {
    /// Time, s from the start.
    pub at_s: f64,
    /// Linear change.
    #[serde(default)]
    pub ramp: Option<Ramp>,
    /// Instant change.
    #[serde(default)]
    pub step: Option<Step>,
    /// Emergency shutdown: the drive trips (no torque from then on).
    #[serde(default)]
    pub drive_trip: Option<bool>,
    /// Start (or change) measurement noise.
    #[serde(default)]
    pub noise: Option<Noise>,
    /// Transmitter failure or repair.
    #[serde(default)]
    pub sensor_fault: Option<SensorFault>,
    /// Operator switches the active law (by name, e.g. "recycle-pi").
    #[serde(default)]
    pub law: Option<String>,
    /// Operator switches the controller mode: "auto" or "manual".
    #[serde(default)]
    pub mode: Option<String>,
}

/// Initial process values (override the plant file's).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct ScenarioInitial {
    /// Throttle opening.
    pub throttle: Option<f64>,
    /// Recycle valve manual opening.
    pub recycle_valve: Option<f64>,
    /// Feed fraction.
    pub feed: Option<f64>,
    /// Flow setpoint for flow-tracking laws, kg/s.
    pub flow_setpoint_kg_s: Option<f64>,
}

/// A scenario file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioFile {
    /// Short name.
    pub name: String,
    /// What it reproduces.
    pub description: String,
    /// Length of the run, s.
    pub duration_s: f64,
    /// Control period, s (default 0.001: 1 kHz).
    #[serde(default = "default_period")]
    pub control_period_s: f64,
    /// Trace sampling period, s (default 0.005).
    #[serde(default = "default_trace_period")]
    pub trace_period_s: f64,
    /// Seed of the noise generator (runs are reproducible).
    #[serde(default)]
    pub seed: u64,
    /// Initial values.
    #[serde(default)]
    pub initial: ScenarioInitial,
    /// The timeline.
    #[serde(default, rename = "event")]
    pub events: Vec<Event>,
}

fn default_period() -> f64 {
    0.001
}
fn default_trace_period() -> f64 {
    0.005
}

/// What an event does, validated.
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    /// Linear change.
    Ramp(Ramp),
    /// Instant change.
    Step(Step),
    /// Drive trip.
    DriveTrip,
    /// Noise (index into the noise table).
    Noise(usize),
    /// Sensor fault.
    SensorFault(SensorFault),
    /// Law switch (index into the law-name table).
    Law(usize),
    /// Mode switch: true = auto, false = manual.
    Mode(bool),
}

/// A loaded, validated scenario.
#[derive(Debug, Clone)]
pub struct Scenario {
    /// Parsed file.
    pub file: ScenarioFile,
    /// Where it came from.
    pub path: PathBuf,
    /// Events sorted by time.
    pub actions: Vec<(f64, Action)>,
    /// Noise definitions referenced by [`Action::Noise`].
    pub noises: Vec<Noise>,
    /// Law names referenced by [`Action::Law`].
    pub law_names: Vec<String>,
}

impl Scenario {
    /// Load and validate; errors name file, key and line.
    pub fn load(path: &Path) -> Result<Scenario, FileError> {
        let (file, text): (ScenarioFile, String) = crate::config::toml_file::load(path)?;
        Self::from_file(file, path, &text)
    }

    /// Parse and validate scenario `text` already in memory; `path` names it in messages.
    /// Same checks as [`load`](Self::load) (the fuzz target `scenario_file` uses it).
    pub fn from_text(text: &str, path: &Path) -> Result<Scenario, FileError> {
        let file: ScenarioFile = crate::config::toml_file::parse(text, path)?;
        Self::from_file(file, path, text)
    }

    /// Validate a parsed file (`text` is used to locate keys in messages).
    ///
    /// `duration_s` is bounded by [`MAX_DURATION_S`]: the trace's memory follows from it.
    pub fn from_file(file: ScenarioFile, path: &Path, text: &str) -> Result<Scenario, FileError> {
        let at = |key: &str, msg: String| FileError::at_key(path, text, key, msg);
        if !(file.duration_s > 0.0 && file.duration_s <= MAX_DURATION_S) {
            return Err(at(
                "duration_s",
                format!(
                    "must be positive and at most {MAX_DURATION_S} s (one day), found {}",
                    file.duration_s
                ),
            ));
        }
        if !(0.0..=0.1).contains(&file.control_period_s) || file.control_period_s == 0.0 {
            return Err(at(
                "control_period_s",
                format!("must be in (0, 0.1] s, found {}", file.control_period_s),
            ));
        }
        if file.trace_period_s.is_nan() || file.trace_period_s < file.control_period_s {
            return Err(at(
                "trace_period_s",
                "must be at least control_period_s".to_string(),
            ));
        }
        let mut actions = Vec::new();
        let mut noises = Vec::new();
        let mut law_names = Vec::new();
        for (i, e) in file.events.iter().enumerate() {
            let key = format!("event[{i}]");
            if !(0.0..=file.duration_s).contains(&e.at_s) {
                return Err(at(
                    &format!("{key}.at_s"),
                    format!(
                        "must be within 0..duration_s ({}), found {}",
                        file.duration_s, e.at_s
                    ),
                ));
            }
            let mut found: Vec<Action> = Vec::new();
            if let Some(r) = e.ramp {
                if r.over_s.is_nan() || r.over_s <= 0.0 {
                    return Err(at(&format!("{key}.ramp.over_s"), "must be positive".into()));
                }
                check_signal_value(r.signal, r.to).map_err(|m| at(&format!("{key}.ramp.to"), m))?;
                found.push(Action::Ramp(r));
            }
            if let Some(s) = e.step {
                check_signal_value(s.signal, s.to).map_err(|m| at(&format!("{key}.step.to"), m))?;
                found.push(Action::Step(s));
            }
            if let Some(t) = e.drive_trip {
                if !t {
                    return Err(at(
                        &format!("{key}.drive_trip"),
                        "only `drive_trip = true` is meaningful".into(),
                    ));
                }
                found.push(Action::DriveTrip);
            }
            if let Some(n) = &e.noise {
                if n.amplitude.is_nan() || n.amplitude < 0.0 {
                    return Err(at(&format!("{key}.noise.amplitude"), "must be ≥ 0".into()));
                }
                noises.push(n.clone());
                found.push(Action::Noise(noises.len() - 1));
            }
            if let Some(f) = e.sensor_fault {
                found.push(Action::SensorFault(f));
            }
            if let Some(l) = &e.law {
                law_names.push(l.clone());
                found.push(Action::Law(law_names.len() - 1));
            }
            if let Some(m) = &e.mode {
                let auto = match m.as_str() {
                    "auto" => true,
                    "manual" => false,
                    other => {
                        return Err(at(
                            &format!("{key}.mode"),
                            format!("unknown mode `{other}`, expected `auto` or `manual`"),
                        ))
                    }
                };
                found.push(Action::Mode(auto));
            }
            match found.len() {
                1 => actions.push((e.at_s, found.remove(0))),
                0 => {
                    return Err(at(&key, "event has no action".into()).with_hint(
                        "add one of: ramp, step, drive_trip, noise, sensor_fault, law, mode",
                    ))
                }
                _ => {
                    return Err(at(&key, "event has more than one action".into())
                        .with_hint("split it into one [[event]] per action"))
                }
            }
        }
        actions.sort_by(|a, b| a.0.total_cmp(&b.0));
        Ok(Scenario {
            file,
            path: path.to_path_buf(),
            actions,
            noises,
            law_names,
        })
    }

    /// Short name.
    pub fn name(&self) -> &str {
        &self.file.name
    }

    /// The timeline in words for the pictures: (time, s; e.g. "throttle → 20 % over 2 s").
    pub fn event_labels(&self) -> Vec<(f64, String)> {
        let signal = |s: Signal, v: f64| match s {
            Signal::Throttle => format!("throttle → {:.0} %", 100.0 * v),
            Signal::Feed => format!("feed → {:.0} %", 100.0 * v),
            Signal::SpeedSetpoint => format!("speed setpoint → {:.0} %", 100.0 * v),
            Signal::DownstreamPressure => format!("header pressure → {:.0} %", 100.0 * v),
            Signal::FlowSetpointKgS => format!("flow setpoint → {v:.3} kg/s"),
            Signal::RecycleManual => format!("recycle manual → {:.0} %", 100.0 * v),
        };
        self.actions
            .iter()
            .map(|(t, a)| {
                let text = match a {
                    Action::Ramp(r) => format!("{} over {} s", signal(r.signal, r.to), r.over_s),
                    Action::Step(s) => signal(s.signal, s.to),
                    Action::DriveTrip => "drive trip".to_string(),
                    Action::Noise(i) => match self.noises.get(*i) {
                        Some(n) if n.amplitude > 0.0 => format!("noise {}", n.amplitude),
                        _ => "noise off".to_string(),
                    },
                    Action::SensorFault(f) => {
                        let what = match f.fault {
                            FaultKind::Stale => "stale",
                            FaultKind::Nan => "NaN",
                            FaultKind::Value => "stuck",
                            FaultKind::Restore => "restored",
                        };
                        format!("{} {what}", f.sensor.name())
                    }
                    Action::Law(i) => format!(
                        "law → {}",
                        self.law_names.get(*i).map_or("?", String::as_str)
                    ),
                    Action::Mode(true) => "auto".to_string(),
                    Action::Mode(false) => "manual".to_string(),
                };
                (*t, text)
            })
            .collect()
    }

    /// Time of the last event, s (0 if none): settling is measured from here.
    pub fn last_event_s(&self) -> f64 {
        self.actions
            .iter()
            .map(|(t, a)| match a {
                Action::Ramp(r) => t + r.over_s,
                _ => *t,
            })
            .fold(0.0, f64::max)
    }
}

fn check_signal_value(signal: Signal, v: f64) -> Result<(), String> {
    let ok = match signal {
        Signal::Throttle | Signal::RecycleManual => (0.0..=1.0).contains(&v),
        Signal::Feed | Signal::DownstreamPressure => (0.0..=3.0).contains(&v),
        Signal::SpeedSetpoint => (0.0..=1.5).contains(&v),
        Signal::FlowSetpointKgS => v.is_finite(),
    };
    if ok {
        Ok(())
    } else {
        Err(format!("value {v} out of range for {signal:?}"))
    }
}

/// A fault state of one sensor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SensorState {
    /// Healthy.
    Ok,
    /// Not updating since the given time.
    Stale {
        /// When it stopped, s.
        since_s: f64,
    },
    /// Reports NaN.
    Nan,
    /// Reports a fixed value.
    Value(f64),
}

/// The process side at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScenarioState {
    /// Throttle opening.
    pub throttle: f64,
    /// Feed fraction.
    pub feed: f64,
    /// Speed setpoint, fraction of nominal.
    pub speed_setpoint: f64,
    /// Downstream pressure fraction.
    pub downstream: f64,
    /// Flow setpoint, kg/s (NaN if none).
    pub flow_setpoint_kg_s: f64,
    /// Manual recycle opening.
    pub recycle_manual: f64,
    /// Drive tripped.
    pub drive_tripped: bool,
    /// Noise amplitude per sensor (SI units) and distribution.
    pub noise: [(f64, Distribution); SensorId::COUNT],
    /// Fault per sensor.
    pub faults: [SensorState; SensorId::COUNT],
    /// A law switch requested at this instant (index into `Scenario::law_names`).
    pub law_request: Option<usize>,
    /// A mode switch requested at this instant (true = auto).
    pub mode_request: Option<bool>,
}

/// Steps a scenario forward in time without allocating.
#[derive(Debug, Clone)]
pub struct Timeline<'a> {
    scenario: &'a Scenario,
    next: usize,
    state: ScenarioState,
    // active ramps per signal: (t0, v0, t1, v1)
    ramps: [Option<(f64, f64, f64, f64)>; 6],
}

fn signal_index(s: Signal) -> usize {
    match s {
        Signal::Throttle => 0,
        Signal::Feed => 1,
        Signal::SpeedSetpoint => 2,
        Signal::DownstreamPressure => 3,
        Signal::FlowSetpointKgS => 4,
        Signal::RecycleManual => 5,
    }
}

impl<'a> Timeline<'a> {
    /// Start at t = 0 with the given initial process values.
    pub fn new(scenario: &'a Scenario, throttle: f64, recycle_manual: f64, feed: f64) -> Self {
        let i = &scenario.file.initial;
        Timeline {
            scenario,
            next: 0,
            state: ScenarioState {
                throttle: i.throttle.unwrap_or(throttle),
                feed: i.feed.unwrap_or(feed),
                speed_setpoint: 1.0,
                downstream: 1.0,
                flow_setpoint_kg_s: i.flow_setpoint_kg_s.unwrap_or(f64::NAN),
                recycle_manual: i.recycle_valve.unwrap_or(recycle_manual),
                drive_tripped: false,
                noise: [(0.0, Distribution::Uniform); SensorId::COUNT],
                faults: [SensorState::Ok; SensorId::COUNT],
                law_request: None,
                mode_request: None,
            },
            ramps: [None; 6],
        }
    }

    /// The initial state (before any event).
    pub fn initial(&self) -> ScenarioState {
        self.state
    }

    fn value_mut(&mut self, s: Signal) -> &mut f64 {
        match s {
            Signal::Throttle => &mut self.state.throttle,
            Signal::Feed => &mut self.state.feed,
            Signal::SpeedSetpoint => &mut self.state.speed_setpoint,
            Signal::DownstreamPressure => &mut self.state.downstream,
            Signal::FlowSetpointKgS => &mut self.state.flow_setpoint_kg_s,
            Signal::RecycleManual => &mut self.state.recycle_manual,
        }
    }

    /// Advance to time `t_s` (monotone) and return the state. One-shot requests (law, mode)
    /// are reported once, at the first call at or after their time.
    pub fn state_at(&mut self, t_s: f64) -> ScenarioState {
        self.state.law_request = None;
        self.state.mode_request = None;
        let actions = &self.scenario.actions;
        while self.next < actions.len() && actions[self.next].0 <= t_s + 1e-12 {
            let (at, action) = (actions[self.next].0, actions[self.next].1.clone());
            self.next += 1;
            match action {
                Action::Ramp(r) => {
                    let v0 = *self.value_mut(r.signal);
                    self.ramps[signal_index(r.signal)] = Some((at, v0, at + r.over_s, r.to));
                }
                Action::Step(s) => {
                    self.ramps[signal_index(s.signal)] = None;
                    *self.value_mut(s.signal) = s.to;
                }
                Action::DriveTrip => self.state.drive_tripped = true,
                Action::Noise(k) => {
                    let n = &self.scenario.noises[k];
                    for s in &n.sensors {
                        self.state.noise[s.index()] = (n.amplitude, n.distribution);
                    }
                }
                Action::SensorFault(f) => {
                    self.state.faults[f.sensor.index()] = match f.fault {
                        FaultKind::Stale => SensorState::Stale { since_s: at },
                        FaultKind::Nan => SensorState::Nan,
                        FaultKind::Value => SensorState::Value(f.value),
                        FaultKind::Restore => SensorState::Ok,
                    }
                }
                Action::Law(k) => self.state.law_request = Some(k),
                Action::Mode(auto) => self.state.mode_request = Some(auto),
            }
        }
        for (idx, signal) in [
            Signal::Throttle,
            Signal::Feed,
            Signal::SpeedSetpoint,
            Signal::DownstreamPressure,
            Signal::FlowSetpointKgS,
            Signal::RecycleManual,
        ]
        .into_iter()
        .enumerate()
        {
            if let Some((t0, v0, t1, v1)) = self.ramps[idx] {
                let a = ((t_s - t0) / (t1 - t0)).clamp(0.0, 1.0);
                let v0 = if v0.is_nan() { v1 } else { v0 };
                *self.value_mut(signal) = v0 + a * (v1 - v0);
                if a >= 1.0 {
                    self.ramps[idx] = None;
                }
            }
        }
        self.state
    }
}

/// Deterministic noise source (SplitMix64), so that runs are reproducible.
#[derive(Debug, Clone)]
pub struct NoiseSource {
    state: u64,
    spare: Option<f64>,
}

impl NoiseSource {
    /// Seeded generator.
    pub fn new(seed: u64) -> Self {
        NoiseSource {
            state: seed ^ 0x9E37_79B9_7F4A_7C15,
            spare: None,
        }
    }

    fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform on [0, 1).
    pub fn uniform01(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A sample of the distribution with the given amplitude.
    pub fn sample(&mut self, amplitude: f64, d: Distribution) -> f64 {
        if amplitude == 0.0 {
            return 0.0;
        }
        match d {
            Distribution::Uniform => amplitude * (2.0 * self.uniform01() - 1.0),
            Distribution::Gaussian => {
                if let Some(s) = self.spare.take() {
                    return amplitude * s;
                }
                // Box–Muller
                let u1 = self.uniform01().max(1e-300);
                let u2 = self.uniform01();
                let r = (-2.0 * u1.ln()).sqrt();
                let th = 2.0 * std::f64::consts::PI * u2;
                self.spare = Some(r * th.sin());
                amplitude * r * th.cos()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Scenario, FileError> {
        let file: ScenarioFile = crate::config::toml_file::parse(text, Path::new("s.toml"))?;
        Scenario::from_file(file, Path::new("s.toml"), text)
    }

    #[test]
    fn ramp_and_step_evaluate_linearly() {
        let s = parse(
            "name='t'\ndescription='d'\nduration_s=10\n[[event]]\nat_s=1\nramp={signal='throttle', to=0.2, over_s=2}\n[[event]]\nat_s=5\nstep={signal='feed', to=0.5}\n",
        )
        .expect("valid");
        let mut tl = Timeline::new(&s, 0.6, 0.0, 1.0);
        assert_eq!(tl.state_at(0.5).throttle, 0.6);
        assert!((tl.state_at(2.0).throttle - 0.4).abs() < 1e-12);
        assert!((tl.state_at(3.5).throttle - 0.2).abs() < 1e-12);
        assert_eq!(tl.state_at(4.9).feed, 1.0);
        assert_eq!(tl.state_at(5.0).feed, 0.5);
        assert_eq!(s.last_event_s(), 5.0);
    }

    #[test]
    fn one_action_per_event() {
        let e = parse("name='t'\ndescription='d'\nduration_s=10\n[[event]]\nat_s=1\ndrive_trip=true\nmode='auto'\n")
            .unwrap_err();
        assert!(e.message.contains("more than one action"), "{e}");
        assert_eq!(e.line, 4, "{e}");
        let e = parse("name='t'\ndescription='d'\nduration_s=10\n[[event]]\nat_s=1\n").unwrap_err();
        assert!(e.message.contains("no action"), "{e}");
    }

    #[test]
    fn unknown_key_and_bad_values_are_located() {
        let e = parse("name='t'\ndescription='d'\nduration_s=10\n[[event]]\nat_s=1\nramp={signal='throttle', to=0.2, over=2}\n")
            .unwrap_err();
        assert!(e.message.contains("unknown field `over`"), "{e}");
        assert_eq!(e.line, 6);
        let e = parse(
            "name='t'\ndescription='d'\nduration_s=10\n[[event]]\nat_s=11\ndrive_trip=true\n",
        )
        .unwrap_err();
        assert_eq!(e.key, "event[0].at_s");
        assert_eq!(e.line, 5);
        let e = parse("name='t'\ndescription='d'\nduration_s=10\n[[event]]\nat_s=1\nstep={signal='throttle', to=1.5}\n")
            .unwrap_err();
        assert!(e.message.contains("out of range"), "{e}");
    }

    #[test]
    fn faults_noise_and_requests() {
        let s = parse("name='t'\ndescription='d'\nduration_s=10\n[[event]]\nat_s=1\nsensor_fault={sensor='orifice_dp', fault='stale'}\n[[event]]\nat_s=2\nnoise={sensors=['p_discharge'], amplitude=5000}\n[[event]]\nat_s=3\nlaw='recycle-pi'\n")
            .expect("valid");
        let mut tl = Timeline::new(&s, 0.6, 0.0, 1.0);
        let st = tl.state_at(1.5);
        assert_eq!(
            st.faults[SensorId::OrificeDp.index()],
            SensorState::Stale { since_s: 1.0 }
        );
        let st = tl.state_at(2.0);
        assert_eq!(st.noise[SensorId::PDischarge.index()].0, 5000.0);
        assert_eq!(tl.state_at(3.0).law_request, Some(0));
        assert_eq!(tl.state_at(3.001).law_request, None, "one-shot");
        assert_eq!(s.law_names[0], "recycle-pi");
    }

    #[test]
    fn noise_is_reproducible_and_bounded() {
        let mut a = NoiseSource::new(7);
        let mut b = NoiseSource::new(7);
        let mut max: f64 = 0.0;
        let mut sum = 0.0;
        let mut sum2 = 0.0;
        for _ in 0..20_000 {
            let x = a.sample(5000.0, Distribution::Uniform);
            assert_eq!(x, b.sample(5000.0, Distribution::Uniform));
            max = max.max(x.abs());
        }
        assert!(max <= 5000.0 && max > 4990.0);
        for _ in 0..20_000 {
            let x = a.sample(1.0, Distribution::Gaussian);
            sum += x;
            sum2 += x * x;
        }
        let mean = sum / 20_000.0;
        let var = sum2 / 20_000.0 - mean * mean;
        assert!(
            mean.abs() < 0.03 && (var - 1.0).abs() < 0.05,
            "{mean} {var}"
        );
    }
}
