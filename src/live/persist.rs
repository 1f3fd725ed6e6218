//! Persistent operator state in the state directory (`/var/lib/antisurge/state.json`): the
//! surge counter, the safety-on steps and the last mode chosen by the operator (with the
//! manual output). Written atomically (temporary file, fsync, rename, fsync of the
//! directory) whenever it changes, so a kill -9 or a watchdog restart loses nothing that
//! was written; restored at start.

use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

/// What is kept across restarts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct PersistentState {
    /// Surge counter (reset only by an authenticated operator command).
    pub surge_count: u64,
    /// Safety-on steps of the control line in force.
    pub safety_on_count: u32,
    /// Mode the operator chose last: true = auto, false = manual.
    pub auto: bool,
    /// Manual-station output, fraction (None: never set).
    #[serde(default)]
    pub manual_output: Option<f64>,
}

/// Errors reading or writing the state file.
#[derive(Debug, thiserror::Error)]
pub enum PersistError {
    /// The file or directory could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The file is not valid state JSON.
    #[error("{path}: not a valid state file ({source}); starting from zero")]
    Parse {
        /// The path.
        path: PathBuf,
        /// The parse error.
        source: serde_json::Error,
    },
}

/// The state file in a state directory.
#[derive(Debug, Clone)]
pub struct StateFile {
    path: PathBuf,
}

impl StateFile {
    /// `state.json` in `dir`.
    pub fn in_dir(dir: &Path) -> StateFile {
        StateFile {
            path: dir.join("state.json"),
        }
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Read the kept state; `Ok(None)` if there is none yet.
    pub fn load(&self) -> Result<Option<PersistentState>, PersistError> {
        match std::fs::read(&self.path) {
            Ok(bytes) => {
                serde_json::from_slice(&bytes)
                    .map(Some)
                    .map_err(|source| PersistError::Parse {
                        path: self.path.clone(),
                        source,
                    })
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(source) => Err(PersistError::Io {
                path: self.path.clone(),
                source,
            }),
        }
    }

    /// Write atomically: a reader (or a restart after kill -9) sees the old or the new file,
    /// never a torn one.
    pub fn store(&self, s: &PersistentState) -> Result<(), PersistError> {
        let io = |source| PersistError::Io {
            path: self.path.clone(),
            source,
        };
        let dir = self.path.parent().unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir).map_err(io)?;
        let tmp = self.path.with_extension("json.tmp");
        let mut f = std::fs::File::create(&tmp).map_err(io)?;
        let text = serde_json::to_string_pretty(s).expect("plain data serializes") + "\n";
        f.write_all(text.as_bytes()).map_err(io)?;
        f.sync_all().map_err(io)?;
        drop(f);
        std::fs::rename(&tmp, &self.path).map_err(io)?;
        std::fs::File::open(dir)
            .and_then(|d| d.sync_all())
            .map_err(io)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stores_atomically_and_reads_back() {
        let dir = tempfile::tempdir().expect("tmp");
        let f = StateFile::in_dir(&dir.path().join("sub"));
        assert!(f.load().expect("load").is_none());
        let s = PersistentState {
            surge_count: 3,
            safety_on_count: 2,
            auto: false,
            manual_output: Some(0.25),
        };
        f.store(&s).expect("store");
        assert_eq!(f.load().expect("load"), Some(s));
        assert!(!f.path().with_extension("json.tmp").exists());
        std::fs::write(f.path(), "{garbage").expect("write");
        let e = f.load().unwrap_err().to_string();
        assert!(e.contains("state.json") && e.contains("not a valid"), "{e}");
    }
}
