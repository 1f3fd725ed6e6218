//! Issue 3 acceptance: no heap allocation in a control cycle (observer + law + speed loop +
//! supervision + surge detection), for every law on every plant it applies to. A counting
//! global allocator counts allocations made by this thread between two points.

use crate::common;

use antisurge::control::core::{ControlCore, CoreSettings};
use antisurge::control::measurements::{OperatorInputs, RawSensors};
use antisurge::control::LawId;
use antisurge::plant::{PlantInputs, SimPlant};
use common::counting_alloc::allocations;

#[test]
fn counting_allocator_counts() {
    let before = allocations();
    let v: Vec<u64> = Vec::with_capacity(16);
    std::hint::black_box(&v);
    assert!(
        allocations() > before,
        "the counter must see a Vec allocation"
    );
}

#[test]
fn control_cycle_does_not_allocate_for_any_law() {
    let mut checked = 0;
    for stem in common::PLANTS {
        let desc = common::plant(stem);
        let init = desc.file.initial;
        for law in LawId::ALL {
            if !law.supports(desc.file.model) {
                continue;
            }
            let (mut plant, inputs) = common::node::plant_at_initial_point(&desc);
            let model = antisurge::sim::control_model(&desc);
            let settings = CoreSettings::defaults_for(&model);
            let cfg = model.controller.clone();
            let torque = plant.truth().load_torque_nm;
            let mut core = ControlCore::new(model, cfg, settings, law, torque).expect("core");
            let op = OperatorInputs {
                speed_setpoint_rad_s: desc.file.drive.nominal_speed_rad_s,
                throttle_demand: init.throttle,
                flow_setpoint_kg_s: f64::NAN,
                recycle_manual: init.recycle_valve,
            };
            let dt = 1e-3;
            // warm up (first cycles may initialise), then count over many cycles while the
            // plant moves (throttle closing) so the law's branches are exercised
            let mut plant_inputs = inputs;
            for k in 0..3000 {
                let t = k as f64 * dt;
                let raw = RawSensors::fresh(plant.sensors());
                let before = allocations();
                let out = core.cycle(t, &raw, &op);
                let after = allocations();
                if k >= 10 {
                    assert_eq!(after, before, "{stem} / {law}: allocation in cycle {k}");
                }
                plant_inputs.commands = out.commands;
                plant_inputs.throttle_process = (init.throttle - 0.1 * t).max(0.45);
                plant.step(&plant_inputs, dt);
            }
            checked += 1;
        }
    }
    assert!(checked >= 10, "plant × law pairs checked: {checked}");
}

/// Issue 23: the vote of redundant transmitters is allocation-free: three Δp transmitters
/// (one frozen, one biased, then one failing), two voted pressures, through a closure.
#[test]
fn voting_redundant_transmitters_does_not_allocate() {
    use antisurge::control::vote::VoteLimits;
    use antisurge::vocab::signals::SensorId;
    let desc = common::plant("kvangardsnes2009_recycle");
    let init = desc.file.initial;
    let inputs = PlantInputs {
        throttle_process: init.throttle,
        recycle_manual: init.recycle_valve,
        feed: init.feed,
        ..PlantInputs::default()
    };
    let mut plant = SimPlant::new(&desc, &inputs).expect("plant");
    let model = antisurge::sim::control_model(&desc);
    let mut settings = CoreSettings::defaults_for(&model);
    settings.vote.per_sensor[SensorId::OrificeDp.index()] = Some(VoteLimits::defaults(3));
    settings.vote.per_sensor[SensorId::PDischarge.index()] = Some(VoteLimits::defaults(2));
    let cfg = model.controller.clone();
    let torque = plant.truth().load_torque_nm;
    let mut core = ControlCore::new(model, cfg, settings, LawId::RecyclePi, torque).expect("core");
    let op = OperatorInputs {
        speed_setpoint_rad_s: desc.file.drive.nominal_speed_rad_s,
        throttle_demand: init.throttle,
        flow_setpoint_kg_s: f64::NAN,
        recycle_manual: init.recycle_valve,
    };
    let dt = 1e-3;
    let mut plant_inputs = inputs;
    let mut frozen = f64::NAN;
    let mut degraded = false;
    for k in 0..4000 {
        let t = k as f64 * dt;
        let s = plant.sensors();
        let mut raw = RawSensors::fresh(s);
        let dp = s.get(SensorId::OrificeDp);
        if k == 1000 {
            frozen = dp;
        }
        let b = if k >= 1000 { frozen } else { dp * 1.001 };
        let c = if k >= 3000 { f64::NAN } else { dp * 1.2 };
        raw.spare.set(SensorId::OrificeDp, 1, b, 0.0);
        raw.spare.set(SensorId::OrificeDp, 2, c, 0.0);
        raw.spare
            .set(SensorId::PDischarge, 1, s.get(SensorId::PDischarge), 0.0);
        let before = allocations();
        let out = core.cycle(t, &raw, &op);
        let after = allocations();
        if k >= 10 {
            assert_eq!(after, before, "allocation in cycle {k}");
        }
        degraded |= core.margin_shift().target > 0.0;
        plant_inputs.commands = out.commands;
        plant_inputs.throttle_process = (init.throttle - 0.1 * t).max(0.45);
        plant.step(&plant_inputs, dt);
    }
    assert!(degraded, "the vote went degraded (its branches ran)");
}

#[test]
fn the_cycle_trigger_and_the_triggered_loop_do_not_allocate() {
    use antisurge::runtime::handoff::monotonic_ns;
    use antisurge::runtime::rt_loop::CycleStats;
    use antisurge::runtime::trigger::{run_triggered, CycleTrigger};
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;

    // the bus task's side: noting trigger messages and firing
    let trigger = Arc::new(CycleTrigger::new());
    trigger.arm(0b11);
    let before = allocations();
    for k in 0..1000u64 {
        trigger.note(0b01, k);
        trigger.note(0b10, k);
    }
    assert_eq!(allocations(), before, "note/fire allocated");
    assert_eq!(trigger.count(), 1000);

    // the control thread's side: waiting on the futex, fires and deadlines, 2-ms period
    let stats = CycleStats::default();
    let stop = AtomicBool::new(false);
    let f = Arc::clone(&trigger);
    let sender = std::thread::spawn(move || {
        for _ in 0..50 {
            std::thread::sleep(std::time::Duration::from_millis(2));
            f.note(0b11, monotonic_ns());
        }
    });
    let before = allocations();
    let n = run_triggered(2_000_000, &trigger, &stop, &stats, |t| t.cycle < 79);
    let allocated = allocations() - before;
    sender.join().expect("sender");
    assert_eq!(n, 80);
    assert_eq!(allocated, 0, "the triggered loop allocated");
    let r = stats.report();
    assert!(r.cycles_by_input > 0 && r.cycles_by_deadline > 0, "{r:?}");
    assert_eq!(r.cycles_by_input + r.cycles_by_deadline, 80);
    assert!(!stop.load(Ordering::Relaxed));
}
