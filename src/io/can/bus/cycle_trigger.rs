//! `[bus.can] cycle_trigger`: which received messages start a control cycle
//! ([`crate::runtime::trigger`]).
//!
//! - `"inputs"` (the default): the messages that carry the inputs every cycle needs (suction
//!   and discharge pressure, shaft speed) that the signal map binds on CAN, of those the ones
//!   with the shortest DBC cycle time (a slower message would make most cycles wait for the
//!   deadline). The cycle runs once all of them arrived since the last run, whatever order the
//!   sender uses.
//! - `"deadline"`: no trigger, the cycle runs on its fixed deadline (before issue 9).
//! - a message name, or a list of them: the cycle runs once each of them arrived.

use serde::{Deserialize, Serialize};

use super::{BusCodec, CanBusError};
use crate::io::can::codec::SignalTarget;

/// Most trigger messages (one bit each in [`crate::runtime::trigger::CycleTrigger`]).
pub const MAX_TRIGGER_MESSAGES: usize = 32;

/// The sensors every cycle needs: their messages are the default trigger.
use crate::vocab::signals::CYCLE_INPUTS;

/// What starts a control cycle (`bus.can.cycle_trigger`).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(from = "RawTrigger", into = "RawTrigger")]
pub enum CycleTriggerSpec {
    /// The messages carrying the cycle's inputs (`"inputs"`, the default).
    #[default]
    Inputs,
    /// The fixed deadline only (`"deadline"`).
    Deadline,
    /// These messages, by DBC name.
    Messages(Vec<String>),
}

/// The TOML forms: one string or a list of strings.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(untagged)]
enum RawTrigger {
    One(String),
    Many(Vec<String>),
}

impl From<RawTrigger> for CycleTriggerSpec {
    fn from(r: RawTrigger) -> Self {
        match r {
            RawTrigger::One(s) if s == "inputs" => CycleTriggerSpec::Inputs,
            RawTrigger::One(s) if s == "deadline" => CycleTriggerSpec::Deadline,
            RawTrigger::One(s) => CycleTriggerSpec::Messages(vec![s]),
            RawTrigger::Many(v) => CycleTriggerSpec::Messages(v),
        }
    }
}

impl From<CycleTriggerSpec> for RawTrigger {
    fn from(s: CycleTriggerSpec) -> Self {
        match s {
            CycleTriggerSpec::Inputs => RawTrigger::One("inputs".into()),
            CycleTriggerSpec::Deadline => RawTrigger::One("deadline".into()),
            CycleTriggerSpec::Messages(v) => RawTrigger::Many(v),
        }
    }
}

/// The trigger resolved against the DBC and the signal map.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TriggerPlan {
    /// Per message index ([`crate::io::can::codec::MessageIndex::get`]): its bit, 0 if it is
    /// not a trigger message.
    pub bits: Vec<u32>,
    /// All the bits: the set that fires the trigger.
    pub required: u32,
    /// The trigger messages' names, in DBC order.
    pub names: Vec<String>,
}

impl TriggerPlan {
    /// For logs, events and status: `"inputs: A + B"`.
    pub fn describe(&self) -> String {
        format!("inputs: {}", self.names.join(" + "))
    }
}

