//! Why something happened: the cause carried by a mode change, a fallback, a trip and the
//! live status, in words an operator understands ("p_discharge out of range: 2.1e7 Pa,
//! plausible 1e4…1.2e7 Pa").
//!
//! A [`Cause`] is fixed-size and `Copy` (the control thread builds it without allocating).
//! Its fault vocabulary is the event log's [`FallbackReason`]; [`Cause::category`] maps it onto
//! the fault categories of the heartbeat's `Faults` bitfield (config/skid.dbc), so the I/O
//! layer's fault vocabulary and this one name the same things.

use serde::{Deserialize, Serialize};

use super::event::FallbackReason;
use crate::control::supervisor::{InputFault, Supervisor, Validity};
use crate::vocab::faults::FieldLinkKind;
use crate::vocab::signals::SensorId;

/// What kind of cause.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CauseKind {
    /// An input the controller needs failed supervision (`input`, `fault`, `value`).
    InputFault,
    /// The law needs a flow and neither the flow element nor the observer gives one
    /// (`input` = orifice_dp with its fault).
    FlowUnavailable,
    /// Every needed input is healthy again (leaving fail-safe or start-up).
    InputsHealthy,
    /// The operator (HMI, status socket) or the configuration asked for it.
    Operator,
    /// The surge margin crossed the trip line or approached it too fast (`value` = margin %,
    /// `min` = trip line %).
    SurgeMargin,
    /// The controller is stopping.
    Shutdown,
    /// The emergency-shutdown / drive-trip input is set (`input` = esd_input, `value` = 1):
    /// the recycle valve opens fully at once.
    EsdInput,
    /// A field link is down (`link`): the root cause of the inputs it carries going stale
    /// (`input` = the first needed one, with its fault and age).
    LinkDown,
}

impl CauseKind {
    /// Numeric code (live snapshot, Modbus block).
    pub const fn code(self) -> u8 {
        match self {
            CauseKind::InputFault => 1,
            CauseKind::FlowUnavailable => 2,
            CauseKind::InputsHealthy => 3,
            CauseKind::Operator => 4,
            CauseKind::SurgeMargin => 5,
            CauseKind::Shutdown => 6,
            CauseKind::EsdInput => 7,
            CauseKind::LinkDown => 8,
        }
    }

    /// Inverse of [`CauseKind::code`].
    pub const fn from_code(c: u8) -> Option<CauseKind> {
        Some(match c {
            1 => CauseKind::InputFault,
            2 => CauseKind::FlowUnavailable,
            3 => CauseKind::InputsHealthy,
            4 => CauseKind::Operator,
            5 => CauseKind::SurgeMargin,
            6 => CauseKind::Shutdown,
            7 => CauseKind::EsdInput,
            8 => CauseKind::LinkDown,
            _ => return None,
        })
    }
}

/// Why a transition happened. Values are SI in the input's unit ([`SensorId::unit`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Cause {
    /// What kind of cause.
    pub kind: CauseKind,
    /// The input concerned, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub input: Option<SensorId>,
    /// Its fault, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fault: Option<FallbackReason>,
    /// The offending value (SI; for `surge_margin`, %). Absent when there was none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub value: Option<f64>,
    /// Lower plausible limit (for `surge_margin`: the trip line, %).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min: Option<f64>,
    /// Upper plausible limit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max: Option<f64>,
    /// Age of the value, ms (absent: never received).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub age_ms: Option<f64>,
    /// Freshness timeout of the input, ms.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timeout_ms: Option<f64>,
    /// The field link concerned ([`CauseKind::LinkDown`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub link: Option<FieldLinkKind>,
}

fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

impl Cause {
    /// A cause with only its kind.
    pub const fn of(kind: CauseKind) -> Cause {
        Cause {
            kind,
            input: None,
            fault: None,
            value: None,
            min: None,
            max: None,
            age_ms: None,
            timeout_ms: None,
            link: None,
        }
    }

