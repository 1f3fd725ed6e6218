//! The multi-rate run of one skid: the plant integrated at [`PLANT_STEP_S`], the control core
//! at the skid's loop rate on sample-and-hold readings that are one bus latency old, its
//! recycle-valve command reaching the positioner one bus latency (and the valve's dead time)
//! later. Scored on the plant's true state by the simulator's own bookkeeping
//! ([`PlantRun`]: the surge detector on the true compressor flow, the closest approach to the
//! surge line from the disturbance on, the recycle energy).
//!
//! The field between plant and controller, per plant step: transmitter noise (uniform, % of
//! span), a frozen or biased Δp, quantisation over each span; the controller takes the
//! newest reading that has arrived (never an older one after a newer: the bus delivers in
//! order; a cycle without a newer sample gets the previous one again, older, which the core
//! recognises and holds on).
//!
//! The drive keeps its own speed: a foreign machine's drive runs its governor (the machine
//! description's default, `owns_drive_speed_loop = false`); it is modelled here as the base
//! plant's speed PI ([`SpeedLoop`], the plant file's gains) on the true speed every plant
//! step, and the controller does not command torque. The loop under test is the anti-surge
//! loop alone.

use super::skid::{Disturbance, DpFault, Rng, Skid, DURATION_S, EVENT_AT_S, PLANT_STEP_S};
use super::CampaignError;
use crate::control::core::{ControlCore, CoreSettings};
use crate::control::measurements::RawSensors;
use crate::control::model::ControlModel;
use crate::control::speed_loop::SpeedLoop;
use crate::control::surge_control_line::ControlLineForm;
use crate::control::{ControllerConfig, LawId};
use crate::scenario::{Event, Ramp, Scenario, ScenarioFile, ScenarioInitial, Signal, Step};
use crate::sim::{ControllerView, PlantRun};
use crate::vocab::signals::{ActuatorCommands, ActuatorId, SensorId};
use crate::vocab::Mode;
use serde::Serialize;
use std::collections::VecDeque;
use std::path::Path;

/// Who drives the recycle valve in a run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Controller {
    /// A law of the control core.
    Law(LawId),
    /// The feasibility oracle: the valve commanded fully open at the first instant the
    /// transmitters could show the disturbance (disturbance time + bus latency + one sample
    /// period), `late_periods` sample periods later still; the command travels to the valve
    /// like any other (bus latency, dead time, stroke), without jitter (the oracle's best
    /// case: the latency drawn for the skid, no extra). Before that the valve holds its
    /// initial opening: in the campaign ([`super::run_skid`]) the opening baseline-pi held on
    /// the control line ([`super::on_the_control_line`]). Not a law of the daemon: no control
    /// core runs.
    Oracle {
        /// Extra delay, sample periods.
        late_periods: u32,
    },
    /// Nobody: the valve holds its initial opening (is the disturbance a challenge at all?);
    /// in the campaign, the opening on the control line, as the oracle.
    Held,
}

impl Controller {
    /// Name in tables.
    pub fn name(&self) -> String {
        match self {
            Controller::Law(l) => l.name().to_string(),
            Controller::Oracle { late_periods: 0 } => "oracle".to_string(),
            Controller::Oracle { late_periods } => format!("oracle +{late_periods} T"),
            Controller::Held => "valve held".to_string(),
        }
    }
}

/// The controllers of a case, in report order: recycle-pi, baseline-pi, the oracle, the late
/// oracle (two sample periods later), the held valve.
pub const CONTROLLERS: [Controller; 5] = [
    Controller::Law(LawId::RecyclePi),
    Controller::Law(LawId::BaselinePi),
    Controller::Oracle { late_periods: 0 },
    Controller::Oracle {
        late_periods: LATE_ORACLE_PERIODS,
    },
    Controller::Held,
];

/// The late oracle acts this many sample periods after the oracle (issue 22: two).
pub const LATE_ORACLE_PERIODS: u32 = 2;

