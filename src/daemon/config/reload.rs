//! `[reload]`: how a changed configuration reaches the running daemon, and which keys a
//! reload can apply live.

use super::problem::KeyProblem;
use serde::{Deserialize, Serialize};

/// `[reload]`: how a changed configuration reaches the running daemon.
///
/// `systemctl reload antisurge` (check-config, then SIGHUP) is the default and the one way
/// that can report a rejected file. Watching the files is opt-in: an editor's half-written
/// file must never be applied, so a watched change is applied only once every config file has
/// stayed unchanged for `settle_ms` and did not change while it was read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReloadSection {
    /// Reload by itself when the main file or `conf.d/*.toml` changes.
    #[serde(default)]
    pub watch_files: bool,
    /// A watched change is applied after the files stayed unchanged this long, ms (100–60000).
    #[serde(default = "d_settle_ms")]
    pub settle_ms: f64,
}

fn d_settle_ms() -> f64 {
    1000.0
}

impl Default for ReloadSection {
    fn default() -> Self {
        ReloadSection {
            watch_files: false,
            settle_ms: d_settle_ms(),
        }
    }
}

impl ReloadSection {
    /// The section's own rules.
    pub fn validate(&self) -> Vec<KeyProblem> {
        let settle = self.settle_ms;
        if settle.is_finite() && (100.0..=60_000.0).contains(&settle) {
            return Vec::new();
        }
        vec![KeyProblem::error(
            "reload.settle_ms",
            format!("{settle} ms is outside 100–60000 ms"),
        )
        .with_hint("1000: a change is applied once the files stayed unchanged for a second")]
    }
}

/// The keys that cannot change while the daemon runs (a reload reports them).
pub const RESTART_KEYS: &[&str] = &[
    "plant",
    "machine",
    "cycle",
    "bus",
    "event_log",
    "simulation",
    "status",
    "reload",
    "sparkplug",
];

/// Is `key` (dotted) applied live on reload?
pub fn is_live_key(key: &str) -> bool {
    !RESTART_KEYS
        .iter()
        .any(|r| key == *r || key.starts_with(&format!("{r}.")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settle_bounds() {
        let mut r = ReloadSection::default();
        assert!(!r.watch_files);
        assert!(r.validate().is_empty());
        r.settle_ms = 50.0;
        assert_eq!(r.validate()[0].key, "reload.settle_ms");
    }

    #[test]
    fn live_keys() {
        assert!(is_live_key("controller.recycle_pi.pi.kp"));
        assert!(is_live_key("control.law"));
        assert!(!is_live_key("cycle.rate_hz"));
        assert!(!is_live_key("bus"));
        // a prefix of a word is not the section
        assert!(is_live_key("busy.x"));
    }
}
