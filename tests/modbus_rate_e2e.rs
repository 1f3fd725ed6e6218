//! Issue 22, deliverable 4: `antisurge run` over Modbus TCP at 50 and 100 Hz polling against a
//! device written here, not against the project's own plant node. The device answers every
//! request after 5–20 ms (a deterministic pseudo-random sequence per seed, requests of one
//! connection served one after the other, like a gateway) and integrates a fast machine in
//! its own thread (1 ms steps, paced by the wall clock). The test owns the disturbances:
//! throttle step, a throttle closure with Δp noise and the Δp register frozen for 1 s, and a
//! 3-s link outage (listener and connections closed). Every verdict is on the plant's TRUE
//! flow in the device (surge cycles by `antisurge::surge::SurgeDetector`), in plant time.
//!
//! The machine (hemchi2016's recycle system made fast: [`MACHINE`]) is chosen so that the
//! feasibility oracle holds: the same plant in process, with the recycle valve slammed fully
//! open two 50-Hz sample periods plus 20 ms latency (60 ms) after the throttle step, does not
//! surge, while with the valve held it reverses its flow within ≈ 80 ms.
//!
//! The real-time cases take one lock (`REAL_TIME`), so they run one after the other even under
//! the default parallel test threads: two daemons and two 1-kHz plants on a 2-core machine
//! would disturb each other's timing.

mod common;

use antisurge::control::speed_loop::SpeedLoop;
use antisurge::plant::file::PlantDescription;
use antisurge::plant::{PlantInputs, SimPlant};
use antisurge::surge::{DetectorConfig, SurgeDetector};
use antisurge::vocab::signals::{ActuatorId, SensorId};
use common::daemon::{logs, signal, spawn, wait};
use std::future::Future;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio_modbus::{ExceptionCode, Request, Response, SlaveRequest};

/// The device's plant step, s.
const PLANT_STEP_S: f64 = 1e-3;
/// Steady throttle opening before the disturbances, fraction.
const THROTTLE_START: f64 = 0.6;
/// Throttle opening after the step / at the end of the closure, fraction.
const THROTTLE_END: f64 = 0.1;
/// Plant time of the disturbance (step, start of the closure), s: the daemon has been in
/// automatic for a few seconds by then (startup grace 1 s).
const DISTURBANCE_AT_S: f64 = 4.0;
/// The request latency range of the device, s.
const LATENCY_MIN_S: f64 = 0.005;
const LATENCY_MAX_S: f64 = 0.020;
/// Register addresses of the device (input table, then the valve's holding register):
/// 0–10 as the shipped map, 11–14 two more Δp transmitters (f32, for the vote cases).
const INPUT_WORDS: usize = 15;
const VALVE_HOLDING: u16 = 102;

/// The fast machine: hemchi2016_recycle.toml (seed 001's supercharger recycle system) with a
/// smaller discharge volume (0.25 m³ for 0.3), a throttle that strokes in 20 ms (a block valve
/// slamming: the step is a step), and a larger, faster anti-surge valve (3× the area, 50 ms
/// full stroke). Stepping the throttle 60 % → 10 % with the recycle valve held closed reverses
/// the compressor flow ≈ 80 ms later (printed and asserted by the oracle test). The law
/// settings are the controller's defaults (only the observer gain, a property of the machine,
/// `{map}` is replaced by the absolute path of the shipped map table. The device integrates
/// this file; the daemon is told the machine by [`MACHINE_FOR_THE_DAEMON`].
const MACHINE: &str = r#"
name = "fast_hemchi"
description = "hemchi2016 recycle system made fast (issue 22 Modbus-rate test)"
source = "config/plants/hemchi2016_recycle.toml, volumes and valves changed by tests/modbus_rate_e2e.rs"
model = "recycle_system"

[gas]
molar_mass_kg_mol = 0.02897
heat_capacity_ratio = 1.4
polytropic_exponent = 0.3

[map.table]
file = "{map}"

[shaft]
inertia_kg_m2 = 0.01
impeller_radius_m = 0.05
slip_factor = 0.9

[drive]
rated_torque_nm = 40.0
min_torque_nm = 0.0
nominal_speed_rad_s = 3140.0
speed_kp_nm_s_rad = 2.0
speed_ki_nm_rad = 10.0

[orifice]
flow_coefficient = 0.6
bore_diameter_m = 0.09

[recycle_system]
suction_volume_m3 = 0.5
discharge_volume_m3 = 0.25         # 0.3 in hemchi2016: a faster machine
suction_sonic_velocity_m_s = 340.0
discharge_sonic_velocity_m_s = 350.0
suction_temperature_k = 293.15
discharge_temperature_k = 320.0
compressor_duct_area_m2 = 0.0045
compressor_duct_length_m = 1.0
recycle_duct_area_m2 = 0.002
recycle_duct_length_m = 2.0
discharge_duct_area_m2 = 0.0045
discharge_duct_length_m = 2.0
downstream_pressure_pa = 100000.0
check_valve = false

[recycle_system.feed.valve]
upstream_pressure_pa = 100000.0
density_kg_m3 = 1.2
[recycle_system.feed.valve.valve]
cv_max_m2 = 1.6e-3
characteristic = "linear"
stroke_time_s = 4.0
positioner_lag_s = 0.05

[recycle_system.recycle_valve]
cv_max_m2 = 3.6e-3                 # 1.2e-3 in hemchi2016
characteristic = "linear"
min_opening = 1e-3
stroke_time_s = 0.05               # 1.0 in hemchi2016: a slam-open anti-surge valve
positioner_lag_s = 0.005           # 0.02 in hemchi2016

[recycle_system.throttle]
cv_max_m2 = 2.0e-3
characteristic = "linear"
stroke_time_s = 0.02               # 4.0 in hemchi2016: the throttle step is a step
positioner_lag_s = 0.005           # 0.05 in hemchi2016

[initial]
throttle = 0.6
recycle_valve = 0.0
feed = 1.0

[integration]
method = "rosenbrock"
rtol = 1e-4
substeps = 1
"#;

/// What the daemon is told about the machine: a vendor-style machine file (README
/// "Commissioning from vendor data"), as on a foreign skid: the speed-line map, the flow
/// element, the design suction conditions (`{p_s}`: the device's steady suction pressure),
/// the recycle valve, and a drive on its own governor (the device's). No law settings.
const MACHINE_FOR_THE_DAEMON: &str = r#"
name = "fast_skid"
[gas]
molar_mass_kg_mol = 0.02897
heat_capacity_ratio = 1.4
polytropic_exponent = 0.3
[speed_line_map]
file = "{map}"
[flow_element]
flow_coefficient = 0.6
bore_diameter_m = 0.09
[design]
suction_pressure_pa = {p_s}
suction_temperature_k = 293.15
speed_rad_s = 3140.0
[recycle_valve]
stroke_time_s = 0.05
cv_max_m2 = 3.6e-3
[drive]
owned_by_controller = false
"#;

/// The device's register map (the shipped `config/signals_modbus.toml` layout, sensors in SI
/// units, f32 high word first): input registers 0–10, the valve command at holding 102. The
/// drive has its own speed governor in the device (the machine file says so): the daemon
/// writes no torque.
const SIGNAL_MAP: &str = r#"
[sensors]
p_suction = { modbus = { unit_id = 1, table = "input", address = 0, data_type = "f32" } }
p_discharge = { modbus = { unit_id = 1, table = "input", address = 2, data_type = "f32" } }
shaft_speed = { modbus = { unit_id = 1, table = "input", address = 4, data_type = "f32" } }
orifice_dp = { modbus = { unit_id = 1, table = "input", address = 6, data_type = "f32" } }
t_suction = { modbus = { unit_id = 1, table = "input", address = 8, data_type = "i16", scale = 0.01, offset = 273.15 } }
recycle_valve_position = { modbus = { unit_id = 1, table = "input", address = 9, data_type = "u16", scale = 1e-4 } }
throttle_position = { modbus = { unit_id = 1, table = "input", address = 10, data_type = "u16", scale = 1e-4 } }

[actuators]
recycle_valve = { modbus = { unit_id = 1, table = "holding", address = 102, data_type = "u16", scale = 1e-4 } }

[feedback]
recycle_valve = { tolerance = 0.05, time_ms = 100, readback = true }
"#;

/// The vote cases' map: [`SIGNAL_MAP`] with Δp transmitters `b` (input 11) and, for three,
/// `c` (input 13) voting with `a` (input 6): issue 23, item 5.
fn vote_map(three: bool) -> String {
    let c = if three {
        "c = { modbus = { unit_id = 1, table = \"input\", address = 13, data_type = \"f32\" } }\n"
    } else {
        ""
    };
    format!(
        "{SIGNAL_MAP}\n[vote.orifice_dp]\nb = {{ modbus = {{ unit_id = 1, table = \"input\", address = 11, data_type = \"f32\" }} }}\n{c}"
    )
}

/// What a redundant Δp transmitter of the device does (outside its fault: the Δp with its
/// own noise).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Transmitter {
    /// Not bound (the case's map has no vote).
    Absent,
    /// Repeats the value it read at `from` until `to`, plant time, s.
    Frozen(f64, f64),
    /// Reads `factor` × the Δp.
    Biased(f64),
    /// Reads no value (an f32 NaN) from plant time `from` on.
    Failed(f64),
}

/// One real-time case at a time (see the module comment).
static REAL_TIME: Mutex<()> = Mutex::new(());

fn real_time() -> MutexGuard<'static, ()> {
    REAL_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

/// splitmix64: the deterministic pseudo-random sequences of latency and noise.
#[derive(Debug, Clone)]
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Rng {
        Rng(seed ^ 0x5DEE_CE66_D1CE_4E5B)
    }
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [-1, 1).
    fn symmetric(&mut self) -> f64 {
        2.0 * self.unit() - 1.0
    }
}

