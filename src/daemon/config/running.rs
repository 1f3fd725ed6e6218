//! The running configuration, and the rule that a reload applies only a complete file.
//!
//! A file cut off while being written (an editor saving in place, a copy interrupted, a
//! full disk) may still parse: the keys after the cut are simply missing and their
//! defaults (plant defaults for the gains) would be applied without a word. So a reload is
//! refused when, against the configuration in force:
//! - a key that a configuration file sets is no longer set by any file (removing a key on
//!   purpose takes a restart, `systemctl restart antisurge`, or setting it to the default
//!   value explicitly), or
//! - a file that ended with a line break no longer does (cut mid-line).
//!
//! The daemon records what it runs in `running-config.json` beside its status socket
//! ([`RunningConfig::save`], at start and after every applied reload; write-then-rename), so
//! that `antisurge check-config --against-running` — which the shipped unit's `ExecReload`
//! runs — applies the same rule, and shows the difference, before the SIGHUP is sent. The
//! environment layer is not compared: a shell checking the file has not the service's
//! environment.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{flatten, Loaded, Problem};
use crate::config::FileError;

/// File name of the record, in the status socket's directory.
pub const FILE_NAME: &str = "running-config.json";

/// How many missing keys a message names (the rest are counted).
const NAMED: usize = 8;

/// What the daemon runs, as far as a reload's completeness needs it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RunningConfig {
    /// The main file.
    pub main_path: PathBuf,
    /// The daemon's process id.
    pub pid: u32,
    /// Every key a configuration file sets (not the environment), with its merged value.
    pub keys: BTreeMap<String, String>,
    /// The files that ended with a line break.
    pub complete_files: BTreeSet<PathBuf>,
}

fn is_file_layer(path: &Path) -> bool {
    path.as_os_str() != "environment"
}

/// One difference between the running configuration and new files.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Change {
    /// Set by the new files, not by the running ones.
    Added(String, String),
    /// Set by both, to different values (old, new).
    Changed(String, String, String),
    /// Set by the running files, missing from the new ones: a refusal.
    Removed(String, String),
}

impl RunningConfig {
    /// The record of `l`, run by this process.
    pub fn of(l: &Loaded) -> RunningConfig {
        let mut keys = BTreeMap::new();
        for layer in l.layers.iter().filter(|x| is_file_layer(&x.path)) {
            for k in flatten(&layer.table).into_keys() {
                let v = l.flat.get(&k).cloned().unwrap_or_default();
                keys.insert(k, v);
            }
        }
        RunningConfig {
            main_path: l.main_path.clone(),
            pid: std::process::id(),
            keys,
            complete_files: l
                .layers
                .iter()
                .filter(|x| is_file_layer(&x.path) && x.text.ends_with('\n'))
                .map(|x| x.path.clone())
                .collect(),
        }
    }

    /// Where the record of a configuration whose status socket is `socket` lives.
    pub fn path_beside(socket: &Path) -> PathBuf {
        socket.with_file_name(FILE_NAME)
    }

