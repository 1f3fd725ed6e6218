//! The daemon's configuration: one typed schema, loaded in layers with the `config` crate.
//!
//! Layers, later ones win key by key:
//! 1. the main file (`antisurge.toml`),
//! 2. every `*.toml` in the `conf.d/` directory beside it, in file-name order,
//! 3. environment variables `ANTISURGE_<SECTION>__<KEY>` (double underscore between levels,
//!    e.g. `ANTISURGE_CONTROL__LAW=drive-torque`, `ANTISURGE_CYCLE__RATE_HZ=500`).
//!
//! The `config` crate merges the layers but forgets where a key came from, so every error is
//! located again here: the last layer that sets the key is searched with `toml_edit` spans
//! ([`crate::config::toml_file::locate_key`]) and the message names that file and line.
//!
//! [`load`] returns the typed [`DaemonConfig`] plus everything resolved from it (the machine
//! model, the signal map, the controller settings with the overrides applied, the input
//! limits). [`check`] runs the cross-field rules; `antisurge check-config`, start-up and hot
//! reload all call the same two functions.

use crate::config::toml_file::locate_key;
use crate::config::FileError;
use crate::control::config::ControllerConfig;
use crate::control::core::CoreSettings;
use crate::control::drive_torque::check_gains;
use crate::control::law::{Law, LawError, LawId};
use crate::control::model::ControlModel;
use crate::control::supervisor::InputLimits;
use crate::events::EventLogConfig;
use crate::io::can::bus::{BusCodec, CanBusConfig, CanBusError};
use crate::io::can::{BindingError, SignalTarget};
use crate::io::modbus::{ModbusLinkConfig, ModbusServerConfig};
use crate::io::signal_map::{Binding, SignalMap};
use crate::plant::file::PlantDescription;
use crate::runtime::rt_loop::RtSettings;
use crate::signals::{ActuatorId, SensorId};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Prefix of the environment variables that override config keys.
pub const ENV_PREFIX: &str = "ANTISURGE";

/// `[plant]`: the machine the controller runs (its model: map, volumes, drive, valves).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantSection {
    /// Plant description file (`config/plants/*.toml`), relative to the main config file.
    pub file: PathBuf,
}

/// Controller mode at start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum StartMode {
    /// The selected law runs as soon as the inputs are healthy.
    #[default]
    Auto,
    /// Speed loop only; the recycle valve holds its position (manual station).
    Manual,
}

/// `[control]`: which law, in which mode, around which setpoints.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlSection {
    /// Surge law (`none`, `recycle-pi`, `recycle-fl`, `drive-torque`, `ccv`,
    /// `throttle-backstep`, `robust`, `tip-sliding`).
    pub law: String,
    /// Mode at start.
    #[serde(default)]
    pub mode: StartMode,
    /// Speed setpoint, rad/s; absent: the plant file's nominal speed.
    #[serde(default)]
    pub speed_setpoint_rad_s: Option<f64>,
    /// Mass-flow setpoint of flow-tracking laws (`recycle-fl`), kg/s; absent: hold the flow.
    #[serde(default)]
    pub flow_setpoint_kg_s: Option<f64>,
    /// Recycle-valve opening in fail-safe, percent (100: fully open, the usual safe state).
    #[serde(default = "d_failsafe_pct")]
    pub failsafe_recycle_opening_pct: f64,
    /// At start, how long to wait for healthy inputs before commanding the fail-safe state,
    /// ms. Meanwhile nothing is commanded: a controller restart on a running machine does not
    /// move its actuators, and the law takes over from the measured positions.
    #[serde(default = "d_startup_grace_ms")]
    pub startup_grace_ms: f64,
}

fn d_failsafe_pct() -> f64 {
    100.0
}

fn d_startup_grace_ms() -> f64 {
    1000.0
}

/// One `[inputs.<sensor>]` table: plausibility range in the sensor's SI unit and freshness.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputSection {
    /// Lowest plausible value (Pa, rad/s, K, fraction or m, per sensor).
    pub min: f64,
    /// Highest plausible value, same unit.
    pub max: f64,
    /// The input is stale when no new value arrived for this long, ms.
    pub timeout_ms: f64,
}

/// How the daemon reaches the skid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Transport {
    /// The simulated plant runs in this process (no hardware; the embedded default).
    #[default]
    InProcess,
    /// Field buses: the signal map binds each signal to CAN (`[bus.can]`) or Modbus
    /// (`[bus.modbus]`).
    Field,
}

