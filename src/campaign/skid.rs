//! Random skids: plant descriptions of the `recycle_system` model drawn from documented ranges
//! around the two in-house recycle plants (`hemchi2016`, `kvangardsnes2009`), with the field
//! between plant and controller (loop rate, bus latency, transmitter noise, quantisation and
//! faults, valve dead time) and one disturbance.
//!
//! Every range below states where it comes from. A draw is rejected (and drawn again from the
//! same case stream) when its estimated surge frequency ([`helmholtz_hz`]) or its simulated
//! step-to-reversal time ([`step_to_reversal_s`]) lies outside [`SURGE_FREQUENCY_HZ`] and
//! [`STEP_TO_REVERSAL_S`], when the map variation leaves no surge line, or when the initial
//! operating point is closer than [`MIN_INITIAL_MARGIN`] to the surge line.
//!
//! Case `k` of campaign seed `S` is drawn from its own stream ([`case_seed`]), so
//! `antisurge campaign --case K` rebuilds exactly that skid without drawing the others.

use super::CampaignError;
use crate::control::model::ControlModel;
use crate::control::ControllerConfig;
use crate::physics::compressor_map::{MapModel, SurgeLine};
use crate::plant::recycle_system::ix;
use crate::plant::{PlantInputs, SimPlant};
use crate::sim::case::PlantCase;
use serde::Serialize;

