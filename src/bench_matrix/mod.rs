//! The control benchmark matrix (`antisurge bench-matrix`): recycle-pi against the textbook
//! `baseline-pi` on every recycle plant, at two control-line margins, through process events
//! (throttle closure and step, feed drop, speed ramp, emergency shutdown) and signal faults
//! (pressure and Δp noise, a frozen Δp, input blips, a link outage).
//!
//! Each case runs the simulated plant and a [`ControlCore`] in one loop, like `sim`, with the
//! field between them modelled here: noise on the readings, a Δp transmitter repeating its
//! last value (fresh, as a healthy Modbus server would), all inputs arriving late (blips), and
//! a link outage in which no input arrives and no command reaches the valve (the positioner
//! holds its last setpoint). Scored on the plant's true state: surge cycles, closest approach
//! to the surge line during and after the event, recycle mass and energy, valve travel, time
//! in fail-safe, and the largest valve step at a resume.
//!
//! The emergency shutdown is also run apart ([`esd_stroke`], the machine check's ESD stroke
//! warning): with the trip seen in the speed decay alone and with the drive's trip contact
//! wired as `esd_input` ([`FieldFault::EsdContact`]), searching the longest recycle-valve
//! stroke that holds in each.
//!
//! Deterministic (fixed noise seeds), allocation outside the cycle only, a few seconds for the
//! whole matrix on one core; cases run on std threads.

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
use std::fmt::Write as _;
use std::path::Path;

/// What the field does to the signals in a case.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FieldFault {
    /// Clean signals.
    None,
    /// White noise: uniform ±1 % of span on each pressure, ±2 % of span on Δp (spans: 1.5× the
    /// initial pressure readings, 2× the initial Δp, i.e. design flow at ≈ 70 % of the flow
    /// range). Fixed seed.
    Noise {
        /// Seed of the noise sequence.
        seed: u64,
    },
    /// The Δp transmitter repeats its value (fresh age) from `at_s` for `for_s`.
    DpFrozen {
        /// Start, s.
        at_s: f64,
        /// Duration, s.
        for_s: f64,
    },
    /// The Δp transmitter drifts: from `at_s` it reads `rate_pct_per_s` % of its span more
    /// per second, up to `max_pct` % of span (a bias that makes it read more flow than
    /// true: the dangerous direction).
    DpDrift {
        /// Start, s.
        at_s: f64,
        /// Drift rate, % of span per s.
        rate_pct_per_s: f64,
        /// Largest offset, % of span.
        max_pct: f64,
    },
    /// Every input arrives `len_s` late, `count` times, every `every_s` from `at_s`.
    Blips {
        /// First blip, s.
        at_s: f64,
        /// Period, s.
        every_s: f64,
        /// Length of each blip, s.
        len_s: f64,
        /// How many.
        count: u32,
    },
    /// No input arrives and no command reaches the plant from `at_s` for `for_s`.
    LinkOutage {
        /// Start, s.
        at_s: f64,
        /// Duration, s.
        for_s: f64,
    },
    /// Not a fault, the field's wiring: the drive's trip contact is wired to the controller
    /// as `esd_input` (bound and supervised like the daemon binds a contact its signal map
    /// names) and reaches it `delay_s` after the plant closes it (a bus poll, a relay). The
    /// other cases leave the contact unwired: the controller sees a drive trip only in the
    /// speed decay.
    EsdContact {
        /// Latency from the drive trip to the controller reading the contact, s.
        delay_s: f64,
    },
}

/// One case of the matrix: a scenario file and what the field does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Case {
    /// Name in the table.
    pub name: &'static str,
    /// Scenario name in `config/scenarios`.
    pub scenario: &'static str,
    /// Field behaviour.
    pub fault: FieldFault,
}

/// The emergency shutdown as the matrix runs it: the trip contact not wired, so the
/// controller sees the drive trip in the speed decay alone ([`TripSignal`] for the other
/// situation).
pub const ESD_CASE: Case = Case {
    name: "ESD rundown",
    scenario: "emergency-shutdown",
    fault: FieldFault::None,
};