/// Write the device's plant file and the daemon's machine file (into `dir`); returns the
/// machine file's path and the loaded plant.
fn machine(dir: &Path) -> (PathBuf, PlantDescription) {
    let map = common::root().join("config/maps/hemchi2016_vortech.csv");
    let map = map.display().to_string();
    let plant_path = dir.join("fast_plant.toml");
    std::fs::write(&plant_path, MACHINE.replace("{map}", &map)).expect("write plant file");
    let desc = PlantDescription::load(&plant_path).unwrap_or_else(|e| panic!("{e}"));
    let p_s = PlantLoop::new(
        &desc,
        Throttle::Step {
            at_s: 0.0,
            to: THROTTLE_START,
        },
    )
    .plant
    .truth()
    .p_suction_pa;
    let machine_path = dir.join("fast_skid_machine.toml");
    let text = MACHINE_FOR_THE_DAEMON
        .replace("{map}", &map)
        .replace("{p_s}", &format!("{p_s:.1}"));
    std::fs::write(&machine_path, text).expect("write machine file");
    (machine_path, desc)
}

/// The throttle opening the process demands, against plant time.
#[derive(Debug, Clone, Copy)]
enum Throttle {
    /// From `THROTTLE_START` to `to` at `at_s`.
    Step { at_s: f64, to: f64 },
    /// Linear from `THROTTLE_START` at `at_s` to `to` at `at_s + over_s`.
    Ramp { at_s: f64, over_s: f64, to: f64 },
}

impl Throttle {
    fn at(self, t_s: f64) -> f64 {
        match self {
            Throttle::Step { at_s, to } => {
                if t_s >= at_s {
                    to
                } else {
                    THROTTLE_START
                }
            }
            Throttle::Ramp { at_s, over_s, to } => {
                let f = ((t_s - at_s) / over_s).clamp(0.0, 1.0);
                THROTTLE_START + f * (to - THROTTLE_START)
            }
        }
    }
    fn start_s(self) -> f64 {
        match self {
            Throttle::Step { at_s, .. } | Throttle::Ramp { at_s, .. } => at_s,
        }
    }
}

/// What the recycle valve does in the in-process oracle runs.
#[derive(Debug, Clone, Copy)]
enum OracleValve {
    /// Held at its initial opening.
    Held,
    /// Commanded fully open this long after the throttle step, s.
    OpenAfter(f64),
}

/// Figures of one run, on the plant's true state from the disturbance on.
#[derive(Debug, Clone, Default)]
struct Figures {
    /// Cycles of the detector's count during which the true operating point reached the surge
    /// line (a flow reversal, or a limit cycle whose swing took the point to or past the line).
    surge_cycles: u32,
    reversals: u32,
    /// Cycles the detector counted (a 0.3–30 Hz swing of more than 5 % of the mean flow)
    /// with the point right of the surge line all along: the valve hunting, not surge.
    hunting_cycles: u32,
    /// Smallest true compressor flow, kg/s.
    min_flow_kg_s: f64,
    /// Smallest true surge margin (flow − surge-line flow at the pressure ratio, over the
    /// latter), fraction.
    min_margin: f64,
    /// Time from the disturbance to the first flow below zero, s (NaN: none).
    reversal_after_s: f64,
    /// Largest valve command applied and largest stem position, fraction.
    max_valve_cmd: f64,
    max_valve_pos: f64,
    /// Time from the disturbance until the stem first moved 5 % open, s (NaN: never).
    valve_5pct_after_s: f64,
    /// Final valve position and flow.
    final_valve_pos: f64,
    final_flow_kg_s: f64,
}

impl Figures {
    fn new() -> Figures {
        Figures {
            min_flow_kg_s: f64::INFINITY,
            min_margin: f64::INFINITY,
            reversal_after_s: f64::NAN,
            valve_5pct_after_s: f64::NAN,
            ..Figures::default()
        }
    }
}

impl std::fmt::Display for Figures {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "surge cycles {} (reversals {}, hunting cycles right of the surge line {}) · min flow {:.4} kg/s · closest approach {:+.1} % surge margin · first reversal {} · valve: cmd max {:.1} %, stem max {:.1} %, 5 % open after {}, final {:.1} % · final flow {:.4} kg/s",
            self.surge_cycles,
            self.reversals,
            self.hunting_cycles,
            self.min_flow_kg_s,
            100.0 * self.min_margin,
            ms(self.reversal_after_s),
            100.0 * self.max_valve_cmd,
            100.0 * self.max_valve_pos,
            ms(self.valve_5pct_after_s),
            100.0 * self.final_valve_pos,
            self.final_flow_kg_s,
        )
    }
}

fn ms(t_s: f64) -> String {
    if t_s.is_finite() {
        format!("{:.0} ms", t_s * 1e3)
    } else {
        "never".into()
    }
}

/// The plant with its drive governor, surge detector and figures: shared by the oracle (in
/// process) and the device (paced by the wall clock).
struct PlantLoop<'a> {
    desc: &'a PlantDescription,
    plant: SimPlant,
    inputs: PlantInputs,
    governor: SpeedLoop,
    detector: SurgeDetector,
    /// Smallest true surge margin since the detector last counted a cycle.
    episode_min_margin: f64,
    /// Counted cycles that reached the surge line, and those that did not.
    surge_cycles: u32,
    hunting_cycles: u32,
    figures: Figures,
    throttle: Throttle,
    k: u64,
}

impl<'a> PlantLoop<'a> {
    fn new(desc: &'a PlantDescription, throttle: Throttle) -> PlantLoop<'a> {
        let mut inputs = PlantInputs {
            throttle_process: THROTTLE_START,
            recycle_manual: desc.file.initial.recycle_valve,
            ..PlantInputs::default()
        };
        inputs.feed = desc.file.initial.feed;
        let plant = SimPlant::new(desc, &inputs).unwrap_or_else(|e| panic!("{e}"));
        let d = desc.file.drive;
        let governor = SpeedLoop::new(
            d.speed_kp_nm_s_rad,
            d.speed_ki_nm_rad,
            (d.min_torque_nm, d.rated_torque_nm),
            plant.truth().load_torque_nm,
        );
        PlantLoop {
            desc,
            plant,
            inputs,
            governor,
            detector: SurgeDetector::new(DetectorConfig::default()),
            episode_min_margin: f64::INFINITY,
            surge_cycles: 0,
            hunting_cycles: 0,
            figures: Figures::new(),
            throttle,
            k: 0,
        }
    }

    fn t_s(&self) -> f64 {
        self.k as f64 * PLANT_STEP_S
    }

    /// One step with the recycle valve commanded to `valve_cmd` (NaN: not commanded yet, the
    /// valve stays at its initial opening).
    fn step(&mut self, valve_cmd: f64) {
        let t = self.t_s();
        let nominal = self.desc.file.drive.nominal_speed_rad_s;
        let omega = self.plant.truth().omega_rad_s;
        let torque = self.governor.update(nominal, omega, 0.0, PLANT_STEP_S);
        self.inputs.commands.set(ActuatorId::DriveTorque, torque);
        self.inputs
            .commands
            .set(ActuatorId::RecycleValve, valve_cmd);
        self.inputs.throttle_process = self.throttle.at(t);
        self.plant.step(&self.inputs, PLANT_STEP_S);
        self.k += 1;
        let t = self.t_s();
        let truth = self.plant.truth();
        let surge = self
            .desc
            .map
            .surge_line
            .flow_at_ratio(truth.pressure_ratio());
        let margin = (truth.flow_map - surge) / surge;
        self.episode_min_margin = self.episode_min_margin.min(margin);
        let counted = self.detector.surge_cycles;
        self.detector.update(t, PLANT_STEP_S, truth.m_kg_s);
        let new_cycles = self.detector.surge_cycles - counted;
        if new_cycles > 0 {
            // the surge line separates the stable region from the unstable one (seed 002 §2.2,
            // zero slope of the pressure rise): a swing that kept the point right of it all
            // along is forced by the valve (hunting), a swing that reached it is surge
            if self.episode_min_margin <= 0.0 || truth.m_kg_s < 0.0 {
                self.surge_cycles += new_cycles;
            } else {
                self.hunting_cycles += new_cycles;
            }
            self.episode_min_margin = margin;
        }
        let since = t - self.throttle.start_s();
        if since >= 0.0 {
            let fg = &mut self.figures;
            fg.surge_cycles = self.surge_cycles;
            fg.hunting_cycles = self.hunting_cycles;
            fg.reversals = self.detector.reversals;
            fg.min_flow_kg_s = fg.min_flow_kg_s.min(truth.m_kg_s);
            fg.min_margin = fg.min_margin.min(margin);
            if fg.reversal_after_s.is_nan() && truth.m_kg_s < 0.0 {
                fg.reversal_after_s = since;
            }
            if valve_cmd.is_finite() {
                fg.max_valve_cmd = fg.max_valve_cmd.max(valve_cmd);
            }
            fg.max_valve_pos = fg.max_valve_pos.max(truth.recycle_valve_position);
            if fg.valve_5pct_after_s.is_nan()
                && truth.recycle_valve_position >= self.desc.file.initial.recycle_valve + 0.05
            {
                fg.valve_5pct_after_s = since;
            }
            fg.final_valve_pos = truth.recycle_valve_position;
            fg.final_flow_kg_s = truth.m_kg_s;
        }
    }
}

/// The oracle: the plant in process (no network), throttle stepped at 0.5 s, the valve held
/// or slammed open, 3 s.
fn oracle(desc: &PlantDescription, valve: OracleValve) -> Figures {
    let step_at_s = 0.5;
    let mut p = PlantLoop::new(
        desc,
        Throttle::Step {
            at_s: step_at_s,
            to: THROTTLE_END,
        },
    );
    let n = (3.0 / PLANT_STEP_S).round() as u64;
    for _ in 0..n {
        let t = p.t_s();
        let cmd = match valve {
            OracleValve::OpenAfter(after_s) if t >= step_at_s + after_s - 1e-9 => 1.0,
            _ => f64::NAN,
        };
        p.step(cmd);
    }
    p.figures
}

// ---------------------------------------------------------------------------------------------
// The device

/// One valve command the daemon wrote, as the device applied it.
#[derive(Debug, Clone, Copy)]
struct ValveWrite {
    /// Plant time when it was applied, s.
    t_s: f64,
    /// Commanded opening, fraction.
    cmd: f64,
    /// The stem position the device last reported to the daemon (in the last read answered
    /// before this write), fraction.
    reported_pos: f64,
    /// The stem position at the write, fraction.
    pos_now: f64,
}

/// The device's state, shared by its plant thread and its Modbus service.
#[derive(Debug)]
struct DeviceState {
    /// Input registers 0–10 as the plant last published them.
    words: [u16; INPUT_WORDS],
    /// The valve command last written, fraction (NaN: never).
    valve_cmd: f64,
    /// Every valve write.
    writes: Vec<ValveWrite>,
    /// Stem position in the last read answered, fraction.
    reported_pos: f64,
    /// Reads answered.
    reads: u64,
    /// Plant time, s.
    t_s: f64,
    /// Stem position now, fraction.
    pos: f64,
    /// Latency sequence.
    latency: Rng,
    /// When set, writes are not applied (the valve held: the sanity case).
    ignore_writes: bool,
    /// Every answer comes this much later over [from, to), plant time, s.
    slow: Option<(f64, f64, f64)>,
}

type Shared = Arc<Mutex<DeviceState>>;

fn lock(s: &Shared) -> MutexGuard<'_, DeviceState> {
    s.lock().unwrap_or_else(|e| e.into_inner())
}

