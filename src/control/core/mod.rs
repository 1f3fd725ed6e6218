//! One control cycle: supervise inputs, estimate the flow, run the active law on top of the
//! speed loop, decide the fail-safe state. Pure and allocation-free; the simulation and the
//! daemon call [`ControlCore::cycle`] once per period.

use super::checks::cross_check::FrozenDpCheck;
use super::checks::drift_check::DriftCheck;
use super::config::{ControllerConfig, FlowSource};
use super::law::api::{LawError, LawEvent, LawId, LawInputs, LoopHistory};
use super::law::Law;
use super::measurements::{Measurements, OperatorInputs, RawSensors};
use super::model::ControlModel;
use super::observer::{LowPass, MassFlowObserver};
use super::speed_loop::SpeedLoop;
use super::supervisor::{InputFault, Validity};
use super::surge_control_line::SurgeControlLine;
use super::vote::Vote;
use crate::surge::{Detection, SurgeDetector};
use crate::vocab::signals::{ActuatorCommands, ActuatorId, SensorId};
use crate::vocab::Mode;

mod settings;
pub use settings::*;

/// What widens the control line now (the degraded policy in force).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MarginShift {
    /// Shift in force, fraction of the control-line flow (moving towards `target`).
    pub now: f64,
    /// Where it is moving: the largest of the causes below, fraction.
    pub target: f64,
    /// A redundant measurement's vote is degraded (its `degraded_margin_pct`), fraction.
    pub vote: f64,
    /// A field link is slow but alive ([`SLOW_LINK_MARGIN`]), fraction.
    pub slow_link: f64,
}

/// What one cycle produced (for traces, the event log and the I/O layer).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleOutput {
    /// Setpoints to send (NaN: not driven).
    pub commands: ActuatorCommands,
    /// Measurements the laws saw.
    pub measurements: Measurements,
    /// Mode after the cycle.
    pub mode: Mode,
    /// Active law.
    pub law: LawId,
    /// Input validity.
    pub validity: Validity,
    /// A law-specific diagnostic (e.g. the control variable z), NaN if none.
    pub law_diagnostic: f64,
    /// What the online surge detector saw this cycle.
    pub surge: Detection,
    /// An event the law reported this cycle.
    pub law_event: Option<LawEvent>,
    /// The law's own drive-torque command this cycle (τ̄d on top of the speed loop), N·m;
    /// NaN when the law does not drive the torque or no law ran. Actuator peaks of a run are
    /// measured on this, not on the total (which includes the load torque the speed loop holds).
    pub law_torque_nm: f64,
    /// The emergency-shutdown / drive-trip input ([`SensorId::EsdInput`]) is set and usable:
    /// the recycle valve is commanded fully open this cycle, whatever the mode and law.
    pub esd_active: bool,
}

/// Filtered derivative: low-pass then difference.
#[derive(Debug, Clone, Copy)]
struct Differentiator {
    lp: LowPass,
    last: f64,
}

impl Differentiator {
    fn new(hz: f64) -> Self {
        Differentiator {
            lp: LowPass::new(hz),
            last: f64::NAN,
        }
    }
    fn update(&mut self, x: f64, dt: f64) -> f64 {
        if !x.is_finite() {
            self.last = f64::NAN;
            return f64::NAN;
        }
        let y = self.lp.update(x, dt);
        let d = if self.last.is_finite() && dt > 0.0 {
            (y - self.last) / dt
        } else {
            0.0
        };
        self.last = y;
        d
    }
}

/// A reconfiguration of the core built off the real-time thread by
/// [`ControlCore::prepare`]; after [`ControlCore::commit`] it holds the replaced parts.
#[derive(Debug)]
pub struct Reconfiguration {
    config: ControllerConfig,
    law: Law,
    detector: SurgeDetector,
    d_suction: Differentiator,
    d_discharge: Differentiator,
}

impl Reconfiguration {
    /// The law it carries.
    pub fn law(&self) -> LawId {
        self.law.id()
    }
}