/// The cases, in table order.
pub const CASES: [Case; 10] = [
    Case {
        name: "throttle closure",
        scenario: "throttle-closure",
        fault: FieldFault::None,
    },
    Case {
        name: "throttle step",
        scenario: "throttle-step",
        fault: FieldFault::None,
    },
    Case {
        name: "feed drop",
        scenario: "feed-drop",
        fault: FieldFault::None,
    },
    Case {
        name: "speed ramp",
        scenario: "speed-ramp",
        fault: FieldFault::None,
    },
    ESD_CASE,
    Case {
        name: "closure + noise",
        scenario: "throttle-closure",
        fault: FieldFault::Noise { seed: 20261125 },
    },
    Case {
        name: "closure + Δp frozen 1 s",
        scenario: "throttle-closure",
        fault: FieldFault::DpFrozen {
            at_s: 5.5,
            for_s: 1.0,
        },
    },
    Case {
        name: "closure + Δp drift",
        scenario: "throttle-closure",
        fault: FieldFault::DpDrift {
            at_s: 1.0,
            rate_pct_per_s: 1000.0,
            max_pct: 30.0,
        },
    },
    Case {
        name: "closure + 100 ms blips",
        scenario: "throttle-closure",
        fault: FieldFault::Blips {
            at_s: 4.0,
            every_s: 1.0,
            len_s: 0.1,
            count: 10,
        },
    },
    Case {
        name: "closure + 3 s link outage",
        scenario: "throttle-closure",
        fault: FieldFault::LinkOutage {
            at_s: 12.0,
            for_s: 3.0,
        },
    },
];

/// The laws compared.
pub const LAWS: [LawId; 2] = [LawId::RecyclePi, LawId::BaselinePi];
/// The control-line margins, percent of surge-line flow.
pub const MARGINS_PCT: [f64; 2] = [10.0, 5.0];

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

/// How the controller learns of the drive trip in an ESD rundown.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TripSignal {
    /// From the speed decay alone (recycle-pi's deceleration trip): no trip contact wired.
    SpeedDecay,
    /// The drive's trip contact wired as `esd_input`, read [`ESD_CONTACT_DELAY_S`] after the
    /// trip: the valve is commanded fully open then, whatever the law sees.
    Contact,
}

impl TripSignal {
    /// The field of the ESD case in this situation.
    pub fn case(self) -> Case {
        match self {
            TripSignal::SpeedDecay => ESD_CASE,
            TripSignal::Contact => Case {
                name: "ESD rundown, trip contact wired",
                scenario: "emergency-shutdown",
                fault: FieldFault::EsdContact {
                    delay_s: ESD_CONTACT_DELAY_S,
                },
            },
        }
    }
}

/// Resolution of the stroke-time search, s: the stroke named is the longest multiple of it
/// that holds (a valve's stroke is specified no finer, and a coarser grid keeps the named
/// stroke from moving with every retune of the law).
pub const ESD_STROKE_RESOLUTION_S: f64 = 0.05;
/// Shortest stroke time the search tries, s (a valve's positioner lag is of this order;
/// nothing faster is a recycle valve).
pub const ESD_STROKE_MIN_S: f64 = 0.05;
/// Latency assumed from the drive trip to the controller acting on a wired trip contact, s:
/// one 1 kHz control cycle (a contact read every cycle and the command written at once, as
/// in-process). A polled bus adds its poll and write periods (Modbus at 50 Hz: up to 20 ms
/// each way); [`EsdStroke::contact_latency_budget_s`] says how much the machine tolerates.
pub const ESD_CONTACT_DELAY_S: f64 = 0.001;
/// Longest contact latency the budget search tries, s (1 ms grid).
pub const ESD_CONTACT_LATENCY_MAX_S: f64 = 0.05;

/// Whether an ESD run holds: no surge cycle, and the true operating point never left of the
/// surge line (a brief excursion that the detector does not count as a cycle is no margin
/// to specify a valve on).
pub fn esd_holds(r: &CaseResult) -> bool {
    r.surge_cycles == 0 && r.min_margin_during.min(r.min_margin_after) >= 0.0
}

