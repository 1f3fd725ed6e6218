//! Issue 12, item 3: transactional reconfiguration. For every plant × law, a control node runs
//! a plant in closed loop; reloads are built off the control thread
//! ([`ControlCore::prepare`]) and swapped in at a cycle boundary. The control thread's cycles
//! (`ControlNode::cycle`) must not allocate, neither for an accepted gain change, nor for a
//! law switch; a refused reload (a law that does not apply) never reaches the thread. The
//! replaced parts come back on the retired ring and are dropped here.

use crate::common;

use antisurge::control::core::{ControlCore, CoreSettings};
use antisurge::control::measurements::OperatorInputs;
use antisurge::control::LawId;
use antisurge::node::control::ControlUpdate;
use antisurge::runtime::handoff::monotonic_ns;
use antisurge::runtime::rt_loop::Tick;
use antisurge::vocab::signals::SensorId;
use common::counting_alloc::heap_ops;
use std::sync::atomic::Ordering;

#[test]
fn reloads_allocate_nothing_on_the_control_thread_for_every_law_and_plant() {
    let mut checked = 0;
    let mut refused = 0;
    for stem in common::PLANTS {
        let desc = common::plant(stem);
        let init = desc.file.initial;
        let laws: Vec<LawId> = LawId::ALL
            .into_iter()
            .filter(|l| l.supports(desc.file.model))
            .collect();
        for &law in &laws {
            let (mut plant, inputs) = common::node::plant_at_initial_point(&desc);
            let model = antisurge::sim::control_model(&desc);
            let settings = CoreSettings::defaults_for(&model);
            let cfg = model.controller.clone();
            let torque = plant.truth().load_torque_nm;
            let core =
                ControlCore::new(model.clone(), cfg.clone(), settings, law, torque).expect("core");
            let op = OperatorInputs {
                speed_setpoint_rad_s: desc.file.drive.nominal_speed_rad_s,
                throttle_demand: init.throttle,
                flow_setpoint_kg_s: f64::NAN,
                recycle_manual: init.recycle_valve,
            };
            let period_ns = 1_000_000;
            let common::node::BareNode {
                mut node,
                sensors,
                outputs,
                health,
                updates: mut updates_tx,
                retired: mut retired_rx,
                ..
            } = common::node::bare_node(core, op, period_ns);
            // the other law for the switch: the next applicable one
            let other = laws[(laws.iter().position(|l| *l == law).expect("law") + 1) % laws.len()];
            let mut gains = cfg.clone();
            gains.recycle_pi.pi.kp_per_map_flow *= 1.5;
            gains.derivative_filter_hz *= 0.8;
            gains.detector = Default::default();
            let update = |c: &antisurge::control::ControllerConfig, l: LawId| ControlUpdate {
                reconf: ControlCore::prepare(&model, c.clone(), l).expect("prepare"),
                settings,
                auto: true,
                op,
            };
            // a refused reload fails here, off the control thread, and is never pushed
            for l in LawId::ALL {
                if !l.supports(desc.file.model) {
                    assert!(ControlCore::prepare(&model, cfg.clone(), l).is_err());
                    refused += 1;
                }
            }
            let dt = 1e-3;
            let t0 = monotonic_ns();
            let mut plant_inputs = inputs;
            let mut worst = 0u64;
            for k in 0..3000u64 {
                match k {
                    1000 => assert!(updates_tx.push(update(&gains, law)).is_ok()),
                    2000 => assert!(updates_tx.push(update(&cfg, other)).is_ok()),
                    _ => {}
                }
                let now = t0 + k * period_ns;
                let snap = plant.sensors();
                for id in SensorId::ALL {
                    sensors.publish(id, snap.values[id.index()], now);
                }
                let tick = Tick {
                    cycle: k,
                    deadline_ns: now,
                    wake_ns: now,
                };
                let before = heap_ops();
                node.cycle(tick);
                let after = heap_ops();
                if k >= 10 {
                    worst = worst.max(after - before);
                    assert_eq!(
                        after,
                        before,
                        "{stem} / {law} → {other}: heap operation on the control thread in cycle {k}"
                    );
                }
                // the configuration task drops what came back
                while retired_rx.pop().is_ok() {}
                let out = outputs.latest().expect("outputs");
                plant_inputs.commands = out.commands;
                plant_inputs.throttle_process = (init.throttle - 0.1 * k as f64 * dt).max(0.45);
                plant.step(&plant_inputs, dt);
            }
            assert_eq!(
                health.updates_applied.load(Ordering::Relaxed),
                2,
                "{stem} / {law}"
            );
            assert_eq!(node.core().law(), other, "{stem} / {law}");
            assert_eq!(worst, 0);
            checked += 1;
        }
    }
    assert!(checked >= 10, "plant × law pairs checked: {checked}");
    assert!(refused >= 1, "no inapplicable law to refuse");
}
