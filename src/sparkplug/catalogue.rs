//! What the node publishes: the node's metrics (cycle statistics, events, command results)
//! and its devices' (`compressor`: the controller's view of the machine; one device per
//! field link, from the link counters), with units and engineering ranges, and their values
//! from the off-thread snapshot.

use std::collections::BTreeMap;

use super::edge::{MetricDef, Value, OP_COMMAND, OP_TOKEN};
use super::forward::HostEvent;
use crate::live::hmi::MapLines;
use crate::live::snapshot::LiveSnapshot;
use crate::runtime::rt_loop::CycleReport;
use crate::vocab::signals::SensorId;

/// The compressor device's name.
pub const COMPRESSOR: &str = "compressor";
/// The node metric naming the last operator command's outcome.
pub const OP_RESULT: &str = "Operator/Last Result";

/// The analogue metrics (the ones with a deadband), compressor then node.
const ANALOGUE: [&str; 16] = [
    "Deviation",
    "Surge Margin",
    "Operating Point/Flow",
    "Operating Point/Pressure Ratio",
    "Operating Point/Surge Line Flow",
    "Operating Point/Control Line Flow",
    "Operating Point/Trip Line Flow",
    "Flow/Mass Flow",
    "Shaft Speed",
    "Valve/Command",
    "Valve/Position",
    "Valve/Manual Output",
    "Safety-On/Shift",
    "Cycle Stats/Wake Jitter p99",
    "Cycle Stats/Compute p99",
    "Cycle Stats/Input Age p99",
];

/// Whether `name` is an analogue metric (one `deadbands_pct` may name).
pub fn is_analogue(name: &str) -> bool {
    ANALOGUE.contains(&name)
}

/// The analogue metrics' names.
pub fn analogue_names() -> Vec<&'static str> {
    ANALOGUE.to_vec()
}

/// Engineering ranges of the map coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ranges {
    /// Flow in map coordinates.
    pub flow: (f64, f64),
    /// Pressure ratio.
    pub ratio: (f64, f64),
    /// Shaft speed, rad/s.
    pub speed: (f64, f64),
}

impl Ranges {
    /// From the map lines the HMI draws (the speed lines' extent); a machine without a map
    /// gets wide defaults.
    pub fn of(map: &MapLines) -> Ranges {
        let pts = map.speed_lines.iter().flat_map(|(_, p)| p.iter());
        let q_hi = pts.clone().map(|p| p.0).fold(f64::NAN, f64::max);
        let r_hi = pts.map(|p| p.1).fold(f64::NAN, f64::max);
        let w_hi = map.speed_lines.iter().map(|l| l.0).fold(f64::NAN, f64::max);
        let nice = |x: f64, d: f64| if x.is_finite() && x > 0.0 { x } else { d };
        Ranges {
            flow: (0.0, nice(q_hi, 2.0)),
            ratio: (1.0, nice(r_hi, 5.0)),
            speed: (0.0, nice(1.2 * w_hi, 2000.0)),
        }
    }
}

/// Deadbands: the default and the per-metric ones, %.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Deadbands {
    /// Every analogue metric's, unless named below.
    pub default_pct: f64,
    /// By metric name.
    pub by_name: BTreeMap<String, f64>,
}

impl Deadbands {
    fn of(&self, name: &str) -> f64 {
        self.by_name.get(name).copied().unwrap_or(self.default_pct)
    }
    fn ranged(&self, name: &str, unit: &'static str, r: (f64, f64)) -> MetricDef {
        MetricDef::ranged(name, unit, r.0, r.1, self.of(name))
    }
    fn relative(&self, name: &str, unit: &'static str) -> MetricDef {
        MetricDef::relative(name, unit, self.of(name))
    }
}

/// The node metrics (after `bdSeq` and the rebirth control).
pub fn node_metrics(db: &Deadbands) -> Vec<MetricDef> {
    vec![
        MetricDef::along("Cycle Stats/Cycles"),
        MetricDef::plain("Cycle Stats/Overruns"),
        MetricDef::plain("Cycle Stats/Skipped"),
        db.relative("Cycle Stats/Wake Jitter p99", "us"),
        db.relative("Cycle Stats/Compute p99", "us"),
        db.relative("Cycle Stats/Input Age p99", "us"),
        MetricDef::plain("Store and Forward/Dropped"),
        MetricDef::explicit("Events/Seq"),
        MetricDef::explicit("Events/Kind"),
        MetricDef::explicit("Events/Cause"),
        MetricDef::explicit("Events/Json"),
        MetricDef::explicit(OP_RESULT),
    ]
}

