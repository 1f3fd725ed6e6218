//! `recycle-pi`: industrial surge avoidance with the recycle valve (seed 001 ch. 3, seed 002
//! §2.2.2, §2.3, ch. 4), built from named parts, each with its purpose, its settings section
//! and its unit tests:
//!
//! | part | file | section | purpose |
//! |---|---|---|---|
//! | PI | [`pi`] | `[controller.recycle_pi.pi]` | holds the point on the control line; the only part that closes the valve |
//! | recycle trip | [`trip`] | `[controller.recycle_pi.trip]` | open-loop step on crossing, or predicted crossing, of the trip line |
//! | closing limiter | [`closing`] | `[controller.recycle_pi.closing]` | closes no faster than a rate, never below the opening the control line needs |
//! | safety-on | [`safety_on`] | `[controller.recycle_pi.safety_on]` | moves the control line right after each detected surge |
//! | throttle watch | [`throttle`] | `[controller.recycle_pi.throttle]` | the process valve's closing, seen before the flow follows, predicts the crossing for the trip |
//! | ESD detection | [`esd`] | `[controller.recycle_pi.esd]` | opens fully on a drive trip (shaft deceleration) |
//! | start and resume | [`start_opening`] | none | bumpless from the *measured* valve position |
//!
//! The output is the high-select of the parts' demands (the PI's, the trip's, the ESD's and
//! the closing limiter's floor), clamped to [`RecyclePiConfig::min_opening`], 1]; the part
//! that set it is [`RecyclePi::output_part`], and each trip event names its criterion. With
//! the trip, the closing limiter, safety-on and the ESD detection off and no z filter, the
//! law is a textbook PI with conditional-integration anti-windup.
//!
//! The operating point (q, R) is taken in invariant coordinates: q is the compressor flow in
//! the map's coordinate (volumetric flow at suction for seed 002's map, eq. 2.14: the density
//! correction with p1 and T1 is done by the core from the orifice Δp or the observer's mass
//! flow) and R = p_d/p_s (seed 002 eq. 2.6). The surge control line q_SCL = c(R) is built on
//! the *derived* surge line j(R) (seed 002 eq. 2.7, 4.1/4.17/4.36 or 4.2;
//! [`SurgeControlLine`]).
//!
//! Control variable, z > 0 left of the line (opens the valve), selectable
//! ([`ControlVariable`]): strategy 1 (seed 002 eq. 4.15–4.19), strategy 2 (eq. 4.33–4.38), or
//! the normalised deviation (default). Correction, stated: the seed's q̄ is the orifice Δp,
//! which carries the sign of the flow; we keep that sign (q̄ = q|q|, not q²) so that reversed
//! flow in deep surge reads as far *left* of the line.
//!
//! Deviation from seed 001 eq. 3.6, stated: there the error is clamped to zero right of the
//! line, so the integral can only grow and the valve never closes again. We use the signed z:
//! right of the line the PI closes the valve, down to the minimum opening.
//!
//! Gains. Seed 001 (ch. 3.4) tunes Kp = 35.5, Ki = 85 on the linear flow error in kg/s. The
//! strategies' z are not linear flow errors: near the line z₁ ≈ 2 q (c − q) and z₂ ≈
//! 2 (c − q)/q; their gains are therefore given per unit of equivalent linear flow error and
//! converted once, at the design point q_ref (the SCL flow at nominal speed).
//!
//! Flow-transmitter fallback: when the core feeds the observer's flow
//! (`Measurements::flow_fallback`), the law cross-checks it against the steady flow on the
//! speed line at the measured ratio and speed (seed 002 §2.2.2, category four) and uses the
//! smaller, the safer for surge.

pub mod closing;
pub mod esd;
pub mod pi;
pub mod safety_on;
pub mod samples;
pub mod throttle;
pub mod trip;

pub use closing::{ClosingConfig, ClosingLimiter};
pub use esd::{EsdConfig, EsdDetector};
pub use pi::{ControlVariable, Pi, PiConfig};
pub use safety_on::{SafetyOn, SafetyOnConfig};
pub use throttle::{ThrottleConfig, ThrottlePrediction, ThrottleWatch};
pub use trip::{RecycleTrip, TripConfig, TripKind};