/// Scores of one run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RunResult {
    /// Surge cycles over the run (true flow).
    pub surge_cycles: u32,
    /// Flow reversals over the run.
    pub flow_reversals: u32,
    /// Closest approach to the surge line from the disturbance on, fraction of surge-line
    /// flow (negative: left of it).
    pub min_margin: f64,
    /// Recycle energy over the run (polytropic head × recycle flow), J.
    pub recycle_energy_j: f64,
    /// Whether the core stayed in automatic mode from its first automatic cycle to the end
    /// (always true for the oracle and the held valve, which run no core).
    pub stayed_auto: bool,
    /// Mean valve command over the last [`OPENING_WINDOW_S`] before the disturbance, fraction
    /// (NaN: none delivered): where the controller held the valve when the disturbance came.
    pub opening_at_event: f64,
    /// Whether the compressor flow reversed before the disturbance (the controller was
    /// recovering from a surge of its own, not holding the control line, when it came).
    pub reversed_before_event: bool,
    /// The part of [`RunResult::recycle_energy_j`] from the disturbance on, J: the window the
    /// surge count and the closest approach are judged on (the rest is the start from the
    /// skid's initial opening to the control line, before any disturbance). A diagnostic:
    /// the campaign's energy line sums the whole run.
    pub recycle_energy_from_event_j: f64,
    /// Recycle trips (each step, repeats included; ESD openings too), from the core's law
    /// events; 0 for the oracle and the held valve.
    pub recycle_trips: u32,
}

/// Window of [`RunResult::opening_at_event`], s: one second, many samples of the noisiest
/// transmitter at the slowest loop rate (20 Hz), well after the 1-s start-up grace.
pub const OPENING_WINDOW_S: f64 = 1.0;

/// The controller configuration of the campaign: [`ControllerConfig::default`] (no tuning
/// for any machine: nobody tuned for these) with the control line `margin_pct` right of the
/// surge line; baseline-pi uses the same line.
pub fn controller_config(margin_pct: f64) -> ControllerConfig {
    let mut cfg = ControllerConfig::default();
    cfg.recycle_pi.control_line = ControlLineForm::Margin {
        margin_pct,
        offset: 0.0,
    };
    cfg
}

fn event(at_s: f64) -> Event {
    Event {
        at_s,
        ramp: None,
        step: None,
        drive_trip: None,
        noise: None,
        sensor_fault: None,
        law: None,
        mode: None,
    }
}

/// Trace period of a campaign run, s (only the closest approach and surge counts are scored,
/// on every plant step; the trace is kept for `--trace`).
pub const TRACE_PERIOD_S: f64 = 0.1;

/// The scenario of a skid: its disturbance at [`EVENT_AT_S`], [`DURATION_S`] long, plant
/// step [`PLANT_STEP_S`], a trace row every `trace_period_s`.
pub fn scenario_of(skid: &Skid, trace_period_s: f64) -> Result<Scenario, CampaignError> {
    let mut e = event(EVENT_AT_S);
    match skid.params.disturbance {
        Disturbance::ThrottleClosure { to, over_s } => {
            e.ramp = Some(Ramp {
                signal: Signal::Throttle,
                to,
                over_s,
            })
        }
        Disturbance::ThrottleStep { to } => {
            e.step = Some(Step {
                signal: Signal::Throttle,
                to,
            })
        }
        Disturbance::FeedDrop { to, over_s } => {
            e.ramp = Some(Ramp {
                signal: Signal::Feed,
                to,
                over_s,
            })
        }
        Disturbance::EsdRundown => e.drive_trip = Some(true),
    }
    let file = ScenarioFile {
        name: format!("campaign-{}", skid.index),
        description: skid.params.disturbance.describe(),
        duration_s: DURATION_S,
        control_period_s: PLANT_STEP_S,
        trace_period_s,
        seed: 0,
        initial: ScenarioInitial::default(),
        events: vec![e],
    };
    Scenario::from_file(file, Path::new("campaign.toml"), "").map_err(|e| CampaignError::Scenario {
        case: skid.index,
        message: e.to_string(),
    })
}

/// The transmitters of a skid: spans, noise, quantisation, the Δp fault.
struct Transmitters {
    span: [f64; SensorId::COUNT],
    noise: [f64; SensorId::COUNT],
    step: [f64; SensorId::COUNT],
    dp_fault: DpFault,
    frozen_dp: f64,
    rng: Rng,
}

impl Transmitters {
    fn new(skid: &Skid, clean: &RawSensors) -> Self {
        let p = &skid.params;
        let mut span = [0.0; SensorId::COUNT];
        let v0 = |id: SensorId| clean.values.get(id).abs();
        span[SensorId::PSuction.index()] = 1.5 * v0(SensorId::PSuction);
        span[SensorId::PDischarge.index()] = 1.5 * v0(SensorId::PDischarge);
        span[SensorId::ShaftSpeed.index()] = 1.5 * v0(SensorId::ShaftSpeed);
        span[SensorId::OrificeDp.index()] = 2.0 * v0(SensorId::OrificeDp);
        span[SensorId::RecycleValvePosition.index()] = 1.0;
        span[SensorId::ThrottlePosition.index()] = 1.0;
        let mut noise = [0.0; SensorId::COUNT];
        noise[SensorId::PSuction.index()] =
            0.01 * p.pressure_noise_pct_span * span[SensorId::PSuction.index()];
        noise[SensorId::PDischarge.index()] =
            0.01 * p.pressure_noise_pct_span * span[SensorId::PDischarge.index()];
        noise[SensorId::OrificeDp.index()] =
            0.01 * p.dp_noise_pct_span * span[SensorId::OrificeDp.index()];
        let levels = f64::from(1u32 << p.quantisation_bits.min(30));
        let step = span.map(|s| if s > 0.0 { s / levels } else { 0.0 });
        Transmitters {
            span,
            noise,
            step,
            dp_fault: p.dp_fault,
            frozen_dp: f64::NAN,
            // the noise stream of the case: the same for every controller
            rng: Rng::new(skid.seed ^ 0x6E6F_6973_6500_0000),
        }
    }

