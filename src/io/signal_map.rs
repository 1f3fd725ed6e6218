//! The one signal map: each sensor and actuator bound either to a CAN signal of the DBC file
//! or to a Modbus register. The daemon and the plant node read the same file, so both ends of
//! a bus agree by construction.
//!
//! ```toml
//! [sensors.p_suction]
//! can = { message = "PLANT_Pressures", signal = "PSuction" }
//!
//! [sensors.orifice_dp]
//! modbus = { unit_id = 1, table = "input", address = 10, data_type = "f32" }
//!
//! [actuators.recycle_valve]
//! can = { message = "CTRL_ActuatorCmd1", signal = "RecycleValveCmd" }
//!
//! # Redundant transmitters: `a` is [sensors.orifice_dp]; b and c vote with it
//! [vote.orifice_dp]
//! b = { modbus = { unit_id = 1, table = "input", address = 12, data_type = "f32" } }
//! c = { modbus = { unit_id = 1, table = "input", address = 14, data_type = "f32" } }
//! ```

use super::can::SignalBinding;
use super::modbus::{find_overlaps, ModbusWatchdog, RegisterBinding};
use super::units::{resolve, Quantity};
use crate::vocab::signals::{ActuatorId, SensorId};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Where one signal lives.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Binding {
    /// A signal of a CAN message defined in the DBC file.
    Can {
        /// Message name in the DBC.
        message: String,
        /// Signal name in the message.
        signal: String,
    },
    /// A Modbus register.
    Modbus(RegisterBinding),
}

/// The signal map file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct SignalMap {
    /// Sensor bindings.
    #[serde(default)]
    pub sensors: BTreeMap<SensorId, Binding>,
    /// Actuator bindings.
    #[serde(default)]
    pub actuators: BTreeMap<ActuatorId, Binding>,
    /// The watchdog contract of each bus: what the controller writes so that the devices'
    /// own watchdogs see it alive.
    #[serde(default)]
    pub watchdog: WatchdogSection,
    /// Actuator feedback supervision: per actuator, the tolerance and time after which a
    /// difference between command and feedback is a fault ([`crate::io::feedback`]).
    #[serde(default)]
    pub feedback: BTreeMap<ActuatorId, super::feedback::FeedbackLimit>,
    /// Redundant transmitters: per measurement, the second (`b`) and third (`c`) binding
    /// that vote with its `[sensors]` binding (`a`), and the vote's settings
    /// (the control core's vote, its settings in [`crate::vocab::vote`]).
    #[serde(default)]
    pub vote: BTreeMap<SensorId, VoteBinding>,
}

/// `[vote.<sensor>]`: the redundant transmitters of one measurement. Transmitter `a` is the
/// sensor's `[sensors]` binding.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VoteBinding {
    /// The second transmitter.
    pub b: Binding,
    /// The third transmitter (median of three), if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub c: Option<Binding>,
    /// Deviation alarm threshold, % of the voted value (default
    /// [`DEFAULT_DEVIATION_PCT`](crate::vocab::vote::DEFAULT_DEVIATION_PCT)).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deviation_pct: Option<f64>,
    /// How long a transmitter must stay beyond the threshold before the alarm, s (default
    /// [`DEFAULT_DEVIATION_S`](crate::vocab::vote::DEFAULT_DEVIATION_S)).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deviation_s: Option<f64>,
    /// Control-line shift while the vote is degraded, % of the control-line flow (default
    /// [`DEFAULT_DEGRADED_MARGIN_PCT`](crate::vocab::vote::DEFAULT_DEGRADED_MARGIN_PCT)).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub degraded_margin_pct: Option<f64>,
}

impl VoteBinding {
    /// The spare bindings with their slot (1 = `b`, 2 = `c`).
    pub fn spares(&self) -> impl Iterator<Item = (usize, &Binding)> {
        std::iter::once((1, &self.b)).chain(self.c.as_ref().map(|c| (2, c)))
    }