use crate::control::law::api::{
    LawError, LawEvent, LawId, LawInputs, LawOutput, SurgeLaw, TripCause,
};
use crate::control::model::ControlModel;
use crate::control::surge_control_line::{ControlLineForm, SurgeControlLine};
use crate::physics::compressor_map::CompressorMap;
use crate::physics::valve::Characteristic;
use crate::vocab::signals::{ActuatorCommands, ActuatorId};
use serde::{Deserialize, Serialize};

/// Settings (`[controller.recycle_pi]` and its part sections).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecyclePiConfig {
    /// The surge control line (seed 002 eq. 4.1/4.17/4.36 margin form, or eq. 4.2 c0 √(R−1);
    /// App. A uses c0 = 0.6). Default: 10 % of surge-line flow.
    pub control_line: ControlLineForm,
    /// Smallest valve opening the law commands, fraction (0..1). Default 0.
    pub min_opening: f64,
    /// While the flow comes from the observer, cross-check it against the steady flow from
    /// the pressure ratio and speed on the speed line (seed 002 §2.2.2, category four) and
    /// use the smaller. Default true.
    pub fallback_speed_line_check: bool,
    /// The PI.
    pub pi: PiConfig,
    /// The recycle trip.
    pub trip: TripConfig,
    /// The throttle watch (feeds the trip).
    pub throttle: ThrottleConfig,
    /// The closing limiter.
    pub closing: ClosingConfig,
    /// Safety-on.
    pub safety_on: SafetyOnConfig,
    /// ESD detection.
    pub esd: EsdConfig,
}

impl Default for RecyclePiConfig {
    fn default() -> Self {
        RecyclePiConfig {
            control_line: ControlLineForm::default(),
            min_opening: 0.0,
            fallback_speed_line_check: true,
            pi: PiConfig::default(),
            trip: TripConfig::default(),
            throttle: ThrottleConfig::default(),
            closing: ClosingConfig::default(),
            safety_on: SafetyOnConfig::default(),
            esd: EsdConfig::default(),
        }
    }
}

/// Which part set the output.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputPart {
    /// The PI's demand.
    Pi,
    /// The recycle trip's held opening.
    Trip,
    /// The closing limiter held a closing back.
    ClosingLimiter,
    /// The ESD detection opened the valve fully.
    Esd,
    /// No usable operating point: the last output is held.
    Hold,
}

impl OutputPart {
    /// Name in status and events.
    pub fn name(self) -> &'static str {
        match self {
            OutputPart::Pi => "pi",
            OutputPart::Trip => "trip",
            OutputPart::ClosingLimiter => "closing_limiter",
            OutputPart::Esd => "esd",
            OutputPart::Hold => "hold",
        }
    }
}

/// Start and resume: the opening a (re)started law takes over from, bumplessly: the output
/// applied now, which the core sets to the *measured* valve position at process start and at
/// every fail-safe exit and link restart (the valve is where it is, not where the last command
/// or the fail-safe wanted it: `ControlCore::cycle`), and leaves at the command after a switch
/// from manual, another law or the ESD contact's opening (the valve is on its way there); else
/// the measured position; else the minimum opening.
pub fn start_opening(measured: f64, applied: f64, min_opening: f64) -> f64 {
    if applied.is_finite() {
        applied.clamp(0.0, 1.0)
    } else if measured.is_finite() {
        measured.clamp(0.0, 1.0)
    } else {
        min_opening
    }
}

