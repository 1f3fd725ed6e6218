//! The Sparkplug B edge node's state, free of I/O: topics, `seq` and `bdSeq`, births with
//! every metric's datatype, units and engineering limits, data by exception with per-metric
//! deadbands, the death certificate, and the commands a host sends (rebirth, operator
//! actions). The network task ([`super::task`]) drives it; everything here is unit-tested.

use std::path::{Path, PathBuf};

use super::proto::{datatype, Metric, MetricValue, Payload, PropertySet};

/// The Sparkplug B namespace.
pub const NAMESPACE: &str = "spBv1.0";
/// The node metric carrying the birth/death sequence.
pub const BD_SEQ: &str = "bdSeq";
/// The node metric a host writes `true` to for a rebirth.
pub const REBIRTH: &str = "Node Control/Rebirth";
/// The command metric (a host's NCMD/DCMD): the operator token.
pub const OP_TOKEN: &str = "Operator/Token";
/// The command metric: the operator action words (`auto`, `manual 20`, `output 20`, `ack`).
pub const OP_COMMAND: &str = "Operator/Command";
/// The first words of the actions a host may send (the HMI's allow-list).
pub const OP_ALLOWED: [&str; 4] = ["auto", "manual", "output", "ack"];

/// A metric's value.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// Double (NaN: published as null).
    Double(f64),
    /// Unsigned 64-bit.
    UInt64(u64),
    /// Unsigned 32-bit.
    UInt32(u32),
    /// Boolean.
    Bool(bool),
    /// String.
    Str(String),
}

impl Value {
    fn datatype(&self) -> u32 {
        match self {
            Value::Double(_) => datatype::DOUBLE,
            Value::UInt64(_) => datatype::UINT64,
            Value::UInt32(_) => datatype::UINT32,
            Value::Bool(_) => datatype::BOOLEAN,
            Value::Str(_) => datatype::STRING,
        }
    }

    fn write(&self, m: &mut Metric) {
        m.datatype = Some(self.datatype());
        m.value = match self {
            Value::Double(x) if !x.is_finite() => {
                m.is_null = Some(true);
                None
            }
            Value::Double(x) => Some(MetricValue::DoubleValue(*x)),
            Value::UInt64(x) => Some(MetricValue::LongValue(*x)),
            Value::UInt32(x) => Some(MetricValue::IntValue(*x)),
            Value::Bool(x) => Some(MetricValue::BooleanValue(*x)),
            Value::Str(x) => Some(MetricValue::StringValue(x.clone())),
        };
    }

    /// Whether `self` differs from the reported `last` by more than `deadband` (doubles:
    /// absolute, in the metric's unit; a change between a number and null always counts;
    /// every other type: any change).
    pub fn exceeds(&self, last: &Value, deadband: f64) -> bool {
        match (self, last) {
            (Value::Double(a), Value::Double(b)) => match (a.is_finite(), b.is_finite()) {
                (true, true) => (a - b).abs() > deadband || (deadband <= 0.0 && a != b),
                (x, y) => x != y,
            },
            (a, b) => a != b,
        }
    }
}

/// One metric: name, unit and engineering range, deadband.
#[derive(Debug, Clone, PartialEq)]
pub struct MetricDef {
    /// Name (`/` separates folders, as Ignition shows them).
    pub name: String,
    /// Engineering unit (`engUnit`), if any.
    pub unit: Option<&'static str>,
    /// Engineering range (`engLow`, `engHigh`), if any.
    pub range: Option<(f64, f64)>,
    /// Report-by-exception deadband, absolute in `unit` (doubles with a range); without a
    /// range, relative: % of the last reported value's magnitude.
    pub deadband: f64,
    /// When the metric is published after its birth.
    pub report: Report,
}

/// When a metric is published after its birth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Report {
    /// By exception: when it moved beyond its deadband.
    Exception,
    /// Never alone: alongside any other metric of its set that is sent (e.g. the cycle
    /// number the values belong to).
    Along,
    /// Only when the node sends it explicitly (events, command results).
    Explicit,
}

impl MetricDef {
    /// A metric without unit or range.
    pub fn plain(name: &str) -> MetricDef {
        MetricDef {
            name: name.into(),
            unit: None,
            range: None,
            deadband: 0.0,
            report: Report::Exception,
        }
    }

