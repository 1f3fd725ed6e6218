//! `antisurge plant`: the simulated skid as a node on the same buses and register map as
//! the controller. Runs the configured scenario in real time from the controller's first
//! heartbeat, writing `trace.csv` as it goes (from a writer thread) and `summary.json` at
//! the end.

use super::config::{self, Transport};
use super::field::{spawn_plant_links, PlantLinks};
use super::service::scenario_path;
use crate::node::plant::{CommandSource, PlantNode, PlantStatus, SensorSink};
use crate::runtime::handoff::{monotonic_ns, CommandBoard, HeartbeatBoard, SnapshotBoard, Wakeup};
use crate::runtime::rt_loop::{run_periodic, setup_current_thread, CycleStats};
use crate::scenario::Scenario;
use crate::sim::PlantRun;
use anyhow::{anyhow, bail, Context, Result};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Options of `antisurge plant`.
#[derive(Debug, Clone, Default)]
pub struct PlantOptions {
    /// Main config file (the same file as the controller's).
    pub config: PathBuf,
    /// Scenario (overrides `simulation.scenario`).
    pub scenario: Option<String>,
    /// Output directory (overrides `simulation.out_dir`).
    pub out_dir: Option<PathBuf>,
}

/// Run the plant node until the scenario ends (or SIGTERM/SIGINT).
pub fn run(opts: &PlantOptions) -> Result<()> {
    super::service::ignore_sigxfsz();
    let l = config::load(&opts.config).map_err(|p| {
        crate::config::ConfigInvalid(format!(
            "the configuration is invalid:\n{}",
            super::service::format_problems(&p)
        ))
    })?;
    if l.config.bus.transport != Transport::Field {
        bail!("`antisurge plant` is a bus node: set [bus] transport = \"field\" with a signal map (the in-process plant runs inside `antisurge run`)");
    }
    let scenario_name = opts
        .scenario
        .clone()
        .unwrap_or_else(|| l.config.simulation.scenario.clone());
    let scenario = Scenario::load(&scenario_path(&l, &scenario_name))
        .map_err(|e| crate::config::ConfigInvalid(e.to_string()))?;
    let out_dir = opts
        .out_dir
        .clone()
        .or_else(|| {
            l.config
                .simulation
                .out_dir
                .as_ref()
                .map(|p| config::resolve(&l.main_path, p))
        })
        .unwrap_or_else(|| {
            PathBuf::from(format!(
                "out/plant-{}-{}",
                l.plant
                    .as_ref()
                    .map_or(l.machine.name.as_str(), |p| p.name()),
                scenario.name()
            ))
        });
    let links = PlantLinks {
        commands: Arc::new(CommandBoard::default()),
        heartbeat: Arc::new(HeartbeatBoard::default()),
        snapshots: Arc::new(SnapshotBoard::default()),
        wake: Arc::new(Wakeup::new().context("eventfd")?),
    };
    let rt = crate::runtime::rt_loop::io_runtime(&l.config.cycle, "antisurge-plant-io")?;
    let stop = Arc::new(AtomicBool::new(false));
    let status = Arc::new(PlantStatus::default());
    let (shutdown_tx, shutdown_rx) = tokio::sync::watch::channel(false);
    let mut tasks = tokio::task::JoinSet::new();
    rt.block_on(async { spawn_plant_links(&l, &mut tasks, &links, shutdown_rx) })?;

    // the plant thread
    let desc = l.sim_plant().map_err(|e| anyhow!("{e}"))?.clone();
    // the device watchdog time: the map's Modbus watchdog contract, else the simulation's
    let hb_ms = l
        .signal_map
        .watchdog
        .modbus
        .and_then(|w| w.timeout_ms)
        .unwrap_or(l.config.simulation.heartbeat_timeout_ms);
    let hold = l.config.simulation.hold_after_end;
    let rt_settings = l.config.cycle;
    let (st, stp, lk) = (Arc::clone(&status), Arc::clone(&stop), links.clone());
    // the trace streams to out_dir/trace.csv from a writer thread started here, of ordinary
    // priority (the plant thread below takes real-time priority and only hands it the rows)
    let (handoff, writer) = crate::node::plant::start_trace(&desc, &scenario, &out_dir)
        .map_err(|e| anyhow!("plant trace: {e}"))?;
    let plant = std::thread::Builder::new()
        .name("antisurge-plant".into())
        .spawn(move || -> Result<crate::sim::SimResult> {
            let granted = setup_current_thread(&rt_settings);
            tracing::info!(target: "rt", "plant thread: {granted}");
            let run = PlantRun::handing_trace_to(&desc, &scenario, handoff)
                .map_err(|e| anyhow!("{e}"))?;
            let mut node = PlantNode::new(
                &desc,
                run,
                CommandSource::Bus {
                    commands: lk.commands,
                    heartbeat: Arc::clone(&lk.heartbeat),
                },
                SensorSink::Bus {
                    snapshots: lk.snapshots,
                    wake: lk.wake,
                },
                hb_ms,
                hold,
                st,
            );
            let period = (scenario.file.control_period_s * 1e9).round() as u64;
            let stats = CycleStats::default();
            run_periodic(period, &stp, &stats, |_| node.step(monotonic_ns()));
            let law = lk.heartbeat.latest().map(|h| h.law).and_then(|c| {
                crate::control::LawId::ALL
                    .iter()
                    .find(|l| l.code() == c)
                    .copied()
            });
            crate::node::plant::finish_trace(&mut node, writer, law.map_or("unknown", |l| l.name()))
                .map_err(|e| anyhow!("{e}"))
        })?;

    // wait for the end of the scenario or a signal
    rt.block_on(async {
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
        let mut int = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::interrupt())?;
        let mut tick = tokio::time::interval(Duration::from_millis(50));
        let mut last_fs = false;
        loop {
            tokio::select! {
                _ = term.recv() => break,
                _ = int.recv() => break,
                _ = tick.tick() => {
                    let fs = status.field_failsafe.load(Ordering::Relaxed);
                    if fs != last_fs {
                        if fs {
                            let age_s = status.failsafe_entry_age_us.load(Ordering::Relaxed) as f64 * 1e-6;
                            tracing::warn!(target: "plant", "controller heartbeat lost: device watchdog saw no heartbeat change for {age_s:.3} s (timeout {hb_ms:.0} ms), field devices in their own fail-safe (recycle valve open, drive on its governor, thrust centred)");
                        } else {
                            tracing::info!(target: "plant", "controller heartbeat back: setpoints applied again");
                        }
                        last_fs = fs;
                    }
                    if plant.is_finished() { break; }
                }
            }
        }
        anyhow::Ok(())
    })?;
    stop.store(true, Ordering::Relaxed);
    let result = plant
        .join()
        .map_err(|_| anyhow!("plant thread panicked"))??;
    let _ = shutdown_tx.send(true);
    rt.block_on(async { while tasks.join_next().await.is_some() {} });
    let mut result = result;
    result.summary.field_failsafe_entries = Some(status.failsafe_entries.load(Ordering::Relaxed));
    result.summary.device_watchdog = status.device_watchdog();
    crate::sim::output::write_summary(&out_dir, &result.summary).map_err(|e| anyhow!("{e}"))?;
    let s = &result.summary;
    println!(
        "plant {} · scenario {} · law {}: {} · {} surge cycles · min flow {:.3} kg/s · field fail-safe entered {} time(s)\n  files in {}/",
        s.plant, s.scenario, s.law,
        if s.surge_cycles == 0 && !s.flow_reversal { "no surge" } else { "SURGE" },
        s.surge_cycles, s.min_flow_kg_s, status.failsafe_entries.load(Ordering::Relaxed),
        out_dir.display()
    );
    Ok(())
}