/// `[bus]`: transport, signal map and the bus settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusSection {
    /// `in_process` (simulated plant inside the daemon) or `field` (CAN and/or Modbus).
    #[serde(default)]
    pub transport: Transport,
    /// Signal map file (sensor/actuator ↔ CAN signal or Modbus register), relative to the
    /// main config file. Required for `field`.
    #[serde(default)]
    pub signal_map: Option<PathBuf>,
    /// SocketCAN settings (required if the map has CAN bindings).
    #[serde(default)]
    pub can: Option<CanBusConfig>,
    /// Modbus client settings (required if the map has Modbus bindings).
    #[serde(default)]
    pub modbus: Option<ModbusLinkConfig>,
}

/// `[simulation]`: the simulated skid, in-process or as `antisurge plant`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimulationSection {
    /// Scenario name (`config/scenarios`) or file, relative to the main config file.
    #[serde(default = "d_scenario")]
    pub scenario: String,
    /// Where the plant writes `trace.csv` and `summary.json` when the scenario ends.
    #[serde(default)]
    pub out_dir: Option<PathBuf>,
    /// Field devices go to their own fail-safe when no controller heartbeat arrived for this
    /// long, ms.
    #[serde(default = "d_hb_timeout")]
    pub heartbeat_timeout_ms: f64,
    /// Keep running (holding the final scenario state) after the scenario ends.
    #[serde(default)]
    pub hold_after_end: bool,
    /// The plant node also serves its signals as a Modbus TCP server.
    #[serde(default)]
    pub modbus_server: Option<ModbusServerConfig>,
}

fn d_scenario() -> String {
    "hold".into()
}
fn d_hb_timeout() -> f64 {
    100.0
}

impl Default for SimulationSection {
    fn default() -> Self {
        SimulationSection {
            scenario: d_scenario(),
            out_dir: None,
            heartbeat_timeout_ms: d_hb_timeout(),
            hold_after_end: false,
            modbus_server: None,
        }
    }
}

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
    /// Web HMI `host:port` (default `127.0.0.1:9651`; empty: off). Loopback only: this build
    /// does not terminate TLS.
    #[serde(default)]
    pub hmi_listen: Option<String>,
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
            modbus_listen: None,
            operator_token_file: None,
        }
    }
}

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

/// The whole configuration file (`config/antisurge.toml` documents every key).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DaemonConfig {
    /// The simulated machine (a plant file); without `[machine]`, also the controller's.
    #[serde(default)]
    pub plant: Option<PlantSection>,
    /// The controller's machine description (vendor data), `config/machines/*.toml`.
    #[serde(default)]
    pub machine: Option<super::config_machine::MachineSection>,
    /// Law, mode, setpoints, fail-safe opening.
    pub control: ControlSection,
    /// The control thread: rate, priority, CPU, memory locking.
    #[serde(default)]
    pub cycle: RtSettings,
    /// Input supervision per sensor; sensors not listed get defaults derived from the plant.
    #[serde(default)]
    pub inputs: BTreeMap<SensorId, InputSection>,
    /// Transport and signal map.
    #[serde(default = "d_bus")]
    pub bus: BusSection,
    /// Overrides of the plant file's `[controller]` keys (law gains, observer, detector).
    #[serde(default)]
    pub controller: toml::Table,
    /// The event log.
    #[serde(default)]
    pub event_log: EventLogConfig,
    /// The simulated skid.
    #[serde(default)]
    pub simulation: SimulationSection,
    /// Status reporting.
    #[serde(default)]
    pub status: StatusSection,
    /// How configuration changes are picked up.
    #[serde(default)]
    pub reload: ReloadSection,
}

fn d_bus() -> BusSection {
    BusSection {
        transport: Transport::InProcess,
        signal_map: None,
        can: None,
        modbus: None,
    }
}

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

/// A configuration problem: an error (refused) or a warning (printed, accepted).
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    /// Located error message.
    pub error: FileError,
    /// A warning does not fail the check.
    pub warning: bool,
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.warning {
            write!(f, "warning: {}", self.error)
        } else {
            write!(f, "error: {}", self.error)
        }
    }
}

/// A loaded, resolved and checked configuration.
#[derive(Debug, Clone)]
pub struct Loaded {
    /// The typed schema.
    pub config: DaemonConfig,
    /// Main file.
    pub main_path: PathBuf,
    /// Source layers, main first.
    pub layers: Vec<Layer>,
    /// The simulated plant (`[plant] file`), if any.
    pub plant: Option<PlantDescription>,
    /// The controller's machine description (`[machine] file`, else derived from the plant).
    pub machine: crate::machine::MachineDescription,
    /// The controller's machine model.
    pub model: ControlModel,
    /// Controller settings: the plant file's `[controller]` with the overrides applied.
    pub controller: ControllerConfig,
    /// Core settings (fail-safe opening, input limits).
    pub core: CoreSettings,
    /// Selected law.
    pub law: LawId,
    /// Signal map (empty for in-process).
    pub signal_map: SignalMap,
    /// The merged key/value view (for diffs on reload).
    pub flat: BTreeMap<String, String>,
    /// Warnings found by the checks.
    pub warnings: Vec<Problem>,
}

