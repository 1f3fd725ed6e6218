//! The field-bus tasks of both nodes, started from the signal map: a CAN task when the map
//! binds CAN signals, a Modbus task when it binds registers. The tasks never decide
//! fail-safe: when a link is down nothing is published and the control thread's freshness
//! checks take the machine to its safe state.

use super::config::Loaded;
use crate::events::event::BusState;
use crate::events::event::Event;
use crate::events::EventSender;
use crate::io::can::bus::{
    run_controller as can_controller, run_plant as can_plant, BusCodec, BusHandles,
    ControllerBoards, PlantBoards,
};
use crate::io::feedback::FeedbackSupervisor;
use crate::io::link::{EventSink, FieldLinkReporter, LinkReports};
use crate::io::modbus::{
    run_controller_triggering as modbus_controller, run_plant_server, LinkMonitor, LinkState,
    ModbusLinkConfig, Pacing, TransportConfig, WriteHealth,
};
use crate::runtime::handoff::{
    CommandBoard, HeartbeatBoard, OutputBoard, SensorBoard, SnapshotBoard, Wakeup,
};
use crate::vocab::faults::FaultCategory;
use crate::vocab::signals::ActuatorId;
use anyhow::{anyhow, Context, Result};
use std::sync::Arc;
use tokio::sync::watch;
use tokio::task::JoinSet;

async fn until_true(mut rx: watch::Receiver<bool>) {
    let _ = rx.wait_for(|s| *s).await;
}

fn can_codec(l: &Loaded) -> Result<(crate::io::can::bus::CanBusConfig, BusCodec)> {
    let mut can = l
        .config
        .bus
        .can
        .clone()
        .ok_or_else(|| anyhow!("the signal map binds CAN signals but [bus.can] is missing"))?;
    can.dbc = super::config::resolve(&l.main_path, &can.dbc);
    let codec = BusCodec::load_for(&can, &can.dbc, &l.signal_map.can_bindings())
        .with_context(|| format!("loading {}", can.dbc.display()))?;
    Ok((can, codec))
}

/// What starts the controller's cycles (`[bus.can] cycle_trigger`, resolved against the DBC
/// and the signal map): `None` when the cycle keeps its fixed deadline (not the field
/// transport, no CAN binding, `"deadline"`, or no cycle input on CAN).
pub fn controller_trigger_plan(l: &Loaded) -> Result<Option<crate::io::can::bus::TriggerPlan>> {
    if modbus_reads_drive_the_cycle(l) {
        return Ok(None);
    }
    if l.config.bus.transport != super::config::Transport::Field || !l.signal_map.uses_can() {
        return Ok(None);
    }
    let (can, codec) = can_codec(l)?;
    codec
        .trigger_plan(&can.cycle_trigger)
        .context("bus.can.cycle_trigger")
}

/// Whether the Modbus link's reads start the controller's cycles (`[bus.modbus]
/// cycle_trigger = "reads"`, the default, on a skid whose map binds no CAN signal: the
/// trigger has one writer).
pub fn modbus_reads_drive_the_cycle(l: &Loaded) -> bool {
    l.config.bus.transport == super::config::Transport::Field
        && l.signal_map.uses_modbus()
        && !l.signal_map.uses_can()
        && l.config
            .bus
            .modbus
            .as_ref()
            .is_some_and(|m| m.cycle_trigger == crate::io::modbus::link::ModbusCycleTrigger::Reads)
}

/// Where the field links report: the daemon's event log and its field-fault handle.
pub fn link_reports(events: EventSender, faults: Arc<crate::io::link::FieldFaults>) -> LinkReports {
    let sink: EventSink = Arc::new(move |e: Event| {
        let _ = events.send(e);
    });
    LinkReports { sink, faults }
}

