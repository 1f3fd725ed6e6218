//! `antisurge sim`: run a scenario on a simulated plant and write trace, summary and pictures.

use super::locate;
use antisurge::control::LawId;
use antisurge::scenario::Scenario;
use antisurge::sim::case::PlantCase;
use antisurge::sim::{self, SimOptions, Summary};
use anyhow::{Context, Result};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Defaults of a bare `antisurge sim`.
pub const DEFAULT_PLANT: &str = "kvangardsnes2009";
/// Default scenario.
pub const DEFAULT_SCENARIO: &str = "throttle-closure";
/// Default law.
pub const DEFAULT_LAW: &str = "recycle-pi";

/// Arguments.
#[derive(Debug, clap::Args)]
pub struct SimArgs {
    /// Plant: a name from config/plants (e.g. `kvangardsnes2009`) or a path to a plant file.
    #[arg(long, default_value = DEFAULT_PLANT)]
    pub plant: String,
    /// Machine description the controller runs on (`config/machines/*.toml`; a name or a
    /// path), with the plant file's `[controller]` settings; default: the plant file's own
    /// description. The plant file still simulates the skid.
    #[arg(long)]
    pub machine: Option<String>,
    /// Scenario: a name from config/scenarios (e.g. `throttle-closure`) or a path.
    #[arg(long, default_value = DEFAULT_SCENARIO)]
    pub scenario: String,
    /// Surge law (`none` = open loop).
    #[arg(long, default_value = DEFAULT_LAW)]
    pub law: String,
    /// Output directory (default: out/<plant>-<scenario>-<law>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Configuration directory (default: ./config, $ANTISURGE_CONFIG_DIR, /etc/antisurge).
    #[arg(long)]
    pub config_dir: Option<PathBuf>,
    /// Skip the pictures.
    #[arg(long)]
    pub no_plots: bool,
    /// Print summary.json to stdout instead of the readable summary.
    #[arg(long)]
    pub json: bool,
    /// Loop delay to simulate, control periods: a command acts this many periods after the
    /// sample it was computed from (bus transfers, drive response). Default 0: ideal loop.
    #[arg(long, default_value_t = 0)]
    pub loop_delay_periods: usize,
    /// Extra random loop delay of 0..=N periods per command (jitter).
    #[arg(long, default_value_t = 0)]
    pub loop_delay_jitter_periods: usize,
}

/// Run the command.
pub fn run(args: &SimArgs) -> Result<()> {
    let cfg = locate::config_dir(args.config_dir.as_deref());
    let plant_path = locate::resolve(&cfg, "plants", &args.plant)?;
    let scenario_path = locate::resolve(&cfg, "scenarios", &args.scenario)?;
    let law = LawId::parse_sim(&args.law)?;
    let desc = PlantCase::load(&plant_path)?;
    let scenario = Scenario::load(&scenario_path)?;
    let model = match &args.machine {
        Some(m) => {
            let path = locate::resolve(&cfg, "machines", m)?;
            let machine = antisurge::machine::file::load(&path)?;
            antisurge::control::model::ControlModel::from_machine(&machine, desc.controller.clone())
        }
        None => antisurge::sim::control_model(&desc),
    };
    let uses_drive_torque = law == LawId::DriveTorque
        || scenario
            .law_names
            .iter()
            .any(|n| n.parse::<LawId>().ok() == Some(LawId::DriveTorque));
    if uses_drive_torque {
        // the same gain checks as check-config (sampled speed loop K1·h/J < 1, eq. 8)
        antisurge::control::laws::drive_torque::check_gains(
            &desc.controller.drive_torque,
            &model,
            scenario.file.control_period_s,
        )
        .with_context(|| {
            format!(
                "{}: [controller.drive_torque] refused for a {:.3} ms control period",
                plant_path.display(),
                1e3 * scenario.file.control_period_s
            )
        })?;
    }
    let out_dir = args.out.clone().unwrap_or_else(|| {
        let name = format!("{}-{}-{}", desc.name(), scenario.name(), law.name());
        let local = PathBuf::from("out");
        if std::fs::create_dir_all(&local).is_ok() {
            local.join(name)
        } else {
            // e.g. run from `/` by an ordinary user: the temporary directory instead
            std::env::temp_dir().join("antisurge-out").join(name)
        }
    });

    let started = Instant::now();
    let mut bar: Option<indicatif::ProgressBar> = None;
    let interactive = std::io::stderr().is_terminal();
    let mut progress = |frac: f64| {
        if !interactive {
            return;
        }
        if bar.is_none() && started.elapsed().as_secs_f64() > 1.0 && frac < 0.9 {
            let b = indicatif::ProgressBar::new(1000);
            b.set_style(
                indicatif::ProgressStyle::with_template(
                    "  simulating {bar:40} {percent:>3}%  eta {eta}",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            bar = Some(b);
        }
        if let Some(b) = &bar {
            b.set_position((frac * 1000.0) as u64);
        }
    };
    // the trace streams to out_dir/trace.csv as the run goes: memory bounded whatever the
    // scenario's length (issue 25)
    let (summary, trace) = sim::run_streamed(
        &desc,
        model,
        &scenario,
        SimOptions {
            law,
            loop_delay_periods: args.loop_delay_periods,
            loop_delay_jitter_periods: args.loop_delay_jitter_periods,
            ..SimOptions::default()
        },
        &out_dir,
        &mut progress,
        &mut |_, _| {},
    )
    .with_context(|| format!("simulating {} on {}", scenario.name(), desc.name()))?;
    if let Some(b) = bar.take() {
        b.finish_and_clear();
    }
    let summary_path = sim::output::write_summary(&out_dir, &summary)
        .with_context(|| format!("writing results to {}", out_dir.display()))?;
    let mut files = vec![trace.path.clone(), summary_path];
    if !args.no_plots {
        files.extend(super::pictures::draw_streamed(
            &out_dir,
            &desc,
            &scenario,
            &summary,
            &trace.pictures,
        )?);
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print_summary(&summary, &out_dir, &files);
    }
    Ok(())
}

fn pct(x: f64) -> String {
    if x.is_finite() {
        format!("{:+.1} %", 100.0 * x)
    } else {
        "n/a".into()
    }
}

fn thousands(x: f64) -> String {
    let v = x.round() as i64;
    let s = v.abs().to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push('\u{202f}');
        }
        out.push(c);
    }
    if v < 0 {
        format!("-{out}")
    } else {
        out
    }
}