fn f32_words(v: f64) -> [u16; 2] {
    let b = (v as f32).to_bits();
    [(b >> 16) as u16, b as u16]
}

fn fraction_word(v: f64) -> u16 {
    (v * 1e4).round().clamp(0.0, 65535.0) as u16
}

/// The Modbus service of the device: every request answered (or applied) after the next
/// latency of its sequence.
#[derive(Clone)]
struct DeviceService(Shared);

type ServiceFuture = Pin<Box<dyn Future<Output = Result<Option<Response>, ExceptionCode>> + Send>>;

impl tokio_modbus::server::Service for DeviceService {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = ServiceFuture;

    fn call(&self, req: Self::Request) -> Self::Future {
        let shared = Arc::clone(&self.0);
        let delay = {
            let mut s = lock(&shared);
            let u = s.latency.unit();
            let late_s = match s.slow {
                Some((from, to, late_s)) if s.t_s >= from && s.t_s < to => late_s,
                _ => 0.0,
            };
            Duration::from_secs_f64(LATENCY_MIN_S + u * (LATENCY_MAX_S - LATENCY_MIN_S) + late_s)
        };
        if req.slave != 1 {
            return Box::pin(std::future::ready(Err(ExceptionCode::GatewayTargetDevice)));
        }
        match req.request {
            Request::ReadInputRegisters(addr, cnt) => {
                let (a, n) = (usize::from(addr), usize::from(cnt));
                if n == 0 || a + n > INPUT_WORDS {
                    return Box::pin(std::future::ready(Err(ExceptionCode::IllegalDataAddress)));
                }
                // the values at the request's arrival, answered `delay` later
                let (words, pos) = {
                    let s = lock(&shared);
                    (s.words[a..a + n].to_vec(), s.words[9])
                };
                Box::pin(async move {
                    tokio::time::sleep(delay).await;
                    let mut s = lock(&shared);
                    if (a..a + n).contains(&9) {
                        s.reported_pos = f64::from(pos) * 1e-4;
                    }
                    s.reads += 1;
                    Ok(Some(Response::ReadInputRegisters(words)))
                })
            }
            Request::ReadHoldingRegisters(addr, 1) if addr == VALVE_HOLDING => {
                // the setpoint register reads back what was last written (by anyone)
                Box::pin(async move {
                    tokio::time::sleep(delay).await;
                    let cmd = lock(&shared).valve_cmd;
                    let word = if cmd.is_finite() {
                        fraction_word(cmd)
                    } else {
                        0
                    };
                    Ok(Some(Response::ReadHoldingRegisters(vec![word])))
                })
            }
            Request::WriteSingleRegister(addr, word) if addr == VALVE_HOLDING => {
                Box::pin(async move {
                    tokio::time::sleep(delay).await;
                    apply_valve_write(&shared, word);
                    Ok(Some(Response::WriteSingleRegister(addr, word)))
                })
            }
            Request::WriteMultipleRegisters(addr, ref words)
                if addr == VALVE_HOLDING && words.len() == 1 =>
            {
                let word = words[0];
                Box::pin(async move {
                    tokio::time::sleep(delay).await;
                    apply_valve_write(&shared, word);
                    Ok(Some(Response::WriteMultipleRegisters(addr, 1)))
                })
            }
            Request::WriteSingleRegister(..) | Request::WriteMultipleRegisters(..) => {
                Box::pin(std::future::ready(Err(ExceptionCode::IllegalDataAddress)))
            }
            _ => Box::pin(std::future::ready(Err(ExceptionCode::IllegalFunction))),
        }
    }
}

fn apply_valve_write(shared: &Shared, word: u16) {
    let mut s = lock(shared);
    let cmd = f64::from(word) * 1e-4;
    let w = ValveWrite {
        t_s: s.t_s,
        cmd,
        reported_pos: s.reported_pos,
        pos_now: s.pos,
    };
    s.writes.push(w);
    if !s.ignore_writes {
        s.valve_cmd = cmd;
    }
}

/// Serve the device on `listener` until the returned task is aborted (which closes the
/// listener and every connection).
fn serve(listener: tokio::net::TcpListener, shared: Shared) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let server = tokio_modbus::server::tcp::Server::new(listener);
        let on_connected = move |stream: tokio::net::TcpStream, _peer: SocketAddr| {
            let service = DeviceService(Arc::clone(&shared));
            async move {
                stream.set_nodelay(true)?;
                Ok(Some((service, stream)))
            }
        };
        let _ = server.serve(&on_connected, |_e| {}).await;
    })
}

/// One real-time case.
#[derive(Debug, Clone, Copy)]
struct Case {
    name: &'static str,
    /// The daemon's poll (and control) rate, Hz.
    poll_hz: f64,
    throttle: Throttle,
    /// Plant time at which the case ends, s.
    end_s: f64,
    /// Δp noise: uniform, ± this, Pa, a new value every plant step; and its seed.
    dp_noise_pa: f64,
    noise_seed: u64,
    /// Latency sequence seed.
    latency_seed: u64,
    /// The Δp register frozen over [from, to), plant time, s.
    dp_frozen: Option<(f64, f64)>,
    /// The link dropped over [from, to), plant time, s.
    outage: Option<(f64, f64)>,
    /// Repeated outages: (first at, every, each lasting, how many), plant time, s.
    outages: Option<(f64, f64, f64, u32)>,
    /// Another Modbus master writes the valve's setpoint to 0 over [from, to), plant time, s.
    second_writer: Option<(f64, f64)>,
    /// No daemon; the valve held (the sanity case).
    no_daemon: bool,
    /// The device answers this much later over [from, to), plant time: (from, to, late), s.
    slow: Option<(f64, f64, f64)>,
    /// Plant time at which a side thread takes `antisurge status --json` and `antisurge
    /// status`, s.
    status_at_s: Option<f64>,
    /// The daemon's Modbus request timeout, ms (None: the default, 100 ms).
    client_timeout_ms: Option<u64>,
    /// The redundant Δp transmitters `b` and `c` (Absent: no vote).
    dp_b: Transmitter,
    dp_c: Transmitter,
    /// `bus.modbus.command_connection`: "own" (the commands on a second connection, so none
    /// waits behind a read on this device that answers one request after the other) or
    /// "shared".
    command_connection: &'static str,
}

impl Case {
    /// Whether the link is down at plant time `t`.
    fn link_down_at(&self, t: f64) -> bool {
        let single = self.outage.is_some_and(|(from, to)| t >= from && t < to);
        let repeated = self.outages.is_some_and(|(first, every, lasting, n)| {
            let k = ((t - first) / every).floor();
            t >= first && k < f64::from(n) && t - first - k * every < lasting
        });
        single || repeated
    }

    fn new(name: &'static str, poll_hz: f64, throttle: Throttle, end_s: f64) -> Case {
        Case {
            name,
            poll_hz,
            throttle,
            end_s,
            dp_noise_pa: 0.0,
            noise_seed: 0,
            latency_seed: 1,
            dp_frozen: None,
            outage: None,
            outages: None,
            second_writer: None,
            no_daemon: false,
            slow: None,
            status_at_s: None,
            client_timeout_ms: None,
            dp_b: Transmitter::Absent,
            dp_c: Transmitter::Absent,
            command_connection: "own",
        }
    }
}

/// What a real-time case returns.
struct Outcome {
    figures: Figures,
    writes: Vec<ValveWrite>,
    reads: u64,
    /// Plant time the plant lagged the wall clock by at most, s (printed, never asserted).
    max_lag_s: f64,
    dir: tempfile::TempDir,
    /// `antisurge status --json` at the end of the run, before and after an `ack` (cases with
    /// a second writer only).
    status_at_end: Option<(serde_json::Value, serde_json::Value)>,
    /// `antisurge status --json` at the end of a slow-device case (its latency window still
    /// holds the slow answers).
    status_slow: Option<serde_json::Value>,
    /// When the device went slow (this machine's clock).
    slow_started: Option<std::time::SystemTime>,
    /// `antisurge status --json` and `antisurge status` at `Case::status_at_s`.
    status_mid: Option<(serde_json::Value, String)>,
}