/// CAN state changes through the one reporter.
fn bus_event_hook(reports: &LinkReports, interface: String) -> crate::io::can::bus::StateHook {
    let reporter = std::sync::Mutex::new(reports.reporter(interface));
    Arc::new(move |s| {
        if let Some(state) = s.to_event() {
            let mut r = reporter
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            r.state(state, &s.to_string());
        }
    })
}

/// Compare every supervised actuator's command with its feedback every 10 ms and report
/// mismatches (event naming the actuator and the difference, journal, fault word).
pub async fn supervise_feedback(
    mut sup: FeedbackSupervisor,
    sensors: Arc<SensorBoard>,
    outputs: Arc<OutputBoard>,
    timeouts_s: [f64; crate::vocab::signals::SensorId::COUNT],
    reports: LinkReports,
    shutdown: watch::Receiver<bool>,
    health: Arc<crate::node::control::Health>,
) {
    let mut acks = health
        .acknowledgements
        .load(std::sync::atomic::Ordering::Relaxed);
    let mut reporters: std::collections::BTreeMap<ActuatorId, FieldLinkReporter> =
        Default::default();
    let stop = until_true(shutdown);
    tokio::pin!(stop);
    let mut tick = tokio::time::interval(std::time::Duration::from_millis(10));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            biased;
            () = &mut stop => return,
            _ = tick.tick() => {}
        }
        let now = crate::runtime::handoff::monotonic_ns();
        // the operator acknowledged: latched mismatches clear once their valve follows
        let a = health
            .acknowledgements
            .load(std::sync::atomic::Ordering::Relaxed);
        if a != acks {
            acks = a;
            sup.acknowledge();
        }
        let Some(o) = outputs.latest() else { continue };
        let (values, age) = sensors.snapshot(now);
        sup.step(
            now,
            |a| o.commands.get(a),
            |s| {
                if age[s.index()] <= timeouts_s[s.index()] {
                    values.get(s)
                } else {
                    f64::NAN
                }
            },
            |t| {
                let r = reporters
                    .entry(t.actuator)
                    .or_insert_with(|| reports.reporter(t.actuator.name()));
                r.fault(
                    FaultCategory::ActuatorFeedbackMismatch,
                    t.active,
                    &t.cause(),
                );
            },
        );
    }
}

/// The Modbus link's name in events: `modbus:<address>` or `modbus:<serial device>`.
fn modbus_link_name(cfg: &ModbusLinkConfig) -> String {
    match &cfg.client.transport {
        TransportConfig::Tcp { address } => format!("modbus:{address}"),
        TransportConfig::Rtu(r) => format!("modbus:{}", r.path),
    }
}

/// The CAN link's name in the status and on the HMI: `can:<interface>`.
fn can_link_name(interface: &str) -> String {
    format!("can:{interface}")
}

/// The input→link table of a configuration
/// ([`crate::io::signal_map::SignalMap::input_links`]): each bound transmitter named by the
/// link of its bus, as the link lamps name them (`links.<kind>.name`). The embedded plant carries
/// every supervised input on no field link. Built once at start (the links and the signal map
/// need a restart to change), off the control thread.
pub fn input_links(l: &Loaded) -> Vec<crate::io::signal_map::InputLink> {
    if l.config.bus.transport != super::config::Transport::Field {
        return crate::vocab::signals::SensorId::ALL
            .into_iter()
            .filter(|id| l.core.supervisor.limits[id.index()].is_some())
            .map(|input| crate::io::signal_map::InputLink {
                input,
                transmitter: "a".into(),
                link: None,
            })
            .collect();
    }
    let can = l
        .config
        .bus
        .can
        .as_ref()
        .map_or_else(|| "can".to_string(), |c| can_link_name(&c.interface));
    let modbus = l
        .config
        .bus
        .modbus
        .as_ref()
        .map_or_else(|| "modbus".to_string(), modbus_link_name);
    l.signal_map.input_links(&can, &modbus)
}