/// The one-screen terminal summary.
pub fn print_summary(s: &Summary, dir: &Path, files: &[PathBuf]) {
    println!(
        "antisurge sim — plant {} · scenario {} · law {}",
        s.plant, s.scenario, s.law
    );
    println!(
        "  {:.1} s simulated in {:.2} s ({:.0}× real time)\n",
        s.duration_s, s.wall_time_s, s.realtime_factor
    );
    println!("  result          {}", s.verdict);
    if s.failsafe_fraction > 0.0 || s.torque_saturation_fraction > 0.0 {
        let eps: Vec<String> = s
            .failsafe_episodes
            .iter()
            .take(3)
            .map(|e| match e.to_s {
                Some(t) => format!("{:.2}–{t:.2} s", e.from_s),
                None => format!("from {:.2} s", e.from_s),
            })
            .collect();
        println!(
            "  health          fail-safe {:.1} % of cycles{} · torque saturated {:.1} %",
            100.0 * s.failsafe_fraction,
            if eps.is_empty() {
                String::new()
            } else {
                format!(
                    " ({}{})",
                    eps.join(", "),
                    if s.failsafe_episodes.len() > 3 {
                        ", …"
                    } else {
                        ""
                    }
                )
            },
            100.0 * s.torque_saturation_fraction
        );
    }
    let a = &s.closest_approach;
    println!(
        "  closest         from {:.2} s (last event): min flow {:.3} kg/s at {:.2} s · min margin {} at {:.2} s",
        a.from_s,
        a.min_flow_kg_s,
        a.min_flow_at_s,
        pct(a.min_surge_margin),
        a.min_surge_margin_at_s
    );
    println!(
        "  flow            final {:.3} kg/s · throughput min {:.3} kg/s · final pressure ratio {:.3}",
        s.final_flow_kg_s, a.min_throughput_kg_s, s.final_pressure_ratio
    );
    println!(
        "  surge margin    final {}   (distance right of the surge line)",
        pct(s.final_surge_margin)
    );
    let fs = &s.flow_source;
    if fs.fallbacks.is_empty() {
        println!("  flow source     {} (no fallback)", fs.configured);
    } else {
        for (i, f) in fs.fallbacks.iter().enumerate() {
            let span = match f.to_s {
                Some(t) => format!("{:.2}–{t:.2} s", f.from_s),
                None => format!("from {:.2} s to the end", f.from_s),
            };
            println!(
                "  {}observer {span} ({}); its largest error {:+.3} kg/s ({:+.0} % of the true flow)",
                if i == 0 { format!("flow source     {}: ", fs.configured) } else { "                  ".into() },
                f.cause,
                f.observer_max_error_kg_s,
                100.0 * f.observer_max_error_fraction
            );
        }
    }
    match s.settle_time_s {
        Some(t) => println!("  settled         {t:.2} s after the last event"),
        None => println!("  settled         no"),
    }
    let p = &s.actuator_peaks;
    let (lo, hi) = p.drive_torque_cmd_range_nm;
    let mut act = if p.law_drive_torque_nm > 0.0 {
        format!(
            "law torque peak ±{} N·m · drive command {}…{} N·m (rating {})",
            thousands(p.law_drive_torque_nm),
            thousands(lo),
            thousands(hi),
            thousands(p.drive_torque_rating_nm)
        )
    } else {
        format!(
            "drive command {}…{} N·m (rating {})",
            thousands(lo),
            thousands(hi),
            thousands(p.drive_torque_rating_nm)
        )
    };
    if p.recycle_valve_opening > 0.0 {
        act.push_str(&format!(
            " · recycle valve peak {:.0} %",
            100.0 * p.recycle_valve_opening
        ));
    }
    if p.tip_clearance_m > 0.0 {
        act.push_str(&format!(
            " · tip clearance peak {:.0} µm ({:.0} % of nominal)",
            1e6 * p.tip_clearance_m,
            100.0 * p.tip_clearance_m / p.tip_clearance_nominal_m
        ));
    }
    if p.ccv > 0.0 {
        act.push_str(&format!(" · CCV peak {:.3}", p.ccv));
    }
    println!("  actuators       {act}");
    if s.recycle_energy_j > 0.0 {
        println!("  recycle energy  {:.2} MJ", s.recycle_energy_j / 1e6);
    }
    println!("\n  files in {}/", dir.display());
    let names: Vec<String> = files
        .iter()
        .filter_map(|f| f.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect();
    println!("    {}", names.join("  "));
}
