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
use super::supervisor::{InputFault, InputLimits, Supervisor, Validity};
use super::surge_control_line::SurgeControlLine;
use super::vote::{Vote, VoteSettings};
use crate::surge::{Detection, SurgeDetector};
use crate::vocab::signals::{ActuatorCommands, ActuatorId, SensorId};
use crate::vocab::Mode;

/// Settings of the control core that are not law gains.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoreSettings {
    /// Recycle valve opening commanded in fail-safe, fraction.
    pub failsafe_recycle_opening: f64,
    /// Input limits.
    pub supervisor: Supervisor,
    /// At start, how long to wait for healthy inputs before commanding the fail-safe state,
    /// s. Meanwhile nothing is commanded, so a controller (re)start on a running machine
    /// does not move its actuators, and the first law cycle takes over from the measured
    /// positions.
    pub startup_grace_s: f64,
    /// Transmitter-failure hold: when an essential input fails in automatic or manual mode,
    /// the last outputs are kept this long before the fail-safe state, s. A blip shorter
    /// than this (a late Modbus answer, a dropped frame) does not slam the valve open; a loss
    /// longer than freshness timeout + hold enters fail-safe.
    pub failure_hold_s: f64,
    /// Hysteresis on leaving fail-safe: inputs must be healthy this long without a break
    /// before the controller resumes, s (no auto ↔ fail-safe chatter on a marginal link).
    pub failsafe_exit_s: f64,
    /// Redundant transmitters: which measurements are voted, and how
    /// ([`crate::control::vote`]); the signal map's `[vote.<sensor>]`.
    pub vote: VoteSettings,
}

impl CoreSettings {
    /// Defaults derived from the machine model: generous plausibility ranges around the
    /// machine's operating region and a 50 ms freshness timeout.
    pub fn defaults_for(model: &ControlModel) -> CoreSettings {
        let timeout_s = 0.05;
        // a drive of unknown nominal speed (vendor data, drive not the controller's): no bound
        let w_max = match 2.0 * model.drive.nominal_speed_rad_s {
            w if w.is_finite() => w,
            _ => f64::MAX,
        };
        let p_hi = match (model.recycle, model.plenum_duct, model.tip, model.spool) {
            (Some(r), ..) => 3.0 * r.downstream_pressure_pa,
            (_, Some(p), ..) => 5.0 * p.ambient_pressure_pa,
            (_, _, Some(t), _) => 5.0 * t.ambient_pressure_pa,
            (_, _, _, Some(s)) => 5.0 * s.ambient_pressure_pa,
            _ => model
                .design_suction_pressure_pa
                .map_or(1e7, |p| 5.0 * p * model.design_pressure_ratio),
        };
        let lim = |min: f64, max: f64| {
            Some(InputLimits {
                min,
                max,
                timeout_s,
            })
        };
        let mut limits = [None; SensorId::COUNT];
        limits[SensorId::PSuction.index()] = lim(1e3, p_hi);
        limits[SensorId::PDischarge.index()] = lim(1e3, p_hi);
        limits[SensorId::ShaftSpeed.index()] = lim(0.0, w_max);
        limits[SensorId::OrificeDp.index()] = lim(-1e5, 1e6);
        limits[SensorId::TSuction.index()] = lim(200.0, 500.0);
        limits[SensorId::RecycleValvePosition.index()] = lim(-0.05, 1.05);
        limits[SensorId::ThrottlePosition.index()] = lim(-0.05, 1.05);
        limits[SensorId::ThrustPosition.index()] = lim(-5e-3, 5e-3);
        let t_max = match 1.5 * model.drive.rated_torque_nm.abs() {
            t if t > 0.0 => t,
            _ => f64::MAX, // a drive the controller does not own: its torque is only read
        };
        limits[SensorId::DriveTorque.index()] = lim(-t_max, t_max);
        CoreSettings {
            failsafe_recycle_opening: match model.recycle_valve.map(|v| v.fail_position) {
                Some(crate::machine::FailPosition::Closed) => 0.0,
                Some(_) => 1.0,
                None => 0.0,
            },
            supervisor: Supervisor { limits },
            startup_grace_s: 1.0,
            failure_hold_s: DEFAULT_FAILURE_HOLD_S,
            failsafe_exit_s: DEFAULT_FAILSAFE_EXIT_S,
            vote: VoteSettings::default(),
        }
    }

