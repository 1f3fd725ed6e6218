//! `antisurge check-config --print`: the effective merged configuration with the source of
//! every value, like `nginx -T` / `sshd -T`: the file and line of the last layer that sets it
//! (main file, a `conf.d/` drop-in), the environment variable, the plant file's tuned
//! `[controller]` table, or `default`. The machine description follows with its file's lines.

use super::layers::{resolve, Layer, ENV_PREFIX};
use super::Loaded;
use crate::config::toml_file::locate_key;
use std::path::Path;

/// The value at exactly the dotted key of a table.
fn get_exact<'a>(t: &'a toml::Table, dotted: &str) -> Option<&'a toml::Value> {
    let mut cur = t;
    let mut parts = dotted.split('.').peekable();
    while let Some(p) = parts.next() {
        let v = cur.get(p)?;
        if parts.peek().is_none() {
            return Some(v);
        }
        cur = v.as_table()?;
    }
    None
}

/// `file:line` of `key` in a TOML text.
fn at(path: &Path, text: &str, key: &str) -> String {
    match locate_key(text, key) {
        Some((line, _)) => format!("{}:{line}", path.display()),
        None => path.display().to_string(),
    }
}

/// Where the effective value of `key` comes from.
pub fn source_of(l: &Loaded, key: &str) -> String {
    if let Some(layer) = l
        .layers
        .iter()
        .rev()
        .find(|x: &&Layer| get_exact(&x.table, key).is_some())
    {
        if layer.path.as_os_str() == "environment" {
            return format!(
                "environment ({ENV_PREFIX}_{})",
                key.replace('.', "__").to_ascii_uppercase()
            );
        }
        return at(&layer.path, &layer.text, key);
    }
    if let (Some(rest), Some(p), None) = (
        key.strip_prefix("controller."),
        l.config.plant.as_ref(),
        l.config.machine.as_ref(),
    ) {
        let path = resolve(&l.main_path, &p.file);
        if let Ok(text) = std::fs::read_to_string(&path) {
            let in_plant = toml::from_str::<toml::Table>(&text)
                .ok()
                .and_then(|t| t.get("controller").and_then(|c| c.as_table()).cloned())
                .is_some_and(|c| get_exact(&c, rest).is_some());
            if in_plant {
                return format!("{} [controller]", at(&path, &text, key));
            }
        }
    }
    "default".into()
}

/// Flatten a table to `dotted.key = value` pairs; arrays and one-key enum tables stay whole.
fn flatten(prefix: &str, v: &toml::Value, out: &mut Vec<(String, String)>) {
    match v {
        toml::Value::Table(t) => {
            for (k, v) in t {
                let p = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten(&p, v, out);
            }
        }
        other => out.push((prefix.to_string(), other.to_string())),
    }
}

/// The effective configuration, one `key = value  # source` line per value.
pub fn print_effective(l: &Loaded) -> String {
    let mut pairs = Vec::new();
    if let Ok(t) = toml::Table::try_from(&l.config) {
        let mut t = t;
        t.remove("controller"); // the overrides; the effective settings follow
        flatten("", &toml::Value::Table(t), &mut pairs);
    }
    if let Ok(c) = toml::Table::try_from(&l.controller) {
        flatten("controller", &toml::Value::Table(c), &mut pairs);
    }
    let width = pairs
        .iter()
        .map(|(k, v)| k.len() + v.len() + 3)
        .max()
        .unwrap_or(0)
        .min(72);
    let mut out = String::from(
        "# effective configuration (later layers win: main file, conf.d/, environment)\n",
    );
    for (k, v) in &pairs {
        let kv = format!("{k} = {v}");
        out += &format!("{kv:<width$}  # {}\n", source_of(l, k));
    }
    // the machine description, from its file
    let file = l.config.machine.as_ref().map(|m| &m.file).or(l
        .config
        .plant
        .as_ref()
        .map(|p| &p.file));
    if let Some(f) = file {
        let path = resolve(&l.main_path, f);
        if let Ok(text) = std::fs::read_to_string(&path) {
            if let Ok(t) = toml::from_str::<toml::Table>(&text) {
                let mut m = Vec::new();
                let mut t = t;
                t.remove("controller");
                flatten("", &toml::Value::Table(t), &mut m);
                out += &format!("\n# machine `{}` ({})\n", l.machine.name, path.display());
                for (k, v) in &m {
                    let kv = format!("{k} = {v}");
                    out += &format!("{kv:<width$}  # {}\n", at(&path, &text, k));
                }
            }
        }
    }
    out
}