/// Surge-frequency range of the drawn skids, Hz (issue 22: the machines the controller must
/// protect surge at 1–10 Hz; the surge detector's doc gives the same band from the seeds;
/// hemchi2016's cycle is ≈ 6–7 Hz).
pub const SURGE_FREQUENCY_HZ: (f64, f64) = (1.0, 10.0);
/// Step-to-reversal range, s: from the discharge slammed shut to the first compressor flow
/// reversal with the recycle valve held (issue 22: 40–400 ms, from the fast in-house plant to
/// large machines with big discharge volumes).
pub const STEP_TO_REVERSAL_S: (f64, f64) = (0.04, 0.4);
/// Factor on the base plant's share of the Helmholtz stiffness that comes from the suction
/// volume, (c1²/V1) / (c1²/V1 + c2²/V2) (kvangardsnes2009: 0.03, a large suction drum;
/// hemchi2016: 0.36; chosen: half to twice the base plant's, so a drawn skid keeps its base's
/// layout; the share is capped at [`SUCTION_SHARE_MAX`]).
pub const SUCTION_SHARE_FACTOR: (f64, f64) = (0.5, 2.0);
/// Largest suction share (chosen: the suction volume never stiffer than three times the
/// discharge side).
pub const SUCTION_SHARE_MAX: f64 = 0.75;
/// Compressor-duct length factor on the base plant's L_c (chosen: ±2× around the in-house
/// ducts, log-uniform).
pub const DUCT_LENGTH_FACTOR: (f64, f64) = (0.5, 2.0);
/// Recycle- and discharge-line length factors on the base plant's L_r, L_t (chosen as
/// [`DUCT_LENGTH_FACTOR`]).
pub const LINE_LENGTH_FACTOR: (f64, f64) = (0.5, 2.0);
/// Map flow-axis stretch (the surge line moves with it) and pressure-rise (Ψ − 1) scale of the
/// base plant's fitted map (chosen: ±10 %, the spread of a vendor map against a test-bed map;
/// the same transformation as `sim::bench::map_off`, applied to the plant and the
/// controller alike: a different machine, known to the controller).
pub const MAP_FLOW_FACTOR: (f64, f64) = (0.9, 1.1);
/// See [`MAP_FLOW_FACTOR`].
pub const MAP_RISE_FACTOR: (f64, f64) = (0.9, 1.1);
/// Recycle-valve full-stroke time, s (issue 22: 0.5–3 s; kvangardsnes2009's comment: fast
/// anti-surge valves stroke in 1–2 s; log-uniform).
pub const RECYCLE_STROKE_S: (f64, f64) = (0.5, 3.0);
/// Recycle-valve dead time, s: from a command reaching the positioner to the stem moving
/// (chosen: a pneumatic actuator's dead band and fill time, tens to a couple of hundred ms).
pub const VALVE_DEAD_TIME_S: (f64, f64) = (0.02, 0.2);
/// Throttle (process valve) full-stroke time, s (the in-house plants: kvangardsnes2009 0.5 s,
/// hemchi2016 4 s; log-uniform). A throttle "step" goes through it.
pub const THROTTLE_STROKE_S: (f64, f64) = (0.5, 4.0);
/// Loop (bus poll) rates, Hz (issue 22: Modbus at 20–100 Hz, the in-process 1 kHz loop).
/// Case k runs at `LOOP_RATES_HZ[k % 4]`, so every rate is equally represented.
pub const LOOP_RATES_HZ: [f64; 4] = [20.0, 50.0, 100.0, 1000.0];
/// Bus latency, s, each way (issue 22: 2–20 ms: a Modbus TCP/RTU transaction; the controller
/// sees every sample this late and its commands reach the valve this late).
pub const LATENCY_S: (f64, f64) = (0.002, 0.02);
/// Largest extra random latency per sample and per command, as a fraction of the latency
/// (chosen: up to half the latency again, uniform per message).
pub const JITTER_FRACTION: (f64, f64) = (0.0, 0.5);
/// Transmitter noise on the pressures, % of span, uniform white (0 to the bench matrix's
/// noise case: ±1 % of span; spans as there: 1.5× the initial readings).
pub const PRESSURE_NOISE_PCT: (f64, f64) = (0.0, 1.0);
/// Transmitter noise on Δp, % of span (0 to the bench matrix's ±2 % of span; span 2× the
/// initial Δp).
pub const DP_NOISE_PCT: (f64, f64) = (0.0, 2.0);
/// Quantisation of every transmitter over its span, bits (chosen: 12-bit analogue input
/// cards to 16-bit Modbus registers; uniform over 12..=16).
pub const QUANTISATION_BITS: (u32, u32) = (12, 16);
/// Frozen Δp: start relative to the disturbance, s (the bench matrix freezes it 0.5 s after
/// the closure starts) and duration, s (the bench matrix: 1 s).
pub const DP_FROZEN_START_S: (f64, f64) = (-0.5, 1.0);
/// See [`DP_FROZEN_START_S`].
pub const DP_FROZEN_FOR_S: (f64, f64) = (0.5, 2.0);
/// Δp bias, % of span (chosen: a calibration error of a few % of span, both signs; positive
/// reads more flow than true, the dangerous direction).
pub const DP_BIAS_PCT: (f64, f64) = (-3.0, 3.0);
/// Throttle closure: final opening (the shipped scenario: 60 % → 20 %, the in-house plants
/// are sized so that 20 % lies left of the surge line).
pub const CLOSURE_TO: (f64, f64) = (0.1, 0.3);
/// Throttle closure: ramp time, s (the shipped scenario: 2 s).
pub const CLOSURE_OVER_S: (f64, f64) = (1.0, 4.0);
/// Throttle step: final opening (the shipped throttle_step: 20 %).
pub const STEP_TO: (f64, f64) = (0.1, 0.3);
/// Feed drop: final feed (the shipped feed_drop: 60 %, recycle_pi_feed_drop_deep: 40 %).
pub const FEED_TO: (f64, f64) = (0.3, 0.6);
/// Feed drop: ramp time, s (both shipped feed drops: 1 s).
pub const FEED_OVER_S: (f64, f64) = (0.5, 2.0);
/// Smallest initial surge margin accepted, fraction of surge-line flow: the default 10 %
/// control line plus 5 %, so that a run starts with the laws at rest (a map variation can move
/// the initial point left).
pub const MIN_INITIAL_MARGIN: f64 = 0.15;
/// When the disturbance starts, s (the shipped scenarios: 5 s; the controller's start-up
/// grace is 1 s).
pub const EVENT_AT_S: f64 = 5.0;
/// Length of a run, s (the shipped ESD scenario: 15 s).
pub const DURATION_S: f64 = 15.0;
/// Draws tried per case before giving up.
pub const MAX_DRAWS: u32 = 400;
/// Plant integration step, s (≤ 1 ms: the shipped scenarios' period; the latency and the
/// valve dead time are resolved to it).
pub const PLANT_STEP_S: f64 = 0.001;

/// The in-house plants the skids vary, by file stem in `config/plants`.
pub const BASE_PLANTS: [&str; 2] = ["hemchi2016_recycle", "kvangardsnes2009_recycle"];

