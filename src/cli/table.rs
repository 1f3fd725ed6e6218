//! `antisurge table`: the benchmark table of docs/benchmarks.md (every plant × applicable law).

use super::locate;
use antisurge::scenario::Scenario;
use antisurge::sim::case::PlantCase;
use anyhow::{Context, Result};
use std::path::PathBuf;

/// Arguments.
#[derive(Debug, clap::Args)]
pub struct TableArgs {
    /// Staircase scenario for the minimum stable throughput (throttle steps).
    #[arg(long, default_value = "throttle-sweep")]
    pub sweep: String,
    /// Staircase for plants whose feed is a fixed mass flow (feed steps).
    #[arg(long, default_value = "feed-sweep")]
    pub feed_sweep: String,
    /// Scenario for effort and recycle energy.
    #[arg(long, default_value = "throttle-closure")]
    pub closure: String,
    /// Configuration directory.
    #[arg(long)]
    pub config_dir: Option<PathBuf>,
    /// Also write the Markdown table to this file.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Instead: drive-torque on this plant against rotor inertia (K1 scaled with J).
    #[arg(long, value_name = "PLANT")]
    pub inertia_sweep: Option<String>,
}

/// Rotor inertias of the sweep, kg·m².
pub const SWEEP_INERTIAS_KG_M2: [f64; 6] = [0.2, 0.5, 1.0, 2.0, 3.0, 5.0];

/// Run the command.
pub fn run(args: &TableArgs) -> Result<()> {
    let cfg = locate::config_dir(args.config_dir.as_deref());
    let plants = locate::list(&cfg.join("plants"))?
        .iter()
        .map(|p| PlantCase::load(p).map_err(anyhow::Error::from))
        .collect::<Result<Vec<_>>>()?;
    let sweep = Scenario::load(&locate::resolve(&cfg, "scenarios", &args.sweep)?)?;
    let feed_sweep = Scenario::load(&locate::resolve(&cfg, "scenarios", &args.feed_sweep)?)?;
    let closure = Scenario::load(&locate::resolve(&cfg, "scenarios", &args.closure)?)?;
    if let Some(name) = &args.inertia_sweep {
        let plant = PlantCase::load(&locate::resolve(&cfg, "plants", name)?)?;
        let rows =
            antisurge::sim::table::inertia_sweep(&plant, &sweep, &closure, &SWEEP_INERTIAS_KG_M2)
                .context("running the inertia sweep")?;
        let md = antisurge::sim::table::inertia_markdown(plant.name(), &rows);
        print!("{md}");
        if let Some(out) = &args.out {
            std::fs::write(out, &md).with_context(|| format!("writing {}", out.display()))?;
        }
        return Ok(());
    }
    eprintln!(
        "running {} and {} on {} plants with every applicable law…",
        sweep.name(),
        closure.name(),
        plants.len()
    );
    let rows = antisurge::sim::table::build(&plants, &sweep, &feed_sweep, &closure)
        .context("building the table")?;
    let md = antisurge::sim::table::markdown(&rows);
    print!("{md}");
    if let Some(out) = &args.out {
        std::fs::write(out, &md).with_context(|| format!("writing {}", out.display()))?;
    }
    Ok(())
}