    /// The vote's settings in the core's units.
    pub fn limits(&self) -> crate::vocab::vote::VoteLimits {
        use crate::vocab::vote::VoteLimits;
        let d = VoteLimits::defaults(if self.c.is_some() { 3 } else { 2 });
        VoteLimits {
            transmitters: d.transmitters,
            deviation: self.deviation_pct.map_or(d.deviation, |p| 0.01 * p),
            deviation_s: self.deviation_s.unwrap_or(d.deviation_s),
            degraded_margin: self
                .degraded_margin_pct
                .map_or(d.degraded_margin, |p| 0.01 * p),
        }
    }
}

/// `[watchdog]` of the signal map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct WatchdogSection {
    /// Modbus: registers for alive counter, toggle, mode, law, faults.
    #[serde(default)]
    pub modbus: Option<ModbusWatchdog>,
}

/// Fold a declared unit into a register binding's scale and offset (SI out). A unit that
/// does not resolve is left alone: [`SignalMap::check`] reports it.
fn to_si(mut r: RegisterBinding, q: Quantity) -> RegisterBinding {
    if let Some(u) = r.unit {
        if let Ok(u) = resolve(u, q) {
            r.offset = r.offset * u.factor + u.offset;
            r.scale *= u.factor;
            r.unit = None;
        }
    }
    r
}

/// One input the field links carry: a transmitter of a measurement and the link it comes
/// in on. The status and the HMI name the link of each input from this table, so that a link
/// that is down marks only the inputs it carries (the root-cause rule: a link failure is the
/// link's, never a sensor's, and an unbound sensor shows nowhere).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct InputLink {
    /// The measurement.
    pub input: SensorId,
    /// The transmitter: `a` (`[sensors.<input>]`), `b` or `c` (`[vote.<input>]`).
    pub transmitter: String,
    /// The link that carries it, as the link lamps name it (`can:<interface>`,
    /// `modbus:<address>`); `None`: no field link (the embedded plant).
    pub link: Option<String>,
}

/// A problem in a signal map.
#[derive(Debug, Clone, PartialEq)]
pub struct MapProblem {
    /// Key path (`sensors.p_suction.modbus`).
    pub key: String,
    /// What is wrong.
    pub message: String,
    /// Legal but suspicious (printed, accepted).
    pub warning: bool,
}

impl SignalMap {
    /// CAN bindings, for the codec.
    pub fn can_bindings(&self) -> Vec<SignalBinding> {
        let mut out = Vec::new();
        for (id, b) in &self.sensors {
            if let Binding::Can { message, signal } = b {
                out.push(SignalBinding::sensor(*id, message, signal));
            }
        }
        for (id, b) in &self.actuators {
            if let Binding::Can { message, signal } = b {
                out.push(SignalBinding::actuator(*id, message, signal));
            }
        }
        out
    }

    /// Modbus sensor bindings, with their declared unit converted to SI.
    pub fn modbus_sensors(&self) -> Vec<(SensorId, RegisterBinding)> {
        self.sensors
            .iter()
            .filter_map(|(id, b)| match b {
                Binding::Modbus(r) => Some((*id, to_si(*r, Quantity::of_sensor(*id)))),
                Binding::Can { .. } => None,
            })
            .collect()
    }

    /// Modbus bindings of the redundant transmitters `b` and `c` (slot 1 and 2), with their
    /// declared unit converted to SI.
    pub fn modbus_spares(&self) -> Vec<(SensorId, usize, RegisterBinding)> {
        let mut out = Vec::new();
        for (id, v) in &self.vote {
            for (slot, b) in v.spares() {
                if let Binding::Modbus(r) = b {
                    out.push((*id, slot, to_si(*r, Quantity::of_sensor(*id))));
                }
            }
        }
        out
    }

