//! `antisurge replay FILE`: run the control core over a black-box recording.

use antisurge::blackbox::{self, replay};
use antisurge::control::LawId;
use antisurge::daemon::config;
use anyhow::{anyhow, Context, Result};
use std::path::PathBuf;

/// Arguments.
#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// A black-box file (`blackbox-<reason>-cycle<N>.csv`, written next to the event log).
    pub file: PathBuf,
    /// Replay with this configuration instead of the recorded one (what would this config
    /// have commanded?). Environment overrides (`ANTISURGE_<SECTION>__<KEY>`) apply as usual.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Replay with this law instead of the recorded one.
    #[arg(long)]
    pub law: Option<String>,
    /// Write recorded and replayed commands side by side here (CSV).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Run the command; exit status 1 when a replay with the recorded settings does not reproduce
/// every command.
pub fn run(args: &ReplayArgs) -> Result<std::process::ExitCode> {
    let rec = blackbox::read_file(&args.file)?;
    let h = &rec.header;
    let cfg_path = args.config.clone().unwrap_or_else(|| h.config.clone());
    let loaded = config::load(&cfg_path).map_err(|p| {
        anyhow!(
            "the configuration {} is invalid:\n{}",
            cfg_path.display(),
            p.iter()
                .map(|p| p.to_string())
                .collect::<Vec<_>>()
                .join("\n")
        )
    })?;
    let env_overrides =
        std::env::vars().any(|(k, _)| k.starts_with("ANTISURGE_") && k.contains("__"));
    let recorded = args.config.is_none() && args.law.is_none() && !env_overrides;
    let law: LawId = match &args.law {
        Some(l) => l.parse()?,
        None => h.law.parse()?,
    };
    let controller = if recorded {
        h.controller.clone()
    } else {
        loaded.controller.clone()
    };
    let r = replay::replay(
        &rec,
        replay::ReplaySetup {
            model: loaded.model.clone(),
            controller,
            settings: loaded.core,
            law,
            recorded_settings: recorded,
        },
    )
    .map_err(|e| anyhow!("{e}"))
    .context("building the control core")?;
    if let Some(out) = &args.out {
        replay::write_comparison(out, &rec.records, &r)
            .with_context(|| format!("writing {}", out.display()))?;
    }
    let rep = &r.report;
    if args.json {
        println!("{}", serde_json::to_string_pretty(rep)?);
    } else {
        println!(
            "antisurge replay — {} ({} cycles, written on {}, law {} → {})",
            args.file.display(),
            rep.cycles,
            h.reason,
            h.law,
            law.name()
        );
        println!(
            "  settings        {}",
            if recorded {
                "as recorded".to_string()
            } else {
                format!(
                    "changed ({}): open loop over the recorded inputs",
                    cfg_path.display()
                )
            }
        );
        if !rep.starts_at_first_cycle {
            println!("  note            the recording starts mid-run: the core starts fresh, so the first cycles differ");
        }
        if !rep.updates_at_cycles.is_empty() {
            println!(
                "  note            settings were reloaded at cycles {:?} (not recorded): the replay keeps its settings",
                rep.updates_at_cycles
            );
        }
        println!(
            "  commands        {} of {} cycles bit-identical{}",
            rep.identical_cycles,
            rep.cycles,
            rep.first_difference
                .map(|(c, t)| format!("; first difference at cycle {c} (t = {t:.3} s)"))
                .unwrap_or_default()
        );
        for a in &rep.actuators {
            println!(
                "  {:<15} {} cycles differ, largest difference {:.4e}",
                a.actuator, a.differing_cycles, a.max_abs_diff
            );
        }
        if let Some(out) = &args.out {
            println!("  side by side in {}", out.display());
        }
    }
    let exact = rep.identical_cycles == rep.cycles;
    Ok(
        if recorded && rep.starts_at_first_cycle && rep.updates_at_cycles.is_empty() && !exact {
            std::process::ExitCode::from(1)
        } else {
            std::process::ExitCode::SUCCESS
        },
    )
}