    /// A metric sent only alongside others ([`Report::Along`]).
    pub fn along(name: &str) -> MetricDef {
        MetricDef {
            report: Report::Along,
            ..MetricDef::plain(name)
        }
    }

    /// A metric sent only explicitly ([`Report::Explicit`]).
    pub fn explicit(name: &str) -> MetricDef {
        MetricDef {
            report: Report::Explicit,
            ..MetricDef::plain(name)
        }
    }

    /// A metric with a unit and no fixed range: its deadband is `deadband_pct` of the last
    /// reported value's magnitude.
    pub fn relative(name: &str, unit: &'static str, deadband_pct: f64) -> MetricDef {
        MetricDef {
            unit: Some(unit),
            deadband: deadband_pct,
            ..MetricDef::plain(name)
        }
    }

    /// A metric with a unit and an engineering range; the deadband is `deadband_pct` of the
    /// range.
    pub fn ranged(name: &str, unit: &'static str, low: f64, high: f64, deadband_pct: f64) -> Self {
        MetricDef {
            name: name.into(),
            unit: Some(unit),
            range: Some((low, high)),
            deadband: (high - low).abs() * deadband_pct * 0.01,
            report: Report::Exception,
        }
    }

    fn properties(&self) -> Option<PropertySet> {
        if self.unit.is_none() && self.range.is_none() {
            return None;
        }
        let mut p = PropertySet::default();
        if let Some(u) = self.unit {
            p.push_str("engUnit", u);
        }
        if let Some((lo, hi)) = self.range {
            p.push_f64("engLow", lo);
            p.push_f64("engHigh", hi);
        }
        if self.deadband > 0.0 && self.range.is_some() {
            p.push_f64("deadband", self.deadband);
        }
        Some(p)
    }
}

/// The metrics of the node or of one device, and what was last reported of each.
#[derive(Debug, Clone, PartialEq)]
pub struct MetricSet {
    /// The definitions, in birth order.
    pub defs: Vec<MetricDef>,
    last: Vec<Option<Value>>,
}

impl MetricSet {
    /// A set of these definitions, nothing reported yet.
    pub fn new(defs: Vec<MetricDef>) -> MetricSet {
        let last = vec![None; defs.len()];
        MetricSet { defs, last }
    }

    /// Every metric with properties and its value (`values` in definition order); all are
    /// then reported.
    pub fn birth(&mut self, values: &[Value], ts_ms: u64) -> Vec<Metric> {
        self.defs
            .iter()
            .zip(values)
            .zip(self.last.iter_mut())
            .map(|((d, v), last)| {
                *last = Some(v.clone());
                let mut m = Metric {
                    name: Some(d.name.clone()),
                    timestamp: Some(ts_ms),
                    properties: d.properties(),
                    ..Default::default()
                };
                v.write(&mut m);
                m
            })
            .collect()
    }

    /// The metrics whose value moved beyond their deadband since last reported (by
    /// exception); those become the reported ones.
    pub fn exceptions(&mut self, values: &[Value], ts_ms: u64) -> Vec<Metric> {
        let mut out = Vec::new();
        for ((d, v), last) in self.defs.iter().zip(values).zip(self.last.iter_mut()) {
            let deadband = match (d.range, last.as_ref()) {
                (None, Some(Value::Double(b))) if b.is_finite() => b.abs() * d.deadband * 0.01,
                _ => d.deadband,
            };
            let report = d.report == Report::Exception
                && match last {
                    None => true,
                    Some(l) => v.exceeds(l, deadband),
                };
            if report {
                *last = Some(v.clone());
                let mut m = Metric {
                    name: Some(d.name.clone()),
                    timestamp: Some(ts_ms),
                    ..Default::default()
                };
                v.write(&mut m);
                out.push(m);
            }
        }
        if !out.is_empty() {
            for (k, (d, v)) in self.defs.iter().zip(values).enumerate() {
                if d.report == Report::Along {
                    self.last[k] = Some(v.clone());
                    let mut m = Metric {
                        name: Some(d.name.clone()),
                        timestamp: Some(ts_ms),
                        ..Default::default()
                    };
                    v.write(&mut m);
                    out.insert(0, m);
                }
            }
        }
        out
    }
}

