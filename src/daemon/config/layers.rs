//! The layer machinery: reading the main file, `conf.d/*.toml` and the environment, merging
//! them with the `config` crate, flattening for reload diffs, and locating a key (file:line
//! of the last layer that sets it, or the environment variable).

use super::DaemonConfig;
use crate::config::toml_file::locate_key;
use crate::config::FileError;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Prefix of the environment variables that override config keys.
pub const ENV_PREFIX: &str = "ANTISURGE";

/// One source layer with its text (for locating keys).
#[derive(Debug, Clone)]
pub struct Layer {
    /// File (or `environment`).
    pub path: PathBuf,
    /// Its text (for env: `key = value` lines).
    pub text: String,
    /// Its parsed table.
    pub table: toml::Table,
}

use crate::config::paths::base_dir;
pub use crate::config::paths::resolve;

fn read_layer(path: &Path) -> Result<Layer, FileError> {
    let text = crate::config::read_config_text(path).map_err(|e| FileError {
        file: path.to_path_buf(),
        key: String::new(),
        line: 0,
        column: 0,
        message: format!("cannot read: {e}"),
        hint: Some("check the path and that the antisurge user may read it".into()),
    })?;
    layer_of_text(path, text)
}

/// A layer from text already read (`path` names it in messages).
pub(super) fn layer_of_text(path: &Path, text: String) -> Result<Layer, FileError> {
    let table: toml::Table =
        crate::config::toml_file::parse(&text, path).map_err(|e| with_line_key(e, &text))?;
    Ok(Layer {
        path: path.to_path_buf(),
        text,
        table,
    })
}

/// The `conf.d/` directory of a main file.
pub fn conf_d(main: &Path) -> PathBuf {
    base_dir(main).join("conf.d")
}

/// Deepest key an environment variable may set (`ANTISURGE_A__B__…`): the schema's deepest key
/// has 6 levels (`controller.recycle_pi.control_line.margin.margin_pct`).
pub const MAX_ENV_DEPTH: usize = 8;

/// Environment overrides (`ANTISURGE_A__B=v` → `a.b`), sorted, from `vars`.
fn env_layer(vars: &[(String, String)]) -> Option<Layer> {
    let mut lines = Vec::new();
    for (k, v) in vars {
        let Some(rest) = k.strip_prefix(&format!("{ENV_PREFIX}_")) else {
            continue;
        };
        // variables of the tools themselves, not config keys
        if rest == "CONFIG_DIR" || rest == "LOG" || !rest.contains("__") {
            continue;
        }
        let key = rest.to_ascii_lowercase().replace("__", ".");
        if key.split('.').count() > MAX_ENV_DEPTH {
            // deeper than any key of the schema; a very deep one overflowed the stack
            tracing::warn!(target: "config", "{k} ignored: more than {MAX_ENV_DEPTH} levels, no config key is that deep");
            continue;
        }
        lines.push((key, v.clone()));
    }
    if lines.is_empty() {
        return None;
    }
    lines.sort();
    let text = lines
        .iter()
        .map(|(k, v)| format!("{k} = {v}\n"))
        .collect::<String>();
    let mut table = toml::Table::new();
    for (k, v) in &lines {
        let value = parse_env_value(v);
        insert_path(&mut table, k, value);
    }
    Some(Layer {
        path: PathBuf::from("environment"),
        text,
        table,
    })
}

fn parse_env_value(v: &str) -> toml::Value {
    if let Ok(t) = toml::from_str::<toml::Table>(&format!("v = {v}")) {
        if let Some(x) = t.get("v") {
            return x.clone();
        }
    }
    toml::Value::String(v.to_string())
}

fn insert_path(table: &mut toml::Table, dotted: &str, value: toml::Value) {
    let mut parts = dotted.split('.').peekable();
    let mut cur = table;
    while let Some(p) = parts.next() {
        if parts.peek().is_none() {
            cur.insert(p.to_string(), value);
            return;
        }
        let entry = cur
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        if !entry.is_table() {
            *entry = toml::Value::Table(toml::Table::new());
        }
        cur = entry.as_table_mut().expect("table");
    }
}

/// Does the table set the dotted key (prefix match for tables)?
fn table_has(table: &toml::Table, dotted: &str) -> bool {
    let mut cur = table;
    let parts: Vec<&str> = dotted.split('.').filter(|s| !s.is_empty()).collect();
    for (i, p) in parts.iter().enumerate() {
        let p = p.split('[').next().unwrap_or(p);
        match cur.get(p) {
            Some(toml::Value::Table(t)) if i + 1 < parts.len() => cur = t,
            Some(_) => return true,
            None => return false,
        }
    }
    true
}

