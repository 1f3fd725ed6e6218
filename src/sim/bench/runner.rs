//! One case in closed loop (the plant, the field between, a control core) and its scores; the
//! whole matrix on threads.

use crate::control::core::{ControlCore, CoreSettings};
use crate::control::laws::recycle_pi::RecyclePiConfig;
use crate::control::measurements::RawSensors;
use crate::control::model::ControlModel;
use crate::control::supervisor::InputFault;
use crate::control::surge_control_line::ControlLineForm;
use crate::control::LawId;
use crate::scenario::Scenario;
use crate::sim::case::PlantCase;
use crate::sim::{ControllerView, PlantRun, SimError};
use crate::vocab::signals::{ActuatorCommands, ActuatorId, SensorId};
use crate::vocab::Mode;
use std::path::Path;

use super::*;

/// Scores of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct CaseResult {
    /// Plant name.
    pub plant: String,
    /// Case name.
    pub case: &'static str,
    /// Law.
    pub law: LawId,
    /// Control-line margin, %.
    pub margin_pct: f64,
    /// Surge cycles (true flow, the simulator's detector).
    pub surge_cycles: u32,
    /// Flow reversals.
    pub flow_reversals: u32,
    /// Closest approach to the surge line from the first event to 3 s after the last one,
    /// fraction of surge-line flow (negative: left of it).
    pub min_margin_during: f64,
    /// Closest approach after that, fraction.
    pub min_margin_after: f64,
    /// Gas recycled, kg.
    pub recycle_kg: f64,
    /// Energy spent recycling (polytropic head × recycle flow), J.
    pub recycle_energy_j: f64,
    /// Valve travel, full strokes (sum of |Δ position|).
    pub valve_travel: f64,
    /// Time in fail-safe, s.
    pub failsafe_s: f64,
    /// Fail-safe entries.
    pub failsafe_entries: u32,
    /// Largest |first command − measured position| when the law (re)starts after the first
    /// cycle, fraction of travel (0 if it never restarts).
    pub resume_step: f64,
    /// Times the controller's cross-check found the Δp frozen (episodes).
    pub dp_frozen_found: u32,
    /// In the "Δp frozen" case, how long after the Δp froze the cross-check first found it,
    /// s (NaN: not found, or another case).
    pub dp_frozen_found_after_s: f64,
    /// Oracle: the recycle energy an ideal controller would spend along this run's true
    /// trajectory holding the compressor exactly on the control line from the instant the
    /// process needs it, J (see [`oracle_recycle_kg_s`]).
    pub oracle_energy_j: f64,
    /// Time from the first event to the first instant the true operating point lies left of
    /// the surge line, s (NaN: never).
    pub surge_after_s: f64,
    /// Times the drift cross-check declared the Δp drifting (episodes).
    pub dp_drift_found: u32,
    /// In the "Δp drift" case, how long after the drift started the cross-check first found
    /// it, s (NaN: not found, or another case).
    pub dp_drift_found_after_s: f64,
    /// Largest |filtered residual| of the drift check against the observer and against the
    /// speed-line flow, fraction of surge-line flow (how close a case came to a find).
    pub dp_drift_residual_max: [f64; 2],
}

/// The recycle flow an ideal controller needs at one instant of the plant's true state, kg/s:
/// the compressor must pass at least the control-line flow `q_cl` (map units, at the present
/// pressure ratio), and what the process does not take through the throttle must come back
/// through the recycle valve: max(0, w_cl − w_throttle), w_cl = q_cl × (w_c / q_c) (the same
/// suction density; `kg_per_map_unit` = w_c/q_c, the last valid one while q_c ≈ 0).
pub fn oracle_recycle_kg_s(q_cl_map: f64, kg_per_map_unit: f64, throttle_flow_kg_s: f64) -> f64 {
    let need = q_cl_map * kg_per_map_unit - throttle_flow_kg_s.max(0.0);
    if need.is_finite() {
        need.max(0.0)
    } else {
        0.0
    }
}