    /// The core's vote settings from `[vote]` (a vote whose measurement `[sensors]` does
    /// not bind is refused by [`check`](Self::check)).
    pub fn vote_settings(&self) -> crate::vocab::vote::VoteSettings {
        let mut s = crate::vocab::vote::VoteSettings::default();
        for (id, v) in &self.vote {
            if self.sensors.contains_key(id) && crate::vocab::vote::Conservative::of(*id).is_some()
            {
                s.per_sensor[id.index()] = Some(v.limits());
            }
        }
        s
    }

    /// Modbus actuator bindings, with their declared unit converted to SI.
    pub fn modbus_actuators(&self) -> Vec<(ActuatorId, RegisterBinding)> {
        self.actuators
            .iter()
            .filter_map(|(id, b)| match b {
                Binding::Modbus(r) => Some((*id, to_si(*r, Quantity::of_actuator(*id)))),
                Binding::Can { .. } => None,
            })
            .collect()
    }

    /// The input→link table (see [`InputLink`]): every bound transmitter, `a` first and
    /// then the `[vote]` spares, in sensor order, named by the link of its binding's bus
    /// (`can` / `modbus`: the names the link lamps use). Built once at start (the links and
    /// the map need a restart to change), never on the control thread.
    pub fn input_links(&self, can: &str, modbus: &str) -> Vec<InputLink> {
        let link = |b: &Binding| match b {
            Binding::Can { .. } => can.to_string(),
            Binding::Modbus(_) => modbus.to_string(),
        };
        let mut out = Vec::new();
        for (id, b) in &self.sensors {
            out.push(InputLink {
                input: *id,
                transmitter: "a".into(),
                link: Some(link(b)),
            });
            for (slot, spare) in self.vote.get(id).into_iter().flat_map(VoteBinding::spares) {
                out.push(InputLink {
                    input: *id,
                    transmitter: crate::vocab::vote::TRANSMITTER_NAMES[slot].into(),
                    link: Some(link(spare)),
                });
            }
        }
        out
    }

    /// Whether any signal uses CAN.
    pub fn uses_can(&self) -> bool {
        self.sensors
            .values()
            .chain(self.actuators.values())
            .chain(self.vote.values().flat_map(|v| v.spares().map(|(_, b)| b)))
            .any(|b| matches!(b, Binding::Can { .. }))
    }

    /// Whether any signal uses Modbus (or a Modbus watchdog is configured).
    pub fn uses_modbus(&self) -> bool {
        self.watchdog.modbus.is_some()
            || self
                .sensors
                .values()
                .chain(self.actuators.values())
                .any(|b| matches!(b, Binding::Modbus(_)))
    }

    /// The Modbus watchdog parts as keyed bindings.
    pub fn modbus_watchdog(&self) -> Vec<(String, RegisterBinding)> {
        self.watchdog
            .modbus
            .iter()
            .flat_map(|w| w.parts())
            .map(|(p, b)| (format!("watchdog.modbus.{}", p.key()), b))
            .collect()
    }

