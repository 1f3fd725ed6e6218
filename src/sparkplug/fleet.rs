//! `antisurge fleet-sim N`: N edge nodes in one process against one broker, each a full
//! [`super::task`] node (births, seq/bdSeq, data by exception, events at QoS 1 from its own
//! event log, store-and-forward) fed by its own simulated skid. The skids here are snapshot
//! timelines (a breathing operating point and a throttle closure at a time of their own, with
//! events), not the plant model: the fleet measures the node and the broker, not the
//! control law, and 100 plant models at 1 kHz do not fit on a small test machine.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::settings::SparkplugSection;
use crate::events::event::Event;
use crate::events::{EventLog, EventLogConfig, FsyncPolicy};
use crate::live::server::LiveContext;
use crate::live::snapshot::{FlowSourceNow, LiveBoard, LiveSnapshot};
use crate::runtime::rt_loop::CycleStats;

use super::catalogue::Ranges;
use super::EdgeInputs;

/// What to run.
#[derive(Debug, Clone)]
pub struct FleetOptions {
    /// Edge nodes.
    pub nodes: usize,
    /// How long, s.
    pub duration_s: f64,
    /// The broker and the node settings shared by every node (`edge_node_id` is the prefix:
    /// nodes are `<prefix>-000` …).
    pub sparkplug: SparkplugSection,
    /// Per-node directories (event log, state) go under here.
    pub dir: PathBuf,
    /// An event from each skid every this many seconds (besides its closure).
    pub event_every_s: f64,
}

/// What the fleet did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FleetReport {
    /// Edge nodes.
    pub nodes: usize,
    /// Wall time, s.
    pub wall_s: f64,
    /// CPU time of the process (user + system), s.
    pub cpu_s: f64,
    /// Events written by all skids (each to be delivered at QoS 1).
    pub events_written: u64,
}

/// A skid's operating point at `t_s` with its closure at `closure_s`: deviation %, valve %.
fn skid_point(i: usize, t_s: f64, closure_s: f64) -> (f64, f64) {
    let period = 7.0 + (i % 13) as f64;
    let breathe = 3.0 * (std::f64::consts::TAU * t_s / period + i as f64).sin();
    let dt = t_s - closure_s;
    let closure = if dt < 0.0 {
        0.0
    } else if dt < 2.0 {
        -12.0 * dt / 2.0
    } else {
        -12.0 * (-(dt - 2.0) / 3.0).exp()
    };
    let dev = 12.0 + breathe + closure;
    let valve = (10.0 - 2.0 * closure).clamp(0.0, 100.0);
    (dev, valve)
}

fn cpu_s() -> f64 {
    // SAFETY: getrusage writes into the struct we own
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) } != 0 {
        return f64::NAN;
    }
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    tv(u.ru_utime) + tv(u.ru_stime)
}

/// Run the fleet for `duration_s` and stop every node cleanly.
pub fn run(o: &FleetOptions) -> Result<FleetReport, String> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| e.to_string())?;
    rt.block_on(run_async(o))
}