/// The four disturbances, in table order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DisturbanceKind {
    /// Throttle ramp closure.
    ThrottleClosure,
    /// Throttle step.
    ThrottleStep,
    /// Feed ramp drop.
    FeedDrop,
    /// Drive trip (emergency shutdown), the machine runs down.
    EsdRundown,
}

impl DisturbanceKind {
    /// All, in table order. Case k has `ALL[(k / 4) % 4]`.
    pub const ALL: [DisturbanceKind; 4] = [
        DisturbanceKind::ThrottleClosure,
        DisturbanceKind::ThrottleStep,
        DisturbanceKind::FeedDrop,
        DisturbanceKind::EsdRundown,
    ];

    /// Name in tables.
    pub fn name(self) -> &'static str {
        match self {
            DisturbanceKind::ThrottleClosure => "throttle closure",
            DisturbanceKind::ThrottleStep => "throttle step",
            DisturbanceKind::FeedDrop => "feed drop",
            DisturbanceKind::EsdRundown => "ESD rundown",
        }
    }
}

/// A drawn disturbance, starting at [`EVENT_AT_S`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Disturbance {
    /// Throttle ramp to `to` over `over_s`.
    ThrottleClosure {
        /// Final opening.
        to: f64,
        /// Ramp time, s.
        over_s: f64,
    },
    /// Throttle step to `to` (through the throttle's stroke).
    ThrottleStep {
        /// Final opening.
        to: f64,
    },
    /// Feed ramp to `to` over `over_s`.
    FeedDrop {
        /// Final feed.
        to: f64,
        /// Ramp time, s.
        over_s: f64,
    },
    /// Drive trip.
    EsdRundown,
}

impl Disturbance {
    /// Its kind.
    pub fn kind(&self) -> DisturbanceKind {
        match self {
            Disturbance::ThrottleClosure { .. } => DisturbanceKind::ThrottleClosure,
            Disturbance::ThrottleStep { .. } => DisturbanceKind::ThrottleStep,
            Disturbance::FeedDrop { .. } => DisturbanceKind::FeedDrop,
            Disturbance::EsdRundown => DisturbanceKind::EsdRundown,
        }
    }

    /// Short description with its parameters.
    pub fn describe(&self) -> String {
        match *self {
            Disturbance::ThrottleClosure { to, over_s } => {
                format!("throttle closure to {:.0} % over {over_s:.1} s", 100.0 * to)
            }
            Disturbance::ThrottleStep { to } => format!("throttle step to {:.0} %", 100.0 * to),
            Disturbance::FeedDrop { to, over_s } => {
                format!("feed drop to {:.0} % over {over_s:.1} s", 100.0 * to)
            }
            Disturbance::EsdRundown => "ESD rundown (drive trip)".to_string(),
        }
    }
}

/// What the Δp transmitter does.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DpFault {
    /// Healthy.
    Healthy,
    /// Repeats its value (fresh, as a healthy Modbus server would) from `from_s` for `for_s`.
    Frozen {
        /// Start, s.
        from_s: f64,
        /// Duration, s.
        for_s: f64,
    },
    /// Reads `pct_span` % of its span more than true, all the run.
    Bias {
        /// Offset, % of span.
        pct_span: f64,
    },
}

/// The drawn parameters of a skid (what the JSON and the failing-case list show).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SkidParams {
    /// Base plant name.
    pub base: String,
    /// Suction volume V1, m³.
    pub suction_volume_m3: f64,
    /// Discharge volume V2, m³.
    pub discharge_volume_m3: f64,
    /// Compressor duct length L_c, m.
    pub compressor_duct_length_m: f64,
    /// Recycle line length L_r, m.
    pub recycle_duct_length_m: f64,
    /// Discharge line length L_t, m.
    pub discharge_duct_length_m: f64,
    /// Map flow-axis factor.
    pub map_flow_factor: f64,
    /// Map pressure-rise factor.
    pub map_rise_factor: f64,
    /// Recycle valve full stroke, s.
    pub recycle_stroke_time_s: f64,
    /// Recycle valve dead time, s.
    pub valve_dead_time_s: f64,
    /// Throttle full stroke, s.
    pub throttle_stroke_time_s: f64,
    /// Pressure noise, ± % of span.
    pub pressure_noise_pct_span: f64,
    /// Δp noise, ± % of span.
    pub dp_noise_pct_span: f64,
    /// Quantisation, bits over the span.
    pub quantisation_bits: u32,
    /// Δp transmitter condition.
    pub dp_fault: DpFault,
    /// Loop rate, Hz.
    pub rate_hz: f64,
    /// Bus latency each way, s.
    pub latency_s: f64,
    /// Largest extra latency per message, s.
    pub jitter_s: f64,
    /// The disturbance.
    pub disturbance: Disturbance,
    /// Estimated surge frequency (two-volume Helmholtz), Hz.
    pub surge_frequency_hz: f64,
    /// Simulated step-to-reversal time, s.
    pub step_to_reversal_s: f64,
    /// Initial surge margin, fraction of surge-line flow.
    pub initial_margin: f64,
    /// Draws it took to accept this skid.
    pub draws: u32,
}

