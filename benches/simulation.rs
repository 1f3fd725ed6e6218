//! 60 simulated seconds of closed-loop simulation (`antisurge::sim::run`: plant, 1 kHz control
//! core with law `none` — speed loop only — surge detector, trace every 5 ms), per plant.
//!
//! - `sim_60s/throttle_closure/<plant>`: the throttle-closure scenario stretched to 60 s:
//!   throttle 60 % → 20 % over 2 s at t = 5 s; with law `none` every plant is in deep surge
//!   for the remaining 53 s, the worst case for the adaptive integrators.
//! - `sim_60s/feed_drop/<plant>` (recycle plants): feed 100 % → 60 % over 1 s at t = 5 s.
//!
//! Target (issue): 60 simulated seconds of any plant in under 0.3 s (≥ 200× real time) on a
//! 2-core machine. Before measuring, each case runs once and prints its wall time, real-time
//! factor and surge count from the run's own summary.
//!
//! Run: `cargo bench --bench simulation`.

use antisurge::control::LawId;
use antisurge::plant::file::PlantDescription;
use antisurge::scenario::Scenario;
use antisurge::sim::{run, SimOptions};
use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::Duration;

const PLANTS: [&str; 5] = [
    "bohagen2007_plenum",
    "kvangardsnes2009_recycle",
    "hemchi2016_recycle",
    "sanadgol2006_tip",
    "liaw2004_spool",
];

const THROTTLE_CLOSURE_60S: &str = r#"
name = "throttle-closure-60s"
description = "Throttle 60 % -> 20 % over 2 s at t = 5 s, 60 s (benches/simulation.rs)"
duration_s = 60.0

[initial]
throttle = 0.6

[[event]]
at_s = 5.0
ramp = { signal = "throttle", to = 0.2, over_s = 2.0 }
"#;

const FEED_DROP_60S: &str = r#"
name = "feed-drop-60s"
description = "Feed 100 % -> 60 % over 1 s at t = 5 s, 60 s (benches/simulation.rs)"
duration_s = 60.0

[[event]]
at_s = 5.0
ramp = { signal = "feed", to = 0.6, over_s = 1.0 }
"#;

fn scenario(text: &str) -> Scenario {
    let path = Path::new("benches/simulation.rs");
    let file = antisurge::config::toml_file::parse(text, path).unwrap_or_else(|e| panic!("{e}"));
    Scenario::from_file(file, path, text).unwrap_or_else(|e| panic!("{e}"))
}

fn plant(stem: &str) -> PlantDescription {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("config/plants")
        .join(format!("{stem}.toml"));
    PlantDescription::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

fn options() -> SimOptions {
    SimOptions {
        law: LawId::None,
        ..SimOptions::default()
    }
}

fn benches(c: &mut Criterion) {
    let cases = [
        (
            "throttle_closure",
            scenario(THROTTLE_CLOSURE_60S),
            &PLANTS[..],
        ),
        ("feed_drop", scenario(FEED_DROP_60S), &PLANTS[1..3]),
    ];
    let mut g = c.benchmark_group("sim_60s");
    for (name, sc, stems) in &cases {
        for stem in *stems {
            let desc = plant(stem);
            let r = run(&desc, sc, options(), &mut |_| {}).unwrap_or_else(|e| panic!("{e}"));
            let s = &r.summary;
            eprintln!(
                "{name}/{stem}: one run {:.3} s wall, {:.0}x real time, {} surge cycles, {} flow reversals",
                s.wall_time_s, s.realtime_factor, s.surge_cycles, s.flow_reversals
            );
            g.bench_function(format!("{name}/{stem}"), |b| {
                b.iter(|| run(black_box(&desc), black_box(sc), options(), &mut |_| {}))
            });
        }
    }
    g.finish();
}

criterion_group! {
    name = simulation;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(4));
    targets = benches
}
criterion_main!(simulation);