    /// Freshness defaults for inputs that arrive by polling every `poll_period_s` (Modbus):
    /// every default timeout becomes at least [`POLL_PERIODS_PER_TIMEOUT`] poll periods, so a
    /// device answering at the poll rate is never stale between two answers.
    pub fn follow_poll_period(&mut self, poll_period_s: f64) {
        self.supervisor
            .follow_poll_period(poll_period_s, POLL_PERIODS_PER_TIMEOUT);
    }

    /// [`follow_poll_period`](Self::follow_poll_period) for the inputs a polled bus delivers
    /// (the daemon: the signal map's Modbus sensors at `[bus.modbus] poll_rate_hz`).
    pub fn follow_poll_period_of(&mut self, ids: &[SensorId], poll_period_s: f64) {
        self.supervisor
            .follow_poll_period_of(ids, poll_period_s, POLL_PERIODS_PER_TIMEOUT);
    }

    /// Bind an on/off contact ([`SensorId::is_contact`], e.g. the ESD / drive-trip input):
    /// supervised like any input, 0 or 1, fresh within the default 50 ms (limits already set
    /// are kept). An unbound contact is ignored, so a skid that does not wire it is not
    /// tripped by a value nobody reads. The daemon binds the contacts its signal map names;
    /// the benchmark binds the ESD contact in its "trip contact wired" runs.
    pub fn bind_contact(&mut self, id: SensorId) {
        if id.is_contact() {
            self.supervisor.limits[id.index()].get_or_insert(InputLimits {
                min: 0.0,
                max: 1.0,
                timeout_s: 0.05,
            });
        }
    }
}

/// Default transmitter-failure hold, s: longer than a 100 ms blip plus a 50 Hz poll period,
/// short against the ≈ 1 s a closing throttle takes to move a machine onto its surge line.
pub const DEFAULT_FAILURE_HOLD_S: f64 = 0.25;
/// Default healthy time before leaving fail-safe, s.
pub const DEFAULT_FAILSAFE_EXIT_S: f64 = 0.5;
/// Default freshness timeout in poll periods of a polled bus.
pub const POLL_PERIODS_PER_TIMEOUT: f64 = 3.0;

/// Control-line shift of the slow-link policy, fraction of the control-line flow: while a
/// field link is slow but alive (`field_link_slow`), each input arrives up to one achieved
/// poll period late, and the operating point moves meanwhile. 5 %: a closure that takes a
/// machine from its control line (10 % margin) to its surge line in ≈ 1 s moves it 5 % of
/// flow in half a second, the age of an input at 2 Hz polling (a device 0.5 s late is no
/// longer "slow": its inputs go stale and the failure hold takes over).
pub const SLOW_LINK_MARGIN: f64 = 0.05;
/// How fast a degraded margin shift moves in and out, fraction of flow per second. A step
/// would read to a law's trip as a sudden approach of the surge line and open the valve;
/// 1 %/s is a third of the slowest approach the recycle trip predicts a crossing from (its
/// 5 % gap between control and trip line over a 1.5-s horizon), so the shift alone never
/// trips it. 5 % takes 5 s.
pub const MARGIN_SHIFT_RATE_PER_S: f64 = 0.01;

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
mod tests {
    use super::*;

    use crate::scenario::Scenario;
    use crate::sim::case::PlantCase;
    use crate::sim::PlantRun;
    use std::path::Path;

    fn kvangardsnes() -> PlantCase {
        let p = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("config/plants/kvangardsnes2009_recycle.toml");
        PlantCase::load(&p).expect("plant")
    }

    fn hold() -> Scenario {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/scenarios/hold.toml");
        Scenario::load(&p).expect("scenario")
    }

    fn core_for(desc: &PlantCase, grace_s: f64) -> ControlCore {
        let model = crate::sim::control_model(desc);
        let mut settings = CoreSettings::defaults_for(&model);
        settings.startup_grace_s = grace_s;
        // these tests look at single cycles: no failure hold, no exit hysteresis
        settings.failure_hold_s = 0.0;
        settings.failsafe_exit_s = 0.0;
        let config = model.controller.clone();
        ControlCore::new(model, config, settings, LawId::RecyclePi, 0.0).expect("core")
    }