/// The control core.
#[derive(Debug, Clone)]
pub struct ControlCore {
    model: ControlModel,
    config: ControllerConfig,
    settings: CoreSettings,
    speed: SpeedLoop,
    law: Law,
    requested_law: LawId,
    mode: Mode,
    auto_requested: bool,
    observer: Option<MassFlowObserver>,
    d_suction: Differentiator,
    d_discharge: Differentiator,
    detector: SurgeDetector,
    manual_recycle: f64,
    last_manual_input: f64,
    last: ActuatorCommands,
    last_t_s: f64,
    /// Time of the first cycle, s (NaN before it).
    first_t_s: f64,
    /// Total drive torque commands of the last cycles (for delay-compensating laws).
    history: LoopHistory,
    /// Sample numbers of the cycle inputs last processed ([`RawSensors::cycle_seq`]; `None`:
    /// none yet, or not numbered).
    last_cycle_seq: Option<[u64; crate::vocab::signals::CYCLE_INPUTS.len()]>,
    /// The same sample on its senders' clocks ([`RawSensors::sender_clock_s`]), s (NaN: none).
    last_sender_s: f64,
    /// Measurements of the last processed sample (repeated by a holding cycle).
    last_meas: Measurements,
    law_started: bool,
    /// Since when essential inputs have failed in auto/manual (the failure hold), s; NaN: not.
    failing_since_s: f64,
    /// Since when inputs have been healthy in fail-safe (exit hysteresis), s; NaN: not.
    healthy_since_s: f64,
    /// The drive torque the drive reports this cycle (fresh and in range), N·m; NaN if none.
    reported_torque_nm: f64,
    /// Whether fail-safe has taken the drive's reported torque as its held torque since the
    /// report became fresh.
    failsafe_torque_latched: bool,
    /// The last finite torque fail-safe held, N·m (a resume without the drive's report
    /// takes over from it while fail-safe leaves the torque uncommanded).
    failsafe_held_torque_nm: f64,
    /// The law's own torque of the last computing cycle (repeated by a holding cycle), N·m.
    last_law_torque_nm: f64,
    /// The law was rebuilt by a reload while it ran (same law, new settings): its restart
    /// takes over the extra torque it applied last instead of starting from none.
    reload_restart: bool,
    /// Cross-check of the flow element's Δp against the pressures (frozen transmitter).
    dp_frozen: FrozenDpCheck,
    /// Cross-check of the flow transmitter against the observer and the speed-line flow
    /// (drifting or biased Δp).
    dp_drift: DriftCheck,
    /// Votes of the measurements with redundant transmitters.
    vote: Vote,
    /// A field link is slow but alive (set by the daemon each cycle).
    link_slow: bool,
    /// The degraded margin shift.
    shift: MarginShift,
}

impl ControlCore {
    /// A core for a machine, starting in automatic mode with `law` once inputs are valid.
    /// `initial_torque_nm` presets the speed loop (bumpless start on a running machine).
    pub fn new(
        model: ControlModel,
        config: ControllerConfig,
        settings: CoreSettings,
        law: LawId,
        initial_torque_nm: f64,
    ) -> Result<Self, LawError> {
        let d = model.drive;
        let active = Law::new(law, &config, &model)?;
        let observer = model
            .observer_plant()
            .map(|p| MassFlowObserver::new(&config.observer, p));
        Ok(ControlCore {
            speed: SpeedLoop::new(
                d.speed_kp_nm_s_rad,
                d.speed_ki_nm_rad,
                (d.min_torque_nm, d.rated_torque_nm),
                initial_torque_nm,
            ),
            d_suction: Differentiator::new(config.derivative_filter_hz),
            d_discharge: Differentiator::new(config.derivative_filter_hz),
            detector: SurgeDetector::new(config.detector),
            law: active,
            requested_law: law,
            mode: Mode::Init,
            auto_requested: true,
            observer,
            manual_recycle: f64::NAN,
            last_manual_input: f64::NAN,
            last: ActuatorCommands::default(),
            last_t_s: f64::NAN,
            first_t_s: f64::NAN,
            history: LoopHistory::EMPTY,
            last_cycle_seq: None,
            last_sender_s: f64::NAN,
            last_meas: Measurements::unavailable(f64::NAN),
            law_started: false,
            failing_since_s: f64::NAN,
            healthy_since_s: f64::NAN,
            reported_torque_nm: f64::NAN,
            failsafe_torque_latched: false,
            failsafe_held_torque_nm: f64::NAN,
            last_law_torque_nm: f64::NAN,
            reload_restart: false,
            dp_frozen: FrozenDpCheck::new(),
            dp_drift: DriftCheck::new(),
            vote: Vote::new(),
            link_slow: false,
            shift: MarginShift::default(),
            model,
            config,
            settings,
        })
    }

    /// The machine model.
    pub fn model(&self) -> &ControlModel {
        &self.model
    }

    /// Controller settings.
    pub fn config(&self) -> &ControllerConfig {
        &self.config
    }

    /// Active law.
    pub fn law(&self) -> LawId {
        self.law.id()
    }

    /// Current mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The frozen-Δp cross-check.
    pub fn dp_cross_check(&self) -> &FrozenDpCheck {
        &self.dp_frozen
    }

    /// The drift/bias cross-check of the flow transmitter (its last verdict holds the
    /// residuals for the event log and status).
    pub fn dp_drift_check(&self) -> &DriftCheck {
        &self.dp_drift
    }

    /// The votes of the measurements with redundant transmitters (this cycle's).
    pub fn vote(&self) -> &Vote {
        &self.vote
    }

    /// The degraded margin shift in force and its causes.
    pub fn margin_shift(&self) -> MarginShift {
        self.shift
    }

    /// Tell the core whether a field link is slow but alive (`field_link_slow`): the
    /// slow-link policy widens the control line by [`SLOW_LINK_MARGIN`] while it lasts.
    pub fn set_link_slow(&mut self, slow: bool) {
        self.link_slow = slow;
    }

