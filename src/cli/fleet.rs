//! `antisurge fleet-sim N`: N simulated skids, each a full Sparkplug B edge node, against one
//! broker (issue 26's fleet benchmark; `.ci/sparkplug_fleet.sh` runs it with a host).

use anyhow::{anyhow, Result};
use clap::Args;
use std::path::PathBuf;

/// Arguments of `antisurge fleet-sim`.
#[derive(Debug, Args)]
pub struct FleetArgs {
    /// How many edge nodes.
    pub nodes: usize,
    /// How long, s.
    #[arg(long, default_value_t = 60.0)]
    pub duration_s: f64,
    /// The broker, host:port.
    #[arg(long, default_value = "127.0.0.1:1883")]
    pub broker: String,
    /// Sparkplug group id.
    #[arg(long, default_value = "fleet")]
    pub group_id: String,
    /// Edge node ids are `<prefix>-000` …
    #[arg(long, default_value = "skid")]
    pub node_prefix: String,
    /// Per-node event logs and state under here.
    #[arg(long, default_value = "out/fleet")]
    pub dir: PathBuf,
    /// Publish interval of every node, ms (100: 10 Hz).
    #[arg(long, default_value_t = 100)]
    pub publish_interval_ms: u64,
    /// Deadband, % of range (0: every change is reported).
    #[arg(long, default_value_t = 0.0)]
    pub deadband_pct: f64,
    /// An event from each skid every this many seconds (QoS 1).
    #[arg(long, default_value_t = 2.0)]
    pub event_every_s: f64,
    /// MQTT keep-alive, s.
    #[arg(long, default_value_t = 5)]
    pub keep_alive_s: u16,
}

/// Run the fleet and print its report (JSON).
pub fn run(a: &FleetArgs) -> Result<()> {
    let sparkplug = antisurge::daemon::config::SparkplugSection {
        enabled: true,
        broker: a.broker.clone(),
        group_id: a.group_id.clone(),
        edge_node_id: a.node_prefix.clone(),
        keep_alive_s: a.keep_alive_s,
        publish_interval_ms: a.publish_interval_ms,
        deadband_pct: a.deadband_pct,
        ..Default::default()
    };
    let problems = sparkplug.validate();
    if let Some(p) = problems.first() {
        return Err(anyhow!("{}: {}", p.key, p.message));
    }
    let r = antisurge::sparkplug::fleet::run(&antisurge::sparkplug::fleet::FleetOptions {
        nodes: a.nodes,
        duration_s: a.duration_s,
        sparkplug,
        dir: a.dir.clone(),
        event_every_s: a.event_every_s,
    })
    .map_err(|e| anyhow!("{e}"))?;
    println!("{}", serde_json::to_string(&r)?);
    Ok(())
}