    /// What the transmitters read at `t_s` of the plant's clean readings.
    fn read(&mut self, t_s: f64, raw: &mut RawSensors) {
        for id in SensorId::ALL {
            let i = id.index();
            let mut v = raw.values.get(id);
            if id == SensorId::OrificeDp {
                match self.dp_fault {
                    DpFault::Healthy => {}
                    DpFault::Bias { pct_span } => v += 0.01 * pct_span * self.span[i],
                    DpFault::Frozen { from_s, for_s } => {
                        if t_s >= from_s && t_s < from_s + for_s {
                            if self.frozen_dp.is_nan() {
                                self.frozen_dp = v;
                            }
                            raw.values.set(id, self.frozen_dp);
                            continue;
                        }
                    }
                }
            }
            // one draw per transmitter and step whether or not it is noisy: the stream
            // stays aligned across skids
            let n = self.rng.symmetric();
            v += self.noise[i] * n;
            if self.step[i] > 0.0 && v.is_finite() {
                v = (v / self.step[i]).round() * self.step[i];
            }
            raw.values.set(id, v);
        }
    }
}

/// Run one controller on a skid with the control line `margin_pct` right of the surge line.
pub fn run(
    skid: &Skid,
    controller: Controller,
    margin_pct: f64,
) -> Result<RunResult, CampaignError> {
    run_traced(skid, controller, margin_pct, TRACE_PERIOD_S).map(|(r, _)| r)
}

