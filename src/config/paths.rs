//! Paths named in a configuration file: relative ones are taken from the main file's directory.

use std::path::{Path, PathBuf};

/// Where the main file's relative paths are resolved from.
pub fn base_dir(main: &Path) -> PathBuf {
    main.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."))
}

/// Resolve `p` against the main file's directory.
pub fn resolve(main: &Path, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        base_dir(main).join(p)
    }
}
