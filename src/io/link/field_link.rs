//! The one face every field link shows the rest of the daemon ([`FieldLink`]): its kind and
//! name, its state in the one vocabulary ([`LinkState`](super::LinkState)), its traffic in the
//! one counters type ([`LinkTraffic`]) and its transport's own counters. The status, the HMI's
//! link lamps and the metrics read links through it and know no transport.

use super::LinkTraffic;
use crate::vocab::faults::FieldLinkKind;

/// A running field link, as the status and the metrics see it (see the module documentation).
/// Reading it never blocks the link's task: states come from a watch channel, counters from
/// relaxed atomics.
pub trait FieldLink: Send + Sync {
    /// Which kind of link (what roots a stale input's cause).
    fn kind(&self) -> FieldLinkKind;
    /// Its name in events, the status and the metrics (`can:can0`, `modbus:10.0.0.5:502`).
    fn name(&self) -> &str;
    /// Its state's name in the status ([`LinkState::status_name`](super::LinkState::status_name)).
    fn status_name(&self) -> &'static str;
    /// Whether it passes traffic now ([`LinkState::is_up`](super::LinkState::is_up)).
    fn is_up(&self) -> bool;
    /// Its traffic in the one counters type.
    fn traffic(&self) -> LinkTraffic;
    /// Its transport's own counters, for the statistics (a JSON object).
    fn counters_json(&self) -> serde_json::Value;

    /// The status's view of the link: its transport's counters, with `name`, `state` and
    /// `traffic` beside them.
    fn to_json(&self) -> serde_json::Value {
        let mut v = self.counters_json();
        if let Some(o) = v.as_object_mut() {
            o.insert("name".into(), self.name().into());
            o.insert("state".into(), self.status_name().into());
            o.insert(
                "traffic".into(),
                serde_json::to_value(self.traffic()).unwrap_or_default(),
            );
        }
        v
    }
}

/// The links a daemon runs (none, one per transport), for the status and the statistics.
#[derive(Clone, Default)]
pub struct FieldLinks(Vec<std::sync::Arc<dyn FieldLink>>);

impl FieldLinks {
    /// Add a link.
    pub fn push(&mut self, link: std::sync::Arc<dyn FieldLink>) {
        self.0.push(link);
    }

    /// The links, in the order they started.
    pub fn iter(&self) -> impl Iterator<Item = &std::sync::Arc<dyn FieldLink>> {
        self.0.iter()
    }

    /// The status's `links` object: each link under its kind (`can`, `modbus`; `null` for a
    /// kind the daemon does not run), and `feedback`, the actuators whose feedback is supervised.
    pub fn to_json(&self, feedback: &[&'static str]) -> serde_json::Value {
        let mut o = serde_json::Map::new();
        o.insert("feedback".into(), serde_json::json!(feedback));
        for kind in FieldLinkKind::ALL {
            let link = self.0.iter().find(|l| l.kind() == kind);
            o.insert(
                kind.name().to_ascii_lowercase(),
                link.map_or(serde_json::Value::Null, |l| l.to_json()),
            );
        }
        serde_json::Value::Object(o)
    }
}

impl std::fmt::Debug for FieldLinks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list()
            .entries(self.0.iter().map(|l| (l.name(), l.status_name())))
            .finish()
    }
}
