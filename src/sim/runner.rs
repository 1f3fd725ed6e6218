//! The simulation loop.

use super::summary::{is_steady, settle_time, ActuatorPeaks, LawEventCounts, Summary};
use super::trace::TraceRow;
use crate::control::core::{ControlCore, CoreSettings};
use crate::control::law::LawEvent;
use crate::control::measurements::{OperatorInputs, RawSensors};
use crate::control::model::ControlModel;
use crate::control::LawId;
use crate::plant::file::PlantDescription;
use crate::plant::{PlantError, PlantInputs, SimPlant};
use crate::scenario::{NoiseSource, Scenario, SensorState, Timeline};
use crate::signals::{ActuatorId, SensorId, SensorSnapshot};
use crate::surge::{DetectorConfig, SurgeDetector};
use std::time::Instant;

/// Options of a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimOptions {
    /// The surge law.
    pub law: LawId,
    /// Call the progress callback every this many control periods.
    pub progress_every: usize,
}

impl Default for SimOptions {
    fn default() -> Self {
        SimOptions {
            law: LawId::None,
            progress_every: 2000,
        }
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
    Law(#[from] crate::control::law::LawError),
    /// A law named in the scenario does not exist.
    #[error("scenario `{scenario}`: {message}")]
    Scenario {
        /// Scenario name.
        scenario: String,
        /// What is wrong.
        message: String,
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

/// Apply scenario faults and noise to the plant's readings; returns raw sensors with ages.
fn field_readings(
    t_s: f64,
    clean: &SensorSnapshot,
    faults: &[SensorState; SensorId::COUNT],
    noise: &[(f64, crate::scenario::Distribution); SensorId::COUNT],
    frozen: &mut SensorSnapshot,
    rng: &mut NoiseSource,
) -> RawSensors {
    let mut raw = RawSensors::fresh(*clean);
    for id in SensorId::ALL {
        let i = id.index();
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

/// Run a scenario on a plant with a law. `progress` receives the completed fraction.
pub fn run(
    desc: &PlantDescription,
    scenario: &Scenario,
    options: SimOptions,
    progress: &mut dyn FnMut(f64),
) -> Result<SimResult, SimError> {
    let wall = Instant::now();
    let init = desc.file.initial;
    let mut timeline = Timeline::new(scenario, init.throttle, init.recycle_valve, init.feed);
    let st0 = timeline.initial();
    let mut inputs = PlantInputs {
        throttle_process: st0.throttle,
        recycle_manual: st0.recycle_manual,
        feed: st0.feed,
        ..PlantInputs::default()
    };
    let mut plant = SimPlant::new(desc, &inputs)?;
    let model = ControlModel::from_plant(desc);
    let settings = CoreSettings::defaults_for(&model);
    let nominal_speed = model.drive.nominal_speed_rad_s;
    let t0_torque = plant.truth().load_torque_nm;
    let config = model.controller.clone();
    let mut core = ControlCore::new(model, config, settings, options.law, t0_torque)?;
    let law_ids: Vec<LawId> = scenario
        .law_names
        .iter()
        .map(|n| {
            n.parse::<LawId>().map_err(|e| SimError::Scenario {
                scenario: scenario.name().to_string(),
                message: e.to_string(),
            })
        })
        .collect::<Result<_, _>>()?;

    let dt = scenario.file.control_period_s;
    let n_steps = (scenario.file.duration_s / dt).round() as usize;
    let trace_every = ((scenario.file.trace_period_s / dt).round() as usize).max(1);
    let mut trace = Vec::with_capacity(n_steps / trace_every + 2);
    let mut detector = SurgeDetector::new(DetectorConfig::default());
    let mut rng = NoiseSource::new(scenario.file.seed);
    let mut frozen = plant.sensors();
    let mut peaks = ActuatorPeaks {
        drive_torque_rating_nm: desc.file.drive.rated_torque_nm,
        nominal_load_torque_nm: t0_torque,
        ccv_rating: desc.file.spool.map_or(f64::NAN, |s| s.ccv_max),
        tip_clearance_nominal_m: desc
            .file
            .thrust_rating
            .map_or(f64::NAN, |t| t.nominal_clearance_m),
        thrust_force_rating_n: desc.file.thrust_rating.map_or(f64::NAN, |t| t.force_max_n),
        thrust_slew_rating_n_s: desc.file.thrust_rating.map_or(f64::NAN, |t| t.slew_max_n_s),
        ..Default::default()
    };
    let mut min_flow = f64::INFINITY;
    let mut min_margin = f64::INFINITY;
    let mut recycle_energy = 0.0;
    let mut last_recycle_pos = plant.truth().recycle_valve_position;
    let mut law_events = LawEventCounts::default();

    for k in 0..=n_steps {
        let t = k as f64 * dt;
        let st = timeline.state_at(t);
        if let Some(i) = st.law_request {
            core.select_law(law_ids[i])?;
        }
        if let Some(auto) = st.mode_request {
            core.request_auto(auto);
        }
        let clean = plant.sensors();
        let raw = field_readings(t, &clean, &st.faults, &st.noise, &mut frozen, &mut rng);
        let op = OperatorInputs {
            speed_setpoint_rad_s: nominal_speed * st.speed_setpoint,
            throttle_demand: st.throttle,
            flow_setpoint_kg_s: st.flow_setpoint_kg_s,
            recycle_manual: st.recycle_manual,
        };
        let out = core.cycle(t, &raw, &op);
        match out.law_event {
            Some(LawEvent::RecycleTrip { .. }) => law_events.recycle_trips += 1,
            Some(LawEvent::SafetyOnShift {
                total_margin,
                count: _,
            }) => {
                law_events.safety_on_shifts += 1;
                law_events.safety_on_total_margin = total_margin;
            }
            None => {}
        }

        // score the true state
        let truth = plant.truth();
        detector.update(t, dt, truth.m_kg_s);
        min_flow = min_flow.min(truth.m_kg_s);
        let margin = core
            .model()
            .surge_margin(truth.flow_map, truth.pressure_ratio());
        if margin.is_finite() {
            min_margin = min_margin.min(margin);
        }
        if truth.recycle_flow_kg_s > 0.0 {
            let head = desc
                .file
                .gas
                .polytropic_head_j_kg(truth.t_suction_k, truth.pressure_ratio());
            recycle_energy += truth.recycle_flow_kg_s * head * dt;
        }
        let c = &out.commands;
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
        if k > 0 && truth.recycle_valve_position.is_finite() {
            let rate = (last_recycle_pos - truth.recycle_valve_position) / dt;
            peaks.recycle_valve_closing_rate_per_s =
                peaks.recycle_valve_closing_rate_per_s.max(rate);
        }
        last_recycle_pos = truth.recycle_valve_position;

        if k % trace_every == 0 {
            let m = &out.measurements;
            trace.push(TraceRow {
                t_s: t,
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
                meas_m_kg_s: m.m_measured_kg_s,
                est_m_kg_s: m.m_observer_kg_s,
                used_m_kg_s: m.m_kg_s,
                cmd_drive_torque_nm: c.get(ActuatorId::DriveTorque),
                cmd_recycle_valve: c.get(ActuatorId::RecycleValve),
                cmd_ccv: c.get(ActuatorId::CloseCoupledValve),
                cmd_throttle: c.get(ActuatorId::Throttle),
                cmd_tip_clearance_m: c.get(ActuatorId::TipClearance),
                mode: f64::from(out.mode.code()),
                law_diagnostic: out.law_diagnostic,
            });
        }
        if k == n_steps {
            break;
        }
        inputs.commands = out.commands;
        inputs.throttle_process = st.throttle;
        inputs.recycle_manual = st.recycle_manual;
        inputs.feed = st.feed;
        inputs.downstream = st.downstream;
        inputs.drive_tripped = st.drive_tripped;
        plant.step(&inputs, dt);
        if options.progress_every > 0 && k % options.progress_every == 0 {
            progress(k as f64 / n_steps as f64);
        }
    }
    progress(1.0);
    let wall_s = wall.elapsed().as_secs_f64();
    let last = trace.last().copied().unwrap_or_default();
    let duration = scenario.file.duration_s;
    let window = (0.25 * duration).clamp(1.0, 3.0);
    let stable = is_steady(&trace, window, 0.02, 1e-4) && !detector.in_surge();
    let settle = if stable {
        settle_time(&trace, scenario.last_event_s(), 0.02, 1e-4)
    } else {
        None
    };
    let summary = Summary {
        plant: desc.name().to_string(),
        scenario: scenario.name().to_string(),
        law: core.law().name().to_string(),
        duration_s: duration,
        stable,
        flow_reversal: detector.reversals > 0,
        flow_reversals: detector.reversals,
        surge_cycles: detector.surge_cycles,
        surge_frequency_hz: detector
            .frequency_hz
            .is_finite()
            .then_some(detector.frequency_hz),
        min_flow_kg_s: min_flow,
        final_flow_kg_s: last.m_kg_s,
        final_pressure_ratio: last.pressure_ratio,
        min_surge_margin: min_margin,
        final_surge_margin: last.surge_margin,
        settle_time_s: settle,
        recycle_energy_j: recycle_energy,
        actuator_peaks: peaks,
        law_events,
        wall_time_s: wall_s,
        realtime_factor: duration / wall_s.max(1e-9),
    };
    Ok(SimResult { trace, summary })
}
