//! `antisurge run`: the controller service. Wires the control thread, the bus tasks (or the
//! in-process plant), the event log, hot reload, systemd notification and shutdown.
//!
//! Threads and tasks:
//! - the control thread (fixed deadline, [`ControlNode`]), the only place setpoints are made;
//! - the CAN task and/or the Modbus task (tokio), or the in-process plant thread;
//! - the event-log writer thread;
//! - the watchdog thread: systemd READY/WATCHDOG from the control thread's [`Health`] only;
//! - tokio tasks for signals (SIGTERM/SIGINT stop, SIGHUP reload), the opt-in config-directory
//!   watcher, and the status log. A reload's load runs on a blocking thread, bounded in size
//!   and time, and is applied only if no file changed while it was read.

use super::config::{self, Loaded, Transport};
use crate::control::core::ControlCore;
use crate::control::measurements::OperatorInputs;
use crate::events::event::Event;
use crate::events::{EventLog, EventSender};
use crate::node::control::{ControlNode, ControlUpdate, ControlWiring, Health};
use crate::node::plant::{CommandSource, PlantNode, PlantStatus, SensorSink};
use crate::runtime::handoff::{monotonic_ns, OutputBoard, SensorBoard, Wakeup};
use crate::runtime::rt_loop::{run_periodic, setup_current_thread, CycleStats, RtSettings};
use crate::runtime::trigger::{run_triggered, CycleTrigger};
use crate::scenario::Scenario;
use anyhow::{anyhow, Context, Result};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Options of `antisurge run` beyond the config file.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Main config file.
    pub config: PathBuf,
    /// Stop after this long (tests, benchmarks); None: until SIGTERM/SIGINT.
    pub duration_s: Option<f64>,
    /// In-process transport: write the plant's trace and summary here at exit.
    pub out_dir: Option<PathBuf>,
}

/// Resolve a scenario name (`throttle-closure`) or file: a file is relative to the config
/// file; a name is looked up in `scenarios/` beside the config file, then beside the plant
/// file's directory (`config/plants/../scenarios`).
pub fn scenario_path(l: &Loaded, name: &str) -> PathBuf {
    let main = &l.main_path;
    let p = Path::new(name);
    if p.extension().is_some_and(|e| e == "toml") {
        return config::resolve(main, p);
    }
    let file = Path::new("scenarios").join(format!("{}.toml", name.replace('-', "_")));
    let beside_config = config::resolve(main, &file);
    if beside_config.is_file() {
        return beside_config;
    }
    let plant_dir = l
        .plant
        .as_ref()
        .and_then(|p| p.path.parent())
        .and_then(Path::parent);
    match plant_dir {
        Some(d) if d.join(&file).is_file() => d.join(&file),
        _ => beside_config,
    }
}

/// Operator inputs from the config.
pub fn operator_inputs(l: &Loaded) -> OperatorInputs {
    OperatorInputs {
        speed_setpoint_rad_s: l
            .config
            .control
            .speed_setpoint_rad_s
            .unwrap_or(l.model.drive.nominal_speed_rad_s),
        throttle_demand: f64::NAN,
        flow_setpoint_kg_s: l.config.control.flow_setpoint_kg_s.unwrap_or(f64::NAN),
        recycle_manual: f64::NAN,
    }
}

/// The live part of a loaded config, built for the control thread here (off it): the law
/// for `model`, the model the running core was built with. Fails if the law does not apply.
pub fn update_of(
    model: &crate::control::model::ControlModel,
    l: &Loaded,
) -> Result<ControlUpdate, crate::control::law::api::LawError> {
    Ok(ControlUpdate {
        reconf: ControlCore::prepare(model, l.controller.clone(), l.law)?,
        settings: l.core,
        auto: l.config.control.mode == config::StartMode::Auto,
        op: operator_inputs(l),
    })
}

/// Format config problems for the terminal and the log.
pub fn format_problems(problems: &[config::Problem]) -> String {
    problems
        .iter()
        .map(|p| p.to_string())
        .collect::<Vec<_>>()
        .join("\n")
}

/// Spawn the control thread. Returns its join handle; it stops (after publishing the safe
/// state) when `stop` is set. With a `trigger` the cycles start on the arrival of their inputs
/// (the bus task fires it), the deadline as fallback ([`crate::runtime::trigger`]); without,
/// on the fixed deadline.
fn spawn_control(
    mut node: ControlNode,
    rt: RtSettings,
    stop: Arc<AtomicBool>,
    stats: Arc<CycleStats>,
    trigger: Option<Arc<CycleTrigger>>,
) -> Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("antisurge-ctl".into())
        .stack_size(crate::runtime::rt_loop::CONTROL_THREAD_STACK_BYTES)
        .spawn(move || {
            let granted = setup_current_thread(&rt);
            tracing::info!(target: "rt", "control thread at {} Hz: {granted}", rt.rate_hz);
            let mut last = 0;
            let body = |tick: crate::runtime::rt_loop::Tick| {
                node.cycle(tick);
                last = tick.cycle;
                true
            };
            match &trigger {
                Some(t) => run_triggered(rt.period_ns(), t, &stop, &stats, body),
                None => run_periodic(rt.period_ns(), &stop, &stats, body),
            };
            let safe = node.shutdown(last + 1);
            tracing::info!(target: "rt", "control thread stopped; safe state commanded: {safe:?}");
        })
        .context("cannot start the control thread")
}

