//! `recycle-pi`: industrial surge avoidance with the recycle valve (seed 001 ch. 3, seed 002
//! §2.2.2, §2.3, ch. 4).
//!
//! The operating point (q, R) is taken in invariant coordinates: q is the compressor flow in
//! the map's coordinate (volumetric flow at suction for seed 002's map, eq. 2.14: the density
//! correction with p1 and T1 is done by the core from the orifice Δp or the observer's mass
//! flow) and R = p_d/p_s (seed 002 eq. 2.6: the pressure rise corrected to the reference inlet
//! pressure is equivalent to R). The surge control line q_SCL = c(R) is built on the *derived*
//! surge line j(R) (seed 002 eq. 2.7, 4.1/4.17/4.36 or 4.2; [`SurgeControlLine`]).
//!
//! Control variable, z > 0 left of the line (opens the valve), selectable:
//! - strategy 1 (seed 002 eq. 4.15–4.19): z = c(R)² − q̄, q̄ = Δp_o K_f/p1 ∝ q², normalised with
//!   K_f/c_q² = 1 so that q̄ = q|q| (map flow units²);
//! - strategy 2 (seed 002 eq. 4.33–4.38): z = 1 − q̄/c(R)², q̄ = Δp_o p_ref/p1 with p_ref/c_q² = 1
//!   (dimensionless). The p_ref/p1 correction of eq. 4.33–4.35 is what the core's density
//!   correction already does: Δp_o/p1 ∝ q², and Δp_m p_ref/p1 = (R − 1) p_ref is a function of R.
//!
//! Correction, stated: the seed's q̄ is the orifice Δp, which carries the sign of the flow; we keep
//! that sign (q̄ = q|q|, not q²) so that reversed flow in deep surge reads as far *left* of the
//! line (a squared flow would read a reversal as a large forward flow and close the valve).
//!
//! The valve command (seed 001 eq. 3.7, PI with K_d = 0; seed 002 §2.2.2):
//! - PI on z (optionally low-passed, `z_filter_hz`) with anti-windup: against the static limits
//!   the integrator tracks the clamped demand; while the closing-rate limit holds the valve above
//!   the demand it stops integrating in the closing direction (conditional integration: the
//!   demand cannot dive below the valve, and noise cannot ratchet the valve open the way
//!   instantaneous tracking of a rate-limited output does);
//! - fast opening, rate-limited closing ([15]): the command never falls faster than
//!   `closing_rate_per_s`; it rises as fast as the PI asks; a sustained closing (after a
//!   restart or a trip) stops where the valve is once the point reaches the control line,
//!   the PI taking over from there, and the approach it caused arms no approach trip for the
//!   approach filter's lag after (its filtered rate still shows the closing);
//! - a minimum opening (`min_opening`);
//! - the recycle trip ([11], [13]): an open-loop step of `trip_step` when the operating point
//!   crosses the trip line (surge margin below `trip_margin_pct`, between surge line and SCL)
//!   or, at or left of the control line (z ≥ 0), approaches it too fast: the filtered rate of
//!   approach −d(margin)/dt exceeds (margin − trip margin)/`trip_lead_time_s`, i.e. the trip line
//!   would be crossed within the lead time. The rate judged is the filtered rate beyond
//!   `trip_noise_factor` × its own noise (σ √(T ω³/4) for margin noise σ sampled every T
//!   through the two-pole filter at ω), and the step grows with the penetration past the
//!   threshold that fired, taken at the shallowest of the `trip_confirm_samples` samples
//!   that agreed, so noise neither fires the trip nor enlarges its step. The noise estimates
//!   start as plain means of their first samples, so a (re)started law judges noise from its
//!   first samples, not from zero. (Armed
//!   only at z ≥ 0: the valve closing back towards the line after a trip is an approach too,
//!   and must not re-trip.) The step is held for
//!   `trip_hold_s` (the integrator tracks the held opening), then the PI takes over from it.
//!   The hold ends early once the point lies right of the control line and moves away from
//!   it; the PI then takes over from the measured stem position if the stem, still stroking
//!   towards the step, has risen from where the trip found it (the opening it has reached
//!   already suffices);
//! - the onset trip: the same prediction from the *raw* margin's rate over the last
//!   `trip_confirm_samples` distinct samples, when they fell strictly and in total by more than
//!   2 × `trip_noise_factor` × their measured noise (agreement over several samples, thresholds
//!   from the noise: white noise cannot fire it). It catches a throttle slam within the window
//!   (kvangardsnes2009 at 5 %: 4 ms after the step, where the 2 Hz approach filter tripped at
//!   25 ms and the 2-s valve could no longer hold it); while held, its level follows its
//!   growing prediction;
//! - a rate or onset trip right of the trip line steps at most 2 × `trip_step` (the level trip
//!   escalates it should the point get there);
//! - after a (re)start far right of the line (link outage, fail-safe exit), the integrator
//!   unwinds so that the valve closes at the distance-adapted rate until the point is within
//!   `closing_rate_distance_pct` of the line;
//! - safety-on ([13] surge-count bias): after each detected surge the SCL moves right by
//!   `safety_on_step_pct` of the surge-line flow (up to `safety_on_max_pct`), counted and
//!   reported as [`LawEvent::SafetyOnShift`];
//! - flow-transmitter fallback: when the core feeds the observer's flow
//!   (`Measurements::flow_fallback`), the law cross-checks it against the steady flow on the
//!   speed line at the measured pressure ratio and speed (seed 002 §2.2.2, category four:
//!   control without flow measurement) and uses the smaller: a guard against an observer
//!   whose model is off (its outflow is the quasi-steady valve equations, without the outlet
//!   lines' inertia). On the seed 002 plant the observer's former one-step update misread the
//!   throttle transient by up to +30 % (it would have closed the valve); its implicit update
//!   ([`super::observer`]) follows it, and the observer alone now holds that case too.
//!
//! Deviation from seed 001 eq. 3.6, stated: there the error is clamped to zero right of the
//! line, so the integral can only grow and the valve never closes again. We use the signed z:
//! right of the line the PI closes the valve (at the closing rate) down to the minimum opening,
//! where the anti-windup holds the integrator.
//!
//! Gains. Seed 001 (ch. 3.4) tunes Kp = 35.5, Ki = 85 on the linear flow error W_SA − W_op in kg/s
//! with the output a valve fraction. Strategy 1's and 2's z are not linear flow errors: near the
//! line z₁ ≈ 2 q (c − q) and z₂ ≈ 2 (c − q)/q. The configured gains are therefore per unit of
//! *equivalent linear flow error* in the map's flow unit (kg/s, or m³/s at suction for seed
//! 002's volumetric map), and are converted once, at the design point q_ref (the SCL flow at
//! nominal speed), into gains on z: K_z = K/(2 q_ref) for strategy 1 and K_z = K q_ref/2 for
//! strategy 2. Both strategies thus have seed 001's loop gain at the design point; away from it
//! their gains differ as seed 002 Fig. 4.7 / 4.11 describe (the constant conversion does not
//! normalise that away).

use super::law::{LawError, LawEvent, LawId, LawInputs, LawOutput, SurgeLaw};
use super::model::ControlModel;
use super::surge_control_line::{ControlLineForm, SurgeControlLine};
use crate::physics::compressor_map::CompressorMap;
use crate::signals::{ActuatorCommands, ActuatorId};
use serde::{Deserialize, Serialize};