/// Where the main file's relative paths are resolved from.
fn base_dir(main: &Path) -> PathBuf {
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

fn read_layer(path: &Path) -> Result<Layer, FileError> {
    let text = crate::config::read_config_text(path).map_err(|e| FileError {
        file: path.to_path_buf(),
        key: String::new(),
        line: 0,
        column: 0,
        message: format!("cannot read: {e}"),
        hint: Some("check the path and that the antisurge user may read it".into()),
    })?;
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
fn table_get<'a>(table: &'a toml::Table, dotted: &str) -> Option<&'a toml::Value> {
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
fn layers_set(layers: &[Layer], dotted: &str) -> bool {
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
fn with_file_line_key(mut e: FileError) -> FileError {
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

/// The key a serde message is about, below the path where serde raised it: `unknown field
/// `x``, `missing field `x`` and an unknown map key (`[inputs.p_sucton]`) are raised at the
/// enclosing table, the `[event_log]` range checks at `event_log`.
fn refine_key(layers: &[Layer], key: &str, message: &str) -> String {
    name_map_keys(
        &layers.iter().map(|l| &l.table).collect::<Vec<_>>(),
        &refine_key_inner(layers, key, message),
        message,
    )
}

fn refine_key_inner(layers: &[Layer], key: &str, message: &str) -> String {
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
    if key == "event_log" {
        if let Some(f) = event_log_key(message) {
            return format!("event_log.{f}");
        }
    }
    key.to_string()
}

/// The `[event_log]` key an event-log configuration message is about.
fn event_log_key(message: &str) -> Option<&'static str> {
    let m = message
        .strip_prefix("event log configuration: ")
        .unwrap_or(message);
    [
        "fsync_interval_ms",
        "fsync",
        "max_bytes",
        "keep_files",
        "rt_queue_capacity",
        "poll_interval_ms",
        "path",
    ]
    .into_iter()
    .find(|k| m.starts_with(k))
}

/// The `[bus.modbus]` key a Modbus link or client validation message is about.
fn modbus_key(message: &str) -> String {
    const KEYS: [(&str, &str); 8] = [
        ("backoff_max_ms", "client.backoff_max_ms"),
        ("timeout_ms", "client.timeout_ms"),
        ("baud", "client.transport.baud"),
        ("stop_bits", "client.transport.stop_bits"),
        ("data_bits", "client.transport.data_bits"),
        ("poll_rate_hz", "poll_rate_hz"),
        ("max_output_age_ms", "max_output_age_ms"),
        ("heartbeat_register", "heartbeat_register"),
    ];
    KEYS.iter()
        .filter_map(|(word, key)| message.find(word).map(|i| (i, *key)))
        .min_by_key(|(i, _)| *i)
        .map_or_else(
            || "bus.modbus".to_string(),
            |(_, k)| format!("bus.modbus.{k}"),
        )
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
    if p.is_absolute() {
        return p.to_path_buf();
    }
    match std::env::var_os("LOGS_DIRECTORY") {
        Some(d) => PathBuf::from(d).join(p),
        None => Path::new("out").join(p),
    }
}

/// Read the layers of `main`: the file, `conf.d/*.toml`, then the environment `vars`.
pub fn read_layers(main: &Path, vars: &[(String, String)]) -> Result<Vec<Layer>, FileError> {
    let mut layers = vec![read_layer(main)?];
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
        let key = refine_key(layers, &key, &message);
        let mut err = locate(layers, &key, message.clone());
        err.hint = hint_for(&message, &key);
        err
    })?;
    Ok((cfg, as_table))
}