/// Topic names of one edge node.
#[derive(Debug, Clone, PartialEq)]
pub struct Topics {
    group: String,
    node: String,
}

/// Why a Sparkplug identifier is unusable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("Sparkplug {what} `{id}` must be non-empty UTF-8 without `/`, `+` or `#`")]
pub struct BadId {
    /// Which identifier.
    pub what: &'static str,
    /// The identifier.
    pub id: String,
}

/// Check a group, edge node or device identifier.
pub fn check_id(what: &'static str, id: &str) -> Result<(), BadId> {
    if id.is_empty() || id.contains(['/', '+', '#']) {
        return Err(BadId {
            what,
            id: id.into(),
        });
    }
    Ok(())
}

impl Topics {
    /// Topics of edge node `node` in group `group`.
    pub fn new(group: &str, node: &str) -> Result<Topics, BadId> {
        check_id("group_id", group)?;
        check_id("edge_node_id", node)?;
        Ok(Topics {
            group: group.into(),
            node: node.into(),
        })
    }

    /// `spBv1.0/<group>/<kind>/<node>`.
    pub fn node(&self, kind: &str) -> String {
        format!("{NAMESPACE}/{}/{kind}/{}", self.group, self.node)
    }

    /// `spBv1.0/<group>/<kind>/<node>/<device>`.
    pub fn device(&self, kind: &str, device: &str) -> String {
        format!("{NAMESPACE}/{}/{kind}/{}/{device}", self.group, self.node)
    }

    /// The command topics to subscribe to: NCMD of the node, DCMD of its devices.
    pub fn commands(&self) -> [String; 2] {
        [self.node("NCMD"), self.device("DCMD", "+")]
    }

    /// What a received topic is: `(kind, device)` for this node, else None.
    pub fn parse<'a>(&self, topic: &'a str) -> Option<(&'a str, Option<&'a str>)> {
        let mut p = topic.split('/');
        if p.next()? != NAMESPACE || p.next()? != self.group {
            return None;
        }
        let kind = p.next()?;
        if p.next()? != self.node {
            return None;
        }
        let dev = p.next();
        p.next().is_none().then_some((kind, dev))
    }
}

/// The message sequence number: 0 in NBIRTH, +1 in every later NDATA/DBIRTH/DDATA/DDEATH,
/// wrapping 255 → 0.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Seq(u8);

impl Seq {
    /// The NBIRTH's (0); the next is 1.
    pub fn birth(&mut self) -> u64 {
        self.0 = 1;
        0
    }

    /// The next message's.
    pub fn take(&mut self) -> u64 {
        let s = self.0;
        self.0 = self.0.wrapping_add(1);
        u64::from(s)
    }
}

/// `bdSeq` kept across restarts in the state directory: each MQTT session (connect) takes
/// the next value, 0..255 wrapping, written before the CONNECT carrying the will so that a
/// restart never reuses the value of the death certificate the broker may still hold.
#[derive(Debug, Clone)]
pub struct BdSeqStore {
    path: PathBuf,
}

impl BdSeqStore {
    /// The file `sparkplug-bdseq` in `state_dir`.
    pub fn in_dir(state_dir: &Path) -> BdSeqStore {
        BdSeqStore {
            path: state_dir.join("sparkplug-bdseq"),
        }
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The value of the last session (None: never connected, or unreadable).
    pub fn last(&self) -> Option<u8> {
        std::fs::read_to_string(&self.path)
            .ok()?
            .trim()
            .parse::<u8>()
            .ok()
    }

    /// Take the next value (0 the first time) and keep it (write then rename).
    pub fn take_next(&self) -> std::io::Result<u8> {
        let next = self.last().map_or(0, |v| v.wrapping_add(1));
        if let Some(d) = self.path.parent() {
            std::fs::create_dir_all(d)?;
        }
        let tmp = self.path.with_extension("tmp");
        std::fs::write(&tmp, format!("{next}\n"))?;
        std::fs::rename(&tmp, &self.path)?;
        Ok(next)
    }
}

/// ms since the Unix epoch.
pub fn now_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// What a host asked for in an NCMD or DCMD.
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    /// Republish NBIRTH and every DBIRTH.
    Rebirth,
    /// An operator action: the token given and the action's words.
    Operator {
        /// The token the host sent (empty: none).
        token: String,
        /// The action.
        words: String,
    },
    /// Something this node does not accept.
    Unknown(String),
}