/// Which control variable the PI acts on (seed 002 ch. 4, or the normalised deviation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ControlVariable {
    /// Strategy 1: z = c(R)² − q̄ (seed 002 eq. 4.19), in map flow units squared.
    Strategy1,
    /// Strategy 2: z = 1 − q̄/c(R)² (seed 002 eq. 4.38), dimensionless. Its steady-state gain
    /// varies less with speed (seed 002 Fig. 4.11 vs 4.7).
    Strategy2,
    /// The normalised deviation d = (q − c(R))/c(R): distance to the control line as a
    /// fraction of the control-line flow, positive = safe; the PI acts on z = −d. Gains
    /// `kp`, `ki_per_s` are per unit of d, so one set of defaults fits every machine (the
    /// map's flow unit and the machine's size drop out).
    #[default]
    Deviation,
}

impl ControlVariable {
    /// z for a flow `q` (map units, signed) and control-line flow `c` at the measured ratio.
    /// q̄ = q|q| keeps the sign of the orifice Δp. NaN if c ≤ 0 for strategy 2.
    #[inline]
    pub fn z(self, q: f64, c: f64) -> f64 {
        let q_bar = q * q.abs();
        match self {
            // seed 002 eq. 4.19 with eq. 4.15, K_f/c_q² = 1
            ControlVariable::Strategy1 => c * c - q_bar,
            // seed 002 eq. 4.38 with eq. 4.33, p_ref/c_q² = 1
            ControlVariable::Strategy2 => {
                if c > 0.0 {
                    1.0 - q_bar / (c * c)
                } else {
                    f64::NAN
                }
            }
            // z = −d = (c − q)/c (signed q: a reversal reads as far left)
            ControlVariable::Deviation => {
                if c > 0.0 {
                    (c - q) / c
                } else {
                    f64::NAN
                }
            }
        }
    }

    /// ∂z/∂q on the line (q = c): the factor that turns a linear flow error into z.
    #[inline]
    pub fn slope_on_line(self, q_line: f64) -> f64 {
        match self {
            ControlVariable::Strategy1 => 2.0 * q_line,
            ControlVariable::Strategy2 => 2.0 / q_line,
            ControlVariable::Deviation => 1.0 / q_line,
        }
    }
}

/// Settings (`[controller.recycle_pi]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecyclePiConfig {
    /// The surge control line (seed 002 eq. 4.1/4.17/4.36 margin form, or eq. 4.2 c0 √(R−1);
    /// App. A uses c0 = 0.6). Default: 10 % of surge-line flow.
    pub control_line: ControlLineForm,
    /// Control variable: `strategy1` (eq. 4.19) or `strategy2` (eq. 4.38). Default strategy 2.
    pub control_variable: ControlVariable,
    /// Proportional gain of `strategy1`/`strategy2`: valve opening (fraction) per map flow
    /// unit (kg/s or m³/s at suction) of equivalent linear flow error at the design point.
    /// Seed 001 §3.4: 35.5 (per kg/s). Not used by `deviation`.
    pub kp_per_map_flow: f64,
    /// Integral gain of `strategy1`/`strategy2`: valve opening (fraction) per map flow unit
    /// and second. Seed 001 §3.4: 85. Not used by `deviation`.
    pub ki_per_map_flow_s: f64,
    /// Proportional gain of `deviation`: valve opening (fraction) per unit of normalised
    /// deviation (a seed gain K per map flow unit is K × q_ref, q_ref the control-line flow
    /// at the design point). Default 1.0: 1 % of the line's flow moves the valve 1 %.
    pub kp: f64,
    /// Integral gain of `deviation`: valve opening per unit of normalised deviation and
    /// second (seed: K_i × q_ref). Default 2.0/s (integral time 0.5 s).
    pub ki_per_s: f64,
    /// Closing-rate adaptation: the allowed closing rate grows by `closing_rate_per_s` for
    /// every this many percent of control-line flow the operating point lies right of the
    /// control line (far from the line the valve closes fast, near it slowly), at most 10× the
    /// base rate; 0 disables. Default 10 %.
    pub closing_rate_distance_pct: f64,
    /// ESD detection: a shaft deceleration beyond this percentage of the nominal speed per
    /// second (a drive trip; speed ramps are far slower) opens the valve fully at once, held
    /// until the speed has risen for 1 s. 0 disables. Default 20 %/s.
    pub esd_decel_pct_per_s: f64,
    /// Trip agreement: the trip condition must hold this many consecutive samples. Default 5.
    pub trip_confirm_samples: u32,
    /// Trip noise allowance: the trip thresholds move by this many times the measured noise
    /// of the surge margin (a running mean absolute deviation from its filtered value), so
    /// noise cannot fire the trip. Default 3.
    pub trip_noise_factor: f64,
    /// Largest closing speed of the valve command, opening fraction per second (seed 002
    /// §2.2.2, [15]: rate-limited closing). Opening is not rate-limited. Default 0.1/s.
    pub closing_rate_per_s: f64,
    /// Smallest valve opening the law commands, fraction (0..1). Default 0.
    pub min_opening: f64,
    /// Trip line: surge margin (q − j(R))/j(R), percent, below which the recycle trip fires
    /// (between the surge line and the SCL). 0 (default): halfway between the surge line
    /// and the control line at every pressure ratio, so the default fits every margin.
    pub trip_margin_pct: f64,
    /// Rate-of-approach trip: fires when the surge margin, extrapolated at its current
    /// (filtered) rate of approach over this horizon, falls below the trip line, s. 0 disables
    /// the rate criterion. Default 0.3 s: the linear extrapolation ignores the PI, already
    /// opening, and at 0.5 s it tripped on 2-s throttle closures the PI held alone (both
    /// recycle plants of the control benchmark; the onset trip, which catches a slam, looks
    /// no further than the approach filter's lag, 0.16 s, either way).
    pub trip_lead_time_s: f64,
    /// Cut-off of the low-pass on the surge margin before differentiation, Hz (two
    /// cascaded stages). Default 2 Hz.
    pub approach_filter_hz: f64,
    /// Cut-off of a first-order low-pass on z before the PI, Hz (0: none). Default 1 Hz.
    pub z_filter_hz: f64,
    /// Open-loop step of the trip, valve opening fraction added to the current command
    /// (seed 002 §2.2.2 [11], [13]), for an approach that just reaches the trip line; a
    /// faster approach, predicted to pass the trip line by more, gets a proportionally larger
    /// step. 0 disables the trip. Default 0.15.
    pub trip_step: f64,
    /// Time the tripped opening is held before the PI takes over, s. Default 1 s.
    pub trip_hold_s: f64,
    /// While the flow comes from the observer, cross-check it against the steady flow from the
    /// pressure ratio and speed on the speed line (seed 002 §2.2.2, category four) and use the
    /// smaller. Default true.
    pub fallback_speed_line_check: bool,
    /// Safety-on: control-line shift per detected surge, percent of surge-line flow (seed 002
    /// §2.2.2 [13] surge-count bias). Default 5 %.
    pub safety_on_step_pct: f64,
    /// Largest total safety-on shift, percent of surge-line flow. Default 20 %.
    pub safety_on_max_pct: f64,
}