    fn op(core: &ControlCore) -> OperatorInputs {
        OperatorInputs {
            speed_setpoint_rad_s: core.model().drive.nominal_speed_rad_s,
            throttle_demand: f64::NAN,
            flow_setpoint_kg_s: f64::NAN,
            recycle_manual: f64::NAN,
        }
    }

    /// A core on kvangardsnes (start-up grace `grace_s`), the plant's healthy initial sample
    /// and the operator inputs.
    fn started(grace_s: f64) -> (ControlCore, RawSensors, OperatorInputs) {
        let desc = kvangardsnes();
        let sc = hold();
        let mut run = PlantRun::new(&desc, &sc).expect("run");
        let core = core_for(&desc, grace_s);
        let op = op(&core);
        let (_, raw) = run.sense(0.0);
        (core, raw, op)
    }

    /// Vendor data only (no map, no model, the drive on its own governor): recycle-pi runs on
    /// pressures, Δp and valve position without a speed reading and never commands torque.
    #[test]
    fn a_drive_the_controller_does_not_own_gets_no_torque_and_speed_is_not_essential() {
        let desc = kvangardsnes();
        let mut m = desc.machine();
        m.family = None;
        m.map = None;
        m.recycle = None;
        m.owns_drive_speed_loop = false;
        let model = ControlModel::from_machine(&m, desc.controller.clone());
        let mut settings = CoreSettings::defaults_for(&model);
        settings.startup_grace_s = 0.0;
        let config = model.controller.clone();
        let mut core = ControlCore::new(model, config, settings, LawId::RecyclePi, 0.0)
            .expect("recycle-pi on vendor data");
        let sc = hold();
        let mut run = PlantRun::new(&desc, &sc).expect("run");
        let (_, mut raw) = run.sense(0.0);
        raw.values.set(SensorId::ShaftSpeed, f64::NAN);
        raw.age_s[SensorId::ShaftSpeed.index()] = f64::INFINITY;
        let op = op(&core);
        for k in 0..20 {
            let t = k as f64 * 1e-3;
            for a in raw.age_s.iter_mut().filter(|a| a.is_finite()) {
                *a = 0.0;
            }
            let out = core.cycle(t, &raw, &op);
            assert_eq!(out.mode, Mode::Auto, "cycle {k}");
            assert!(
                out.commands.get(ActuatorId::DriveTorque).is_nan(),
                "cycle {k}"
            );
            assert!(out.commands.get(ActuatorId::RecycleValve).is_finite());
            let (_, next) = run.sense(t);
            raw.values = next.values;
            raw.sample_seq = next.sample_seq;
            raw.values.set(SensorId::ShaftSpeed, f64::NAN);
        }
        // the plant-file machine owns its drive: the same sample without speed fails safe
        let mut owned = core_for(&desc, 0.0);
        let out = owned.cycle(0.0, &raw, &op);
        assert_eq!(out.mode, Mode::FailSafe);
    }

    /// A core whose ESD input is bound (supervised 0..1, 50 ms like the other inputs).
    fn with_esd(mut core: ControlCore) -> ControlCore {
        let mut s = *core.settings();
        s.supervisor.limits[SensorId::EsdInput.index()] = Some(InputLimits {
            min: 0.0,
            max: 1.0,
            timeout_s: 0.05,
        });
        core.set_settings(s);
        core
    }