/// Per sensor, the kinds of field link that carry any of its transmitters (bits of
/// `1 << FieldLinkKind::code`), from the input->link table ([`input_links`]): what the
/// control thread roots a stale input's cause in. Built once at start.
pub fn input_link_kinds(
    table: &[crate::io::signal_map::InputLink],
) -> [u8; crate::vocab::signals::SensorId::COUNT] {
    let mut kinds = [0u8; crate::vocab::signals::SensorId::COUNT];
    for row in table {
        if let Some(link) = &row.link {
            kinds[row.input.index()] |=
                1 << crate::vocab::faults::FieldLinkKind::of_link_name(link).code();
        }
    }
    kinds
}

/// What a link's quality is judged against: its configured poll period and the freshness
/// budget of the inputs it carries (the smallest input timeout among them; `None` when it
/// carries no supervised input).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QualityBudget {
    /// The configured poll period, s.
    pub period_s: f64,
    /// The smallest freshness timeout of the inputs the link carries, s.
    pub freshness_s: Option<f64>,
}

impl QualityBudget {
    /// Why the link is slow, or `None` when it is not. A link is slow when its achieved poll
    /// period exceeds the freshness budget of the inputs it carries: then every input goes
    /// stale between two answers, however quickly each comes. (Not when it merely misses its
    /// configured rate: a device 14 ms away cannot be polled at 100 Hz, and a lamp that is
    /// always on is no lamp. The figures, rate included, are in the status and the metrics.)
    /// Without a supervised input on the link, twice the configured period stands in.
    pub fn slow(&self, poll_period_us: u64, p50_us: u64, p99_us: u64) -> Option<String> {
        if poll_period_us == 0 {
            return None;
        }
        let period_s = poll_period_us as f64 * 1e-6;
        let age_s = (poll_period_us + p99_us) as f64 * 1e-6;
        let limit_s = self.freshness_s.unwrap_or(2.0 * self.period_s);
        if period_s <= limit_s {
            return None;
        }
        let mut why = format!(
            "achieved poll period {:.0} ms against {:.0} ms configured (answer latency p50 {:.0} ms, p99 {:.0} ms)",
            period_s * 1e3,
            self.period_s * 1e3,
            p50_us as f64 * 1e-3,
            p99_us as f64 * 1e-3
        );
        if let Some(b) = self.freshness_s {
            why.push_str(&format!(
                ": beyond the freshness budget {:.0} ms of its inputs (worst input age {:.0} ms)",
                b * 1e3,
                age_s * 1e3
            ));
        }
        Some(why)
    }
}

/// How long a link must be back within its budget before its slow fault clears, s: the
/// period window itself (`quality::PERIOD_WINDOW_S`), so one quick answer among slow ones
/// does not clear it.
const SLOW_CLEARS_AFTER_S: f64 = crate::io::modbus::link::quality::PERIOD_WINDOW_S;