/// The daemon's config: defaults except what the skid needs (bus and map, the machine,
/// margin 10 %, the poll rate and the control rate with it, input freshness for that poll),
/// and the status socket in the test's directory with the metrics and HMI listeners off (they
/// bind fixed ports by default).
fn daemon_config(dir: &Path, machine: &Path, map: &Path, port: u16, case: &Case) -> PathBuf {
    let poll_hz = case.poll_hz;
    let timeout = case
        .client_timeout_ms
        .map(|t| format!("\ntimeout_ms = {t}"))
        .unwrap_or_default();
    // freshness: the device answers in up to 20 ms, one request after another, so a value
    // can be 2 poll periods + 2 latencies old; 200 ms as the project's other Modbus tests
    let inputs = [
        ("p_suction", 1.0e4, 1.0e6),
        ("p_discharge", 1.0e4, 1.0e6),
        ("shaft_speed", 0.0, 5000.0),
        ("orifice_dp", -1.0e5, 1.0e5),
        // (without its own timeout t_suction kept the 50-ms default: the tightest budget of
        // all, which a healthy device answering three requests of up to 20 ms each in one
        // link cycle can exceed)
        ("t_suction", 200.0, 400.0),
        ("recycle_valve_position", -0.05, 1.05),
        ("throttle_position", -0.05, 1.05),
    ]
    .iter()
    .map(|(n, lo, hi)| format!("[inputs.{n}]\nmin = {lo:e}\nmax = {hi:e}\ntimeout_ms = 200.0\n"))
    .collect::<String>();
    let cfg = format!(
        r#"
[machine]
file = "{machine}"
[control]
law = "recycle-pi"
[cycle]
rate_hz = {poll_hz:.1}
lock_memory = false
{inputs}
[bus]
transport = "field"
signal_map = "{map}"
[bus.modbus]
poll_rate_hz = {poll_hz:.1}
command_connection = "{cc}"
[bus.modbus.client]
transport = {{ kind = "tcp", address = "127.0.0.1:{port}" }}{timeout}
[controller.recycle_pi]
control_line = {{ margin = {{ margin_pct = 10.0 }} }}
[event_log]
path = "{events}"
[status]
log_interval_s = 5.0
socket = "{socket}"
operator_token_file = "{token}"
metrics_listen = ""
hmi_listen = ""
"#,
        machine = machine.display(),
        map = map.display(),
        events = dir.join("events.jsonl").display(),
        socket = dir.join("status.sock").display(),
        token = dir.join("operator.token").display(),
        cc = case.command_connection,
    );
    let path = dir.join("antisurge.toml");
    std::fs::write(&path, cfg).expect("write config");
    path
}

/// Run one case in real time: the device (plant thread + Modbus server), the daemon against
/// it, the disturbances; returns the plant's figures and the valve writes.
fn run_case(case: Case) -> Outcome {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path().to_path_buf();
    let (machine_path, desc) = machine(&dir);
    let map_path = dir.join("signal_map.toml");
    let map = match (case.dp_b, case.dp_c) {
        (Transmitter::Absent, _) => SIGNAL_MAP.to_string(),
        (_, Transmitter::Absent) => vote_map(false),
        _ => vote_map(true),
    };
    std::fs::write(&map_path, map).expect("write map");
    {
        use std::os::unix::fs::PermissionsExt;
        let token = dir.join("operator.token");
        std::fs::write(&token, "e2e-token\n").expect("token");
        std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    }

    let shared: Shared = Arc::new(Mutex::new(DeviceState {
        words: [0; INPUT_WORDS],
        valve_cmd: f64::NAN,
        writes: Vec::new(),
        reported_pos: f64::NAN,
        reads: 0,
        t_s: 0.0,
        pos: desc.file.initial.recycle_valve,
        latency: Rng::new(case.latency_seed),
        ignore_writes: case.no_daemon,
        slow: case.slow,
    }));

    // the Modbus side: its own runtime, one worker
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime");
    let listener = rt
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .expect("bind port 0");
    let port = listener.local_addr().expect("addr").port();
    let server = Arc::new(Mutex::new(Some(rt.enter_and_serve(listener, &shared))));

    let mut daemon = (!case.no_daemon).then(|| {
        let cfg = daemon_config(&dir, &machine_path, &map_path, port, &case);
        spawn(
            &dir,
            "run",
            &["run", "--config", &cfg.display().to_string()],
        )
    });

    // the plant thread, paced by the wall clock; the link outage is switched from here
    let (figures, max_lag_s, slow_started, status_mid) = {
        let shared = Arc::clone(&shared);
        let mut p = PlantLoop::new(&desc, case.throttle);
        let mut noise = Rng::new(case.noise_seed);
        let mut frozen_dp = f64::NAN;
        let mut frozen_spare = [f64::NAN; 2];
        let mut link_down = false;
        let mut slow_started = None;
        let n = (case.end_s / PLANT_STEP_S).round() as u64;
        let t0 = Instant::now();
        let status_side = case.status_at_s.map(|at_s| {
            let dir = dir.clone();
            std::thread::spawn(move || {
                let due = Duration::from_secs_f64(at_s);
                if let Some(wait) = due.checked_sub(t0.elapsed()) {
                    std::thread::sleep(wait);
                }
                let sock = dir.join("status.sock").display().to_string();
                let human = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
                    .args(["status", "--socket", &sock])
                    .output()
                    .map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
                    .unwrap_or_default();
                (status_json(&dir), human)
            })
        });
        let mut max_lag_s: f64 = 0.0;
        for k in 0..n {
            let due = Duration::from_secs_f64(k as f64 * PLANT_STEP_S);
            let elapsed = t0.elapsed();
            if let Some(wait) = due.checked_sub(elapsed) {
                std::thread::sleep(wait);
            } else {
                max_lag_s = max_lag_s.max((elapsed - due).as_secs_f64());
            }
            let t = p.t_s();
            if case.outage.is_some() || case.outages.is_some() {
                let down = case.link_down_at(t);
                if down && !link_down {
                    // stop answering: listener and connections closed
                    if let Some(h) = lock_server(&server).take() {
                        h.abort();
                        let _ = rt.block_on(h);
                    }
                } else if !down && link_down {
                    let l = rt
                        .block_on(tokio::net::TcpListener::bind(("127.0.0.1", port)))
                        .expect("rebind the device's port");
                    *lock_server(&server) = Some(rt.enter_and_serve(l, &shared));
                }
                link_down = down;
            }
            if let Some((from, to)) = case.second_writer {
                if t >= from && t < to {
                    // the other master's write lands after the daemon's: the setpoint is 0
                    lock(&shared).valve_cmd = 0.0;
                }
            }
            if let Some((from, ..)) = case.slow {
                if t >= from && slow_started.is_none() {
                    slow_started = Some(std::time::SystemTime::now());
                }
            }
            let cmd = lock(&shared).valve_cmd;
            p.step(cmd);
            // publish what the transmitters read
            let s = p.plant.sensors();
            let t = p.t_s();
            let mut dp = s.get(SensorId::OrificeDp) + case.dp_noise_pa * noise.symmetric();
            match case.dp_frozen {
                Some((from, to)) if t >= from && t < to => {
                    if frozen_dp.is_nan() {
                        frozen_dp = dp;
                    }
                    dp = frozen_dp;
                }
                _ => frozen_dp = f64::NAN,
            }
            let mut w = [0u16; INPUT_WORDS];
            w[0..2].copy_from_slice(&f32_words(s.get(SensorId::PSuction)));
            w[2..4].copy_from_slice(&f32_words(s.get(SensorId::PDischarge)));
            w[4..6].copy_from_slice(&f32_words(s.get(SensorId::ShaftSpeed)));
            w[6..8].copy_from_slice(&f32_words(dp));
            w[8] = ((s.get(SensorId::TSuction) - 273.15) * 100.0).round() as i16 as u16;
            w[9] = fraction_word(s.get(SensorId::RecycleValvePosition));
            w[10] = fraction_word(s.get(SensorId::ThrottlePosition));
            // the redundant Δp transmitters, each with its own noise and fault
            for (k, tx) in [case.dp_b, case.dp_c].into_iter().enumerate() {
                if tx == Transmitter::Absent {
                    continue;
                }
                let own = s.get(SensorId::OrificeDp) + case.dp_noise_pa * noise.symmetric();
                let v = match tx {
                    Transmitter::Frozen(from, to) if t >= from && t < to => {
                        if frozen_spare[k].is_nan() {
                            frozen_spare[k] = own;
                        }
                        frozen_spare[k]
                    }
                    Transmitter::Biased(f) => f * own,
                    Transmitter::Failed(from) if t >= from => f64::NAN,
                    _ => {
                        frozen_spare[k] = f64::NAN;
                        own
                    }
                };
                w[11 + 2 * k..13 + 2 * k].copy_from_slice(&f32_words(v));
            }
            let mut st = lock(&shared);
            st.words = w;
            st.t_s = t;
            st.pos = s.get(SensorId::RecycleValvePosition);
        }
        let status_mid = status_side.map(|h| h.join().expect("status thread"));
        (p.figures, max_lag_s, slow_started, status_mid)
    };

    // the device still answers (its last values): the status, then an acknowledgement
    let status_slow = (case.slow.is_some() && daemon.is_some()).then(|| status_json(&dir));
    let status_at_end = (case.second_writer.is_some() && daemon.is_some()).then(|| {
        let before = status_json(&dir);
        let sock = dir.join("status.sock").display().to_string();
        let tf = dir.join("operator.token").display().to_string();
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
            .args(["operate", "--socket", &sock, "--token-file", &tf, "ack"])
            .output()
            .expect("operate ack");
        assert!(out.status.success(), "ack refused: {out:?}");
        // the feedback task checks every 10 ms; poll the status until it has (bounded)
        let mut after = status_json(&dir);
        for _ in 0..100 {
            if after["field_faults"]
                .as_array()
                .is_some_and(|a| a.is_empty())
            {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
            after = status_json(&dir);
        }
        (before, after)
    });

    if let Some(d) = daemon.as_mut() {
        signal(d, libc::SIGTERM);
        let _ = wait(d, Duration::from_secs(20), "controller", &dir);
    }
    if let Some(h) = lock_server(&server).take() {
        h.abort();
    }
    drop(rt);
    if let Some(keep) = std::env::var_os("ANTISURGE_E2E_KEEP") {
        // (debugging: keep the run's files, e.g. the black box around the disturbance)
        let to = PathBuf::from(keep).join(format!(
            "{}-{:.0}hz-{}",
            case.name.replace(' ', "_"),
            case.poll_hz,
            case.noise_seed
        ));
        let _ = std::process::Command::new("cp")
            .arg("-r")
            .arg(&dir)
            .arg(&to)
            .status();
    }
    let st = lock(&shared);
    Outcome {
        figures,
        writes: st.writes.clone(),
        reads: st.reads,
        max_lag_s,
        dir: tmp,
        status_at_end,
        status_slow,
        slow_started,
        status_mid,
    }
}

/// `antisurge status --json` of the daemon in `dir`.
fn status_json(dir: &Path) -> serde_json::Value {
    let sock = dir.join("status.sock").display().to_string();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(["status", "--json", "--socket", &sock])
        .output()
        .expect("antisurge status");
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "status --json: {e}: {}",
            String::from_utf8_lossy(&out.stderr)
        )
    })
}

