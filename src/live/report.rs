//! The status report: the live snapshot plus cycle statistics and links, as served on the
//! status socket (`antisurge status --json`), summarised in one line for `sd_notify STATUS=`
//! and the periodic journal line, and printed for a terminal (`antisurge status`).

use serde::{Deserialize, Serialize};

use super::snapshot::{FlowSourceNow, LiveSnapshot};
use crate::events::cause::Cause;
use crate::io::signal_map::InputLink;
use crate::vocab::signals::SensorId;

/// One fault lamp: an input that is not usable now.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FaultLamp {
    /// The input.
    pub input: SensorId,
}

/// One input the skid's field links carry (a transmitter of a measurement), with the link
/// that carries it and whether that link is down: the HMI marks amber only the inputs of a
/// link that is down, naming the link (the root cause), and leaves the healthy link's inputs
/// as they are. Unbound sensors have no entry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InputReport {
    /// The measurement.
    pub input: SensorId,
    /// The transmitter: `a` (`[sensors]`), `b` or `c` (`[vote]`).
    pub transmitter: String,
    /// The link that carries it (`can:<interface>`, `modbus:<address>`, as
    /// `links.<kind>.name`); null: no field link (the embedded plant).
    pub link: Option<String>,
    /// Whether that link is down now (`links.<kind>.state` is `down`).
    pub link_down: bool,
    /// `ok`; `link_down`: its link is down, the link is the root cause (amber); `fault`: the
    /// input's own fault on a live link (stale, out of range, voted out, …; red).
    pub state: String,
}

/// One redundant transmitter (the HMI draws a lamp per entry).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransmitterLamp {
    /// The measurement, e.g. `orifice_dp`.
    pub measurement: String,
    /// The transmitter in the signal map: `a` (`[sensors.<measurement>]`), `b` or `c`
    /// (`[vote.<measurement>]`).
    pub binding: String,
    /// Its reading, SI unit (null: none).
    pub value: Option<f64>,
    /// The unit of `value`.
    pub unit: String,
    /// `healthy`, `deviating` or `voted_out`.
    pub state: String,
    /// The check behind `deviating` / `voted_out`: `stale`, `nan`, `out_of_range`, `frozen`,
    /// `deviation` (null when healthy).
    pub reason: Option<String>,
}

/// One measurement's vote.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VoteReport {
    /// The measurement.
    pub measurement: String,
    /// `median`, `conservative`, `hold_last` or `none`.
    pub rule: String,
    /// Valid transmitters.
    pub valid: u8,
    /// Transmitters bound.
    pub bound: u8,
    /// The voted value, SI (null: none).
    pub value: Option<f64>,
    /// Unit of `value`.
    pub unit: String,
    /// Fewer valid than bound, or fewer than two that agree: the control line is shifted.
    pub degraded: bool,
}

/// The degraded policy in force: how far the control line is widened and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct DegradedPolicy {
    /// Whether a degraded policy is in force (a shift applied or on its way).
    pub in_force: bool,
    /// Control-line shift in force, % of the control-line flow.
    pub margin_shift_pct: f64,
    /// Where the shift is moving (1 %/s), %.
    pub target_margin_shift_pct: f64,
    /// What asks for it: `vote_degraded` (with the measurements), `field_link_slow`.
    pub causes: Vec<String>,
    /// The policy in words.
    pub text: String,
}

