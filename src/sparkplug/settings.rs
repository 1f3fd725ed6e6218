//! `[sparkplug]`: the Sparkplug B edge node (off by default). See README.md "Sparkplug B for
//! the SCADA engineer".

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::config::problem::KeyProblem;

/// `[sparkplug]`: publish the controller to an MQTT broker as a Sparkplug B edge node.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SparkplugSection {
    /// Run the edge node.
    #[serde(default)]
    pub enabled: bool,
    /// The broker, `host:port` (default `127.0.0.1:1883`; 8883 is usual with TLS).
    #[serde(default = "d_broker")]
    pub broker: String,
    /// Sparkplug group id (the second level of every topic).
    #[serde(default = "d_group")]
    pub group_id: String,
    /// Sparkplug edge node id (this controller).
    #[serde(default = "d_node")]
    pub edge_node_id: String,
    /// MQTT client id (default `antisurge-<group>-<edge node>`).
    #[serde(default)]
    pub client_id: Option<String>,
    /// MQTT keep-alive, s: the broker publishes the death certificate (NDEATH) at most 1.5×
    /// this after the daemon is gone.
    #[serde(default = "d_keep_alive")]
    pub keep_alive_s: u16,
    /// How often the snapshot is compared with what was last reported, ms.
    #[serde(default = "d_interval")]
    pub publish_interval_ms: u64,
    /// Report-by-exception deadband of every analogue metric: % of its engineering range
    /// (of the last reported value where the metric has no range).
    #[serde(default = "d_deadband")]
    pub deadband_pct: f64,
    /// Per-metric deadbands, % as `deadband_pct`, by metric name (e.g. `"Deviation" = 0.1`).
    #[serde(default)]
    pub deadbands_pct: BTreeMap<String, f64>,
    /// Accept operator actions in NCMD/DCMD (with the operator token; the HMI's allow-list:
    /// auto, manual, output, ack). Refused and logged otherwise.
    #[serde(default)]
    pub commands_enabled: bool,
    /// MQTT user name, if the broker asks for one.
    #[serde(default)]
    pub username: Option<String>,
    /// File holding the MQTT password (first line), with the token file's rules: a regular,
    /// non-empty file not readable by everyone (mode 0640 root:antisurge).
    #[serde(default)]
    pub password_file: Option<PathBuf>,
    /// CA certificate(s), PEM, to verify the broker: set, the node connects over TLS.
    #[serde(default)]
    pub ca_file: Option<PathBuf>,
    /// Events kept while the broker is away (state directory), oldest dropped beyond.
    #[serde(default = "d_spool")]
    pub store_forward_events: usize,
}

fn d_broker() -> String {
    "127.0.0.1:1883".into()
}
fn d_group() -> String {
    "antisurge".into()
}
fn d_node() -> String {
    "skid-1".into()
}
fn d_keep_alive() -> u16 {
    5
}
fn d_interval() -> u64 {
    100
}
fn d_deadband() -> f64 {
    0.5
}
fn d_spool() -> usize {
    10_000
}

impl Default for SparkplugSection {
    fn default() -> Self {
        SparkplugSection {
            enabled: false,
            broker: d_broker(),
            group_id: d_group(),
            edge_node_id: d_node(),
            client_id: None,
            keep_alive_s: d_keep_alive(),
            publish_interval_ms: d_interval(),
            deadband_pct: d_deadband(),
            deadbands_pct: BTreeMap::new(),
            commands_enabled: false,
            username: None,
            password_file: None,
            ca_file: None,
            store_forward_events: d_spool(),
        }
    }
}

impl SparkplugSection {
    /// The same section with relative file paths taken from `main`'s directory.
    pub fn resolved(&self, main: &Path) -> SparkplugSection {
        SparkplugSection {
            password_file: self
                .password_file
                .as_ref()
                .map(|p| crate::config::paths::resolve(main, p)),
            ca_file: self
                .ca_file
                .as_ref()
                .map(|p| crate::config::paths::resolve(main, p)),
            ..self.clone()
        }
    }

    /// `host` and `port` of the broker.
    pub fn broker_host_port(&self) -> Result<(String, u16), String> {
        let (h, p) = self
            .broker
            .rsplit_once(':')
            .ok_or_else(|| format!("`{}` is not host:port", self.broker))?;
        let port: u16 = p
            .parse()
            .map_err(|_| format!("`{p}` in `{}` is not a port", self.broker))?;
        let h = h.trim_start_matches('[').trim_end_matches(']');
        if h.is_empty() {
            return Err(format!("`{}` has no host", self.broker));
        }
        Ok((h.to_string(), port))
    }