    /// The supervision fault of one input, with its value, age and limits.
    pub fn input(
        kind: CauseKind,
        id: SensorId,
        fault: InputFault,
        value: f64,
        age_s: f64,
        sup: &Supervisor,
    ) -> Cause {
        let lim = sup.limits[id.index()];
        Cause {
            kind,
            input: Some(id),
            fault: fallback_reason(fault),
            value: finite(value),
            min: lim.map(|l| l.min),
            max: lim.map(|l| l.max),
            age_ms: finite(age_s * 1e3),
            timeout_ms: lim.map(|l| l.timeout_s * 1e3),
            link: None,
        }
    }

    /// Why the controller cannot run its law: the first needed input that failed (pressures,
    /// speed), else the flow element when the law needs a flow. `None` if every needed input
    /// is usable.
    pub fn of_unusable_inputs(
        validity: &Validity,
        values: &[f64; SensorId::COUNT],
        age_s: &[f64; SensorId::COUNT],
        sup: &Supervisor,
        needs_flow: bool,
    ) -> Option<Cause> {
        let essentials = [
            SensorId::PSuction,
            SensorId::PDischarge,
            SensorId::ShaftSpeed,
        ];
        let pick = |kind, id: SensorId| {
            let i = id.index();
            Cause::input(kind, id, validity.fault[i], values[i], age_s[i], sup)
        };
        // (an input the supervisor does not use, e.g. a speed the skid does not bind, is
        // never the cause)
        if let Some(id) = essentials
            .into_iter()
            .find(|id| sup.limits[id.index()].is_some() && !validity.ok(*id))
        {
            return Some(pick(CauseKind::InputFault, id));
        }
        if needs_flow {
            return Some(pick(CauseKind::FlowUnavailable, SensorId::OrificeDp));
        }
        None
    }

    /// The root cause of an input fault when a field link is down: the link, carrying the
    /// input as its detail. Other causes, and faults a link cannot cause (out of range, NaN
    /// from a live device), are returned as they are.
    pub fn rooted_in_link(self, down: Option<FieldLinkKind>) -> Cause {
        match (self.kind, self.fault, down) {
            (
                CauseKind::InputFault | CauseKind::FlowUnavailable,
                Some(FallbackReason::Stale) | Some(FallbackReason::Nan) | None,
                Some(link),
            ) => Cause {
                kind: CauseKind::LinkDown,
                link: Some(link),
                ..self
            },
            _ => self,
        }
    }

    /// The fault category of the heartbeat's `Faults` bitfield (config/skid.dbc) this cause
    /// falls under, if any: `sensor_timeout`, `sensor_alive_error`, `sensor_implausible`.
    pub fn category(&self) -> Option<&'static str> {
        if self.kind == CauseKind::LinkDown {
            return Some("field_link_down");
        }
        match self.fault? {
            FallbackReason::Stale | FallbackReason::BusOff => Some("sensor_timeout"),
            FallbackReason::AliveCounter => Some("sensor_alive_error"),
            FallbackReason::Nan
            | FallbackReason::OutOfRange
            | FallbackReason::Frozen
            | FallbackReason::Drift => Some("sensor_implausible"),
        }
    }

    /// One line for the operator, e.g. `p_discharge out of range: 2.1e7 Pa (plausible 1e4 …
    /// 1.2e7 Pa)`.
    pub fn describe(&self) -> String {
        let unit = self.input.map(|i| i.unit()).unwrap_or("");
        let name = self.input.map(|i| i.name()).unwrap_or("input");
        let fault = match self.fault {
            Some(FallbackReason::Stale) => match (self.age_ms, self.timeout_ms) {
                (Some(a), Some(t)) => {
                    format!("stale: last value {a:.0} ms old (timeout {t:.0} ms)")
                }
                (None, _) => "no value received".to_string(),
                (Some(a), None) => format!("stale: last value {a:.0} ms old"),
            },
            Some(FallbackReason::OutOfRange) => format!(
                "out of range: {} {unit} (plausible {} … {} {unit})",
                num(self.value),
                num(self.min),
                num(self.max)
            ),
            Some(FallbackReason::Nan) => "not a number (no valid value)".to_string(),
            Some(FallbackReason::AliveCounter) => "alive counter stopped or jumped".to_string(),
            Some(FallbackReason::BusOff) => "bus off".to_string(),
            Some(FallbackReason::Frozen) => {
                "frozen: no change while the pressures moved (cross-check)".to_string()
            }
            Some(FallbackReason::Drift) => {
                "drifting or biased: disagrees with the observer's and the speed-line flow (cross-check)"
                    .to_string()
            }
            None => "healthy".to_string(),
        };
        match self.kind {
            CauseKind::InputFault => format!("{name} {fault}"),
            CauseKind::FlowUnavailable => {
                format!("no flow for the law: {name} {fault} and no observer estimate")
            }
            CauseKind::InputsHealthy => "inputs healthy".to_string(),
            CauseKind::Operator => "operator request".to_string(),
            CauseKind::SurgeMargin => format!(
                "surge margin {} % approaching the trip line {} %",
                num(self.value),
                num(self.min)
            ),
            CauseKind::Shutdown => "controller stopping".to_string(),
            CauseKind::EsdInput => {
                format!("emergency shutdown / drive trip: {name} set, recycle valve fully open")
            }
            CauseKind::LinkDown => format!(
                "{} link down: the inputs it carries are stale ({name} {fault})",
                self.link.map_or("field", |l| l.name())
            ),
        }
    }
}

