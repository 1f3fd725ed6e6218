//! The daemon config's machine: `[machine] file` (vendor data, `config/machines/*.toml`) or
//! `[plant] file` (a simulation plant file, which yields the same machine description), what
//! the selected law and flow source need of it, and plausibility warnings (transmitter ranges
//! against the operating envelope, the flow element against the surge line).
//!
//! With both sections, `[machine]` is what the controller knows and `[plant]` the simulated
//! skid (`antisurge plant`, in-process): the controller is then told nothing of the plant.

use super::layers::{locate, resolve, Layer};
use super::{Loaded, Problem, Transport};
use crate::config::FileError;
use crate::control::config::{ControllerConfig, FlowSource};
use crate::control::law::api::LawError;
use crate::machine::surge_line::element_dp_pa;
use crate::machine::MachineDescription;
use crate::sim::case::PlantCase;
use crate::vocab::signals::{ActuatorId, SensorId};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// `[machine]`: the machine description file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MachineSection {
    /// Machine file (`config/machines/*.toml`), relative to the main config file.
    pub file: PathBuf,
}

/// What the controller is given: the machine description, the simulated plant if any, and the
/// tuned controller defaults (a plant file's `[controller]`; seed defaults for vendor data).
pub struct Resolved {
    /// The simulated plant (`[plant]`), if any.
    pub plant: Option<PlantCase>,
    /// The controller's machine.
    pub machine: MachineDescription,
    /// Controller defaults before the config's `[controller]` overrides.
    pub controller: ControllerConfig,
}

/// Load `[machine]` and/or `[plant]`.
pub fn resolve_machine(
    main: &Path,
    layers: &[Layer],
    machine: Option<&MachineSection>,
    plant: Option<&Path>,
    file_error: &dyn Fn(FileError) -> FileError,
) -> Result<Resolved, FileError> {
    let plant = match plant {
        Some(p) => {
            let path = resolve(main, p);
            Some(PlantCase::load(&path).map_err(|e| {
                if e.line == 0 && e.key.is_empty() {
                    locate(
                        layers,
                        "plant.file",
                        format!(
                            "cannot load the plant file {}: {}",
                            path.display(),
                            e.message
                        ),
                    )
                } else {
                    file_error(e)
                }
            })?)
        }
        None => None,
    };
    match (machine, &plant) {
        (Some(m), _) => {
            let path = resolve(main, &m.file);
            let desc = crate::machine::file::load(&path).map_err(|e| {
                if e.line == 0 && e.key.is_empty() {
                    locate(
                        layers,
                        "machine.file",
                        format!("cannot load the machine file {}: {}", path.display(), e.message),
                    )
                    .with_hint("config/machines/vendor_example.toml shows every key")
                } else {
                    e
                }
            })?;
            Ok(Resolved {
                plant,
                machine: desc,
                // the schema's defaults (an empty `[controller]`), as for a plant file without one
                controller: toml::from_str::<ControllerConfig>("").unwrap_or_default(),
            })
        }
        (None, Some(p)) => Ok(Resolved {
            machine: p.machine(),
            controller: p.controller.clone(),
            plant,
        }),
        (None, None) => Err(locate(
            layers,
            "machine",
            "no machine: the controller needs [machine] file (vendor data) or [plant] file (a simulation plant)",
        )
        .with_hint("[machine]\nfile = \"machines/vendor_example.toml\"")),
    }
}

/// The bindings the selected law, the flow source and the drive ownership need: exactly
/// these, nothing else (law registry, `control::law::REGISTRY`).
pub fn required_bindings(l: &Loaded) -> (Vec<ActuatorId>, Vec<SensorId>) {
    let d = l.law.descriptor();
    let mut actuators: Vec<ActuatorId> = d.actuators.iter().collect();
    let mut sensors = vec![SensorId::PSuction, SensorId::PDischarge];
    if l.model.owns_drive {
        if !actuators.contains(&ActuatorId::DriveTorque) {
            actuators.push(ActuatorId::DriveTorque);
        }
        sensors.push(SensorId::ShaftSpeed);
    }
    if d.needs_flow && l.controller.flow_source != FlowSource::Observer {
        sensors.push(SensorId::OrificeDp);
    }
    for s in d.sensors {
        if !sensors.contains(s) {
            sensors.push(*s);
        }
    }
    (actuators, sensors)
}