impl BusCodec {
    /// Resolve `spec` for the controller: `None` for `"deadline"`, or when the default finds
    /// no cycle input bound on CAN (the loop then keeps its deadline). A name not in the DBC,
    /// or a message that carries no sensor of the signal map, is an error naming it
    /// (`key = "cycle_trigger"`).
    pub fn trigger_plan(
        &self,
        spec: &CycleTriggerSpec,
    ) -> Result<Option<TriggerPlan>, CanBusError> {
        let frames = &self.frames;
        let bad = |message: String| CanBusError::Config {
            key: "cycle_trigger",
            message,
        };
        let chosen: Vec<_> = match spec {
            CycleTriggerSpec::Deadline => return Ok(None),
            CycleTriggerSpec::Inputs => {
                let carrying: Vec<_> = frames
                    .sensor_messages()
                    .filter(|&m| {
                        frames.targets(m).iter().any(
                            |t| matches!(t, SignalTarget::Sensor(s) if CYCLE_INPUTS.contains(&s)),
                        )
                    })
                    .collect();
                // event-driven messages (no cycle time) count as the fastest
                let cycle = |m| frames.cycle_time_ms(m).unwrap_or(0);
                let Some(fastest) = carrying.iter().map(|&m| cycle(m)).min() else {
                    return Ok(None);
                };
                carrying
                    .into_iter()
                    .filter(|&m| cycle(m) == fastest)
                    .collect()
            }
            CycleTriggerSpec::Messages(names) => {
                if names.is_empty() {
                    return Err(bad(
                        "an empty list; name the messages that start a cycle, or \"inputs\" or \"deadline\"".into(),
                    ));
                }
                let mut out = Vec::with_capacity(names.len());
                for name in names {
                    let m = frames
                        .message_index(name)
                        .ok_or_else(|| bad(format!("message {name:?} is not in the DBC")))?;
                    if !frames.sensor_messages().any(|s| s == m) {
                        return Err(bad(format!(
                            "message {name:?} carries no sensor of the signal map: the controller does not read it, so it cannot start a cycle"
                        )));
                    }
                    if !out.contains(&m) {
                        out.push(m);
                    }
                }
                out.sort_unstable();
                out
            }
        };
        if chosen.len() > MAX_TRIGGER_MESSAGES {
            return Err(bad(format!(
                "{} messages; at most {MAX_TRIGGER_MESSAGES}",
                chosen.len()
            )));
        }
        let mut bits = vec![0u32; frames.len()];
        let mut required = 0u32;
        let mut names = Vec::with_capacity(chosen.len());
        for (i, m) in chosen.into_iter().enumerate() {
            let bit = 1u32 << i;
            if let Some(b) = bits.get_mut(m.get()) {
                *b = bit;
            }
            required |= bit;
            names.push(frames.message_name(m).unwrap_or("?").to_string());
        }
        Ok(Some(TriggerPlan {
            bits,
            required,
            names,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::can::codec::{skid_bindings, SignalBinding};
    use crate::vocab::signals::SensorId;
    use std::path::Path;

    fn skid(bindings: &[SignalBinding]) -> BusCodec {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/skid.dbc");
        BusCodec::load(&path, bindings).expect("skid codec")
    }

    fn parse(toml_value: &str) -> CycleTriggerSpec {
        #[derive(Deserialize)]
        struct T {
            cycle_trigger: CycleTriggerSpec,
        }
        toml::from_str::<T>(&format!("cycle_trigger = {toml_value}"))
            .expect("parses")
            .cycle_trigger
    }

    #[test]
    fn the_forms_parse() {
        assert_eq!(parse("\"inputs\""), CycleTriggerSpec::Inputs);
        assert_eq!(parse("\"deadline\""), CycleTriggerSpec::Deadline);
        assert_eq!(
            parse("\"PLANT_Pressures\""),
            CycleTriggerSpec::Messages(vec!["PLANT_Pressures".into()])
        );
        assert_eq!(
            parse("[\"A\", \"B\"]"),
            CycleTriggerSpec::Messages(vec!["A".into(), "B".into()])
        );
    }

    #[test]
    fn the_default_is_the_messages_carrying_pressures_and_speed() {
        let c = skid(&skid_bindings());
        let p = c
            .trigger_plan(&CycleTriggerSpec::Inputs)
            .expect("resolves")
            .expect("a plan");
        // PLANT_Pressures (p_suction, p_discharge) and PLANT_SpeedFlowTemp (shaft_speed), both
        // 1 ms; not PLANT_Positions (2 ms) or PLANT_Drive (10 ms), which carry no cycle input
        assert_eq!(p.names, ["PLANT_Pressures", "PLANT_SpeedFlowTemp"]);
        assert_eq!(p.required, 0b11);
        let pressures = c.frames.message_index("PLANT_Pressures").expect("in DBC");
        let speed = c
            .frames
            .message_index("PLANT_SpeedFlowTemp")
            .expect("in DBC");
        assert_eq!(p.bits[pressures.get()] | p.bits[speed.get()], 0b11);
        assert_eq!(p.bits.iter().filter(|&&b| b != 0).count(), 2);
        assert_eq!(
            p.describe(),
            "inputs: PLANT_Pressures + PLANT_SpeedFlowTemp"
        );
    }

    #[test]
    fn the_default_prefers_the_fastest_message_and_needs_a_can_input() {
        // speed and flow at 10 ms: only the 1-ms pressures trigger
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/skid.dbc");
        let text = std::fs::read_to_string(path).expect("skid.dbc");
        let slow = "BA_ \"GenMsgCycleTime\" BO_ 257 10;";
        let text = text.replace("BA_ \"GenMsgCycleTime\" BO_ 257 1;", slow);
        assert!(text.contains(slow));
        let db = crate::io::can::CanDatabase::parse(&text, "skid.dbc, 10-ms speed").expect("dbc");
        let c = BusCodec::new(&db, &skid_bindings()).expect("codec");
        let p = c.trigger_plan(&CycleTriggerSpec::Inputs).expect("ok");
        assert_eq!(p.expect("plan").names, ["PLANT_Pressures"]);
        // no cycle input on CAN (e.g. all on Modbus): the deadline
        let b: Vec<_> = skid_bindings()
            .into_iter()
            .filter(|b| {
                !matches!(
                    b.target,
                    SignalTarget::Sensor(
                        SensorId::PSuction | SensorId::PDischarge | SensorId::ShaftSpeed
                    )
                )
            })
            .collect();
        assert_eq!(
            skid(&b)
                .trigger_plan(&CycleTriggerSpec::Inputs)
                .expect("ok"),
            None
        );
    }

    #[test]
    fn named_messages_are_checked() {
        let c = skid(&skid_bindings());
        assert_eq!(
            c.trigger_plan(&CycleTriggerSpec::Deadline).expect("ok"),
            None
        );
        let one = c
            .trigger_plan(&CycleTriggerSpec::Messages(vec!["PLANT_Pressures".into()]))
            .expect("ok")
            .expect("plan");
        assert_eq!((one.names.len(), one.required), (1, 1));
        let e = c
            .trigger_plan(&CycleTriggerSpec::Messages(vec![
                "PLANT_Pressures".into(),
                "PLANT_Pressure".into(),
            ]))
            .expect_err("unknown name");
        let text = e.to_string();
        assert!(
            matches!(
                e,
                CanBusError::Config {
                    key: "cycle_trigger",
                    ..
                }
            ),
            "{text}"
        );
        assert!(
            text.contains("\"PLANT_Pressure\" is not in the DBC"),
            "{text}"
        );
        let e = c
            .trigger_plan(&CycleTriggerSpec::Messages(
                vec!["CTRL_ActuatorCmd1".into()],
            ))
            .expect_err("the controller's own message");
        assert!(e.to_string().contains("carries no sensor"), "{e}");
        assert!(c.trigger_plan(&CycleTriggerSpec::Messages(vec![])).is_err());
    }
}
