//! Issue 12, item 4: a live gain change is bumpless. For every law in the registry, a control
//! node runs a shipped plant it applies to in closed loop at a steady operating point; a
//! reload doubles every bounded gain of the law (`BOUNDED_GAINS` entries of its section), a
//! second one sets them to half the original. Around each reload no command may move by more
//! than 1 % of its actuator's range in one cycle. A run without the reloads is the reference:
//! it shows the law itself moves less than that there, and that the new gains took effect.
//! Before the fix a drive-torque reload stepped the torque by 16 % of the drive's range (the
//! restart dropped the law's extra torque) and a ccv reload by 9.5 % (the spool laws' restart
//! re-referenced the eq. 7 torque schedule and reset the trim).

use crate::common;

use antisurge::control::config::BOUNDED_GAINS;
use antisurge::control::core::{ControlCore, CoreSettings};
use antisurge::control::law::REGISTRY;
use antisurge::control::measurements::OperatorInputs;
use antisurge::control::model::ControlModel;
use antisurge::control::{ControllerConfig, LawId};
use antisurge::node::control::ControlUpdate;
use antisurge::runtime::handoff::monotonic_ns;
use antisurge::runtime::rt_loop::Tick;
use antisurge::sim::case::PlantCase;
use antisurge::vocab::signals::{ActuatorId, SensorId};
use std::sync::atomic::Ordering;

const CYCLES: u64 = 6000;
const PERIOD_NS: u64 = 1_000_000;
/// Reload cycles (1 kHz): the law has settled at the operating point by the first.
const RELOADS: [u64; 2] = [3000, 4500];
/// Cycles after a reload that are checked.
const WINDOW: u64 = 500;
/// Largest move of a command in one cycle around a reload, fraction of the actuator's range.
const MAX_STEP: f64 = 0.01;

/// `config` with every bounded gain of `law`'s section multiplied by `factor`.
fn scaled(config: &ControllerConfig, law: LawId, factor: f64) -> ControllerConfig {
    let section = law.name().replace('-', "_");
    let mut t = toml::Table::try_from(config).expect("config as a table");
    let mut n = 0;
    for key in BOUNDED_GAINS {
        // a dotted path below `[controller]`: section, sub-sections, then the gain
        let parts: Vec<&str> = key.split('.').collect();
        if parts.len() < 2 || parts[0] != section {
            continue;
        }
        let (leaf, path) = parts.split_last().expect("two parts");
        let mut table = &mut t;
        for p in path {
            table = table[*p].as_table_mut().expect("section");
        }
        let v = table[*leaf].as_float().expect("gain");
        table.insert((*leaf).into(), toml::Value::Float(v * factor));
        n += 1;
    }
    assert!(n > 0 || law == LawId::None, "{law}: no bounded gain");
    t.try_into().expect("config from the table")
}

/// Range of an actuator's command on this machine (the 1 % refers to it); NaN where the
/// machine has no such actuator.
fn range(model: &ControlModel, a: ActuatorId) -> f64 {
    match a {
        ActuatorId::RecycleValve | ActuatorId::Throttle => 1.0,
        ActuatorId::DriveTorque => model.drive.rated_torque_nm - model.drive.min_torque_nm,
        ActuatorId::CloseCoupledValve => model.spool.map_or(f64::NAN, |s| 2.0 * s.ccv_max),
        ActuatorId::TipClearance => model.thrust.map_or(f64::NAN, |t| 2.0 * t.modulation_max_m),
    }
}