/// Whether the recycle valve's stroke suffices for an ESD rundown without surge (recycle-pi
/// with its defaults at one control-line margin), in both situations of [`TripSignal`], and
/// the longest stroke time that holds in each (bisection on the stroke, resolution
/// [`ESD_STROKE_RESOLUTION_S`], from [`ESD_STROKE_MIN_S`] to the plant's own stroke).
#[derive(Debug, Clone, PartialEq)]
pub struct EsdStroke {
    /// Plant name.
    pub plant: String,
    /// Control-line margin, %.
    pub margin_pct: f64,
    /// The plant's recycle-valve stroke time, s.
    pub stroke_time_s: f64,
    /// Surge cycles of the ESD with that stroke, trip seen in the speed decay only.
    pub surge_cycles: u32,
    /// Surge cycles of the ESD with that stroke and the trip contact wired.
    pub contact_surge_cycles: u32,
    /// With the plant's stroke, speed decay only: time from the drive trip to the first
    /// instant left of the surge line, s (NaN: never).
    pub surge_after_s: f64,
    /// Longest stroke that holds the ESD with zero surge cycles from the speed decay alone,
    /// s (the plant's own if it does; None: not even [`ESD_STROKE_MIN_S`]).
    pub longest_speed_decay_s: Option<f64>,
    /// Longest stroke that holds it with the trip contact wired, s (None: not even
    /// [`ESD_STROKE_MIN_S`]).
    pub longest_contact_s: Option<f64>,
    /// When the speed decay alone does not hold with any stroke: the longest latency from
    /// the drive trip to the wired contact's open command, on a 1 ms grid up to
    /// [`ESD_CONTACT_LATENCY_MAX_S`], with which the fastest valve ([`ESD_STROKE_MIN_S`])
    /// holds, s (None: not searched, or not even 1 ms).
    pub contact_latency_budget_s: Option<f64>,
}

impl EsdStroke {
    /// Whether the plant's own stroke holds the ESD from the speed decay alone.
    pub fn holds_own(&self) -> bool {
        self.longest_speed_decay_s == Some(self.stroke_time_s)
    }

    /// What the check recommends when the plant's stroke does not hold from the speed decay
    /// alone: the stroke time, and whether the trip contact must be wired for it (None:
    /// nothing needed, or no stroke holds even with the contact).
    pub fn recommended(&self) -> Option<(f64, TripSignal)> {
        if self.holds_own() {
            return None;
        }
        match (self.longest_speed_decay_s, self.longest_contact_s) {
            (Some(t), _) => Some((t, TripSignal::SpeedDecay)),
            (None, Some(t)) => Some((t, TripSignal::Contact)),
            (None, None) => None,
        }
    }
}

/// Check the ESD stroke of every recycle plant at every margin of the matrix.
pub fn esd_strokes(plants: &[PlantCase], config_dir: &Path) -> Result<Vec<EsdStroke>, SimError> {
    let path = config_dir.join("scenarios").join("emergency_shutdown.toml");
    let sc = Scenario::load(&path).map_err(|e| SimError::Scenario {
        scenario: "emergency-shutdown".into(),
        message: e.to_string(),
    })?;
    let mut out = Vec::new();
    for p in plants
        .iter()
        .filter(|p| LawId::RecyclePi.supports(p.file.model))
    {
        for m in MARGINS_PCT {
            if let Some(v) = esd_stroke(p, &sc, m)? {
                out.push(v);
            }
        }
    }
    Ok(out)
}

/// The plant with another recycle-valve stroke time, s.
pub fn with_stroke(p: &PlantCase, stroke_time_s: f64) -> PlantCase {
    let mut v = p.clone();
    if let Some(rs) = v.file.recycle_system.as_mut() {
        rs.recycle_valve.stroke_time_s = stroke_time_s;
    }
    v
}

/// The ESD rundown (scenario `sc`) of plant `p`, recycle-pi with its defaults at
/// `margin_pct`, with the trip seen as `trip` says.
pub fn esd_run(
    p: &PlantCase,
    sc: &Scenario,
    margin_pct: f64,
    trip: TripSignal,
) -> Result<CaseResult, SimError> {
    run_case(p, sc, &trip.case(), LawId::RecyclePi, margin_pct)
}

