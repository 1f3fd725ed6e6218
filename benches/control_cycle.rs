//! One control cycle (supervision + observer + law + speed loop + surge detector) for every law
//! on its benchmark plant.
//!
//! Two measurements:
//! - criterion: mean time of `ControlCore::cycle` on a fixed sensor snapshot;
//! - a closed-loop latency run (printed first): the plant runs the throttle-closure scenario's
//!   inputs, every cycle is timed individually with the monotonic clock, and p50/p99/max are
//!   reported (target: p99 under 1 µs). `cargo bench --bench control_cycle`.

use antisurge::control::core::{ControlCore, CoreSettings};
use antisurge::control::measurements::{OperatorInputs, RawSensors};
use antisurge::control::LawId;
use antisurge::plant::{PlantInputs, SimPlant};
use antisurge::runtime::handoff::monotonic_ns;
use antisurge::sim::case::PlantCase;
use criterion::{criterion_group, Criterion};
use std::path::Path;

const PAIRS: [(&str, LawId); 8] = [
    ("bohagen2007_plenum", LawId::None),
    ("bohagen2007_plenum", LawId::DriveTorque),
    ("kvangardsnes2009_recycle", LawId::RecyclePi),
    ("hemchi2016_recycle", LawId::RecycleFl),
    ("liaw2004_spool", LawId::Ccv),
    ("liaw2004_spool", LawId::ThrottleBackstep),
    ("liaw2004_spool", LawId::Robust),
    ("sanadgol2006_tip", LawId::TipSliding),
];

struct Setup {
    core: ControlCore,
    plant: SimPlant,
    inputs: PlantInputs,
    op: OperatorInputs,
}

/// The drive-torque law again, predicting over 0.5 ms of loop delay (as on the HIL bus).
const COMPENSATED: (&str, LawId, f64) = ("bohagen2007_plenum", LawId::DriveTorque, 0.5);

fn setup(stem: &str, law: LawId, delay_compensation_ms: f64) -> Setup {
    let desc = PlantCase::load(Path::new(&format!(
        "{}/config/plants/{stem}.toml",
        env!("CARGO_MANIFEST_DIR")
    )))
    .expect("plant");
    let init = desc.file.initial;
    let inputs = PlantInputs {
        throttle_process: init.throttle,
        recycle_manual: init.recycle_valve,
        feed: init.feed,
        ..PlantInputs::default()
    };
    let plant = SimPlant::new(&desc, &inputs).expect("plant");
    let model = antisurge::sim::control_model(&desc);
    let settings = CoreSettings::defaults_for(&model);
    let mut cfg = model.controller.clone();
    cfg.drive_torque.delay_compensation_ms = delay_compensation_ms;
    let core =
        ControlCore::new(model, cfg, settings, law, plant.truth().load_torque_nm).expect("core");
    let op = OperatorInputs {
        speed_setpoint_rad_s: desc.file.drive.nominal_speed_rad_s,
        throttle_demand: init.throttle,
        flow_setpoint_kg_s: f64::NAN,
        recycle_manual: init.recycle_valve,
    };
    Setup {
        core,
        plant,
        inputs,
        op,
    }
}

fn latency_report() {
    println!(
        "closed-loop cycle latency (throttle 60 % → 20 % over 2 s at t = 5 s, 20 s at 1 kHz):"
    );
    println!(
        "{:<28} {:<18} {:>8} {:>8} {:>8}",
        "plant", "law", "p50 ns", "p99 ns", "max ns"
    );
    let runs = PAIRS.iter().map(|&(s, l)| (s, l, 0.0)).chain([COMPENSATED]);
    for (stem, law, comp_ms) in runs {
        let mut s = setup(stem, law, comp_ms);
        let dt = 1e-3;
        let mut samples: Vec<u64> = Vec::with_capacity(20_000);
        for k in 0..20_000 {
            let t = k as f64 * dt;
            let throttle = if t < 5.0 {
                0.6
            } else {
                (0.6 - 0.2 * (t - 5.0)).max(0.2)
            };
            s.op.throttle_demand = throttle;
            let raw = RawSensors::fresh(s.plant.sensors());
            let t0 = monotonic_ns();
            let out = s.core.cycle(t, &raw, &s.op);
            let t1 = monotonic_ns();
            samples.push(t1 - t0);
            s.inputs.commands = out.commands;
            s.inputs.throttle_process = throttle;
            s.plant.step(&s.inputs, dt);
        }
        samples.sort_unstable();
        let q = |p: f64| samples[((p * samples.len() as f64) as usize).min(samples.len() - 1)];
        let name = if comp_ms > 0.0 {
            format!("{} +{comp_ms} ms", law.name())
        } else {
            law.name().to_string()
        };
        println!(
            "{:<28} {:<18} {:>8} {:>8} {:>8}",
            stem,
            name,
            q(0.5),
            q(0.99),
            samples[samples.len() - 1]
        );
    }
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("control_cycle");
    g.sample_size(30);
    for (stem, law) in PAIRS {
        let mut s = setup(stem, law, 0.0);
        let raw = RawSensors::fresh(s.plant.sensors());
        let mut t = 0.0;
        g.bench_function(format!("{}/{}", stem, law.name()), |b| {
            b.iter(|| {
                t += 1e-3;
                std::hint::black_box(s.core.cycle(t, &raw, &s.op))
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);

fn main() {
    latency_report();
    benches();
    Criterion::default().configure_from_args().final_summary();
}