/// The commands in a received NCMD/DCMD payload.
pub fn commands(p: &Payload) -> Vec<Command> {
    let mut out = Vec::new();
    let mut token = String::new();
    let mut words = None;
    for m in &p.metrics {
        let name = m.name.as_deref().unwrap_or("");
        match (name, &m.value) {
            (REBIRTH, Some(MetricValue::BooleanValue(true))) => out.push(Command::Rebirth),
            (REBIRTH, _) => {}
            (OP_TOKEN, Some(MetricValue::StringValue(t))) => token = t.clone(),
            (OP_COMMAND, Some(MetricValue::StringValue(w))) => words = Some(w.clone()),
            (n, _) => out.push(Command::Unknown(n.into())),
        }
    }
    if let Some(words) = words {
        out.push(Command::Operator { token, words });
    }
    out
}

/// Whether an operator action's words are on the allow-list a host may use.
pub fn allowed(words: &str) -> bool {
    words
        .split_whitespace()
        .next()
        .is_some_and(|w| OP_ALLOWED.contains(&w))
}

/// The edge node: topics, sequence numbers, the node's metrics and its devices'.
#[derive(Debug, Clone)]
pub struct EdgeNode {
    /// Topics.
    pub topics: Topics,
    seq: Seq,
    bd_seq: u8,
    born: bool,
    node: MetricSet,
    devices: Vec<(String, MetricSet)>,
}

impl EdgeNode {
    /// A node with these node metrics (without `bdSeq` and the rebirth control, added
    /// here) and devices.
    pub fn new(
        topics: Topics,
        node_metrics: Vec<MetricDef>,
        devices: Vec<(String, Vec<MetricDef>)>,
    ) -> Result<EdgeNode, BadId> {
        for (d, _) in &devices {
            check_id("device id", d)?;
        }
        let mut defs = vec![MetricDef::plain(BD_SEQ), MetricDef::plain(REBIRTH)];
        defs.extend(node_metrics);
        Ok(EdgeNode {
            topics,
            seq: Seq::default(),
            bd_seq: 0,
            born: false,
            node: MetricSet::new(defs),
            devices: devices
                .into_iter()
                .map(|(n, d)| (n, MetricSet::new(d)))
                .collect(),
        })
    }

    /// The devices' names.
    pub fn device_names(&self) -> impl Iterator<Item = &str> {
        self.devices.iter().map(|(n, _)| n.as_str())
    }

    /// Whether NBIRTH was published in this session.
    pub fn is_born(&self) -> bool {
        self.born
    }

    /// A new MQTT session with this `bdSeq`: nothing is born until [`Self::nbirth`].
    pub fn session(&mut self, bd_seq: u8) {
        self.bd_seq = bd_seq;
        self.born = false;
    }

    /// Every node metric's value: `bdSeq`, the rebirth control (false), then `values`.
    fn node_values(&self, values: &[Value]) -> Vec<Value> {
        let mut all = vec![Value::UInt64(u64::from(self.bd_seq)), Value::Bool(false)];
        all.extend_from_slice(values);
        all
    }

    /// The NDEATH (the MQTT will of the session): `bdSeq` only, no `seq`.
    pub fn ndeath(&self) -> (String, Payload) {
        let ts = now_ms();
        let mut m = Metric {
            name: Some(BD_SEQ.into()),
            timestamp: Some(ts),
            ..Default::default()
        };
        Value::UInt64(u64::from(self.bd_seq)).write(&mut m);
        (
            self.topics.node("NDEATH"),
            Payload {
                timestamp: Some(ts),
                metrics: vec![m],
                ..Default::default()
            },
        )
    }

    /// NBIRTH (seq 0, `bdSeq` of the session, every node metric with its properties);
    /// `values` are the node metrics after `bdSeq` and the rebirth control.
    pub fn nbirth(&mut self, values: &[Value]) -> (String, Payload) {
        let ts = now_ms();
        let all = self.node_values(values);
        let metrics = self.node.birth(&all, ts);
        self.born = true;
        (
            self.topics.node("NBIRTH"),
            sequenced(ts, metrics, self.seq.birth()),
        )
    }

