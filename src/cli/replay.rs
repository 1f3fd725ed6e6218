//! `antisurge replay FILE`: run the control core over a black-box recording.

use antisurge::blackbox::{self, replay};
use antisurge::control::LawId;
use antisurge::daemon::config;
use anyhow::{anyhow, Context, Result};
use std::path::PathBuf;

/// Arguments.
#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// A black-box file (`blackbox-<reason>-cycle<N>.csv`, written next to the event log), or
    /// with `--candump` a `candump -l` log.
    pub file: PathBuf,
    /// FILE is a `candump -l` log captured on the skid's bus: its frames are decoded through
    /// the configuration's signal map and DBC (`--config`, default ./config/antisurge.toml)
    /// by the daemon's own receive path and replayed on the configured control period. The
    /// commands compared against are the actuator frames on the bus.
    #[arg(long)]
    pub candump: bool,
    /// With `--candump`: the interface whose frames are imported (default: the first frame's).
    #[arg(long, requires = "candump")]
    pub interface: Option<String>,
    /// Replay with this configuration instead of the recorded one (what would this config
    /// have commanded?). Environment overrides (`ANTISURGE_<SECTION>__<KEY>`) apply as usual.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Replay with this law instead of the recorded one.
    #[arg(long)]
    pub law: Option<String>,
    /// Where to write the pictures of the replayed run (map.svg with the operating point,
    /// timeseries.svg with valves, mode and margin, and with changed settings the recorded
    /// commands beside the replayed ones) and commands.csv (recorded and replayed commands side
    /// by side). Default: out/replay-<FILE's name> (in the temporary directory when the
    /// current one is not writable), as `sim`.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write commands.csv only, no pictures.
    #[arg(long)]
    pub no_plots: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Run the command; exit status 1 when a replay with the recorded settings does not reproduce
