//! The field faults reach the control thread through the handle the daemon passes in (no
//! process-wide state): a fault a link task raises is in the fault word of the next cycle's
//! outputs (the heartbeat's `Faults`, the Modbus watchdog's register), a slow link widens the
//! control line, and a second node beside it sees none of it.

use crate::common;

use antisurge::control::core::{ControlCore, CoreSettings};
use antisurge::control::measurements::OperatorInputs;
use antisurge::control::LawId;
use antisurge::plant::SimPlant;
use antisurge::runtime::handoff::monotonic_ns;
use antisurge::runtime::rt_loop::Tick;
use antisurge::vocab::faults::{FaultCategory, FieldLinkKind};
use antisurge::vocab::signals::SensorId;

fn node() -> (common::node::BareNode, SimPlant) {
    let desc = common::plant("kvangardsnes2009_recycle");
    let (plant, inputs) = common::node::plant_at_initial_point(&desc);
    let model = antisurge::sim::control_model(&desc);
    let settings = CoreSettings::defaults_for(&model);
    let core = ControlCore::new(
        model.clone(),
        model.controller.clone(),
        settings,
        LawId::RecyclePi,
        plant.truth().load_torque_nm,
    )
    .expect("core");
    let op = OperatorInputs {
        speed_setpoint_rad_s: desc.file.drive.nominal_speed_rad_s,
        throttle_demand: inputs.throttle_process,
        flow_setpoint_kg_s: f64::NAN,
        recycle_manual: inputs.recycle_manual,
    };
    (common::node::bare_node(core, op, 1_000_000), plant)
}

/// Run `n` cycles from cycle `k0` on the plant's (held) readings; the last outputs' fault word.
fn cycles(b: &mut common::node::BareNode, plant: &SimPlant, t0: u64, k0: u64, n: u64) -> u32 {
    let snap = plant.sensors();
    for k in k0..k0 + n {
        let now = t0 + k * 1_000_000;
        for id in SensorId::ALL {
            b.sensors.publish(id, snap.values[id.index()], now);
        }
        b.node.cycle(Tick {
            cycle: k,
            deadline_ns: now,
            wake_ns: now,
        });
    }
    b.outputs.latest().expect("outputs").faults
}

#[test]
fn a_field_fault_raised_on_the_handle_is_in_the_next_outputs_and_nowhere_else() {
    let (mut a, plant) = node();
    let (mut b, _) = node();
    let t0 = monotonic_ns();
    let field_bits = FaultCategory::FieldWriteFailed.bit();
    assert_eq!(cycles(&mut a, &plant, t0, 0, 50) & field_bits, 0, "healthy");
    a.field.raise(FaultCategory::FieldWriteFailed);
    a.field.link_down(FieldLinkKind::Modbus, true);
    let word = cycles(&mut a, &plant, t0, 50, 1);
    assert_eq!(
        word & FaultCategory::FieldWriteFailed.bit(),
        FaultCategory::FieldWriteFailed.bit(),
        "{word:#x}"
    );
    assert_eq!(
        cycles(&mut b, &plant, t0, 0, 51) & field_bits,
        0,
        "the node beside it has its own handle"
    );
    a.field.clear(FaultCategory::FieldWriteFailed);
    assert_eq!(
        cycles(&mut a, &plant, t0, 51, 1) & FaultCategory::FieldWriteFailed.bit(),
        0,
        "cleared on the next cycle"
    );
    // a slow link asks the core to widen the control line (the slow-link policy)
    assert_eq!(a.node.core().margin_shift().target, 0.0);
    a.field.raise(FaultCategory::FieldLinkSlow);
    cycles(&mut a, &plant, t0, 52, 1);
    assert!(a.node.core().margin_shift().target > 0.0);
    assert_eq!(b.node.core().margin_shift().target, 0.0);
}