    #[test]
    fn the_esd_input_opens_the_valve_at_once_and_the_law_resumes_from_open() {
        let (core, mut raw, op) = started(0.0);
        let mut core = with_esd(core);
        let mut t = 0.0;
        let mut cycle = |core: &mut ControlCore, raw: &RawSensors| {
            t += 1e-3;
            core.cycle(t, raw, &op)
        };
        raw.values.set(SensorId::EsdInput, 0.0);
        let mut u0 = f64::NAN;
        for _ in 0..50 {
            let out = cycle(&mut core, &raw);
            assert_eq!(out.mode, Mode::Auto);
            assert!(!out.esd_active);
            u0 = out.commands.get(ActuatorId::RecycleValve);
        }
        assert!(u0 < 0.5, "the law holds the valve at {u0}");
        // set: fully open in the same cycle (no rate limit), held while set
        raw.values.set(SensorId::EsdInput, 1.0);
        for k in 0..20 {
            let out = cycle(&mut core, &raw);
            assert!(out.esd_active, "cycle {k}");
            assert_eq!(out.commands.get(ActuatorId::RecycleValve), 1.0, "cycle {k}");
            assert_eq!(out.mode, Mode::Auto, "protection, not a fault");
        }
        // a stale contact is not believed (same freshness rule as every input)
        raw.age_s[SensorId::EsdInput.index()] = 0.2;
        let out = cycle(&mut core, &raw);
        assert!(!out.esd_active);
        assert_eq!(
            out.validity.fault[SensorId::EsdInput.index()],
            InputFault::Stale
        );
        raw.age_s[SensorId::EsdInput.index()] = 0.0;
        // cleared: the law starts from the open valve and closes at its own rate
        raw.values.set(SensorId::EsdInput, 0.0);
        let out = cycle(&mut core, &raw);
        assert!(!out.esd_active);
        let u = out.commands.get(ActuatorId::RecycleValve);
        assert!(
            u > 0.9 && u <= 1.0,
            "bumpless from open, got {u} (law held {u0})"
        );
    }

    #[test]
    fn the_esd_input_acts_in_init_and_manual_and_an_unbound_one_is_ignored() {
        let desc = kvangardsnes();
        let mut core = with_esd(core_for(&desc, 1.0));
        let op = op(&core);
        let mut raw = RawSensors::missing();
        raw.values.set(SensorId::EsdInput, 1.0);
        raw.age_s[SensorId::EsdInput.index()] = 0.0;
        let out = core.cycle(0.0, &raw, &op);
        assert_eq!(out.mode, Mode::Init);
        assert!(out.esd_active);
        assert_eq!(out.commands.get(ActuatorId::RecycleValve), 1.0);
        assert!(out.commands.get(ActuatorId::DriveTorque).is_nan());

        // manual: the station output is open when the contact clears
        let (core, mut raw, op) = started(0.0);
        let mut core = with_esd(core);
        core.request_auto(false);
        raw.values.set(SensorId::EsdInput, 0.0);
        let mut t = 0.0;
        for _ in 0..10 {
            t += 1e-3;
            assert_eq!(core.cycle(t, &raw, &op).mode, Mode::Manual);
        }
        raw.values.set(SensorId::EsdInput, 1.0);
        t += 1e-3;
        assert_eq!(
            core.cycle(t, &raw, &op)
                .commands
                .get(ActuatorId::RecycleValve),
            1.0
        );
        raw.values.set(SensorId::EsdInput, 0.0);
        t += 1e-3;
        let out = core.cycle(t, &raw, &op);
        assert!(!out.esd_active);
        assert_eq!(out.commands.get(ActuatorId::RecycleValve), 1.0);

        // not bound (no limits): a 1 on the input changes nothing
        let (mut core, mut raw, op) = started(0.0);
        raw.values.set(SensorId::EsdInput, 1.0);
        let out = core.cycle(1e-3, &raw, &op);
        assert!(!out.esd_active);
        assert!(out.commands.get(ActuatorId::RecycleValve) < 0.5);
    }

    #[test]
    fn no_inputs_at_start_commands_nothing_then_fail_safe_after_the_grace() {
        let desc = kvangardsnes();
        let mut core = core_for(&desc, 0.5);
        let op = op(&core);
        for k in 0..500 {
            let out = core.cycle(k as f64 * 1e-3, &RawSensors::missing(), &op);
            assert_eq!(out.mode, Mode::Init, "cycle {k}");
            for id in ActuatorId::ALL {
                assert!(out.commands.get(id).is_nan(), "{id:?} commanded in init");
            }
        }
        let out = core.cycle(0.5, &RawSensors::missing(), &op);
        assert_eq!(out.mode, Mode::FailSafe);
        assert_eq!(out.commands.get(ActuatorId::RecycleValve), 1.0);
    }