/// Does the flow source use the observer (so its gain condition applies)?
pub fn uses_observer(l: &Loaded) -> bool {
    l.law.descriptor().needs_flow && l.controller.flow_source != FlowSource::Orifice
}

/// An error in the machine's own file (`[machine] file` or `[plant] file`) at `key`, or at
/// the section's `file` key of the config.
fn machine_file_error(l: &Loaded, key: &str, message: String) -> FileError {
    let file = l
        .config
        .machine
        .as_ref()
        .map(|m| (&m.file, "machine.file"))
        .or(l.config.plant.as_ref().map(|p| (&p.file, "plant.file")));
    if let Some((f, cfg_key)) = file {
        let path = resolve(&l.main_path, f);
        if let Ok(text) = std::fs::read_to_string(&path) {
            let head = key.split('.').next().unwrap_or(key);
            for k in [key, head] {
                if crate::config::toml_file::locate_key(&text, k).is_some() {
                    let mut e = FileError::at_key(&path, &text, k, message);
                    e.key = key.to_string();
                    return e;
                }
            }
        }
        return locate(&l.layers, cfg_key, message);
    }
    locate(&l.layers, "machine", message)
}

/// The located problem for a law that cannot be built for want of machine data.
pub fn machine_data_error(l: &Loaded, e: &LawError) -> Option<Problem> {
    let LawError::MachineData {
        law,
        machine,
        missing,
    } = e
    else {
        return None;
    };
    let (what, how) = missing.describe();
    Some(Problem {
        error: locate(
            &l.layers,
            "control.law",
            format!(
                "law `{law}` needs {what}, which the machine description of `{machine}` does not give (missing machine-file key `{key}`)",
                key = missing.key()
            ),
        )
        .with_hint(format!("add {how} to the machine file, or pick a law the data support (README: the surge laws)")),
        warning: false,
    })
}

/// The design operating envelope: (suction pressure, discharge pressure), Pa, if known.
fn envelope(l: &Loaded) -> Option<(f64, f64)> {
    let p_s = l.model.design_suction_pressure_pa?;
    Some((p_s, p_s * l.model.design_pressure_ratio))
}

