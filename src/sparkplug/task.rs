//! The edge node's task: an ordinary tokio task (never the control thread) that reads the
//! same lock-free snapshot as the status socket and the metrics endpoint, publishes births,
//! data by exception and events to the broker with `rumqttc`, keeps events in the
//! store-and-forward queue while the broker is away, and answers the host's commands.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use prost::Message;
use rumqttc::{
    AsyncClient, Event as MqttEvent, EventLoop, LastWill, MqttOptions, Outgoing, Packet, QoS,
    TlsConfiguration, Transport,
};
use tokio::sync::watch;
use tokio_rustls::rustls;

use super::catalogue::{self, Deadbands, Ranges, COMPRESSOR, OP_RESULT};
use super::edge::{self, BdSeqStore, Command, EdgeNode, MetricDef, Topics, Value};
use super::forward::{HostEvent, LogFollower, Spool};
use super::proto::Payload;
use super::settings::SparkplugSection;
use crate::events::event::Event;
use crate::live::server::{LiveContext, SERVED_KEPT};

/// Event NDATAs in flight (published, not yet acknowledged) at most.
const MAX_INFLIGHT_EVENTS: usize = 64;

/// What the node reads.
pub struct EdgeInputs {
    /// The operator services' context: snapshot, statistics, links, event sender, token.
    pub ctx: LiveContext,
    /// Engineering ranges of the map coordinates.
    pub ranges: Ranges,
    /// The state directory (`bdSeq`, store-and-forward queue).
    pub state_dir: PathBuf,
    /// The event log followed for events.
    pub events_path: PathBuf,
}

/// Why the node cannot start.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    /// A bad identifier.
    #[error(transparent)]
    Id(#[from] edge::BadId),
    /// A bad key.
    #[error("{0}")]
    Config(String),
    /// The bdSeq file.
    #[error("cannot keep bdSeq in {0}: {1}")]
    BdSeq(PathBuf, std::io::Error),
}

/// The CA certificates in a PEM file, as rustls roots.
pub fn ca_roots(file: &Path) -> Result<rustls::RootCertStore, String> {
    use rustls_pki_types::pem::PemObject;
    use rustls_pki_types::CertificateDer;
    let mut roots = rustls::RootCertStore::empty();
    let certs = CertificateDer::pem_file_iter(file)
        .map_err(|e| format!("cannot read {}: {e}", file.display()))?;
    for c in certs {
        let c = c.map_err(|e| format!("{}: {e}", file.display()))?;
        roots
            .add(c)
            .map_err(|e| format!("{}: {e}", file.display()))?;
    }
    if roots.is_empty() {
        return Err(format!("no certificate in {}", file.display()));
    }
    Ok(roots)
}

fn mqtt_options(cfg: &SparkplugSection, will: (String, Payload)) -> Result<MqttOptions, String> {
    let (host, port) = cfg.broker_host_port()?;
    let id = cfg
        .client_id
        .clone()
        .unwrap_or_else(|| format!("antisurge-{}-{}", cfg.group_id, cfg.edge_node_id));
    let mut o = MqttOptions::new(id, host, port);
    o.set_keep_alive(Duration::from_secs(u64::from(cfg.keep_alive_s.max(1))));
    o.set_clean_session(true);
    o.set_max_packet_size(1 << 20, 1 << 20);
    o.set_last_will(last_will(will));
    if let Some(user) = &cfg.username {
        let password = match &cfg.password_file {
            Some(f) => {
                if let Some(why) = crate::live::tls_settings::token_file_problem(f) {
                    return Err(format!("broker password: {why}"));
                }
                std::fs::read_to_string(f)
                    .map_err(|e| format!("cannot read {}: {e}", f.display()))?
                    .lines()
                    .next()
                    .unwrap_or("")
                    .trim()
                    .to_string()
            }
            None => String::new(),
        };
        o.set_credentials(user.clone(), password);
    }
    if let Some(ca) = &cfg.ca_file {
        let provider = Arc::new(rustls::crypto::ring::default_provider());
        let tls = rustls::ClientConfig::builder_with_provider(provider)
            .with_safe_default_protocol_versions()
            .map_err(|e| e.to_string())?
            .with_root_certificates(ca_roots(ca)?)
            .with_no_client_auth();
        o.set_transport(Transport::tls_with_config(TlsConfiguration::Rustls(
            Arc::new(tls),
        )));
    }
    Ok(o)
}