    /// DBIRTH of device `i`.
    pub fn dbirth(&mut self, i: usize, values: &[Value]) -> Option<(String, Payload)> {
        let ts = now_ms();
        let (name, set) = self.devices.get_mut(i)?;
        let metrics = set.birth(values, ts);
        Some((
            self.topics.device("DBIRTH", name),
            sequenced(ts, metrics, self.seq.take()),
        ))
    }

    /// NDATA by exception (None: nothing moved beyond its deadband).
    pub fn ndata(&mut self, values: &[Value]) -> Option<(String, Payload)> {
        let ts = now_ms();
        let all = self.node_values(values);
        let metrics = self.node.exceptions(&all, ts);
        (!metrics.is_empty()).then(|| {
            (
                self.topics.node("NDATA"),
                sequenced(ts, metrics, self.seq.take()),
            )
        })
    }

    /// DDATA of device `i` by exception (with its [`Report::Along`] metrics).
    pub fn ddata(&mut self, i: usize, values: &[Value]) -> Option<(String, Payload)> {
        let ts = now_ms();
        let (name, set) = self.devices.get_mut(i)?;
        let metrics = set.exceptions(values, ts);
        if metrics.is_empty() {
            return None;
        }
        Some((
            self.topics.device("DDATA", name),
            sequenced(ts, metrics, self.seq.take()),
        ))
    }

    /// An NDATA of these metrics as they are (events: not by exception), `historical` when
    /// replayed from the store-and-forward queue.
    pub fn ndata_of(
        &mut self,
        metrics: Vec<(String, Value, u64)>,
        historical: bool,
    ) -> (String, Payload) {
        let ts = now_ms();
        let metrics = metrics
            .into_iter()
            .map(|(name, v, t)| {
                let mut m = Metric {
                    name: Some(name),
                    timestamp: Some(t),
                    is_historical: historical.then_some(true),
                    ..Default::default()
                };
                v.write(&mut m);
                m
            })
            .collect();
        (
            self.topics.node("NDATA"),
            sequenced(ts, metrics, self.seq.take()),
        )
    }
}

