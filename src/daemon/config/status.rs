//! `[status]`: status line, statistics, status socket, metrics, HMI and the DCS block.

use super::problem::KeyProblem;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// `[status]`: periodic status line and statistics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StatusSection {
    /// Status line to the log every this many seconds (0: never).
    #[serde(default = "d_status_s")]
    pub log_interval_s: f64,
    /// Write cycle statistics (JSON) here at exit, if set.
    #[serde(default)]
    pub stats_file: Option<PathBuf>,
    /// Status socket for `antisurge status` (relative: under `$RUNTIME_DIRECTORY`, else
    /// `./out/`). Default `status.sock`.
    #[serde(default)]
    pub socket: Option<PathBuf>,
    /// Where the surge counter, safety-on shifts and last mode are kept across restarts
    /// (default `$STATE_DIRECTORY`, else `./out/state`).
    #[serde(default)]
    pub state_dir: Option<PathBuf>,
    /// Prometheus/OpenMetrics endpoint `host:port` (default `127.0.0.1:9650`; empty: off).
    /// Only loopback unless `metrics_allow_remote = true`.
    #[serde(default)]
    pub metrics_listen: Option<String>,
    /// Allow the metrics endpoint on a non-loopback address (read-only data).
    #[serde(default)]
    pub metrics_allow_remote: bool,
    /// Web HMI `host:port` (default `127.0.0.1:9651`; empty: off). Beyond loopback only
    /// with `[status.tls]` and the operator token file in place.
    #[serde(default)]
    pub hmi_listen: Option<String>,
    /// `[status.tls]`: serve the HMI over HTTPS (certificate and key, PEM).
    #[serde(default)]
    pub tls: Option<super::tls::TlsSection>,
    /// Modbus TCP server block for the DCS, `host:port` (default: off). Read-only input
    /// registers; register map in README.md.
    #[serde(default)]
    pub modbus_listen: Option<String>,
    /// File holding the operator token (root-owned, mode 0640 root:antisurge); without it
    /// operator actions are refused. Default `/etc/antisurge/operator.token`.
    #[serde(default)]
    pub operator_token_file: Option<PathBuf>,
}

fn d_status_s() -> f64 {
    10.0
}

impl Default for StatusSection {
    fn default() -> Self {
        StatusSection {
            log_interval_s: d_status_s(),
            stats_file: None,
            socket: None,
            state_dir: None,
            metrics_listen: None,
            metrics_allow_remote: false,
            hmi_listen: None,
            tls: None,
            modbus_listen: None,
            operator_token_file: None,
        }
    }
}

impl StatusSection {
    /// The section's own rules: the status-line interval, and where the HMI and the metrics
    /// endpoint may listen with the TLS files ([`super::tls::bind_problems`]).
    pub fn validate(&self) -> Vec<KeyProblem> {
        let mut out = super::tls::bind_problems(self);
        let s = self.log_interval_s;
        if !(s.is_finite() && s >= 0.0) {
            out.insert(
                0,
                KeyProblem::error(
                    "status.log_interval_s",
                    format!("{s} s must be ≥ 0 (0: no status line)"),
                ),
            );
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_pass_and_a_negative_interval_is_refused() {
        let mut s = StatusSection::default();
        assert_eq!(s.log_interval_s, 10.0);
        assert!(s.validate().is_empty());
        s.log_interval_s = -1.0;
        assert_eq!(s.validate()[0].key, "status.log_interval_s");
    }
}