/// [`run`], keeping the simulator's trace (a row every `trace_period_s`) and summary.
pub fn run_traced(
    skid: &Skid,
    controller: Controller,
    margin_pct: f64,
    trace_period_s: f64,
) -> Result<(RunResult, crate::sim::SimResult), CampaignError> {
    let sc = scenario_of(skid, trace_period_s)?;
    let desc = &skid.plant;
    let mut pr = PlantRun::new(desc, &sc)?;
    let p = &skid.params;
    let dt = PLANT_STEP_S;
    let n = pr.n_steps();
    let period_steps = ((1.0 / p.rate_hz) / dt).round().max(1.0) as usize;
    let period_s = period_steps as f64 * dt;
    let latency_steps = |extra: f64| ((p.latency_s + extra) / dt).round() as usize;
    let dead_steps = (p.valve_dead_time_s / dt).round() as usize;
    let t0_torque = pr.plant().truth().load_torque_nm;
    let drive = desc.file.drive;
    let mut governor = SpeedLoop::new(
        drive.speed_kp_nm_s_rad,
        drive.speed_ki_nm_rad,
        (drive.min_torque_nm, drive.rated_torque_nm),
        t0_torque,
    );
    // the controller: the machine as described, its drive on its own governor
    let mut core = match controller {
        Controller::Law(law) => {
            let mut machine = desc.machine();
            machine.owns_drive_speed_loop = false;
            let cfg = controller_config(margin_pct);
            let model = ControlModel::from_machine(&machine, cfg.clone());
            let mut settings = CoreSettings::defaults_for(&model);
            if period_steps > 1 {
                // as the daemon does for inputs polled on a bus
                settings.follow_poll_period(period_s);
            }
            Some(ControlCore::new(model, cfg, settings, law, t0_torque)?)
        }
        _ => None,
    };
    let nominal_speed = drive.nominal_speed_rad_s;
    // the oracle's open command: issued at disturbance + latency + one period (+ late
    // periods), on the plant-step grid
    let oracle_issue_k = match controller {
        Controller::Oracle { late_periods } => {
            let t = EVENT_AT_S + p.latency_s + period_s * (1.0 + f64::from(late_periods));
            Some((t / dt - 1e-9).ceil() as usize)
        }
        _ => None,
    };

    let (_, clean0) = pr.sense(0.0);
    let mut tx = Transmitters::new(skid, &clean0);
    let mut jitter = Rng::new(skid.seed ^ 0x6A69_7474_6572_0000);
    let history_len = latency_steps(p.jitter_s) + 2;
    let mut history: Vec<RawSensors> = vec![RawSensors::missing(); history_len];
    let mut last_sample_k: Option<usize> = None;
    // (arrival step, issue step, valve command)
    let mut in_flight: VecDeque<(usize, usize, f64)> = VecDeque::with_capacity(64);
    let mut valve_cmd = f64::NAN;
    let mut valve_from = 0usize;
    let mut view = ControllerView::UNKNOWN;
    let mut seen_auto = false;
    let mut stayed_auto = true;
    let mut delivered = ActuatorCommands::default();
    let (mut opening_sum, mut opening_n) = (0.0, 0u32);
    let mut reversed_before_event = false;
    let mut energy_from_event = 0.0;
    for k in 0..=n {
        let t = k as f64 * dt;
        let (st, mut raw) = pr.sense(t);
        tx.read(t, &mut raw);
        history[k % history_len] = raw;
        if k % period_steps == 0 {
            // one latency draw per sample and per command, whoever controls
            let d_in = latency_steps(p.jitter_s * jitter.unit()).min(history_len - 1);
            let d_out = latency_steps(p.jitter_s * jitter.unit());
            if let Some(core) = core.as_mut() {
                let mut s = k.saturating_sub(d_in);
                if let Some(last) = last_sample_k {
                    s = s.max(last);
                }
                last_sample_k = Some(s);
                let mut seen = history[s % history_len];
                let age = (k - s) as f64 * dt;
                for a in seen.age_s.iter_mut().filter(|a| a.is_finite()) {
                    *a = age;
                }
                let op = crate::sim::operator_inputs(&st, nominal_speed);
                let out = core.cycle(t, &seen, &op);
                if let Some(e) = out.law_event {
                    pr.count_law_event(e);
                }
                if out.mode == Mode::Auto {
                    seen_auto = true;
                } else if seen_auto {
                    stayed_auto = false;
                }
                view = ControllerView::of(&out);
                in_flight.push_back((
                    k + d_out + dead_steps,
                    k,
                    out.commands.get(ActuatorId::RecycleValve),
                ));
            }
        }
        if oracle_issue_k == Some(k) {
            in_flight.push_back((k + latency_steps(0.0) + dead_steps, k, 1.0));
        }
        // the newest command that has arrived
        while let Some(i) = in_flight.iter().position(|&(arrive, _, _)| arrive <= k) {
            if let Some((_, from, u)) = in_flight.remove(i) {
                if from >= valve_from {
                    valve_from = from;
                    valve_cmd = u;
                }
            }
        }
        delivered.set(ActuatorId::RecycleValve, valve_cmd);
        if valve_cmd.is_finite() && (EVENT_AT_S - OPENING_WINDOW_S..EVENT_AT_S).contains(&t) {
            opening_sum += valve_cmd;
            opening_n += 1;
        }
        let truth = pr.plant().truth();
        if t < EVENT_AT_S && truth.m_kg_s < 0.0 {
            reversed_before_event = true;
        }
        delivered.set(
            ActuatorId::DriveTorque,
            governor.update(
                nominal_speed * st.speed_setpoint,
                truth.omega_rad_s,
                0.0,
                dt,
            ),
        );
        pr.record(k, t, dt, &raw, &delivered, &view);
        // (the simulator's own sum, `PlantRun::record`, over the disturbance's window)
        if t >= EVENT_AT_S && truth.recycle_flow_kg_s > 0.0 {
            let head = desc
                .file
                .gas
                .polytropic_head_j_kg(truth.t_suction_k, truth.pressure_ratio());
            energy_from_event += truth.recycle_flow_kg_s * head * dt;
        }
        if k == n {
            break;
        }
        pr.advance(&st, &delivered, dt);
    }
    let sim = pr.finish(&controller.name());
    let s = &sim.summary;
    let r = RunResult {
        surge_cycles: s.surge_cycles,
        flow_reversals: s.flow_reversals,
        min_margin: s.closest_approach.min_surge_margin,
        recycle_energy_j: s.recycle_energy_j,
        stayed_auto: core.is_none() || (seen_auto && stayed_auto),
        opening_at_event: if opening_n > 0 {
            opening_sum / f64::from(opening_n)
        } else {
            f64::NAN
        },
        reversed_before_event,
        recycle_energy_from_event_j: energy_from_event,
        recycle_trips: s.law_events.recycle_trips,
    };
    Ok((r, sim))
}