/// Everything the in-process plant thread needs.
struct InProcessPlant {
    handle: std::thread::JoinHandle<Result<Option<PathBuf>>>,
    status: Arc<PlantStatus>,
}

fn spawn_in_process_plant(
    l: &Loaded,
    sensors: Arc<SensorBoard>,
    outputs: Arc<OutputBoard>,
    stop: Arc<AtomicBool>,
    out_dir: Option<PathBuf>,
    hold: bool,
) -> Result<InProcessPlant> {
    let desc = l.sim_plant().map_err(|e| anyhow!("{e}"))?.clone();
    let scenario_file = scenario_path(l, &l.config.simulation.scenario);
    let scenario = Scenario::load(&scenario_file).map_err(|e| {
        crate::config::ConfigInvalid(format!("loading the simulation scenario: {e}"))
    })?;
    let hb_ms = l.config.simulation.heartbeat_timeout_ms;
    let law = l.law.name().to_string();
    let status = Arc::new(PlantStatus::default());
    let st = Arc::clone(&status);
    // the trace streams to out_dir/trace.csv from a writer thread started here, of ordinary
    // priority (issue 25: the whole trace was kept until exit); the plant thread only hands
    // it the rows
    let trace = match &out_dir {
        Some(dir) => Some(
            crate::node::plant::start_trace(&desc, &scenario, dir)
                .map_err(|e| anyhow!("in-process plant trace: {e}"))?,
        ),
        None => None,
    };
    let handle = std::thread::Builder::new()
        .name("antisurge-plant".into())
        .stack_size(crate::runtime::rt_loop::WORKER_THREAD_STACK_BYTES)
        .spawn(move || -> Result<Option<PathBuf>> {
            // a trace no one writes is not kept (issue 25: 3 MB of the default run's RSS)
            let (run, writer) = match trace {
                Some((handoff, writer)) => (
                    PlantRun::handing_trace_to(&desc, &scenario, handoff),
                    Some(writer),
                ),
                None => (
                    PlantRun::new(&desc, &scenario).map(PlantRun::without_trace),
                    None,
                ),
            };
            let run = run.map_err(|e| anyhow!("{e}"))?;
            let mut node = PlantNode::new(
                &desc,
                run,
                CommandSource::InProcess(outputs),
                SensorSink::InProcess(sensors),
                hb_ms,
                hold,
                st,
            );
            let period = (scenario.file.control_period_s * 1e9).round() as u64;
            let stats = CycleStats::default();
            run_periodic(period, &stop, &stats, |_| node.step(monotonic_ns()));
            if let (Some(dir), Some(writer)) = (out_dir, writer) {
                let result = crate::node::plant::finish_trace(&mut node, writer, &law)
                    .map_err(|e| anyhow!("{e}"))?;
                crate::sim::output::write_summary(&dir, &result.summary)
                    .map_err(|e| anyhow!("{e}"))?;
                return Ok(Some(dir));
            }
            Ok(None)
        })
        .context("cannot start the in-process plant")?;
    Ok(InProcessPlant { handle, status })
}

use crate::sim::PlantRun;

/// Initial torque of the speed loop: the machine's load torque at its initial operating
/// point, from the controller's own model (a bumpless start on a running machine).
/// The black-box header of a daemon started from `loaded`: what `antisurge replay` builds the
/// control core from (also used to import a `candump -l` log with the same settings).
pub fn blackbox_header(loaded: &Loaded) -> crate::blackbox::Header {
    let cfg = &loaded.config;
    crate::blackbox::Header {
        version: env!("CARGO_PKG_VERSION").to_string(),
        config: std::fs::canonicalize(&loaded.main_path).unwrap_or(loaded.main_path.clone()),
        law: loaded.law.name().to_string(),
        auto: cfg.control.mode == config::StartMode::Auto,
        initial_torque_nm: initial_torque_nm(loaded),
        period_ns: cfg.cycle.period_ns(),
        controller: loaded.controller.clone(),
        reason: String::new(),
        dropped: 0,
    }
}

pub(crate) fn initial_torque_nm(l: &Loaded) -> f64 {
    let Some(plant) = &l.plant else {
        return 0.0; // no simulated plant: the torque is not the controller's to start from
    };
    let init = plant.file.initial;
    let inputs = crate::plant::PlantInputs {
        throttle_process: init.throttle,
        recycle_manual: init.recycle_valve,
        feed: init.feed,
        ..Default::default()
    };
    crate::plant::SimPlant::new(plant, &inputs)
        .map(|p| p.truth().load_torque_nm)
        .unwrap_or(0.0)
}