/// The event-log reason of a supervision fault (None: the input is usable). The one mapping
/// from the control core's [`InputFault`] to the words of the event log.
pub fn fallback_reason(fault: InputFault) -> Option<FallbackReason> {
    match fault {
        InputFault::None => None,
        InputFault::Nan => Some(FallbackReason::Nan),
        InputFault::OutOfRange => Some(FallbackReason::OutOfRange),
        InputFault::Stale => Some(FallbackReason::Stale),
        InputFault::Frozen => Some(FallbackReason::Frozen),
        InputFault::Drift => Some(FallbackReason::Drift),
    }
}

fn num(x: Option<f64>) -> String {
    match x {
        Some(v) if v != 0.0 && (v.abs() >= 1e5 || v.abs() < 1e-2) => format!("{v:.3e}"),
        Some(v) => format!("{v:.4}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_string(),
        None => "?".to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::measurements::RawSensors;
    use crate::control::supervisor::InputLimits;
    use crate::vocab::signals::SensorSnapshot;

    #[test]
    fn a_frozen_dp_is_named_with_its_check() {
        let r = fallback_reason(InputFault::Frozen);
        assert_eq!(r, Some(FallbackReason::Frozen));
        let c = Cause::input(
            CauseKind::InputFault,
            SensorId::OrificeDp,
            InputFault::Frozen,
            1.2e4,
            0.0,
            &sup(),
        );
        assert_eq!(
            c.describe(),
            "orifice_dp frozen: no change while the pressures moved (cross-check)"
        );
        assert_eq!(c.category(), Some("sensor_implausible"));
        assert_eq!(fallback_reason(InputFault::None), None);
    }

    #[test]
    fn a_link_down_is_the_root_and_an_unbound_sensor_is_never_the_cause() {
        let mut sup = sup();
        // a recycle skid whose drive keeps its own speed: no speed transmitter bound
        sup.limits[SensorId::ShaftSpeed.index()] = None;
        let mut fault = [InputFault::None; SensorId::COUNT];
        fault[SensorId::ShaftSpeed.index()] = InputFault::Nan;
        fault[SensorId::PSuction.index()] = InputFault::Stale;
        let v = Validity { fault };
        let values = [f64::NAN; SensorId::COUNT];
        let mut age = [0.0; SensorId::COUNT];
        age[SensorId::PSuction.index()] = 0.3;
        let c = Cause::of_unusable_inputs(&v, &values, &age, &sup, false).expect("a cause");
        assert_eq!(
            c.input,
            Some(SensorId::PSuction),
            "not the unbound speed: {c:?}"
        );
        assert_eq!(
            c.rooted_in_link(None),
            c,
            "no link down: the input is the cause"
        );
        let rooted = c.rooted_in_link(Some(FieldLinkKind::Modbus));
        assert_eq!(rooted.kind, CauseKind::LinkDown);
        assert_eq!(rooted.category(), Some("field_link_down"));
        assert!(
            rooted
                .describe()
                .starts_with("Modbus link down: the inputs it carries are stale (p_suction stale"),
            "{}",
            rooted.describe()
        );
        assert_eq!(
            CauseKind::from_code(CauseKind::LinkDown.code()),
            Some(CauseKind::LinkDown)
        );
        // a value out of range comes from a live device: no link is its root
        let mut fault = [InputFault::None; SensorId::COUNT];
        fault[SensorId::PDischarge.index()] = InputFault::OutOfRange;
        let c = Cause::of_unusable_inputs(&Validity { fault }, &values, &age, &sup, false).unwrap();
        assert_eq!(
            c.rooted_in_link(Some(FieldLinkKind::Can)).kind,
            CauseKind::InputFault
        );
    }

    fn sup() -> Supervisor {
        let mut limits = [None; SensorId::COUNT];
        for id in [
            SensorId::PSuction,
            SensorId::PDischarge,
            SensorId::ShaftSpeed,
            SensorId::OrificeDp,
        ] {
            limits[id.index()] = Some(InputLimits {
                min: 1e4,
                max: 1.2e6,
                timeout_s: 0.05,
            });
        }
        Supervisor { limits }
    }

    fn healthy() -> RawSensors {
        let mut v = SensorSnapshot::default();
        for id in [
            SensorId::PSuction,
            SensorId::PDischarge,
            SensorId::ShaftSpeed,
            SensorId::OrificeDp,
        ] {
            v.set(id, 1e5);
        }
        RawSensors::fresh(v)
    }

    fn cause_of(raw: &RawSensors, needs_flow: bool) -> Option<Cause> {
        let s = sup();
        let v = s.check(raw);
        Cause::of_unusable_inputs(&v, &raw.values.values, &raw.age_s, &s, needs_flow)
    }

    #[test]
    fn names_the_failed_input_its_fault_and_value() {
        assert_eq!(cause_of(&healthy(), false), None);
        let mut raw = healthy();
        raw.values.set(SensorId::PDischarge, 2.1e7);
        let c = cause_of(&raw, false).expect("cause");
        assert_eq!(c.kind, CauseKind::InputFault);
        assert_eq!(c.input, Some(SensorId::PDischarge));
        assert_eq!(c.fault, Some(FallbackReason::OutOfRange));
        assert_eq!(c.value, Some(2.1e7));
        assert_eq!(c.category(), Some("sensor_implausible"));
        let text = c.describe();
        assert!(
            text.contains("p_discharge out of range: 2.100e7 Pa"),
            "{text}"
        );
        assert!(text.contains("1.200e6"), "{text}");

        let mut raw = healthy();
        raw.age_s[SensorId::ShaftSpeed.index()] = 0.2;
        let c = cause_of(&raw, false).expect("cause");
        assert_eq!(
            (c.input, c.fault),
            (Some(SensorId::ShaftSpeed), Some(FallbackReason::Stale))
        );
        assert_eq!(c.category(), Some("sensor_timeout"));
        assert!(
            c.describe().contains("200 ms old (timeout 50 ms)"),
            "{}",
            c.describe()
        );

        let mut raw = healthy();
        raw.values.set(SensorId::PSuction, f64::NAN);
        let c = cause_of(&raw, false).expect("cause");
        assert_eq!(
            (c.input, c.fault, c.value),
            (Some(SensorId::PSuction), Some(FallbackReason::Nan), None)
        );
    }

    #[test]
    fn flow_cause_only_when_the_law_needs_a_flow() {
        let raw = healthy();
        let c = cause_of(&raw, true).expect("cause");
        assert_eq!(c.kind, CauseKind::FlowUnavailable);
        assert_eq!(c.input, Some(SensorId::OrificeDp));
    }

    #[test]
    fn json_round_trip_leaves_out_what_is_unknown() {
        let mut raw = healthy();
        raw.values.set(SensorId::PDischarge, 2.1e7);
        let c = cause_of(&raw, false).expect("cause");
        let j = serde_json::to_string(&c).expect("json");
        assert!(j.contains(r#""input":"p_discharge""#), "{j}");
        assert!(j.contains(r#""fault":"out_of_range""#), "{j}");
        let back: Cause = serde_json::from_str(&j).expect("parse");
        assert_eq!(back, c);
        let j = serde_json::to_string(&Cause::of(CauseKind::Operator)).expect("json");
        assert_eq!(j, r#"{"kind":"operator"}"#);
        for k in 1..=6 {
            assert_eq!(CauseKind::from_code(k).map(|c| c.code()), Some(k));
        }
    }
}