/// What `antisurge status --json` prints. Floats are `null` when unknown.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StatusReport {
    /// antisurge version.
    pub version: String,
    /// Seconds since the daemon started.
    pub uptime_s: f64,
    /// Control cycle number of the snapshot.
    pub cycle: u64,
    /// Mode: init | manual | auto | fail_safe.
    pub mode: String,
    /// Active law.
    pub law: String,
    /// Whether auto is requested (false: manual station).
    pub auto_requested: bool,
    /// Where the flow comes from.
    pub flow_source: FlowSourceNow,
    /// Cause of the last mode change (null once acknowledged while healthy).
    pub cause: Option<Cause>,
    /// The cause in words.
    pub cause_text: Option<String>,
    /// Inputs not usable now.
    pub faults: Vec<FaultLamp>,
    /// Field faults active now (links, writes, actuator feedback; latched ones until
    /// acknowledged), by category name: the same fault word the CAN heartbeat and the Modbus
    /// watchdog register carry.
    #[serde(default)]
    pub field_faults: Vec<String>,
    /// Deviation from the control line, % of control-line flow (positive = safe).
    pub deviation_pct: Option<f64>,
    /// Surge margin to the surge line, %.
    pub surge_margin_pct: Option<f64>,
    /// Operating point: flow in map coordinates.
    pub flow_map: Option<f64>,
    /// Operating point: pressure ratio.
    pub pressure_ratio: Option<f64>,
    /// Mass flow used by the law, kg/s.
    pub m_kg_s: Option<f64>,
    /// Shaft speed, rad/s.
    pub omega_rad_s: Option<f64>,
    /// Suction pressure the cycle used, Pa (null: no usable transmitter).
    #[serde(default)]
    pub p_suction_pa: Option<f64>,
    /// Discharge pressure the cycle used, Pa (null: no usable transmitter).
    #[serde(default)]
    pub p_discharge_pa: Option<f64>,
    /// Flow element's Δp the cycle used (voted where redundant), Pa (null: none usable).
    #[serde(default)]
    pub orifice_dp_pa: Option<f64>,
    /// Suction temperature measured, K (null: no usable transmitter; the cycle then uses the
    /// machine's nominal temperature).
    #[serde(default)]
    pub t_suction_k: Option<f64>,
    /// Surge, control and trip line flows at the current ratio (map flow units).
    pub surge_line_flow: Option<f64>,
    /// Control-line flow (with safety-on) at the current ratio.
    pub control_line_flow: Option<f64>,
    /// Trip-line flow at the current ratio.
    pub trip_line_flow: Option<f64>,
    /// Recycle valve output commanded, %.
    pub valve_output_pct: Option<f64>,
    /// Recycle valve position measured, %.
    pub valve_position_pct: Option<f64>,
    /// Manual-station output, %.
    pub manual_output_pct: Option<f64>,
    /// Surge counter (kept across restarts).
    pub surge_count: u64,
    /// Safety-on steps in force and the shift they add, % of surge-line flow.
    pub safety_on_count: u32,
    /// Safety-on shift, %.
    pub safety_on_shift_pct: f64,
    /// Recycle trips since start.
    pub trip_count: u64,
    /// Cycle statistics (jitter, compute time, overruns).
    pub cycle_stats: serde_json::Value,
    /// Field links (CAN, Modbus counters).
    pub links: serde_json::Value,
    /// Redundant transmitters: one entry per transmitter of each voted measurement.
    #[serde(default)]
    pub transmitters: Vec<TransmitterLamp>,
    /// The votes of the measurements with redundant transmitters.
    #[serde(default)]
    pub votes: Vec<VoteReport>,
    /// The degraded policy in force (a degraded vote, a slow field link).
    #[serde(default)]
    pub degraded_policy: DegradedPolicy,
    /// The inputs the skid's links carry, per transmitter, with their link (empty: no
    /// table given, e.g. the one-line status).
    #[serde(default)]
    pub inputs: Vec<InputReport>,
    /// Faults of the votes now, by category name (`transmitter_deviation`,
    /// `vote_degraded`): the bits the control thread adds to the fault word on the wire.
    #[serde(default)]
    pub vote_faults: Vec<String>,
}