/// The value at exactly the dotted key (no parent fallback, `[i]` indices ignored).
pub(super) fn table_get<'a>(table: &'a toml::Table, dotted: &str) -> Option<&'a toml::Value> {
    let mut parts = dotted
        .split('.')
        .filter(|s| !s.is_empty())
        .map(|p| p.split('[').next().unwrap_or(p))
        .peekable();
    let mut cur = table;
    while let Some(p) = parts.next() {
        let v = cur.get(p)?;
        if parts.peek().is_none() {
            return Some(v);
        }
        cur = v.as_table()?;
    }
    None
}

/// Does any layer set exactly `dotted`?
pub(super) fn layers_set(layers: &[Layer], dotted: &str) -> bool {
    layers.iter().any(|l| table_get(&l.table, dotted).is_some())
}

/// The dotted key written on `line` (1-based) of a TOML text: the table header above it plus
/// the key left of `=` (the header itself on a header line). The TOML parser reports syntax
/// errors by position only; this names the key the operator was writing.
pub fn key_at_line(text: &str, line: usize) -> String {
    fn clean(k: &str) -> String {
        k.split('.')
            .map(|p| p.trim().trim_matches(|c| c == '"' || c == '\''))
            .filter(|p| !p.is_empty())
            .collect::<Vec<_>>()
            .join(".")
    }
    fn header(l: &str) -> Option<String> {
        let l = l.split('#').next().unwrap_or(l).trim();
        if l.starts_with('[') {
            Some(clean(l.trim_start_matches('[').trim_end_matches(']')))
        } else {
            None
        }
    }
    let mut table = String::new();
    for (i, raw) in text.lines().enumerate() {
        let l = raw.trim();
        if i + 1 == line {
            if let Some(h) = header(l) {
                return h;
            }
            if let Some((k, _)) = l.split_once('=') {
                let k = clean(k);
                if !k.is_empty() && !k.contains(char::is_whitespace) {
                    return if table.is_empty() {
                        k
                    } else {
                        format!("{table}.{k}")
                    };
                }
            }
            return table;
        }
        if let Some(h) = header(l) {
            table = h;
        }
    }
    String::new()
}

/// A positioned error without a key (a TOML syntax error) gets the key written on its line.
fn with_line_key(mut e: FileError, text: &str) -> FileError {
    if e.key.is_empty() && e.line > 0 {
        e.key = key_at_line(text, e.line);
    }
    e
}

/// [`with_line_key`] for an error in a file not read here (plant file, signal map).
pub(super) fn with_file_line_key(mut e: FileError) -> FileError {
    if let Ok(text) = crate::config::read_config_text(&e.file) {
        if e.key.contains('?') {
            if let Ok(table) = toml::from_str::<toml::Table>(&text) {
                e.key = name_map_keys(&[&table], &e.key, &e.message);
            }
        }
        return with_line_key(e, &text);
    }
    e
}

/// serde_path_to_error writes `?` for a map key that is not a string (a sensor name in
/// `[inputs.<sensor>]`, `[sensors.<sensor>]`): put back the name written in the file, the one
/// the message is about.
fn name_map_keys(tables: &[&toml::Table], key: &str, message: &str) -> String {
    let Some(i) = key.split('.').position(|p| p == "?") else {
        return key.to_string();
    };
    let parts: Vec<&str> = key.split('.').collect();
    let prefix = parts[..i].join(".");
    let rest = &parts[i + 1..];
    let join = |cand: &str, rest: &[&str]| {
        let mut v: Vec<&str> = parts[..i].to_vec();
        v.push(cand);
        v.extend_from_slice(rest);
        v.join(".")
    };
    if rest.is_empty() {
        // `unknown variant `p_sucton``: the map key itself is wrong
        if let Some(v) = message
            .strip_prefix("unknown variant `")
            .and_then(|r| r.split('`').next())
        {
            return join(v, rest);
        }
    }
    let missing = message.starts_with("missing field");
    for t in tables.iter().rev() {
        let Some(toml::Value::Table(map)) = table_get(t, &prefix) else {
            continue;
        };
        for cand in map.keys() {
            let full = join(cand, rest);
            let found = if missing {
                let parent = join(cand, &rest[..rest.len().saturating_sub(1)]);
                table_get(t, &parent).is_some_and(toml::Value::is_table)
                    && table_get(t, &full).is_none()
            } else {
                table_get(t, &full).is_some()
            };
            if found {
                return name_map_keys(tables, &full, message);
            }
        }
    }
    key.to_string()
}