/// A payload at `ts` with `metrics` and its sequence number.
fn sequenced(ts: u64, metrics: Vec<Metric>, seq: u64) -> Payload {
    Payload {
        timestamp: Some(ts),
        metrics,
        seq: Some(seq),
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;

    fn node() -> EdgeNode {
        EdgeNode::new(
            Topics::new("Plant1", "skid-7").expect("ids"),
            vec![MetricDef::plain("Cycles")],
            vec![(
                "compressor".into(),
                vec![
                    MetricDef::along("Cycle"),
                    MetricDef::ranged("Deviation", "%", -50.0, 50.0, 1.0),
                    MetricDef::plain("Mode"),
                ],
            )],
        )
        .expect("node")
    }

    fn dev(cycle: u64, dev: f64, mode: &str) -> Vec<Value> {
        vec![
            Value::UInt64(cycle),
            Value::Double(dev),
            Value::Str(mode.into()),
        ]
    }

    #[test]
    fn payloads_round_trip_through_protobuf() {
        let mut n = node();
        n.session(7);
        let (topic, p) = n.nbirth(&[Value::UInt64(3)]);
        assert_eq!(topic, "spBv1.0/Plant1/NBIRTH/skid-7");
        let back = Payload::decode(p.encode_to_vec().as_slice()).expect("decode");
        assert_eq!(back, p);
        assert_eq!(back.seq, Some(0));
        let bd = &back.metrics[0];
        assert_eq!(bd.name.as_deref(), Some("bdSeq"));
        assert_eq!(bd.datatype, Some(datatype::UINT64));
        assert_eq!(bd.value, Some(MetricValue::LongValue(7)));
        let (topic, p) = n.dbirth(0, &dev(10, 12.5, "auto")).expect("device");
        assert_eq!(topic, "spBv1.0/Plant1/DBIRTH/skid-7/compressor");
        let back = Payload::decode(p.encode_to_vec().as_slice()).expect("decode");
        assert_eq!(back.seq, Some(1));
        let d = &back.metrics[1];
        assert_eq!(d.value, Some(MetricValue::DoubleValue(12.5)));
        let props = d.properties.as_ref().expect("properties");
        assert_eq!(
            props.get("engUnit").and_then(|v| v.value.clone()),
            Some(super::super::proto::PropertyValueKind::StringValue(
                "%".into()
            ))
        );
        assert_eq!(
            props.get("engHigh").and_then(|v| v.value.clone()),
            Some(super::super::proto::PropertyValueKind::DoubleValue(50.0))
        );
        // a NaN is a null, typed
        let (_, p) = n.ddata(0, &dev(11, f64::NAN, "auto")).expect("null sent");
        let back = Payload::decode(p.encode_to_vec().as_slice()).expect("decode");
        let d = back
            .metrics
            .iter()
            .find(|m| m.name.as_deref() == Some("Deviation"));
        let d = d.expect("deviation");
        assert_eq!(
            (d.is_null, d.datatype, &d.value),
            (Some(true), Some(datatype::DOUBLE), &None)
        );
        let (topic, death) = n.ndeath();
        assert_eq!(topic, "spBv1.0/Plant1/NDEATH/skid-7");
        assert_eq!(death.seq, None);
        assert_eq!(death.metrics[0].value, Some(MetricValue::LongValue(7)));
    }

    #[test]
    fn data_by_exception_with_deadband_and_the_cycle_alongside() {
        let mut n = node();
        n.session(0);
        n.nbirth(&[Value::UInt64(0)]);
        n.dbirth(0, &dev(1, 10.0, "auto"));
        // deadband: 1 % of 100 % span = 1.0; the cycle alone does not make a message
        assert!(n.ddata(0, &dev(2, 10.9, "auto")).is_none());
        let (_, p) = n
            .ddata(0, &dev(3, 11.2, "auto"))
            .expect("beyond the deadband");
        let names: Vec<_> = p.metrics.iter().filter_map(|m| m.name.clone()).collect();
        assert_eq!(names, ["Cycle", "Deviation"]);
        assert_eq!(p.metrics[0].value, Some(MetricValue::LongValue(3)));
        // measured against the last reported value, not the last seen: no creep
        assert!(n.ddata(0, &dev(4, 12.1, "auto")).is_none());
        assert!(n.ddata(0, &dev(5, 12.3, "auto")).is_some());
        // strings report on any change
        let (_, p) = n.ddata(0, &dev(6, 12.3, "manual")).expect("mode");
        assert_eq!(p.metrics[1].name.as_deref(), Some("Mode"));
        // node data likewise; bdSeq and the rebirth control never change within a session
        assert!(n.ndata(&[Value::UInt64(0)]).is_none());
        let (t, p) = n.ndata(&[Value::UInt64(9)]).expect("changed");
        assert_eq!(t, "spBv1.0/Plant1/NDATA/skid-7");
        assert_eq!(p.metrics.len(), 1);
    }

    #[test]
    fn seq_starts_at_zero_in_nbirth_counts_every_message_and_wraps() {
        let mut n = node();
        n.session(1);
        let mut seqs = vec![n.nbirth(&[Value::UInt64(0)]).1.seq];
        seqs.push(n.dbirth(0, &dev(0, 0.0, "a")).expect("d").1.seq);
        for k in 1..300u64 {
            let (_, p) = n.ddata(0, &dev(k, k as f64 * 10.0, "a")).expect("moves");
            seqs.push(p.seq);
        }
        let seqs: Vec<u64> = seqs.into_iter().map(|s| s.expect("seq")).collect();
        assert_eq!(seqs[..3], [0, 1, 2]);
        for w in seqs.windows(2) {
            assert_eq!(w[1], (w[0] + 1) % 256, "{w:?}");
        }
        assert!(seqs.contains(&255));
        // a rebirth restarts at 0 with the same bdSeq, and the DBIRTH follows with 1
        let (_, p) = n.nbirth(&[Value::UInt64(0)]);
        assert_eq!(
            (p.seq, &p.metrics[0].value),
            (Some(0), &Some(MetricValue::LongValue(1)))
        );
        let (_, p) = n.dbirth(0, &dev(7, 0.0, "a")).expect("device");
        assert_eq!(p.seq, Some(1));
        // the birth values are the reported ones: the same values make no DDATA
        assert!(n.ddata(0, &dev(8, 0.0, "a")).is_none());
    }

    #[test]
    fn explicit_metrics_never_go_by_exception_and_rangeless_deadbands_are_relative() {
        let mut set = MetricSet::new(vec![
            MetricDef::relative("Mass Flow", "kg/s", 1.0),
            MetricDef::explicit("Events/Kind"),
        ]);
        let v = |m: f64, k: &str| vec![Value::Double(m), Value::Str(k.into())];
        set.birth(&v(10.0, ""), 0);
        // 1 % of the last reported 10 kg/s: 0.1
        assert!(set.exceptions(&v(10.09, "surge"), 0).is_empty());
        let m = set.exceptions(&v(10.11, "surge"), 0);
        assert_eq!(m.len(), 1);
        assert_eq!(m[0].name.as_deref(), Some("Mass Flow"));
        // null and back count as changes
        assert_eq!(set.exceptions(&v(f64::NAN, ""), 0).len(), 1);
        assert_eq!(set.exceptions(&v(10.11, ""), 0).len(), 1);
        // an explicit NDATA is numbered like the others and may be historical
        let mut n = node();
        n.session(0);
        n.nbirth(&[Value::UInt64(0)]);
        let (_, p) = n.ndata_of(
            vec![("Events/Kind".into(), Value::Str("x".into()), 5)],
            true,
        );
        assert_eq!(
            (p.seq, p.metrics[0].is_historical, p.metrics[0].timestamp),
            (Some(1), Some(true), Some(5))
        );
    }

    #[test]
    fn bd_seq_is_kept_across_restarts_and_wraps() {
        let dir = tempfile::tempdir().expect("tmp");
        let s = BdSeqStore::in_dir(&dir.path().join("state"));
        assert_eq!(s.last(), None);
        assert_eq!(s.take_next().expect("write"), 0);
        assert_eq!(s.take_next().expect("write"), 1);
        // a new process reads the same file
        let again = BdSeqStore::in_dir(&dir.path().join("state"));
        assert_eq!(again.last(), Some(1));
        assert_eq!(again.take_next().expect("write"), 2);
        std::fs::write(again.path(), "255\n").expect("write");
        assert_eq!(again.take_next().expect("write"), 0);
    }

    #[test]
    fn commands_rebirth_and_operator_actions() {
        let t = Topics::new("G", "N").expect("ids");
        assert_eq!(t.parse("spBv1.0/G/NCMD/N"), Some(("NCMD", None)));
        assert_eq!(
            t.parse("spBv1.0/G/DCMD/N/compressor"),
            Some(("DCMD", Some("compressor")))
        );
        assert_eq!(t.parse("spBv1.0/G/DCMD/other/compressor"), None);
        assert_eq!(t.commands(), ["spBv1.0/G/NCMD/N", "spBv1.0/G/DCMD/N/+"]);
        assert!(Topics::new("a/b", "N").is_err() && Topics::new("G", "#").is_err());
        let metric = |n: &str, v: MetricValue| Metric {
            name: Some(n.into()),
            value: Some(v),
            ..Default::default()
        };
        let p = Payload {
            metrics: vec![
                metric(REBIRTH, MetricValue::BooleanValue(true)),
                metric(OP_TOKEN, MetricValue::StringValue("t0k".into())),
                metric(OP_COMMAND, MetricValue::StringValue("manual 20".into())),
                metric("Valve/Command", MetricValue::DoubleValue(1.0)),
            ],
            ..Default::default()
        };
        let c = commands(&Payload::decode(p.encode_to_vec().as_slice()).expect("decode"));
        assert_eq!(
            c,
            [
                Command::Rebirth,
                Command::Unknown("Valve/Command".into()),
                Command::Operator {
                    token: "t0k".into(),
                    words: "manual 20".into()
                }
            ]
        );
        assert!(allowed("auto") && allowed("manual 20") && allowed("output 5") && allowed("ack"));
        assert!(!allowed("reset-surge-counter") && !allowed("") && !allowed("open-all"));
    }
}