fn hint_for(message: &str, key: &str) -> Option<String> {
    if message.starts_with("unknown field") {
        Some("keys carry their unit (`_hz`, `_ms`, `_pct`, `_rad_s`, `_kg_s`); check the spelling against config/antisurge.toml".into())
    } else if message.starts_with("missing field") {
        // `key` names the missing key itself (see `refine_key`)
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

/// Deep-merge `over` into `base` (a fully serialized settings table). A one-key table of
/// `base` whose key `over` does not repeat is an enum variant (`control_line = { sqrt = … }`)
/// and is replaced by the other variant, not merged with it.
fn deep_merge(base: &mut toml::Table, over: &toml::Table) {
    for (k, v) in over {
        match (base.get_mut(k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o))
                if !(b.len() == 1 && b.keys().all(|bk| !o.contains_key(bk))) =>
            {
                deep_merge(b, o)
            }
            _ => {
                base.insert(k.clone(), v.clone());
            }
        }
    }
}

/// The plant file's controller settings with the `[controller]` overrides applied.
fn controller_settings(
    layers: &[Layer],
    base: &ControllerConfig,
    over: &toml::Table,
) -> Result<ControllerConfig, FileError> {
    if over.is_empty() {
        return Ok(base.clone());
    }
    let mut table = toml::Table::try_from(base).map_err(|e| FileError {
        file: layers[0].path.clone(),
        key: "controller".into(),
        line: 0,
        column: 0,
        message: format!("cannot represent the plant's controller settings: {e}"),
        hint: None,
    })?;
    deep_merge(&mut table, over);
    let text = toml::to_string(&table).unwrap_or_default();
    let de = toml::de::Deserializer::parse(&text).map_err(|e| FileError {
        file: layers[0].path.clone(),
        key: "controller".into(),
        line: 0,
        column: 0,
        message: e.to_string(),
        hint: None,
    })?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let key = format!("controller.{}", e.path());
        let message = e.into_inner().message().trim().to_string();
        let key = refine_key(layers, &key, &message);
        let mut err = locate(layers, &key, message.clone());
        err.hint = hint_for(&message, &key);
        err
    })
}

/// Load, resolve and check a configuration with the process environment.
pub fn load(main: &Path) -> Result<Loaded, Vec<Problem>> {
    let vars: Vec<(String, String)> = std::env::vars().collect();
    load_with_env(main, &vars)
}

fn err(e: FileError) -> Vec<Problem> {
    vec![Problem {
        error: e,
        warning: false,
    }]
}

/// Load with an explicit environment (tests).
pub fn load_with_env(main: &Path, vars: &[(String, String)]) -> Result<Loaded, Vec<Problem>> {
    let layers = read_layers(main, vars).map_err(err)?;
    let (config, merged) = merge(&layers).map_err(err)?;
    let at = |key: &str, msg: String| locate(&layers, key, msg);

    let resolved = super::config_machine::resolve_machine(
        main,
        &layers,
        config.machine.as_ref(),
        config.plant.as_ref().map(|p| p.file.as_path()),
        &with_file_line_key,
    )
    .map_err(err)?;
    let (plant, machine) = (resolved.plant, resolved.machine);
    let model = ControlModel::from_machine(&machine, resolved.controller);
    let controller =
        controller_settings(&layers, &model.controller, &config.controller).map_err(err)?;
    let law: LawId = config
        .control
        .law
        .parse()
        .map_err(|e: crate::control::law::UnknownLaw| {
            err(at("control.law", e.to_string()).with_hint("e.g. law = \"recycle-pi\""))
        })?;

    let signal_map = match (&config.bus.transport, &config.bus.signal_map) {
        (Transport::InProcess, None) => SignalMap::default(),
        (_, Some(p)) => {
            let path = resolve(main, p);
            let (m, _text): (SignalMap, String) =
                crate::config::toml_file::load(&path).map_err(|e| {
                    if e.line == 0 && e.key.is_empty() {
                        err(at(
                            "bus.signal_map",
                            format!(
                                "cannot load the signal map {}: {}",
                                path.display(),
                                e.message
                            ),
                        ))
                    } else {
                        err(with_file_line_key(e))
                    }
                })?;
            m
        }
        (Transport::Field, None) => {
            return Err(err(at(
                "bus.signal_map",
                "transport = \"field\" needs a signal map".into(),
            )
            .with_hint("signal_map = \"signals.toml\"")))
        }
    };

    // input limits: plant-derived defaults, overridden per sensor
    let mut core = CoreSettings::defaults_for(&model);
    super::config_machine::apply_transmitter_ranges(&machine, &mut core);
    // freshness defaults follow the bus: inputs polled over Modbus may be up to a poll period
    // (plus the answer) old between answers, so their default timeout is 3 poll periods
    if let (Transport::Field, Some(m)) = (&config.bus.transport, &config.bus.modbus) {
        let polled: Vec<SensorId> = signal_map.modbus_sensors().iter().map(|s| s.0).collect();
        core.follow_poll_period_of(&polled, 1.0 / m.poll_rate_hz);
    }
    for (id, s) in &config.inputs {
        core.supervisor.limits[id.index()] = Some(InputLimits {
            min: s.min,
            max: s.max,
            timeout_s: s.timeout_ms * 1e-3,
        });
    }
    core.failsafe_recycle_opening = config.control.failsafe_recycle_opening_pct * 0.01;
    core.startup_grace_s = config.control.startup_grace_ms * 1e-3;

    let mut config = config;
    config.event_log.path = output_path(&config.event_log.path);
    config.status.stats_file = config.status.stats_file.as_deref().map(output_path);
    let mut loaded = Loaded {
        config,
        main_path: main.to_path_buf(),
        flat: flatten(&merged),
        layers,
        plant,
        machine,
        model,
        controller,
        core,
        law,
        signal_map,
        warnings: Vec::new(),
    };
    let problems = check(&loaded);
    let (warnings, errors): (Vec<_>, Vec<_>) = problems.into_iter().partition(|p| p.warning);
    if !errors.is_empty() {
        let mut all = errors;
        all.extend(warnings);
        return Err(all);
    }
    loaded.warnings = warnings;
    Ok(loaded)
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
];