    /// Move the margin shift towards its target (at most [`MARGIN_SHIFT_RATE_PER_S`]).
    fn update_margin_shift(&mut self, dt: f64) {
        let vote = self.vote.degraded_margin(&self.settings.vote);
        let slow_link = if self.link_slow {
            SLOW_LINK_MARGIN
        } else {
            0.0
        };
        let target = vote.max(slow_link);
        let step = MARGIN_SHIFT_RATE_PER_S * dt.max(0.0);
        let now = self.shift.now + (target - self.shift.now).clamp(-step, step);
        self.shift = MarginShift {
            now,
            target,
            vote,
            slow_link,
        };
    }

    /// The measurements a law sees: with a control-line law (recycle-pi), the flow scaled
    /// by 1/(1 + shift), so its control and trip lines act `shift` of their flow further
    /// right; laws without a control line (active surge control on a model) see the
    /// measurements as they are.
    fn law_measurements(&self, m: &Measurements) -> Measurements {
        let s = self.shift.now;
        if s <= 0.0 || self.control_line().is_none() {
            return *m;
        }
        let mut out = *m;
        out.m_kg_s /= 1.0 + s;
        out.flow_map /= 1.0 + s;
        out
    }

    /// The online surge detector.
    pub fn detector(&self) -> &SurgeDetector {
        &self.detector
    }

    /// Build a reconfiguration off the real-time thread (this allocates): the law `law` with
    /// `config` for `model` (the model the core was built with), a fresh surge detector and
    /// derivative filters in case their settings changed. Fails, and nothing reaches the
    /// control thread, if the law does not apply. [`commit`](Self::commit) swaps it in.
    pub fn prepare(
        model: &ControlModel,
        config: ControllerConfig,
        law: LawId,
    ) -> Result<Reconfiguration, LawError> {
        Ok(Reconfiguration {
            law: Law::new(law, &config, model)?,
            detector: SurgeDetector::new(config.detector),
            d_suction: Differentiator::new(config.derivative_filter_hz),
            d_discharge: Differentiator::new(config.derivative_filter_hz),
            config,
        })
    }

    /// Swap a prepared reconfiguration in at this cycle boundary, without allocating or
    /// freeing (ros2_control's controller switch is the model): the same law takes over the
    /// running one's state (recycle-pi: integrator re-based, trip and safety-on kept), another
    /// law starts bumplessly from the current outputs; the observer keeps its estimate; the
    /// detector and derivative filters keep their history unless their settings changed.
    /// Returns the replaced parts, to be dropped off the real-time thread.
    pub fn commit(&mut self, mut r: Reconfiguration) -> Reconfiguration {
        let same_law = r.law.id() == self.law.id();
        let carried = same_law && self.law_started && r.law.take_over_from(&self.law);
        self.observer = self.model.observer_plant().map(|p| match &self.observer {
            Some(running) => running.retuned(&r.config.observer, p),
            None => MassFlowObserver::new(&r.config.observer, p),
        });
        if r.config.detector != self.config.detector {
            std::mem::swap(&mut self.detector, &mut r.detector);
        }
        if r.config.derivative_filter_hz != self.config.derivative_filter_hz {
            std::mem::swap(&mut self.d_suction, &mut r.d_suction);
            std::mem::swap(&mut self.d_discharge, &mut r.d_discharge);
        }
        std::mem::swap(&mut self.law, &mut r.law);
        std::mem::swap(&mut self.config, &mut r.config);
        self.requested_law = self.law.id();
        self.reload_restart = same_law && self.law_started && !carried;
        self.law_started = same_law && carried;
        r
    }

    /// Replace the input limits and fail-safe opening (hot reload); takes effect next cycle.
    pub fn set_settings(&mut self, settings: CoreSettings) {
        self.settings = settings;
    }

    /// Settings in force.
    pub fn settings(&self) -> &CoreSettings {
        &self.settings
    }

    /// Enter the fail-safe state now (shutdown, loss of the control thread's inputs) and
    /// return its setpoints: recycle valve to its safe opening, thrust to centre, CCV
    /// neutral, drive torque held. The next healthy cycle resumes bumplessly.
    pub fn safe_state(&mut self) -> ActuatorCommands {
        let meas = Measurements::unavailable(self.last_t_s);
        let validity = self.settings.supervisor.check(&RawSensors::missing());
        self.failsafe(meas, validity).commands
    }

    /// Request automatic (true) or manual (false) mode.
    pub fn request_auto(&mut self, auto: bool) {
        if self.auto_requested && !auto {
            // entering manual: the manual station starts from the current valve output
            self.manual_recycle = self.last.get(ActuatorId::RecycleValve);
        }
        if !self.auto_requested && auto {
            self.law_started = false;
            self.reload_restart = false;
        }
        self.auto_requested = auto;
    }

    /// Whether automatic mode is requested (false: the manual station is in charge).
    pub fn auto_requested(&self) -> bool {
        self.auto_requested
    }

    /// The manual station's valve output, fraction (NaN until manual was first entered).
    pub fn manual_output(&self) -> f64 {
        self.manual_recycle
    }

