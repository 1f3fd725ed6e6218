//! `antisurge bench-matrix`: the control benchmark matrix of docs/benchmarks.md (recycle-pi against the
//! textbook baseline-pi on every recycle plant, two margins, process events and signal faults).

use super::locate;
use antisurge::sim::case::PlantCase;
use anyhow::{Context, Result};
use std::path::PathBuf;

/// Arguments.
#[derive(Debug, clap::Args)]
pub struct BenchMatrixArgs {
    /// Configuration directory.
    #[arg(long)]
    pub config_dir: Option<PathBuf>,
    /// Threads (default: the machine's cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Also write the Markdown to this file.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Run the command.
pub fn run(args: &BenchMatrixArgs) -> Result<()> {
    let cfg = locate::config_dir(args.config_dir.as_deref());
    let plants = locate::list(&cfg.join("plants"))?
        .iter()
        .map(|p| PlantCase::load(p).map_err(anyhow::Error::from))
        .collect::<Result<Vec<_>>>()?;
    let threads = args.threads.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    let rows = antisurge::sim::bench::run_matrix(&plants, &cfg, threads)
        .context("running the benchmark matrix")?;
    let esd =
        antisurge::sim::bench::esd_strokes(&plants, &cfg).context("checking the ESD stroke")?;
    let variants = antisurge::sim::bench::esd_variants_markdown(&cfg)
        .context("running the ESD on the plant variants")?;
    let md = format!(
        "{}\nESD rundown, recycle-pi:\n\n{}{}",
        antisurge::sim::bench::markdown(&rows),
        antisurge::sim::bench::esd_markdown(&esd),
        variants
    );
    print!("{md}");
    if let Some(out) = &args.out {
        std::fs::write(out, &md).with_context(|| format!("writing {}", out.display()))?;
    }
    Ok(())
}