fn last_will((topic, p): (String, Payload)) -> LastWill {
    LastWill::new(topic, p.encode_to_vec(), QoS::AtLeastOnce, false)
}

/// Start the node on `tasks` (the caller logs the error and the controller runs on).
pub fn spawn(
    cfg: &SparkplugSection,
    inputs: EdgeInputs,
    shutdown: watch::Receiver<bool>,
    tasks: &mut tokio::task::JoinSet<()>,
) -> Result<(), StartError> {
    let node = Node::new(cfg, inputs)?;
    tracing::info!(target: "sparkplug", "Sparkplug B edge node {} on {} (bdSeq {}, commands {})",
        node.node.topics.node("NBIRTH"), cfg.broker, node.bd_seq,
        if cfg.commands_enabled { "enabled" } else { "refused" });
    let (client, el) = AsyncClient::new(
        mqtt_options(cfg, node.node.ndeath()).map_err(StartError::Config)?,
        4096,
    );
    let (tx, rx) = tokio::sync::mpsc::channel(1024);
    let (finish_tx, finish_rx) = tokio::sync::oneshot::channel();
    tasks.spawn(poll(el, tx, finish_rx));
    tasks.spawn(node.run(client, rx, finish_tx, shutdown));
    Ok(())
}

/// What the connection task reports.
enum Polled {
    /// An MQTT event.
    Event(MqttEvent),
    /// The connection is lost (or could not be made): the node answers with the will of the
    /// next attempt (None: the same), then the connection task retries after a second.
    Lost(String, tokio::sync::oneshot::Sender<Option<LastWill>>),
}

/// The connection task: owns the event loop and polls it without ever cancelling a poll (a
/// poll dropped mid-connect would drop the connection and fire the will).
async fn poll(
    mut el: EventLoop,
    tx: tokio::sync::mpsc::Sender<Polled>,
    mut finish: tokio::sync::oneshot::Receiver<()>,
) {
    loop {
        let r = tokio::select! {
            r = el.poll() => r,
            _ = &mut finish => return,
        };
        match r {
            Ok(ev) => {
                if tx.send(Polled::Event(ev)).await.is_err() {
                    return;
                }
            }
            Err(e) => {
                // nothing of the old session is sent in the new one: its seq numbers are gone
                el.clean();
                el.pending.clear();
                let (wtx, wrx) = tokio::sync::oneshot::channel();
                if tx.send(Polled::Lost(e.to_string(), wtx)).await.is_err() {
                    return;
                }
                match wrx.await {
                    Ok(Some(w)) => {
                        el.mqtt_options.set_last_will(w);
                    }
                    Ok(None) => {}
                    Err(_) => return,
                }
                tokio::select! {
                    _ = tokio::time::sleep(Duration::from_secs(1)) => {}
                    _ = &mut finish => return,
                }
            }
        }
    }
}

/// The running node.
struct Node {
    cfg: SparkplugSection,
    inputs: EdgeInputs,
    node: EdgeNode,
    store: BdSeqStore,
    bd_seq: u8,
    /// Link devices: (device index, counter names).
    links: Vec<(usize, Vec<String>)>,
    spool: Spool,
    follower: LogFollower,
    inflight: VecDeque<(Option<u16>, HostEvent)>,
    acked_path: PathBuf,
    connected_at_ms: Option<u64>,
    op_result: String,
    last_event: Option<HostEvent>,
    warned: bool,
}

impl Node {
    /// The `k`-th link device's index and values from the links' state `now`
    /// ([`catalogue::link_devices`]); a link missing from it reports nothing.
    fn link_device_values(
        &self,
        k: usize,
        now: &[(String, Vec<(String, Value)>)],
    ) -> (usize, Vec<Value>) {
        let (i, names) = &self.links[k];
        let dev = self.node.device_names().nth(*i).unwrap_or("");
        let cur = now
            .iter()
            .find(|(n, _)| n == dev)
            .map(|d| d.1.as_slice())
            .unwrap_or(&[]);
        (*i, catalogue::link_values(names, cur))
    }