/// Follow a Modbus link's state and write health and report every transition through a
/// [`FieldLinkReporter`]: link up/down, exception answers with their code, failed writes
/// (raised at the first failure, with the exception code or the timeout) and the safe
/// state the link takes when they last; and its quality against `budget` every 100 ms
/// (`field_link_slow`, see [`QualityBudget::slow`]).
pub async fn report_modbus(
    monitor: Arc<LinkMonitor>,
    mut reporter: FieldLinkReporter,
    budget: QualityBudget,
    health: Arc<crate::node::control::Health>,
    shutdown: watch::Receiver<bool>,
) {
    let mut states = monitor.subscribe();
    let mut writes = monitor.subscribe_writes();
    let mut others = monitor.subscribe_another_writer();
    // another writer: latched until the operator acknowledges and the read-back is clean
    let mut another_latched = false;
    let mut acks_at_raise = 0u64;
    let stop = until_true(shutdown);
    tokio::pin!(stop);
    let mut tick = tokio::time::interval(std::time::Duration::from_millis(100));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut slow = false;
    let mut fine_since: Option<tokio::time::Instant> = None;
    let mut last_ok = (0u64, tokio::time::Instant::now());
    loop {
        // judged while the link is alive, i.e. answered a poll in full within the period
        // window (a link that answers nothing is down, the root cause then, reported once; one
        // that times out and reconnects between late answers is slow); a slow fault raised
        // before stays until the link answers within budget again
        let c = monitor.counters().snapshot();
        if c.polls_ok != last_ok.0 {
            last_ok = (c.polls_ok, tokio::time::Instant::now());
        }
        let alive = c.polls_ok > 0 && last_ok.1.elapsed().as_secs_f64() <= SLOW_CLEARS_AFTER_S;
        if alive {
            match budget.slow(c.poll_period_us, c.latency_p50_us, c.latency_p99_us) {
                Some(why) => {
                    fine_since = None;
                    if !slow {
                        // raised once, with the figures of the moment (they move on in the
                        // status and the metrics)
                        slow = true;
                        reporter.fault(FaultCategory::FieldLinkSlow, true, &why);
                    }
                }
                None if slow => {
                    let since = *fine_since.get_or_insert_with(tokio::time::Instant::now);
                    if since.elapsed().as_secs_f64() >= SLOW_CLEARS_AFTER_S {
                        slow = false;
                        fine_since = None;
                        reporter.fault(
                            FaultCategory::FieldLinkSlow,
                            false,
                            "poll period and answer latency back within budget",
                        );
                    }
                }
                None => {}
            }
        }
        let state = *states.borrow_and_update();
        match state {
            LinkState::Up => {
                reporter.state(BusState::Up, "");
                reporter.fault(FaultCategory::SensorTimeout, false, "reads answered");
            }
            LinkState::Degraded(x) => {
                reporter.state(BusState::Up, "");
                if x.function == 3 || x.function == 4 {
                    reporter.fault(
                        FaultCategory::SensorTimeout,
                        true,
                        &format!(
                            "device refused the read with exception {} ({:?}) at unit {} function 0x{:02X} address {}",
                            u8::from(x.code), x.code, x.unit_id, x.function, x.address
                        ),
                    );
                }
            }
            LinkState::Down {
                attempt,
                backoff_ms,
                cause,
            } => reporter.state(
                BusState::Down,
                &format!("down: {cause:?} ({attempt} failures, next attempt in {backoff_ms} ms)"),
            ),
            LinkState::Idle | LinkState::Stopped => {}
        }
        let seen = *others.borrow_and_update();
        let acks = health
            .acknowledgements
            .load(std::sync::atomic::Ordering::Relaxed);
        match seen {
            Some(w) => {
                if !another_latched {
                    // raised once, with the first value seen; the latch holds it
                    acks_at_raise = acks;
                    another_latched = true;
                    reporter.fault(FaultCategory::AnotherWriter, true, &w.to_string());
                } else if acks != acks_at_raise {
                    // acknowledged while the other master still writes: stays raised
                    acks_at_raise = acks;
                }
            }
            None if another_latched && acks != acks_at_raise => {
                another_latched = false;
                reporter.fault(
                    FaultCategory::AnotherWriter,
                    false,
                    "acknowledged; the command registers read back what this controller wrote",
                );
            }
            None => {}
        }
        let write_health = *writes.borrow_and_update();
        match write_health {
            WriteHealth::Ok => reporter.fault(
                FaultCategory::FieldWriteFailed,
                false,
                "writes acknowledged",
            ),
            WriteHealth::Failing { cause, safe_state } => {
                let text = if safe_state {
                    format!("{cause}; writes failing too long: watchdog withheld, the device goes to its own safe state")
                } else {
                    cause.to_string()
                };
                reporter.fault(FaultCategory::FieldWriteFailed, true, &text);
            }
        }
        tokio::select! {
            biased;
            () = &mut stop => return,
            r = states.changed() => if r.is_err() { return },
            r = writes.changed() => if r.is_err() { return },
            r = others.changed() => if r.is_err() { return },
            _ = tick.tick() => {}
        }
    }
}