/// The node metrics' values, in [`node_metrics`] order.
pub fn node_values(
    r: &CycleReport,
    dropped: u64,
    last_event: Option<&HostEvent>,
    op_result: &str,
) -> Vec<Value> {
    let e = last_event;
    vec![
        Value::UInt64(r.cycles),
        Value::UInt64(r.overruns),
        Value::UInt64(r.skipped),
        Value::Double(r.wake_jitter.p99_us),
        Value::Double(r.compute.p99_us),
        Value::Double(r.input_age.p99_us),
        Value::UInt64(dropped),
        Value::UInt64(e.map_or(0, |e| e.seq)),
        Value::Str(e.map(|e| e.kind.clone()).unwrap_or_default()),
        Value::Str(e.map(|e| e.cause.clone()).unwrap_or_default()),
        Value::Str(e.map(|e| e.json.clone()).unwrap_or_default()),
        Value::Str(op_result.into()),
    ]
}

/// An event as the metrics of one NDATA.
pub fn event_metrics(e: &HostEvent) -> Vec<(String, Value, u64)> {
    let t = e.ts_ms;
    vec![
        ("Events/Seq".into(), Value::UInt64(e.seq), t),
        ("Events/Kind".into(), Value::Str(e.kind.clone()), t),
        ("Events/Cause".into(), Value::Str(e.cause.clone()), t),
        ("Events/Json".into(), Value::Str(e.json.clone()), t),
    ]
}

/// The compressor device's metrics.
pub fn compressor_metrics(r: &Ranges, db: &Deadbands) -> Vec<MetricDef> {
    let pct = (0.0, 100.0);
    vec![
        MetricDef::along("Cycle"),
        db.ranged("Deviation", "%", (-100.0, 100.0)),
        db.ranged("Surge Margin", "%", (-100.0, 100.0)),
        db.ranged("Operating Point/Flow", "map flow", r.flow),
        db.ranged("Operating Point/Pressure Ratio", "1", r.ratio),
        db.ranged("Operating Point/Surge Line Flow", "map flow", r.flow),
        db.ranged("Operating Point/Control Line Flow", "map flow", r.flow),
        db.ranged("Operating Point/Trip Line Flow", "map flow", r.flow),
        db.relative("Flow/Mass Flow", "kg/s"),
        MetricDef::plain("Flow/Source"),
        db.ranged("Shaft Speed", "rad/s", r.speed),
        db.ranged("Valve/Command", "%", pct),
        db.ranged("Valve/Position", "%", pct),
        db.ranged("Valve/Manual Output", "%", pct),
        MetricDef::plain("Mode"),
        MetricDef::plain("Law"),
        MetricDef::plain("Auto Requested"),
        MetricDef::plain("Faults/Active"),
        MetricDef::plain("Faults/Inputs"),
        MetricDef::plain("Faults/Cause"),
        MetricDef::plain("Surge Count"),
        MetricDef::plain("Trip Count"),
        db.ranged("Safety-On/Shift", "%", (0.0, 50.0)),
        MetricDef::plain("Safety-On/Steps"),
        MetricDef::explicit(OP_TOKEN),
        MetricDef::explicit(OP_COMMAND),
    ]
}

/// The compressor device's values from a snapshot, in [`compressor_metrics`] order.
pub fn compressor_values(s: &LiveSnapshot) -> Vec<Value> {
    let faults: Vec<&str> = SensorId::ALL
        .into_iter()
        .filter(|id| s.fault_bits & (1 << id.index()) != 0)
        .map(|id| id.name())
        .collect();
    let source = s.flow_source.name();
    vec![
        Value::UInt64(s.cycle),
        Value::Double(s.deviation_pct),
        Value::Double(s.surge_margin_pct),
        Value::Double(s.flow_map),
        Value::Double(s.pressure_ratio),
        Value::Double(s.surge_line_flow),
        Value::Double(s.control_line_flow),
        Value::Double(s.trip_line_flow),
        Value::Double(s.m_kg_s),
        Value::Str(source.into()),
        Value::Double(s.omega_rad_s),
        Value::Double(100.0 * s.valve_output),
        Value::Double(100.0 * s.valve_position),
        Value::Double(100.0 * s.manual_output),
        Value::Str(s.mode.name().into()),
        Value::Str(s.law.name().into()),
        Value::Bool(s.auto_requested),
        Value::UInt32(s.fault_bits),
        Value::Str(faults.join(",")),
        Value::Str(s.cause.map(|c| c.describe()).unwrap_or_default()),
        Value::UInt64(s.surge_count),
        Value::UInt64(s.trip_count),
        Value::Double(s.safety_on_shift_pct),
        Value::UInt32(s.safety_on_count),
        Value::Str(String::new()),
        Value::Str(String::new()),
    ]
}

