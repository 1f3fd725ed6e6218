//! Cost of advancing each benchmark plant.
//!
//! - `rk4/<plant>`: one fixed RK4 step (1 ms) of the plant's `OdeSystem` at its initial steady
//!   state (4 RHS evaluations): the raw cost of the model equations.
//! - `ros2/<plant>`: one fixed ROS2 step (1 ms) of the two recycle plants at their initial
//!   steady state (finite-difference Jacobian, LU, 2 solves).
//! - `sim_plant_step/<plant>`: one `SimPlant::step` over a 1 ms control period with the plant's
//!   configured real-time integration (RK4 with sub-steps, or error-controlled ROS2), inputs
//!   held at the initial steady state.
//! - `sim_plant_step_surge/<plant>`: the same for the recycle plants in open-loop deep surge
//!   (throttle commanded to 20 %, torque held): every iteration advances the plant by another
//!   1 ms, so the figure is the mean over surge cycles, where the adaptive ROS2 sub-steps most.
//!
//! Run: `cargo bench --bench plant_step`.

use antisurge::plant::{PlantInputs, SimPlant};
use antisurge::sim::case::PlantCase;
use antisurge::solver::{rk4, rosenbrock, OdeSystem};
use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::SVector;
use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

const PLANTS: [&str; 5] = [
    "bohagen2007_plenum",
    "kvangardsnes2009_recycle",
    "hemchi2016_recycle",
    "sanadgol2006_tip",
    "liaw2004_spool",
];

/// Control period, s.
const DT: f64 = 1e-3;

fn load(stem: &str) -> (PlantCase, PlantInputs, SimPlant) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("config/plants")
        .join(format!("{stem}.toml"));
    let desc = PlantCase::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let init = desc.file.initial;
    let inputs = PlantInputs {
        throttle_process: init.throttle,
        recycle_manual: init.recycle_valve,
        feed: init.feed,
        ..PlantInputs::default()
    };
    let plant = SimPlant::new(&desc, &inputs).unwrap_or_else(|e| panic!("{stem}: {e}"));
    (desc, inputs, plant)
}

fn rk4_step<const N: usize, S: OdeSystem<N>>(sys: &S, x: &SVector<f64, N>) -> SVector<f64, N> {
    rk4::step(black_box(sys), 0.0, black_box(x), DT)
}

fn benches(c: &mut Criterion) {
    let plants: Vec<(&str, PlantInputs, SimPlant)> = PLANTS
        .iter()
        .map(|&stem| {
            let (_, inputs, plant) = load(stem);
            (stem, inputs, plant)
        })
        .collect();

    let mut g = c.benchmark_group("rk4");
    for (stem, _, plant) in &plants {
        match plant {
            SimPlant::PlenumDuct(p) => {
                g.bench_function(*stem, |b| b.iter(|| rk4_step(&p.model, &p.x)))
            }
            SimPlant::Recycle(p) => g.bench_function(*stem, |b| b.iter(|| rk4_step(p, &p.x))),
            SimPlant::TipClearance(p) => g.bench_function(*stem, |b| b.iter(|| rk4_step(p, &p.x))),
            SimPlant::Spool(p) => g.bench_function(*stem, |b| b.iter(|| rk4_step(p, &p.x))),
        };
    }
    g.finish();

    let mut g = c.benchmark_group("ros2");
    for (stem, _, plant) in &plants {
        if let SimPlant::Recycle(p) = plant {
            g.bench_function(*stem, |b| {
                b.iter(|| rosenbrock::step(black_box(p), 0.0, black_box(&p.x), DT))
            });
        }
    }
    g.finish();

    let mut g = c.benchmark_group("sim_plant_step");
    for (stem, inputs, plant) in &plants {
        let mut p = plant.clone();
        g.bench_function(*stem, |b| b.iter(|| p.step(black_box(inputs), DT)));
        let (x0, x1) = (plant.truth(), p.truth());
        assert!(
            (x1.m_kg_s - x0.m_kg_s).abs() <= 1e-3 * x0.m_kg_s.abs().max(1e-9),
            "{stem}: drifted from its steady state: {} -> {} kg/s",
            x0.m_kg_s,
            x1.m_kg_s
        );
    }
    g.finish();

    let mut g = c.benchmark_group("sim_plant_step_surge");
    for (stem, inputs, plant) in &plants {
        if !matches!(plant, SimPlant::Recycle(_)) {
            continue;
        }
        let surge_inputs = PlantInputs {
            throttle_process: 0.2,
            ..*inputs
        };
        let mut p = plant.clone();
        // 3 s: past the onset, into the limit cycle
        for _ in 0..3000 {
            p.step(&surge_inputs, DT);
        }
        g.bench_function(*stem, |b| b.iter(|| p.step(black_box(&surge_inputs), DT)));
        let t = p.truth();
        assert!(
            t.m_kg_s.is_finite() && t.p_discharge_pa.is_finite(),
            "{stem}: {t:?}"
        );
    }
    g.finish();
}

criterion_group! {
    name = plant_step;
    config = Criterion::default()
        .sample_size(30)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    targets = benches
}
criterion_main!(plant_step);