    #[test]
    fn a_start_waits_for_the_valve_position_that_comes_in_a_later_frame() {
        // pressures and flow in one frame, the valve position in another arriving 10 ms
        // later: the law starts from the measured position, not from a closed valve
        let (mut core, raw, op) = started(1.0);
        let measured = raw.values.get(SensorId::RecycleValvePosition);
        assert!(measured > 0.01, "{measured}");
        let mut partial = raw;
        partial.values.set(SensorId::RecycleValvePosition, f64::NAN);
        partial.age_s[SensorId::RecycleValvePosition.index()] = f64::INFINITY;
        for k in 0..10 {
            let out = core.cycle(k as f64 * 1e-3, &partial, &op);
            assert_eq!(out.mode, Mode::Init, "cycle {k}");
            assert!(out.commands.get(ActuatorId::RecycleValve).is_nan());
        }
        let out = core.cycle(0.010, &raw, &op);
        assert_eq!(out.mode, Mode::Auto);
        let u = out.commands.get(ActuatorId::RecycleValve);
        assert!(
            (u - measured).abs() < 0.005,
            "first command {u}, valve at {measured}"
        );

        // a position that never comes does not keep the controller from starting: after
        // the grace it runs (from the last applied output) like any start without feedback
        let (mut core, _, _) = started(0.05);
        let mut k = 0;
        let mode = loop {
            let out = core.cycle(k as f64 * 1e-3, &partial, &op);
            if out.mode != Mode::Init || k > 100 {
                break out.mode;
            }
            k += 1;
        };
        assert_eq!(mode, Mode::Auto, "started after {k} ms");
        assert!((50..=52).contains(&k), "started after {k} ms, grace 50 ms");
    }

    #[test]
    fn first_healthy_cycle_takes_over_from_the_measured_valve_position() {
        // a controller (re)start on a running machine, inputs arriving after 30 ms: the law
        // starts from where the valve is, not from the fail-safe opening
        let (mut core, raw, op) = started(1.0);
        let measured = raw.values.get(SensorId::RecycleValvePosition);
        assert!(measured.is_finite() && measured < 0.5, "{measured}");
        for k in 0..30 {
            let out = core.cycle(k as f64 * 1e-3, &RawSensors::missing(), &op);
            assert_eq!(out.mode, Mode::Init);
        }
        let out = core.cycle(0.030, &raw, &op);
        assert_eq!(out.mode, Mode::Auto);
        let u = out.commands.get(ActuatorId::RecycleValve);
        assert!(
            (u - measured).abs() < 0.005,
            "first command {u}, valve at {measured}"
        );

        // with no grace, the same start goes fail-safe first (commanding 100 %), and the law
        // still resumes from the measured position, not from the fail-safe command
        let (mut eager, _, _) = started(0.0);
        let fs = eager.cycle(0.0, &RawSensors::missing(), &op);
        assert_eq!(fs.mode, Mode::FailSafe);
        assert_eq!(fs.commands.get(ActuatorId::RecycleValve), 1.0);
        let u = eager
            .cycle(0.001, &raw, &op)
            .commands
            .get(ActuatorId::RecycleValve);
        assert!(
            (u - measured).abs() < 0.005,
            "resumed at {u}, valve at {measured}"
        );
    }

    /// A core with the default supervision following a 50 Hz poll, and a function giving the
    /// raw sample at `t` with its poll age (arrivals every 20 ms), late by `late_s`.
    fn polled() -> (ControlCore, RawSensors, OperatorInputs) {
        let (mut core, raw, op) = started(1.0);
        let model = core.model().clone();
        let mut settings = CoreSettings::defaults_for(&model);
        settings.follow_poll_period(0.02);
        core.set_settings(settings);
        (core, raw, op)
    }

    /// `raw` read at `t_s`, `age_s` after it was sampled: its sample number counts the
    /// microseconds of its sampling time (one number per sample, as the sensor board's).
    fn aged(raw: &RawSensors, t_s: f64, age_s: f64) -> RawSensors {
        let mut r = *raw;
        r.age_s = [age_s; SensorId::COUNT];
        r.sample_seq = [((t_s - age_s) * 1e6).round() as u64 + 1; SensorId::COUNT];
        r
    }