/// The longest stroke time, on the [`ESD_STROKE_RESOLUTION_S`] grid between
/// [`ESD_STROKE_MIN_S`] and `up_to_s`, with which `p` holds the ESD without a surge cycle
/// and never left of the surge line ([`esd_holds`]; bisection: a slower valve is assumed to
/// do no better, which a scan in 10 ms steps bore out on the shipped plants); None if not
/// even the shortest does. `own_holds`: the result at
/// `up_to_s`, if already known.
fn longest_holding_stroke(
    p: &PlantCase,
    sc: &Scenario,
    margin_pct: f64,
    trip: TripSignal,
    up_to_s: f64,
    own_holds: bool,
) -> Result<Option<f64>, SimError> {
    if own_holds {
        return Ok(Some(up_to_s));
    }
    // grid point k is k / steps_per_s seconds (a division: 0.3, not 0.30000000000000004)
    let steps_per_s = (1.0 / ESD_STROKE_RESOLUTION_S).round();
    let at = |k: u32| f64::from(k) / steps_per_s;
    let holds = |k: u32| -> Result<bool, SimError> {
        let v = with_stroke(p, at(k));
        Ok(esd_holds(&esd_run(&v, sc, margin_pct, trip)?))
    };
    let mut lo = (ESD_STROKE_MIN_S * steps_per_s).round() as u32;
    // the largest grid point below the plant's own stroke (which fails)
    let mut hi = ((up_to_s * steps_per_s - 1e-9).ceil() as u32).saturating_sub(1);
    if hi <= lo || !holds(lo)? {
        return Ok(None);
    }
    if holds(hi)? {
        return Ok(Some(at(hi)));
    }
    // invariant: lo holds, hi does not
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if holds(mid)? {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(Some(at(lo)))
}

/// The ESD stroke verdict of one plant (None: no recycle valve) under the scenario `sc` (a
/// drive trip), recycle-pi with its defaults at `margin_pct`, in both situations of
/// [`TripSignal`].
pub fn esd_stroke(
    p: &PlantCase,
    sc: &Scenario,
    margin_pct: f64,
) -> Result<Option<EsdStroke>, SimError> {
    let Some(rs) = p.file.recycle_system else {
        return Ok(None);
    };
    let stroke = rs.recycle_valve.stroke_time_s;
    let own = esd_run(p, sc, margin_pct, TripSignal::SpeedDecay)?;
    let own_contact = esd_run(p, sc, margin_pct, TripSignal::Contact)?;
    let longest_speed_decay_s = longest_holding_stroke(
        p,
        sc,
        margin_pct,
        TripSignal::SpeedDecay,
        stroke,
        esd_holds(&own),
    )?;
    let longest_contact_s = longest_holding_stroke(
        p,
        sc,
        margin_pct,
        TripSignal::Contact,
        stroke,
        esd_holds(&own_contact),
    )?;
    let contact_latency_budget_s = if longest_speed_decay_s.is_none() {
        esd_contact_latency_s(&with_stroke(p, ESD_STROKE_MIN_S), sc, margin_pct)?
    } else {
        None
    };
    Ok(Some(EsdStroke {
        plant: p.name().to_string(),
        margin_pct,
        stroke_time_s: stroke,
        surge_cycles: own.surge_cycles,
        contact_surge_cycles: own_contact.surge_cycles,
        surge_after_s: own.surge_after_s,
        longest_speed_decay_s,
        longest_contact_s,
        contact_latency_budget_s,
    }))
}

/// The longest latency from the drive trip to the controller acting on the wired trip
/// contact with which plant `p` holds the ESD ([`esd_holds`]), on a 1 ms grid up to
/// [`ESD_CONTACT_LATENCY_MAX_S`] (None: not even 1 ms). Tells whether a polled contact
/// (Modbus at 50 Hz: up to 20 ms to read, as much to write) is fast enough.
pub fn esd_contact_latency_s(
    p: &PlantCase,
    sc: &Scenario,
    margin_pct: f64,
) -> Result<Option<f64>, SimError> {
    let mut best = None;
    let max_ms = (ESD_CONTACT_LATENCY_MAX_S * 1e3).round() as u32;
    for ms in 1..=max_ms {
        let case = Case {
            name: "ESD rundown, trip contact wired",
            scenario: "emergency-shutdown",
            fault: FieldFault::EsdContact {
                delay_s: f64::from(ms) * 1e-3,
            },
        };
        if !esd_holds(&run_case(p, sc, &case, LawId::RecyclePi, margin_pct)?) {
            break;
        }
        best = Some(f64::from(ms) * 1e-3);
    }
    Ok(best)
}

/// The built-in emergency-shutdown scenario (a copy of `config/scenarios/emergency_shutdown.toml`
/// compiled in, so that the machine check needs no config directory).
pub fn builtin_esd_scenario() -> Result<Scenario, SimError> {
    const TEXT: &str = include_str!("../../config/scenarios/emergency_shutdown.toml");
    let e = |m: String| SimError::Scenario {
        scenario: "emergency-shutdown".into(),
        message: m,
    };
    let file = toml::from_str(TEXT).map_err(|x| e(x.to_string()))?;
    Scenario::from_file(file, Path::new("emergency_shutdown.toml"), TEXT)
        .map_err(|x| e(x.to_string()))
}

/// A stroke time as text (the search's resolution: at most two decimals).
fn secs(t: f64) -> String {
    let s = format!("{t:.2}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// "1 surge cycle", "2 surge cycles".
fn cycles(n: u32) -> String {
    format!("{n} surge cycle{}", if n == 1 { "" } else { "s" })
}

/// Why an ESD run does not hold ([`esd_holds`]): its surge cycles, or its excursion left of
/// the surge line.
fn failure(r: &CaseResult) -> String {
    if r.surge_cycles > 0 {
        cycles(r.surge_cycles)
    } else {
        format!(
            "no surge cycle, but {} left of the surge line",
            pct(-r.min_margin_during.min(r.min_margin_after))
        )
    }
}

fn esd_verdict(r: &EsdStroke) -> String {
    let wired = format!(
        "with the drive's trip contact wired as esd_input (acted on within {:.0} ms of the trip)",
        1e3 * ESD_CONTACT_DELAY_S
    );
    let contact = match r.longest_contact_s {
        Some(t) if t == r.stroke_time_s => format!("{wired} it holds"),
        Some(t) => format!(
            "{wired} it still surges ({}), and a ≤ {} s stroke holds",
            cycles(r.contact_surge_cycles),
            secs(t)
        ),
        None => format!(
            "{wired} it still surges ({}), and no stroke down to {} s holds",
            cycles(r.contact_surge_cycles),
            secs(ESD_STROKE_MIN_S)
        ),
    };
    let crossed = if r.surge_after_s.is_finite() {
        format!(
            "the machine crosses its surge line {:.0} ms after the drive trip",
            1e3 * r.surge_after_s
        )
    } else {
        "the machine comes too close to its surge line".to_string()
    };
    if r.holds_own() {
        return format!("suffices from the speed decay alone (no surge cycle); {contact}");
    }
    let own = format!(
        "is too slow ({}{}, the trip seen in the speed decay alone)",
        cycles(r.surge_cycles),
        if r.surge_cycles == 0 {
            ", but left of the surge line"
        } else {
            ""
        }
    );
    match (r.longest_speed_decay_s, r.longest_contact_s) {
        (Some(t), _) => format!(
            "{own}; a ≤ {} s stroke holds the ESD without surge from the speed decay alone; \
             {contact}",
            secs(t)
        ),
        (None, Some(t)) => format!(
            "{own}, and no stroke down to {} s holds without the trip contact: {crossed}, \
             before the speed decay identifies the trip; a ≤ {} s stroke holds it {wired}{}",
            secs(ESD_STROKE_MIN_S),
            secs(t),
            match r.contact_latency_budget_s {
                Some(l) => format!(
                    "; the open command must reach the valve within {:.0} ms of the trip \
                     however fast the valve (a 50 Hz Modbus poll and write take up to 40 ms)",
                    1e3 * l
                ),
                None => String::new(),
            }
        ),
        (None, None) => format!(
            "{own}, and no stroke down to {} s holds, not even with the drive's trip contact \
             wired as esd_input: {crossed}; it needs a wider control margin",
            secs(ESD_STROKE_MIN_S),
        ),
    }
}

/// The machine check's warning on the ESD stroke of a simulated plant, with recycle-pi at a
/// `margin_pct` control line: None if the valve's stroke holds an ESD (drive trip) without
/// surge from the speed decay alone (or the plant has no recycle valve), else one line naming
/// the longest stroke time that would, and whether the drive's trip contact must be wired
/// as `esd_input` for it.
pub fn esd_stroke_warning(p: &PlantCase, margin_pct: f64) -> Result<Option<String>, SimError> {
    esd_stroke_warning_as_wired(p, margin_pct, None)
}

/// [`esd_stroke_warning`] for a controller whose configuration binds the trip contact
/// (`esd_input` in the signal map) with a worst-case latency `contact_latency_s` from the
/// drive trip to the open command at the valve (read period + control cycle + write
/// period): the warning then also says whether the plant's own stroke holds the ESD with the
/// contact as configured. None: the contact is not bound (the warning is
/// [`esd_stroke_warning`]'s).
pub fn esd_stroke_warning_as_wired(
    p: &PlantCase,
    margin_pct: f64,
    contact_latency_s: Option<f64>,
) -> Result<Option<String>, SimError> {
    let sc = builtin_esd_scenario()?;
    let Some(v) = esd_stroke(p, &sc, margin_pct)? else {
        return Ok(None);
    };
    if v.holds_own() {
        return Ok(None);
    }
    let configured = match contact_latency_s {
        Some(d) => {
            let case = Case {
                name: "ESD rundown, trip contact as configured",
                scenario: "emergency-shutdown",
                fault: FieldFault::EsdContact { delay_s: d },
            };
            let r = run_case(p, &sc, &case, LawId::RecyclePi, margin_pct)?;
            format!(
                ". As configured, esd_input is bound and acted on up to {:.0} ms after the trip: \
                 with it the {} s stroke {}",
                1e3 * d,
                secs(v.stroke_time_s),
                if esd_holds(&r) {
                    "holds the ESD".to_string()
                } else {
                    format!("does not hold the ESD ({})", failure(&r))
                }
            )
        }
        None => String::new(),
    };
    Ok(Some(format!(
        "recycle_system.recycle_valve.stroke_time_s: in an emergency shutdown (drive trip, simulated, recycle-pi at a {margin_pct} % margin) the recycle valve's {} s stroke {}{configured}",
        secs(v.stroke_time_s),
        esd_verdict(&v)
    )))
}

/// The ESD verdicts as Markdown lines.
pub fn esd_markdown(rows: &[EsdStroke]) -> String {
    let mut s = String::new();
    for r in rows {
        let _ = writeln!(
            s,
            "- {} at {:.0} %: the recycle valve's {} s stroke {}.",
            r.plant,
            r.margin_pct,
            secs(r.stroke_time_s),
            esd_verdict(r)
        );
    }
    s
}

fn pct(x: f64) -> String {
    if x.is_finite() {
        format!("{:+.1} %", 100.0 * x)
    } else {
        "—".to_string()
    }
}

/// Whether a case counts in the energy sums: the nine cases of issue 10's matrix do; the
/// "Δp drift" case is a detection test added beside them (a run that surges recycles little,
/// so its energy would reward the law that fails it).
pub fn counts_in_energy(case: &str) -> bool {
    !case.contains("Δp drift")
}

/// Sum of recycle energy over the matrix (the cases [`counts_in_energy`]) for one plant, law
/// and margin, J.
pub fn energy_total(rows: &[CaseResult], plant: &str, law: LawId, margin_pct: f64) -> f64 {
    rows.iter()
        .filter(|r| r.plant == plant && r.law == law && r.margin_pct == margin_pct)
        .filter(|r| counts_in_energy(r.case))
        .map(|r| r.recycle_energy_j)
        .sum()
}

/// The matrix as Markdown: one table per plant, then the energy totals.
pub fn markdown(rows: &[CaseResult]) -> String {
    let mut s = String::new();
    let mut plants: Vec<&str> = Vec::new();
    for r in rows {
        if !plants.contains(&r.plant.as_str()) {
            plants.push(&r.plant);
        }
    }
    for p in &plants {
        let _ = writeln!(s, "**{p}**\n");
        s.push_str("| case | law | margin | surge cycles | closest approach during / after | recycle | recycle energy | valve travel | fail-safe | resume step |\n");
        s.push_str("|---|---|---|---|---|---|---|---|---|---|\n");
        for r in rows.iter().filter(|r| r.plant == *p) {
            let _ = writeln!(
                s,
                "| {} | {} | {:.0} % | {} | {} / {} | {:.1} kg | {:.3} MJ | {:.0} % | {} | {:.1} % |",
                r.case,
                r.law.name(),
                r.margin_pct,
                r.surge_cycles,
                pct(r.min_margin_during),
                pct(r.min_margin_after),
                r.recycle_kg,
                r.recycle_energy_j / 1e6,
                100.0 * r.valve_travel,
                if r.failsafe_entries > 0 {
                    format!("{:.2} s ({}×)", r.failsafe_s, r.failsafe_entries)
                } else {
                    "—".to_string()
                },
                100.0 * r.resume_step
            );
        }
        s.push('\n');
    }
    s.push_str("Δp frozen 1 s (the cross-check of the Δp against the pressures):\n\n");
    for p in &plants {
        let found: Vec<String> = rows
            .iter()
            .filter(|r| r.plant == *p && matches!(r.case, c if c.contains("Δp frozen")))
            .map(|r| {
                if r.dp_frozen_found_after_s.is_finite() {
                    format!(
                        "{} @ {:.0} % after {:.0} ms",
                        r.law.name(),
                        r.margin_pct,
                        1e3 * r.dp_frozen_found_after_s
                    )
                } else {
                    format!("{} @ {:.0} % not found", r.law.name(), r.margin_pct)
                }
            })
            .collect();
        let spurious: u32 = rows
            .iter()
            .filter(|r| r.plant == *p && !r.case.contains("Δp frozen"))
            .map(|r| r.dp_frozen_found)
            .sum();
        let _ = writeln!(
            s,
            "- {p}: found {}; false finds in the other cases: {spurious}.",
            found.join(", ")
        );
    }
    s.push('\n');
    s.push_str(
        "Δp drift (the cross-check of the transmitter's flow against the observer and the speed-line flow):\n\n",
    );
    for p in &plants {
        let found: Vec<String> = rows
            .iter()
            .filter(|r| r.plant == *p && r.case.contains("Δp drift"))
            .map(|r| {
                if r.dp_drift_found_after_s.is_finite() {
                    format!(
                        "{} @ {:.0} % after {:.2} s",
                        r.law.name(),
                        r.margin_pct,
                        r.dp_drift_found_after_s
                    )
                } else {
                    format!("{} @ {:.0} % not found", r.law.name(), r.margin_pct)
                }
            })
            .collect();
        let others = rows
            .iter()
            .filter(|r| r.plant == *p && !r.case.contains("Δp drift"));
        let spurious: u32 = others.clone().map(|r| r.dp_drift_found).sum();
        let worst = others
            .flat_map(|r| r.dp_drift_residual_max)
            .fold(0.0f64, f64::max);
        let _ = writeln!(
            s,
            "- {p}: found {}; false finds in the other cases: {spurious} (largest filtered residual there: {:.1} % of surge-line flow).",
            found.join(", "),
            100.0 * worst
        );
    }
    s.push('\n');
    s.push_str(
        "| plant | recycle energy over the matrix (all cases but the Δp drift) | surge cycles (all cases) |\n|---|---|---|\n",
    );
    for p in &plants {
        for law in LAWS {
            for m in MARGINS_PCT {
                let cycles: u32 = rows
                    .iter()
                    .filter(|r| r.plant == *p && r.law == law && r.margin_pct == m)
                    .map(|r| r.surge_cycles)
                    .sum();
                let _ = writeln!(
                    s,
                    "| {p} | {} @ {m:.0} %: {:.2} MJ | {cycles} |",
                    law.name(),
                    energy_total(rows, p, law, m) / 1e6
                );
            }
        }
    }
    s.push_str(
        "\nThe energy lines (recycle-pi at 10 % within baseline-pi at 10 %; at 5 % within 0.9 × that), \
         and the oracle: the recycle an ideal controller needs to \
         hold the compressor exactly on the control line from the instant the process needs it \
         (per millisecond max(0, control-line flow − throttle flow) × polytropic head, from the \
         plant's true state along each law's runs at that margin):\n\n",
    );
    for p in &plants {
        let e = |law, m| energy_total(rows, p, law, m) / 1e6;
        let o = |m| oracle_total(rows, p, LawId::RecyclePi, m) / 1e6;
        let (r10, r5, b10) = (
            e(LawId::RecyclePi, 10.0),
            e(LawId::RecyclePi, 5.0),
            e(LawId::BaselinePi, 10.0),
        );
        let holds = |ok: bool| if ok { "holds" } else { "does not hold" };
        let ob = |m| oracle_total(rows, p, LawId::BaselinePi, m) / 1e6;
        let lim = 0.9 * b10;
        let feasible = if o(5.0) <= lim && ob(5.0) <= lim {
            "the 5 % line is physically feasible on this plant"
        } else if o(5.0) > lim && ob(5.0) > lim {
            "even the oracle exceeds 0.9 × baseline-pi @ 10 %: the 5 % line is physically infeasible on this plant's matrix"
        } else {
            "the 5 % line is at the edge of what is physically possible on this plant's matrix (the oracle along runs that surge is not a bound)"
        };
        let _ = writeln!(
            s,
            "- {p}: recycle-pi @ 10 % {} MJ ≤ baseline-pi @ 10 % {} MJ {} (ratio {:.4}); recycle-pi @ 5 % {} MJ ≤ 0.9 × {} = {} MJ {} (ratio to baseline-pi @ 10 % {:.4}). Oracle along recycle-pi's runs: {:.3} MJ @ 10 %, {:.3} MJ @ 5 % ({:.3} × baseline-pi @ 10 %); along baseline-pi's: {:.3} MJ @ 10 %, {:.3} MJ @ 5 % ({:.3} ×): {feasible}.",
            mj5(r10),
            mj5(b10),
            holds(r10 <= b10),
            r10 / b10,
            mj5(r5),
            mj5(b10),
            mj5(lim),
            holds(r5 <= lim),
            r5 / b10,
            o(10.0),
            o(5.0),
            o(5.0) / b10,
            ob(10.0),
            ob(5.0),
            ob(5.0) / b10
        );
    }
    s
}

/// An energy in MJ to five significant digits (at least three decimals): the verdicts compare
/// totals that differ in the fourth digit.
fn mj5(x: f64) -> String {
    let digits = if x.is_finite() && x.abs() > 0.0 {
        (4 - x.abs().log10().floor() as i32).max(3) as usize
    } else {
        3
    };
    format!("{x:.digits$}")
}

/// Sum of the oracle recycle energy over the matrix for one plant, along one law's runs at
/// one margin, J.
pub fn oracle_total(rows: &[CaseResult], plant: &str, law: LawId, margin_pct: f64) -> f64 {
    rows.iter()
        .filter(|r| r.plant == plant && r.law == law && r.margin_pct == margin_pct)
        .filter(|r| counts_in_energy(r.case))
        .map(|r| r.oracle_energy_j)
        .sum()
}

/// The ESD rundown on the plant variants in `config_dir/plants/variants` (the shipped plants
/// with a recycle-valve stroke the ESD check names), recycle-pi at every margin of the
/// matrix, in both situations of [`TripSignal`], as Markdown lines. Whether the trip contact
/// is wired is the controller's configuration (the signal map binds `esd_input`), not the
/// plant's: every simulated plant closes its contact when its drive trips.
pub fn esd_variants_markdown(config_dir: &Path) -> Result<String, SimError> {
    let sc = builtin_esd_scenario()?;
    let mut s = String::new();
    for (f, p) in esd_variants(config_dir)? {
        let Some(rs) = p.file.recycle_system else {
            continue;
        };
        let mut parts = Vec::new();
        for m in MARGINS_PCT {
            for (trip, what) in [
                (TripSignal::SpeedDecay, "speed decay alone"),
                (TripSignal::Contact, "trip contact wired"),
            ] {
                let r = esd_run(&p, &sc, m, trip)?;
                parts.push(format!(
                    "at {m:.0} % with the {what} {} (closest approach {})",
                    cycles(r.surge_cycles),
                    pct(r.min_margin_during.min(r.min_margin_after))
                ));
            }
        }
        let _ = writeln!(
            s,
            "- variant {} (`plants/variants/{}`, recycle valve stroke {} s): {}.",
            p.name(),
            f.file_name()
                .map_or(String::new(), |n| n.to_string_lossy().into_owned()),
            secs(rs.recycle_valve.stroke_time_s),
            parts.join(", ")
        );
    }
    Ok(s)
}

/// The plant variants in `config_dir/plants/variants`, sorted by file name (none if the
/// folder is absent).
pub fn esd_variants(config_dir: &Path) -> Result<Vec<(std::path::PathBuf, PlantCase)>, SimError> {
    let dir = config_dir.join("plants").join("variants");
    let mut files: Vec<_> = match std::fs::read_dir(&dir) {
        Ok(rd) => rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "toml"))
            .collect(),
        Err(_) => return Ok(Vec::new()),
    };
    files.sort();
    files
        .into_iter()
        .map(|f| {
            let p = PlantCase::load(&f).map_err(|e| SimError::Scenario {
                scenario: "emergency-shutdown".into(),
                message: e.to_string(),
            })?;
            Ok((f, p))
        })
        .collect()
}