/// every command.
pub fn run(args: &ReplayArgs) -> Result<std::process::ExitCode> {
    let load = |cfg_path: &std::path::Path| {
        config::load(cfg_path).map_err(|p| {
            anyhow!(
                "the configuration {} is invalid:\n{}",
                cfg_path.display(),
                p.iter()
                    .map(|p| p.to_string())
                    .collect::<Vec<_>>()
                    .join("\n")
            )
        })
    };
    let (rec, loaded, cfg_path, import) = if args.candump {
        let cfg_path = args
            .config
            .clone()
            .unwrap_or_else(super::daemon::default_config);
        let loaded = load(&cfg_path)?;
        let (rec, stats) = import_candump(&args.file, args.interface.as_deref(), &loaded)?;
        (rec, loaded, cfg_path, Some(stats))
    } else {
        let rec = blackbox::read_file(&args.file)?;
        let cfg_path = args
            .config
            .clone()
            .unwrap_or_else(|| rec.header.config.clone());
        let loaded = load(&cfg_path)?;
        (rec, loaded, cfg_path, None)
    };
    let h = &rec.header;
    let env_overrides =
        std::env::vars().any(|(k, _)| k.starts_with("ANTISURGE_") && k.contains("__"));
    // a bus log carries no settings: it is always replayed with the configuration's
    let recorded =
        import.is_none() && args.config.is_none() && args.law.is_none() && !env_overrides;
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
    let out_dir = args.out.clone().unwrap_or_else(|| {
        let name = format!(
            "replay-{}",
            args.file.file_stem().unwrap_or_default().to_string_lossy()
        );
        let local = PathBuf::from("out");
        if std::fs::create_dir_all(&local).is_ok() {
            local.join(name)
        } else {
            std::env::temp_dir().join("antisurge-out").join(name)
        }
    });
    std::fs::create_dir_all(&out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let csv = out_dir.join("commands.csv");
    replay::write_comparison(&csv, &rec.records, &r)
        .with_context(|| format!("writing {}", csv.display()))?;
    let mut files = vec![csv];
    let mut no_map = false;
    if !args.no_plots {
        let trace = r.trace(&rec.records, &loaded.model);
        // with the recorded settings the commands are the recorded ones: nothing to compare
        let recorded_cmds = (!recorded || r.report.identical_cycles < r.report.cycles)
            .then(|| replay::with_recorded_commands(&trace, &rec.records));
        let rp = &loaded.controller.recycle_pi;
        let machine = super::pictures::Machine {
            map: loaded.model.map.as_ref(),
            surge_line: loaded.model.surge_line,
            recycle: loaded
                .model
                .recycle_valve
                .map(|_| (rp.control_line, rp.trip.margin_pct)),
        };
        no_map = machine.map.is_none();
        let title = format!(
            "replay of {} · {} → {}{}",
            args.file.file_name().unwrap_or_default().to_string_lossy(),
            h.law,
            law.name(),
            if recorded_cmds.is_some() {
                " · replayed commands (dashed) vs recorded (solid, dark)"
            } else {
                ""
            }
        );
        files.extend(super::pictures::draw_run(
            &out_dir,
            &machine,
            &trace,
            &title,
            &[],
            recorded_cmds.as_deref(),
        )?);
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
        if let Some(st) = &import {
            let s = &st.sensor_side;
            println!(
                "  bus log         {} frames of {} over {:.3} s ({} of other interfaces skipped); \
                 sensor frames published {}, unknown id {}, wrong length {}, bad CRC {}, \
                 repeated alive {}, remote/FD/error {}; commands on the bus: {} frames",
                st.frames - st.other_interface,
                st.interface,
                st.span_s,
                st.other_interface,
                s.rx_published,
                s.unknown_id,
                s.wrong_dlc,
                s.bad_crc,
                s.alive_repeated,
                s.remote_frames + s.fd_frames + s.error_frames,
                st.command_side.rx_published,
            );
        }
        println!(
            "  settings        {}",
            if import.is_some() {
                format!(
                    "{} (a bus log carries none); inputs replayed open loop",
                    cfg_path.display()
                )
            } else if recorded {
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
            "  commands        {} of {} cycles bit-identical{}{}",
            rep.identical_cycles,
            rep.cycles,
            rep.first_difference
                .map(|(c, t)| format!("; first difference at cycle {c} (t = {t:.3} s)"))
                .unwrap_or_default(),
            if import.is_some() {
                " to the commands last seen on the bus"
            } else {
                ""
            }
        );
        for a in &rep.actuators {
            println!(
                "  {:<15} {} cycles differ, largest difference {:.4e}",
                a.actuator, a.differing_cycles, a.max_abs_diff
            );
        }
        if no_map {
            println!("  note            the machine description has no speed-line map: no map.svg");
        }
        println!("  written to      {}", out_dir.display());
        for f in &files {
            println!("                  {}", f.display());
        }
    }
    let exact = rep.identical_cycles == rep.cycles || import.is_some();
    Ok(
        if recorded && rep.starts_at_first_cycle && rep.updates_at_cycles.is_empty() && !exact {
            std::process::ExitCode::from(1)
        } else {
            std::process::ExitCode::SUCCESS
        },
    )
}

/// Import a `candump -l` log through the configuration's signal map and DBC.
fn import_candump(
    file: &std::path::Path,
    interface: Option<&str>,
    loaded: &config::Loaded,
) -> Result<(blackbox::Recording, blackbox::candump::ImportStats)> {
    let can = loaded.config.bus.can.as_ref().ok_or_else(|| {
        anyhow!(
            "{}: [bus.can] is missing: a candump log is decoded with the DBC and the signal map's CAN bindings",
            loaded.main_path.display()
        )
    })?;
    let dbc = config::resolve(&loaded.main_path, &can.dbc);
    let bindings = loaded.signal_map.can_bindings();
    if bindings.is_empty() {
        return Err(anyhow!(
            "{}: the signal map binds no CAN signals: nothing in a candump log maps to a sensor",
            loaded.main_path.display()
        ));
    }
    let codec = antisurge::io::can::bus::BusCodec::load(&dbc, &bindings)
        .with_context(|| format!("loading {}", dbc.display()))?;
    let frames = blackbox::candump::read(file)?;
    let imp = blackbox::candump::import(
        &frames,
        std::sync::Arc::new(codec),
        antisurge::daemon::service::blackbox_header(loaded),
        antisurge::daemon::service::operator_inputs(loaded),
        interface,
        file,
    )?;
    Ok((imp.recording, imp.stats))
}