/// A field link's counters (the `links` JSON of the status report) flattened to metric
/// names (`a/b`) and values; numbers that fit are UInt64, others Double.
pub fn flatten_link(v: &serde_json::Value) -> Vec<(String, Value)> {
    fn walk(prefix: &str, v: &serde_json::Value, out: &mut Vec<(String, Value)>) {
        let name = |k: &str| {
            if prefix.is_empty() {
                k.to_string()
            } else {
                format!("{prefix}/{k}")
            }
        };
        match v {
            serde_json::Value::Object(m) => {
                for (k, x) in m {
                    walk(&name(k), x, out);
                }
            }
            serde_json::Value::Bool(b) => out.push((prefix.into(), Value::Bool(*b))),
            serde_json::Value::Number(n) => out.push((
                prefix.into(),
                n.as_u64().map_or_else(
                    || Value::Double(n.as_f64().unwrap_or(f64::NAN)),
                    Value::UInt64,
                ),
            )),
            serde_json::Value::String(s) => out.push((prefix.into(), Value::Str(s.clone()))),
            serde_json::Value::Array(a) => out.push((
                prefix.into(),
                Value::Str(serde_json::to_string(a).unwrap_or_default()),
            )),
            serde_json::Value::Null => {}
        }
    }
    let mut out = Vec::new();
    walk("", v, &mut out);
    out.retain(|(n, _)| !n.is_empty());
    out
}

/// The link devices present in the `links` JSON (`{"can": {…}, "modbus": null}`): name and
/// its flattened counters.
pub fn link_devices(links: &serde_json::Value) -> Vec<(String, Vec<(String, Value)>)> {
    let Some(m) = links.as_object() else {
        return Vec::new();
    };
    m.iter()
        .filter(|(_, v)| v.is_object())
        .map(|(k, v)| (format!("link-{k}"), flatten_link(v)))
        .collect()
}

/// Values of a link device in the order of `names` (a counter gone: null).
pub fn link_values(names: &[String], now: &[(String, Value)]) -> Vec<Value> {
    names
        .iter()
        .map(|n| {
            now.iter()
                .find(|(k, _)| k == n)
                .map_or(Value::Double(f64::NAN), |(_, v)| v.clone())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_metric_has_a_value_and_the_analogue_list_is_the_ranged_one() {
        let db = Deadbands {
            default_pct: 0.5,
            ..Default::default()
        };
        let r = Ranges {
            flow: (0.0, 2.0),
            ratio: (1.0, 4.0),
            speed: (0.0, 1000.0),
        };
        let defs = compressor_metrics(&r, &db);
        assert_eq!(
            defs.len(),
            compressor_values(&LiveSnapshot::default()).len()
        );
        let n = node_metrics(&db);
        assert_eq!(
            n.len(),
            node_values(
                &crate::runtime::rt_loop::CycleStats::default().report(),
                0,
                None,
                ""
            )
            .len()
        );
        let analogue: Vec<&str> = defs
            .iter()
            .chain(n.iter())
            .filter(|d| d.unit.is_some())
            .map(|d| d.name.as_str())
            .collect();
        assert_eq!(analogue, ANALOGUE);
        let dev = &defs[1];
        assert_eq!(
            (dev.name.as_str(), dev.unit, dev.deadband),
            ("Deviation", Some("%"), 1.0)
        );
        let by = Deadbands {
            default_pct: 0.5,
            by_name: [("Deviation".to_string(), 0.1)].into(),
        };
        assert!((compressor_metrics(&r, &by)[1].deadband - 0.2).abs() < 1e-12);
    }

    #[test]
    fn links_flatten_to_devices() {
        let j = serde_json::json!({"can": {"frames_rx": 12, "bus": {"state": "active", "load_pct": 3.5}, "ok": true}, "modbus": null});
        let d = link_devices(&j);
        assert_eq!(d.len(), 1);
        assert_eq!(d[0].0, "link-can");
        let names: Vec<String> = d[0].1.iter().map(|(n, _)| n.clone()).collect();
        assert_eq!(names, ["bus/load_pct", "bus/state", "frames_rx", "ok"]);
        let v = link_values(&["frames_rx".into(), "gone".into()], &d[0].1);
        assert_eq!(v[0], Value::UInt64(12));
        assert!(matches!(v[1], Value::Double(x) if x.is_nan()));
    }
}