    /// Write to `path` (a temporary file renamed over it: a reader never sees half).
    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)?;
        }
        let tmp = path.with_extension(format!("json.{}.tmp", std::process::id()));
        let text = serde_json::to_string_pretty(self).map_err(std::io::Error::other)? + "\n";
        std::fs::write(&tmp, text)?;
        std::fs::rename(&tmp, path)
    }

    /// Read a record.
    pub fn load(path: &Path) -> Result<RunningConfig, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// The differences of `new` against this record, key order.
    pub fn diff(&self, new: &Loaded) -> Vec<Change> {
        let next = RunningConfig::of(new);
        let all: BTreeSet<&String> = self.keys.keys().chain(next.keys.keys()).collect();
        all.into_iter()
            .filter_map(|k| match (self.keys.get(k), next.keys.get(k)) {
                (Some(a), Some(b)) if a != b => {
                    Some(Change::Changed(k.clone(), a.clone(), b.clone()))
                }
                (Some(a), None) => Some(Change::Removed(k.clone(), a.clone())),
                (None, Some(b)) => Some(Change::Added(k.clone(), b.clone())),
                _ => None,
            })
            .collect()
    }

    /// Why `new` must not replace this configuration (empty: it may).
    pub fn incomplete(&self, new: &Loaded) -> Vec<Problem> {
        let mut out = Vec::new();
        for layer in new.layers.iter().filter(|x| is_file_layer(&x.path)) {
            if self.complete_files.contains(&layer.path) && !layer.text.ends_with('\n') {
                let line = layer.text.lines().count().max(1);
                out.push(Problem {
                    error: FileError {
                        file: layer.path.clone(),
                        key: String::new(),
                        line,
                        column: 0,
                        message: "the file does not end with a line break, as the running one did: cut off while being written? Nothing was applied".into(),
                        hint: Some(SAVE_HINT.into()),
                    },
                    warning: false,
                });
            }
        }
        let removed: Vec<String> = self
            .diff(new)
            .into_iter()
            .filter_map(|c| match c {
                Change::Removed(k, _) => Some(k),
                _ => None,
            })
            .collect();
        if let Some(first) = removed.first() {
            let mut named = removed
                .iter()
                .take(NAMED)
                .cloned()
                .collect::<Vec<_>>()
                .join(", ");
            if removed.len() > NAMED {
                named += &format!(" and {} more", removed.len() - NAMED);
            }
            out.push(Problem {
                error: FileError {
                    file: new.main_path.clone(),
                    key: first.clone(),
                    line: 0,
                    column: 0,
                    message: format!(
                        "{} key(s) set in the running configuration are missing from the new files ({named}): a file cut off while being written? A missing key is a refusal, not a default; nothing was applied",
                        removed.len()
                    ),
                    hint: Some(format!(
                        "{SAVE_HINT}; to drop a key on purpose, set it to its default value, or restart the service (systemctl restart antisurge)"
                    )),
                },
                warning: false,
            });
        }
        out
    }
}

/// How to save a configuration so that no reader sees half of it.
pub const SAVE_HINT: &str =
    "save atomically: sudoedit, or write a temporary file and rename it over the old one";

/// The differences as text, one per line (`check-config --against-running`).
pub fn format_diff(changes: &[Change]) -> String {
    let mut s = String::new();
    for c in changes {
        match c {
            Change::Added(k, v) => s += &format!("  + {k} = {v}\n"),
            Change::Changed(k, a, b) => s += &format!("  ~ {k}: {a} -> {b}\n"),
            Change::Removed(k, a) => s += &format!("  - {k} (was {a}): MISSING\n"),
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn loaded(dir: &Path, text: &str) -> Result<Loaded, Vec<Problem>> {
        let main = dir.join("antisurge.toml");
        super::super::load_text_with_env(&main, text, &[])
    }

    const FULL: &str = "[plant]\nfile = \"PLANT\"\n\n[control]\nlaw = \"recycle-pi\"\nfailsafe_recycle_opening_pct = 90.0\n\n[status]\nlog_interval_s = 5.0\n";

    #[test]
    fn a_cut_file_is_refused_and_a_whole_one_is_not() {
        let dir = tempfile::tempdir().expect("tmp");
        let plant = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("config/plants/kvangardsnes2009_recycle.toml");
        let full = FULL.replace("PLANT", &plant.display().to_string());
        let running = RunningConfig::of(&loaded(dir.path(), &full).expect("full"));
        assert!(running.keys.contains_key("status.log_interval_s"));

        let same = loaded(dir.path(), &full).expect("same");
        assert!(running.incomplete(&same).is_empty());
        let changed = loaded(dir.path(), &full.replace("5.0", "7.0")).expect("changed");
        assert!(running.incomplete(&changed).is_empty());
        assert_eq!(
            running.diff(&changed),
            [Change::Changed(
                "status.log_interval_s".into(),
                "5.0".into(),
                "7.0".into()
            )]
        );

        // cut before [status]: parses, one key missing
        let cut = &full[..full.find("[status]").expect("status")];
        let half = loaded(dir.path(), cut).expect("the cut file parses");
        let p = running.incomplete(&half);
        assert_eq!(p.len(), 1, "{p:?}");
        assert_eq!(p[0].error.key, "status.log_interval_s");
        assert!(p[0].error.message.contains("missing"), "{}", p[0].error);
        // cut in the last line: every key there, no line break at the end
        let cut = &full[..full.len() - 1];
        let p = running.incomplete(&loaded(dir.path(), cut).expect("parses"));
        assert!(
            p.len() == 1 && p[0].error.message.contains("line break"),
            "{p:?}"
        );
        // the record survives a round trip through its file
        let file = dir.path().join("run").join(FILE_NAME);
        running.save(&file).expect("save");
        assert_eq!(RunningConfig::load(&file).expect("load"), running);
    }
}