/// The controller configuration of a case: the plant's observer and detector settings, and
/// recycle-pi with its built-in defaults (no per-plant tuning: the defaults must hold on every
/// machine) on a control line `margin_pct` right of the surge line, which baseline-pi uses too.
pub fn controller_for(model: &ControlModel, margin_pct: f64) -> crate::control::ControllerConfig {
    let mut cfg = model.controller.clone();
    cfg.recycle_pi = RecyclePiConfig {
        control_line: ControlLineForm::Margin {
            margin_pct,
            offset: 0.0,
        },
        ..RecyclePiConfig::default()
    };
    cfg
}

/// xorshift64* uniform in [−1, 1].
fn uniform(state: &mut u64) -> f64 {
    *state ^= *state >> 12;
    *state ^= *state << 25;
    *state ^= *state >> 27;
    let r = state.wrapping_mul(0x2545_F491_4F6C_DD1D);
    (r >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
}

/// Count one find of a cross-check (a fault newly declared at `t_s`) and, for the case that
/// injects that fault from `injected_at_s`, the time from the injection to the first find.
fn count_find(found: &mut u32, found_after_s: &mut f64, injected_at_s: Option<f64>, t_s: f64) {
    *found += 1;
    if let Some(at_s) = injected_at_s {
        if found_after_s.is_nan() && t_s >= at_s {
            *found_after_s = t_s - at_s;
        }
    }
}

/// Run one case.
pub fn run_case(
    desc: &PlantCase,
    scenario: &Scenario,
    case: &Case,
    law: LawId,
    margin_pct: f64,
) -> Result<CaseResult, SimError> {
    run_case_traced(desc, scenario, case, law, margin_pct).map(|(r, _)| r)
}

/// Run one case and keep the simulator's trace too (for pictures and for finding out why a
/// case surges).
pub fn run_case_traced(
    desc: &PlantCase,
    scenario: &Scenario,
    case: &Case,
    law: LawId,
    margin_pct: f64,
) -> Result<(CaseResult, crate::sim::SimResult), SimError> {
    let model = crate::sim::control_model(desc);
    run_case_traced_with_model(desc, scenario, case, law, margin_pct, model)
}

/// The controller's model with a map that is not the plant's: flows stretched by
/// `flow_factor` and the pressure rise R − 1 scaled by `rise_factor` (the controller is not
/// told the machine exactly; the surge line it protects is kept).
pub fn map_off(model: &ControlModel, flow_factor: f64, rise_factor: f64) -> ControlModel {
    use crate::physics::compressor_map::MapModel;
    let mut m = model.clone();
    if let Some(map) = m.map.as_mut() {
        if let MapModel::Polynomial(p) = &mut map.model {
            *p = p.scaled(flow_factor, rise_factor);
        }
    }
    m
}

/// [`run_case`] with the controller's model given (e.g. [`map_off`]).
pub fn run_case_with_model(
    desc: &PlantCase,
    scenario: &Scenario,
    case: &Case,
    law: LawId,
    margin_pct: f64,
    model: ControlModel,
) -> Result<CaseResult, SimError> {
    run_case_traced_with_model(desc, scenario, case, law, margin_pct, model).map(|(r, _)| r)
}

/// [`run_case_traced`] with the controller's model given.
pub fn run_case_traced_with_model(
    desc: &PlantCase,
    scenario: &Scenario,
    case: &Case,
    law: LawId,
    margin_pct: f64,
    model: ControlModel,
) -> Result<(CaseResult, crate::sim::SimResult), SimError> {
    let mut pr = PlantRun::new(desc, scenario)?;
    let mut settings = CoreSettings::defaults_for(&model);
    let contact_delay_s = match case.fault {
        FieldFault::EsdContact { delay_s } => {
            settings.bind_contact(SensorId::EsdInput);
            delay_s
        }
        _ => f64::NAN,
    };
    let mut contact_closed_at = f64::NAN;
    let nominal_speed = model.drive.nominal_speed_rad_s;
    let t0_torque = pr.plant().truth().load_torque_nm;
    let config = controller_for(&model, margin_pct);
    let mut core = ControlCore::new(model.clone(), config, settings, law, t0_torque)?;
    let dt = pr.dt_s();
    let n = pr.n_steps();

    let t_first = scenario
        .actions
        .iter()
        .map(|(t, _)| *t)
        .fold(f64::INFINITY, f64::min);
    let t_first = match case.fault {
        FieldFault::LinkOutage { at_s, .. } | FieldFault::Blips { at_s, .. } => t_first.min(at_s),
        _ => t_first,
    };
    let t_end_fault = match case.fault {
        FieldFault::DpFrozen { at_s, for_s } | FieldFault::LinkOutage { at_s, for_s } => {
            at_s + for_s
        }
        FieldFault::Blips {
            at_s,
            every_s,
            len_s,
            count,
        } => at_s + every_s * f64::from(count.saturating_sub(1)) + len_s,
        _ => 0.0,
    };
    let t_after = scenario.last_event_s().max(t_end_fault) + 3.0;

    let (_, raw0) = pr.sense(0.0);
    let span = |id: SensorId, k: f64| k * raw0.values.get(id).abs();
    let noise_amp = {
        let mut a = [0.0; SensorId::COUNT];
        a[SensorId::PSuction.index()] = 0.01 * span(SensorId::PSuction, 1.5);
        a[SensorId::PDischarge.index()] = 0.01 * span(SensorId::PDischarge, 1.5);
        a[SensorId::OrificeDp.index()] = 0.02 * span(SensorId::OrificeDp, 2.0);
        a
    };
    let mut rng = match case.fault {
        FieldFault::Noise { seed } => seed | 1,
        _ => 1,
    };

    let mut res = CaseResult {
        plant: desc.name().to_string(),
        case: case.name,
        law,
        margin_pct,
        surge_cycles: 0,
        flow_reversals: 0,
        min_margin_during: f64::INFINITY,
        min_margin_after: f64::INFINITY,
        recycle_kg: 0.0,
        recycle_energy_j: 0.0,
        valve_travel: 0.0,
        failsafe_s: 0.0,
        failsafe_entries: 0,
        resume_step: 0.0,
        dp_frozen_found: 0,
        dp_frozen_found_after_s: f64::NAN,
        oracle_energy_j: 0.0,
        surge_after_s: f64::NAN,
        dp_drift_found: 0,
        dp_drift_found_after_s: f64::NAN,
        dp_drift_residual_max: [0.0; 2],
    };
    let gas = &desc.file.gas;
    let mut kg_per_map_unit = f64::NAN;
    let mut was_drifting = false;
    let mut was_frozen = false;
    let mut held_raw: Option<RawSensors> = None;
    let mut frozen_dp = f64::NAN;
    let mut delivered = ActuatorCommands::default();
    let mut last_pos = pr.plant().truth().recycle_valve_position;
    let mut last_mode = Mode::Init;
    let mut seen_auto = false;
    for k in 0..=n {
        let t = k as f64 * dt;
        let (st, mut raw) = pr.sense(t);
        // the field between plant and controller
        let mut link_down = false;
        match case.fault {
            FieldFault::None => {}
            FieldFault::Noise { .. } => {
                for id in [
                    SensorId::PSuction,
                    SensorId::PDischarge,
                    SensorId::OrificeDp,
                ] {
                    let v = raw.values.get(id) + noise_amp[id.index()] * uniform(&mut rng);
                    raw.values.set(id, v);
                }
            }
            FieldFault::DpFrozen { at_s, for_s } => {
                if t >= at_s && t < at_s + for_s {
                    if frozen_dp.is_nan() {
                        frozen_dp = raw.values.get(SensorId::OrificeDp);
                    }
                    raw.values.set(SensorId::OrificeDp, frozen_dp);
                }
            }
            FieldFault::DpDrift {
                at_s,
                rate_pct_per_s,
                max_pct,
            } => {
                if t >= at_s {
                    let off = (rate_pct_per_s * (t - at_s)).min(max_pct);
                    let v = raw.values.get(SensorId::OrificeDp)
                        + 0.01 * off * span(SensorId::OrificeDp, 2.0);
                    raw.values.set(SensorId::OrificeDp, v);
                }
            }
            FieldFault::Blips {
                at_s,
                every_s,
                len_s,
                count,
            } => {
                let i = ((t - at_s) / every_s).floor();
                let into = t - at_s - i * every_s;
                if t >= at_s && i < f64::from(count) && into < len_s {
                    let h = held_raw.get_or_insert(raw);
                    let mut late = *h;
                    for a in late.age_s.iter_mut() {
                        *a += into;
                    }
                    raw = late;
                } else {
                    held_raw = None;
                }
            }
            FieldFault::LinkOutage { at_s, for_s } => {
                if t >= at_s && t < at_s + for_s {
                    link_down = true;
                    let h = held_raw.get_or_insert(raw);
                    let mut late = *h;
                    for a in late.age_s.iter_mut() {
                        *a += t - at_s;
                    }
                    raw = late;
                }
            }
            FieldFault::EsdContact { .. } => {
                // the plant closes its contact with the drive trip; the controller reads
                // it `contact_delay_s` later (fresh: a polled bit that has not changed yet)
                if raw.values.get(SensorId::EsdInput) >= 0.5 {
                    if contact_closed_at.is_nan() {
                        contact_closed_at = t;
                    }
                    if t < contact_closed_at + contact_delay_s - 0.5 * dt {
                        raw.values.set(SensorId::EsdInput, 0.0);
                    }
                }
            }
        }
        let op = crate::sim::operator_inputs(&st, nominal_speed);
        let out = core.cycle(t, &raw, &op);
        if let Some(e) = out.law_event {
            pr.count_law_event(e);
        }
        // scoring
        let dp_fault = out.validity.fault[SensorId::OrificeDp.index()];
        let frozen_at_s = match case.fault {
            FieldFault::DpFrozen { at_s, .. } => Some(at_s),
            _ => None,
        };
        let frozen = dp_fault == InputFault::Frozen;
        if frozen && !was_frozen {
            count_find(
                &mut res.dp_frozen_found,
                &mut res.dp_frozen_found_after_s,
                frozen_at_s,
                t,
            );
        }
        was_frozen = frozen;
        let drift_at_s = match case.fault {
            FieldFault::DpDrift { at_s, .. } => Some(at_s),
            _ => None,
        };
        let drifting = dp_fault == InputFault::Drift;
        if drifting && !was_drifting {
            count_find(
                &mut res.dp_drift_found,
                &mut res.dp_drift_found_after_s,
                drift_at_s,
                t,
            );
        }
        was_drifting = drifting;
        let v = core.dp_drift_check().verdict();
        for (m, x) in res
            .dp_drift_residual_max
            .iter_mut()
            .zip([v.vs_observer, v.vs_speed_line])
        {
            if x.is_finite() {
                *m = m.max(x.abs());
            }
        }
        if out.mode == Mode::FailSafe {
            res.failsafe_s += dt;
            if last_mode != Mode::FailSafe {
                res.failsafe_entries += 1;
            }
        }
        if out.mode == Mode::Auto && last_mode != Mode::Auto {
            if seen_auto {
                let u = out.commands.get(ActuatorId::RecycleValve);
                let pos = pr.plant().truth().recycle_valve_position;
                if u.is_finite() && pos.is_finite() {
                    res.resume_step = res.resume_step.max((u - pos).abs());
                }
            }
            seen_auto = true;
        }
        last_mode = out.mode;
        let truth = pr.plant().truth();
        let margin = model.surge_margin(truth.flow_map, truth.pressure_ratio());
        if margin.is_finite() && t >= t_first {
            if margin < 0.0 && res.surge_after_s.is_nan() {
                res.surge_after_s = t - t_first;
            }
            if t < t_after {
                res.min_margin_during = res.min_margin_during.min(margin);
            } else {
                res.min_margin_after = res.min_margin_after.min(margin);
            }
        }
        if truth.recycle_flow_kg_s > 0.0 {
            res.recycle_kg += truth.recycle_flow_kg_s * dt;
        }
        // the oracle: an ideal controller on exactly this control line
        if truth.flow_map.abs() > 1e-9 && truth.m_kg_s.is_finite() {
            let k_m = truth.m_kg_s / truth.flow_map;
            if k_m > 0.0 && k_m.is_finite() {
                kg_per_map_unit = k_m;
            }
        }
        let ratio = truth.pressure_ratio();
        let q_cl = (1.0 + 0.01 * margin_pct) * model.surge_line.flow_at_ratio(ratio);
        let w_oracle = oracle_recycle_kg_s(q_cl, kg_per_map_unit, truth.throttle_flow_kg_s);
        if w_oracle > 0.0 {
            let head = gas.polytropic_head_j_kg(truth.t_suction_k, ratio);
            if head.is_finite() {
                res.oracle_energy_j += w_oracle * head * dt;
            }
        }
        let pos = truth.recycle_valve_position;
        if pos.is_finite() && last_pos.is_finite() {
            res.valve_travel += (pos - last_pos).abs();
        }
        last_pos = pos;
        let view = ControllerView::of(&out);
        pr.record(k, t, dt, &raw, &out.commands, &view);
        if k == n {
            break;
        }
        if !link_down {
            delivered = out.commands;
        }
        pr.advance(&st, &delivered, dt);
    }
    let sim = pr.finish(law.name());
    let s = &sim.summary;
    res.surge_cycles = s.surge_cycles;
    res.flow_reversals = s.flow_reversals;
    res.recycle_energy_j = s.recycle_energy_j;
    Ok((res, sim))
}

/// Run the whole matrix on the recycle plants among `plants`, on up to `threads` threads.
/// Scenarios are loaded from `config_dir/scenarios`.
pub fn run_matrix(
    plants: &[PlantCase],
    config_dir: &Path,
    threads: usize,
) -> Result<Vec<CaseResult>, SimError> {
    let mut scenarios = Vec::new();
    for c in CASES {
        let path = config_dir
            .join("scenarios")
            .join(format!("{}.toml", c.scenario.replace('-', "_")));
        let sc = Scenario::load(&path).map_err(|e| SimError::Scenario {
            scenario: c.scenario.to_string(),
            message: e.to_string(),
        })?;
        scenarios.push(sc);
    }
    let mut jobs = Vec::new();
    for p in plants
        .iter()
        .filter(|p| LawId::RecyclePi.supports(p.file.model))
    {
        for (ci, _) in CASES.iter().enumerate() {
            for law in LAWS {
                for m in MARGINS_PCT {
                    jobs.push((p, ci, law, m));
                }
            }
        }
    }
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results: std::sync::Mutex<Vec<(usize, Result<CaseResult, SimError>)>> =
        std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..threads.max(1) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(&(p, ci, law, m)) = jobs.get(i) else {
                    break;
                };
                let r = run_case(p, &scenarios[ci], &CASES[ci], law, m);
                if let Ok(mut g) = results.lock() {
                    g.push((i, r));
                }
            });
        }
    });
    let mut all = results.into_inner().unwrap_or_default();
    all.sort_by_key(|(i, _)| *i);
    all.into_iter().map(|(_, r)| r).collect()
}