    /// Set the manual station's valve output, fraction 0..1 (takes effect in manual; the
    /// law's protection still opens further when the operating point needs it).
    pub fn set_manual_output(&mut self, opening: f64) {
        if opening.is_finite() {
            self.manual_recycle = opening.clamp(0.0, 1.0);
        }
    }

    /// The active law's surge control line (with its safety-on shift) and trip-line margin
    /// (fraction of surge-line flow), for the operator's map; `None` for laws without one.
    pub fn control_line(&self) -> Option<(SurgeControlLine, f64)> {
        match &self.law {
            Law::RecyclePi(l) => Some((
                *l.control_line(),
                0.01 * self.config.recycle_pi.trip.margin_pct,
            )),
            _ => None,
        }
    }

    /// Safety-on steps and recycle trips of the active law so far.
    pub fn safety_on_and_trips(&self) -> (u32, u32) {
        match &self.law {
            Law::RecyclePi(l) => (l.safety_on_count(), l.trip_count()),
            _ => (0, 0),
        }
    }

    /// Restore the safety-on steps kept across a restart (persistent state).
    pub fn restore_safety_on(&mut self, count: u32) {
        if let Law::RecyclePi(l) = &mut self.law {
            l.restore_safety_on(count);
        }
    }

    /// Build measurements from validated inputs.
    fn measurements(
        &mut self,
        t_s: f64,
        dt: f64,
        raw: &RawSensors,
        v: &mut Validity,
    ) -> Measurements {
        let get = |id: SensorId| {
            if v.ok(id) {
                raw.values.get(id)
            } else {
                f64::NAN
            }
        };
        let p_s = get(SensorId::PSuction);
        let p_d = get(SensorId::PDischarge);
        let omega = get(SensorId::ShaftSpeed);
        let t_s_k = if v.ok(SensorId::TSuction) {
            raw.values.get(SensorId::TSuction)
        } else {
            self.model.nominal_suction_temperature_k
        };
        let recycle = get(SensorId::RecycleValvePosition);
        let throttle = get(SensorId::ThrottlePosition);
        let thrust = get(SensorId::ThrustPosition);
        let mut m_meas = self.model.orifice.mass_flow_kg_s(
            &self.model.gas,
            get(SensorId::OrificeDp),
            p_s,
            t_s_k,
        );

        // observer: runs whenever its inputs are there, so it is warm for a fallback
        let mut m_obs = f64::NAN;
        if let Some(obs) = &mut self.observer {
            let out = self.model.outflow_kg_s(p_s, p_d, recycle, throttle);
            if p_s.is_finite() && p_d.is_finite() && omega.is_finite() && out.is_finite() {
                if !obs.started() && m_meas.is_finite() {
                    obs.reset(m_meas, p_d, p_s);
                }
                let model = &self.model;
                m_obs = obs.update(p_s, p_d, out, dt, |m| {
                    model.pressure_ratio_at(m, p_s, t_s_k, omega, thrust)
                });
                if !m_obs.is_finite() {
                    // never carry a broken estimate: restart from the measured or steady flow
                    let m0 = if m_meas.is_finite() { m_meas } else { out };
                    obs.reset(m0, p_d, p_s);
                    m_obs = m0;
                }
            }
        }
        // cross-check: the transmitter's flow against the observer's and the speed-line flow
        // (a frozen Δp is the other check's; the drift check holds meanwhile)
        let ratio = p_d / p_s;
        let (q_line, line_unc) = match self.model.speed_line_flow(ratio, omega) {
            Some((q, slope)) if slope < 0.0 => (
                q,
                0.01 * self.config.drift_check.map_uncertainty_pct
                    * (q + (ratio - 1.0) / slope.abs()),
            ),
            _ => (f64::NAN, f64::NAN),
        };
        // the observer's steady-state error from a map error δΨ = ε (R − 1): the error
        // dynamics (seed 000 eq. 16) settle at m̃ = p_s δΨ / (c2 − p_s ∂Ψ/∂m); plus a map
        // whose flows are off by ε: the observer settles where Ψ̂(m̂) matches, ε m̂ off
        let eps = 0.01 * self.config.drift_check.map_uncertainty_pct;
        let obs_unc = match &self.observer {
            Some(o) if m_obs.is_finite() => {
                let dm = 1e-4 * m_obs.abs().max(1e-3);
                let psi = |m: f64| self.model.pressure_ratio_at(m, p_s, t_s_k, omega, thrust);
                let slope = (psi(m_obs + dm) - psi(m_obs - dm)) / (2.0 * dm);
                let gain = o.c2() - p_s * slope.max(0.0);
                let m_err = if gain > 0.0 {
                    p_s * eps * (ratio - 1.0).abs() / gain
                } else {
                    f64::INFINITY
                };
                self.model.map_flow(m_err + eps * m_obs.abs(), p_s, t_s_k)
            }
            _ => f64::NAN,
        };
        let drift = self.dp_drift.update(
            &self.config.drift_check,
            t_s,
            self.model.map_flow(m_meas, p_s, t_s_k),
            self.model.map_flow(m_obs, p_s, t_s_k),
            obs_unc,
            q_line,
            line_unc,
            // the residuals' unit, the surge-line flow at the measured ratio, floored at half
            // the design point's: running down towards standstill (R → 1) the surge-line
            // flow goes to zero, and the map's 3 % flow error, which the observer and the
            // speed line share (it confirms nothing), read as 70-140 % (kvangardsnes2009's
            // ESD rundown at 13 % speed with the map 3 % off in flow: a false find; a tenth
            // of the design flow still read it as 7 %). Near the design point, where surge
            // matters, the unit is unchanged.
            self.model.surge_line.flow_at_ratio(ratio).max(
                0.5 * self
                    .model
                    .surge_line
                    .flow_at_ratio(self.model.design_pressure_ratio),
            ),
        );
        if drift.drifting && v.ok(SensorId::OrificeDp) {
            v.fault[SensorId::OrificeDp.index()] = InputFault::Drift;
            m_meas = f64::NAN;
        }
        let (m, fallback) = match self.config.flow_source {
            FlowSource::Orifice => (m_meas, false),
            FlowSource::Observer => (m_obs, false),
            FlowSource::OrificeWithObserverFallback => {
                // the estimate standing in for the flow element: the observer where the
                // machine data give one; else, with a speed-line map and a measured speed,
                // the speed line's flow at the measured ratio less its uncertainty (the
                // conservative side: less flow, less margin); else none (fail-safe)
                let m_line = if q_line.is_finite() && line_unc.is_finite() {
                    self.model
                        .mass_flow_of_map((q_line - line_unc.max(0.0)).max(0.0), p_s, t_s_k)
                } else {
                    f64::NAN
                };
                let m_est = if m_obs.is_finite() { m_obs } else { m_line };
                if m_meas.is_finite() {
                    (m_meas, false)
                } else if matches!(
                    v.fault[SensorId::OrificeDp.index()],
                    InputFault::Frozen | InputFault::Drift
                ) && m_est.is_finite()
                {
                    // a frozen or drifting Δp: the conservative estimate, the lower of the
                    // observer's flow and the transmitter's (a closing machine loses flow that
                    // the frozen value does not show; a transmitter reading high is replaced;
                    // an observer off the other way is capped)
                    let m_frozen = self.model.orifice.mass_flow_kg_s(
                        &self.model.gas,
                        raw.values.get(SensorId::OrificeDp),
                        p_s,
                        t_s_k,
                    );
                    (m_est.min(m_frozen), true)
                } else {
                    (m_est, m_est.is_finite())
                }
            }
        };
        Measurements {
            t_s,
            p_suction_pa: p_s,
            p_discharge_pa: p_d,
            omega_rad_s: omega,
            t_suction_k: t_s_k,
            m_kg_s: m,
            m_measured_kg_s: m_meas,
            m_observer_kg_s: m_obs,
            flow_map: self.model.map_flow(m, p_s, t_s_k),
            pressure_ratio: p_d / p_s,
            recycle_position: recycle,
            throttle_position: throttle,
            thrust_position_m: thrust,
            dp_suction_dt_pa_s: self.d_suction.update(p_s, dt),
            dp_discharge_dt_pa_s: self.d_discharge.update(p_d, dt),
            flow_fallback: fallback,
        }
    }

