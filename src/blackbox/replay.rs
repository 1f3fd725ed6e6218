//! `antisurge replay`: run the control core over a black-box recording.
//!
//! With the recorded settings, the core is built exactly as the daemon built it (machine model
//! from the config's plant file, the controller settings stored in the file's header, the
//! config's input limits) and fed each recorded cycle's time, inputs with their ages and
//! operator inputs. The core is deterministic, so every command comes out bit for bit as
//! recorded — if the recording starts at the daemon's first cycle and no settings changed
//! mid-run (both are checked and reported).
//!
//! With changed settings (another config, a law, a gain), the same inputs show what this
//! controller would have commanded. The inputs are the recorded ones: the plant's answer to the
//! different commands is not simulated (open loop over the recording).

use super::{CycleRecord, Recording};
use crate::control::core::{ControlCore, CoreSettings};
use crate::control::measurements::Measurements;
use crate::control::model::ControlModel;
use crate::control::{ControllerConfig, LawId};
use crate::sim::trace::TraceRow;
use crate::vocab::signals::{ActuatorId, SensorId};
use serde::Serialize;

/// Per-actuator comparison of recorded and replayed commands.
#[derive(Debug, Clone, Serialize)]
pub struct ActuatorDiff {
    /// Actuator name.
    pub actuator: String,
    /// Cycles whose command differs in any bit (NaN = NaN counts as equal).
    pub differing_cycles: usize,
    /// Largest |recorded − replayed|.
    pub max_abs_diff: f64,
}

/// Result of a replay.
#[derive(Debug, Clone, Serialize)]
pub struct ReplayReport {
    /// Cycles replayed.
    pub cycles: usize,
    /// Cycles whose every command is bit-identical to the recording.
    pub identical_cycles: usize,
    /// First differing cycle: (cycle, t_s).
    pub first_difference: Option<(u64, f64)>,
    /// Per driven actuator.
    pub actuators: Vec<ActuatorDiff>,
    /// Whether the recording starts at the daemon's first cycle (else the core's state at the
    /// start is unknown and the replay warms up from a fresh core).
    pub starts_at_first_cycle: bool,
    /// Cycles at which the daemon applied a settings update (not in the recording: the replay
    /// keeps its settings there).
    pub updates_at_cycles: Vec<u64>,
    /// Whether the replay used the recorded settings.
    pub recorded_settings: bool,
}

/// The replayed commands (one per record) and the comparison.
#[derive(Debug, Clone)]
pub struct Replay {
    /// Commands per record, with mode code.
    pub commands: Vec<(crate::vocab::signals::ActuatorCommands, u8)>,
    /// What the laws saw in each record's cycle (flow, pressure ratio, valve positions): the
    /// operating point of the pictures.
    pub measurements: Vec<Measurements>,
    /// Report.
    pub report: ReplayReport,
}

/// What to build the core from.
pub struct ReplaySetup {
    /// Machine model.
    pub model: ControlModel,
    /// Controller settings.
    pub controller: ControllerConfig,
    /// Core settings (input limits, fail-safe opening).
    pub settings: CoreSettings,
    /// Law.
    pub law: LawId,
    /// Whether these are the recorded settings (for the report).
    pub recorded_settings: bool,
}

fn same(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
}

/// Replay `rec` with a core built from `setup`.
pub fn replay(
    rec: &Recording,
    setup: ReplaySetup,
) -> Result<Replay, crate::control::law::api::LawError> {
    let h = &rec.header;
    let mut core = ControlCore::new(
        setup.model,
        setup.controller,
        setup.settings,
        setup.law,
        h.initial_torque_nm,
    )?;
    core.request_auto(h.auto);
    let mut commands = Vec::with_capacity(rec.records.len());
    let mut measurements = Vec::with_capacity(rec.records.len());
    let mut identical = 0usize;
    let mut first = None;
    let mut diffs: Vec<ActuatorDiff> = ActuatorId::ALL
        .iter()
        .map(|a| ActuatorDiff {
            actuator: a.name().to_string(),
            differing_cycles: 0,
            max_abs_diff: 0.0,
        })
        .collect();
    let mut updates_at = Vec::new();
    let mut last_updates = rec.records.first().map_or(0, |r| r.updates_applied);
    for r in &rec.records {
        if r.updates_applied != last_updates {
            updates_at.push(r.cycle);
            last_updates = r.updates_applied;
        }
        let out = core.cycle(r.t_s, &r.raw, &r.op);
        let mut all = true;
        for id in ActuatorId::ALL {
            let (a, b) = (r.commands.get(id), out.commands.get(id));
            if !same(a, b) {
                all = false;
                let d = &mut diffs[id.index()];
                d.differing_cycles += 1;
                let e = (a - b).abs();
                if e.is_finite() {
                    d.max_abs_diff = d.max_abs_diff.max(e);
                } else {
                    d.max_abs_diff = f64::INFINITY;
                }
            }
        }
        if all {
            identical += 1;
        } else if first.is_none() {
            first = Some((r.cycle, r.t_s));
        }
        commands.push((out.commands, out.mode.code()));
        measurements.push(out.measurements);
    }
    let driven: Vec<ActuatorDiff> = diffs
        .into_iter()
        .zip(ActuatorId::ALL)
        .filter(|(d, id)| {
            d.differing_cycles > 0 || rec.records.iter().any(|r| r.commands.get(*id).is_finite())
        })
        .map(|(d, _)| d)
        .collect();
    Ok(Replay {
        commands,
        measurements,
        report: ReplayReport {
            cycles: rec.records.len(),
            identical_cycles: identical,
            first_difference: first,
            actuators: driven,
            starts_at_first_cycle: rec.records.first().is_some_and(|r| r.cycle == 0),
            updates_at_cycles: updates_at,
            recorded_settings: setup.recorded_settings,
        },
    })
}