/// Apply a reloaded configuration (`loaded`: the result of [`load_with_time_limit`]): diff,
/// hand the live part to the control thread, log. Returns the new loaded config when it was
/// accepted.
fn reload(
    current: &Loaded,
    model: &crate::control::model::ControlModel,
    loaded: Result<Loaded, Vec<config::Problem>>,
    updates: &mut rtrb::Producer<ControlUpdate>,
    events: &EventSender,
) -> (Option<Loaded>, &'static str, String) {
    let file = current.main_path.display().to_string();
    match loaded {
        Err(problems) => {
            let first = problems.iter().find(|p| !p.warning).or(problems.first());
            tracing::error!(target: "config", "reload rejected, the running configuration stays:\n{}", format_problems(&problems));
            if let Some(p) = first {
                let _ = events.send(Event::ConfigRejected {
                    file: p.error.file.display().to_string(),
                    key: (!p.error.key.is_empty()).then(|| p.error.key.clone()),
                    line: (p.error.line > 0).then_some(p.error.line as u32),
                    message: p.error.message.clone(),
                });
            }
            let why = first.map(|p| p.to_string()).unwrap_or_default();
            (None, "refused", why)
        }
        Ok(new) => {
            let mut diff = Vec::new();
            let mut restart = Vec::new();
            let keys: std::collections::BTreeSet<&String> =
                current.flat.keys().chain(new.flat.keys()).collect();
            for k in keys {
                let (a, b) = (current.flat.get(k), new.flat.get(k));
                if a != b {
                    if config::is_live_key(k) {
                        diff.push(crate::events::event::ConfigChange {
                            key: k.clone(),
                            old: a.cloned(),
                            new: b.cloned(),
                        });
                    } else {
                        restart.push(k.clone());
                    }
                }
            }
            // the plant file's own [controller] may have changed too
            let controller_changed = new.controller != current.controller;
            if diff.is_empty() && !controller_changed && restart.is_empty() {
                tracing::info!(target: "config", "reload: nothing changed");
                return (None, "unchanged", "nothing changed".into());
            }
            for w in &new.warnings {
                tracing::warn!(target: "config", "{w}");
            }
            if !restart.is_empty() {
                tracing::warn!(target: "config", "these keys need a restart to take effect: {}", restart.join(", "));
                let _ = events.send(Event::RestartRequired {
                    keys: restart.clone(),
                });
            }
            if !diff.is_empty() || controller_changed {
                let update = match update_of(model, &new) {
                    Ok(u) => u,
                    Err(e) => {
                        tracing::error!(target: "config", "reload rejected, the running configuration stays: {e}");
                        let _ = events.send(Event::ConfigRejected {
                            file: file.clone(),
                            key: Some("control.law".into()),
                            line: None,
                            message: e.to_string(),
                        });
                        return (None, "refused", e.to_string());
                    }
                };
                if updates.push(update).is_err() {
                    tracing::error!(target: "config", "reload: the control thread has not taken the previous update yet; try again");
                    return (
                        None,
                        "refused",
                        "the control thread has not taken the previous update yet; try again"
                            .into(),
                    );
                }
                tracing::info!(target: "config", "reload applied: {} key(s) changed", diff.len());
                let keys = diff
                    .iter()
                    .map(|c| c.key.as_str())
                    .collect::<Vec<_>>()
                    .join(", ");
                let _ = events.send(Event::ConfigApplied { file, diff });
                return (Some(new), "applied", keys);
            }
            (
                Some(new),
                "applied",
                format!("keys that need a restart: {}", restart.join(", ")),
            )
        }
    }
}

/// Longest a configuration load may take (start, reload). Every file is a bounded regular file
/// ([`crate::config::read_config_text`]), so only a hung file system can reach this.
pub const CONFIG_LOAD_LIMIT: Duration = Duration::from_secs(5);

/// [`config::load`] on its own thread, given at most [`CONFIG_LOAD_LIMIT`]. A load that does
/// not finish in time is an error (its thread is abandoned): nothing waits on it longer, and
/// the watchdog thread never waits on it at all.
pub fn load_with_time_limit(main: &Path) -> Result<Loaded, Vec<config::Problem>> {
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    let path = main.to_path_buf();
    let problem = |message: String| {
        vec![config::Problem {
            error: crate::config::FileError {
                file: main.to_path_buf(),
                key: String::new(),
                line: 0,
                column: 0,
                message,
                hint: Some("check the file system the configuration is on".into()),
            },
            warning: false,
        }]
    };
    // a sized stack, not Rust's 2 MiB: glibc keeps an exited thread's stack and hands it to
    // the next thread that asks for no more than 4× less (issue 25: an I/O thread asking for
    // 512 KiB got the loader's 2 MiB, all of it locked). The parsers bound their nesting
    // (`a_deeply_nested_config_is_refused_on_the_loader_stack`).
    let spawned = std::thread::Builder::new()
        .name("antisurge-cfg".into())
        .stack_size(crate::runtime::rt_loop::WORKER_THREAD_STACK_BYTES)
        .spawn(move || {
            let _ = tx.send(config::load(&path));
        });
    if let Err(e) = spawned {
        return Err(problem(format!("cannot start the loader thread: {e}")));
    }
    match rx.recv_timeout(CONFIG_LOAD_LIMIT) {
        Ok(r) => r,
        Err(_) => Err(problem(format!(
            "loading took longer than {} s; nothing was applied",
            CONFIG_LOAD_LIMIT.as_secs()
        ))),
    }
}

/// Size and modification time of the main file and every `conf.d/*.toml`: a reload is
/// applied only when this did not change while the files were read (and, for watched
/// changes, for `reload.settle_ms` before).
pub type Fingerprint = Vec<(PathBuf, u64, Option<std::time::SystemTime>)>;

/// The current [`Fingerprint`] of `main`'s configuration files.
pub fn fingerprint(main: &Path) -> Fingerprint {
    let mut files = vec![main.to_path_buf()];
    if let Ok(rd) = std::fs::read_dir(config::conf_d(main)) {
        let mut more: Vec<PathBuf> = rd
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|x| x == "toml"))
            .collect();
        more.sort();
        files.extend(more);
    }
    files
        .into_iter()
        .map(|p| {
            let m = std::fs::metadata(&p).ok();
            let len = m.as_ref().map_or(0, |m| m.len());
            let mtime = m.and_then(|m| m.modified().ok());
            (p, len, mtime)
        })
        .collect()
}