    #[test]
    fn freshness_follows_the_poll_period() {
        let (core, _, _) = polled();
        let lim = core.settings().supervisor.limits[SensorId::PSuction.index()].unwrap();
        assert!((lim.timeout_s - 0.06).abs() < 1e-12, "{}", lim.timeout_s);
    }

    #[test]
    fn blips_of_100_ms_every_second_do_not_enter_fail_safe() {
        // 50 Hz poll; from t = 1 s, for 10 s, every second the answers stop for 100 ms
        let (mut core, raw, op) = polled();
        let dt = 1e-3;
        let mut last_arrival = 0.0;
        let mut stale_cycles = 0;
        for k in 0..12_000 {
            let t = k as f64 * dt;
            let in_blip = (1.0..11.0).contains(&t) && (t - t.floor()) < 0.1;
            let due = (t / 0.02).floor() * 0.02;
            if !in_blip && due > last_arrival {
                last_arrival = due;
            }
            let out = core.cycle(t, &aged(&raw, t, t - last_arrival), &op);
            assert_ne!(out.mode, Mode::FailSafe, "fail-safe at {t:.3} s");
            if !out.validity.ok(SensorId::PSuction) {
                stale_cycles += 1;
            }
        }
        // the blips were seen (inputs stale), and held through
        assert!(stale_cycles > 300, "{stale_cycles}");
    }

    #[test]
    fn a_loss_longer_than_the_hold_enters_fail_safe_in_time_and_leaves_with_hysteresis() {
        let (mut core, raw, op) = polled();
        let s = *core.settings();
        let timeout = s.supervisor.limits[SensorId::PSuction.index()]
            .unwrap()
            .timeout_s;
        let dt = 1e-3;
        for k in 0..1000 {
            let t = k as f64 * dt;
            assert_eq!(core.cycle(t, &aged(&raw, t, 0.0), &op).mode, Mode::Auto);
        }
        // answers stop at t = 1 s
        let mut entered = None;
        for k in 1000..2000 {
            let t = k as f64 * dt;
            let out = core.cycle(t, &aged(&raw, t, t - 0.999), &op);
            if out.mode == Mode::FailSafe && entered.is_none() {
                entered = Some(t);
            }
        }
        let entered = entered.expect("never entered fail-safe");
        let due = 0.999 + timeout + s.failure_hold_s;
        assert!(
            entered <= due + 2.0 * dt && entered >= due - 2.0 * dt,
            "fail-safe at {entered}, due at {due}"
        );
        // back: healthy for less than the exit time keeps fail-safe, then auto
        let mut resumed = None;
        for k in 2000..3000 {
            let t = k as f64 * dt;
            let out = core.cycle(t, &aged(&raw, t, 0.0), &op);
            if out.mode == Mode::Auto && resumed.is_none() {
                resumed = Some(t);
            }
        }
        let resumed = resumed.expect("never resumed");
        assert!(
            (resumed - (2.0 + s.failsafe_exit_s)).abs() < 2.0 * dt,
            "resumed at {resumed}"
        );
    }

    /// [`started`], one cycle run in auto: with the torque it commands, N·m.
    fn started_holding_torque() -> (ControlCore, RawSensors, OperatorInputs, f64) {
        let (mut core, raw, op) = started(1.0);
        let held = core
            .cycle(0.0, &raw, &op)
            .commands
            .get(ActuatorId::DriveTorque);
        assert!(held.is_finite());
        (core, raw, op, held)
    }

    #[test]
    fn resume_after_fail_safe_takes_over_from_the_reported_drive_torque() {
        // the drive ran on its own governor during the fail-safe and now delivers 300 N·m
        // more than the controller held: the speed loop restarts from what the drive reports
        let (mut core, raw, op, held) = started_holding_torque();
        for k in 1..=100 {
            let out = core.cycle(k as f64 * 1e-3, &RawSensors::missing(), &op);
            assert_eq!(out.mode, Mode::FailSafe);
            assert_eq!(out.commands.get(ActuatorId::DriveTorque), held);
        }
        let mut back = raw;
        back.values.set(SensorId::DriveTorque, held + 300.0);
        let out = core.cycle(0.101, &back, &op);
        assert_eq!(out.mode, Mode::Auto);
        let t = out.commands.get(ActuatorId::DriveTorque);
        assert!(
            (t - (held + 300.0)).abs() < 5.0,
            "resumed at {t}, drive at {}",
            held + 300.0
        );

        // without the drive's report, it resumes from the held torque
        let (mut core, _, _) = started(1.0);
        core.cycle(0.0, &raw, &op);
        core.cycle(0.001, &RawSensors::missing(), &op);
        let mut blind = raw;
        blind.values.set(SensorId::DriveTorque, f64::NAN);
        let t = core
            .cycle(0.002, &blind, &op)
            .commands
            .get(ActuatorId::DriveTorque);
        assert!((t - held).abs() < 5.0, "resumed at {t}, held {held}");
    }