/// The key a deserialization error is about. This is the one place where a key is read from
/// error text, because serde gives nothing else: its standard errors `unknown field `x``,
/// `missing field `x`` and an unknown map key (`[inputs.p_sucton]`, `unknown variant`) are
/// raised at the enclosing table with the key's name only in the message, and
/// serde_path_to_error writes `?` for a map key that is not a string. The rules of the
/// sections themselves return typed problems with their key ([`super::problem::KeyProblem`]).
pub(super) fn serde_error_key(layers: &[Layer], key: &str, message: &str) -> String {
    name_map_keys(
        &layers.iter().map(|l| &l.table).collect::<Vec<_>>(),
        &serde_field_key(layers, key, message),
        message,
    )
}

fn serde_field_key(layers: &[Layer], key: &str, message: &str) -> String {
    let join = |leaf: &str| {
        if key.is_empty() {
            leaf.to_string()
        } else {
            format!("{key}.{leaf}")
        }
    };
    let quoted = |prefix: &str| {
        message
            .strip_prefix(prefix)
            .and_then(|r| r.strip_prefix('`'))
            .and_then(|r| r.split('`').next())
            .map(str::to_string)
    };
    if let Some(f) = quoted("unknown field ").or_else(|| quoted("missing field ")) {
        if key.rsplit('.').next() != Some(f.as_str()) {
            return join(&f);
        }
    }
    if let Some(v) = quoted("unknown variant ") {
        // an unknown name used as a table key (a sensor name), not as a value
        if layers
            .iter()
            .any(|l| table_get(&l.table, &join(&v)).is_some_and(toml::Value::is_table))
        {
            return join(&v);
        }
    }
    key.to_string()
}

/// An error about `key`, located in the last layer that sets it (or its nearest parent).
pub fn locate(layers: &[Layer], key: &str, message: impl Into<String>) -> FileError {
    let message = message.into();
    let mut probe = key.to_string();
    loop {
        for layer in layers.iter().rev() {
            if !probe.is_empty() && table_has(&layer.table, &probe) {
                let (line, column) = if layer.path.as_os_str() == "environment" {
                    layer
                        .text
                        .lines()
                        .position(|l| l.starts_with(&probe))
                        .map(|i| (i + 1, 1))
                        .unwrap_or((0, 0))
                } else {
                    locate_key(&layer.text, &probe).unwrap_or((0, 0))
                };
                let file = if layer.path.as_os_str() == "environment" {
                    PathBuf::from(format!(
                        "environment ({ENV_PREFIX}_{})",
                        probe.replace('.', "__").to_ascii_uppercase()
                    ))
                } else {
                    layer.path.clone()
                };
                return FileError {
                    file,
                    key: key.to_string(),
                    line,
                    column,
                    message,
                    hint: None,
                };
            }
        }
        match probe.rfind('.') {
            Some(i) => probe.truncate(i),
            None => break,
        }
    }
    FileError {
        file: layers
            .first()
            .map(|l| l.path.clone())
            .unwrap_or_else(|| PathBuf::from("antisurge.toml")),
        key: key.to_string(),
        line: 0,
        column: 0,
        message,
        hint: None,
    }
}

/// Where a relative output path (event log, statistics) goes: under `$LOGS_DIRECTORY` (set by
/// systemd's `LogsDirectory=`), else under `./out/`.
pub fn output_path(p: &Path) -> PathBuf {
    output_path_in(p, std::env::var_os("LOGS_DIRECTORY").as_deref())
}

/// [`output_path`] with the value of `$LOGS_DIRECTORY` given (systemd may list several
/// directories separated by `:`; the first is the unit's own).
fn output_path_in(p: &Path, logs_directory: Option<&std::ffi::OsStr>) -> PathBuf {
    if p.is_absolute() {
        return p.to_path_buf();
    }
    match logs_directory.and_then(|d| d.to_str().map(|d| d.split(':').next().unwrap_or(d))) {
        Some(d) if !d.is_empty() => PathBuf::from(d).join(p),
        _ => Path::new("out").join(p),
    }
}

/// Read the layers of `main`: the file, `conf.d/*.toml`, then the environment `vars`.
pub fn read_layers(main: &Path, vars: &[(String, String)]) -> Result<Vec<Layer>, FileError> {
    read_layers_after(read_layer(main)?, main, vars)
}

/// The layers after the main file's `first`: `conf.d/*.toml`, then the environment `vars`.
pub(super) fn read_layers_after(
    first: Layer,
    main: &Path,
    vars: &[(String, String)],
) -> Result<Vec<Layer>, FileError> {
    let mut layers = vec![first];
    let dir = conf_d(main);
    if dir.is_dir() {
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .map_err(|e| FileError {
                file: dir.clone(),
                key: String::new(),
                line: 0,
                column: 0,
                message: format!("cannot list: {e}"),
                hint: None,
            })?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "toml"))
            .collect();
        files.sort();
        for f in files {
            layers.push(read_layer(&f)?);
        }
    }
    if let Some(env) = env_layer(vars) {
        layers.push(env);
    }
    Ok(layers)
}

