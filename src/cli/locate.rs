//! Finding plant and scenario files by name or path.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// The configuration directory: `--config-dir`, `$ANTISURGE_CONFIG_DIR`, `./config`, the
/// directory next to the executable's `../config`, `/etc/antisurge`, or else the shipped
/// plants, maps and scenarios built into the binary ([`embedded_config_dir`]).
pub fn config_dir(explicit: Option<&Path>) -> PathBuf {
    if let Some(p) = explicit {
        return p.to_path_buf();
    }
    if let Ok(p) = std::env::var("ANTISURGE_CONFIG_DIR") {
        return PathBuf::from(p);
    }
    let local = PathBuf::from("config");
    if local.join("plants").is_dir() {
        return local;
    }
    if let Ok(exe) = std::env::current_exe() {
        for up in exe.ancestors().skip(1).take(4) {
            let c = up.join("config");
            if c.join("plants").is_dir() {
                return c;
            }
        }
    }
    let etc = PathBuf::from("/etc/antisurge");
    if etc.join("plants").is_dir() {
        return etc;
    }
    // nothing on disk: the copies built into the binary
    embedded_config_dir().unwrap_or(etc)
}

mod embedded {
    include!(concat!(env!("OUT_DIR"), "/embedded_config.rs"));
}

/// Write the shipped plants, maps and scenarios built into the binary to a directory under
/// the temporary directory (once per build) and return it.
pub fn embedded_config_dir() -> Option<PathBuf> {
    let dir = std::env::temp_dir().join(format!(
        "antisurge-{}-{}-config",
        env!("CARGO_PKG_VERSION"),
        env!("ANTISURGE_COMMIT")
    ));
    for (rel, text) in embedded::FILES {
        let p = dir.join(rel);
        if std::fs::read_to_string(&p).ok().as_deref() == Some(*text) {
            continue;
        }
        std::fs::create_dir_all(p.parent()?).ok()?;
        std::fs::write(&p, text).ok()?;
    }
    Some(dir)
}

/// Resolve `name_or_path` in `dir/<kind>/`: an existing path, `<name>.toml`, or a file whose
/// stem starts with `<name>` (so `bohagen2007` finds `bohagen2007_plenum.toml`). Names may
/// use `-` or `_`.
pub fn resolve(config: &Path, kind: &str, name_or_path: &str) -> Result<PathBuf> {
    let p = Path::new(name_or_path);
    if p.extension().is_some_and(|e| e == "toml") || p.components().count() > 1 {
        if p.is_file() {
            return Ok(p.to_path_buf());
        }
        bail!("{kind} file {} does not exist", p.display());
    }
    let dir = config.join(kind);
    let wanted = name_or_path.replace('-', "_");
    let mut candidates = list(&dir)?;
    candidates.sort();
    if let Some(exact) = candidates.iter().find(|c| stem(c) == wanted) {
        return Ok(exact.clone());
    }
    let prefixed: Vec<&PathBuf> = candidates
        .iter()
        .filter(|c| stem(c).starts_with(&wanted))
        .collect();
    match prefixed.as_slice() {
        [one] => Ok((*one).clone()),
        [] => bail!(
            "unknown {} `{name_or_path}` (looked in {}); available: {}",
            kind.trim_end_matches('s'),
            dir.display(),
            names(&candidates)
        ),
        many => bail!(
            "`{name_or_path}` matches several {kind}: {}",
            many.iter().map(|c| stem(c)).collect::<Vec<_>>().join(", ")
        ),
    }
}

/// TOML files in a directory.
pub fn list(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).with_context(|| format!("cannot read {}", dir.display()))? {
        let p = e?.path();
        if p.extension().is_some_and(|x| x == "toml") {
            out.push(p);
        }
    }
    out.sort();
    Ok(out)
}

fn stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn names(c: &[PathBuf]) -> String {
    c.iter().map(|p| stem(p)).collect::<Vec<_>>().join(", ")
}