impl Default for RecyclePiConfig {
    fn default() -> Self {
        RecyclePiConfig {
            control_line: ControlLineForm::default(),
            control_variable: ControlVariable::default(),
            kp_per_map_flow: 35.5,
            ki_per_map_flow_s: 85.0,
            kp: 1.0,
            ki_per_s: 2.0,
            closing_rate_distance_pct: 10.0,
            esd_decel_pct_per_s: 20.0,
            trip_confirm_samples: 5,
            trip_noise_factor: 3.0,
            closing_rate_per_s: 0.1,
            min_opening: 0.0,
            trip_margin_pct: 0.0,
            trip_lead_time_s: 0.3,
            approach_filter_hz: 2.0,
            z_filter_hz: 1.0,
            trip_step: 0.15,
            trip_hold_s: 1.0,
            fallback_speed_line_check: true,
            safety_on_step_pct: 5.0,
            safety_on_max_pct: 20.0,
        }
    }
}

/// The SCL flow at a speed: the crossing of the speed line with the control line, found by
/// bisection on R between 1 and the speed line's peak ratio. `None` if there is no crossing.
pub fn control_line_flow_at_speed(
    map: &CompressorMap,
    scl: &SurgeControlLine,
    omega_rad_s: f64,
) -> Option<(f64, f64)> {
    let (_, r_peak) = map.peak(omega_rad_s)?;
    // f(R) = Ψ(c(R), ω) − R: positive near R = 1 (c → 0, left of the peak), negative at the
    // peak ratio (c(R_peak) lies right of the peak, where Ψ < R_peak)
    let f = |r: f64| map.pressure_ratio(scl.flow_at_ratio(r), omega_rad_s) - r;
    let (mut lo, mut hi) = (1.0 + 1e-6, r_peak);
    if !(f(lo) > 0.0 && f(hi) < 0.0) {
        return None;
    }
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if f(mid) > 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let r = 0.5 * (lo + hi);
    Some((scl.flow_at_ratio(r), r))
}