/// Is `key` (dotted) applied live on reload?
pub fn is_live_key(key: &str) -> bool {
    !RESTART_KEYS
        .iter()
        .any(|r| key == *r || key.starts_with(&format!("{r}.")))
}

/// Where a key of the rules below is reported: `controller.*` keys that no config layer sets
/// come from the plant file's `[controller]` table and are located there; everything else in
/// the last config layer that sets it.
fn locate_for(l: &Loaded, key: &str, message: String) -> FileError {
    if let (true, false, Some(plant)) = (
        key.starts_with("controller."),
        layers_set(&l.layers, key),
        l.config
            .plant
            .as_ref()
            .filter(|_| l.config.machine.is_none()),
    ) {
        let path = resolve(&l.main_path, &plant.file);
        if let Ok(text) = crate::config::read_config_text(&path) {
            let set = toml::from_str::<toml::Table>(&text)
                .ok()
                .is_some_and(|t| table_get(&t, key).is_some());
            if set {
                return FileError::at_key(&path, &text, key, message);
            }
        }
    }
    locate(&l.layers, key, message)
}

/// An error about a key of the signal map file, located in that file.
fn map_error(l: &Loaded, key: &str, message: String) -> FileError {
    match &l.config.bus.signal_map {
        Some(p) => {
            let path = resolve(&l.main_path, p);
            let text = crate::config::read_config_text(&path).unwrap_or_default();
            FileError::at_key(&path, &text, key, message)
        }
        None => locate(&l.layers, "bus.signal_map", message),
    }
}

/// The signal-map key of a CAN binding target.
fn target_key(t: SignalTarget) -> String {
    match t {
        SignalTarget::Sensor(s) => format!("sensors.{}.can", s.name()),
        SignalTarget::Actuator(a) => format!("actuators.{}.can", a.name()),
    }
}

/// The signal map's own rules (whatever the transport: the plant node reads the same file):
/// Modbus registers valid and not overlapping, actuators in holding registers, no DBC signal
/// bound twice, the Modbus heartbeat block clear of the signals.
fn check_map(l: &Loaded) -> Vec<Problem> {
    let map = &l.signal_map;
    let mut out = Vec::new();
    let push_w = |out: &mut Vec<Problem>, e: FileError, hint: Option<&str>, warning: bool| {
        out.push(Problem {
            error: FileError {
                hint: hint.map(str::to_string),
                ..e
            },
            warning,
        })
    };
    let push =
        |out: &mut Vec<Problem>, e: FileError, hint: Option<&str>| push_w(out, e, hint, false);
    for p in map.check() {
        let hint = p
            .key
            .ends_with(".unit")
            .then_some("declare the unit the device uses (e.g. \"%\", \"bar\", \"rpm\", \"degC\"); it must measure what the signal is");
        push_w(&mut out, map_error(l, &p.key, p.message), hint, p.warning);
    }
    let mut seen: Vec<(String, &str, &str)> = Vec::new();
    let can = map
        .sensors
        .iter()
        .map(|(id, b)| (format!("sensors.{}.can", id.name()), b))
        .chain(
            map.actuators
                .iter()
                .map(|(id, b)| (format!("actuators.{}.can", id.name()), b)),
        );
    for (key, b) in can {
        let Binding::Can { message, signal } = b else {
            continue;
        };
        if let Some((first, _, _)) = seen
            .iter()
            .find(|(_, m, s)| *m == message.as_str() && *s == signal.as_str())
        {
            push(
                &mut out,
                map_error(
                    l,
                    &key,
                    format!("CAN signal {message}.{signal} is already bound to `{first}`"),
                ),
                Some("each DBC signal carries one sensor or actuator"),
            );
        } else {
            seen.push((key, message, signal));
        }
    }
    if out.iter().all(|p| p.warning) {
        if let Some(hb) = l
            .config
            .bus
            .modbus
            .as_ref()
            .and_then(|m| m.heartbeat_register)
        {
            if let Err(e) = crate::io::modbus::link::check_map(map, Some(&hb)) {
                push(
                    &mut out,
                    locate(&l.layers, "bus.modbus.heartbeat_register", e.to_string()),
                    Some("move the heartbeat block to free holding registers"),
                );
            }
        }
    }
    out
}

