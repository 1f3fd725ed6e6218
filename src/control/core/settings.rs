//! The control core's settings that are not law gains: input supervision, fail-safe timing,
//! the start-up grace, redundant transmitters, and the degraded policy's constants.

use crate::control::model::ControlModel;
use crate::control::supervisor::{InputLimits, Supervisor};
use crate::control::vote::VoteSettings;
use crate::vocab::signals::SensorId;

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