/// Merge the layers with the `config` crate and deserialize the schema; errors are located.
pub fn merge(layers: &[Layer]) -> Result<(DaemonConfig, toml::Table), FileError> {
    let mut builder = config::Config::builder();
    for layer in layers {
        // each layer re-serialized from its parsed table, so env values keep their types
        let text = toml::to_string(&layer.table).map_err(|e| FileError {
            file: layer.path.clone(),
            key: String::new(),
            line: 0,
            column: 0,
            message: format!("cannot re-serialize: {e}"),
            hint: None,
        })?;
        builder = builder.add_source(config::File::from_str(&text, config::FileFormat::Toml));
    }
    let merged = builder.build().map_err(|e| FileError {
        file: layers[0].path.clone(),
        key: String::new(),
        line: 0,
        column: 0,
        message: format!("cannot merge the config layers: {e}"),
        hint: None,
    })?;
    let as_table: toml::Table = merged.clone().try_deserialize().map_err(|e| FileError {
        file: layers[0].path.clone(),
        key: String::new(),
        line: 0,
        column: 0,
        message: format!("cannot merge the config layers: {e}"),
        hint: None,
    })?;
    // the typed schema from the merged table, with the key path of any error
    let text = toml::to_string(&as_table).unwrap_or_default();
    let de = toml::de::Deserializer::parse(&text).map_err(|e| FileError {
        file: layers[0].path.clone(),
        key: String::new(),
        line: 0,
        column: 0,
        message: e.to_string(),
        hint: None,
    })?;
    let cfg: DaemonConfig = serde_path_to_error::deserialize(de).map_err(|e| {
        let key = e.path().to_string();
        let key = if key == "." { String::new() } else { key };
        let inner = e.into_inner();
        let message = inner.message().trim().to_string();
        // the merged text's span means nothing to the operator: the key is located again in
        // the last layer that sets it
        if key == "event_log" {
            // a value the event log refuses (a typed error), reported by serde as text
            if let Some(p) = as_table
                .get("event_log")
                .and_then(toml::Value::as_table)
                .and_then(super::event_log::table_problem)
            {
                return locate(layers, &p.key, message);
            }
        }
        let key = serde_error_key(layers, &key, &message);
        let mut err = locate(layers, &key, message.clone());
        err.hint = hint_for(&message, &key);
        err
    })?;
    Ok((cfg, as_table))
}

pub(super) fn hint_for(message: &str, key: &str) -> Option<String> {
    if message.starts_with("unknown field") {
        Some("keys carry their unit (`_hz`, `_ms`, `_pct`, `_rad_s`, `_kg_s`); check the spelling against config/antisurge.toml".into())
    } else if message.starts_with("missing field") {
        // `key` names the missing key itself (see `serde_error_key`)
        Some(match key.rsplit_once('.') {
            Some((table, leaf)) => {
                format!("add `{leaf} = …` under [{table}]; config/antisurge.toml shows every key")
            }
            None => format!("add a [{key}] section; config/antisurge.toml shows every key"),
        })
    } else if message.starts_with("invalid type") {
        Some("numbers without quotes, text in quotes, lists in [ ]".into())
    } else if message.starts_with("unknown variant") {
        Some("use one of the listed names".into())
    } else {
        None
    }
}

/// Flatten a table into `dotted.key → value` strings (for reload diffs).
pub fn flatten(table: &toml::Table) -> BTreeMap<String, String> {
    fn walk(prefix: &str, v: &toml::Value, out: &mut BTreeMap<String, String>) {
        match v {
            toml::Value::Table(t) => {
                for (k, v) in t {
                    let p = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    walk(&p, v, out);
                }
            }
            other => {
                out.insert(prefix.to_string(), other.to_string());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk("", &toml::Value::Table(table.clone()), &mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::EventLogConfig;
    use std::ffi::OsStr;

    #[test]
    fn the_default_event_log_follows_logs_directory() {
        let default = EventLogConfig::default().path;
        assert_eq!(
            output_path_in(&default, Some(OsStr::new("/var/log/antisurge"))),
            Path::new("/var/log/antisurge/events.jsonl")
        );
        // systemd lists several LogsDirectory= entries with ':'; the first is the unit's own
        assert_eq!(
            output_path_in(&default, Some(OsStr::new("/srv/logs/a:/srv/logs/b"))),
            Path::new("/srv/logs/a/events.jsonl")
        );
        assert_eq!(
            output_path_in(&default, None),
            Path::new("out/events.jsonl")
        );
        // an absolute path is the operator's choice
        assert_eq!(
            output_path_in(Path::new("/data/ev.jsonl"), Some(OsStr::new("/x"))),
            Path::new("/data/ev.jsonl")
        );
    }
}