fn lock_server(
    s: &Mutex<Option<tokio::task::JoinHandle<()>>>,
) -> MutexGuard<'_, Option<tokio::task::JoinHandle<()>>> {
    s.lock().unwrap_or_else(|e| e.into_inner())
}

trait ServeOn {
    fn enter_and_serve(
        &self,
        listener: tokio::net::TcpListener,
        shared: &Shared,
    ) -> tokio::task::JoinHandle<()>;
}

impl ServeOn for tokio::runtime::Runtime {
    fn enter_and_serve(
        &self,
        listener: tokio::net::TcpListener,
        shared: &Shared,
    ) -> tokio::task::JoinHandle<()> {
        let _g = self.enter();
        serve(listener, Arc::clone(shared))
    }
}

/// Print a case's figures and the daemon's writes (count, first after the disturbance).
fn report(case: &Case, o: &Outcome) {
    let start = case.throttle.start_s();
    let before = o.writes.iter().filter(|w| w.t_s < start).count();
    let first_after = o
        .writes
        .iter()
        .find(|w| w.t_s >= start && w.cmd > 0.05)
        .map_or("none".to_string(), |w| {
            format!("{:.0} % at +{:.0} ms", 100.0 * w.cmd, 1e3 * (w.t_s - start))
        });
    eprintln!(
        "[{}] {:.0} Hz: {} · writes {} ({} before the disturbance), reads {}, first command > 5 %: {} · plant lag behind the wall clock at most {:.1} ms",
        case.name,
        case.poll_hz,
        o.figures,
        o.writes.len(),
        before,
        o.reads,
        first_after,
        1e3 * o.max_lag_s
    );
}

/// The daemon was in control before the disturbance: it wrote valve commands in the second
/// before it (else the case says nothing about the law).
fn assert_in_control(case: &Case, o: &Outcome) {
    let start = case.throttle.start_s();
    let n = o
        .writes
        .iter()
        .filter(|w| w.t_s >= start - 1.0 && w.t_s < start)
        .count();
    assert!(
        n >= 5,
        "[{}] the daemon wrote {n} valve commands in the second before the disturbance: not in control\n{}",
        case.name,
        logs(o.dir.path())
    );
}

// ---------------------------------------------------------------------------------------------
// Case 1: the oracle, and the sanity of the counting

/// The feasibility oracle's verdict, printed before the runs: the machine reverses its flow
/// within ≈ 80 ms of the throttle step with the valve held (and surges), the valve slammed
/// open 60 ms after the step (two 50-Hz periods + 20 ms latency) holds it, and so does 40 ms
/// (100 Hz); opened 150 ms after the step it does not: the oracle can fail.
#[test]
fn feasibility_oracle_holds_with_the_valve_slammed_open_60_ms_after_the_step() {
    let tmp = tempfile::tempdir().expect("tmp");
    let (_, desc) = machine(tmp.path());
    let held = oracle(&desc, OracleValve::Held);
    let at_60 = oracle(&desc, OracleValve::OpenAfter(0.060));
    let at_40 = oracle(&desc, OracleValve::OpenAfter(0.040));
    let at_150 = oracle(&desc, OracleValve::OpenAfter(0.150));
    // the limit the law's first command must beat (quoted by the step cases)
    let at_65 = oracle(&desc, OracleValve::OpenAfter(0.065));
    let at_70 = oracle(&desc, OracleValve::OpenAfter(0.070));
    eprintln!("oracle, valve open at +65 ms:  {at_65}");
    eprintln!("oracle, valve open at +70 ms:  {at_70}");
    eprintln!("oracle, valve held:            {held}");
    eprintln!("oracle, valve open at +60 ms:  {at_60}");
    eprintln!("oracle, valve open at +40 ms:  {at_40}");
    eprintln!("oracle, valve open at +150 ms: {at_150}");
    eprintln!(
        "feasibility oracle verdict: {} (50 Hz: 2 × 20 ms + 20 ms = 60 ms → {} surge cycles, min flow {:.4} kg/s)",
        if at_60.surge_cycles == 0 { "HOLDS" } else { "DOES NOT HOLD" },
        at_60.surge_cycles,
        at_60.min_flow_kg_s
    );
    // a fast machine: step to reversal with the valve held
    assert!(
        held.surge_cycles > 0 && (0.04..=0.1).contains(&held.reversal_after_s),
        "valve held: {held}"
    );
    assert_eq!(at_60.surge_cycles, 0, "valve open at +60 ms: {at_60}");
    assert!(at_60.min_flow_kg_s > 0.0, "{at_60}");
    assert_eq!(at_40.surge_cycles, 0, "valve open at +40 ms: {at_40}");
    assert!(at_150.surge_cycles > 0, "valve open at +150 ms: {at_150}");
    assert_eq!(at_65.surge_cycles, 0, "valve open at +65 ms: {at_65}");
    assert!(at_70.surge_cycles > 0, "valve open at +70 ms: {at_70}");
}

/// The device's own counting through the whole real-time path: no daemon, the valve held,
/// the throttle step surges the machine and the device counts it.
#[test]
fn the_device_counts_the_surge_of_a_held_valve() {
    let _rt = real_time();
    let mut case = Case::new(
        "sanity: valve held, no daemon",
        100.0,
        Throttle::Step {
            at_s: 1.0,
            to: THROTTLE_END,
        },
        3.0,
    );
    case.no_daemon = true;
    let o = run_case(case);
    report(&case, &o);
    assert!(o.figures.surge_cycles >= 3, "{}", o.figures);
    assert!(o.figures.min_flow_kg_s < 0.0, "{}", o.figures);
}

// ---------------------------------------------------------------------------------------------
// Case 2: the throttle step

fn throttle_step(poll_hz: f64, name: &'static str) {
    let _rt = real_time();
    let case = Case::new(
        name,
        poll_hz,
        Throttle::Step {
            at_s: DISTURBANCE_AT_S,
            to: THROTTLE_END,
        },
        DISTURBANCE_AT_S + 4.0,
    );
    let o = run_case(case);
    report(&case, &o);
    assert_in_control(&case, &o);
    assert_eq!(
        o.figures.surge_cycles,
        0,
        "[{name}] {}\n{}",
        o.figures,
        logs(o.dir.path())
    );
}

/// First run (recycle-pi before the issue-22 rebuild): 8 and 10 surge cycles in two runs, the
/// first command above 5 % 243–256 ms after the step (the oracle needs 60 ms). With the
/// commands on their own connection, 1 surge cycle in 2 of 5 runs (the trip fired on the second
/// sample after the step). With the throttle watch (the throttle position register shows the
/// slam on the first poll after it began): 0 surge cycles, the first command at +39 and +53 ms.
/// Ten further runs on 2026-11-29 (five on the tree before that day's merges, five after):
/// first command at +36 … +77 ms, one surge cycle in 2 of the 10 (at +68 and +70 ms; the flow
/// reverses ≈ 78 ms after the step). At 100 Hz the watch fired later than at 50 Hz (+31 …
/// +47 ms). The black boxes showed why: on a noise-free standstill the trip's horizon lacked
/// the poll period (the sample period was counted over *distinct* values only, and there were
/// none before the step), so a first poll that caught the throttle a quarter of the way
/// through its slam predicted too little and fired nothing; and a late read waited P/2 behind
/// the deadline cycle that stood in for it. With the poll period in the horizon and late reads
/// run at once: 0 surge cycles in 10 of 10 runs, the valve 5 % open 40–70 ms after the step.
#[test]
fn throttle_step_at_100_hz_polling_does_not_surge() {
    throttle_step(100.0, "throttle step");
}

/// First run: 11 surge cycles, the first command above 5 % 272 ms after the step. With the
/// throttle watch: 0 surge cycles, the first command at +35 and +56 ms.
#[test]
fn throttle_step_at_50_hz_polling_does_not_surge() {
    throttle_step(50.0, "throttle step");
}

// ---------------------------------------------------------------------------------------------
// Case 3: noisy closure, Δp frozen for 1 s

/// Δp noise amplitude, Pa: ± 5 % of the ≈ 5 kPa the flow element reads at the start.
const DP_NOISE_PA: f64 = 250.0;

