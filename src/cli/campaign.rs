//! `antisurge campaign`: the robustness campaign of issue 22 (random skids at field-bus loop
//! rates, recycle-pi against baseline-pi and the feasibility oracle).

use super::locate;
use antisurge::campaign::{self, report, CampaignOptions};
use anyhow::{Context, Result};
use std::path::PathBuf;

/// Arguments.
#[derive(Debug, clap::Args)]
pub struct CampaignArgs {
    /// Number of cases (the campaign's cases 0..N).
    #[arg(long, default_value_t = campaign::DEFAULT_CASES)]
    pub cases: usize,
    /// Campaign seed (fixed default: every run of the same seed draws the same skids).
    #[arg(long, default_value_t = campaign::DEFAULT_SEED)]
    pub seed: u64,
    /// Control-line margin, % of surge-line flow (recycle-pi's and baseline-pi's line).
    #[arg(long, default_value_t = campaign::DEFAULT_MARGIN_PCT)]
    pub margin_pct: f64,
    /// The reduced campaign of the CI test: the first 32 cases (every loop rate × every
    /// disturbance on both base plants).
    #[arg(long, conflicts_with = "cases")]
    pub reduced: bool,
    /// Run only case K (to reproduce a failing case) and print it in detail.
    #[arg(long, value_name = "K")]
    pub case: Option<usize>,
    /// Run the case(s) at this loop rate instead of their own, Hz (e.g. `--case 5 --rate-hz
    /// 1000`: the same skid and disturbance at 1 kHz).
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// Also write the results as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Print the summary between the docs/benchmarks.md markers (`<!-- campaign:begin -->`,
    /// `<!-- campaign:end -->`), ready to paste.
    #[arg(long)]
    pub readme: bool,
    /// With `--case`: write every controller's trace and summary (`trace.csv`,
    /// `summary.json`, a row every 5 ms) under this directory, one folder per controller.
    #[arg(long, requires = "case")]
    pub trace: Option<PathBuf>,
    /// Also print every case in a table after the summary.
    #[arg(long, conflicts_with = "readme")]
    pub per_case: bool,
    /// Configuration directory (the base plants are read from its `plants/`).
    #[arg(long)]
    pub config_dir: Option<PathBuf>,
    /// Threads (default: the machine's cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// Run the command.
pub fn run(args: &CampaignArgs) -> Result<()> {
    let cfg = locate::config_dir(args.config_dir.as_deref());
    let bases = campaign::load_bases(&cfg).context("loading the base plants")?;
    let threads = args.threads.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    let opts = CampaignOptions {
        cases: if args.reduced {
            campaign::REDUCED_CASES
        } else {
            args.cases
        },
        seed: args.seed,
        margin_pct: args.margin_pct,
        only_case: args.case,
        threads,
        rate_hz: args.rate_hz,
    };
    let result =
        campaign::run_campaign(&bases, &opts, args.reduced).context("running the campaign")?;
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&result).context("serialising the results")?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(k) = args.case {
        for c in &result.cases {
            print!("{}", report::case_detail(&result, c));
        }
        if let Some(dir) = &args.trace {
            let mut skid = campaign::skid::draw_skid(&bases, args.seed, k)?;
            if let Some(r) = args.rate_hz {
                skid.params.rate_hz = r;
            }
            let law = |l| {
                campaign::runner::run(&skid, campaign::runner::Controller::Law(l), args.margin_pct)
            };
            let laws = [
                law(antisurge::control::law::api::LawId::RecyclePi)?,
                law(antisurge::control::law::api::LawId::BaselinePi)?,
            ];
            for c in campaign::runner::CONTROLLERS {
                let on = campaign::skid_for(c, &skid, [&laws[0], &laws[1]]);
                let (_, sim) = campaign::runner::run_traced(&on, c, args.margin_pct, 0.005)?;
                let out = dir.join(c.name().replace([' ', '+'], ""));
                antisurge::sim::output::write_data(&out, &sim, &skid.plant.map)
                    .with_context(|| format!("writing {}", out.display()))?;
            }
            println!("  traces in {}", dir.display());
        }
        return Ok(());
    }
    let md = report::markdown(&result);
    if args.readme {
        print!("<!-- campaign:begin -->\n{md}<!-- campaign:end -->\n");
    } else {
        print!("{md}");
    }
    if args.per_case {
        print!("\nEvery case:\n\n{}", report::per_case_markdown(&result));
    }
    Ok(())
}