async fn run_async(o: &FleetOptions) -> Result<FleetReport, String> {
    let (shutdown_tx, shutdown_rx) = tokio::sync::watch::channel(false);
    let mut tasks = tokio::task::JoinSet::new();
    let mut logs = Vec::new();
    let mut skids = Vec::new();
    let start = Instant::now();
    let cpu0 = cpu_s();
    for i in 0..o.nodes {
        let id = format!("{}-{i:03}", o.sparkplug.edge_node_id);
        let dir = o.dir.join(&id);
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let log = EventLog::start(EventLogConfig {
            path: dir.join("events.jsonl"),
            fsync: FsyncPolicy::Never,
            ..EventLogConfig::default()
        })
        .map_err(|e| format!("{id}: event log: {e}"))?;
        let board = Arc::new(LiveBoard::default());
        let (tx, _rx) = rtrb::RingBuffer::new(4);
        let ctx = LiveContext {
            live: Arc::clone(&board),
            commands: Arc::new(Mutex::new(tx)),
            stats: Arc::new(CycleStats::default()),
            links: Arc::new(|| serde_json::json!({})),
            inputs: Arc::new([]),
            events: log.sender(),
            token_file: dir.join("no-token"),
            started: Instant::now(),
            served: Arc::default(),
        };
        let cfg = SparkplugSection {
            enabled: true,
            edge_node_id: id.clone(),
            client_id: Some(format!("fleet-{}-{id}", o.sparkplug.group_id)),
            ..o.sparkplug.clone()
        };
        let inputs = EdgeInputs {
            ctx,
            ranges: Ranges {
                flow: (0.0, 2.0),
                ratio: (1.0, 4.0),
                speed: (0.0, 1500.0),
            },
            state_dir: dir.join("state"),
            events_path: dir.join("events.jsonl"),
        };
        super::spawn(&cfg, inputs, shutdown_rx.clone(), &mut tasks).map_err(|e| e.to_string())?;
        skids.push((i, board, log.sender()));
        logs.push(log);
    }
    // the skids: each its own timeline, snapshots at 50 Hz, events as they happen
    let written = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let mut skid_tasks = tokio::task::JoinSet::new();
    let (skids_stop_tx, skids_stop_rx) = tokio::sync::watch::channel(false);
    for (i, board, events) in skids {
        let mut stop = skids_stop_rx.clone();
        let written = Arc::clone(&written);
        let duration_s = o.duration_s;
        let every = o.event_every_s.max(0.1);
        skid_tasks.spawn(async move {
            let closure_s = 3.0 + (i as f64 * 0.618_034).fract() * (duration_s - 8.0).max(1.0);
            let t0 = Instant::now();
            let mut tick = tokio::time::interval(Duration::from_millis(20));
            let mut next_event = every * (1.0 + (i % 10) as f64 / 10.0);
            let mut closed = false;
            let mut cycle = 0u64;
            loop {
                tokio::select! {
                    _ = tick.tick() => {}
                    _ = stop.changed() => return,
                }
                let t = t0.elapsed().as_secs_f64();
                cycle += 20;
                let (dev, valve) = skid_point(i, t, closure_s);
                board.publish(&LiveSnapshot {
                    cycle,
                    t_ns: (t * 1e9) as u64,
                    mode: crate::vocab::Mode::Auto,
                    law: crate::control::LawId::RecyclePi,
                    flow_source: FlowSourceNow::Orifice,
                    flow_map: 1.0 + dev * 0.01,
                    pressure_ratio: 2.0,
                    m_kg_s: 12.0 + dev * 0.1,
                    omega_rad_s: 1000.0,
                    surge_line_flow: 0.9,
                    control_line_flow: 1.0,
                    trip_line_flow: 0.95,
                    deviation_pct: dev,
                    surge_margin_pct: dev + 10.0,
                    valve_output: valve * 0.01,
                    valve_position: valve * 0.01,
                    ..LiveSnapshot::default()
                });
                if !closed && t >= closure_s {
                    closed = true;
                    let _ = events.send(Event::Note {
                        text: format!("fleet-sim skid {i}: throttle closure at {t:.1} s"),
                    });
                    written.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
                if t >= next_event {
                    next_event += every;
                    let _ = events.send(Event::Note {
                        text: format!("fleet-sim skid {i}: deviation {dev:.2} % at {t:.1} s"),
                    });
                    written.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
            }
        });
    }
    tokio::time::sleep(Duration::from_secs_f64(o.duration_s)).await;
    let _ = skids_stop_tx.send(true);
    while skid_tasks.join_next().await.is_some() {}
    // the nodes forward what is in the logs before they stop
    tokio::time::sleep(Duration::from_millis(1000)).await;
    let _ = shutdown_tx.send(true);
    while tasks.join_next().await.is_some() {}
    let wall_s = start.elapsed().as_secs_f64();
    let cpu = cpu_s() - cpu0;
    for l in logs {
        let _ = l.shutdown();
    }
    Ok(FleetReport {
        nodes: o.nodes,
        wall_s,
        cpu_s: cpu,
        events_written: written.load(std::sync::atomic::Ordering::Relaxed),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_skid_breathes_and_its_closure_pulls_the_deviation_down_then_back() {
        let (before, _) = skid_point(0, 9.9, 10.0);
        let (bottom, valve) = skid_point(0, 12.0, 10.0);
        let (after, _) = skid_point(0, 30.0, 10.0);
        assert!(bottom < before - 5.0, "{before} → {bottom}");
        assert!(valve > 30.0);
        assert!(after > bottom + 8.0, "{bottom} → {after}");
    }
}
