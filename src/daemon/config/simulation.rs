//! `[simulation]`: the simulated skid, in-process or as `antisurge plant`.

use super::problem::KeyProblem;
use crate::io::modbus::ModbusServerConfig;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// `[simulation]`: the simulated skid, in-process or as `antisurge plant`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimulationSection {
    /// Scenario name (`config/scenarios`) or file, relative to the main config file.
    #[serde(default = "d_scenario")]
    pub scenario: String,
    /// Where `antisurge plant` streams `trace.csv` and writes `summary.json` when the scenario
    /// ends (`antisurge run`'s in-process plant takes `--out DIR` instead).
    #[serde(default)]
    pub out_dir: Option<PathBuf>,
    /// Field devices go to their own fail-safe when no controller heartbeat arrived for this
    /// long, ms.
    #[serde(default = "d_hb_timeout")]
    pub heartbeat_timeout_ms: f64,
    /// Keep running (holding the final scenario state) after the scenario ends.
    #[serde(default)]
    pub hold_after_end: bool,
    /// The plant node also serves its signals as a Modbus TCP server.
    #[serde(default)]
    pub modbus_server: Option<ModbusServerConfig>,
}

fn d_scenario() -> String {
    "hold".into()
}
fn d_hb_timeout() -> f64 {
    100.0
}

impl Default for SimulationSection {
    fn default() -> Self {
        SimulationSection {
            scenario: d_scenario(),
            out_dir: None,
            heartbeat_timeout_ms: d_hb_timeout(),
            hold_after_end: false,
            modbus_server: None,
        }
    }
}

impl SimulationSection {
    /// The section's own rules.
    pub fn validate(&self) -> Vec<KeyProblem> {
        let t = self.heartbeat_timeout_ms;
        if t.is_finite() && t > 0.0 {
            return Vec::new();
        }
        vec![KeyProblem::error(
            "simulation.heartbeat_timeout_ms",
            format!("{t} ms must be positive"),
        )]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_pass_and_a_zero_heartbeat_timeout_is_refused() {
        let mut s = SimulationSection::default();
        assert_eq!(s.scenario, "hold");
        assert!(s.validate().is_empty());
        s.heartbeat_timeout_ms = 0.0;
        assert_eq!(s.validate()[0].key, "simulation.heartbeat_timeout_ms");
    }
}