/// A drawn skid: its plant and its parameters.
#[derive(Debug, Clone)]
pub struct Skid {
    /// Case number in its campaign.
    pub index: usize,
    /// The case's own seed (noise and jitter sequences too).
    pub seed: u64,
    /// Parameters.
    pub params: SkidParams,
    /// The plant (the base plant's file with the drawn values; `[controller]` is not used).
    pub plant: PlantCase,
}

/// SplitMix64: a small, fast, well-mixed generator (the campaign needs reproducibility, not
/// cryptographic quality).
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// From a seed.
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    /// Next 64 bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [lo, hi].
    pub fn uniform(&mut self, r: (f64, f64)) -> f64 {
        r.0 + (r.1 - r.0) * self.unit()
    }

    /// Log-uniform in [lo, hi] (both > 0).
    pub fn log_uniform(&mut self, r: (f64, f64)) -> f64 {
        (r.0.ln() + (r.1.ln() - r.0.ln()) * self.unit()).exp()
    }

    /// Uniform in [−1, 1).
    pub fn symmetric(&mut self) -> f64 {
        2.0 * self.unit() - 1.0
    }
}

/// The seed of case `k` of a campaign with seed `campaign_seed`.
pub fn case_seed(campaign_seed: u64, k: usize) -> u64 {
    let mut r = Rng::new(campaign_seed ^ (k as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
    r.next_u64()
}

/// Estimated surge (Helmholtz) frequency of a two-volume recycle system, Hz: the compressor
/// duct's gas mass oscillating between the two volumes in series,
/// f = 1/(2π) √(A_c/L_c · (c1²/V1 + c2²/V2)) (the one-volume f = a/(2π) √(A/(V L)) with both
/// compliances). On hemchi2016 it gives 8.5 Hz where the simulated deep surge runs at 7.4 Hz.
pub fn helmholtz_hz(rs: &crate::plant::file::RecycleParams) -> f64 {
    let stiffness = rs.suction_sonic_velocity_m_s.powi(2) / rs.suction_volume_m3
        + rs.discharge_sonic_velocity_m_s.powi(2) / rs.discharge_volume_m3;
    (rs.compressor_duct_area_m2 / rs.compressor_duct_length_m * stiffness).sqrt()
        / (2.0 * std::f64::consts::PI)
}

/// The plant's inputs at its initial steady state (throttle, recycle valve, feed).
fn initial_inputs(plant: &PlantCase) -> PlantInputs {
    let init = plant.file.initial;
    PlantInputs {
        throttle_process: init.throttle,
        recycle_manual: init.recycle_valve,
        feed: init.feed,
        ..PlantInputs::default()
    }
}

/// Step-to-reversal time of a plant, s: from its initial steady state, the discharge
/// (throttle) slammed shut in one plant step, recycle valve and drive torque held, the time to
/// the first compressor flow reversal (w_c < 0). None: no reversal within `horizon_s`.
pub fn step_to_reversal_s(plant: &PlantCase, horizon_s: f64) -> Option<f64> {
    let inputs = initial_inputs(plant);
    let mut p = SimPlant::new(plant, &inputs).ok()?;
    if let SimPlant::Recycle(r) = &mut p {
        r.x[ix::LT] = 0.0;
    } else {
        return None;
    }
    let closed = PlantInputs {
        throttle_process: 0.0,
        ..inputs
    };
    let n = (horizon_s / PLANT_STEP_S).round() as usize;
    for k in 1..=n {
        p.step(&closed, PLANT_STEP_S);
        let w = p.truth().m_kg_s;
        if !w.is_finite() {
            return None;
        }
        if w < 0.0 {
            return Some(k as f64 * PLANT_STEP_S);
        }
    }
    None
}

/// The surge margin of a plant's initial steady state, fraction of surge-line flow (NaN: no
/// steady state).
pub fn initial_margin(plant: &PlantCase) -> f64 {
    let inputs = initial_inputs(plant);
    let Ok(p) = SimPlant::new(plant, &inputs) else {
        return f64::NAN;
    };
    let t = p.truth();
    let model = ControlModel::from_machine(&plant.machine(), ControllerConfig::default());
    model.surge_margin(t.flow_map, t.pressure_ratio())
}

/// The loop rate of case `k`.
pub fn rate_of_case(k: usize) -> f64 {
    LOOP_RATES_HZ[k % LOOP_RATES_HZ.len()]
}

/// The disturbance kind of case `k`.
pub fn disturbance_of_case(k: usize) -> DisturbanceKind {
    DisturbanceKind::ALL[(k / LOOP_RATES_HZ.len()) % DisturbanceKind::ALL.len()]
}

/// The base plant of case `k` (index into the bases): alternates every 16 cases, so that 32
/// consecutive cases hold every rate × disturbance on both plants.
pub fn base_of_case(k: usize, n_bases: usize) -> usize {
    (k / (LOOP_RATES_HZ.len() * DisturbanceKind::ALL.len())) % n_bases.max(1)
}

/// Stretch the flow axis of a fitted map by `flow_factor` and scale its pressure rise by
/// `rise_factor`, and tabulate its surge line again. None: not a fitted map, or no surge
/// line after the change.
fn vary_map(
    map: &crate::physics::compressor_map::CompressorMap,
    flow_factor: f64,
    rise_factor: f64,
) -> Option<crate::physics::compressor_map::CompressorMap> {
    let mut m = *map;
    let MapModel::Polynomial(p) = &mut m.model else {
        return None;
    };
    *p = p.scaled(flow_factor, rise_factor);
    let poly = *p;
    m.surge_line = SurgeLine::tabulate(poly.omega_min, poly.omega_max, |w| poly.peak(w)).ok()?;
    Some(m)
}

/// Draw case `k` of campaign `campaign_seed` on the base plants `bases` (the in-house recycle
/// plants, [`BASE_PLANTS`]).
pub fn draw_skid(bases: &[PlantCase], campaign_seed: u64, k: usize) -> Result<Skid, CampaignError> {
    let seed = case_seed(campaign_seed, k);
    let mut rng = Rng::new(seed);
    let base = bases
        .get(base_of_case(k, bases.len()))
        .ok_or(CampaignError::NoBasePlant)?;
    let rate_hz = rate_of_case(k);
    let kind = disturbance_of_case(k);
    let Some(rs0) = base.file.recycle_system else {
        return Err(CampaignError::NotRecycle(base.name().to_string()));
    };
    let base_share = {
        let s1 = rs0.suction_sonic_velocity_m_s.powi(2) / rs0.suction_volume_m3;
        let s2 = rs0.discharge_sonic_velocity_m_s.powi(2) / rs0.discharge_volume_m3;
        s1 / (s1 + s2)
    };
    for draw in 1..=MAX_DRAWS {
        // geometry: the Helmholtz frequency first, then the volumes that give it
        let f_hz = rng.log_uniform(SURGE_FREQUENCY_HZ);
        let share = (base_share * rng.log_uniform(SUCTION_SHARE_FACTOR)).min(SUCTION_SHARE_MAX);
        let lc = rs0.compressor_duct_length_m * rng.log_uniform(DUCT_LENGTH_FACTOR);
        let lr = rs0.recycle_duct_length_m * rng.log_uniform(LINE_LENGTH_FACTOR);
        let lt = rs0.discharge_duct_length_m * rng.log_uniform(LINE_LENGTH_FACTOR);
        let w2 = (2.0 * std::f64::consts::PI * f_hz).powi(2) * lc / rs0.compressor_duct_area_m2;
        let v1 = rs0.suction_sonic_velocity_m_s.powi(2) / (share * w2);
        let v2 = rs0.discharge_sonic_velocity_m_s.powi(2) / ((1.0 - share) * w2);
        let flow_factor = rng.uniform(MAP_FLOW_FACTOR);
        let rise_factor = rng.uniform(MAP_RISE_FACTOR);
        let stroke = rng.log_uniform(RECYCLE_STROKE_S);
        let dead = rng.uniform(VALVE_DEAD_TIME_S);
        let throttle_stroke = rng.log_uniform(THROTTLE_STROKE_S);
        let p_noise = rng.uniform(PRESSURE_NOISE_PCT);
        let dp_noise = rng.uniform(DP_NOISE_PCT);
        let bits = QUANTISATION_BITS.0
            + (rng.next_u64() % u64::from(QUANTISATION_BITS.1 - QUANTISATION_BITS.0 + 1)) as u32;
        let dp_fault = match rng.next_u64() % 4 {
            0 => DpFault::Frozen {
                from_s: EVENT_AT_S + rng.uniform(DP_FROZEN_START_S),
                for_s: rng.uniform(DP_FROZEN_FOR_S),
            },
            1 => DpFault::Bias {
                pct_span: rng.uniform(DP_BIAS_PCT),
            },
            _ => DpFault::Healthy,
        };
        let latency_s = rng.uniform(LATENCY_S);
        let jitter_s = latency_s * rng.uniform(JITTER_FRACTION);
        let disturbance = match kind {
            DisturbanceKind::ThrottleClosure => Disturbance::ThrottleClosure {
                to: rng.uniform(CLOSURE_TO),
                over_s: rng.uniform(CLOSURE_OVER_S),
            },
            DisturbanceKind::ThrottleStep => Disturbance::ThrottleStep {
                to: rng.uniform(STEP_TO),
            },
            DisturbanceKind::FeedDrop => Disturbance::FeedDrop {
                to: rng.uniform(FEED_TO),
                over_s: rng.uniform(FEED_OVER_S),
            },
            DisturbanceKind::EsdRundown => Disturbance::EsdRundown,
        };

        let mut plant = base.clone();
        let Some(map) = vary_map(&base.map, flow_factor, rise_factor) else {
            continue;
        };
        plant.plant.map = map;
        plant.plant.file.name = format!("{}-campaign-{k}", base.name());
        let Some(rs) = plant.plant.file.recycle_system.as_mut() else {
            continue;
        };
        rs.suction_volume_m3 = v1;
        rs.discharge_volume_m3 = v2;
        rs.compressor_duct_length_m = lc;
        rs.recycle_duct_length_m = lr;
        rs.discharge_duct_length_m = lt;
        rs.recycle_valve.stroke_time_s = stroke;
        rs.throttle.stroke_time_s = throttle_stroke;
        let rs = *rs;
        let f_est = helmholtz_hz(&rs);
        if !(SURGE_FREQUENCY_HZ.0..=SURGE_FREQUENCY_HZ.1).contains(&f_est) {
            continue;
        }
        let margin0 = initial_margin(&plant);
        // NaN (no steady state) is rejected too
        if margin0.is_nan() || margin0 < MIN_INITIAL_MARGIN {
            continue;
        }
        let Some(t_rev) = step_to_reversal_s(&plant, STEP_TO_REVERSAL_S.1 + PLANT_STEP_S) else {
            continue;
        };
        if !(STEP_TO_REVERSAL_S.0..=STEP_TO_REVERSAL_S.1).contains(&t_rev) {
            continue;
        }
        let params = SkidParams {
            base: base.name().to_string(),
            suction_volume_m3: v1,
            discharge_volume_m3: v2,
            compressor_duct_length_m: lc,
            recycle_duct_length_m: lr,
            discharge_duct_length_m: lt,
            map_flow_factor: flow_factor,
            map_rise_factor: rise_factor,
            recycle_stroke_time_s: stroke,
            valve_dead_time_s: dead,
            throttle_stroke_time_s: throttle_stroke,
            pressure_noise_pct_span: p_noise,
            dp_noise_pct_span: dp_noise,
            quantisation_bits: bits,
            dp_fault,
            rate_hz,
            latency_s,
            jitter_s,
            disturbance,
            surge_frequency_hz: f_est,
            step_to_reversal_s: t_rev,
            initial_margin: margin0,
            draws: draw,
        };
        return Ok(Skid {
            index: k,
            seed,
            params,
            plant,
        });
    }
    Err(CampaignError::NoSkid {
        case: k,
        draws: MAX_DRAWS,
    })
}