    /// The output of a cycle in which no law ran (start-up, fail-safe, or a held sample).
    fn passive_output(
        &self,
        commands: ActuatorCommands,
        measurements: Measurements,
        validity: Validity,
    ) -> CycleOutput {
        CycleOutput {
            commands,
            measurements,
            mode: self.mode,
            law: self.law.id(),
            validity,
            law_diagnostic: f64::NAN,
            surge: Detection::None,
            law_event: None,
            law_torque_nm: if matches!(self.mode, Mode::Auto) {
                self.last_law_torque_nm
            } else {
                f64::NAN
            },
            esd_active: false,
        }
    }

    /// Still starting, inputs not yet healthy: command nothing.
    fn init_hold(&mut self, meas: Measurements, validity: Validity) -> CycleOutput {
        self.last = ActuatorCommands::default();
        self.history.push(f64::NAN);
        self.passive_output(self.last, meas, validity)
    }

    fn failsafe(&mut self, meas: Measurements, validity: Validity) -> CycleOutput {
        // recycle valve to its safe opening, thrust to centre, CCV neutral, torque held
        self.mode = Mode::FailSafe;
        self.law_started = false;
        self.reload_restart = false;
        let mut cmd = ActuatorCommands::default();
        if self.model.has_recycle_valve() {
            cmd.set(
                ActuatorId::RecycleValve,
                self.settings.failsafe_recycle_opening,
            );
        }
        if self.model.tip.is_some() {
            cmd.set(ActuatorId::TipClearance, 0.0);
        }
        if self.model.spool.is_some() {
            cmd.set(ActuatorId::CloseCoupledValve, 0.0);
        }
        // the torque held is the one the drive reports delivering while that report is fresh
        // (a link back up during the fail-safe exit hysteresis must not override the drive's
        // own governor with a stale command), else the last command
        // (taken once per fresh report stretch: the drive then follows the held command, and
        // re-tracking its lagging report would make the command chatter)
        // While the drive's report is bound but stale (the link is down: the skid hears nothing
        // from the controller either, and its drive runs on its own governor) the torque is
        // not commanded (NaN: "not available" on CAN, no write on Modbus): when the link comes
        // back, the frames sent before the controller has read the drive's report would
        // otherwise hand the drive a stale command (HIL link_bounce: steps of 400 N·m as the
        // drive left its governor for it, and back).
        let last_torque = self.last.get(ActuatorId::DriveTorque);
        if last_torque.is_finite() {
            self.failsafe_held_torque_nm = last_torque;
        }
        let report_stale = validity.fault[SensorId::DriveTorque.index()] == InputFault::Stale;
        let held = if self.reported_torque_nm.is_finite() && !self.failsafe_torque_latched {
            self.failsafe_torque_latched = true;
            self.reported_torque_nm
        } else if report_stale {
            f64::NAN
        } else if last_torque.is_finite() {
            last_torque
        } else {
            self.failsafe_held_torque_nm
        };
        cmd.set(ActuatorId::DriveTorque, held);
        self.history.push(cmd.get(ActuatorId::DriveTorque));
        self.last = cmd;
        self.passive_output(cmd, meas, validity)
    }