/// Plausibility warnings: legal, but likely a unit mistake.
pub fn plausibility(l: &Loaded) -> Vec<Problem> {
    let mut out = Vec::new();
    let warn = |e: FileError| Problem {
        error: e,
        warning: true,
    };
    let Some((p_s, p_d)) = envelope(l) else {
        return out;
    };
    // transmitter ranges (machine file) and input ranges (config) against the envelope
    let expect = [(SensorId::PSuction, p_s), (SensorId::PDischarge, p_d)];
    for (id, v) in expect {
        if let Some(r) = l.machine.transmitters.get(&id) {
            if !(r.min <= v && v <= r.max) {
                // explained by another unit: an error naming it (issue 25), else a warning
                let units = super::sanity::likely_units(r.min, r.max, v);
                let message = match units.first() {
                    Some(_) => format!(
                        "range [{}, {}] looks typed in {}: in {} it excludes the design {} of {v:.4e} Pa, so every reading would be refused and the controller would hold fail-safe (recycle valve open)",
                        r.min,
                        r.max,
                        units.join(" or "),
                        id.unit(),
                        id.name()
                    ),
                    None => format!(
                        "range [{}, {}] {} excludes the design {} of {v:.4e} Pa: typed in bar or kPa?",
                        r.min,
                        r.max,
                        id.unit(),
                        id.name()
                    ),
                };
                out.push(Problem {
                    error: machine_file_error(
                        l,
                        &format!("transmitters.{}.max", id.name()),
                        message,
                    )
                    .with_hint("ranges are in SI units: Pa absolute (1 bar = 1e5 Pa)"),
                    warning: units.is_empty(),
                });
            }
        }
        if let Some(s) = l.config.inputs.get(&id) {
            // a range explained by another unit is an error (super::sanity), not a warning
            if !(s.min <= v && v <= s.max)
                && super::sanity::likely_units(s.min, s.max, v).is_empty()
            {
                let mut e = locate(
                    &l.layers,
                    &format!("inputs.{}.max", id.name()),
                    format!(
                        "plausible range [{}, {}] {} excludes the machine's design {} of {v:.4e} Pa: every reading will be refused and the controller will hold fail-safe (recycle valve open)",
                        s.min,
                        s.max,
                        id.unit(),
                        id.name()
                    ),
                );
                e.hint = Some("ranges are in SI units: Pa absolute (1 bar = 1e5 Pa)".into());
                out.push(warn(e));
            }
        }
    }
    // the flow element: the surge line's flow at the design ratio must be measurable within
    // the Δp transmitter's range
    let dp_range = l
        .machine
        .transmitters
        .get(&SensorId::OrificeDp)
        .map(|r| r.max)
        .or(l.config.inputs.get(&SensorId::OrificeDp).map(|s| s.max));
    if let (Some(dp_max), crate::physics::compressor_map::FlowCoordinate::InletVolumeM3S) =
        (dp_range, l.model.flow_coordinate)
    {
        let q = l
            .model
            .surge_line
            .flow_at_ratio(l.model.design_pressure_ratio);
        let t = l.model.nominal_suction_temperature_k;
        let dp = element_dp_pa(&l.model.orifice, &l.model.gas, q, p_s, t);
        if dp > dp_max {
            out.push(warn(
                machine_file_error(
                    l,
                    "flow_element",
                    format!(
                        "the surge flow at the design ratio ({q:.4} m³/s) gives Δp = {dp:.4e} Pa over the flow element, above the Δp transmitter's {dp_max:.4e} Pa: the controller cannot see the surge line"
                    ),
                )
                .with_hint("check the flow element (c_w, bore) and the Δp range (Pa)"),
            ));
        }
    }
    out
}

/// Transport rules for a machine-only config: the in-process simulation needs a plant.
pub fn transport_problem(l: &Loaded) -> Option<Problem> {
    (l.config.bus.transport == Transport::InProcess && l.plant.is_none()).then(|| Problem {
        error: locate(
            &l.layers,
            "bus.transport",
            "transport `in_process` simulates the machine in this process, which needs [plant] file: a machine file has no plant model",
        )
        .with_hint("transport = \"field\" with a signal map, or add [plant] file for a simulation"),
        warning: false,
    })
}

impl Loaded {
    /// The simulated plant (`[plant] file`), or a located error saying it is missing.
    pub fn sim_plant(&self) -> Result<&PlantCase, FileError> {
        self.plant.as_ref().ok_or_else(|| {
            locate(
                &self.layers,
                "plant",
                "simulating the skid needs [plant] file (a simulation plant); this config describes only the controller's machine",
            )
            .with_hint("add [plant]\nfile = \"plants/<name>.toml\"")
        })
    }
}

/// The machine's transmitter ranges become the inputs' plausibility limits (5 % of span beyond
/// either end: a transmitter saturates a little past its calibrated range); `[inputs.<sensor>]`
/// in the config still overrides them.
pub fn apply_transmitter_ranges(
    machine: &MachineDescription,
    core: &mut crate::control::core::CoreSettings,
) {
    for (id, r) in &machine.transmitters {
        let span = r.max - r.min;
        let slot = &mut core.supervisor.limits[id.index()];
        let timeout_s = slot.map_or(0.05, |l| l.timeout_s);
        *slot = Some(crate::control::supervisor::InputLimits {
            min: r.min - 0.05 * span,
            max: r.max + 0.05 * span,
            timeout_s,
        });
    }
}