/// The throttle closes 60 % → 10 % over 2 s with ± 250 Pa of Δp noise; the Δp register holds
/// its value from 0.5 s to 1.5 s into the closure. First run: 10 of 10 seeds surged, 3–4 cycles
/// each (the valve tripped fully open ≈ 0.9–1 s into the closure, then closed back into surge
/// ≈ 3.1 s after its start). Issue 23: the freeze is found within 300 ms of the controller's
/// own sample time in every seed, the event names `orifice_dp` and the check, the machine's
/// speed-line map stands in for the flow (no fail-safe), and no event names a sensor the skid
/// does not bind.
fn noisy_closure_with_dp_frozen(poll_hz: f64) {
    let _rt = real_time();
    let mut failed = Vec::new();
    let mut latencies_ms = Vec::new();
    for seed in 1..=10u64 {
        let mut case = Case::new(
            "noisy closure, Δp frozen 1 s",
            poll_hz,
            Throttle::Ramp {
                at_s: DISTURBANCE_AT_S,
                over_s: 2.0,
                to: THROTTLE_END,
            },
            DISTURBANCE_AT_S + 4.5,
        );
        case.dp_noise_pa = DP_NOISE_PA;
        case.noise_seed = seed;
        case.latency_seed = 100 + seed;
        case.dp_frozen = Some((DISTURBANCE_AT_S + 0.5, DISTURBANCE_AT_S + 1.5));
        let o = run_case(case);
        eprint!("seed {seed}: ");
        report(&case, &o);
        assert_in_control(&case, &o);
        if o.figures.surge_cycles > 0 {
            failed.push((seed, o.figures.surge_cycles));
        }
        let dir = o.dir.path();
        let events = std::fs::read_to_string(dir.join("events.jsonl")).expect("event log");
        let found = events.lines().find(|l| {
            l.contains("\"event\":\"fallback_entered\"")
                && l.contains("\"input\":\"orifice_dp\"")
                && l.contains("\"reason\":\"frozen\"")
        });
        assert!(
            found.is_some(),
            "seed {seed}: no frozen orifice_dp event:\n{events}"
        );
        assert!(
            found.is_some_and(|l| l.contains("\"replaced_by\":\"speed_line\"")),
            "seed {seed}: {found:?}"
        );
        // (a fail-safe whose root is the link, when a busy test machine starves the device,
        // is not what this case is about; one caused by the flow element is)
        let flow_failsafe = events.lines().find(|l| {
            l.contains("\"to\":\"fail_safe\"")
                && (l.contains("\"kind\":\"flow_unavailable\"")
                    || l.contains("\"input\":\"orifice_dp\""))
        });
        assert!(
            flow_failsafe.is_none(),
            "seed {seed}: fail-safe although the speed line gives a flow: {flow_failsafe:?}"
        );
        for unbound in ["thrust_position", "drive_torque", "esd_input"] {
            assert!(
                !events.contains(&format!("\"{unbound}\"")),
                "seed {seed}: an event names {unbound}, which this skid does not bind:\n{events}"
            );
        }
        for l in events
            .lines()
            .filter(|l| l.contains("\"to\":\"fail_safe\""))
        {
            eprintln!("seed {seed}: {l}");
        }
        latencies_ms.push(1e3 * detection_latency_s(dir));
    }
    eprintln!(
        "{poll_hz} Hz: frozen Δp found after {latencies_ms:.0?} ms of controller sample time"
    );
    assert!(
        latencies_ms.iter().all(|l| *l <= 300.0),
        "{poll_hz} Hz: detection after {latencies_ms:.0?} ms (≤ 300 ms)"
    );
    assert!(
        failed.is_empty(),
        "surged with (seed, cycles): {failed:?} of 10 seeds"
    );
}

/// From the black box the daemon writes at exit (one clock: the controller's cycle times):
/// the time from the first cycle that read the frozen value to the first cycle in fallback.
fn detection_latency_s(dir: &Path) -> f64 {
    let bb = std::fs::read_dir(dir.join("blackbox"))
        .expect("black-box directory")
        .filter_map(Result::ok)
        .map(|e| e.path())
        .find(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with("blackbox-exit"))
        })
        .expect("black box written at exit");
    let text = std::fs::read_to_string(&bb).expect("black box");
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect(name);
    let (t, dp, age, fb) = (
        col("t_s"),
        col("in_orifice_dp"),
        col("age_s_orifice_dp"),
        col("flow_fallback"),
    );
    let rows: Vec<(f64, f64, f64, bool)> = lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let num = |i: usize| f[i].parse().unwrap_or(f64::NAN);
            (num(t), num(dp), num(age), f[fb] == "1")
        })
        .collect();
    let k_f = rows.iter().position(|r| r.3).expect("a cycle in fallback");
    let frozen = rows[k_f].1;
    // back to the first cycle that read the frozen value fresh (within the inputs' 200-ms
    // freshness: a link that a busy machine let time out is the link's fault, not the check's)
    let mut k_0 = k_f;
    while k_0 > 0 && rows[k_0 - 1].1 == frozen && rows[k_0 - 1].2 <= 0.2 {
        k_0 -= 1;
    }
    rows[k_f].0 - rows[k_0].0
}

#[test]
fn noisy_closure_with_dp_frozen_for_1_s_at_100_hz_is_found_and_does_not_surge_over_10_seeds() {
    noisy_closure_with_dp_frozen(100.0);
}

#[test]
fn noisy_closure_with_dp_frozen_for_1_s_at_50_hz_is_found_and_does_not_surge_over_10_seeds() {
    noisy_closure_with_dp_frozen(50.0);
}

// ---------------------------------------------------------------------------------------------
// Redundant Δp transmitters (issue 23, item 5)

/// The black box the daemon wrote at exit: its columns and rows, on the controller's clock.
struct BlackBox {
    cols: Vec<String>,
    rows: Vec<Vec<f64>>,
}

impl BlackBox {
    fn read(dir: &Path) -> BlackBox {
        let bb = std::fs::read_dir(dir.join("blackbox"))
            .expect("black-box directory")
            .filter_map(Result::ok)
            .map(|e| e.path())
            .find(|p| {
                p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with("blackbox-exit"))
            })
            .expect("black box written at exit");
        let text = std::fs::read_to_string(&bb).expect("black box");
        let mut lines = text.lines().filter(|l| !l.starts_with('#'));
        let cols = lines
            .next()
            .expect("header")
            .split(',')
            .map(str::to_string)
            .collect();
        let rows = lines
            .map(|l| {
                l.split(',')
                    .map(|x| x.parse().unwrap_or(f64::NAN))
                    .collect()
            })
            .collect();
        BlackBox { cols, rows }
    }

    fn col(&self, name: &str) -> Vec<f64> {
        let i = self
            .cols
            .iter()
            .position(|c| c == name)
            .unwrap_or_else(|| panic!("no column {name}"));
        self.rows.iter().map(|r| r[i]).collect()
    }
}

/// The `transmitter` event of `orifice_dp`'s transmitter `t` in `state` by `check`, if any.
fn transmitter_event<'a>(events: &'a str, t: &str, state: &str, check: &str) -> Option<&'a str> {
    events.lines().find(|l| {
        l.contains("\"event\":\"transmitter\"")
            && l.contains("\"input\":\"orifice_dp\"")
            && l.contains(&format!("\"transmitter\":\"{t}\""))
            && l.contains(&format!("\"state\":\"{state}\""))
            && l.contains(&format!("\"check\":\"{check}\""))
    })
}

/// No fail-safe of the run is the flow element's doing (a fail-safe rooted in the link, when
/// a busy test machine starves the device, is not what the vote cases are about).
fn assert_no_flow_failsafe(name: &str, events: &str) {
    let flow_failsafe = events.lines().find(|l| {
        l.contains("\"to\":\"fail_safe\"")
            && (l.contains("\"kind\":\"flow_unavailable\"")
                || l.contains("\"input\":\"orifice_dp\""))
    });
    assert!(
        flow_failsafe.is_none(),
        "[{name}] fail-safe caused by the flow element: {flow_failsafe:?}"
    );
}

/// Issue 23 acceptance: three Δp transmitters on the device, voted by the daemon: `a`
/// healthy, `b` frozen for 1 s during the noisy closure (as the single-transmitter case above),
/// `c` reading 20 % high all along. Asserted at 100 and 50 Hz polling: the vote follows `a`
/// within 300 ms of `b`'s freeze (controller clock, from the black box: the first cycle that
/// read the frozen value to the first cycle from which, until the freeze ends, the vote is
/// `a`'s reading or below it, never `c`'s), `b` is voted out by the frozen check and `c` for
/// its deviation (while `a` and `b` agreed; events naming the transmitter and the check), `a`
/// is never named, no fail-safe from the flow element, zero surge cycles on the device's true
/// flow through the closure.
#[test]
fn three_dp_transmitters_one_frozen_one_biased_the_vote_follows_the_healthy_one() {
    let _rt = real_time();
    for poll_hz in [100.0, 50.0] {
        let mut case = Case::new(
            "three Δp: b frozen 1 s, c +20 %",
            poll_hz,
            Throttle::Ramp {
                at_s: DISTURBANCE_AT_S,
                over_s: 2.0,
                to: THROTTLE_END,
            },
            DISTURBANCE_AT_S + 4.5,
        );
        case.dp_noise_pa = DP_NOISE_PA;
        case.noise_seed = 3;
        case.latency_seed = 103;
        case.dp_b = Transmitter::Frozen(DISTURBANCE_AT_S + 0.5, DISTURBANCE_AT_S + 1.5);
        case.dp_c = Transmitter::Biased(1.2);
        let o = run_case(case);
        report(&case, &o);
        assert_in_control(&case, &o);
        let dir = o.dir.path();
        let events = events_until_shutdown(dir);
        let frozen = transmitter_event(&events, "b", "voted_out", "frozen");
        // c deviates while a and b agree: voted out for it (the deviation alarm)
        let biased = transmitter_event(&events, "c", "voted_out", "deviation");
        eprintln!("[{}] {poll_hz} Hz: {frozen:?}\n{biased:?}", case.name);
        assert!(frozen.is_some(), "b not voted out as frozen:\n{events}");
        assert!(
            biased.is_some(),
            "c not voted out for its deviation:\n{events}"
        );
        let named_a = events.lines().find(|l| {
            l.contains("\"event\":\"transmitter\"")
                && l.contains("\"transmitter\":\"a\"")
                && !l.contains("\"state\":\"healthy\"")
        });
        assert!(
            named_a.is_none(),
            "the healthy transmitter named: {named_a:?}"
        );
        assert_no_flow_failsafe(case.name, &events);
        // the vote against b's freeze, on the controller's clock
        let bb = BlackBox::read(dir);
        let (t, a, b, vote) = (
            bb.col("t_s"),
            bb.col("in_orifice_dp"),
            bb.col("in_orifice_dp_b"),
            bb.col("vote_orifice_dp"),
        );
        // the freeze: the longest run of one reading of b
        let (mut k0, mut k_end, mut run_from) = (0, 0, 0);
        for k in 1..=b.len() {
            if k == b.len() || b[k] != b[run_from] {
                if k - run_from > k_end - k0 {
                    (k0, k_end) = (run_from, k);
                }
                run_from = k;
            }
        }
        // following a: the vote is a's reading, or less (the hold-last vote's last agreed
        // value where a reads more); never more flow than a shows, never c's reading
        let c = bb.col("in_orifice_dp_c");
        let follows = |k: usize| vote[k] <= a[k] && vote[k] != c[k];
        let follows_from = (k0..k_end)
            .rev()
            .take_while(|&k| follows(k))
            .last()
            .expect("the vote follows a before the freeze ends");
        let after_s = t[follows_from] - t[k0];
        let exactly_a = (follows_from..k_end).filter(|&k| vote[k] == a[k]).count();
        eprintln!(
            "[{}] {poll_hz} Hz: from then on the vote is a's reading in {exactly_a} of {} cycles, below it in the others",
            case.name,
            k_end - follows_from
        );
        if after_s > 0.3 {
            for l in events
                .lines()
                .filter(|l| l.contains("\"event\":\"transmitter\""))
            {
                eprintln!("{l}");
            }
            for k in k0..k_end {
                if !follows(k) {
                    eprintln!(
                        "t {:.3} a {} b {} c {} vote {}",
                        t[k], a[k], b[k], c[k], vote[k]
                    );
                }
            }
        }
        eprintln!(
            "[{}] {poll_hz} Hz: b frozen for {:.0} ms of controller time; the vote follows a {:.0} ms after the freeze",
            case.name,
            1e3 * (t[k_end - 1] - t[k0]),
            1e3 * after_s
        );
        assert!(t[k_end - 1] - t[k0] > 0.8, "the freeze is in the black box");
        assert!(
            after_s <= 0.3,
            "the vote follows a {after_s:.3} s after the freeze"
        );
        assert_eq!(
            o.figures.surge_cycles, 0,
            "[{}] {poll_hz} Hz: {}",
            case.name, o.figures
        );
    }
}