    /// Checks that do not need the DBC: Modbus registers must not overlap, and register
    /// bindings must be valid (actuators in holding registers).
    pub fn check(&self) -> Vec<MapProblem> {
        let mut problems = Vec::new();
        let mut keyed: Vec<(String, RegisterBinding)> = Vec::new();
        let unit_check = |problems: &mut Vec<MapProblem>, key: &str, r: &RegisterBinding, q| {
            if let Some(u) = r.unit {
                if let Err(e) = resolve(u, q) {
                    problems.push(MapProblem {
                        key: format!("{key}.unit"),
                        message: e.to_string(),
                        warning: false,
                    });
                }
            }
        };
        for (id, b) in &self.sensors {
            if let Binding::Modbus(r) = b {
                let key = format!("sensors.{}.modbus", id.name());
                unit_check(&mut problems, &key, r, Quantity::of_sensor(*id));
                if r.table.is_bits() && !id.is_contact() {
                    problems.push(MapProblem {
                        key: key.clone(),
                        message: format!(
                            "{} is a measured value in {}; a {} carries one bit",
                            id.name(),
                            id.unit(),
                            r.table.name()
                        ),
                        warning: false,
                    });
                }
                keyed.push((key, *r));
            }
        }
        for (id, v) in &self.vote {
            let key = format!("vote.{}", id.name());
            if crate::vocab::vote::Conservative::of(*id).is_none() {
                problems.push(MapProblem {
                    key: key.clone(),
                    message: format!(
                        "{} takes no vote: redundant transmitters are voted for orifice_dp, p_suction, p_discharge and t_suction, whose side of less surge margin is defined",
                        id.name()
                    ),
                    warning: false,
                });
            }
            if !self.sensors.contains_key(id) {
                problems.push(MapProblem {
                    key: key.clone(),
                    message: format!(
                        "{} is not bound in [sensors]: its binding there is transmitter a of the vote",
                        id.name()
                    ),
                    warning: false,
                });
            }
            let pct_ok = |x: Option<f64>, lo: f64, hi: f64| {
                x.is_none_or(|x| x.is_finite() && x > lo && x <= hi)
            };
            for (name, x, lo, hi, what) in [
                (
                    "deviation_pct",
                    v.deviation_pct,
                    0.0,
                    100.0,
                    "a percentage of the vote in (0, 100]",
                ),
                (
                    "deviation_s",
                    v.deviation_s,
                    0.0,
                    60.0,
                    "seconds in (0, 60]",
                ),
                (
                    "degraded_margin_pct",
                    v.degraded_margin_pct,
                    -1e-300,
                    50.0,
                    "a percentage of the control-line flow in [0, 50]",
                ),
            ] {
                if !pct_ok(x, lo, hi) {
                    problems.push(MapProblem {
                        key: format!("{key}.{name}"),
                        message: format!("must be {what}, got {}", x.unwrap_or(f64::NAN)),
                        warning: false,
                    });
                }
            }
            for (slot, b) in v.spares() {
                let name = crate::vocab::vote::TRANSMITTER_NAMES[slot];
                match b {
                    Binding::Modbus(r) => {
                        let k = format!("{key}.{name}.modbus");
                        unit_check(&mut problems, &k, r, Quantity::of_sensor(*id));
                        if r.table.is_bits() {
                            problems.push(MapProblem {
                                key: k.clone(),
                                message: format!(
                                    "{} is a measured value in {}; a {} carries one bit",
                                    id.name(),
                                    id.unit(),
                                    r.table.name()
                                ),
                                warning: false,
                            });
                        }
                        keyed.push((k, *r));
                    }
                    Binding::Can { .. } => problems.push(MapProblem {
                        key: format!("{key}.{name}.can"),
                        message: "redundant transmitters are read over Modbus; a CAN binding of a second or third transmitter is not supported yet".into(),
                        warning: false,
                    }),
                }
            }
        }
        for (id, b) in &self.actuators {
            let Binding::Modbus(r) = b else { continue };
            let key = format!("actuators.{}.modbus", id.name());
            unit_check(&mut problems, &key, r, Quantity::of_actuator(*id));
            if r.table != super::modbus::RegisterTable::Holding {
                problems.push(MapProblem {
                    key: key.clone(),
                    message: format!(
                        "an actuator must be a holding register ({} in {}; input registers and discrete inputs are read-only, a coil carries one bit)",
                        id.name(),
                        id.unit()
                    ),
                    warning: false,
                });
            }
            keyed.push((key, *r));
        }
        if let Some(wd) = &self.watchdog.modbus {
            for (key, message) in wd.problems() {
                problems.push(MapProblem {
                    key,
                    message,
                    warning: false,
                });
            }
            keyed.extend(self.modbus_watchdog());
        }
        for (key, r) in &keyed {
            if let Err(e) = r.validate() {
                problems.push(MapProblem {
                    key: key.clone(),
                    message: e.to_string(),
                    warning: false,
                });
            }
            if r.address_looks_modicon {
                problems.push(MapProblem {
                    key: format!("{key}.address"),
                    message: format!(
                        "protocol address {} looks like a Modicon register number; if the manual says {}, write `register = {}` instead of `table` and `address`",
                        r.address, r.address, r.address
                    ),
                    warning: true,
                });
            }
        }
        for (a, l) in &self.feedback {
            let key = format!("feedback.{}", a.name());
            if l.readback
                && !matches!(self.actuators.get(a), Some(Binding::Modbus(r)) if r.table == super::modbus::RegisterTable::Holding)
            {
                problems.push(MapProblem {
                    key: format!("{key}.readback"),
                    message: format!(
                        "readback needs {} bound to a Modbus holding register (the controller reads its own command back with function 3)",
                        a.name()
                    ),
                    warning: false,
                });
            }
            match super::feedback::feedback_sensor(*a) {
                None => problems.push(MapProblem {
                    key: key.clone(),
                    message: format!("{} has no feedback sensor to compare with", a.name()),
                    warning: false,
                }),
                Some(s) if !self.sensors.contains_key(&s) => problems.push(MapProblem {
                    key: key.clone(),
                    message: format!(
                        "the feedback sensor {} of {} is not bound in [sensors]",
                        s.name(),
                        a.name()
                    ),
                    warning: false,
                }),
                Some(_) => {}
            }
            if !(l.tolerance.is_finite()
                && l.tolerance > 0.0
                && l.time_ms.is_finite()
                && l.time_ms >= 0.0)
            {
                problems.push(MapProblem {
                    key,
                    message: format!(
                        "tolerance must be > 0 and time_ms ≥ 0, got {} and {}",
                        l.tolerance, l.time_ms
                    ),
                    warning: false,
                });
            }
        }
        let regs: Vec<RegisterBinding> = keyed.iter().map(|(_, r)| *r).collect();
        for o in find_overlaps(&regs) {
            problems.push(MapProblem {
                key: keyed[o.second].0.clone(),
                message: format!(
                    "register range overlaps `{}` (unit {}, {:?} register {})",
                    keyed[o.first].0,
                    regs[o.first].unit_id,
                    regs[o.first].table,
                    regs[o.first].address
                ),
                warning: false,
            });
        }
        problems
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::modbus::RegisterTable;

    impl RegisterBinding {
        fn encode_words(&self, v: f64) -> [u16; 2] {
            let mut w = [0u16; 2];
            let _ = self.encode(v, &mut w).unwrap();
            w
        }
    }

    fn parse(t: &str) -> SignalMap {
        crate::config::toml_file::parse(t, std::path::Path::new("signals.toml")).expect("parse")
    }

    #[test]
    fn parses_both_kinds_and_splits_them() {
        let m = parse(
            "[sensors.p_suction]\ncan = { message = \"PLANT_Pressures\", signal = \"PSuction\" }\n\
             [sensors.orifice_dp]\nmodbus = { unit_id = 1, table = \"input\", address = 10, data_type = \"f32\" }\n\
             [actuators.recycle_valve]\ncan = { message = \"CTRL_ActuatorCmd1\", signal = \"RecycleValveCmd\" }\n",
        );
        assert_eq!(m.can_bindings().len(), 2);
        assert_eq!(m.modbus_sensors().len(), 1);
        assert!(m.uses_can() && m.uses_modbus());
        assert!(m.check().is_empty());
    }

    #[test]
    fn each_bound_transmitter_is_named_by_the_link_of_its_bus_and_an_unbound_sensor_by_none() {
        // CAN and Modbus on one skid, a Δp vote across both buses
        let m = parse(
            "[sensors.p_suction]\ncan = { message = \"PLANT_Pressures\", signal = \"PSuction\" }\n\
             [sensors.p_discharge]\ncan = { message = \"PLANT_Pressures\", signal = \"PDischarge\" }\n\
             [sensors.orifice_dp]\nmodbus = { unit_id = 1, table = \"input\", address = 10, data_type = \"f32\" }\n\
             [vote.orifice_dp]\nb = { can = { message = \"PLANT_Flow\", signal = \"OrificeDpB\" } }\n\
             c = { modbus = { unit_id = 1, table = \"input\", address = 14, data_type = \"f32\" } }\n",
        );
        let t = m.input_links("can:can0", "modbus:10.0.0.5:502");
        let rows: Vec<(&str, &str, Option<&str>)> = t
            .iter()
            .map(|l| (l.input.name(), l.transmitter.as_str(), l.link.as_deref()))
            .collect();
        assert_eq!(
            rows,
            [
                ("p_suction", "a", Some("can:can0")),
                ("p_discharge", "a", Some("can:can0")),
                ("orifice_dp", "a", Some("modbus:10.0.0.5:502")),
                ("orifice_dp", "b", Some("can:can0")),
                ("orifice_dp", "c", Some("modbus:10.0.0.5:502")),
            ]
        );
        // an unbound sensor is in no row: it shows nowhere
        for unbound in [SensorId::ShaftSpeed, SensorId::TSuction] {
            assert!(t.iter().all(|l| l.input != unbound), "{unbound:?} in {t:?}");
        }
        let json = serde_json::to_value(&t[3]).expect("json");
        assert_eq!(
            json,
            serde_json::json!({"input": "orifice_dp", "transmitter": "b", "link": "can:can0"})
        );
    }

    #[test]
    fn readback_needs_a_modbus_holding_register() {
        let can = parse(
            "[sensors.recycle_valve_position]\ncan = { message = \"PLANT_Valves\", signal = \"RecycleValvePos\" }\n\
             [actuators.recycle_valve]\ncan = { message = \"CTRL_ActuatorCmd1\", signal = \"RecycleValveCmd\" }\n\
             [feedback]\nrecycle_valve = { tolerance = 0.05, time_ms = 100, readback = true }\n",
        );
        let p = can.check();
        assert!(
            p.iter().any(|x| x.key == "feedback.recycle_valve.readback"
                && x.message.contains("holding register")),
            "{p:?}"
        );
        let modbus = parse(
            "[sensors.recycle_valve_position]\nmodbus = { unit_id = 1, table = \"input\", address = 9, data_type = \"u16\", scale = 1e-4 }\n\
             [actuators.recycle_valve]\nmodbus = { unit_id = 1, table = \"holding\", address = 102, data_type = \"u16\", scale = 1e-4 }\n\
             [feedback]\nrecycle_valve = { tolerance = 0.05, time_ms = 100, readback = true }\n",
        );
        assert!(modbus.check().is_empty(), "{:?}", modbus.check());
        assert!(modbus.feedback[&ActuatorId::RecycleValve].readback);
    }

    #[test]
    fn votes_bind_b_and_c_beside_a_and_are_checked() {
        let m = parse(
            "[sensors.orifice_dp]\nmodbus = { unit_id = 1, table = \"input\", address = 10, data_type = \"f32\" }\n\
             [vote.orifice_dp]\nb = { modbus = { unit_id = 1, table = \"input\", address = 12, data_type = \"f32\", unit = \"kPa\" } }\n\
             c = { modbus = { unit_id = 1, table = \"input\", address = 14, data_type = \"f32\" } }\ndeviation_pct = 3.0\n",
        );
        assert!(m.check().is_empty(), "{:?}", m.check());
        let spares = m.modbus_spares();
        assert_eq!(spares.len(), 2);
        // b in kPa: 2 kPa reads 2000 Pa
        let (_, slot, b) = spares[0];
        assert_eq!(slot, 1);
        let mut w = [0u16; 2];
        let _ = b.encode(2000.0, &mut w).unwrap();
        assert!((b.decode(&w).unwrap() - 2000.0).abs() < 1e-6);
        let v = m.vote_settings().per_sensor[SensorId::OrificeDp.index()].expect("voted");
        assert_eq!((v.transmitters, v.deviation, v.deviation_s), (3, 0.03, 0.5));
        // a vote without a, on a measurement without a vote, overlapping a, on CAN
        let bad = parse(
            "[sensors.orifice_dp]\nmodbus = { unit_id = 1, table = \"input\", address = 10, data_type = \"f32\" }\n\
             [vote.p_suction]\nb = { modbus = { unit_id = 1, table = \"input\", address = 20, data_type = \"f32\" } }\n\
             [vote.shaft_speed]\nb = { modbus = { unit_id = 1, table = \"input\", address = 22, data_type = \"f32\" } }\n\
             [vote.orifice_dp]\nb = { modbus = { unit_id = 1, table = \"input\", address = 11, data_type = \"f32\" } }\n\
             c = { can = { message = \"M\", signal = \"S\" } }\ndeviation_s = 0\n",
        );
        let p = bad.check();
        let has =
            |key: &str, text: &str| p.iter().any(|x| x.key == key && x.message.contains(text));
        assert!(has("vote.p_suction", "not bound in [sensors]"), "{p:?}");
        assert!(has("vote.shaft_speed", "takes no vote"), "{p:?}");
        assert!(has("vote.orifice_dp.b.modbus", "overlaps"), "{p:?}");
        assert!(has("vote.orifice_dp.c.can", "Modbus"), "{p:?}");
        assert!(has("vote.orifice_dp.deviation_s", "seconds"), "{p:?}");
    }

    #[test]
    fn overlapping_registers_and_readonly_actuators_are_reported() {
        let m = parse(
            "[sensors.p_suction]\nmodbus = { unit_id = 1, table = \"holding\", address = 10, data_type = \"f32\" }\n\
             [actuators.recycle_valve]\nmodbus = { unit_id = 1, table = \"holding\", address = 11, data_type = \"u16\" }\n\
             [actuators.throttle]\nmodbus = { unit_id = 1, table = \"input\", address = 30, data_type = \"u16\" }\n",
        );
        let p = m.check();
        assert!(p.iter().any(|x| x.message.contains("overlaps")), "{p:?}");
        assert!(
            p.iter()
                .any(|x| x.key == "actuators.throttle.modbus" && x.message.contains("holding")),
            "{p:?}"
        );
    }

    #[test]
    fn units_modicon_numbers_and_their_warning() {
        let m = parse(
            "[sensors.recycle_valve_position]\nmodbus = { unit_id = 1, register = 30010, data_type = \"u16\", scale = 0.01, unit = \"%\" }\n\
             [sensors.p_suction]\nmodbus = { unit_id = 1, table = \"input\", address = 30001, data_type = \"f32\", word_order = \"little\", unit = \"kPa\" }\n",
        );
        let s = m.modbus_sensors();
        let (_, valve) = s[1];
        assert_eq!((valve.table, valve.address), (RegisterTable::Input, 9));
        // 5000 counts × 0.01 = 50 % = 0.5
        assert!((valve.decode(&[5000]).unwrap() - 0.5).abs() < 1e-12);
        let (_, p) = s[0];
        let mut w = [0u16; 2];
        let _ = p.encode(101_325.0, &mut w).unwrap();
        assert_eq!(
            w,
            crate::io::modbus::RegisterBinding::new(
                1,
                RegisterTable::Input,
                0,
                crate::io::modbus::DataType::F32
            )
            .with_order(
                crate::io::modbus::ByteOrder::Big,
                crate::io::modbus::WordOrder::Little
            )
            .encode_words(101.325)
        );
        let problems = m.check();
        assert_eq!(problems.len(), 1, "{problems:?}");
        assert!(problems[0].warning);
        assert_eq!(problems[0].key, "sensors.p_suction.modbus.address");
        assert!(
            problems[0].message.contains("register = 30001"),
            "{problems:?}"
        );
    }

    #[test]
    fn unknown_sensor_name_is_rejected() {
        let e = crate::config::toml_file::parse::<SignalMap>(
            "[sensors.p_sucton]\ncan = { message = \"a\", signal = \"b\" }\n",
            std::path::Path::new("s.toml"),
        )
        .unwrap_err();
        assert!(e.message.contains("p_sucton"), "{e}");
    }
}