/// The CAN bindings against the DBC file (field transport only: the in-process plant needs
/// no DBC).
fn check_dbc(l: &Loaded, can: &CanBusConfig) -> Option<FileError> {
    let dbc = resolve(&l.main_path, &can.dbc);
    match BusCodec::load(&dbc, &l.signal_map.can_bindings()) {
        Ok(_) => None,
        Err(CanBusError::Binding(b)) => {
            let target = match &b {
                BindingError::UnknownMessage { target, .. }
                | BindingError::UnknownSignal { target, .. }
                | BindingError::ProtectionSignal { target, .. }
                | BindingError::Unit { target, .. }
                | BindingError::DuplicateTarget { target, .. } => Some(*target),
                BindingError::SignalBoundTwice { second, .. } => Some(*second),
                _ => None,
            };
            let message = format!("{b} (DBC {})", dbc.display());
            Some(match target {
                Some(t) => map_error(l, &target_key(t), message),
                None => locate(&l.layers, "bus.can.dbc", message),
            })
        }
        Err(e) => Some(locate(
            &l.layers,
            "bus.can.dbc",
            format!("cannot use the DBC file: {e}"),
        )),
    }
}

/// The worst-case bus load of the DBC's periodic messages at `bus.can.bitrate_bps`, refused
/// above `bus.can.max_load_pct`.
fn check_bus_load(l: &Loaded, can: &CanBusConfig) -> Option<FileError> {
    let bitrate = can.bitrate_bps?;
    let db = crate::io::can::CanDatabase::from_file(resolve(&l.main_path, &can.dbc)).ok()?;
    let load = crate::io::can::busload::BusLoad::of(&db, bitrate);
    (load.percent() > f64::from(can.max_load_pct)).then(|| {
        FileError {
            hint: Some(format!(
                "the DBC's periodic messages need {:.0} kbit/s with worst-case bit stuffing: raise the bit rate on every node (deploy/80-can0.network BitRate=) and here, or lengthen cycle times in the DBC",
                load.bits_per_s / 1000.0
            )),
            ..locate(
                &l.layers,
                "bus.can.bitrate_bps",
                format!(
                    "worst-case bus load {:.1} % at {} kbit/s exceeds the limit of {} % (bus.can.max_load_pct)",
                    load.percent(),
                    bitrate / 1000,
                    can.max_load_pct
                ),
            )
        }
    })
}