    #[test]
    fn with_the_link_down_fail_safe_leaves_the_torque_to_the_drive_and_resumes_from_its_report() {
        // a link down: every reading stale (the last values kept, aged past their timeouts)
        let (mut core, raw, op, held) = started_holding_torque();
        for k in 1..=200 {
            let out = core.cycle(
                k as f64 * 1e-3,
                &aged(&raw, k as f64 * 1e-3, k as f64 * 1e-3),
                &op,
            );
            if out.mode == Mode::FailSafe {
                // not commanded: the drive keeps its own governor, and no stale command
                // reaches it in the first frames after the link is back
                assert!(
                    out.commands.get(ActuatorId::DriveTorque).is_nan(),
                    "torque {} commanded in fail-safe with the drive's report stale",
                    out.commands.get(ActuatorId::DriveTorque)
                );
            }
        }
        // the link is back, the drive delivering 400 N·m more on its governor: fail-safe
        // holds that, and the resume takes over from it
        let mut back = raw;
        back.values.set(SensorId::DriveTorque, held + 400.0);
        let mut first = None;
        for k in 201..=1500 {
            let out = core.cycle(k as f64 * 1e-3, &back, &op);
            let t = out.commands.get(ActuatorId::DriveTorque);
            first.get_or_insert(t);
            assert!(
                (t - (held + 400.0)).abs() < 5.0,
                "torque {t} at {} s ({:?}), the drive at {}",
                k as f64 * 1e-3,
                out.mode,
                held + 400.0
            );
        }
        assert!(first.is_some());
        // a drive that does not report torque (its reading not available): fail-safe holds
        // the last command, as before
        let (mut core, raw, op) = started(1.0);
        core.cycle(0.0, &raw, &op);
        let out = core.cycle(0.001, &RawSensors::missing(), &op);
        assert_eq!(out.mode, Mode::FailSafe);
        assert_eq!(out.commands.get(ActuatorId::DriveTorque), held);
    }

    #[test]
    fn a_repeated_sample_holds_the_outputs_and_is_processed_once() {
        // the controller's clock runs ahead of the sender's: the second cycle sees the same
        // sample (arrival time unchanged, age one period older) and must hold, not re-run the
        // observer and the law on it
        let (mut core, raw, op) = started(1.0);
        let first = core.cycle(0.0, &raw, &op);
        assert_eq!(first.mode, Mode::Auto);
        let mut again = raw;
        again.age_s = [0.001; SensorId::COUNT];
        let held = core.cycle(0.001, &again, &op);
        // (NaN fields: compare the printed values)
        assert_eq!(
            format!("{:?}", held.commands),
            format!("{:?}", first.commands)
        );
        assert_eq!(
            format!("{:?}", held.measurements),
            format!("{:?}", first.measurements)
        );
        assert!(held.law_diagnostic.is_nan(), "the law did not run");
        // a new sample runs the law, with dt over both periods
        let mut next = raw;
        next.sample_seq = raw.sample_seq.map(|n| n + 1);
        next.values.set(
            SensorId::PDischarge,
            raw.values.get(SensorId::PDischarge) + 50.0,
        );
        let out = core.cycle(0.002, &next, &op);
        assert!(out.law_diagnostic.is_finite());
        assert!((out.measurements.t_s - 0.002).abs() < 1e-12);
        // the number decides, not the age: a new sample whose age puts it at the last one's
        // time (two frames handed over in one batch) runs the law; the last one again holds
        let mut batched = next;
        batched.sample_seq = next.sample_seq.map(|n| n + 1);
        batched.age_s = [0.001; SensorId::COUNT];
        assert!(core.cycle(0.003, &batched, &op).law_diagnostic.is_finite());
        let mut late = batched;
        late.age_s = [0.002; SensorId::COUNT];
        assert!(core.cycle(0.004, &late, &op).law_diagnostic.is_nan());
        // a sample that stops coming still goes stale and fails safe
        let mut stale = batched;
        stale.age_s = [0.2; SensorId::COUNT];
        assert_eq!(core.cycle(0.2, &stale, &op).mode, Mode::FailSafe);
    }

