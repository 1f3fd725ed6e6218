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
//! limits). [`check`] runs every rule; `antisurge check-config`, start-up and hot reload all
//! call the same two functions.
//!
//! The module is split by owner:
//! - [`layers`]: files, `conf.d/`, the environment layer, merge, flatten, locating a key;
//! - one file per section with its types, defaults and a `validate` returning typed
//!   [`KeyProblem`]s that carry their key path ([`control`], [`cycle`], [`inputs`], [`bus`],
//!   [`controller`], [`event_log`], [`simulation`], [`status`] with [`tls`], [`reload`], [`plant`],
//!   [`machine`]);
//! - [`cross`]: the rules between sections (the law on this machine, what the law needs
//!   bound, signal map against the buses, DBC, bus load, risky combinations), in one place;
//! - [`print`]: `check-config --print`;
//! - [`unit`]: what the shipped systemd unit lets the service bind;
//! - [`sanity`]: pressure ranges typed in another unit, valve openings in percent or fraction;
//! - [`dry_run`]: a reload against the live inputs (a range that refuses them is refused);
//! - [`running`]: the running configuration's record and the completeness rule of a reload.

pub mod bus;
pub mod control;
pub mod controller;
pub mod cross;
pub mod cycle;
pub mod dry_run;
pub mod event_log;
pub mod inputs;
pub mod layers;
pub mod machine;
pub mod plant;
pub mod print;
pub mod problem;
pub mod reload;
pub mod running;
pub mod sanity;
pub mod simulation;
pub use crate::live::settings as status;
pub use crate::live::tls_settings as tls;
pub use crate::sparkplug::settings as sparkplug;
pub mod unit;

pub use bus::{BusSection, Transport};
pub use control::{ControlSection, StartMode};
pub use inputs::InputSection;
pub use layers::{
    conf_d, flatten, key_at_line, locate, merge, output_path, read_layers, resolve, Layer,
    ENV_PREFIX, MAX_ENV_DEPTH,
};
pub use machine::MachineSection;
pub use plant::PlantSection;
pub use problem::{KeyProblem, Problem, Severity};
pub use reload::{is_live_key, ReloadSection, RESTART_KEYS};
pub use simulation::SimulationSection;
pub use sparkplug::SparkplugSection;
pub use status::StatusSection;