/// Issue 23 acceptance: two Δp transmitters, `b` failed (no value) 2.5 s before the noisy
/// closure. Asserted: `b` voted out (`nan`), the vote holds the last agreed value (rule
/// `hold_last`, 1 of 2 valid) with the `vote_degraded` fault, the degraded policy's control-line
/// shift in force (status JSON and text during the closure), no fail-safe from the flow
/// element, zero surge cycles through the closure.
#[test]
fn two_dp_transmitters_one_failed_hold_last_with_a_fault_and_a_wider_margin() {
    let _rt = real_time();
    let mut case = Case::new(
        "two Δp: b failed",
        100.0,
        Throttle::Ramp {
            at_s: DISTURBANCE_AT_S,
            over_s: 2.0,
            to: THROTTLE_END,
        },
        DISTURBANCE_AT_S + 4.5,
    );
    case.dp_noise_pa = DP_NOISE_PA;
    case.noise_seed = 5;
    case.latency_seed = 105;
    case.dp_b = Transmitter::Failed(DISTURBANCE_AT_S - 2.5);
    case.status_at_s = Some(DISTURBANCE_AT_S + 1.0);
    let o = run_case(case);
    report(&case, &o);
    assert_in_control(&case, &o);
    let events = events_until_shutdown(o.dir.path());
    let failed = transmitter_event(&events, "b", "voted_out", "nan");
    eprintln!("[{}] {failed:?}", case.name);
    assert!(
        failed.is_some_and(|l| l.contains("\"rule\":\"hold_last\"")),
        "b not voted out (nan) with the vote holding:\n{events}"
    );
    assert_no_flow_failsafe(case.name, &events);
    let (st, human) = o.status_mid.as_ref().expect("status during the closure");
    let vote = &st["votes"][0];
    eprintln!(
        "[{}] status during the closure: votes {vote} · transmitters {} · policy {} · vote faults {}",
        case.name, st["transmitters"], st["degraded_policy"], st["vote_faults"]
    );
    assert_eq!(vote["measurement"], "orifice_dp", "{st}");
    assert_eq!(vote["rule"], "hold_last", "{st}");
    assert_eq!(
        (vote["valid"].as_u64(), vote["bound"].as_u64()),
        (Some(1), Some(2))
    );
    assert_eq!(vote["degraded"], true);
    let b = &st["transmitters"][1];
    assert_eq!(
        (
            b["binding"].as_str(),
            b["state"].as_str(),
            b["reason"].as_str()
        ),
        (Some("b"), Some("voted_out"), Some("nan")),
        "{st}"
    );
    assert!(
        st["vote_faults"]
            .as_array()
            .is_some_and(|f| f.iter().any(|x| x == "vote_degraded")),
        "{st}"
    );
    let policy = &st["degraded_policy"];
    let shift = policy["margin_shift_pct"].as_f64().unwrap_or(0.0);
    assert!(
        policy["in_force"] == true && shift > 1.0 && shift <= 5.0,
        "{policy}"
    );
    assert!(
        human.contains("vote          orifice_dp 1 of 2 valid, hold-last (degraded)")
            && human.contains("degraded      hold and widen"),
        "{human}"
    );
    assert_eq!(o.figures.surge_cycles, 0, "[{}] {}", case.name, o.figures);
}

// ---------------------------------------------------------------------------------------------
// Case 4: a 3-s link outage

/// First run: the valve stood at 51.2 % when the link dropped; the first command after the
/// resume was the fail-safe 100 %: a 48.8 % step.
#[test]
fn after_a_3_s_link_outage_the_first_valve_command_matches_the_measured_position() {
    let _rt = real_time();
    // a slow partial closure the law holds with the valve part open, then the outage (the
    // device keeps its last setpoint: no device watchdog in this map)
    let mut case = Case::new(
        "3-s link outage",
        100.0,
        Throttle::Ramp {
            at_s: DISTURBANCE_AT_S,
            over_s: 3.0,
            to: 0.2,
        },
        DISTURBANCE_AT_S + 10.5,
    );
    let (down, up) = (DISTURBANCE_AT_S + 4.0, DISTURBANCE_AT_S + 7.0);
    case.outage = Some((down, up));
    // the status 1 s into the outage names the link, down
    case.status_at_s = Some(down + 1.0);
    let o = run_case(case);
    let (st, human) = o.status_mid.clone().expect("status during the outage");
    eprintln!(
        "[{}] status 1 s into the outage: links.modbus = {}, field_faults = {}\n{human}",
        case.name, st["links"]["modbus"], st["field_faults"]
    );
    assert_eq!(st["links"]["modbus"]["state"], "down", "{st}");
    assert!(
        st["links"]["modbus"]["name"]
            .as_str()
            .is_some_and(|n| n.starts_with("modbus:127.0.0.1:")),
        "{st}"
    );
    assert!(
        st["field_faults"]
            .as_array()
            .is_some_and(|a| a.iter().any(|f| f == "field_link_down")),
        "{st}"
    );
    assert!(
        human.lines().any(|l| l.starts_with("modbus link")
            && l.contains("modbus:127.0.0.1:")
            && l.contains(" down")),
        "{human}"
    );
    report(&case, &o);
    assert_in_control(&case, &o);
    let last_before = o.writes.iter().rev().find(|w| w.t_s < down).copied();
    let first_after = o.writes.iter().find(|w| w.t_s >= up).copied();
    eprintln!(
        "[{}] last write before the outage: {last_before:?}; first write after the resume: {first_after:?}",
        case.name
    );
    let w = first_after
        .unwrap_or_else(|| panic!("no valve write after the resume\n{}", logs(o.dir.path())));
    let step = (w.cmd - w.reported_pos).abs();
    eprintln!(
        "[{}] resume: first command {:.2} % at +{:.0} ms after the link came back, measured position reported {:.2} % (stem then {:.2} %): step {:.2} % of travel",
        case.name,
        100.0 * w.cmd,
        1e3 * (w.t_s - up),
        100.0 * w.reported_pos,
        100.0 * w.pos_now,
        100.0 * step
    );
    assert!(
        step <= 0.02,
        "first command after the resume {:.2} % vs reported position {:.2} %\n{}",
        100.0 * w.cmd,
        100.0 * w.reported_pos,
        logs(o.dir.path())
    );
    // the resume (fail-safe exit, the command taken over from the measured position and
    // closing from there) raises no feedback mismatch: the valve follows its positioner model
    let events = events_until_shutdown(o.dir.path());
    assert!(
        !events.contains("actuator_feedback_mismatch"),
        "a mismatch on the resume:\n{events}"
    );
    // the fail-safe names its root: the Modbus link, not the sensors it carries
    let failsafe = events
        .lines()
        .find(|l| l.contains("\"to\":\"fail_safe\""))
        .unwrap_or_else(|| panic!("no fail-safe during the outage:\n{events}"));
    assert!(
        failsafe.contains("\"kind\":\"link_down\"") && failsafe.contains("\"link\":\"modbus\""),
        "{failsafe}"
    );
}

// ---------------------------------------------------------------------------------------------
// Case 5: a second master writes the valve to 0 for 4 s (issue 23)