    /// Redundant Δp transmitters: a vote of three feeds the core like one transmitter; two
    /// of them failing leave a hold-last vote (no fail-safe), and the degraded policy widens
    /// the control line at 1 %/s up to 5 %, acting on the law's flow only; back to three,
    /// the shift goes out at the same rate. A slow link asks for the same 5 %.
    #[test]
    fn a_vote_feeds_the_core_and_a_degraded_vote_widens_the_control_line_at_its_rate() {
        use crate::control::vote::{VoteLimits, VoteRule};
        let (mut core, raw, op) = started(1.0);
        let mut s = *core.settings();
        s.vote.per_sensor[SensorId::OrificeDp.index()] = Some(VoteLimits::defaults(3));
        core.set_settings(s);
        let dp = raw.values.get(SensorId::OrificeDp);
        let pd = raw.values.get(SensorId::PDischarge);
        let sample = |k: usize, b: f64, c: f64| {
            let mut r = raw;
            r.values.set(SensorId::PDischarge, pd + (k % 2) as f64);
            r.sample_seq = raw.sample_seq.map(|n| n + k as u64);
            r.spare.set(SensorId::OrificeDp, 1, b, 0.0);
            r.spare.set(SensorId::OrificeDp, 2, c, 0.0);
            r
        };
        let first = core.cycle(0.0, &sample(0, dp * 1.2, dp * 1.001), &op);
        assert_eq!(first.mode, Mode::Auto);
        let v = *core.vote().of(SensorId::OrificeDp).expect("voted");
        assert_eq!(
            (v.rule, v.valid, v.value),
            (VoteRule::Median, 3, dp * 1.001)
        );
        assert_eq!(core.margin_shift().now, 0.0);
        let dt = 1e-3;
        let mut t = 0.0;
        for k in 1..=7000 {
            t = k as f64 * dt;
            let out = core.cycle(t, &sample(k, f64::NAN, f64::NAN), &op);
            assert_eq!(out.mode, Mode::Auto, "{t}");
            assert!(out.measurements.m_kg_s.is_finite());
            if k == 1000 {
                let sh = core.margin_shift().now;
                assert!((sh - 0.01).abs() < 2e-3, "{sh} after 1 s");
            }
        }
        let v = *core.vote().of(SensorId::OrificeDp).expect("voted");
        assert_eq!((v.rule, v.valid, v.degraded), (VoteRule::HoldLast, 1, true));
        let sh = core.margin_shift();
        assert!((sh.now - 0.05).abs() < 1e-9 && sh.vote == 0.05, "{sh:?}");
        // the law's flow, not the measured one
        let m = core.last_meas;
        let law = core.law_measurements(&m);
        assert!((law.flow_map * 1.05 - m.flow_map).abs() < 1e-9 * m.flow_map.abs());
        // three again (live transmitters: their readings move): the shift goes out at 1 %/s
        for k in 1..=2000 {
            let wobble = 1.0 + 1e-4 * (k % 7) as f64;
            core.cycle(t + k as f64 * dt, &sample(k, dp * wobble, dp / wobble), &op);
        }
        let sh = core.margin_shift();
        assert!(
            sh.target == 0.0 && (sh.now - 0.03).abs() < 2e-3,
            "{sh:?} {:?}",
            core.vote().of(SensorId::OrificeDp)
        );
        // a slow link asks for the slow-link margin
        core.set_link_slow(true);
        core.cycle(t + 2.001, &sample(1, dp, dp), &op);
        assert_eq!(core.margin_shift().target, SLOW_LINK_MARGIN);
    }
}