    fn new(cfg: &SparkplugSection, inputs: EdgeInputs) -> Result<Node, StartError> {
        let topics = Topics::new(&cfg.group_id, &cfg.edge_node_id)?;
        let db = Deadbands {
            default_pct: cfg.deadband_pct,
            by_name: cfg.deadbands_pct.clone(),
        };
        let mut devices = vec![(
            COMPRESSOR.to_string(),
            catalogue::compressor_metrics(&inputs.ranges, &db),
        )];
        let mut links = Vec::new();
        for (name, counters) in catalogue::link_devices(&(inputs.ctx.links)()) {
            let defs: Vec<MetricDef> = counters
                .iter()
                .map(|(n, v)| match v {
                    Value::Double(_) => MetricDef::relative(n, "1", cfg.deadband_pct),
                    _ => MetricDef::plain(n),
                })
                .collect();
            links.push((
                devices.len(),
                counters.into_iter().map(|(n, _)| n).collect(),
            ));
            devices.push((name, defs));
        }
        let mut node = EdgeNode::new(topics, catalogue::node_metrics(&db), devices)?;
        let store = BdSeqStore::in_dir(&inputs.state_dir);
        let bd_seq = store
            .take_next()
            .map_err(|e| StartError::BdSeq(store.path().to_path_buf(), e))?;
        node.session(bd_seq);
        let spool = Spool::open(&inputs.state_dir, cfg.store_forward_events);
        let acked_path = inputs.state_dir.join("sparkplug-events-acked");
        let acked = std::fs::read_to_string(&acked_path)
            .ok()
            .and_then(|t| t.trim().parse::<u64>().ok());
        let after = match (spool.last_seq(), acked) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        };
        let follower = LogFollower::new(&inputs.events_path, after);
        Ok(Node {
            cfg: cfg.clone(),
            inputs,
            node,
            store,
            bd_seq,
            links,
            spool,
            follower,
            inflight: VecDeque::new(),
            acked_path,
            connected_at_ms: None,
            op_result: String::new(),
            last_event: None,
            warned: false,
        })
    }

    async fn run(
        mut self,
        client: AsyncClient,
        mut rx: tokio::sync::mpsc::Receiver<Polled>,
        finish: tokio::sync::oneshot::Sender<()>,
        mut shutdown: watch::Receiver<bool>,
    ) {
        let mut ticker = tokio::time::interval(Duration::from_millis(self.cfg.publish_interval_ms));
        ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        loop {
            tokio::select! {
                r = shutdown.changed() => {
                    if r.is_err() || *shutdown.borrow() {
                        self.stop(&client, &mut rx).await;
                        let _ = finish.send(());
                        return;
                    }
                }
                p = rx.recv() => match p {
                    Some(Polled::Event(ev)) => self.on_event(&client, ev),
                    Some(Polled::Lost(why, answer)) => {
                        let will = self.on_lost(&why);
                        let _ = answer.send(will);
                    }
                    None => return,
                },
                _ = ticker.tick() => self.on_tick(&client),
            }
        }
    }

    /// A clean stop: the death certificate ourselves (the broker drops the will on a clean
    /// DISCONNECT), then disconnect.
    async fn stop(&mut self, client: &AsyncClient, rx: &mut tokio::sync::mpsc::Receiver<Polled>) {
        // the events in flight: their acknowledgements, for a second at most
        let _ = tokio::time::timeout(Duration::from_secs(1), async {
            while self.connected_at_ms.is_some() && !self.inflight.is_empty() {
                match rx.recv().await {
                    Some(Polled::Event(ev)) => self.on_event(client, ev),
                    Some(Polled::Lost(why, answer)) => {
                        let _ = answer.send(self.on_lost(&why));
                    }
                    None => break,
                }
            }
        })
        .await;
        self.requeue_inflight();
        let _ = self.spool.sync();
        if self.connected_at_ms.is_none() {
            return;
        }
        let (t, p) = self.node.ndeath();
        let _ = client.try_publish(t, QoS::AtLeastOnce, false, p.encode_to_vec());
        let _ = client.try_disconnect();
        let _ = tokio::time::timeout(Duration::from_secs(2), async {
            while let Some(p) = rx.recv().await {
                match p {
                    Polled::Event(MqttEvent::Outgoing(Outgoing::Disconnect)) | Polled::Lost(..) => {
                        break
                    }
                    _ => {}
                }
            }
        })
        .await;
        tracing::info!(target: "sparkplug", "NDEATH published, disconnected from {}", self.cfg.broker);
    }

    /// The connection is lost: events in flight back to the queue; a new bdSeq (and will)
    /// if a session had been established with the current one.
    fn on_lost(&mut self, why: &str) -> Option<LastWill> {
        let was_connected = self.connected_at_ms.take().is_some();
        if was_connected || !self.warned {
            tracing::warn!(target: "sparkplug", "broker {}: {why}; events are kept ({} queued) and replayed on reconnect", self.cfg.broker, self.spool.len() + self.inflight.len());
            self.warned = true;
        }
        self.requeue_inflight();
        let _ = self.spool.sync();
        if !was_connected {
            // no session was established with this bdSeq: the next attempt keeps it
            return None;
        }
        // each session has its own bdSeq, in its will and its NBIRTH
        match self.store.take_next() {
            Ok(b) => self.bd_seq = b,
            Err(e) => {
                tracing::error!(target: "sparkplug", "cannot keep bdSeq in {}: {e}", self.store.path().display());
                self.bd_seq = self.bd_seq.wrapping_add(1);
            }
        }
        self.node.session(self.bd_seq);
        Some(last_will(self.node.ndeath()))
    }

    fn requeue_inflight(&mut self) {
        let back: Vec<HostEvent> = self.inflight.drain(..).map(|(_, e)| e).collect();
        if !back.is_empty() {
            self.spool.requeue_front(back);
        }
    }

    fn publish(&self, client: &AsyncClient, (topic, p): (String, Payload), qos: QoS) -> bool {
        match client.try_publish(topic, qos, false, p.encode_to_vec()) {
            Ok(()) => true,
            Err(e) => {
                tracing::warn!(target: "sparkplug", "publish not queued: {e}");
                false
            }
        }
    }

    fn on_event(&mut self, client: &AsyncClient, ev: MqttEvent) {
        match ev {
            MqttEvent::Incoming(Packet::ConnAck(_)) => {
                self.connected_at_ms = Some(edge::now_ms());
                self.warned = false;
                tracing::info!(target: "sparkplug", "connected to {} (bdSeq {})", self.cfg.broker, self.bd_seq);
                for t in self.node.topics.commands() {
                    let _ = client.try_subscribe(t, QoS::AtLeastOnce);
                }
                self.births(client);
                self.send_events(client);
            }
            MqttEvent::Incoming(Packet::Publish(p)) => {
                self.on_command(client, &p.topic, &p.payload)
            }
            MqttEvent::Outgoing(Outgoing::Publish(pkid)) if pkid != 0 => {
                if let Some(slot) = self.inflight.iter_mut().find(|(k, _)| k.is_none()) {
                    slot.0 = Some(pkid);
                }
            }
            MqttEvent::Incoming(Packet::PubAck(a)) => {
                if let Some(i) = self.inflight.iter().position(|(k, _)| *k == Some(a.pkid)) {
                    if let Some((_, e)) = self.inflight.remove(i) {
                        let _ = std::fs::write(&self.acked_path, format!("{}\n", e.seq));
                    }
                }
            }
            _ => {}
        }
    }

    fn births(&mut self, client: &AsyncClient) {
        let c = &self.inputs.ctx;
        let nv = catalogue::node_values(
            &c.stats.report(),
            self.spool.dropped,
            self.last_event.as_ref(),
            &self.op_result,
        );
        let b = self.node.nbirth(&nv);
        self.publish(client, b, QoS::AtMostOnce);
        let snap = c.live.latest().unwrap_or_default();
        if let Some(b) = self.node.dbirth(0, &catalogue::compressor_values(&snap)) {
            self.publish(client, b, QoS::AtMostOnce);
        }
        let now = catalogue::link_devices(&(c.links)());
        for k in 0..self.links.len() {
            let (i, vals) = self.link_device_values(k, &now);
            if let Some(b) = self.node.dbirth(i, &vals) {
                self.publish(client, b, QoS::AtMostOnce);
            }
        }
    }

    fn send_events(&mut self, client: &AsyncClient) {
        let Some(since) = self.connected_at_ms else {
            return;
        };
        if !self.node.is_born() {
            return;
        }
        while self.inflight.len() < MAX_INFLIGHT_EVENTS {
            let Some(e) = self.spool.pop() else { break };
            let historical = e.ts_ms < since;
            let msg = self.node.ndata_of(catalogue::event_metrics(&e), historical);
            if !self.publish(client, msg, QoS::AtLeastOnce) {
                self.spool.requeue_front(vec![e]);
                break;
            }
            self.last_event = Some(e.clone());
            self.inflight.push_back((None, e));
        }
    }

    fn on_tick(&mut self, client: &AsyncClient) {
        for e in self.follower.poll() {
            self.spool.push(e);
        }
        if self.connected_at_ms.is_some() && self.node.is_born() {
            self.send_events(client);
            let c = self.inputs.ctx.clone();
            if let Some(s) = c.live.latest() {
                if let Some(m) = self.node.ddata(0, &catalogue::compressor_values(&s)) {
                    if self.publish(client, m, QoS::AtMostOnce) {
                        // the host may ask `antisurge status --cycle N` for the same snapshot
                        if let Ok(mut q) = c.served.lock() {
                            if q.back().map(|b| b.cycle) != Some(s.cycle) {
                                if q.len() == SERVED_KEPT {
                                    q.pop_front();
                                }
                                q.push_back(s);
                            }
                        }
                    }
                }
            }
            let nv = catalogue::node_values(
                &c.stats.report(),
                self.spool.dropped,
                self.last_event.as_ref(),
                &self.op_result,
            );
            if let Some(m) = self.node.ndata(&nv) {
                self.publish(client, m, QoS::AtMostOnce);
            }
            if !self.links.is_empty() {
                let now = catalogue::link_devices(&(c.links)());
                for k in 0..self.links.len() {
                    let (i, vals) = self.link_device_values(k, &now);
                    if let Some(m) = self.node.ddata(i, &vals) {
                        self.publish(client, m, QoS::AtMostOnce);
                    }
                }
            }
        }
        if let Err(e) = self.spool.sync() {
            tracing::warn!(target: "sparkplug", "store-and-forward queue not written: {e}");
        }
    }

    fn on_command(&mut self, client: &AsyncClient, topic: &str, body: &[u8]) {
        let Some((kind, device)) = self.node.topics.parse(topic) else {
            return;
        };
        let known_device = device.is_none_or(|d| self.node.device_names().any(|n| n == d));
        if !matches!((kind, device), ("NCMD", None) | ("DCMD", Some(_))) || !known_device {
            return;
        }
        let p = match Payload::decode(body) {
            Ok(p) => p,
            Err(e) => {
                tracing::warn!(target: "sparkplug", "{kind} on {topic}: not a Sparkplug B payload ({e})");
                return;
            }
        };
        for cmd in edge::commands(&p) {
            match cmd {
                Command::Rebirth => {
                    tracing::info!(target: "sparkplug", "rebirth asked by the host ({kind})");
                    self.births(client);
                }
                Command::Operator { token, words } => {
                    let result = self.operate(kind, &token, &words);
                    self.op_result = result.clone();
                    if self.node.is_born() {
                        let m = self.node.ndata_of(
                            vec![(OP_RESULT.into(), Value::Str(result), edge::now_ms())],
                            false,
                        );
                        self.publish(client, m, QoS::AtMostOnce);
                    }
                }
                Command::Unknown(name) => {
                    tracing::warn!(target: "sparkplug", "{kind}: metric `{name}` is not writable; ignored")
                }
            }
        }
    }

    /// An operator action from the host: refused unless commands are enabled, the action is
    /// on the HMI's allow-list and the token is right; recorded in the event log either way.
    fn operate(&self, kind: &str, token: &str, words: &str) -> String {
        let ctx = &self.inputs.ctx;
        let refuse = |why: String| {
            let text = format!("Sparkplug {kind} `{words}` refused: {why}");
            tracing::warn!(target: "operator", "{text}");
            let _ = ctx.events.send(Event::Note { text: text.clone() });
            text
        };
        if !self.cfg.commands_enabled {
            return refuse("commands are disabled ([sparkplug] commands_enabled = false)".into());
        }
        if !edge::allowed(words) {
            return refuse(format!(
                "not on the allow-list ({})",
                edge::OP_ALLOWED.join(", ")
            ));
        }
        let w: Vec<&str> = words.split_whitespace().collect();
        match ctx.operate(token, &w, &format!("Sparkplug {kind}")) {
            Ok(what) => format!("done: {what}"),
            Err(e) => refuse(e.to_string()),
        }
    }
}