/// The daemon holds the valve at its command; another Modbus master writes the setpoint to 0
/// for 4 s in steady running. The command/feedback mismatch is raised (the valve leaves the
/// positioner model of its 50-ms stroke by more than 5 % for 100 ms), names the valve, stays
/// latched after the writes stop and the valve follows again (status `field_faults`), and
/// clears on the operator's acknowledgement. No mismatch is raised anywhere else in the run.
#[test]
fn a_second_writer_is_a_latched_feedback_mismatch_until_acknowledged() {
    let _rt = real_time();
    // the throttle closes slowly to 10 % first, so the daemon holds the valve open (a
    // master writing 0 onto a closed valve changes nothing)
    let mut case = Case::new(
        "second writer",
        100.0,
        Throttle::Ramp {
            at_s: 1.5,
            over_s: 2.0,
            to: THROTTLE_END,
        },
        DISTURBANCE_AT_S + 6.0,
    );
    case.second_writer = Some((DISTURBANCE_AT_S, DISTURBANCE_AT_S + 4.0));
    let o = run_case(case);
    report(&case, &o);
    let events = events_until_shutdown(o.dir.path());
    let raised: Vec<&str> = events
        .lines()
        .filter(|l| {
            l.contains("\"fault\":\"actuator_feedback_mismatch\"") && l.contains("\"active\":true")
        })
        .collect();
    assert_eq!(raised.len(), 1, "one mismatch, raised once:\n{events}");
    assert!(
        raised[0].contains("\"link\":\"recycle_valve\""),
        "{}",
        raised[0]
    );
    // raised 100 ms after the valve left the model (the 10-ms checks): the cause says so
    let lasted: f64 = raised[0]
        .split("for ")
        .last()
        .and_then(|t| t.split(" s").next())
        .and_then(|t| t.parse().ok())
        .expect("duration in the cause");
    assert!((0.1..0.15).contains(&lasted), "{}", raised[0]);
    let (before, after) = o.status_at_end.expect("status at the end");
    assert_eq!(
        before["field_faults"],
        serde_json::json!(["actuator_feedback_mismatch", "another_writer"]),
        "latched 2 s after the writes stopped: {before:#}"
    );
    // the read-back of the setpoint register names another writer, once, with the register
    let others: Vec<&str> = events
        .lines()
        .filter(|l| l.contains("\"fault\":\"another_writer\"") && l.contains("\"active\":true"))
        .collect();
    assert_eq!(others.len(), 1, "another writer raised once:\n{events}");
    assert!(
        others[0].contains("holding register 102 (unit 1) reads 0.0000"),
        "{}",
        others[0]
    );
    eprintln!("[{}] {}", case.name, others[0]);
    let mismatch_seq = |l: &str| -> u64 {
        l.split("\"seq\":")
            .nth(1)
            .and_then(|r| r.split(',').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or(0)
    };
    eprintln!(
        "[{}] another_writer (seq {}) {} the feedback mismatch (seq {})",
        case.name,
        mismatch_seq(others[0]),
        if mismatch_seq(others[0]) < mismatch_seq(raised[0]) {
            "before"
        } else {
            "after"
        },
        mismatch_seq(raised[0])
    );
    assert_eq!(
        after["field_faults"],
        serde_json::json!([]),
        "cleared by the ack: {after:#}"
    );
    let cleared = events
        .lines()
        .filter(|l| {
            l.contains("\"fault\":\"actuator_feedback_mismatch\"") && l.contains("\"active\":false")
        })
        .count();
    assert_eq!(cleared, 1, "{events}");
    let all = std::fs::read_to_string(o.dir.path().join("events.jsonl")).expect("event log");
    assert!(
        all.lines()
            .any(|l| l.contains("\"fault\":\"another_writer\"") && l.contains("\"active\":false")),
        "another_writer cleared by the ack:\n{all}"
    );
}

/// The event log up to the daemon's shutdown (after it the test's device no longer moves the
/// valve, so the shutdown's opening command is not followed: not what the cases judge).
fn events_until_shutdown(dir: &Path) -> String {
    let all = std::fs::read_to_string(dir.join("events.jsonl")).expect("event log");
    all.lines()
        .take_while(|l| !l.contains("\"to\":\"shutdown\""))
        .map(|l| format!("{l}\n"))
        .collect()
}

/// Issue 23, link quality: the device answers 90 ms late for 8 s (its poll rate falls from
/// 100 Hz to ≈ 4 Hz, a read and a write per poll). Asserted: a `field_link_slow` fault event naming the Modbus link while
/// the device is slow, with the achieved period and latency in its cause, cleared after; the
/// status shows the link's quality (period, p50/p99 latency); every fail-safe of the run is
/// rooted in an input that went stale beyond its budget (or the link), so a valve at 100 % is
/// never the slow link's doing alone. The time from the slowdown to the event is printed.
#[test]
fn a_device_answering_90_ms_late_for_8_s_is_reported_as_a_slow_link() {
    let _rt = real_time();
    let mut case = Case::new(
        "device 90 ms late for 8 s",
        100.0,
        Throttle::Ramp {
            at_s: DISTURBANCE_AT_S,
            over_s: 3.0,
            to: 0.3,
        },
        DISTURBANCE_AT_S + 9.5,
    );
    let (from, to) = (DISTURBANCE_AT_S - 1.0, DISTURBANCE_AT_S + 7.0);
    case.slow = Some((from, to, 0.09));
    // one connection, a read and a write per poll: ≈ 4 Hz, beyond the inputs' 200-ms budget
    // (with the commands on their own connection the reads come every ≈ 100 ms, within it)
    case.command_connection = "shared";
    // slow but alive: the answers (90 ms late on the device's own 10–20 ms) come within the
    // request timeout, so the link stays up (with the default 100 ms they time out and the
    // link is down, reported as such)
    case.client_timeout_ms = Some(250);
    // the degraded policy in force, 3 s into the slowdown
    case.status_at_s = Some(from + 3.0);
    let o = run_case(case);
    report(&case, &o);
    let events = events_until_shutdown(o.dir.path());
    let raised: Vec<&str> = events
        .lines()
        .filter(|l| l.contains("\"fault\":\"field_link_slow\"") && l.contains("\"active\":true"))
        .collect();
    assert!(!raised.is_empty(), "no field_link_slow event:\n{events}");
    let first = raised[0];
    assert!(
        first.contains("\"link\":\"modbus:127.0.0.1:") && first.contains("achieved poll period"),
        "{first}"
    );
    eprintln!("[{}] {first}", case.name);
    // the event's time against the device's slowdown, both on this machine's clock (printed,
    // never asserted: a busy machine delays the daemon, not the design)
    let start = o.slow_started.expect("the device went slow");
    let ts = first
        .split("\"ts\":\"")
        .nth(1)
        .and_then(|r| r.split('"').next())
        .and_then(|t| antisurge::events::Timestamp::parse_rfc3339(t).ok())
        .expect("event time")
        .to_system_time();
    let after = ts
        .duration_since(start)
        .unwrap_or_else(|_| panic!("raised before the device went slow: {first}"));
    eprintln!(
        "[{}] field_link_slow raised {:.0} ms after the device went slow",
        case.name,
        after.as_secs_f64() * 1e3
    );
    let cleared = events
        .lines()
        .any(|l| l.contains("\"fault\":\"field_link_slow\"") && l.contains("\"active\":false"));
    assert!(
        cleared,
        "field_link_slow never cleared after the device recovered:\n{events}"
    );
    // status: the link's quality
    let st = o.status_slow.as_ref().expect("status");
    let m = &st["links"]["modbus"];
    let p99 = m["latency_p99_us"].as_u64().unwrap_or(0);
    let p50 = m["latency_p50_us"].as_u64().unwrap_or(0);
    let period = m["poll_period_us"].as_u64().unwrap_or(0);
    eprintln!("[{}] status at the end: poll period {period} µs, latency p50 {p50} µs, p99 {p99} µs, timeouts {}, exceptions {}", case.name, m["timeouts"], m["exceptions"]);
    assert!(
        p99 >= 90_000,
        "the slow answers are in the 10-s window: {m}"
    );
    assert!(
        period > 0 && period < 90_000,
        "back to its rate after the device recovered: {m}"
    );
    // a fail-safe in this run is rooted in stale inputs or the link, never in anything else
    for l in events
        .lines()
        .filter(|l| l.contains("\"to\":\"fail_safe\""))
    {
        eprintln!("[{}] {l}", case.name);
        assert!(
            l.contains("\"fault\":\"stale\"")
                || l.contains("\"kind\":\"link_down\"")
                || l.contains("stale"),
            "a fail-safe not rooted in a stale input: {l}"
        );
    }
    // the documented degraded policy, in the status while the link is slow
    let (st, human) = o.status_mid.as_ref().expect("status during the slowdown");
    let policy = &st["degraded_policy"];
    eprintln!("[{}] status 3 s into the slowdown: {policy}", case.name);
    assert_eq!(policy["in_force"], true, "{st}");
    assert!(
        policy["causes"]
            .as_array()
            .is_some_and(|c| c.iter().any(|x| x == "field_link_slow")),
        "{policy}"
    );
    assert!(
        policy["text"]
            .as_str()
            .is_some_and(|t| t.starts_with("hold and widen")),
        "{policy}"
    );
    assert!(human.contains("degraded      hold and widen"), "{human}");
    // the trace: the valve is commanded fully open only in a fail-safe entered after an
    // input stayed stale beyond its budget (the test's 200-ms freshness; the core adds its
    // 250-ms failure hold before it fails safe)
    let bb = BlackBox::read(o.dir.path());
    let (cmd, mode) = (bb.col("cmd_recycle_valve"), bb.col("mode"));
    let age = |name: &str| bb.col(&format!("age_s_{name}"));
    let ages = [age("p_suction"), age("p_discharge"), age("orifice_dp")];
    let mut open_rows = 0;
    let mut stale_since_failsafe = false;
    for k in 0..cmd.len() {
        if mode[k] != 3.0 {
            stale_since_failsafe = false;
            continue;
        }
        stale_since_failsafe |= ages.iter().any(|a| a[k] > 0.2);
        if cmd[k] >= 0.999 {
            open_rows += 1;
            assert!(
                stale_since_failsafe,
                "valve at 100 % at t = {:.3} s without an input stale beyond its budget",
                bb.col("t_s")[k]
            );
        }
    }
    eprintln!(
        "[{}] black box: {} cycles, valve commanded 100 % in {open_rows} (each in a fail-safe after a stale input)",
        case.name,
        cmd.len()
    );
}

/// Issue 23: "every resume raises a false `actuator_feedback_mismatch`". Ten link outages of
/// 0.6 s, 2 s apart, each long enough for the inputs to go stale (fail-safe, valve commanded
/// open) and each followed by a resume from the measured position: ten fail-safe exits, zero
/// feedback mismatches (the valve follows its positioner model through every resume).
#[test]
fn ten_fail_safe_exits_and_resumes_raise_no_feedback_mismatch() {
    let _rt = real_time();
    let mut case = Case::new(
        "ten 0.6-s outages",
        100.0,
        Throttle::Ramp {
            at_s: DISTURBANCE_AT_S,
            over_s: 3.0,
            to: 0.2,
        },
        DISTURBANCE_AT_S + 25.0,
    );
    case.outages = Some((DISTURBANCE_AT_S + 4.0, 2.0, 0.6, 10));
    let o = run_case(case);
    report(&case, &o);
    assert_in_control(&case, &o);
    let events = events_until_shutdown(o.dir.path());
    let exits = events
        .lines()
        .filter(|l| {
            l.contains("\"event\":\"mode_changed\"") && l.contains("\"from\":\"fail_safe\"")
        })
        .count();
    let mismatches = events
        .lines()
        .filter(|l| l.contains("actuator_feedback_mismatch"))
        .count();
    eprintln!(
        "[{}] fail-safe exits {exits}, actuator_feedback_mismatch events {mismatches}",
        case.name
    );
    assert!(
        exits >= 10,
        "{exits} fail-safe exits (10 outages):\n{events}"
    );
    assert_eq!(mismatches, 0, "mismatch events:\n{events}");
}
