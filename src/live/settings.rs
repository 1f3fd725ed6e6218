//! `[status]`: status line, statistics, status socket, metrics, HMI and the DCS block: the
//! settings of `live/`, kept here with the parts that use them (the daemon's config
//! re-exports them; the TLS part is `tls_settings`).

use super::tls_settings as tls;

use crate::config::problem::KeyProblem;
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
    pub tls: Option<tls::TlsSection>,
    /// Modbus TCP server block for the DCS, `host:port` (default: off). Read-only input
    /// registers; register map in README.md.
    #[serde(default)]
    pub modbus_listen: Option<String>,
    /// Most DCS clients connected at once (default: [`default_modbus_max_connections`], 64,
    /// fewer under a small open-file limit). At the cap a newcomer takes the place of a
    /// connection that never sent a request, else of one idle for 1 s or more, else it is
    /// closed at once.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modbus_max_connections: Option<u32>,
    /// A DCS connection that sends no request for this long is closed (default 30 s).
    #[serde(default = "d_modbus_idle_timeout_s")]
    pub modbus_idle_timeout_s: f64,
    /// Requests one DCS connection may make per second (burst: as many at once); faster
    /// clients are slowed down, not served sooner (default 20; the block changes every
    /// 100 ms).
    #[serde(default = "d_modbus_max_requests_per_s")]
    pub modbus_max_requests_per_s: f64,
    /// File holding the operator token (root-owned, mode 0640 root:antisurge); without it
    /// operator actions are refused. Default `/etc/antisurge/operator.token`.
    #[serde(default)]
    pub operator_token_file: Option<PathBuf>,
}

fn d_status_s() -> f64 {
    10.0
}

fn d_modbus_idle_timeout_s() -> f64 {
    30.0
}

fn d_modbus_max_requests_per_s() -> f64 {
    20.0
}

/// Descriptors kept for everything but the DCS block (event log, buses, status socket,
/// metrics, HMI and their clients) when deriving the default connection cap.
pub const FD_RESERVE: u64 = 256;

/// Upper end of the default DCS connection cap (a DCS has a handful of stations).
pub const MODBUS_MAX_CONNECTIONS_DEFAULT: u32 = 64;

/// The default DCS connection cap for an open-file limit of `nofile`: 64, or a quarter of
/// what the limit leaves after [`FD_RESERVE`] descriptors if that is less (at least 1).
pub fn default_modbus_max_connections(nofile: u64) -> u32 {
    let spare = nofile.saturating_sub(FD_RESERVE) / 4;
    spare.clamp(1, u64::from(MODBUS_MAX_CONNECTIONS_DEFAULT)) as u32
}

/// The process's soft open-file limit (`RLIMIT_NOFILE`), 1024 if it cannot be read.
pub fn open_file_limit() -> u64 {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes into the struct we pass and has no other effect.
    if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut r) } == 0 {
        r.rlim_cur
    } else {
        1024
    }
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
            modbus_max_connections: None,
            modbus_idle_timeout_s: d_modbus_idle_timeout_s(),
            modbus_max_requests_per_s: d_modbus_max_requests_per_s(),
            operator_token_file: None,
        }
    }
}

impl StatusSection {
    /// The DCS block's connection cap: `modbus_max_connections`, else the default for the
    /// process's open-file limit.
    pub fn modbus_max_connections(&self) -> u32 {
        self.modbus_max_connections
            .unwrap_or_else(|| default_modbus_max_connections(open_file_limit()))
    }

    /// The section's own rules: the status-line interval, where the HMI and the metrics
    /// endpoint may listen with the TLS files ([`tls::bind_problems`]), and the DCS block's
    /// limits. (The ports the service unit can bind are the daemon's check:
    /// `daemon::config::unit::bind_problems`.)
    pub fn validate(&self) -> Vec<KeyProblem> {
        let mut out = tls::bind_problems(self);
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
        out.extend(self.dcs_limit_problems(open_file_limit()));
        out
    }

    /// The DCS block's limits against an open-file limit of `nofile`.
    pub fn dcs_limit_problems(&self, nofile: u64) -> Vec<KeyProblem> {
        let mut out = Vec::new();
        if let Some(n) = self.modbus_max_connections {
            let room = nofile.saturating_sub(FD_RESERVE);
            if n == 0 {
                out.push(
                    KeyProblem::error(
                        "status.modbus_max_connections",
                        "0 connections would refuse every DCS client".to_string(),
                    )
                    .with_hint("leave it out for the default (64), or set 1 or more"),
                );
            } else if u64::from(n) > room {
                out.push(
                    KeyProblem::error(
                        "status.modbus_max_connections",
                        format!(
                            "{n} connections do not fit the open-file limit of {nofile} \
                             ({FD_RESERVE} are kept for the daemon's own files and links)"
                        ),
                    )
                    .with_hint(
                        "lower it, or raise LimitNOFILE= in a drop-in (systemctl edit antisurge)",
                    ),
                );
            }
        }
        let t = self.modbus_idle_timeout_s;
        if !(t.is_finite() && t > 0.0 && t <= 3600.0) {
            out.push(
                KeyProblem::error(
                    "status.modbus_idle_timeout_s",
                    format!("{t} s must be > 0 and ≤ 3600"),
                )
                .with_hint("e.g. modbus_idle_timeout_s = 30"),
            );
        }
        let r = self.modbus_max_requests_per_s;
        if !(r.is_finite() && (1.0..=1000.0).contains(&r)) {
            out.push(
                KeyProblem::error(
                    "status.modbus_max_requests_per_s",
                    format!("{r} requests/s must be between 1 and 1000"),
                )
                .with_hint("e.g. modbus_max_requests_per_s = 20 (the block changes every 100 ms)"),
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

    #[test]
    fn the_dcs_connection_cap_follows_the_open_file_limit() {
        assert_eq!(default_modbus_max_connections(1024), 64);
        assert_eq!(default_modbus_max_connections(512), 64);
        assert_eq!(default_modbus_max_connections(320), 16);
        assert_eq!(default_modbus_max_connections(100), 1);
        let mut s = StatusSection {
            modbus_max_connections: Some(1000),
            ..StatusSection::default()
        };
        let p = s.dcs_limit_problems(1024);
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].key, "status.modbus_max_connections");
        assert!(p[0].message.contains("1024"), "{}", p[0].message);
        assert!(s.dcs_limit_problems(4096).is_empty());
        s.modbus_max_connections = Some(0);
        s.modbus_idle_timeout_s = 0.0;
        s.modbus_max_requests_per_s = f64::NAN;
        let keys: Vec<_> = s
            .dcs_limit_problems(4096)
            .into_iter()
            .map(|p| p.key)
            .collect();
        assert_eq!(
            keys,
            [
                "status.modbus_max_connections",
                "status.modbus_idle_timeout_s",
                "status.modbus_max_requests_per_s"
            ]
        );
    }
}
