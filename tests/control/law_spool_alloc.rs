//! The seed 003 laws (`ccv`, `throttle-backstep`, `robust`) must not allocate per cycle: a
//! counting global allocator counts this thread's allocations over many `start`/`update` calls
//! with a moving throttle demand (the equilibrium is recomputed every cycle).

use crate::common;

use common::counting_alloc::allocations;

use std::hint::black_box;

use antisurge::control::law::api::LawInputs;
use antisurge::control::law::Law;
use antisurge::control::measurements::{Measurements, OperatorInputs};
use antisurge::control::LawId;
use antisurge::vocab::signals::{ActuatorCommands, ActuatorId};

#[test]
fn spool_laws_do_not_allocate_per_cycle() {
    let desc = common::plant("liaw2004_spool");
    let model = antisurge::sim::control_model(&desc);
    let sp = desc.file.spool.expect("spool");
    let p01 = sp.ambient_pressure_pa;
    for id in [LawId::Ccv, LawId::ThrottleBackstep, LawId::Robust] {
        let mut law = Law::new(id, &model.controller, &model).expect("law");
        let mut current = ActuatorCommands::default();
        current.set(ActuatorId::DriveTorque, 0.0);
        let before = allocations();
        let mut acc = 0.0;
        for k in 0..5000 {
            let t = k as f64 * 1e-3;
            let opening = 0.6 - 0.4 * (t / 5.0).min(1.0);
            let phi = 0.5 + 0.3 * (20.0 * t).sin();
            let psi = 0.5 + 0.2 * (20.0 * t).cos();
            let w = 1.0 + 0.05 * (3.0 * t).sin();
            let pd = p01 + psi * sp.pressure_scale_pa;
            let m = Measurements {
                t_s: t,
                p_suction_pa: p01,
                p_discharge_pa: pd,
                omega_rad_s: w * sp.speed_scale_rad_s,
                t_suction_k: 293.15,
                m_kg_s: phi * sp.flow_scale_kg_s,
                m_measured_kg_s: phi * sp.flow_scale_kg_s,
                m_observer_kg_s: f64::NAN,
                flow_map: phi * sp.flow_scale_kg_s,
                pressure_ratio: pd / p01,
                recycle_position: f64::NAN,
                throttle_position: opening,
                thrust_position_m: f64::NAN,
                dp_suction_dt_pa_s: 0.0,
                dp_discharge_dt_pa_s: 0.0,
                flow_fallback: false,
            };
            let op = OperatorInputs {
                speed_setpoint_rad_s: desc.file.drive.nominal_speed_rad_s,
                throttle_demand: opening,
                flow_setpoint_kg_s: f64::NAN,
                recycle_manual: f64::NAN,
            };
            let inputs = LawInputs {
                m: &m,
                op: &op,
                model: &model,
                history: &antisurge::control::law::api::LoopHistory::EMPTY,
            };
            if k % 1000 == 0 {
                law.start(&inputs, &current);
            }
            let out = law.update(&inputs, 1e-3);
            acc += out.commands.get(ActuatorId::DriveTorque) + out.diagnostic;
        }
        black_box(acc);
        assert!(acc.is_finite(), "{id}");
        assert_eq!(allocations() - before, 0, "{id} allocated");
    }
}