/// A reload in progress: its load runs on a blocking thread while the service keeps serving
/// signals.
struct PendingLoad {
    before: Fingerprint,
    task: tokio::task::JoinHandle<Result<Loaded, Vec<config::Problem>>>,
}

fn start_load(main: &Path) -> PendingLoad {
    let before = fingerprint(main);
    let p = main.to_path_buf();
    PendingLoad {
        before,
        task: tokio::task::spawn_blocking(move || load_with_time_limit(&p)),
    }
}

/// Ignore SIGXFSZ: with a file-size limit (`ulimit -f`, `LimitFSIZE=`) a write past it would
/// kill the process; ignored, the write fails with EFBIG, which the event log handles like a
/// full disk (events counted as lost, retried). Call before any thread starts.
pub fn ignore_sigxfsz() {
    // SAFETY: installing SIG_IGN for one signal; no handler code runs.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

/// Run the service until SIGTERM/SIGINT (or `duration_s`).
pub fn run(opts: &RunOptions) -> Result<()> {
    ignore_sigxfsz();
    let loaded = load_with_time_limit(&opts.config).map_err(|p| {
        crate::config::ConfigInvalid(format!(
            "the configuration is invalid; nothing was started:\n{}",
            format_problems(&p)
        ))
    })?;
    for w in &loaded.warnings {
        tracing::warn!(target: "config", "{w}");
    }
    let rt = crate::runtime::rt_loop::io_runtime(&loaded.config.cycle, "antisurge-io")
        .context("cannot start the I/O runtime")?;
    let plan = ServePlan::of(&loaded, opts)?;
    rt.block_on(serve(loaded, plan))
}

/// What `antisurge run` starts, with which settings, decided from the loaded configuration
/// and the options alone (no file, socket or thread touched): the plan step of the service,
/// [`serve`] the spawn step that carries it out.
#[derive(Debug, Clone, PartialEq)]
pub struct ServePlan {
    /// What starts a control cycle, in words (event log, journal, stats file).
    pub cycle_trigger: String,
    /// Whether a cycle trigger is made (CAN inputs or Modbus reads drive the cycle).
    pub triggered: bool,
    /// Where the sensors come from and the commands go.
    pub plant: PlantPlan,
    /// The black box's directory (beside the event log) and its ring's records.
    pub blackbox_dir: PathBuf,
    /// Records of the black box's ring ([`crate::blackbox::history_capacity`]).
    pub blackbox_records: usize,
    /// Whether the core asks for automatic mode at start.
    pub start_auto: bool,
    /// Whether the Sparkplug B edge node runs.
    pub sparkplug: bool,
    /// Whether the config directory is watched (else SIGHUP alone reloads).
    pub watch_files: bool,
    /// How long watched files must stay unchanged before a reload.
    pub settle: Duration,
    /// The running configuration's record (`check-config --against-running`), and beside
    /// it the reload's verdict and the operator's override.
    pub running_file: PathBuf,
    /// The reload verdict `antisurge reload` waits for.
    pub verdict_file: PathBuf,
    /// The operator's override of the reload's valve-step dry run.
    pub override_file: PathBuf,
    /// Stop after this long (None: until a signal).
    pub duration_s: Option<f64>,
}

/// The plant side of a [`ServePlan`].
#[derive(Debug, Clone, PartialEq)]
pub enum PlantPlan {
    /// The simulated plant in process; `hold`: it holds its last state after the scenario
    /// ends (else the run stops there); its trace and summary go to `out_dir`.
    InProcess {
        /// Hold after the scenario's end.
        hold: bool,
        /// Trace and summary directory.
        out_dir: Option<PathBuf>,
        /// The run stops when the scenario ends (a trace asked for, no duration).
        stop_at_end: bool,
    },
    /// The field links of the signal map (CAN, Modbus).
    Field,
}

impl ServePlan {
    /// The plan for `loaded` run with `opts`.
    pub fn of(loaded: &Loaded, opts: &RunOptions) -> Result<ServePlan> {
        let cfg = &loaded.config;
        // what starts a cycle: the arrival of its CAN inputs, the Modbus link's reads, or the
        // fixed deadline
        let trigger_plan = super::field::controller_trigger_plan(loaded)?;
        let modbus_reads = super::field::modbus_reads_drive_the_cycle(loaded);
        let cycle_trigger = if modbus_reads {
            "inputs: modbus reads".to_string()
        } else {
            trigger_plan
                .as_ref()
                .map_or_else(|| "deadline".to_string(), |p| p.describe())
        };
        let plant = match cfg.bus.transport {
            Transport::InProcess => PlantPlan::InProcess {
                // a run without an end and a place for its trace holds the plant's last state
                hold: opts.out_dir.is_none()
                    || opts.duration_s.is_none()
                    || cfg.simulation.hold_after_end,
                out_dir: opts.out_dir.clone(),
                stop_at_end: opts.out_dir.is_some() && opts.duration_s.is_none(),
            },
            Transport::Field => PlantPlan::Field,
        };
        let running_file =
            config::running::RunningConfig::path_beside(&crate::live::socket_path(&cfg.status));
        Ok(ServePlan {
            cycle_trigger,
            triggered: trigger_plan.is_some() || modbus_reads,
            plant,
            blackbox_dir: cfg
                .event_log
                .path
                .parent()
                .map_or_else(|| PathBuf::from("blackbox"), |d| d.join("blackbox")),
            blackbox_records: crate::blackbox::history_capacity(cfg.cycle.period_ns()),
            start_auto: cfg.control.mode == config::StartMode::Auto,
            sparkplug: cfg.sparkplug.enabled,
            watch_files: cfg.reload.watch_files,
            settle: Duration::from_secs_f64(cfg.reload.settle_ms / 1e3),
            verdict_file: running_file.with_file_name(super::reload_trial::VERDICT_FILE),
            override_file: running_file.with_file_name(super::reload_trial::OVERRIDE_FILE),
            running_file,
            duration_s: opts.duration_s,
        })
    }
}

/// The spawn step: start what `plan` names, serve until a signal or the plan's end, then
/// command the safe state and stop.
async fn serve(loaded: Loaded, plan: ServePlan) -> Result<()> {
    let cfg = loaded.config.clone();
    if let Some(dir) = cfg.event_log.path.parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    // the event log is an audit trail, never a start dependency of the protection: if it
    // cannot be opened the controller runs with it degraded and the writer keeps retrying
    let (log, open_error) = EventLog::start_degraded_ok(cfg.event_log.clone())
        .map_err(|e| anyhow!("{e}"))
        .with_context(|| {
            format!(
                "cannot start the event log {}",
                cfg.event_log.path.display()
            )
        })?;
    if let Some(e) = open_error {
        tracing::error!(target: "events", "event log DEGRADED: {e}; the controller runs without it, events are counted as lost, and the log is retried every {} s", crate::events::writer::REOPEN_RETRY.as_secs());
    }
    let events = log.sender();
    // the operator surfaces are bound before anything runs: one that cannot be bound (a
    // squatted port) or an unsafe token file stops the start (issue 24)
    let identity = crate::live::Identity::new(&loaded.machine.name, &loaded.main_path);
    let mut live = match crate::live::prepare(&cfg.status, identity) {
        Ok(l) => l,
        Err(e) => {
            let _ = events.send(Event::Stopped {
                reason: format!("not started: {e}"),
            });
            drop(events);
            let _ = log.shutdown();
            return Err(anyhow::Error::new(e));
        }
    };
    let cycle_trigger = plan.cycle_trigger.clone();
    let trigger = plan.triggered.then(|| Arc::new(CycleTrigger::new()));
    tracing::info!(target: "rt", "control cycle trigger: {cycle_trigger}");
    let _ = events.send(Event::started_with_trigger(
        &loaded.main_path,
        loaded.law,
        cycle_trigger.clone(),
    ));

    let sensors = Arc::new(SensorBoard::default());
    let outputs = Arc::new(OutputBoard::default());
    let wake = Arc::new(Wakeup::new().context("cannot create the wakeup eventfd")?);
    let stats = Arc::new(CycleStats::default());
    let health = Arc::new(Health::default());
    let (mut updates_tx, updates_rx) = rtrb::RingBuffer::<ControlUpdate>::new(4);
    // replaced laws and settings come back here to be dropped off the control thread
    let (retired_tx, mut retired_rx) =
        rtrb::RingBuffer::<crate::control::core::Reconfiguration>::new(8);
    let model0 = loaded.model.clone();
    let stop = Arc::new(AtomicBool::new(false));

    let core = ControlCore::new(
        loaded.model.clone(),
        loaded.controller.clone(),
        loaded.core,
        loaded.law,
        initial_torque_nm(&loaded),
    )
    .map_err(|e| anyhow!("{e}"))?;
    let mut core = core;
    core.request_auto(plan.start_auto);
    // the field faults the link tasks raise, read by the control thread each cycle
    let field_faults = Arc::new(crate::io::link::FieldFaults::default());
    let node = ControlNode::new(
        core,
        operator_inputs(&loaded),
        ControlWiring {
            sensors: Arc::clone(&sensors),
            outputs: Arc::clone(&outputs),
            wake: Arc::clone(&wake),
            updates: updates_rx,
            retired: retired_tx,
            events: Some(log.rt_sender().map_err(|e| anyhow!("{e}"))?),
            health: Arc::clone(&health),
            stats: Arc::clone(&stats),
            field: Arc::clone(&field_faults),
        },
        cfg.cycle.period_ns(),
    );
    let mut node = node;
    if let Some(rx) = live.rx.take() {
        node.attach_live(Arc::clone(&live.board), rx);
    }
    node.restore(&live.kept);
    let live_board = Arc::clone(&live.board);
    // the black box: per-cycle records, written on fail-safe, surge and exit next to the
    // event log (crate::blackbox)
    let (bb_tx, recorder) = crate::blackbox::Recorder::start(
        plan.blackbox_dir.clone(),
        blackbox_header(&loaded),
        plan.blackbox_records,
    )
    .context("cannot start the black-box recorder")?;
    let node = node
        .with_black_box(bb_tx)
        .with_input_links(super::field::input_link_kinds(&super::field::input_links(
            &loaded,
        )));
    let control = spawn_control(
        node,
        cfg.cycle,
        Arc::clone(&stop),
        Arc::clone(&stats),
        trigger.clone(),
    )?;
    // systemd READY/WATCHDOG from the control loop's health only, on their own thread
    let wd_stop = Arc::new(AtomicBool::new(false));
    let watchdog = super::notify::spawn_watchdog(Arc::clone(&health), Arc::clone(&wd_stop))
        .context("cannot start the watchdog thread")?;

    let (shutdown_tx, shutdown_rx) = tokio::sync::watch::channel(false);
    let mut tasks = tokio::task::JoinSet::new();
    let mut plant = None;
    let mut link_counters = super::field::LinkCounters::default();
    let plant_stop = Arc::new(AtomicBool::new(false));
    match &plan.plant {
        PlantPlan::InProcess { hold, out_dir, .. } => {
            plant = Some(spawn_in_process_plant(
                &loaded,
                Arc::clone(&sensors),
                Arc::clone(&outputs),
                Arc::clone(&plant_stop),
                out_dir.clone(),
                *hold,
            )?);
            tracing::info!(target: "antisurge", "in-process plant `{}` running scenario `{}`", loaded.machine.name, cfg.simulation.scenario);
        }
        PlantPlan::Field => {
            link_counters = super::field::spawn_controller_links(
                &loaded,
                &mut tasks,
                crate::io::can::bus::ControllerBoards {
                    sensors: Arc::clone(&sensors),
                    outputs: Arc::clone(&outputs),
                    wake: Arc::clone(&wake),
                    trigger: trigger.clone(),
                },
                shutdown_rx.clone(),
                super::field::link_reports(events.clone(), Arc::clone(&field_faults)),
                Arc::clone(&health),
            )?;
        }
    }

    let links = link_counters.clone();
    let (current_model, current_controller, current_law) =
        (loaded.model.clone(), loaded.controller.clone(), loaded.law);
    let _live = crate::live::spawn(
        &cfg.status,
        crate::live::hmi::MapLines::new(
            &current_model,
            &current_controller,
            current_law == crate::control::LawId::RecyclePi,
        ),
        cfg.event_log.path.clone(),
        live,
        Arc::clone(&stats),
        Arc::new(move || links.to_json()),
        super::field::input_links(&loaded),
        events.clone(),
        shutdown_rx.clone(),
        &mut tasks,
    );
    // the Sparkplug B edge node (issue 26): off the control thread, reads the same snapshot
    if plan.sparkplug {
        let inputs = crate::sparkplug::EdgeInputs {
            ctx: _live.clone(),
            ranges: crate::sparkplug::catalogue::Ranges::of(&crate::live::hmi::MapLines::new(
                &current_model,
                &current_controller,
                current_law == crate::control::LawId::RecyclePi,
            )),
            state_dir: crate::live::state_dir(&cfg.status),
            events_path: cfg.event_log.path.clone(),
        };
        if let Err(e) =
            crate::sparkplug::spawn(&cfg.sparkplug, inputs, shutdown_rx.clone(), &mut tasks)
        {
            tracing::error!(target: "sparkplug", "no Sparkplug B edge node: {e}");
        }
    }
    // signals, reload, watchdog, status
    let mut sigterm = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    let mut sigint = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::interrupt())?;
    let mut sighup = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::hangup())?;
    let (watch_tx, mut watch_rx) = tokio::sync::mpsc::channel::<()>(16);
    let _watcher = if plan.watch_files {
        super::reload_watch::watch_config_dir(&loaded.main_path, watch_tx)
            .map_err(|e| tracing::warn!(target: "config", "not watching the config directory ({e}); SIGHUP still reloads"))
            .ok()
    } else {
        drop(watch_tx);
        None
    };
    let settle = plan.settle;
    // what runs, for `check-config --against-running` (issue 25: no half file)
    let running_file = plan.running_file.clone();
    let record = |l: &Loaded| {
        if let Err(e) = config::running::RunningConfig::of(l).save(&running_file) {
            tracing::warn!(target: "config", "cannot record the running configuration in {}: {e}; `check-config --against-running` will not see it", running_file.display());
        }
    };
    record(&loaded);
    // the answer `antisurge reload` waits for (issue 25: the reload's exit status)
    let verdict_file = plan.verdict_file.clone();
    let override_file = plan.override_file.clone();
    let _ = std::fs::remove_file(&override_file);
    let mut verdict = super::reload_trial::Verdict {
        seq: 0,
        pid: std::process::id(),
        outcome: "started".into(),
        message: String::new(),
        overridden: false,
    };
    if let Err(e) = verdict.save(&verdict_file) {
        tracing::warn!(target: "config", "cannot write {}: {e}; `antisurge reload` will not see the daemon's answer", verdict_file.display());
    }
    let mut current = loaded;
    let mut ticker = tokio::time::interval(Duration::from_millis(100));
    let started = std::time::Instant::now();
    let mut last_status = std::time::Instant::now();
    // a watched change waiting for the files to settle: since when, and how they looked
    let mut settling: Option<(std::time::Instant, Fingerprint)> = None;
    let mut loading: Option<PendingLoad> = None;
    let mut reload_again = false;
    let reason: String = loop {
        tokio::select! {
            _ = sigterm.recv() => break "SIGTERM".into(),
            _ = sigint.recv() => break "SIGINT".into(),
            _ = sighup.recv() => {
                tracing::info!(target: "config", "SIGHUP: reloading {}", current.main_path.display());
                if loading.is_some() { reload_again = true; } else { loading = Some(start_load(&current.main_path)); }
            }
            Some(()) = watch_rx.recv() => {
                // editors write in pieces, or a temporary file renamed over the target:
                // wait until the files stay unchanged for `settle`
                while watch_rx.try_recv().is_ok() {}
                settling = Some((std::time::Instant::now(), fingerprint(&current.main_path)));
            }
            done = async { (&mut loading.as_mut().expect("guarded").task).await }, if loading.is_some() => {
                let before = loading.take().map(|l| l.before).unwrap_or_default();
                let result = match done {
                    Ok(r) if fingerprint(&current.main_path) == before => r,
                    Ok(_) => Err(vec![config::Problem {
                        error: crate::config::FileError {
                            file: current.main_path.clone(),
                            key: String::new(),
                            line: 0,
                            column: 0,
                            message: "the configuration changed while it was being read (a save in progress?); nothing was applied".into(),
                            hint: Some("reload again once the file is saved".into()),
                        },
                        warning: false,
                    }]),
                    Err(e) => {
                        tracing::error!(target: "config", "reload: the loader failed: {e}");
                        verdict.seq += 1;
                        verdict.outcome = "refused".into();
                        verdict.message = format!("the loader failed: {e}");
                        verdict.overridden = false;
                        let _ = verdict.save(&verdict_file);
                        continue;
                    }
                };
                // a file cut off while being written may parse: keys missing against the
                // running configuration are a refusal, not defaults
                let result = result.and_then(|new| {
                    let mut p = config::running::RunningConfig::of(&current).incomplete(&new);
                    // nor may it refuse what the transmitters read now (fail-safe at once)
                    if p.is_empty() {
                        p = config::dry_run::inputs_refused(&current, &new, |id| sensors.get(id).0);
                    }
                    if p.is_empty() { Ok(new) } else { Err(p) }
                });
                // nor step the recycle valve by more than the bumpless limit (dry run of the
                // running and the new law on the live inputs), unless the operator overrode it
                let overridden = std::fs::remove_file(&override_file).is_ok();
                let result = match result {
                    Ok(new) if !overridden => {
                        let samples = super::reload_trial::sample_live(&sensors, 1.0 / current.config.cycle.rate_hz).await;
                        match super::reload_trial::valve_step(&model0, &current, &new, &samples) {
                            Some(t) => {
                                tracing::info!(target: "config", "reload dry run: largest recycle valve step {:.2} % over {} samples (limit {:.1} %)", 100.0 * t.step, t.compared, 100.0 * super::reload_trial::BUMPLESS_STEP_LIMIT);
                                match super::reload_trial::refusal(&current, &new, &t) { Some(p) => Err(vec![p]), None => Ok(new) }
                            }
                            None => Ok(new),
                        }
                    }
                    Ok(new) => {
                        tracing::warn!(target: "config", "reload: the operator overrode the valve-step dry run ({})", override_file.display());
                        Ok(new)
                    }
                    r => r,
                };
                let (applied, outcome, message) = reload(&current, &model0, result, &mut updates_tx, &events);
                if let Some(n) = applied { current = n; record(&current); }
                verdict.seq += 1;
                verdict.outcome = outcome.into();
                verdict.message = message;
                verdict.overridden = overridden;
                if let Err(e) = verdict.save(&verdict_file) {
                    tracing::warn!(target: "config", "cannot write {}: {e}", verdict_file.display());
                }
                if std::mem::take(&mut reload_again) { loading = Some(start_load(&current.main_path)); }
            }
            _ = ticker.tick() => {
                // replaced laws and settings are freed here, off the control thread
                while retired_rx.pop().is_ok() {}
                if let Some((since, fp)) = settling.take() {
                    let now_fp = fingerprint(&current.main_path);
                    if now_fp != fp {
                        settling = Some((std::time::Instant::now(), now_fp));
                    } else if since.elapsed() < settle {
                        settling = Some((since, fp));
                    } else if loading.is_some() {
                        reload_again = true;
                    } else {
                        tracing::info!(target: "config", "config files changed and stayed unchanged for {} ms: reloading", settle.as_millis());
                        loading = Some(start_load(&current.main_path));
                    }
                }
                if let Some(d) = plan.duration_s {
                    if started.elapsed().as_secs_f64() >= d { break "duration elapsed".into(); }
                }
                let every = current.config.status.log_interval_s;
                if every > 0.0 && last_status.elapsed().as_secs_f64() >= every {
                    last_status = std::time::Instant::now();
                    let r = stats.report();
                    let live = live_board.latest().map(|s| crate::live::report::status_line(&s)).unwrap_or_else(|| health.mode().name().into());
                    tracing::info!(target: "status", "{live} · {} cycles ({} on inputs, {} on deadline) · jitter p99 {:.0} µs · compute p99 {:.1} µs · overruns {}{}",
                        r.cycles, r.cycles_by_input, r.cycles_by_deadline, r.wake_jitter.p99_us, r.compute.p99_us, r.overruns,
                        if log.writable() { "" } else { " · event log DEGRADED (not writable, retrying)" });
                }
                if let Some(p) = &plant {
                    if p.status.finished.load(Ordering::Relaxed) && matches!(plan.plant, PlantPlan::InProcess { stop_at_end: true, .. }) {
                        break "scenario finished".into();
                    }
                }
            }
        }
    };
    tracing::info!(target: "antisurge", "{reason}: commanding the safe state and stopping");
    wd_stop.store(true, Ordering::Relaxed);
    let _ = watchdog.join();
    stop.store(true, Ordering::Relaxed);
    let _ = tokio::task::spawn_blocking(move || control.join()).await;
    let _ = tokio::task::spawn_blocking(move || recorder.finish()).await;
    // let the bus tasks send the safe state and a few heartbeats with the shutdown mode
    tokio::time::sleep(Duration::from_millis(100)).await;
    let _ = shutdown_tx.send(true);
    while tasks.join_next().await.is_some() {}
    plant_stop.store(true, Ordering::Relaxed);
    if let Some(p) = plant {
        match p.handle.join() {
            Ok(Ok(Some(dir))) => {
                tracing::info!(target: "antisurge", "plant trace and summary in {}", dir.display())
            }
            Ok(Err(e)) => tracing::error!(target: "antisurge", "in-process plant: {e:#}"),
            _ => {}
        }
    }
    let report = stats.report();
    if let Some(path) = &current.config.status.stats_file {
        let json = serde_json::json!({
            "cycles": report.cycles,
            "cycle_trigger": cycle_trigger,
            "cycles_by_input": report.cycles_by_input,
            "cycles_by_deadline": report.cycles_by_deadline,
            "overruns": report.overruns,
            "wake_jitter_us": report.wake_jitter,
            "compute_us": report.compute,
            "input_age_us": report.input_age,
            "rate_hz": current.config.cycle.rate_hz,
            "max_rss_kib": super::notify::max_rss_kib(),
            "links": link_counters.to_json(),
            "surges": health.surges.load(Ordering::Relaxed),
            "updates_applied": health.updates_applied.load(Ordering::Relaxed),
            "event_log_writable": log.writable(),
        });
        if let Err(e) = std::fs::write(path, serde_json::to_string_pretty(&json)? + "\n") {
            tracing::warn!(target: "antisurge", "cannot write {}: {e}", path.display());
        }
    }
    let _ = events.send(Event::Stopped { reason });
    drop(events);
    log.shutdown().map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn loaded(rel: &str) -> Loaded {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
        load_with_time_limit(&path).unwrap_or_else(|p| panic!("{rel}: {}", format_problems(&p)))
    }

    #[test]
    fn the_plan_of_the_shipped_config_runs_the_plant_in_process_and_holds_it() {
        let l = loaded("config/antisurge.toml");
        let plan = ServePlan::of(&l, &RunOptions::default()).expect("plan");
        assert_eq!(
            plan.plant,
            PlantPlan::InProcess {
                hold: true,
                out_dir: None,
                stop_at_end: false
            }
        );
        // in process, nothing drives the cycle but its deadline
        assert_eq!(
            (plan.cycle_trigger.as_str(), plan.triggered),
            ("deadline", false)
        );
        assert_eq!(
            plan.blackbox_dir,
            l.config
                .event_log
                .path
                .parent()
                .expect("dir")
                .join("blackbox")
        );
        assert_eq!(plan.blackbox_records, 10_000, "10 s at 1 kHz");
        assert_eq!(plan.verdict_file.parent(), plan.running_file.parent());
        assert_ne!(plan.verdict_file, plan.running_file);
        assert_eq!(plan.duration_s, None);
        // a run asked for a trace without a duration stops when the scenario ends; with a
        // duration the plant stops at the scenario's end and the run at the duration
        let traced = RunOptions {
            out_dir: Some("out".into()),
            ..RunOptions::default()
        };
        let p = ServePlan::of(&l, &traced).expect("plan");
        assert!(matches!(
            p.plant,
            PlantPlan::InProcess {
                hold: true,
                stop_at_end: true,
                ..
            }
        ));
        let timed = RunOptions {
            duration_s: Some(5.0),
            ..traced
        };
        let p = ServePlan::of(&l, &timed).expect("plan");
        let hold = l.config.simulation.hold_after_end;
        assert!(
            matches!(p.plant, PlantPlan::InProcess { hold: h, stop_at_end: false, .. } if h == hold),
            "{:?}",
            p.plant
        );
        assert_eq!(p.duration_s, Some(5.0));
    }

    #[test]
    fn the_plan_of_a_modbus_skid_runs_its_links_and_its_cycle_on_the_reads_or_the_deadline() {
        let l = loaded("tests/good_configs/field_modbus_recycle_pi.toml");
        let plan = ServePlan::of(&l, &RunOptions::default()).expect("plan");
        assert_eq!(plan.plant, PlantPlan::Field);
        let reads = super::super::field::modbus_reads_drive_the_cycle(&l);
        assert_eq!(plan.triggered, reads);
        assert_eq!(
            plan.cycle_trigger,
            if reads {
                "inputs: modbus reads"
            } else {
                "deadline"
            }
        );
        assert_eq!(plan.blackbox_records, 500, "10 s at 50 Hz");
        assert!(!plan.sparkplug);
    }

    #[test]
    fn a_deeply_nested_config_is_refused_on_the_loader_stack() {
        // the loader thread's stack is sized (WORKER_THREAD_STACK_BYTES): a file nested far
        // beyond any real config must come back as a problem, not overflow the stack
        let dir = tempfile::tempdir().expect("tmp");
        for depth in [100usize, 1_000, 100_000] {
            let main = dir.path().join(format!("nested{depth}.toml"));
            let text = format!("x = {}1{}\n", "[".repeat(depth), "]".repeat(depth));
            std::fs::write(&main, text).expect("write");
            let Err(problems) = load_with_time_limit(&main) else {
                panic!("depth {depth}: loaded");
            };
            assert!(!problems.is_empty(), "depth {depth}");
        }
        let main = dir.path().join("inline.toml");
        let text = format!("x = {}1{}\n", "{ a = ".repeat(50_000), " }".repeat(50_000));
        std::fs::write(&main, text).expect("write");
        assert!(load_with_time_limit(&main).is_err());
    }
}
