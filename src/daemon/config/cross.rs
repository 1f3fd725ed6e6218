//! The rules between sections, in one place: the selected law on this machine (seed gain
//! conditions, machine data), the observer when the flow source uses it, what the law needs
//! bound in the signal map, the signal map against the buses, the DBC, the bus load, and the
//! legal but risky combinations (warnings).

use super::layers::{locate, resolve};
use super::problem::{KeyProblem, Problem};
use super::{Loaded, Transport};
use crate::config::FileError;
use crate::control::law::api::{LawError, LawId};
use crate::control::law::Law;
use crate::control::laws::drive_torque::check_gains;
use crate::io::can::bus::{BusCodec, CanBusConfig, CanBusError};
use crate::io::can::{BindingError, SignalTarget};
use crate::io::signal_map::Binding;
use crate::vocab::signals::ActuatorId;

/// An error about a key of the signal map file, located in that file.
pub(crate) fn map_error(l: &Loaded, key: &str, message: String) -> FileError {
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
    match BusCodec::load_for(can, &dbc, &l.signal_map.can_bindings()) {
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
                // the heartbeat names of [bus.can.heartbeat] (src/io/can/heartbeat.rs)
                None if can.heartbeat.is_some() => {
                    locate(&l.layers, "bus.can.heartbeat.message", message)
                }
                None => locate(&l.layers, "bus.can.dbc", message),
            })
        }
        Err(CanBusError::FrameId(e)) => Some(locate(
            &l.layers,
            &format!("bus.can.frame_ids.{}", e.message),
            format!("{e} (DBC {})", dbc.display()),
        )),
        // e.g. not_available = "none" with an unbound signal in a sent message
        Err(CanBusError::Config { key, message }) => Some(locate(
            &l.layers,
            &format!("bus.can.{key}"),
            format!("{message} (DBC {})", dbc.display()),
        )),
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
    let db = can.database(&resolve(&l.main_path, &can.dbc)).ok()?;
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

/// A located error at `key` of the configuration with a hint (empty: none).
fn error_at(l: &Loaded, key: &str, message: String, hint: &str) -> Problem {
    KeyProblem::error(key, message).with_hint(hint).locate_in(l)
}

/// The law on this machine with these gains (applicability, seed 000 eq. 8, eq. 17, the
/// surge control line against the surge line), then the observer's gain condition when the
/// flow source uses the observer. Returns (errors about config keys, errors about the
/// machine's data).
pub fn law(l: &Loaded) -> (Vec<Problem>, Vec<Problem>) {
    let mut out = Vec::new();
    let mut machine_problems = Vec::new();
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
                if let Err(e) = check_gains(
                    &l.controller.drive_torque,
                    &l.model,
                    1.0 / l.config.cycle.rate_hz,
                ) {
                    let (key, msg, hint) = law_error(e);
                    out.push(error_at(l, &key, msg, hint));
                }
            }
        }
        Err(e) => match super::machine::machine_data_error(l, &e) {
            Some(p) => machine_problems.push(p),
            None => {
                let (key, msg, hint) = law_error(e);
                out.push(error_at(l, &key, msg, hint));
            }
        },
    }
    // the observer's gain condition only when the flow source uses the observer
    if let (true, Some(min)) = (
        super::machine::uses_observer(l),
        l.model.observer_min_gain(),
    ) {
        let c2 = l.controller.observer.c2_pa_s_kg;
        if !(c2.is_finite() && c2 > min) {
            out.push(error_at(
                l,
                "controller.observer.c2_pa_s_kg",
                format!(
                    "observer gain c2 = {c2:.4e} is below the bound of seed 000 eq. 17 ({min:.4e}): the flow estimate would not converge"
                ),
                "raise c2 above the bound (about 2× is a good start)",
            ));
        }
    }
    (out, machine_problems)
}