/// The transmitters, votes and degraded policy of a snapshot.
fn vote_reports(s: &LiveSnapshot) -> (Vec<TransmitterLamp>, Vec<VoteReport>, DegradedPolicy) {
    let mut lamps = Vec::new();
    let mut votes = Vec::new();
    let mut degraded = Vec::new();
    for v in s.votes.votes.iter().filter(|v| v.bound > 0) {
        let unit = v.input.unit().to_string();
        for t in 0..usize::from(v.bound).min(crate::control::vote::MAX_TRANSMITTERS) {
            lamps.push(TransmitterLamp {
                measurement: v.input.name().into(),
                binding: crate::control::vote::TRANSMITTER_NAMES[t].into(),
                value: f(v.values[t]),
                unit: unit.clone(),
                state: v.states[t].name().into(),
                reason: v.states[t].reason().map(|c| c.name().to_string()),
            });
        }
        if v.degraded {
            degraded.push(v.input.name());
        }
        votes.push(VoteReport {
            measurement: v.input.name().into(),
            rule: v.rule.name().into(),
            valid: v.valid,
            bound: v.bound,
            value: f(v.value),
            unit,
            degraded: v.degraded,
        });
    }
    let sh = s.votes.shift;
    let pct = |x: f64| if x.is_finite() { 100.0 * x } else { 0.0 };
    let mut causes = Vec::new();
    if sh.vote > 0.0 {
        causes.push(format!("vote_degraded: {}", degraded.join(", ")));
    }
    if sh.slow_link > 0.0 {
        causes.push("field_link_slow".to_string());
    }
    let in_force = sh.now > 0.0 || sh.target > 0.0;
    let text = if !in_force {
        "none: control line as configured".to_string()
    } else {
        format!(
            "hold and widen: control line +{:.1} % of its flow (to +{:.1} %, 1 %/s) while {}; between answers the last inputs are held; fail-safe only when an input stays stale past its freshness timeout plus the failure hold",
            pct(sh.now),
            pct(sh.target),
            if causes.is_empty() { "the cause clears".to_string() } else { causes.join(" and ") }
        )
    };
    (
        lamps,
        votes,
        DegradedPolicy {
            in_force,
            margin_shift_pct: pct(sh.now),
            target_margin_shift_pct: pct(sh.target),
            causes,
            text,
        },
    )
}