    /// The section's rules (checked when enabled; the metric names of `deadbands_pct`
    /// always).
    pub fn validate(&self) -> Vec<KeyProblem> {
        let mut out = Vec::new();
        for (name, pct) in &self.deadbands_pct {
            if !super::catalogue::is_analogue(name) {
                out.push(
                    KeyProblem::error(
                        format!("sparkplug.deadbands_pct.{name}"),
                        format!("`{name}` is not an analogue metric of this node"),
                    )
                    .with_hint(format!(
                        "known: {}",
                        super::catalogue::analogue_names().join(", ")
                    )),
                );
            } else if !(pct.is_finite() && *pct >= 0.0) {
                out.push(KeyProblem::error(
                    format!("sparkplug.deadbands_pct.{name}"),
                    format!("{pct} % must be ≥ 0"),
                ));
            }
        }
        let d = self.deadband_pct;
        if !(d.is_finite() && d >= 0.0) {
            out.push(KeyProblem::error(
                "sparkplug.deadband_pct",
                format!("{d} % must be ≥ 0"),
            ));
        }
        if !self.enabled {
            return out;
        }
        if let Err(e) = self.broker_host_port() {
            out.push(KeyProblem::error("sparkplug.broker", e));
        }
        if let Err(e) = super::edge::check_id("group_id", &self.group_id) {
            out.push(KeyProblem::error("sparkplug.group_id", e.to_string()));
        }
        if let Err(e) = super::edge::check_id("edge_node_id", &self.edge_node_id) {
            out.push(KeyProblem::error("sparkplug.edge_node_id", e.to_string()));
        }
        if self.keep_alive_s == 0 {
            out.push(KeyProblem::error(
                "sparkplug.keep_alive_s",
                "0 s would disable keep-alive: the broker could not detect a dead node (NDEATH)",
            ));
        }
        if !(10..=60_000).contains(&self.publish_interval_ms) {
            out.push(KeyProblem::error(
                "sparkplug.publish_interval_ms",
                format!("{} ms must be within 10…60000", self.publish_interval_ms),
            ));
        }
        if self.store_forward_events == 0 {
            out.push(KeyProblem::error(
                "sparkplug.store_forward_events",
                "must be ≥ 1",
            ));
        }
        if let Some(f) = &self.password_file {
            if let Some(why) = crate::live::tls_settings::token_file_problem(f) {
                out.push(
                    KeyProblem::error(
                        "sparkplug.password_file",
                        format!("the broker password file has the token file's rules: {why}"),
                    )
                    .with_hint("a regular, non-empty file of mode 0640 root:antisurge"),
                );
            }
            if self.username.is_none() {
                out.push(KeyProblem::error(
                    "sparkplug.username",
                    "a password_file needs a username",
                ));
            }
        }
        if let Some(f) = &self.ca_file {
            if let Err(e) = super::task::ca_roots(f) {
                out.push(KeyProblem::error("sparkplug.ca_file", e));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_off_on_loopback_and_valid() {
        let s = SparkplugSection::default();
        assert!(!s.enabled && !s.commands_enabled);
        assert_eq!(s.broker_host_port(), Ok(("127.0.0.1".into(), 1883)));
        assert!(s.validate().is_empty());
        let on = SparkplugSection { enabled: true, ..s };
        assert!(on.validate().is_empty(), "{:?}", on.validate());
    }

    #[test]
    fn bad_keys_are_named() {
        let mut s = SparkplugSection {
            enabled: true,
            broker: "nohost".into(),
            group_id: "a/b".into(),
            keep_alive_s: 0,
            ..SparkplugSection::default()
        };
        s.deadbands_pct.insert("Deviation".into(), 0.1);
        s.deadbands_pct.insert("Nonsense".into(), 0.1);
        let keys: Vec<String> = s.validate().into_iter().map(|p| p.key).collect();
        assert_eq!(
            keys,
            [
                "sparkplug.deadbands_pct.Nonsense",
                "sparkplug.broker",
                "sparkplug.group_id",
                "sparkplug.keep_alive_s"
            ]
        );
        let dir = tempfile::tempdir().expect("tmp");
        let pw = dir.path().join("pw");
        std::fs::write(&pw, "secret\n").expect("write");
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&pw, std::fs::Permissions::from_mode(0o644)).expect("chmod");
        let s = SparkplugSection {
            enabled: true,
            username: Some("u".into()),
            password_file: Some(pw.clone()),
            ..SparkplugSection::default()
        };
        let p = s.validate();
        assert!(
            p.len() == 1 && p[0].message.contains("readable by everyone"),
            "{p:?}"
        );
        std::fs::set_permissions(&pw, std::fs::Permissions::from_mode(0o640)).expect("chmod");
        assert!(s.validate().is_empty());
    }
}