use crate::config::FileError;
use crate::control::config::ControllerConfig;
use crate::control::core::CoreSettings;
use crate::control::law::api::LawId;
use crate::control::model::ControlModel;
use crate::control::supervisor::InputLimits;
use crate::events::EventLogConfig;
use crate::io::signal_map::SignalMap;
use crate::runtime::rt_loop::RtSettings;
use crate::sim::case::PlantCase;
use crate::vocab::signals::SensorId;
use layers::{layers_set, table_get, with_file_line_key};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The whole configuration file (`config/antisurge.toml` documents every key).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DaemonConfig {
    /// The simulated machine (a plant file); without `[machine]`, also the controller's.
    #[serde(default)]
    pub plant: Option<PlantSection>,
    /// The controller's machine description (vendor data), `config/machines/*.toml`.
    #[serde(default)]
    pub machine: Option<MachineSection>,
    /// Law, mode, setpoints, fail-safe opening.
    pub control: ControlSection,
    /// The control thread: rate, priority, CPU, memory locking.
    #[serde(default)]
    pub cycle: RtSettings,
    /// Input supervision per sensor; sensors not listed get defaults derived from the plant.
    #[serde(default)]
    pub inputs: BTreeMap<SensorId, InputSection>,
    /// Transport and signal map.
    #[serde(default = "bus::d_bus")]
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
    /// The Sparkplug B edge node (off by default).
    #[serde(default)]
    pub sparkplug: SparkplugSection,
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
    pub plant: Option<PlantCase>,
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

/// Load, resolve and check a configuration with the process environment.
pub fn load(main: &Path) -> Result<Loaded, Vec<Problem>> {
    let vars: Vec<(String, String)> = std::env::vars().collect();
    load_with_env(main, &vars)
}

fn err(e: FileError) -> Vec<Problem> {
    vec![Problem::error(e)]
}

/// Load with an explicit environment (tests).
pub fn load_with_env(main: &Path, vars: &[(String, String)]) -> Result<Loaded, Vec<Problem>> {
    let layers = read_layers(main, vars).map_err(err)?;
    load_layers(main, layers)
}

/// Load with the main file's `text` given instead of read from `main` (`main` still names it
/// and places `conf.d/` and relative paths). The fuzz target `config_layers` parses from
/// memory through here: the same checks as [`load_with_env`], no file per input.
pub fn load_text_with_env(
    main: &Path,
    text: &str,
    vars: &[(String, String)],
) -> Result<Loaded, Vec<Problem>> {
    let first = layers::layer_of_text(main, text.to_string()).map_err(err)?;
    let layers = layers::read_layers_after(first, main, vars).map_err(err)?;
    load_layers(main, layers)
}

fn load_layers(main: &Path, layers: Vec<Layer>) -> Result<Loaded, Vec<Problem>> {
    let (config, merged) = merge(&layers).map_err(err)?;
    let at = |key: &str, msg: String| locate(&layers, key, msg);

    let resolved = machine::resolve_machine(
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
        controller::controller_settings(&layers, &model.controller, &config.controller)
            .map_err(err)?;
    let law: LawId =
        config
            .control
            .law
            .parse()
            .map_err(|e: crate::control::law::api::UnknownLaw| {
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
    machine::apply_transmitter_ranges(&machine, &mut core);
    // a contact the signal map binds (ESD / drive trip) is supervised like any input:
    // 0 or 1, fresh within the default timeout (polled: the poll-period rule below)
    for id in SensorId::ALL.into_iter().filter(|id| id.is_contact()) {
        if signal_map.sensors.contains_key(&id) {
            core.bind_contact(id);
        }
    }
    config.bus.follow_poll_period(&signal_map, &mut core);
    for (id, s) in &config.inputs {
        core.supervisor.limits[id.index()] = Some(InputLimits {
            min: s.min,
            max: s.max,
            timeout_s: s.timeout_ms * 1e-3,
        });
    }
    // an input the field buses do not carry is not supervised: never a fault, a lamp or a
    // cause (a recycle skid whose drive keeps its own speed binds no shaft speed); the
    // embedded plant delivers every sensor
    if !matches!(config.bus.transport, Transport::InProcess) {
        for id in SensorId::ALL {
            if !signal_map.sensors.contains_key(&id) {
                core.supervisor.limits[id.index()] = None;
            }
        }
    }
    // redundant transmitters: the signal map's [vote] (b and c share a's limits)
    core.vote = signal_map.vote_settings();
    core.failsafe_recycle_opening = config.control.failsafe_recycle_opening_pct * 0.01;
    core.startup_grace_s = config.control.startup_grace_ms * 1e-3;

    let mut config = config;
    config.event_log.path = output_path(&config.event_log.path);
    config.status.stats_file = config.status.stats_file.as_deref().map(output_path);
    config.status.tls = config.status.tls.as_ref().map(|t| t.resolved(main));
    config.sparkplug = config.sparkplug.resolved(main);
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

/// Where a key of the rules below is reported: `controller.*` keys that no config layer sets
/// come from the plant file's `[controller]` table and are located there; everything else in
/// the last config layer that sets it.
pub(crate) fn locate_for(l: &Loaded, key: &str, message: String) -> FileError {
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

impl KeyProblem {
    /// The problem located in the configuration `l` (file:line of the last layer that sets
    /// the key; a `controller.*` key set only by the plant file, in that file).
    pub fn locate_in(self, l: &Loaded) -> Problem {
        let mut error = locate_for(l, &self.key, self.message);
        if self.hint.is_some() {
            error.hint = self.hint;
        }
        Problem {
            error,
            warning: self.severity == Severity::Warning,
        }
    }
}

/// Every rule, in the order check-config prints them: each section's own rules, then the
/// rules between sections ([`cross`]), then plausibility warnings. Returns errors and
/// warnings, located.
pub fn check(l: &Loaded) -> Vec<Problem> {
    let c = &l.config;
    let mut own: Vec<KeyProblem> =
        cycle::validate(&c.cycle, crate::runtime::rt_loop::configured_cpus());
    own.extend(controller::validate(&l.controller));
    own.extend(c.reload.validate());
    own.extend(c.control.validate(l.model.drive.nominal_speed_rad_s));
    let mut out: Vec<Problem> = own.into_iter().map(|p| p.locate_in(l)).collect();
    let (law, machine_data) = cross::law(l);
    out.extend(law);
    let mut own = inputs::validate(&c.inputs, c.cycle.rate_hz);
    own.extend(c.bus.validate());
    out.extend(own.into_iter().map(|p| p.locate_in(l)));
    let map_problems = cross::signal_map(l);
    out.extend(cross::bindings(l));
    let mut own = event_log::validate(&c.event_log);
    own.extend(c.simulation.validate());
    own.extend(c.status.validate());
    // a port the service unit's capabilities cannot bind
    own.extend(unit::bind_problems(&c.status));
    own.extend(c.sparkplug.validate());
    out.extend(own.into_iter().map(|p| p.locate_in(l)));
    out.extend(map_problems);
    out.extend(machine::transport_problem(l));
    out.extend(machine_data);
    out.extend(sanity::pressure_ranges(l));
    out.extend(sanity::fraction_bindings(l));
    out.extend(machine::plausibility(l));
    let warnings = cross::warnings(l, &out);
    out.extend(warnings);
    out
}
