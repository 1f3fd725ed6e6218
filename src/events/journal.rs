//! The journal side of the event log: every mode change, fallback, trip and surge written to
//! the event log also goes to the journal (tracing, target `event`) as a WARN or ERROR line
//! with structured fields (`event`, `from`, `to`, `cause`, `input`, `fault`, `value`, `min`,
//! `max`, `age_ms` …; journald shows them upper-cased: `INPUT=p_discharge`). Called by the
//! writer thread, never by the control thread.

use super::cause::Cause;
use super::event::Event;
use crate::vocab::Mode;

fn fault_name(c: &Option<Cause>) -> Option<&'static str> {
    c.and_then(|c| c.fault).map(|f| match f {
        super::FallbackReason::Stale => "stale",
        super::FallbackReason::OutOfRange => "out_of_range",
        super::FallbackReason::Nan => "nan",
        super::FallbackReason::AliveCounter => "alive_counter",
        super::FallbackReason::BusOff => "bus_off",
        super::FallbackReason::Frozen => "frozen",
        super::FallbackReason::Drift => "drift",
    })
}

/// Log the safety-relevant events to the journal; other kinds are left to their producers.
pub fn record(event: &Event) {
    match event {
        Event::ModeChanged(m) => {
            let c = m.cause;
            let text = c.map(|c| c.describe()).unwrap_or_default();
            let kind = c.map(|c| kind_name(&c));
            let input = c.and_then(|c| c.input).map(|i| i.name());
            let fault = fault_name(&c);
            let (from, to) = (m.from.name(), m.to.name());
            macro_rules! line {
                ($lvl:ident) => {
                    tracing::$lvl!(target: "event", event = "mode_changed", from, to,
                        cause = kind, input, fault, value = c.and_then(|c| c.value),
                        min = c.and_then(|c| c.min), max = c.and_then(|c| c.max),
                        age_ms = c.and_then(|c| c.age_ms),
                        "mode {from} → {to}: {text}")
                };
            }
            if m.to == Mode::FailSafe {
                line!(error)
            } else {
                line!(warn)
            }
        }
        Event::FallbackEntered(f) => {
            let off = |x: Option<f64>, what: &str| {
                x.map(|v| format!(", reads {v:+.1} % of surge-line flow against the {what}"))
                    .unwrap_or_default()
            };
            let detail = format!(
                "{}{}",
                off(f.vs_observer_pct, "observer"),
                off(f.vs_speed_line_pct, "speed-line flow")
            );
            tracing::warn!(target: "event", event = "fallback_entered", input = f.input.name(),
                fault = ?f.reason, replaced_by = ?f.replaced_by,
                vs_observer_pct = f.vs_observer_pct, vs_speed_line_pct = f.vs_speed_line_pct,
                "{} failed ({:?}{detail}): {:?} stands in", f.input.name(), f.reason, f.replaced_by)
        }
        Event::FallbackLeft(f) => {
            tracing::warn!(target: "event", event = "fallback_left", input = f.input.name(),
                duration_ms = f.duration_ms,
                "{} healthy again after {} ms", f.input.name(), f.duration_ms)
        }
        Event::SurgeDetected(s) => {
            tracing::warn!(target: "event", event = "surge_detected",
                surge_count_total = s.surge_count_total, frequency_hz = s.frequency_hz,
                min_flow_kg_s = s.min_flow_kg_s, flow_reversal = s.flow_reversal,
                "surge detected (#{}): {}, lowest flow {:.3} kg/s", s.surge_count_total,
                if s.flow_reversal { "flow reversed" } else { "oscillation" }, s.min_flow_kg_s)
        }
        Event::RecycleTrip(t) => {
            let text = t.cause.map(|c| c.describe()).unwrap_or_default();
            tracing::warn!(target: "event", event = "recycle_trip", reason = ?t.reason,
                value = t.cause.and_then(|c| c.value), min = t.cause.and_then(|c| c.min),
                "recycle trip ({:?}): {text}", t.reason)
        }
        Event::SafetyOnShift(s) => {
            tracing::warn!(target: "event", event = "safety_on_shift", count = s.count,
                total_margin_pct = s.total_margin_pct,
                "safety-on: control line moved right, {} step(s), {:.1} % in total",
                s.count, s.total_margin_pct)
        }
        Event::SurgeCounter(s) => {
            tracing::warn!(target: "event", event = "surge_counter",
                previous_count = s.previous_count, count = s.count,
                "surge counter set from {} to {}", s.previous_count, s.count)
        }
        Event::Transmitter(t) => {
            let check = t.check.map(|c| format!(" ({c:?})")).unwrap_or_default();
            let name = t.name();
            let state = t.state;
            macro_rules! line {
                ($lvl:ident) => {
                    tracing::$lvl!(target: "event", event = "transmitter", input = t.input.name(),
                        transmitter = name.as_str(), state = ?t.state, check = ?t.check,
                        value = t.value, vote = t.vote, deviation_pct = t.deviation_pct,
                        valid = t.valid, bound = t.bound, rule = ?t.rule,
                        "transmitter {name} {state:?}{check}: reads {:.6} against the vote {:.6}, {} of {} valid, {:?}",
                        t.value, t.vote, t.valid, t.bound, t.rule)
                };
            }
            if t.state == super::event::TransmitterStateName::Healthy {
                line!(info)
            } else {
                line!(warn)
            }
        }
        Event::LawChanged(l) => {
            tracing::warn!(target: "event", event = "law_changed", from = l.from.name(),
                to = l.to.name(), "law {} → {}", l.from, l.to)
        }
        _ => {}
    }
}

fn kind_name(c: &Cause) -> &'static str {
    use super::cause::CauseKind::*;
    match c.kind {
        InputFault => "input_fault",
        FlowUnavailable => "flow_unavailable",
        InputsHealthy => "inputs_healthy",
        Operator => "operator",
        SurgeMargin => "surge_margin",
        Shutdown => "shutdown",
        EsdInput => "esd_input",
        LinkDown => "link_down",
    }
}