    /// Run one cycle at time `t_s`.
    ///
    /// An emergency-shutdown / drive-trip input ([`SensorId::EsdInput`], supervised like any
    /// input: it counts only while fresh and in range) overrides every mode and law: the
    /// recycle valve is commanded fully open at once, with no rate limit (seed 002 §2.2.2,
    /// the response to ESD events). While it is set the law is held in reset, so when it
    /// clears the law starts bumplessly from the open valve; in manual the station's output
    /// stays open until the operator moves it.
    pub fn cycle(&mut self, t_s: f64, raw: &RawSensors, op: &OperatorInputs) -> CycleOutput {
        let mut out = self.cycle_laws(t_s, raw, op);
        let esd = out.validity.ok(SensorId::EsdInput)
            && raw.values.get(SensorId::EsdInput) >= 0.5
            && self.model.has_recycle_valve();
        if esd {
            out.commands.set(ActuatorId::RecycleValve, 1.0);
            self.last.set(ActuatorId::RecycleValve, 1.0);
            self.law_started = false;
            if self.mode == Mode::Manual {
                self.manual_recycle = 1.0;
            }
            out.esd_active = true;
        }
        out
    }

    /// One cycle without the ESD override (see [`cycle`](Self::cycle)).
    fn cycle_laws(&mut self, t_s: f64, raw: &RawSensors, op: &OperatorInputs) -> CycleOutput {
        // redundant transmitters: each checked on its own, voted into one value
        let voted;
        let mut vote_fault = [None; SensorId::COUNT];
        let raw = if self.settings.vote.any() {
            voted = self.vote.apply(
                t_s,
                raw,
                &self.settings.supervisor,
                &self.settings.vote,
                &mut vote_fault,
            );
            &voted
        } else {
            raw
        };
        let mut validity = self.settings.supervisor.check(raw);
        for (f, v) in validity.fault.iter_mut().zip(vote_fault) {
            if let Some(v) = v {
                *f = v;
            }
        }
        // cross-check: a Δp repeating itself while the pressures move is frozen (a voted Δp:
        // each transmitter has its own check in the vote; the vote itself may hold a value)
        let usable = |id: SensorId| {
            if validity.ok(id) {
                raw.values.get(id)
            } else {
                f64::NAN
            }
        };
        let dp_voted = self.settings.vote.per_sensor[SensorId::OrificeDp.index()].is_some();
        if !dp_voted
            && self.dp_frozen.update(
                t_s,
                usable(SensorId::OrificeDp),
                usable(SensorId::PSuction),
                usable(SensorId::PDischarge),
            )
        {
            validity.fault[SensorId::OrificeDp.index()] = InputFault::Frozen;
        }
        self.reported_torque_nm = if validity.ok(SensorId::DriveTorque) {
            raw.values.get(SensorId::DriveTorque)
        } else {
            f64::NAN
        };
        if !self.reported_torque_nm.is_finite() || self.mode != Mode::FailSafe {
            self.failsafe_torque_latched = false;
        }
        // speed is essential when the controller runs the speed loop or the law reads it
        // (law registry); a recycle-pi skid whose drive keeps its own speed may not bind it
        let speed_needed = self.model.owns_drive
            || self
                .law
                .id()
                .descriptor()
                .sensors
                .contains(&SensorId::ShaftSpeed);
        let essentials_ok = validity.ok(SensorId::PSuction)
            && validity.ok(SensorId::PDischarge)
            && (!speed_needed || validity.ok(SensorId::ShaftSpeed));
        // A cycle without a new pressure/speed sample holds its outputs: observers, filters
        // and integrators take each sample once. (Sender and controller run on their own
        // clocks; without this a late sample would be processed twice, which a law on a fast
        // unstable mode does not survive.) Freshness is still supervised: a sample that stops
        // coming goes stale and the core fails safe as before.
        // A sample is known by its number (RawSensors::sample_seq: the sensor board's publish
        // count), not by its age: ages move with the reader's clock.
        let essentials = crate::vocab::signals::CYCLE_INPUTS;
        let cycle_seq = raw.cycle_seq();
        // The time the plant let pass since the last processed sample: on the senders' clocks
        // where they have them (RawSensors::sample_clock_s), else between this cycle and the
        // last. A controller woken 3.4 ms after a sample taken 1 ms after the last one
        // integrated its observer over 3.4 ms, and the drive-torque law threw the plant into
        // surge (HIL `timing`, CI 2026-11-29). A clock that went back (its link reset) is not
        // used for that one cycle.
        let sender_s = raw.sender_clock_s();
        let sender_dt = sender_s - self.last_sender_s;
        if essentials_ok
            && matches!(self.mode, Mode::Auto | Mode::Manual)
            && ((cycle_seq.is_some() && cycle_seq == self.last_cycle_seq) || sender_dt == 0.0)
        {
            self.history.push(self.last.get(ActuatorId::DriveTorque));
            return self.passive_output(self.last, self.last_meas, validity);
        }
        self.last_cycle_seq = cycle_seq;
        self.last_sender_s = sender_s;
        let dt = if sender_dt > 0.0 {
            sender_dt
        } else if self.last_t_s.is_finite() {
            (t_s - self.last_t_s).max(0.0)
        } else {
            0.0
        };
        self.last_t_s = t_s;
        let meas = self.measurements(t_s, dt, raw, &mut validity);
        self.last_meas = meas;
        self.update_margin_shift(dt);
        let age = essentials
            .iter()
            .map(|s| raw.age_s[s.index()])
            .fold(0.0f64, f64::max);
        self.history.sample_age_s = if age.is_finite() { age } else { 0.0 };
        let law_needs_flow = self.law.id() != LawId::None && self.auto_requested;
        if self.first_t_s.is_nan() {
            self.first_t_s = t_s;
        }
        // A start takes over from the measured recycle valve position (bumpless): while the
        // position is bound but has not arrived yet (it may come in a later frame or poll
        // than the pressures), the start waits for it within the start-up grace. Starting
        // without it began from a closed valve at a plant whose valve stood at 12 % and
        // fired a recycle trip 26 ms later (HIL, 1 run in 2).
        let valve_pending = self.model.has_recycle_valve()
            && self.settings.supervisor.limits[SensorId::RecycleValvePosition.index()].is_some()
            && !validity.ok(SensorId::RecycleValvePosition);
        if self.mode == Mode::Init
            && valve_pending
            && essentials_ok
            && t_s - self.first_t_s < self.settings.startup_grace_s
        {
            return self.init_hold(meas, validity);
        }
        if !essentials_ok || (law_needs_flow && !meas.m_kg_s.is_finite()) {
            if self.mode == Mode::Init && t_s - self.first_t_s < self.settings.startup_grace_s {
                return self.init_hold(meas, validity);
            }
            self.healthy_since_s = f64::NAN;
            if matches!(self.mode, Mode::Auto | Mode::Manual) {
                // transmitter-failure hold: keep the last outputs for a short time
                if self.failing_since_s.is_nan() {
                    self.failing_since_s = t_s;
                }
                if t_s - self.failing_since_s < self.settings.failure_hold_s {
                    self.history.push(self.last.get(ActuatorId::DriveTorque));
                    return self.passive_output(self.last, meas, validity);
                }
            }
            self.failing_since_s = f64::NAN;
            return self.failsafe(meas, validity);
        }
        self.failing_since_s = f64::NAN;
        if self.mode == Mode::FailSafe {
            // hysteresis: stay in fail-safe until the inputs have been healthy for a while
            if self.healthy_since_s.is_nan() {
                self.healthy_since_s = t_s;
            }
            if t_s - self.healthy_since_s < self.settings.failsafe_exit_s {
                // the inputs are back and proving themselves: the recycle valve is held where
                // it is measured, not driven to the fail-safe opening it could not reach while
                // the link was down (a 3-s Modbus outage wrote 100 % onto a valve at 4 %
                // first thing after the resume); the law then takes over from the same
                // position. A valve already at the fail-safe opening stays there.
                let mut out = self.failsafe(meas, validity);
                if self.model.has_recycle_valve() && meas.recycle_position.is_finite() {
                    out.commands.set(
                        ActuatorId::RecycleValve,
                        meas.recycle_position.clamp(0.0, 1.0),
                    );
                    self.last = out.commands;
                }
                return out;
            }
        }
        self.healthy_since_s = f64::NAN;
        let from_failsafe = matches!(self.mode, Mode::FailSafe | Mode::Init);
        self.mode = if self.auto_requested {
            Mode::Auto
        } else {
            Mode::Manual
        };
        if from_failsafe {
            // take over from the torque the drive reports delivering (its own governor may
            // have run meanwhile), else from the torque held in fail-safe
            let actual = if validity.ok(SensorId::DriveTorque) {
                raw.values.get(SensorId::DriveTorque)
            } else {
                f64::NAN
            };
            let from = if actual.is_finite() {
                actual
            } else if self.last.get(ActuatorId::DriveTorque).is_finite() {
                self.last.get(ActuatorId::DriveTorque)
            } else {
                self.failsafe_held_torque_nm
            };
            if from.is_finite() {
                self.speed
                    .track(from, op.speed_setpoint_rad_s, meas.omega_rad_s);
            }
        }
        // the current outputs, with positions measured where the controller did not drive them;
        // every resume (start, fail-safe exit, link restart) takes over from the *measured*
        // valve position, not from the fail-safe command the valve may not have reached
        let mut current = self.last;
        if current.get(ActuatorId::RecycleValve).is_nan()
            || (from_failsafe && meas.recycle_position.is_finite())
        {
            current.set(ActuatorId::RecycleValve, meas.recycle_position);
        }
        if current.get(ActuatorId::Throttle).is_nan() {
            current.set(ActuatorId::Throttle, meas.throttle_position);
        }
        let mut cmd = ActuatorCommands::default();
        let mut extra_torque = 0.0;
        let mut law_torque = f64::NAN;
        let mut diagnostic = f64::NAN;
        let mut law_event = None;
        let law_meas = self.law_measurements(&meas);
        let inputs = LawInputs {
            m: &law_meas,
            op,
            model: &self.model,
            history: &self.history,
        };
        match self.mode {
            Mode::Auto => {
                if !self.law_started {
                    // bumpless: the law's integrators start from the outputs applied now;
                    // its torque is extra torque on top of the speed loop: none from another
                    // law or mode, the running law's own after a reload of its settings (a
                    // drive-torque gain change stepped 16 % of the drive's range)
                    let mut cur = current;
                    let extra = if self.reload_restart && self.last_law_torque_nm.is_finite() {
                        self.last_law_torque_nm
                    } else {
                        0.0
                    };
                    cur.set(ActuatorId::DriveTorque, extra);
                    self.law.start(&inputs, &cur);
                    self.law_started = true;
                    self.reload_restart = false;
                }
                let out = self.law.update(&inputs, dt);
                cmd = out.commands;
                diagnostic = out.diagnostic;
                law_event = out.event;
                let t = cmd.get(ActuatorId::DriveTorque);
                if t.is_finite() {
                    extra_torque = t;
                    law_torque = t;
                }
            }
            Mode::Manual => {
                if self.model.has_recycle_valve() {
                    // bumpless manual: hold the last output until the operator moves the station
                    if self.manual_recycle.is_nan() {
                        self.manual_recycle = current.get(ActuatorId::RecycleValve);
                    }
                    if op.recycle_manual != self.last_manual_input
                        && self.last_manual_input.is_finite()
                    {
                        self.manual_recycle = op.recycle_manual;
                    }
                    // protection stays active in manual: the law (control line, recycle trip)
                    // runs on and its valve opening is a floor under the manual output
                    let mut u = self.manual_recycle;
                    if meas.m_kg_s.is_finite() && self.law.id() != LawId::None {
                        if !self.law_started {
                            self.law.start(&inputs, &current);
                            self.law_started = true;
                        }
                        let out = self.law.update(&inputs, dt);
                        diagnostic = out.diagnostic;
                        law_event = out.event;
                        let floor = out.commands.get(ActuatorId::RecycleValve);
                        if floor.is_finite() && (u.is_nan() || u < floor) {
                            u = floor;
                        }
                    }
                    cmd.set(ActuatorId::RecycleValve, u);
                }
            }
            Mode::Init | Mode::FailSafe | Mode::Shutdown => {}
        }
        self.last_manual_input = op.recycle_manual;
        // the drive's speed loop runs here only when the controller owns the drive; otherwise
        // its own governor keeps speed and no torque is commanded (NaN: not driven)
        let torque = if self.model.owns_drive {
            self.speed
                .update(op.speed_setpoint_rad_s, meas.omega_rad_s, extra_torque, dt)
        } else {
            f64::NAN
        };
        cmd.set(ActuatorId::DriveTorque, torque);
        self.history.push(torque);

        let surge = self.detector.update(t_s, dt, meas.m_kg_s);
        if matches!(surge, Detection::SurgeStarted | Detection::ReversalStarted) {
            self.law.surge_detected();
        }
        self.last = cmd;
        self.last_law_torque_nm = law_torque;
        CycleOutput {
            commands: cmd,
            measurements: meas,
            mode: self.mode,
            law: self.law.id(),
            validity,
            law_diagnostic: diagnostic,
            surge,
            law_event,
            law_torque_nm: law_torque,
            esd_active: false,
        }
    }
}

#[cfg(test)]
mod tests;