/// Commands of every cycle, closed loop from the plant's initial state; `reloads` pushes the
/// given settings at the given cycles.
fn run(
    desc: &PlantCase,
    law: LawId,
    reloads: &[(u64, ControllerConfig)],
) -> Vec<[f64; ActuatorId::COUNT]> {
    let (mut plant, inputs) = common::node::plant_at_initial_point(desc);
    let model = antisurge::sim::control_model(desc);
    let settings = CoreSettings::defaults_for(&model);
    let torque = plant.truth().load_torque_nm;
    let core = ControlCore::new(
        model.clone(),
        model.controller.clone(),
        settings,
        law,
        torque,
    )
    .expect("core");
    let op = OperatorInputs {
        speed_setpoint_rad_s: desc.file.drive.nominal_speed_rad_s,
        throttle_demand: inputs.throttle_process,
        flow_setpoint_kg_s: f64::NAN,
        recycle_manual: inputs.recycle_manual,
    };
    let common::node::BareNode {
        mut node,
        sensors,
        outputs,
        health,
        updates: mut updates_tx,
        retired: mut retired_rx,
        ..
    } = common::node::bare_node(core, op, PERIOD_NS);
    let dt = PERIOD_NS as f64 * 1e-9;
    let t0 = monotonic_ns();
    let mut plant_inputs = inputs;
    let mut out = Vec::with_capacity(CYCLES as usize);
    for k in 0..CYCLES {
        if let Some((_, cfg)) = reloads.iter().find(|(at, _)| *at == k) {
            let update = ControlUpdate {
                reconf: ControlCore::prepare(&model, cfg.clone(), law).expect("prepare"),
                settings,
                auto: true,
                op,
            };
            assert!(updates_tx.push(update).is_ok());
        }
        let now = t0 + k * PERIOD_NS;
        let snap = plant.sensors();
        for id in SensorId::ALL {
            sensors.publish(id, snap.values[id.index()], now);
        }
        node.cycle(Tick {
            cycle: k,
            deadline_ns: now,
            wake_ns: now,
        });
        while retired_rx.pop().is_ok() {}
        let o = outputs.latest().expect("outputs");
        plant_inputs.commands = o.commands;
        // the process closes its throttle towards surge: the law is working at the reloads
        plant_inputs.throttle_process = (inputs.throttle_process - 0.1 * k as f64 * dt).max(0.45);
        plant.step(&plant_inputs, dt);
        out.push(o.commands.values);
    }
    assert_eq!(
        health.updates_applied.load(Ordering::Relaxed),
        reloads.len() as u64,
        "{law}: reloads applied"
    );
    assert_eq!(node.core().law(), law);
    out
}

/// Largest per-cycle move of actuator `a` over cycles `from..to`, fraction of its range.
fn worst_step(
    trace: &[[f64; ActuatorId::COUNT]],
    a: ActuatorId,
    r: f64,
    from: u64,
    to: u64,
) -> f64 {
    (from as usize..to as usize)
        .map(|k| (trace[k][a.index()] - trace[k - 1][a.index()]).abs() / r)
        .filter(|s| s.is_finite())
        .fold(0.0, f64::max)
}

#[test]
fn a_live_gain_change_moves_no_command_more_than_one_percent_per_cycle_for_every_law() {
    let mut checked = Vec::new();
    for d in REGISTRY {
        let law = d.id;
        let desc = common::PLANTS
            .iter()
            .map(|s| common::plant(s))
            .find(|p| law.supports(p.file.model))
            .unwrap_or_else(|| panic!("no shipped plant for {law}"));
        let model = antisurge::sim::control_model(&desc);
        let cfg = model.controller.clone();
        let reloads = [
            (RELOADS[0], scaled(&cfg, law, 2.0)),
            (RELOADS[1], scaled(&cfg, law, 0.5)),
        ];
        let reference = run(&desc, law, &[]);
        let changed = run(&desc, law, &reloads);
        let mut effect = 0.0f64;
        for a in ActuatorId::ALL {
            let r = range(&model, a);
            if !(r.is_finite() && r > 0.0) {
                continue;
            }
            for at in RELOADS {
                let own = worst_step(&reference, a, r, at, at + WINDOW);
                let step = worst_step(&changed, a, r, at, at + WINDOW);
                assert!(
                    own < MAX_STEP,
                    "{law} on {}: {a:?} moves {:.3} % per cycle without a reload: no steady point",
                    desc.file.name,
                    100.0 * own
                );
                assert!(
                    step <= MAX_STEP,
                    "{law} on {}: {a:?} stepped {:.3} % of its range in one cycle after the gain change at cycle {at}",
                    desc.file.name,
                    100.0 * step
                );
            }
            for k in RELOADS[0] as usize..CYCLES as usize {
                let diff = (changed[k][a.index()] - reference[k][a.index()]).abs() / r;
                if diff.is_finite() {
                    effect = effect.max(diff);
                }
            }
        }
        if law != LawId::None && d.actuators.iter().count() > 0 {
            assert!(
                effect > 0.0,
                "{law}: the gain change had no effect on any command"
            );
        }
        checked.push((law, effect));
    }
    assert_eq!(checked.len(), REGISTRY.len());
    eprintln!("law, largest deviation from the reference run after the reloads (fraction of range): {checked:?}");
}