/// The signal map's own rules (whatever the transport), then, for the field transport, the
/// DBC and the bus load (only once the map itself is clean).
pub fn signal_map(l: &Loaded) -> Vec<Problem> {
    let c = &l.config;
    let mut map_problems = if c.bus.signal_map.is_some() {
        check_map(l)
    } else {
        Vec::new()
    };
    if c.bus.transport == Transport::Field && !l.signal_map.can_bindings().is_empty() {
        if let Some(can) = &c.bus.can {
            if can.validate().is_ok() && map_problems.is_empty() {
                map_problems.extend(check_dbc(l, can).map(Problem::error));
                map_problems.extend(check_bus_load(l, can).map(Problem::error));
            }
        }
    }
    map_problems
}

/// Field transport: exactly what the law, the flow source and the drive ownership need is
/// bound (law registry), and each bus the map uses is configured.
pub fn bindings(l: &Loaded) -> Vec<Problem> {
    let c = &l.config;
    let mut out = Vec::new();
    if c.bus.transport != Transport::Field {
        return out;
    }
    let map = &l.signal_map;
    let (actuators, sensors) = super::machine::required_bindings(l);
    for a in actuators {
        if !map.actuators.contains_key(&a) {
            let why = if a == ActuatorId::DriveTorque && !l.law.actuators().contains(a) {
                "the controller owns the drive's speed loop, which drives".to_string()
            } else {
                format!("law `{}` drives", l.law)
            };
            out.push(error_at(
                l,
                "bus.signal_map",
                format!("{why} `{}` but the signal map does not bind it", a.name()),
                &format!("add [actuators.{}] to the signal map", a.name()),
            ));
        }
    }
    for s in sensors {
        if !map.sensors.contains_key(&s) {
            out.push(error_at(
                l,
                "bus.signal_map",
                format!(
                    "law `{}` reads `{}` but the signal map does not bind it",
                    l.law,
                    s.name()
                ),
                &format!("add [sensors.{}] to the signal map", s.name()),
            ));
        }
    }
    if !map.can_bindings().is_empty() && c.bus.can.is_none() {
        out.push(error_at(
            l,
            "bus.can",
            "the signal map binds CAN signals but [bus.can] is missing".into(),
            "interface = \"can0\" and dbc = \"skid.dbc\"",
        ));
    }
    if !(map.modbus_sensors().is_empty() && map.modbus_actuators().is_empty())
        && c.bus.modbus.is_none()
    {
        out.push(error_at(
            l,
            "bus.modbus",
            "the signal map binds Modbus registers but [bus.modbus] is missing".into(),
            "see config/antisurge.toml for a [bus.modbus] example",
        ));
    }
    out
}

/// Legal but risky combinations (warnings); `so_far` are the problems already found (a
/// refused control line is not warned about again).
pub fn warnings(l: &Loaded, so_far: &[Problem]) -> Vec<Problem> {
    let mut out = Vec::new();
    if let crate::control::surge_control_line::ControlLineForm::Margin { margin_pct, .. } =
        l.controller.recycle_pi.control_line
    {
        // (a line left of the trip line is already an error about the same key)
        let refused = so_far
            .iter()
            .any(|p| p.error.key == "controller.recycle_pi.control_line");
        if matches!(l.law, LawId::RecyclePi) && margin_pct < 5.0 && !refused {
            out.push(
                KeyProblem::warning(
                    "controller.recycle_pi.control_line.margin.margin_pct",
                    format!(
                        "surge control line margin {margin_pct} % is under 5 %: little room for measurement error"
                    ),
                )
                .locate_in(l),
            );
        }
    }
    let f = l.config.control.failsafe_recycle_opening_pct;
    if f < 50.0 && l.model.has_recycle_valve() {
        out.push(Problem {
            error: locate(
                &l.layers,
                "control.failsafe_recycle_opening_pct",
                format!(
                    "fail-safe recycle opening {f} % is under 50 %: a fail-safe at low flow may not keep the machine out of surge"
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