/// Write recorded and replayed commands side by side (CSV: t_s, mode, then per actuator
/// `rec_<name>`, `replay_<name>`).
pub fn write_comparison(
    path: &std::path::Path,
    records: &[CycleRecord],
    replayed: &Replay,
) -> std::io::Result<()> {
    use std::io::Write;
    let f = std::fs::File::create(path)?;
    let mut w = std::io::BufWriter::new(f);
    write!(w, "t_s,mode_recorded,mode_replayed")?;
    for id in ActuatorId::ALL {
        write!(w, ",rec_{0},replay_{0}", id.name())?;
    }
    writeln!(w)?;
    for (r, (c, m)) in records.iter().zip(&replayed.commands) {
        write!(w, "{},{},{}", r.t_s, r.mode.code(), m)?;
        for id in ActuatorId::ALL {
            write!(w, ",{},{}", r.commands.get(id), c.get(id))?;
        }
        writeln!(w)?;
    }
    w.flush()
}

impl Replay {
    /// The replayed run as trace rows for the pictures (`crate::plot`), one per record: the
    /// measured operating point (flow the laws used in the map's coordinate, pressure ratio,
    /// pressures, speed, valve positions) with its surge margin on `model`'s surge line, and
    /// the replayed commands and mode. A recording holds no plant truth: the true-state columns
    /// the recording cannot know (true mass flow, delivered torque, flows through the valves)
    /// are NaN, so the pictures draw only what was measured.
    pub fn trace(&self, records: &[CycleRecord], model: &ControlModel) -> Vec<TraceRow> {
        records
            .iter()
            .zip(&self.measurements)
            .zip(&self.commands)
            .map(|((r, m), (c, mode))| {
                let raw = |id| r.raw.values.get(id);
                TraceRow {
                    t_s: r.t_s,
                    flow_map: m.flow_map,
                    p_suction_pa: m.p_suction_pa,
                    p_discharge_pa: m.p_discharge_pa,
                    pressure_ratio: m.pressure_ratio,
                    omega_rad_s: m.omega_rad_s,
                    recycle_valve_position: m.recycle_position,
                    throttle_position: m.throttle_position,
                    tip_clearance_m: m.thrust_position_m,
                    surge_margin: model.surge_margin(m.flow_map, m.pressure_ratio),
                    meas_p_suction_pa: raw(SensorId::PSuction),
                    meas_p_discharge_pa: raw(SensorId::PDischarge),
                    meas_omega_rad_s: raw(SensorId::ShaftSpeed),
                    meas_orifice_dp_pa: raw(SensorId::OrificeDp),
                    meas_m_kg_s: m.m_measured_kg_s,
                    est_m_kg_s: m.m_observer_kg_s,
                    used_m_kg_s: m.m_kg_s,
                    cmd_drive_torque_nm: c.get(ActuatorId::DriveTorque),
                    cmd_recycle_valve: c.get(ActuatorId::RecycleValve),
                    cmd_ccv: c.get(ActuatorId::CloseCoupledValve),
                    cmd_throttle: c.get(ActuatorId::Throttle),
                    cmd_tip_clearance_m: c.get(ActuatorId::TipClearance),
                    mode: f64::from(*mode),
                    law_diagnostic: f64::NAN,
                    m_kg_s: f64::NAN,
                    recycle_flow_kg_s: f64::NAN,
                    throttle_flow_kg_s: f64::NAN,
                    feed_flow_kg_s: f64::NAN,
                    drive_torque_nm: f64::NAN,
                    load_torque_nm: f64::NAN,
                    ccv: f64::NAN,
                    thrust_force_n: f64::NAN,
                    thrust_slew_n_s: f64::NAN,
                }
            })
            .collect()
    }
}

/// The same rows with the recorded commands and mode in place of the replayed ones (the
/// comparison the time series draws when the settings changed).
pub fn with_recorded_commands(rows: &[TraceRow], records: &[CycleRecord]) -> Vec<TraceRow> {
    rows.iter()
        .zip(records)
        .map(|(row, r)| {
            let c = &r.commands;
            TraceRow {
                cmd_drive_torque_nm: c.get(ActuatorId::DriveTorque),
                cmd_recycle_valve: c.get(ActuatorId::RecycleValve),
                cmd_ccv: c.get(ActuatorId::CloseCoupledValve),
                cmd_throttle: c.get(ActuatorId::Throttle),
                cmd_tip_clearance_m: c.get(ActuatorId::TipClearance),
                mode: f64::from(r.mode.code()),
                law_diagnostic: r.law_diagnostic,
                ..*row
            }
        })
        .collect()
}