/// Flow on the stable branch of the speed line at ω that gives pressure ratio `ratio`: the
/// steady operating point from pressure ratio and speed alone (seed 002 §2.2.2, category four:
/// "control without flow measurements"). Above the speed line's peak ratio the point is at or
/// left of the surge line: the peak flow is returned. NaN if the speed line has no peak.
pub fn speed_line_flow(map: &CompressorMap, ratio: f64, omega_rad_s: f64) -> f64 {
    let Some((q_peak, r_peak)) = map.peak(omega_rad_s) else {
        return f64::NAN;
    };
    if ratio >= r_peak || ratio.is_nan() {
        return q_peak;
    }
    // Ψ decreases right of the peak: bracket, then bisect
    let (mut lo, mut hi) = (q_peak, 2.0 * q_peak.abs().max(1e-9));
    for _ in 0..20 {
        if map.pressure_ratio(hi, omega_rad_s) < ratio {
            break;
        }
        lo = hi;
        hi *= 2.0;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if map.pressure_ratio(mid, omega_rad_s) > ratio {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Length of the onset detector's ring of raw margins (the window is at most one less).
const HIST_LEN: usize = 17;

/// Law state (fixed size, no allocation).
#[derive(Debug, Clone)]
pub struct RecyclePi {
    cfg: RecyclePiConfig,
    scl: SurgeControlLine,
    /// Design-point SCL flow (nominal speed), map units.
    q_ref: f64,
    /// Gains on z.
    kp_z: f64,
    ki_z: f64,
    /// z through the optional low-pass.
    z_f: f64,
    /// Integrator state (valve fraction).
    integ: f64,
    /// Last command, fraction.
    u_last: f64,
    /// Surge margin through two cascaded first-order low-passes, and the previous output.
    margin_f1: f64,
    margin_f2: f64,
    margin_f2_last: f64,
    /// Remaining trip hold time, s (≤ 0: not tripped).
    trip_left_s: f64,
    /// Consecutive samples the trip condition held.
    trip_agree: u32,
    /// The shallowest (largest) prediction over the present run of samples that agreed on a
    /// trip, surge-margin fraction: a rate trip's step is sized on it, not on the last
    /// sample's noise.
    agree_pred_max: f64,
    /// Whether the closing-rate limit held the valve above the PI's demand last cycle (the
    /// law is closing the valve).
    closing: bool,
    /// Time left in which an approach counts as the closing's own (see `approach_armed`), s.
    own_approach_left_s: f64,
    /// How long the closing-rate limit has been closing the valve without a break, s.
    closing_for_s: f64,
    /// Running mean absolute deviation of the surge margin from its filtered value (noise).
    margin_noise: f64,
    /// Samples in `margin_noise` so far (saturating): until it has ≈ 1 s of them, the
    /// estimate is their plain mean rather than a 1-s average that starts from zero.
    margin_noise_n: u32,
    /// The two previous raw margins (for the noise estimate).
    margin_prev: [f64; 2],
    /// The last distinct raw margins, newest at `hist_at`, and the time each took since the
    /// one before, s (ring; the onset detector's window: a value held by a slower bus or a
    /// hold is one sample, not several).
    margin_hist: [f64; HIST_LEN],
    hist_dt_s: [f64; HIST_LEN],
    hist_at: usize,
    /// Time of the newest distinct margin, s, and whether the flow came from the fallback.
    hist_t_s: f64,
    hist_fallback: bool,
    /// Noise of the distinct margins (mean of half the absolute second difference).
    onset_noise: f64,
    /// Distinct margins in `onset_noise` so far (saturating; as `margin_noise_n`).
    onset_noise_n: u32,
    /// Mean time between distinct margins, s (the input's sample period: a poll slower
    /// than the cycle holds each value for several cycles).
    sample_dt_s: f64,
    /// Whether the held trip came from the onset detector (it may raise its own level).
    onset_tripped: bool,
    /// The command when the held trip started, fraction.
    trip_base: f64,
    /// The measured valve position when the held trip started, fraction (NaN: not measured).
    trip_stem0: f64,
    /// Filtered shaft speed, rad/s, and its previous value (ESD detection).
    omega_f: f64,
    omega_f_last: f64,
    /// Emergency shutdown detected (valve held fully open), and how long the speed has
    /// been rising since, s.
    esd: bool,
    esd_rising_s: f64,
    /// Opening held by the trip.
    trip_level: f64,
    /// Whether the held trip was a level trip (past the trip line).
    level_tripped: bool,
    /// Trips so far.
    trips: u32,
    /// Safety-on shifts so far.
    shifts: u32,
    /// A safety-on shift not yet reported.
    shift_pending: bool,
    /// After a (re)start far right of the control line: the integrator unwinds so that the
    /// demand falls at the distance-adapted closing rate (see `update`), until the point is
    /// within `closing_rate_distance_pct` of the line or a trip fires.
    resume_unwind: bool,
    started: bool,
}

impl RecyclePi {
    /// Build for a machine: binds the control line to the machine's derived surge line, checks
    /// that it lies right of the trip line over the map's range and converts the gains at the
    /// design point.
    pub fn new(cfg: &RecyclePiConfig, model: &ControlModel) -> Result<Self, LawError> {
        let err = |key: &str, message: String| LawError::Setting {
            law: LawId::RecyclePi,
            key: format!("recycle_pi.{key}"),
            message,
        };
        let positive = |key: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(err(key, format!("must be a finite number ≥ 0, found {v}")))
            }
        };
        positive("kp_per_map_flow", cfg.kp_per_map_flow)?;
        positive("ki_per_map_flow_s", cfg.ki_per_map_flow_s)?;
        positive("kp", cfg.kp)?;
        positive("ki_per_s", cfg.ki_per_s)?;
        positive("closing_rate_distance_pct", cfg.closing_rate_distance_pct)?;
        positive("trip_noise_factor", cfg.trip_noise_factor)?;
        positive("esd_decel_pct_per_s", cfg.esd_decel_pct_per_s)?;
        positive("trip_lead_time_s", cfg.trip_lead_time_s)?;
        positive("trip_hold_s", cfg.trip_hold_s)?;
        positive("safety_on_step_pct", cfg.safety_on_step_pct)?;
        positive("safety_on_max_pct", cfg.safety_on_max_pct)?;
        positive("trip_margin_pct", cfg.trip_margin_pct)?;
        positive("z_filter_hz", cfg.z_filter_hz)?;
        if !(cfg.closing_rate_per_s.is_finite() && cfg.closing_rate_per_s > 0.0) {
            return Err(err(
                "closing_rate_per_s",
                format!("must be positive, found {}", cfg.closing_rate_per_s),
            ));
        }
        if !(cfg.approach_filter_hz.is_finite() && cfg.approach_filter_hz > 0.0) {
            return Err(err(
                "approach_filter_hz",
                format!("must be positive, found {}", cfg.approach_filter_hz),
            ));
        }
        if !(0.0..=1.0).contains(&cfg.min_opening) {
            return Err(err(
                "min_opening",
                format!("must be in 0..1, found {}", cfg.min_opening),
            ));
        }
        if !(0.0..=1.0).contains(&cfg.trip_step) {
            return Err(err(
                "trip_step",
                format!("must be in 0..1, found {}", cfg.trip_step),
            ));
        }
        let scl = SurgeControlLine::new(model.surge_line, cfg.control_line);
        // the trip line must lie between the surge line and the SCL over the map's range
        let mut pts = model.surge_line.points();
        let r_lo = pts.next().map_or(f64::NAN, |p| p.1);
        let r_hi = pts.last().map_or(f64::NAN, |p| p.1);
        if let Err((r, margin)) =
            scl.check_right_of_surge_line((r_lo, r_hi), (0.01 * cfg.trip_margin_pct).max(1e-3))
        {
            return Err(err(
                "control_line",
                format!(
                    "lies {:.1} % right of the surge line at pressure ratio {r:.3}: not right of the \
                     trip line ({} %)",
                    100.0 * margin,
                    cfg.trip_margin_pct
                ),
            ));
        }
        // the design point on the control line: where the speed line at nominal speed crosses
        // it (with a map), else the control line at the design pressure ratio (vendor data)
        let q_ref = match &model.map {
            Some(map) => control_line_flow_at_speed(map, &scl, model.drive.nominal_speed_rad_s)
                .map(|(q, _)| q)
                .ok_or_else(|| {
                    err(
                        "control_line",
                        format!(
                            "does not cross the speed line at the nominal speed {} rad/s",
                            model.drive.nominal_speed_rad_s
                        ),
                    )
                })?,
            None => scl.flow_at_ratio(model.design_pressure_ratio),
        };
        // gains on z = gains on the linear flow error / (∂z/∂q on the line at q_ref); the
        // normalised deviation's gains are on z = −d directly
        let s = cfg.control_variable.slope_on_line(q_ref);
        let (kp_z, ki_z) = match cfg.control_variable {
            ControlVariable::Deviation => (cfg.kp, cfg.ki_per_s),
            _ => (cfg.kp_per_map_flow / s, cfg.ki_per_map_flow_s / s),
        };
        Ok(RecyclePi {
            cfg: cfg.clone(),
            scl,
            q_ref,
            kp_z,
            ki_z,
            z_f: f64::NAN,
            integ: 0.0,
            u_last: f64::NAN,
            margin_f1: f64::NAN,
            margin_f2: f64::NAN,
            margin_f2_last: f64::NAN,
            trip_left_s: 0.0,
            trip_agree: 0,
            agree_pred_max: f64::NAN,
            closing: false,
            own_approach_left_s: 0.0,
            closing_for_s: 0.0,
            margin_noise: 0.0,
            margin_noise_n: 0,
            margin_prev: [f64::NAN; 2],
            margin_hist: [f64::NAN; HIST_LEN],
            hist_dt_s: [f64::NAN; HIST_LEN],
            hist_at: 0,
            hist_t_s: f64::NAN,
            hist_fallback: false,
            onset_noise: 0.0,
            onset_noise_n: 0,
            sample_dt_s: f64::NAN,
            onset_tripped: false,
            trip_base: 0.0,
            trip_stem0: f64::NAN,
            omega_f: f64::NAN,
            omega_f_last: f64::NAN,
            esd: false,
            esd_rising_s: 0.0,
            trip_level: 0.0,
            level_tripped: false,
            trips: 0,
            shifts: 0,
            shift_pending: false,
            resume_unwind: false,
            started: false,
        })
    }

    /// The control line in use (with its safety-on shift).
    pub fn control_line(&self) -> &SurgeControlLine {
        &self.scl
    }

    /// Design-point SCL flow at nominal speed, map units.
    pub fn design_flow(&self) -> f64 {
        self.q_ref
    }

    /// Gains on z actually used: (K_p, K_i).
    pub fn z_gains(&self) -> (f64, f64) {
        (self.kp_z, self.ki_z)
    }

    /// Safety-on shifts so far.
    pub fn safety_on_count(&self) -> u32 {
        self.shifts
    }

    /// Restore `count` safety-on steps kept across a restart (the operator's surge history
    /// outlives the process); the shift is capped at `safety_on_max_pct`.
    pub fn restore_safety_on(&mut self, count: u32) {
        self.shifts = count;
        self.scl.shift = (0.01 * self.cfg.safety_on_step_pct * f64::from(count))
            .min(0.01 * self.cfg.safety_on_max_pct);
    }

    /// Recycle trips so far.
    pub fn trip_count(&self) -> u32 {
        self.trips
    }

    /// Whether the trip currently holds the valve.
    pub fn tripped(&self) -> bool {
        self.trip_left_s > 0.0
    }

    /// Hot reload: take over the running instance's state, with this instance's gains.
    ///
    /// The trip hold, the approach filters, the trip and safety-on counters and the control
    /// line's safety-on shift always carry over (an edited gain must not move the line back
    /// left after a surge, nor cancel a trip). When z means the same thing in both (same
    /// control variable, control line and z filter), the PI integrator is re-based so that
    /// the unclamped demand at the last z is unchanged: a bumpless parameter change that
    /// also keeps a closing-rate-limited valve on its way. Returns false when z changed
    /// meaning; the caller then starts the law bumplessly from the applied opening.
    pub fn take_over_from(&mut self, old: &RecyclePi) -> bool {
        if !old.started {
            return false;
        }
        self.scl.shift = old.scl.shift.min(0.01 * self.cfg.safety_on_max_pct);
        self.shifts = old.shifts;
        self.trips = old.trips;
        let same_z = self.cfg.control_variable == old.cfg.control_variable
            && self.cfg.control_line == old.cfg.control_line
            && self.cfg.z_filter_hz == old.cfg.z_filter_hz;
        if !same_z || !old.u_last.is_finite() {
            return false;
        }
        self.z_f = old.z_f;
        self.integ = if old.z_f.is_finite() {
            old.integ + (old.kp_z - self.kp_z) * old.z_f
        } else {
            old.integ
        };
        self.u_last = old.u_last;
        self.margin_f1 = old.margin_f1;
        self.margin_f2 = old.margin_f2;
        self.margin_f2_last = old.margin_f2_last;
        self.trip_left_s = old.trip_left_s;
        self.trip_level = old.trip_level;
        self.level_tripped = old.level_tripped;
        self.onset_tripped = old.onset_tripped;
        self.trip_base = old.trip_base;
        self.trip_stem0 = old.trip_stem0;
        self.margin_hist = old.margin_hist;
        self.hist_dt_s = old.hist_dt_s;
        self.hist_at = old.hist_at;
        self.hist_t_s = old.hist_t_s;
        self.hist_fallback = old.hist_fallback;
        self.onset_noise = old.onset_noise;
        self.onset_noise_n = old.onset_noise_n;
        self.margin_noise = old.margin_noise;
        self.margin_noise_n = old.margin_noise_n;
        self.sample_dt_s = old.sample_dt_s;
        self.shift_pending = old.shift_pending;
        self.started = true;
        true
    }

    /// The control variable at an operating point (flow in map units, pressure ratio).
    #[inline]
    pub fn z_at(&self, flow_map: f64, pressure_ratio: f64) -> f64 {
        self.cfg
            .control_variable
            .z(flow_map, self.scl.flow_at_ratio(pressure_ratio))
    }

    fn reset_margin_filter(&mut self, margin: f64) {
        self.margin_f1 = margin;
        self.margin_f2 = margin;
        self.margin_f2_last = margin;
    }

    /// ESD detection on the shaft speed (2 Hz low-pass, then differentiated): a deceleration
    /// beyond `esd_decel_pct_per_s` of the nominal speed per second. Returns true when it
    /// starts. 0 disables.
    fn detect_esd(&mut self, omega: f64, nominal: f64, dt: f64) -> bool {
        if self.cfg.esd_decel_pct_per_s <= 0.0 || !omega.is_finite() || dt <= 0.0 {
            return false;
        }
        if !self.omega_f.is_finite() {
            self.omega_f = omega;
            self.omega_f_last = omega;
            return false;
        }
        let a = 1.0 - (-2.0 * std::f64::consts::PI * 2.0 * dt).exp();
        self.omega_f_last = self.omega_f;
        self.omega_f += a * (omega - self.omega_f);
        let rate = (self.omega_f - self.omega_f_last) / dt;
        let limit = -0.01 * self.cfg.esd_decel_pct_per_s * nominal.abs();
        if self.esd {
            self.esd_rising_s = if rate > 0.0 {
                self.esd_rising_s + dt
            } else {
                0.0
            };
            if self.esd_rising_s >= 1.0 {
                self.esd = false;
            }
            false
        } else if rate < limit {
            self.esd = true;
            self.esd_rising_s = 0.0;
            true
        } else {
            false
        }
    }

    /// Whether an emergency shutdown (drive trip) is detected.
    pub fn esd_detected(&self) -> bool {
        self.esd
    }

    /// Trip line at a pressure ratio, fraction of surge-line flow: `trip_margin_pct`, or
    /// halfway to the control line.
    /// Whether the rate-of-approach trip is armed: at or left of the control line (z ≥ 0),
    /// and right of it too unless a trip is being held or its valve is still closing back
    /// (that closing is an approach as well, and must not re-trip). A fast approach from
    /// far right (a throttle slam) must trip before the control line: seconds-long valve
    /// strokes cannot catch it there.
    ///
    /// Never while the closing-rate limit is closing the valve, nor for the approach filter's
    /// lag after a sustained closing (its filtered rate still shows the closing): that
    /// approach is the law's own doing (after a trip, a fail-safe resume or a load change);
    /// the PI stops closing as soon as the point reaches the line, and the level trip stays
    /// armed throughout.
    fn approach_armed(&self, z: f64) -> bool {
        !self.closing
            && self.own_approach_left_s <= 0.0
            && (z >= 0.0 || (self.trip_left_s <= 0.0 && self.u_last <= self.limits().0 + 1e-9))
    }

    /// Lag of the two-pole approach filter on a ramp, s: 2/ω, ω = 2π `approach_filter_hz`
    /// (0 without the filter).
    fn approach_lag_s(&self) -> f64 {
        if self.cfg.approach_filter_hz > 0.0 {
            2.0 / (2.0 * std::f64::consts::PI * self.cfg.approach_filter_hz)
        } else {
            0.0
        }
    }

    /// The onset detector's prediction: the raw surge margin extrapolated over
    /// `trip_lead_time_s` at its rate over the last `trip_confirm_samples` samples, when
    /// over that window it never rose by more than the noise gate and fell in total by more
    /// than twice that gate (`trip_noise_factor` × the measured noise): agreement over
    /// several samples, so white noise cannot fire it (a monotonic run of that depth is
    /// improbable), a clean fast fall fires it within the window. NaN otherwise.
    fn onset_prediction(&self) -> f64 {
        let w = (self.cfg.trip_confirm_samples.max(1) as usize).min(HIST_LEN - 1);
        if self.cfg.trip_lead_time_s <= 0.0 {
            return f64::NAN;
        }
        let idx = |i: usize| (self.hist_at + HIST_LEN - i) % HIST_LEN;
        let at = |i: usize| self.margin_hist[idx(i)];
        let mut span_s = 0.0;
        for i in 0..w {
            let (newer, older) = (at(i), at(i + 1));
            // strictly falling distinct samples (a rise of any size breaks the agreement)
            if !(newer.is_finite() && older.is_finite()) || newer > older {
                return f64::NAN;
            }
            span_s += self.hist_dt_s[idx(i)];
        }
        let drop = at(w) - at(0);
        if !(drop > 2.0 * self.cfg.trip_noise_factor * self.onset_noise && span_s > 0.0) {
            return f64::NAN;
        }
        // the horizon: the approach filter's lag (two poles), not the whole lead time
        let lag_s = if self.cfg.approach_filter_hz > 0.0 {
            self.approach_lag_s()
        } else {
            self.cfg.trip_lead_time_s
        };
        at(0) - self.cfg.trip_lead_time_s.min(lag_s) * drop / span_s
    }

    /// Record a raw margin for the onset detector when it differs from the last one (time
    /// from the measurements' own clock, so a hold or a slow poll counts as the time it
    /// took); a switch to or from the fallback flow starts the window afresh (the step
    /// between two flow sources is no approach).
    fn push_onset_sample(&mut self, margin: f64, t_s: f64, fallback: bool) {
        if fallback != self.hist_fallback || !margin.is_finite() || !t_s.is_finite() {
            self.margin_hist = [f64::NAN; HIST_LEN];
            self.hist_fallback = fallback;
            self.hist_t_s = f64::NAN;
        }
        let last = self.margin_hist[self.hist_at];
        if margin == last || !margin.is_finite() {
            return;
        }
        let age = t_s - self.hist_t_s;
        let (p1, p2) = (
            last,
            self.margin_hist[(self.hist_at + HIST_LEN - 1) % HIST_LEN],
        );
        if p1.is_finite() && p2.is_finite() && age.is_finite() {
            self.onset_noise_n = self.onset_noise_n.saturating_add(1);
            let a = noise_weight(age, self.onset_noise_n);
            let d2 = 0.5 * (margin - 2.0 * p1 + p2).abs();
            self.onset_noise += a * (d2 - self.onset_noise);
        }
        self.hist_at = (self.hist_at + 1) % HIST_LEN;
        self.margin_hist[self.hist_at] = margin;
        self.hist_dt_s[self.hist_at] = if age.is_finite() { age } else { f64::NAN };
        self.hist_t_s = t_s;
        // the sample period (a hold or an outage is no sample period: at most 0.1 s counts)
        if age.is_finite() && age > 0.0 {
            let age = age.min(0.1);
            self.sample_dt_s = if self.sample_dt_s.is_finite() {
                self.sample_dt_s + 0.05 * (age - self.sample_dt_s)
            } else {
                age
            };
        }
    }

    /// Standard deviation of the filtered rate of approach that margin noise of standard
    /// deviation `noise` (fraction of surge-line flow) leaves, 1/s: σ √(T ω³/4), T the input's
    /// sample period (`dt_s` until one is measured), ω = 2π `approach_filter_hz`.
    fn rate_noise_per_s(&self, noise: f64, dt_s: f64) -> f64 {
        let t = if self.sample_dt_s.is_finite() {
            self.sample_dt_s.max(dt_s)
        } else {
            dt_s
        };
        let w = 2.0 * std::f64::consts::PI * self.cfg.approach_filter_hz;
        let s = noise * (t * w * w * w / 4.0).sqrt();
        if s.is_finite() {
            s
        } else {
            0.0
        }
    }

    fn trip_margin_at(&self, ratio: f64) -> f64 {
        trip_margin_at(self.cfg.trip_margin_pct, &self.scl, ratio)
    }

    /// Allowed closing rate, fraction/s: the base rate, plus one base rate per
    /// `closing_rate_distance_pct` of control-line flow right of the line.
    fn closing_rate(&self, q: f64, ratio: f64) -> f64 {
        self.cfg.closing_rate_per_s * self.distance_factor(q, ratio)
    }

    /// How far right of the control line the operating point lies, as the factor
    /// 1 + distance/`closing_rate_distance_pct` (1 at or left of the line, at most 10): the
    /// closing rate grows with it (a valve left open far from the line after a trip or a
    /// fail-safe resume closes quickly; near the line slowly). (Growing the integral gain
    /// with it too closed the valve into surge after a frozen Δp at a 5 % margin.)
    fn distance_factor(&self, q: f64, ratio: f64) -> f64 {
        if self.cfg.closing_rate_distance_pct <= 0.0 {
            return 1.0;
        }
        let c = self.scl.flow_at_ratio(ratio);
        let right = if c > 0.0 { (q - c) / c } else { 0.0 };
        if right.is_finite() && right > 0.0 {
            (1.0 + right / (0.01 * self.cfg.closing_rate_distance_pct)).min(10.0)
        } else {
            1.0
        }
    }

    #[inline]
    fn limits(&self) -> (f64, f64) {
        (self.cfg.min_opening, 1.0)
    }
}

impl SurgeLaw for RecyclePi {
    fn start(&mut self, inputs: &LawInputs<'_>, current: &ActuatorCommands) {
        let m = inputs.m;
        let mut u0 = current.get(ActuatorId::RecycleValve);
        if !u0.is_finite() {
            u0 = m.recycle_position;
        }
        if !u0.is_finite() {
            u0 = self.cfg.min_opening;
        }
        // bumpless: the first PI output equals the applied opening
        let z0 = self.z_at(m.flow_map, m.pressure_ratio);
        self.u_last = u0;
        self.z_f = z0;
        self.integ = if z0.is_finite() {
            u0 - self.kp_z * z0
        } else {
            u0
        };
        let margin = inputs.model.surge_margin(m.flow_map, m.pressure_ratio);
        self.reset_margin_filter(margin);
        self.trip_left_s = 0.0;
        self.trip_agree = 0;
        self.margin_prev = [f64::NAN; 2];
        self.margin_hist = [f64::NAN; HIST_LEN];
        self.hist_t_s = f64::NAN;
        self.onset_tripped = false;
        // the speed filter restarts too: after a fail-safe or a hold, the last filtered
        // speed is old, and the difference is no deceleration
        self.omega_f = f64::NAN;
        self.omega_f_last = f64::NAN;
        self.esd = false;
        self.resume_unwind = true;
        self.started = true;
    }

    fn update(&mut self, inputs: &LawInputs<'_>, dt_s: f64) -> LawOutput {
        if !self.started {
            let cur = ActuatorCommands::default();
            self.start(inputs, &cur);
        }
        let m = inputs.m;
        let r = m.pressure_ratio;
        let mut q = m.flow_map;
        if let (true, true, Some(map)) = (
            m.flow_fallback,
            self.cfg.fallback_speed_line_check,
            &inputs.model.map,
        ) {
            // transmitter failed: cross-check the observer's flow against the steady flow from
            // pressure ratio and speed, and use the smaller (the safer for surge)
            let q_line = speed_line_flow(map, r, m.omega_rad_s);
            if q_line < q {
                q = q_line;
            }
        }
        let z = self.z_at(q, r);
        let mut out = LawOutput::idle();
        if !z.is_finite() || !self.u_last.is_finite() {
            // no usable operating point: hold the valve (the core goes fail-safe on lost inputs)
            if self.u_last.is_finite() {
                out.commands.set(ActuatorId::RecycleValve, self.u_last);
            }
            return out;
        }
        let dt = dt_s.max(0.0);
        let z_raw = z;
        let z = if self.cfg.z_filter_hz > 0.0 && self.z_f.is_finite() {
            let a = 1.0 - (-2.0 * std::f64::consts::PI * self.cfg.z_filter_hz * dt).exp();
            self.z_f += a * (z_raw - self.z_f);
            self.z_f
        } else {
            self.z_f = z_raw;
            z_raw
        };

        // rate of approach: the surge margin through two first-order low-passes (the
        // derivative of noisy pressures needs the second), then differentiated
        let margin = inputs.model.surge_margin(q, r);
        let mut d_margin = 0.0;
        if margin.is_finite() && self.margin_f2.is_finite() {
            let a = 1.0 - (-2.0 * std::f64::consts::PI * self.cfg.approach_filter_hz * dt).exp();
            self.margin_f2_last = self.margin_f2;
            self.margin_f1 += a * (margin - self.margin_f1);
            self.margin_f2 += a * (self.margin_f1 - self.margin_f2);
            if dt > 0.0 {
                d_margin = (self.margin_f2 - self.margin_f2_last) / dt;
            }
        } else {
            self.reset_margin_filter(margin);
        }

        // recycle trip ([11], [13]): the trip line is crossed, or, at or left of the control
        // line (z ≥ 0), it would be crossed within the lead time at the present rate of approach
        // noise-proof: the level criterion uses the filtered margin, both thresholds move
        // left by the measured noise (mean absolute deviation of the margin from its filtered
        // value, ≈ 1 s average), and the condition must hold over several samples
        let trip_margin = self.trip_margin_at(r);
        // (noise from the second difference |m_k − 2 m_k−1 + m_k−2|/2: ≈ σ for white noise,
        // ≈ 0 for a ramp, so a fast but clean approach does not raise the allowance)
        let [p1, p2] = self.margin_prev;
        if margin.is_finite() && p1.is_finite() && p2.is_finite() {
            self.margin_noise_n = self.margin_noise_n.saturating_add(1);
            let a = noise_weight(dt, self.margin_noise_n);
            let d2 = 0.5 * (margin - 2.0 * p1 + p2).abs();
            self.margin_noise += a * (d2 - self.margin_noise);
        }
        self.margin_prev = [margin, p1];
        // (capped: in deep surge the margin swings hard, which is no reason not to trip)
        // (the larger of the per-cycle and the per-change noise: a value held by a slower
        // bus changes only every few cycles, and its per-cycle second difference understates
        // its noise: a 100 Hz poll under a 1 kHz loop fired the rate trip on noise)
        let noise = self.margin_noise.max(self.onset_noise);
        let allowance = (self.cfg.trip_noise_factor * noise).min(0.5 * trip_margin);
        // the level the trip judges: the raw margin when it has moved away from its filtered
        // value by more than `trip_noise_factor` × its noise (a real, fast move: no filter
        // lag; the gate is not capped like the allowance), else the
        // filtered one (noise alone: a single noisy sample must not size the step)
        let gate = (self.cfg.trip_noise_factor * noise).max(1e-6);
        let margin_t = if (margin - self.margin_f1).abs() > gate {
            margin
        } else {
            self.margin_f1
        };
        // the rate judged is the filtered rate beyond its own noise: white noise of standard
        // deviation σ, sampled every T, leaves σ √(T ω³/4) in the derivative of its two-pole
        // low-pass at ω = 2π `approach_filter_hz` (∫ w² |H(jw)|² dw/2π = ω³/4 for H =
        // ω²/(s + ω)²); at a 5 % margin with 1 % pressure noise that is ±0.08/s, which over
        // the then 0.5 s lead time alone crossed the trip line on noise (hemchi2016: four trips in
        // 15 s, each 10-14 % of valve for nothing)
        let rate_noise = self.cfg.trip_noise_factor * self.rate_noise_per_s(noise, dt);
        let predicted = margin_t + self.cfg.trip_lead_time_s * (d_margin + rate_noise).min(0.0);
        let armed = self.approach_armed(z);
        let trip_cond = margin.is_finite()
            && (margin_t < trip_margin - allowance
                || (armed && predicted < trip_margin - allowance));
        self.trip_agree = if trip_cond {
            self.trip_agree.saturating_add(1)
        } else {
            0
        };
        self.agree_pred_max = if self.trip_agree <= 1 {
            predicted
        } else {
            self.agree_pred_max.max(predicted)
        };
        // onset detector: the raw margin's own rate over the agreement window, without the
        // approach filter's lag (≈ 0.15 s at 2 Hz, far too late for a throttle slam on a
        // seconds-long valve stroke: kvangardsnes2009 at 5 % crosses its surge line 55 ms
        // after the step, and the filtered rate tripped at 25 ms)
        self.push_onset_sample(margin, m.t_s, m.flow_fallback);
        let onset_pred = if armed {
            self.onset_prediction()
        } else {
            f64::NAN
        };
        let onset_now = onset_pred < trip_margin - allowance;
        let trip_now =
            (trip_cond && self.trip_agree >= self.cfg.trip_confirm_samples.max(1)) || onset_now;
        // the step is sized on the deeper of the two predictions
        let predicted = if onset_now {
            predicted.min(onset_pred)
        } else {
            self.agree_pred_max
        };
        self.trip_left_s -= dt;
        // the hold ends early once the trip has done its work: the point right of the control
        // line by the noise allowance, and moving away from it (the filtered rate positive).
        // Holding a slam's step the full `trip_hold_s` while the point ran 40 % beyond the
        // line recycled 3 % of kvangardsnes2009's throttle-step energy for nothing.
        if self.trip_left_s > 0.0
            && !self.esd
            && z_raw < -allowance
            && z < 0.0
            && d_margin > rate_noise
        {
            self.trip_left_s = 0.0;
            // the PI takes over from where the valve is, not from the command: a valve
            // stroking towards a slam's step is still opening when the point turns (the
            // opening it has reached already suffices), and its command would carry it on
            // (kvangardsnes2009: command 0.35, stem 0.25 and rising, the point 20 % right
            // of its line and moving away)
            // Only a stem that has moved up, by more than 1 % of travel, from where it stood
            // when the trip started is on its way: one held there by a second master or a
            // stuck positioner is not, and taking over from it would hide the mismatch the
            // core watches for.
            let pos = m.recycle_position;
            if pos.is_finite() && pos < self.u_last && pos > self.trip_stem0 + 0.01 {
                self.u_last = pos.max(self.limits().0);
                self.integ = self.u_last - self.kp_z * z;
            }
        }
        let mut event = None;
        // a level trip (past the trip line) escalates a held, smaller rate trip: the rate
        // trip's proportional step must not block the full step when the point gets there
        let level_now = margin_t < trip_margin - allowance;
        let escalate = level_now && !self.level_tripped && self.trip_left_s > 0.0;
        // a held onset trip follows the onset's growing prediction (the first samples of a
        // slam see only its start): its level may rise, silently, while the onset lasts
        let follow_onset = onset_now && self.onset_tripped && self.trip_left_s > 0.0;
        if trip_now
            && (self.trip_left_s <= 0.0 || escalate || follow_onset)
            && self.cfg.trip_step > 0.0
        {
            let (_, hi) = self.limits();
            // the step grows with the predicted penetration past the trip line (seed 002
            // §2.2.2 [11]: the faster the approach, the larger the open-loop step): a slow
            // drift gets `trip_step`, a throttle slam that would cross the whole trip margin
            // within the lead time gets a multiple of it (a soft PI cannot catch that alone)
            // Below the trip line (the level criterion) at least `trip_step`; a rate trip
            // still right of the line gets a step in proportion to the predicted penetration
            // (a slow drift that would just touch the trip line needs little, and a full
            // `trip_step` there recycled 3 % of a matrix's energy for nothing)
            let level = margin_t < trip_margin - allowance;
            let depth = if trip_margin > 0.0 {
                // (the penetration past the threshold that fired: the noise allowance
                // delays a trip, and counting it in the depth as well stepped 12 % of valve
                // on hemchi2016's noisy closure where the clean one steps 1 %; and, for a
                // rate trip, the shallowest prediction of the samples that agreed: the last
                // one alone carries its filtered rate's noise × the lead time, and stepped
                // 4.3 % there)
                let d = (trip_margin - allowance - predicted) / trip_margin;
                if level {
                    d.max(1.0)
                } else {
                    d.max(0.0)
                }
            } else {
                1.0
            };
            // A rate or onset trip (still right of the trip line) gets at most 2 × `trip_step`:
            // its prediction extrapolates the approach linearly over the lead time, and for
            // a throttle slam that reads as a penetration of several surge-line flows, which
            // no valve needs (kvangardsnes2009 throttle step at 10 %: 71 % valve travel for a
            // closest approach of +6.0 %, the same +6.0 % with 56 %; a cap of 1 × fell to
            // 27 % but let the observer-fallback run on hemchi2016 settle on the line only
            // after 11.4 s); should the point still reach the trip line, the level trip
            // escalates the held step.
            let depth = if level { depth } else { depth.min(2.0) };
            let raised_only = follow_onset && !escalate;
            // a raised onset trip steps from where its trip started (the valve command has
            // followed the held level since: stepping from it would ratchet)
            if self.trip_left_s <= 0.0 {
                // a fresh trip: where the stem stood when it started
                self.trip_stem0 = m.recycle_position;
            }
            if !raised_only {
                self.trip_base = self.u_last;
            }
            self.trip_level = (self.trip_base + self.cfg.trip_step * depth).min(hi).max(
                if self.trip_left_s > 0.0 {
                    self.trip_level
                } else {
                    0.0
                },
            );
            if !raised_only {
                self.level_tripped = level;
                self.onset_tripped = onset_now && !level;
                self.trip_left_s = self.cfg.trip_hold_s.max(dt);
                self.trips = self.trips.saturating_add(1);
                event = Some(LawEvent::RecycleTrip {
                    opening: self.trip_level,
                });
            }
        }

        // emergency shutdown (seed 002 §2.2.2: ESD events): the shaft decelerates faster than
        // any speed ramp (drive trip) → valve fully open at once, held until the speed has
        // been rising for 1 s (the drive back)
        let esd_started =
            self.detect_esd(m.omega_rad_s, inputs.model.drive.nominal_speed_rad_s, dt);
        if esd_started && event.is_none() {
            event = Some(LawEvent::RecycleTrip { opening: 1.0 });
            self.trips = self.trips.saturating_add(1);
        }
        if self.esd {
            self.trip_level = 1.0;
            self.trip_left_s = self.trip_left_s.max(self.cfg.trip_hold_s.max(dt));
        }

        // PI on z (seed 001 eq. 3.7, K_d = 0) with anti-windup against the static limits: the
        // integrator tracks the clamped demand
        let (lo, hi) = self.limits();
        let mut integ_next = self.integ + self.ki_z * z * dt;
        let rate = self.closing_rate(q, r);
        if self.resume_unwind
            && (z >= 0.0
                || self.distance_factor(q, r) <= 1.5
                || self.trip_left_s > 0.0
                || self.u_last <= lo)
        {
            self.resume_unwind = false;
        }
        // resume far right of the line (a link outage or a fail-safe leaves the valve open):
        // the bumpless start put Kp·z0 into the integrator, and as the point moves towards
        // the line the rising Kp·z cancels the integral's fall, so the demand, not the
        // closing-rate limit, set the pace (hemchi2016: 0.12/s from 43 % open while 80 %
        // right of the line). Until the point is within `closing_rate_distance_pct` of the
        // line, the integrator unwinds so that the demand falls at least at the
        // distance-adapted closing rate; from there on the PI closes as before (the base
        // rate near the line: no overshoot into it). Only after a (re)start: after a trip
        // the same unwinding closed kvangardsnes2009's valve back into surge.
        if self.resume_unwind && self.u_last > lo {
            integ_next = integ_next.min(self.u_last - rate * dt - self.kp_z * z);
        }
        let u_pi = integ_next + self.kp_z * z;
        let demand = u_pi.clamp(lo, hi);
        // fast opening, rate-limited closing ([15]): the valve follows the demand up at once and
        // down at most at the closing rate; the PI keeps its own demand meanwhile. The rate
        // grows with the distance right of the control line: far from it the valve closes
        // fast (less recycle after a trip or a fail-safe), near it slowly.
        let mut follow = demand.max(self.u_last - rate * dt);
        // ... and a sustained closing (see below) stops at the control line: once the point
        // has reached it (z ≥ 0) the valve stays where it is and the PI takes over from
        // there. After a restart the demand may lie far below the valve (the PI unwound while
        // the point still ran away from the line), and closing on until the demand met the
        // valve carried kvangardsnes2009 past its control line at 0.35/s of margin
        // (HIL link bounce, the seed-form tuning).
        let lag_s = self.approach_lag_s();
        let hold_at_line = z >= 0.0
            && follow < self.u_last
            && self.closing_for_s >= lag_s
            && self.closing_for_s > 0.0;
        if hold_at_line {
            follow = self.u_last;
        }
        let mut u = follow;
        // trip hold: at least the tripped opening
        if self.trip_left_s > 0.0 {
            u = u.max(self.trip_level);
        }
        u = u.clamp(lo, hi);
        // anti-windup: when the trip holds the valve above the PI, the integrator tracks the
        // applied opening (the PI takes over from it bumplessly); while the closing-rate limit
        // holds the valve above the demand, the integrator does not integrate further in the
        // closing direction (conditional integration), so the demand cannot dive below the
        // valve; against the static limits it tracks the clamped demand
        // At the closed limit the integrator stops at the limit itself (not at limit − Kp·z,
        // which would let every noise uptick right of the line open the valve).
        self.integ = if u > follow {
            u - self.kp_z * z
        } else if u_pi > hi {
            hi - self.kp_z * z
        } else if u_pi < lo {
            if z < 0.0 {
                integ_next.max(lo)
            } else {
                integ_next
            }
        } else if hold_at_line {
            u - self.kp_z * z
        } else if u > demand && z < 0.0 {
            self.integ
        } else {
            integ_next
        };
        self.u_last = u;
        self.closing = u > demand && !hold_at_line;
        // a sustained closing (longer than the approach filter's lag: after a restart or a
        // trip, not a noisy demand dipping for a cycle) moves the point towards the line by
        // the law's own doing, and its filtered rate still shows that for the filter's lag
        // after it ends: the approach trips wait that long (kvangardsnes2009 on the HIL link
        // bounce, the seed-form tuning: the closing after the resume ended with the point
        // still approaching at 0.35/s of margin, which fired a 15 % trip at once)
        if self.closing {
            self.closing_for_s += dt;
        } else {
            if self.closing_for_s >= lag_s && lag_s > 0.0 {
                self.own_approach_left_s = lag_s;
            }
            self.closing_for_s = 0.0;
            self.own_approach_left_s -= dt;
        }

        if event.is_none() && self.shift_pending {
            self.shift_pending = false;
            event = Some(LawEvent::SafetyOnShift {
                total_margin: self.scl.shift,
                count: self.shifts,
            });
        }
        out.commands.set(ActuatorId::RecycleValve, u);
        out.diagnostic = z_raw;
        out.event = event;
        out
    }

    fn surge_detected(&mut self) {
        // safety-on: move the control line right by one step (seed 002 §2.2.2, [13])
        let max = 0.01 * self.cfg.safety_on_max_pct;
        let next = (self.scl.shift + 0.01 * self.cfg.safety_on_step_pct).min(max);
        if next > self.scl.shift {
            self.scl.shift = next;
            self.shifts = self.shifts.saturating_add(1);
            self.shift_pending = true;
        }
    }
}

/// Weight of a new sample, `age_s` after the one before, in a noise estimate that has
/// `n` ≥ 1 samples with it: the 1-s running average's weight (the age in seconds), but at
/// least 1/n, so the first samples make a plain mean instead of an average still near its
/// starting zero. (From zero, a 1-s average had reached a fifth of ±4 % flow noise after
/// 200 ms of a 1 kHz loop, and the onset trip fired a 30 % step on that noise, 20 % right
/// of the control line.)
fn noise_weight(age_s: f64, n: u32) -> f64 {
    age_s.clamp(0.0, 1.0).max(1.0 / f64::from(n.max(1)))
}

/// The trip line at a pressure ratio, as a surge margin (fraction of surge-line flow):
/// `trip_margin_pct` when set (> 0), else halfway between the surge line and the control line
/// `scl`. The law trips on it and the pictures draw it from here.
pub fn trip_margin_at(trip_margin_pct: f64, scl: &SurgeControlLine, ratio: f64) -> f64 {
    if trip_margin_pct > 0.0 {
        return 0.01 * trip_margin_pct;
    }
    let j = scl.surge_line().flow_at_ratio(ratio);
    let c = scl.flow_at_ratio(ratio);
    if j > 0.0 {
        0.5 * (c - j) / j
    } else {
        0.0
    }
}
