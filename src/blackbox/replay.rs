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
use crate::control::model::ControlModel;
use crate::control::{ControllerConfig, LawId};
use crate::signals::ActuatorId;
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
    pub commands: Vec<(crate::signals::ActuatorCommands, u8)>,
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
) -> Result<Replay, crate::control::law::LawError> {
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
        write!(w, "{},{},{}", r.t_s, r.mode, m)?;
        for id in ActuatorId::ALL {
            write!(w, ",{},{}", r.commands.get(id), c.get(id))?;
        }
        writeln!(w)?;
    }
    w.flush()
}