/// Law state (fixed size, no allocation).
#[derive(Debug, Clone)]
pub struct RecyclePi {
    cfg: RecyclePiConfig,
    scl: SurgeControlLine,
    /// Design-point SCL flow (nominal speed), map units.
    q_ref: f64,
    pi: Pi,
    trip: RecycleTrip,
    throttle: ThrottleWatch,
    closing: ClosingLimiter,
    safety_on: SafetyOn,
    esd: EsdDetector,
    /// Last output, fraction (NaN before the start).
    u_last: f64,
    part: OutputPart,
    /// Whether the last cycle's flow came from the fallback (a switch of flow source is a
    /// step in the margin, not an approach: the trip forgets its samples).
    last_fallback: bool,
    /// Whether the closing may take the return rate: set when the flow transmitter's return
    /// released a trip ([`ClosingLimiter::return_rate_per_s`]), cleared when the PI's own
    /// demand is selected again or a trip fires.
    returning: bool,
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
        let non_negative = |key: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(err(key, format!("must be a finite number ≥ 0, found {v}")))
            }
        };
        non_negative("pi.kp_per_map_flow", cfg.pi.kp_per_map_flow)?;
        non_negative("pi.ki_per_map_flow_s", cfg.pi.ki_per_map_flow_s)?;
        non_negative("pi.kp", cfg.pi.kp)?;
        non_negative("pi.ki_per_s", cfg.pi.ki_per_s)?;
        non_negative("pi.z_filter_hz", cfg.pi.z_filter_hz)?;
        non_negative("trip.margin_pct", cfg.trip.margin_pct)?;
        non_negative("trip.lead_time_s", cfg.trip.lead_time_s)?;
        non_negative("trip.rate_window_s", cfg.trip.rate_window_s)?;
        non_negative("trip.confirm_s", cfg.trip.confirm_s)?;
        non_negative("trip.hold_s", cfg.trip.hold_s)?;
        non_negative("trip.noise_factor", cfg.trip.noise_factor)?;
        non_negative("safety_on.step_pct", cfg.safety_on.step_pct)?;
        non_negative("safety_on.max_pct", cfg.safety_on.max_pct)?;
        non_negative("esd.decel_pct_per_s", cfg.esd.decel_pct_per_s)?;
        non_negative("esd.release_s", cfg.esd.release_s)?;
        if cfg.closing.rate_per_s <= 0.0 || cfg.closing.rate_per_s.is_nan() {
            return Err(err(
                "closing.rate_per_s",
                format!("must be positive, found {}", cfg.closing.rate_per_s),
            ));
        }
        if !(cfg.esd.filter_hz.is_finite() && cfg.esd.filter_hz > 0.0) {
            return Err(err(
                "esd.filter_hz",
                format!("must be positive, found {}", cfg.esd.filter_hz),
            ));
        }
        if !(0.0..=1.0).contains(&cfg.min_opening) {
            return Err(err(
                "min_opening",
                format!("must be in 0..1, found {}", cfg.min_opening),
            ));
        }
        if !(0.0..=1.0).contains(&cfg.trip.step) {
            return Err(err(
                "trip.step",
                format!("must be in 0..1, found {}", cfg.trip.step),
            ));
        }
        let scl = SurgeControlLine::new(model.surge_line, cfg.control_line);
        // the trip line must lie between the surge line and the SCL over the map's range
        let mut pts = model.surge_line.points();
        let r_lo = pts.next().map_or(f64::NAN, |p| p.1);
        let r_hi = pts.last().map_or(f64::NAN, |p| p.1);
        if let Err((r, margin)) =
            scl.check_right_of_surge_line((r_lo, r_hi), (0.01 * cfg.trip.margin_pct).max(1e-3))
        {
            return Err(err(
                "control_line",
                format!(
                    "lies {:.1} % right of the surge line at pressure ratio {r:.3}: not right of the \
                     trip line ({} %)",
                    100.0 * margin,
                    cfg.trip.margin_pct
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
        let (kp_z, ki_z) = cfg.pi.z_gains(q_ref);
        let (characteristic, stroke_time_s) = model
            .recycle_valve
            .map_or((Characteristic::Linear, f64::NAN), |v| {
                (v.spec.characteristic, v.spec.stroke_time_s)
            });
        Ok(RecyclePi {
            cfg: cfg.clone(),
            scl,
            q_ref,
            pi: Pi::new(kp_z, ki_z, cfg.pi.z_filter_hz),
            trip: RecycleTrip::new(&cfg.trip, stroke_time_s),
            throttle: ThrottleWatch::new(&cfg.throttle),
            closing: ClosingLimiter::new(&cfg.closing, characteristic),
            safety_on: SafetyOn::new(&cfg.safety_on),
            esd: EsdDetector::new(&cfg.esd),
            u_last: f64::NAN,
            part: OutputPart::Hold,
            last_fallback: false,
            returning: false,
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
        (self.pi.kp, self.pi.ki_per_s)
    }

    /// The trip's prediction horizon in use, s (derived from the valve's stroke time unless
    /// set).
    pub fn trip_lead_time_s(&self) -> f64 {
        self.trip.lead_time_s()
    }

    /// Safety-on shifts so far.
    pub fn safety_on_count(&self) -> u32 {
        self.safety_on.count()
    }

    /// Restore `count` safety-on steps kept across a restart (the operator's surge history
    /// outlives the process); the shift is capped at `safety_on.max_pct`.
    pub fn restore_safety_on(&mut self, count: u32) {
        self.safety_on.restore(count);
        self.scl.shift = self.safety_on.shift();
    }

    /// Recycle trips so far (each step counts, repeats included).
    pub fn trip_count(&self) -> u32 {
        self.trip.count()
    }

    /// Whether the trip currently holds the valve.
    pub fn tripped(&self) -> bool {
        self.trip.holding()
    }

    /// Which part set the last output.
    pub fn output_part(&self) -> OutputPart {
        self.part
    }

    /// Whether an emergency shutdown (drive trip) is detected.
    pub fn esd_detected(&self) -> bool {
        self.esd.active()
    }

    /// Hot reload: take over the running instance's state, with this instance's settings.
    ///
    /// The trip and safety-on counters and the control line's safety-on shift always carry
    /// over (an edited gain must not move the line back left after a surge). When z means the
    /// same thing in both (same control variable, control line and z filter), the PI is
    /// re-based so that its unclamped demand at the last z is unchanged, and the trip's
    /// samples and hold carry over: a bumpless change of settings. Returns false when z
    /// changed meaning; the caller then starts the law bumplessly from the applied opening.
    pub fn take_over_from(&mut self, old: &RecyclePi) -> bool {
        if !old.started {
            return false;
        }
        self.restore_safety_on(old.safety_on.count());
        let same_z = self.cfg.pi.control_variable == old.cfg.pi.control_variable
            && self.cfg.control_line == old.cfg.control_line
            && self.cfg.pi.z_filter_hz == old.cfg.pi.z_filter_hz;
        self.trip.take_over(&old.trip);
        self.throttle.take_over(&old.throttle);
        if !same_z || !old.u_last.is_finite() {
            // the counters stay; the rest starts afresh from the applied opening
            self.trip.restart();
            self.throttle.restart();
            return false;
        }
        self.pi.take_over(&old.pi);
        self.esd = old.esd;
        self.u_last = old.u_last;
        self.part = old.part;
        self.last_fallback = old.last_fallback;
        self.returning = old.returning;
        self.started = true;
        true
    }

    /// The control variable at an operating point (flow in map units, pressure ratio).
    #[inline]
    pub fn z_at(&self, flow_map: f64, pressure_ratio: f64) -> f64 {
        self.cfg
            .pi
            .control_variable
            .z(flow_map, self.scl.flow_at_ratio(pressure_ratio))
    }

    #[inline]
    fn limits(&self) -> (f64, f64) {
        (self.cfg.min_opening, 1.0)
    }
}

impl SurgeLaw for RecyclePi {
    fn start(&mut self, inputs: &LawInputs<'_>, current: &ActuatorCommands) {
        let m = inputs.m;
        let u0 = start_opening(
            m.recycle_position,
            current.get(ActuatorId::RecycleValve),
            self.cfg.min_opening,
        );
        let z0 = self.z_at(m.flow_map, m.pressure_ratio);
        self.u_last = u0;
        self.pi.start(u0, z0);
        self.trip.restart();
        self.throttle.restart();
        self.esd.restart();
        self.part = OutputPart::Pi;
        self.last_fallback = m.flow_fallback;
        self.returning = false;
        self.started = true;
    }

    fn update(&mut self, inputs: &LawInputs<'_>, dt_s: f64) -> LawOutput {
        if !self.started {
            self.start(inputs, &ActuatorCommands::default());
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
        let c = self.scl.flow_at_ratio(r);
        let z = self.cfg.pi.control_variable.z(q, c);
        let mut out = LawOutput::idle();
        if !z.is_finite() || !self.u_last.is_finite() {
            // no usable operating point: hold the valve (the core goes fail-safe on lost inputs)
            if self.u_last.is_finite() {
                out.commands.set(ActuatorId::RecycleValve, self.u_last);
            }
            self.part = OutputPart::Hold;
            return out;
        }
        let dt = dt_s.max(0.0);
        let (lo, hi) = self.limits();
        // a switch of flow source is a step between two sources, not a change of the flow:
        // the PI's filter restarts at the new source's z, the trip forgets its samples
        let switched = m.flow_fallback != self.last_fallback;
        let back_on_transmitter = switched && !m.flow_fallback;
        if switched {
            self.pi.restart_filter(z);
        }

        // the PI (its own demand, conditional integration against the static limits)
        let z_f = self.pi.filter(z, dt);
        let pi_demand = self.pi.step(z_f, dt, lo, hi);

        // the recycle trip, on the surge margin against the trip line
        if switched {
            self.trip.forget_samples();
            self.last_fallback = m.flow_fallback;
        }
        let margin = inputs.model.surge_margin(q, r);
        let trip_line = trip_margin_at(self.cfg.trip.margin_pct, &self.scl, r);
        let j = self.scl.surge_line().flow_at_ratio(r);
        // the control line as a surge margin
        let line = if j > 0.0 { (c - j) / j } else { f64::NAN };
        let gap = line - trip_line;
        // the flow transmitter is trusted again and shows the point right of the control
        // line: a trip held on the observer's estimate has no measured approach behind it;
        // the hold ends, and the closing back is paced by the distance the transmitter shows
        if back_on_transmitter && self.trip.holding() && margin > line {
            self.trip.release();
            self.returning = true;
        }
        // the sample's own time: a value held by a slower poll is one sample, not several
        let age_s = inputs.history.sample_age_s;
        let t_sample_s = m.t_s
            - if age_s.is_finite() {
                age_s.max(0.0)
            } else {
                0.0
            };
        let mut throttle = self.throttle.update(
            m.throttle_position,
            t_sample_s,
            self.trip.horizon_s(age_s),
            self.cfg.trip.rate_window_s,
            self.cfg.trip.noise_factor,
            dt,
        );
        // the throttle passes the compressor flow less what the recycle valve returns; of the
        // flow it will no longer pass, the part the margin's trend already shows falling over
        // the horizon is the margin prediction's to judge (a slow ramp the flow follows as it
        // goes): the throttle predicts what the flow has not yet shown
        let share = throttle_share(inputs.model, m);
        let shown = self.trip.horizon_s(age_s) * self.trip.trend_fall_per_s() / (1.0 + margin);
        throttle.flow_ratio = (1.0 - share * (1.0 - throttle.flow_ratio) + shown.max(0.0)).min(1.0);
        let (trip_demand, trip_fired) = self.trip.update(
            margin,
            t_sample_s,
            trip_line,
            gap,
            self.u_last,
            age_s,
            throttle,
            dt,
        );
        if trip_fired.is_some() {
            self.returning = false;
        }
        if trip_fired == Some(TripKind::Throttle) {
            self.throttle.stepped();
        } else if !self.trip.holding() {
            self.throttle.released();
        }

        // ESD detection on the shaft speed
        let esd_started =
            self.esd
                .update(m.omega_rad_s, inputs.model.drive.nominal_speed_rad_s, dt);
        let esd_demand = if self.esd.active() { hi } else { f64::NAN };

        // the closing limiter's floor
        // (slowed so that its own approach cannot make the trip predict a crossing)
        let cap = if self.cfg.trip.enabled && self.cfg.trip.step > 0.0 {
            let u_pos = if m.recycle_position.is_finite() {
                m.recycle_position
            } else {
                self.u_last
            };
            if self.trip.drifting_below(line) {
                // the point still drifts towards the control line and would pass it within a
                // hold time (the plant answering an earlier closing, or a disturbance):
                // closing now would add to an approach whose end is not yet known; the
                // closing waits until the drift settles
                0.0
            } else {
                ClosingLimiter::approach_cap_per_s(
                    u_pos,
                    margin,
                    trip_line,
                    self.trip.horizon_s(age_s),
                )
            }
        } else {
            f64::INFINITY
        };
        let return_rate = if self.returning {
            let u_pos = if m.recycle_position.is_finite() {
                m.recycle_position
            } else {
                self.u_last
            };
            ClosingLimiter::return_rate_per_s(u_pos, margin, line, self.trip.hold_s())
        } else {
            f64::NAN
        };
        let floor = self
            .closing
            .floor(self.u_last, m.recycle_position, q, c, cap, return_rate, dt);

        // high-select
        let mut u = pi_demand;
        let mut part = OutputPart::Pi;
        for (d, p) in [
            (floor, OutputPart::ClosingLimiter),
            (trip_demand, OutputPart::Trip),
            (esd_demand, OutputPart::Esd),
        ] {
            if d > u + 1e-12 {
                u = d;
                part = p;
            }
        }
        let u = u.clamp(lo, hi);
        self.pi.follow(u, pi_demand, z_f);
        self.u_last = u;
        self.part = part;
        if part == OutputPart::Pi {
            self.returning = false;
        }

        out.event = if esd_started {
            Some(LawEvent::RecycleTrip {
                opening: hi,
                cause: TripCause::SpeedDecay,
            })
        } else if let Some(kind) = trip_fired {
            Some(LawEvent::RecycleTrip {
                opening: u,
                cause: match kind {
                    TripKind::Level => TripCause::TripLine,
                    TripKind::Predicted => TripCause::PredictedCrossing,
                    TripKind::Throttle => TripCause::ThrottleClosure,
                },
            })
        } else if self.safety_on.take_pending() {
            Some(LawEvent::SafetyOnShift {
                total_margin: self.scl.shift,
                count: self.safety_on.count(),
            })
        } else {
            None
        };
        out.commands.set(ActuatorId::RecycleValve, u);
        out.diagnostic = z;
        out
    }

    fn surge_detected(&mut self) {
        if self.safety_on.on_surge() {
            self.scl.shift = self.safety_on.shift();
        }
    }
}

/// The fraction of the compressor flow that leaves through the throttle: 1 − w_r/w_c, the
/// recycle flow w_r = C_v(u) √(2 ρ_d (p_d − p_s)) (seed 002 eq. 2.15) at the measured valve
/// position, from the valve capacity of the machine data, ρ_d at the discharge pressure and
/// the polytropic discharge temperature T_s R^σ (seed 002 eq. 2.2). Where the capacity, the
/// position or a pressure is unknown: 1, the whole compressor flow (the bound the closing
/// limiter uses too: the recycle flow is at most the compressor flow).
pub fn throttle_share(model: &ControlModel, m: &super::measurements::Measurements) -> f64 {
    let Some(valve) = model.recycle_valve else {
        return 1.0;
    };
    let cv = valve.spec.cv_m2(m.recycle_position);
    let r = m.p_discharge_pa / m.p_suction_pa;
    let t_d = m.t_suction_k * r.max(1.0).powf(model.gas.polytropic_exponent);
    let rho_d = model.gas.density_kg_m3(m.p_discharge_pa, t_d);
    let dp = m.p_discharge_pa - m.p_suction_pa;
    let w_r = cv * (2.0 * rho_d * dp.max(0.0)).sqrt();
    let share = 1.0 - w_r / m.m_kg_s;
    if share.is_finite() && m.m_kg_s > 0.0 {
        share.clamp(0.0, 1.0)
    } else {
        1.0
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