/// The controller's links, for the status and the statistics written at exit: each through
/// the one [`FieldLink`](crate::io::link::FieldLink) face, whatever its transport.
#[derive(Debug, Clone, Default)]
pub struct LinkCounters {
    /// The links the daemon started.
    pub links: crate::io::link::FieldLinks,
    /// The actuators whose feedback is supervised (`[feedback]` of the signal map), by name:
    /// the HMI's feedback lamp says which (none: "not supervised").
    pub feedback: Vec<&'static str>,
}

impl LinkCounters {
    /// JSON view.
    pub fn to_json(&self) -> serde_json::Value {
        self.links.to_json(&self.feedback)
    }
}

/// Start the controller's bus tasks on `boards` (the cycle trigger, if any, goes to the CAN
/// task).
pub fn spawn_controller_links(
    l: &Loaded,
    tasks: &mut JoinSet<()>,
    boards: ControllerBoards,
    shutdown: watch::Receiver<bool>,
    reports: LinkReports,
    health: Arc<crate::node::control::Health>,
) -> Result<LinkCounters> {
    let ControllerBoards {
        sensors,
        outputs,
        wake,
        trigger,
    } = boards;
    let mut counters = LinkCounters::default();
    let mut modbus_view = None;
    let map = &l.signal_map;
    let mut sup = FeedbackSupervisor::new(&map.feedback);
    if let Some(v) = l.model.recycle_valve {
        // the feedback follows the valve's own positioner model (crate::io::feedback)
        sup = sup.with_valve(crate::vocab::signals::ActuatorId::RecycleValve, v.spec);
    }
    counters.feedback = map
        .feedback
        .keys()
        .filter(|a| crate::io::feedback::feedback_sensor(**a).is_some())
        .map(|a| a.name())
        .collect();
    if !sup.is_empty() {
        // feedback counts as fresh for its input timeout (else: no judgement)
        let mut timeouts_s = [0.2; crate::vocab::signals::SensorId::COUNT];
        for (id, t) in timeouts_s.iter_mut().enumerate() {
            if let Some(lim) = l.core.supervisor.limits[id] {
                *t = lim.timeout_s;
            }
        }
        tasks.spawn(supervise_feedback(
            sup,
            Arc::clone(&sensors),
            Arc::clone(&outputs),
            timeouts_s,
            reports.clone(),
            shutdown.clone(),
            Arc::clone(&health),
        ));
    }
    if map.uses_can() {
        let (can, codec) = can_codec(l)?;
        let (handles, state) = BusHandles::new(shutdown.clone());
        counters
            .links
            .push(Arc::new(crate::io::can::bus::CanLinkView {
                name: can_link_name(&can.interface),
                counters: Arc::clone(&handles.counters),
                state,
            }));
        let handles = handles.with_hook(bus_event_hook(&reports, can.interface.clone()));
        let boards = ControllerBoards {
            sensors: Arc::clone(&sensors),
            outputs: Arc::clone(&outputs),
            wake: Arc::clone(&wake),
            trigger: trigger.clone(),
        };
        tracing::info!(target: "can", "controller on {} ({})", can.interface, can.dbc.display());
        tasks.spawn(async move {
            if let Err(e) = can_controller(can, codec, boards, handles).await {
                tracing::error!(target: "can", "CAN task stopped: {e}");
            }
        });
    }
    if map.uses_modbus() {
        let cfg = l.config.bus.modbus.clone().ok_or_else(|| {
            anyhow!("the signal map binds Modbus registers but [bus.modbus] is missing")
        })?;
        let map = map.clone();
        let monitor = Arc::new(LinkMonitor::new());
        let view = Arc::new(crate::io::modbus::ModbusLinkView {
            name: modbus_link_name(&cfg),
            monitor: Arc::clone(&monitor),
        });
        counters.links.push(view.clone());
        modbus_view = Some(view);
        let reporter = reports.reporter(modbus_link_name(&cfg));
        let freshness_s = map
            .modbus_sensors()
            .iter()
            .filter_map(|(id, _)| l.core.supervisor.limits[id.index()].map(|lim| lim.timeout_s))
            .reduce(f64::min);
        let budget = QualityBudget {
            period_s: 1.0 / cfg.poll_rate_hz,
            freshness_s,
        };
        tasks.spawn(report_modbus(
            Arc::clone(&monitor),
            reporter,
            budget,
            Arc::clone(&health),
            shutdown.clone(),
        ));
        tracing::info!(target: "modbus", "controller polling at {} Hz", cfg.poll_rate_hz);
        let sd = shutdown.clone();
        let trigger = if modbus_reads_drive_the_cycle(l) {
            trigger
        } else {
            None
        };
        tasks.spawn(async move {
            if let Err(e) = modbus_controller(
                &cfg,
                &map,
                sensors,
                outputs,
                Pacing::Interval,
                monitor,
                trigger,
                until_true(sd),
            )
            .await
            {
                tracing::error!(target: "modbus", "Modbus task stopped: {e}");
            }
        });
    }
    crate::live::metrics::register_links(counters.links.clone(), modbus_view);
    Ok(counters)
}