/// The cross-field rules. Returns errors and warnings, located.
pub fn check(l: &Loaded) -> Vec<Problem> {
    let mut out = Vec::new();
    let mut out_machine: Vec<Problem> = Vec::new();
    out_machine.extend(super::config_machine::transport_problem(l));
    let layers = &l.layers;
    let c = &l.config;
    let mut error = |key: &str, msg: String, hint: &str| {
        let mut e = locate_for(l, key, msg);
        if !hint.is_empty() {
            e.hint = Some(hint.to_string());
        }
        out.push(Problem {
            error: e,
            warning: false,
        });
    };

    // cycle
    if !(c.cycle.rate_hz.is_finite() && c.cycle.rate_hz > 0.0 && c.cycle.rate_hz <= 10_000.0) {
        error(
            "cycle.rate_hz",
            format!("{} Hz is outside 0 < rate_hz ≤ 10000", c.cycle.rate_hz),
            "1000 on CAN, 50–100 on Modbus",
        );
    }
    if let Some(p) = c.cycle.priority {
        if !(1..=99).contains(&p) {
            error(
                "cycle.priority",
                format!("{p} is not a SCHED_FIFO priority (1–99)"),
                "80 is the usual choice; leave it out for normal scheduling",
            );
        }
    }
    if let Some(cpu) = c.cycle.cpu {
        // the index reaches CPU_SET (unsafe) at start: refuse it here, not with an abort there
        let n = crate::runtime::rt_loop::configured_cpus();
        if cpu >= n {
            error(
                "cycle.cpu",
                format!(
                    "CPU {cpu} does not exist: this machine has CPUs 0–{}",
                    n - 1
                ),
                "leave it out for no pinning, or name an isolated CPU (isolcpus=)",
            );
        }
    }
    // gains: documented plausibility bounds (control/config.rs), before any law sees them
    for (key, message) in l.controller.plausibility_problems() {
        error(
            &format!("controller.{key}"),
            message,
            "the seed defaults are in the plant files; change a gain by a factor of 2 at a time",
        );
    }
    let settle = c.reload.settle_ms;
    if !(settle.is_finite() && (100.0..=60_000.0).contains(&settle)) {
        error(
            "reload.settle_ms",
            format!("{settle} ms is outside 100–60000 ms"),
            "1000: a change is applied once the files stayed unchanged for a second",
        );
    }
    // control
    let f = c.control.failsafe_recycle_opening_pct;
    if !(f.is_finite() && (0.0..=100.0).contains(&f)) {
        error(
            "control.failsafe_recycle_opening_pct",
            format!("{f} is outside 0–100 %"),
            "100 (fully open) is the usual safe state",
        );
    }
    let g = c.control.startup_grace_ms;
    if !(g.is_finite() && (0.0..=60_000.0).contains(&g)) {
        error(
            "control.startup_grace_ms",
            format!("{g} is outside 0–60000 ms"),
            "1000 gives the buses time to deliver the first readings; 0 goes fail-safe at once",
        );
    }
    if let Some(w) = c.control.speed_setpoint_rad_s {
        let nominal = l.model.drive.nominal_speed_rad_s;
        if !(w.is_finite() && w > 0.0 && w <= 1.2 * nominal) {
            error(
                "control.speed_setpoint_rad_s",
                format!("{w} rad/s is outside (0, 120 % of the nominal {nominal:.1} rad/s]"),
                "leave it out to run at the plant's nominal speed",
            );
        }
    }
    if let Some(m) = c.control.flow_setpoint_kg_s {
        if !(m.is_finite() && m > 0.0) {
            error(
                "control.flow_setpoint_kg_s",
                format!("{m} kg/s must be a positive mass flow"),
                "",
            );
        }
    }
    // the law on this machine with these gains (applicability, eq. 8, eq. 17, SCL vs surge line)
    let law_error = |e: LawError| {
        match e.clone() {
        LawError::NotApplicable { law, plant, kind } => (
            "control.law".to_string(),
            format!(
                "law `{law}` cannot run on plant `{plant}` (model {kind:?}): it needs the actuators {}",
                actuator_list(law)
            ),
            "pick a law whose actuator the machine has (README: the surge laws)",
        ),
        LawError::MachineData { .. } => (
            "control.law".to_string(),
            e.to_string(),
            "give the machine data the law needs (README: commissioning from vendor data)",
        ),
        LawError::Setting { law, key, message } => (
            format!("controller.{key}"),
            format!("law `{law}`: {message}"),
            "the seeds' gain conditions are explained in README.md (the surge laws)",
        ),
    }
    };
    match Law::new(l.law, &l.controller, &l.model) {
        Ok(_) => {
            // eq. 8 depends on the operating region, so the law's constructor leaves it to here
            if l.law == LawId::DriveTorque {
                if let Err(e) =
                    check_gains(&l.controller.drive_torque, &l.model, 1.0 / c.cycle.rate_hz)
                {
                    let (key, msg, hint) = law_error(e);
                    error(&key, msg, hint);
                }
            }
        }
        Err(e) => match super::config_machine::machine_data_error(l, &e) {
            Some(p) => out_machine.push(p),
            None => {
                let (key, msg, hint) = law_error(e);
                error(&key, msg, hint);
            }
        },
    }
    // the observer's gain condition only when the flow source uses the observer
    if let (true, Some(min)) = (
        super::config_machine::uses_observer(l),
        l.model.observer_min_gain(),
    ) {
        let c2 = l.controller.observer.c2_pa_s_kg;
        if !(c2.is_finite() && c2 > min) {
            error(
                "controller.observer.c2_pa_s_kg",
                format!(
                    "observer gain c2 = {c2:.4e} is below the bound of seed 000 eq. 17 ({min:.4e}): the flow estimate would not converge"
                ),
                "raise c2 above the bound (about 2× is a good start)",
            );
        }
    }
    // inputs
    for (id, s) in &c.inputs {
        let key = format!("inputs.{}", id.name());
        if !(s.min.is_finite() && s.max.is_finite() && s.min < s.max) {
            error(
                &format!("{key}.max"),
                format!(
                    "range [{}, {}] {} is empty or not finite (min must be below max)",
                    s.min,
                    s.max,
                    id.unit()
                ),
                "min < max, in the sensor's SI unit",
            );
        }
        let period_ms = 1e3 / c.cycle.rate_hz.max(1e-9);
        if !(s.timeout_ms.is_finite() && s.timeout_ms > period_ms) {
            error(
                &format!("{key}.timeout_ms"),
                format!(
                    "{} ms must be longer than one control period ({period_ms:.2} ms)",
                    s.timeout_ms
                ),
                "a few sensor periods, e.g. 50",
            );
        }
    }
    // bus: the settings that are present are checked whatever the transport
    if let Some(can) = &c.bus.can {
        if let Err(e) = can.validate() {
            let key = match &e {
                CanBusError::Config { key, .. } => format!("bus.can.{key}"),
                _ => "bus.can".to_string(),
            };
            error(&key, e.to_string(), "");
        }
    }
    if let Some(m) = &c.bus.modbus {
        if let Err(e) = m.validate() {
            let msg = e.to_string();
            error(&modbus_key(&msg), msg, "");
        }
    }
    let mut map_problems = if c.bus.signal_map.is_some() {
        check_map(l)
    } else {
        Vec::new()
    };
    if c.bus.transport == Transport::Field {
        let map = &l.signal_map;
        // exactly what the law, the flow source and the drive ownership need (law registry)
        let (actuators, sensors) = super::config_machine::required_bindings(l);
        for a in actuators {
            if !map.actuators.contains_key(&a) {
                let why = if a == ActuatorId::DriveTorque && !l.law.actuators().contains(a) {
                    "the controller owns the drive's speed loop, which drives".to_string()
                } else {
                    format!("law `{}` drives", l.law)
                };
                error(
                    "bus.signal_map",
                    format!("{why} `{}` but the signal map does not bind it", a.name()),
                    &format!("add [actuators.{}] to the signal map", a.name()),
                );
            }
        }
        for s in sensors {
            if !map.sensors.contains_key(&s) {
                error(
                    "bus.signal_map",
                    format!(
                        "law `{}` reads `{}` but the signal map does not bind it",
                        l.law,
                        s.name()
                    ),
                    &format!("add [sensors.{}] to the signal map", s.name()),
                );
            }
        }
        if !map.can_bindings().is_empty() {
            match &c.bus.can {
                None => error(
                    "bus.can",
                    "the signal map binds CAN signals but [bus.can] is missing".into(),
                    "interface = \"can0\" and dbc = \"skid.dbc\"",
                ),
                Some(can) => {
                    if can.validate().is_ok() && map_problems.is_empty() {
                        if let Some(e) = check_dbc(l, can) {
                            map_problems.push(Problem {
                                error: e,
                                warning: false,
                            });
                        }
                        if let Some(e) = check_bus_load(l, can) {
                            map_problems.push(Problem {
                                error: e,
                                warning: false,
                            });
                        }
                    }
                }
            }
        }
        if !(map.modbus_sensors().is_empty() && map.modbus_actuators().is_empty())
            && c.bus.modbus.is_none()
        {
            error(
                "bus.modbus",
                "the signal map binds Modbus registers but [bus.modbus] is missing".into(),
                "see config/antisurge.toml for a [bus.modbus] example",
            );
        }
    }
    if let Err(e) = c.event_log.validate() {
        let msg = e.to_string();
        let key =
            event_log_key(&msg).map_or_else(|| "event_log".into(), |k| format!("event_log.{k}"));
        error(&key, msg, "");
    }
    if !(c.simulation.heartbeat_timeout_ms.is_finite() && c.simulation.heartbeat_timeout_ms > 0.0) {
        error(
            "simulation.heartbeat_timeout_ms",
            format!("{} ms must be positive", c.simulation.heartbeat_timeout_ms),
            "",
        );
    }
    if !(c.status.log_interval_s.is_finite() && c.status.log_interval_s >= 0.0) {
        error(
            "status.log_interval_s",
            format!(
                "{} s must be ≥ 0 (0: no status line)",
                c.status.log_interval_s
            ),
            "",
        );
    }
    out.extend(map_problems);
    out.extend(out_machine);
    out.extend(super::config_machine::plausibility(l));

    // warnings: legal but risky
    if let crate::control::surge_control_line::ControlLineForm::Margin { margin_pct, .. } =
        l.controller.recycle_pi.control_line
    {
        // (a line left of the trip line is already an error about the same key)
        let refused = out
            .iter()
            .any(|p| p.error.key == "controller.recycle_pi.control_line");
        if matches!(l.law, LawId::RecyclePi) && margin_pct < 5.0 && !refused {
            out.push(Problem {
                error: locate_for(
                    l,
                    "controller.recycle_pi.control_line.margin.margin_pct",
                    format!(
                        "surge control line margin {margin_pct} % is under 5 %: little room for measurement error"
                    ),
                ),
                warning: true,
            });
        }
    }
    if c.control.failsafe_recycle_opening_pct < 50.0 && l.model.has_recycle_valve() {
        out.push(Problem {
            error: locate(
                layers,
                "control.failsafe_recycle_opening_pct",
                format!(
                    "fail-safe recycle opening {} % is under 50 %: a fail-safe at low flow may not keep the machine out of surge",
                    c.control.failsafe_recycle_opening_pct
                ),
            ),
            warning: true,
        });
    }
    out
}

fn actuator_list(law: LawId) -> String {
    law.actuators()
        .iter()
        .map(ActuatorId::name)
        .collect::<Vec<_>>()
        .join(" + ")
}