fn f(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

impl StatusReport {
    /// Build from a snapshot.
    pub fn new(
        s: &LiveSnapshot,
        uptime_s: f64,
        cycle_stats: serde_json::Value,
        links: serde_json::Value,
    ) -> StatusReport {
        StatusReport {
            version: env!("CARGO_PKG_VERSION").into(),
            uptime_s,
            cycle: s.cycle,
            mode: s.mode.name().into(),
            law: s.law.name().into(),
            auto_requested: s.auto_requested,
            flow_source: s.flow_source,
            cause: s.cause,
            cause_text: s.cause.map(|c| c.describe()),
            faults: SensorId::ALL
                .into_iter()
                .filter(|id| s.fault_bits & (1 << id.index()) != 0)
                .map(|input| FaultLamp { input })
                .collect(),
            field_faults: crate::vocab::faults::FaultSet(s.field_faults)
                .categories()
                .map(|c| c.name().to_string())
                .collect(),
            deviation_pct: f(s.deviation_pct),
            surge_margin_pct: f(s.surge_margin_pct),
            flow_map: f(s.flow_map),
            pressure_ratio: f(s.pressure_ratio),
            m_kg_s: f(s.m_kg_s),
            omega_rad_s: f(s.omega_rad_s),
            p_suction_pa: f(s.p_suction_pa),
            p_discharge_pa: f(s.p_discharge_pa),
            orifice_dp_pa: f(s.orifice_dp_pa),
            t_suction_k: f(s.t_suction_k),
            surge_line_flow: f(s.surge_line_flow),
            control_line_flow: f(s.control_line_flow),
            trip_line_flow: f(s.trip_line_flow),
            valve_output_pct: f(100.0 * s.valve_output),
            valve_position_pct: f(100.0 * s.valve_position),
            manual_output_pct: f(100.0 * s.manual_output),
            surge_count: s.surge_count,
            safety_on_count: s.safety_on_count,
            safety_on_shift_pct: s.safety_on_shift_pct,
            trip_count: s.trip_count,
            cycle_stats,
            links,
            transmitters: Vec::new(),
            votes: Vec::new(),
            degraded_policy: DegradedPolicy::default(),
            vote_faults: Vec::new(),
            inputs: Vec::new(),
        }
        .with_votes(s)
    }

    /// With the state of each input of `table` (the input→link table built at start from the
    /// signal map): its link down (from this report's `links.<kind>.name` and `.state`, what
    /// the link lamps show), or its own fault (a voted transmitter voted out; any other input
    /// in `faults`).
    pub fn with_inputs(mut self, table: &[InputLink], s: &LiveSnapshot) -> StatusReport {
        let down: Vec<&str> = ["can", "modbus"]
            .iter()
            .filter_map(|k| {
                let l = self.links.get(*k)?;
                (l.get("state")?.as_str()? == "down").then_some(l.get("name")?.as_str()?)
            })
            .collect();
        self.inputs = table
            .iter()
            .map(|row| {
                let link_down = row.link.as_deref().is_some_and(|l| down.contains(&l));
                let vote = s
                    .votes
                    .votes
                    .iter()
                    .find(|v| v.bound > 0 && v.input == row.input);
                let fault = match vote {
                    Some(v) => crate::control::vote::TRANSMITTER_NAMES
                        .iter()
                        .position(|t| *t == row.transmitter)
                        .is_some_and(|t| {
                            matches!(
                                v.states[t],
                                crate::control::vote::TransmitterState::VotedOut(_)
                            )
                        }),
                    None => s.fault_bits & (1 << row.input.index()) != 0,
                };
                InputReport {
                    input: row.input,
                    transmitter: row.transmitter.clone(),
                    link: row.link.clone(),
                    link_down,
                    state: if link_down {
                        "link_down"
                    } else if fault {
                        "fault"
                    } else {
                        "ok"
                    }
                    .into(),
                }
            })
            .collect();
        self
    }

    fn with_votes(mut self, s: &LiveSnapshot) -> StatusReport {
        (self.transmitters, self.votes, self.degraded_policy) = vote_reports(s);
        self.vote_faults = crate::control::vote::fault_set(&s.votes.votes)
            .categories()
            .map(|c| c.name().to_string())
            .collect();
        self
    }
}

fn pct(x: Option<f64>) -> String {
    x.map(|v| format!("{v:.1} %")).unwrap_or_else(|| "–".into())
}

/// One line: mode, law, deviation, valve, surges, flow source, and the cause when not
/// healthy. Used for `STATUS=` and the periodic journal line.
pub fn status_line(s: &LiveSnapshot) -> String {
    let r = StatusReport::new(s, 0.0, serde_json::Value::Null, serde_json::Value::Null);
    let mut line = format!(
        "{} · {} · deviation {} · valve {} (at {}) · surges {} · safety-on {} · flow {:?}",
        r.mode,
        r.law,
        r.deviation_pct
            .map(|v| format!("{v:+.1} %"))
            .unwrap_or_else(|| "–".into()),
        pct(r.valve_output_pct),
        pct(r.valve_position_pct),
        r.surge_count,
        r.safety_on_count,
        r.flow_source,
    );
    if !r.faults.is_empty() {
        let names: Vec<&str> = r.faults.iter().map(|l| l.input.name()).collect();
        line += &format!(" · faults: {}", names.join(", "));
    }
    let out: Vec<String> = r
        .transmitters
        .iter()
        .filter(|t| t.state != "healthy")
        .map(|t| {
            format!(
                "{}.{} {} ({})",
                t.measurement,
                t.binding,
                t.state.replace('_', " "),
                t.reason.as_deref().unwrap_or("?")
            )
        })
        .collect();
    if !out.is_empty() {
        line += &format!(" · transmitters: {}", out.join(", "));
    }
    if r.degraded_policy.in_force {
        line += &format!(
            " · control line +{:.1} % ({})",
            r.degraded_policy.margin_shift_pct,
            r.degraded_policy.causes.join(", ")
        );
    }
    if matches!(r.mode.as_str(), "fail_safe" | "init") {
        if let Some(t) = r.cause_text {
            line = format!("{} — {t}", line);
        }
    }
    line
}

/// The report for a terminal.
pub fn human(r: &StatusReport) -> String {
    let mut o = String::new();
    let mode = if r.mode == "manual" || (!r.auto_requested && r.mode == "auto") {
        format!(
            "{} (manual station, output {})",
            r.mode,
            pct(r.manual_output_pct)
        )
    } else {
        r.mode.clone()
    };
    o += &format!("mode          {mode}\n");
    o += &format!("law           {}\n", r.law);
    if let Some(c) = &r.cause_text {
        o += &format!("cause         {c}\n");
    }
    o += &format!(
        "deviation     {}  (from the control line; positive = safe)\n",
        r.deviation_pct
            .map(|v| format!("{v:+.2} %"))
            .unwrap_or_else(|| "–".into())
    );
    o += &format!("surge margin  {}\n", pct(r.surge_margin_pct));
    o += &format!(
        "operating pt  flow {}  ratio {}  ({:?})\n",
        r.flow_map
            .map(|v| format!("{v:.4}"))
            .unwrap_or_else(|| "–".into()),
        r.pressure_ratio
            .map(|v| format!("{v:.4}"))
            .unwrap_or_else(|| "–".into()),
        r.flow_source
    );
    let unit = |x: Option<f64>, scale: f64, offset: f64, d: usize, u: &str| {
        x.map_or("–".to_string(), |v| {
            format!("{:.d$} {u}", v * scale + offset)
        })
    };
    o += &format!(
        "process       suction {}  discharge {}  Δp {}  T suction {}\n",
        unit(r.p_suction_pa, 1e-3, 0.0, 1, "kPa"),
        unit(r.p_discharge_pa, 1e-3, 0.0, 1, "kPa"),
        unit(r.orifice_dp_pa, 1e-3, 0.0, 3, "kPa"),
        unit(r.t_suction_k, 1.0, -273.15, 1, "°C"),
    );
    o += &format!(
        "valve         output {}  position {}\n",
        pct(r.valve_output_pct),
        pct(r.valve_position_pct)
    );
    o += &format!(
        "surges        {}   safety-on {} step(s), +{:.1} %   trips {}\n",
        r.surge_count, r.safety_on_count, r.safety_on_shift_pct, r.trip_count
    );
    if !r.field_faults.is_empty() {
        o += &format!("field faults  {}\n", r.field_faults.join(", "));
    }
    if !r.vote_faults.is_empty() {
        o += &format!("vote faults   {}\n", r.vote_faults.join(", "));
    }
    let lamps = if r.faults.is_empty() {
        "none".to_string()
    } else {
        r.faults
            .iter()
            .map(|l| {
                // a link that is down is the root: named beside the inputs it carries
                match r.inputs.iter().find(|i| i.input == l.input && i.link_down) {
                    Some(i) => format!(
                        "{} (link {} down)",
                        l.input.name(),
                        i.link.as_deref().unwrap_or("?")
                    ),
                    None => l.input.name().to_string(),
                }
            })
            .collect::<Vec<_>>()
            .join(", ")
    };
    o += &format!("faults        {lamps}\n");
    for v in &r.votes {
        let tx: Vec<String> = r
            .transmitters
            .iter()
            .filter(|t| t.measurement == v.measurement)
            .map(|t| {
                let value = t.value.map_or("–".into(), |x| format!("{x:.6}"));
                match &t.reason {
                    Some(why) => format!(
                        "{} {value} {} ({why})",
                        t.binding,
                        t.state.replace('_', " ")
                    ),
                    None => format!("{} {value} {}", t.binding, t.state),
                }
            })
            .collect();
        o += &format!(
            "vote          {} {} of {} valid, {}{} = {} {} · {}\n",
            v.measurement,
            v.valid,
            v.bound,
            v.rule.replace('_', "-"),
            if v.degraded { " (degraded)" } else { "" },
            v.value.map_or("–".into(), |x| format!("{x:.6}")),
            v.unit,
            tx.join(" · ")
        );
    }
    if r.degraded_policy.in_force {
        o += &format!("degraded      {}\n", r.degraded_policy.text);
    }
    if let Some(m) = r.links.get("modbus").filter(|m| m.is_object()) {
        let n = |k: &str| m.get(k).and_then(serde_json::Value::as_u64).unwrap_or(0);
        let ms = |k: &str| n(k) as f64 * 1e-3;
        let text = |k: &str| m.get(k).and_then(serde_json::Value::as_str).unwrap_or("?");
        o += &format!(
            "modbus link   {} {}, poll period {:.0} ms, latency p50 {:.1} ms p99 {:.1} ms, timeouts {}, exceptions {}, reconnects {}, heartbeats {}\n",
            text("name"),
            text("state"),
            ms("poll_period_us"),
            ms("latency_p50_us"),
            ms("latency_p99_us"),
            n("timeouts"),
            n("exceptions"),
            n("reconnects"),
            n("heartbeats")
        );
    }
    if let Some(j) = r.cycle_stats.get("wake_jitter_us") {
        o += &format!(
            "cycle         {} cycles, jitter p99 {} µs, overruns {}\n",
            r.cycle_stats
                .get("cycles")
                .unwrap_or(&serde_json::Value::Null),
            j.get("p99_us").unwrap_or(&serde_json::Value::Null),
            r.cycle_stats
                .get("overruns")
                .unwrap_or(&serde_json::Value::Null)
        );
    }
    o += &format!(
        "uptime        {:.0} s (antisurge {})\n",
        r.uptime_s, r.version
    );
    o
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::cause::CauseKind;
    use crate::events::FallbackReason;
    use crate::vocab::Mode;

    #[test]
    fn fail_safe_line_and_text_name_the_input_and_fault() {
        let s = LiveSnapshot {
            mode: Mode::FailSafe,
            fault_bits: 1 << SensorId::PDischarge.index(),
            cause: Some(Cause {
                kind: CauseKind::InputFault,
                input: Some(SensorId::PDischarge),
                fault: Some(FallbackReason::OutOfRange),
                value: Some(2.1e7),
                min: Some(1e4),
                max: Some(1.2e7),
                age_ms: Some(0.0),
                timeout_ms: Some(50.0),
                link: None,
            }),
            surge_count: 3,
            ..LiveSnapshot::default()
        };
        let line = status_line(&s);
        assert!(line.starts_with("fail_safe"), "{line}");
        assert!(line.contains("faults: p_discharge"), "{line}");
        assert!(
            line.contains("p_discharge out of range: 2.100e7 Pa"),
            "{line}"
        );
        let r = StatusReport::new(&s, 1.0, serde_json::Value::Null, serde_json::Value::Null);
        let text = human(&r);
        assert!(
            text.contains("cause         p_discharge out of range"),
            "{text}"
        );
        assert!(text.contains("surges        3"), "{text}");
        assert!(
            text.contains("process       suction –  discharge –  Δp –  T suction –"),
            "{text}"
        );
        let mut pv = s;
        pv.p_suction_pa = 101_325.0;
        pv.p_discharge_pa = 2.5e5;
        pv.orifice_dp_pa = 1234.0;
        pv.t_suction_k = 293.15;
        let r = StatusReport::new(&pv, 1.0, serde_json::Value::Null, serde_json::Value::Null);
        let json = serde_json::to_value(&r).expect("json");
        assert_eq!(json["p_suction_pa"], 101_325.0);
        assert_eq!(json["p_discharge_pa"], 2.5e5);
        assert_eq!(json["orifice_dp_pa"], 1234.0);
        assert_eq!(json["t_suction_k"], 293.15);
        assert_eq!(json["field_faults"], serde_json::json!([]));
        // the field links' faults come with the cycle's snapshot
        let mut ff = pv;
        ff.field_faults = crate::vocab::faults::FaultCategory::FieldWriteFailed.bit();
        let fr = StatusReport::new(&ff, 1.0, serde_json::Value::Null, serde_json::Value::Null);
        assert_eq!(fr.field_faults, ["field_write_failed"]);
        let text = human(&r);
        assert!(
            text.contains(
                "process       suction 101.3 kPa  discharge 250.0 kPa  Δp 1.234 kPa  T suction 20.0 °C"
            ),
            "{text}"
        );
        let back: StatusReport =
            serde_json::from_str(&serde_json::to_string(&r).expect("json")).expect("parse");
        assert_eq!(back, r);
    }

    #[test]
    fn transmitters_votes_and_the_degraded_policy_are_shown() {
        use crate::control::vote::{TransmitterCheck, TransmitterState, VoteRule, VoteStatus};
        let mut s = LiveSnapshot {
            mode: Mode::Auto,
            ..LiveSnapshot::default()
        };
        s.votes.votes[3] = VoteStatus {
            input: SensorId::OrificeDp,
            bound: 3,
            valid: 2,
            rule: VoteRule::Conservative,
            value: 1000.0,
            values: [1000.0, 1200.0, 1100.0],
            states: [
                TransmitterState::Healthy,
                TransmitterState::Deviating,
                TransmitterState::VotedOut(TransmitterCheck::Frozen),
            ],
            degraded: true,
        };
        s.votes.shift.now = 0.02;
        s.votes.shift.target = 0.05;
        s.votes.shift.vote = 0.05;
        let r = StatusReport::new(&s, 1.0, serde_json::Value::Null, serde_json::Value::Null);
        let json = serde_json::to_value(&r).expect("json");
        assert_eq!(
            json["transmitters"][2],
            serde_json::json!({"measurement": "orifice_dp", "binding": "c", "value": 1100.0,
                "unit": "Pa", "state": "voted_out", "reason": "frozen"})
        );
        assert_eq!(json["votes"][0]["rule"], "conservative");
        assert_eq!(
            json["vote_faults"],
            serde_json::json!(["transmitter_deviation", "vote_degraded"])
        );
        assert_eq!(json["degraded_policy"]["in_force"], true);
        assert_eq!(
            json["degraded_policy"]["causes"][0],
            "vote_degraded: orifice_dp"
        );
        let text = human(&r);
        assert!(
            text.contains("vote          orifice_dp 2 of 3 valid, conservative (degraded)"),
            "{text}"
        );
        assert!(text.contains("c 1100.000000 voted out (frozen)"), "{text}");
        assert!(
            text.contains("degraded      hold and widen: control line +2.0 %"),
            "{text}"
        );
        let line = status_line(&s);
        assert!(
            line.contains(
                "transmitters: orifice_dp.b deviating (deviation), orifice_dp.c voted out (frozen)"
            ),
            "{line}"
        );
    }

    #[test]
    fn a_link_down_marks_only_the_inputs_it_carries_and_names_the_link() {
        use crate::control::vote::{TransmitterCheck, TransmitterState, VoteRule, VoteStatus};
        // the table of a skid with both buses (SignalMap::input_links): the pressures on CAN,
        // the Δp `a` and `c` on Modbus, `b` on CAN; no shaft speed or temperature bound
        let row = |input, t: &str, link: &str| InputLink {
            input,
            transmitter: t.into(),
            link: Some(link.into()),
        };
        let (can, modbus) = ("can:can0", "modbus:10.0.0.5:502");
        let table = [
            row(SensorId::PSuction, "a", can),
            row(SensorId::PDischarge, "a", can),
            row(SensorId::OrificeDp, "a", modbus),
            row(SensorId::OrificeDp, "b", can),
            row(SensorId::OrificeDp, "c", modbus),
        ];
        // the Modbus link is down: its transmitters stale and voted out; on the live CAN link
        // p_discharge is out of range (its own fault), p_suction healthy
        let mut s = LiveSnapshot {
            mode: Mode::Auto,
            fault_bits: 1 << SensorId::PDischarge.index(),
            ..LiveSnapshot::default()
        };
        s.votes.votes[3] = VoteStatus {
            input: SensorId::OrificeDp,
            bound: 3,
            valid: 1,
            rule: VoteRule::HoldLast,
            value: 1000.0,
            values: [f64::NAN, 1000.0, f64::NAN],
            states: [
                TransmitterState::VotedOut(TransmitterCheck::Stale),
                TransmitterState::Healthy,
                TransmitterState::VotedOut(TransmitterCheck::Stale),
            ],
            degraded: true,
        };
        let links = serde_json::json!({
            "can": {"name": can, "state": "up"},
            "modbus": {"name": modbus, "state": "down"},
        });
        let r = StatusReport::new(&s, 1.0, serde_json::Value::Null, links).with_inputs(&table, &s);
        let got: Vec<(&str, &str, &str, bool)> = r
            .inputs
            .iter()
            .map(|i| {
                (
                    i.input.name(),
                    i.transmitter.as_str(),
                    i.state.as_str(),
                    i.link_down,
                )
            })
            .collect();
        assert_eq!(
            got,
            [
                ("p_suction", "a", "ok", false),
                ("p_discharge", "a", "fault", false),
                ("orifice_dp", "a", "link_down", true),
                ("orifice_dp", "b", "ok", false),
                ("orifice_dp", "c", "link_down", true),
            ]
        );
        let json = serde_json::to_value(&r).expect("json");
        assert_eq!(
            json["inputs"][2],
            serde_json::json!({"input": "orifice_dp", "transmitter": "a", "link": modbus,
                "link_down": true, "state": "link_down"})
        );
        // no row for an unbound sensor
        assert!(r
            .inputs
            .iter()
            .all(|i| !matches!(i.input, SensorId::ShaftSpeed | SensorId::TSuction)));
        let back: StatusReport =
            serde_json::from_str(&serde_json::to_string(&r).expect("json")).expect("parse");
        assert_eq!(back, r);

        // the CAN link down instead: its inputs (the pressures, Δp `b`) are the link's, the
        // faults line names the link beside them; the Modbus transmitters stay as they are
        let mut s = LiveSnapshot {
            mode: Mode::FailSafe,
            fault_bits: (1 << SensorId::PSuction.index()) | (1 << SensorId::PDischarge.index()),
            ..LiveSnapshot::default()
        };
        s.votes.votes[3] = VoteStatus {
            input: SensorId::OrificeDp,
            bound: 3,
            valid: 2,
            rule: VoteRule::Conservative,
            value: 1000.0,
            values: [1000.0, f64::NAN, 1001.0],
            states: [
                TransmitterState::Healthy,
                TransmitterState::VotedOut(TransmitterCheck::Stale),
                TransmitterState::Healthy,
            ],
            degraded: true,
        };
        let links = serde_json::json!({
            "can": {"name": can, "state": "down"},
            "modbus": {"name": modbus, "state": "up"},
        });
        let r = StatusReport::new(&s, 1.0, serde_json::Value::Null, links).with_inputs(&table, &s);
        let states: Vec<&str> = r.inputs.iter().map(|i| i.state.as_str()).collect();
        assert_eq!(states, ["link_down", "link_down", "ok", "link_down", "ok"]);
        let text = human(&r);
        assert!(
            text.contains(
                "faults        p_suction (link can:can0 down), p_discharge (link can:can0 down)"
            ),
            "{text}"
        );
    }
}