/// The plant node's boards.
#[derive(Clone)]
pub struct PlantLinks {
    /// Received setpoints.
    pub commands: Arc<CommandBoard>,
    /// Received heartbeat.
    pub heartbeat: Arc<HeartbeatBoard>,
    /// Snapshot to send.
    pub snapshots: Arc<SnapshotBoard>,
    /// Wakes the CAN sender.
    pub wake: Arc<Wakeup>,
}

/// Start the plant's bus tasks (CAN node and/or Modbus TCP server).
pub fn spawn_plant_links(
    l: &Loaded,
    tasks: &mut JoinSet<()>,
    b: &PlantLinks,
    shutdown: watch::Receiver<bool>,
) -> Result<()> {
    let map = &l.signal_map;
    if map.uses_can() {
        let (can, codec) = can_codec(l)?;
        let (handles, _state) = BusHandles::new(shutdown.clone());
        let boards = PlantBoards {
            commands: Arc::clone(&b.commands),
            heartbeat: Arc::clone(&b.heartbeat),
            snapshots: Arc::clone(&b.snapshots),
            wake: Arc::clone(&b.wake),
        };
        tracing::info!(target: "can", "plant node on {}", can.interface);
        tasks.spawn(async move {
            if let Err(e) = can_plant(can, codec, boards, handles).await {
                tracing::error!(target: "can", "CAN task stopped: {e}");
            }
        });
    }
    if let Some(server) = l.config.simulation.modbus_server.clone() {
        let map = map.clone();
        let (s, c, h) = (
            Arc::clone(&b.snapshots),
            Arc::clone(&b.commands),
            Arc::clone(&b.heartbeat),
        );
        let sd = shutdown.clone();
        tracing::info!(target: "modbus", "plant Modbus TCP server on {}", server.listen);
        tasks.spawn(async move {
            if let Err(e) = run_plant_server(&server, &map, s, c, h, until_true(sd)).await {
                tracing::error!(target: "modbus", "Modbus server stopped: {e}");
            }
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::QualityBudget;

    #[test]
    fn a_link_is_slow_when_its_period_exceeds_its_inputs_freshness_not_its_rate() {
        let b = QualityBudget {
            period_s: 0.01,
            freshness_s: Some(0.05),
        };
        // a device 14 ms away polled at 100 Hz: 28 ms achieved, within the 50-ms budget
        assert_eq!(b.slow(28_000, 14_000, 19_000), None);
        // 90 ms late: 200 ms per poll, every input stale between two answers
        let why = b.slow(200_000, 95_000, 105_000).expect("slow");
        assert!(
            why.contains("achieved poll period 200 ms against 10 ms configured")
                && why.contains("freshness budget 50 ms")
                && why.contains("worst input age 305 ms"),
            "{why}"
        );
        // nothing measured yet
        assert_eq!(b.slow(0, 0, 0), None);
        // no supervised input on the link: twice the configured period
        let w = QualityBudget {
            period_s: 0.01,
            freshness_s: None,
        };
        assert_eq!(w.slow(20_000, 1_000, 2_000), None);
        assert!(w.slow(21_000, 1_000, 2_000).is_some());
    }

    #[test]
    fn both_links_show_the_one_face_name_state_and_traffic() {
        use crate::io::can::bus::{BusState, CanCounters, CanLinkView, CanTrouble, DownCause};
        use std::sync::atomic::Ordering;
        let (tx, rx) = tokio::sync::watch::channel(BusState::Up);
        let can = std::sync::Arc::new(CanCounters::default());
        can.tx_frames.store(7, Ordering::Relaxed);
        can.rx_frames.store(9, Ordering::Relaxed);
        can.bad_crc.store(2, Ordering::Relaxed);
        can.link_down.store(1, Ordering::Relaxed);
        let mut counters = super::LinkCounters::default();
        counters.links.push(std::sync::Arc::new(CanLinkView {
            name: super::can_link_name("can0"),
            counters: can,
            state: rx,
        }));
        let j = counters.to_json();
        assert_eq!(j["can"]["name"], "can:can0");
        assert_eq!(j["can"]["state"], "up");
        assert_eq!(
            j["can"]["traffic"],
            serde_json::json!({"sent": 7, "received": 9, "errors": 2, "down": 1, "reconnects": 0})
        );
        assert_eq!(
            j["can"]["bad_crc"], 2,
            "the transport's own counters beside"
        );
        assert_eq!(j["modbus"], serde_json::Value::Null, "no Modbus link run");
        tx.send_replace(BusState::down(DownCause::BusOff));
        assert_eq!(counters.to_json()["can"]["state"], "down");
        tx.send_replace(BusState::Degraded(CanTrouble::ErrorPassive));
        assert_eq!(
            counters.to_json()["can"]["state"],
            "up",
            "traffic still passes"
        );
        counters
            .links
            .push(std::sync::Arc::new(crate::io::modbus::ModbusLinkView {
                name: "modbus:127.0.0.1:502".into(),
                monitor: std::sync::Arc::new(crate::io::modbus::LinkMonitor::new()),
            }));
        let j = counters.to_json();
        assert_eq!(j["modbus"]["name"], "modbus:127.0.0.1:502");
        assert_eq!(j["modbus"]["state"], "idle");
        assert_eq!(j["modbus"]["traffic"]["sent"], 0);
        assert_eq!(j["modbus"]["link_down"], 0);
        assert_eq!(j["can"]["state"], "up");
    }

    #[test]
    fn each_sensor_knows_the_kinds_of_link_that_carry_it() {
        use crate::io::signal_map::InputLink;
        use crate::vocab::faults::FieldLinkKind;
        use crate::vocab::signals::SensorId;
        let row = |input, t: &str, link: Option<&str>| InputLink {
            input,
            transmitter: t.into(),
            link: link.map(str::to_string),
        };
        let kinds = super::input_link_kinds(&[
            row(SensorId::PSuction, "a", Some("can:can0")),
            row(SensorId::OrificeDp, "a", Some("modbus:10.0.0.5:502")),
            row(SensorId::OrificeDp, "b", Some("can:can0")),
            row(SensorId::TSuction, "a", None),
        ]);
        let (can, modbus) = (
            1 << FieldLinkKind::Can.code(),
            1 << FieldLinkKind::Modbus.code(),
        );
        assert_eq!(kinds[SensorId::PSuction.index()], can);
        assert_eq!(kinds[SensorId::OrificeDp.index()], can | modbus);
        assert_eq!(kinds[SensorId::TSuction.index()], 0, "the embedded plant");
        assert_eq!(kinds[SensorId::ShaftSpeed.index()], 0, "unbound");
    }
}
