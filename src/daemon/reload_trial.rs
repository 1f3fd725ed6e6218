//! A reload tried against the live plant for a valve step before it is applied (issue 25,
//! item 1: "step the valve by more than the bumpless limit is refused").
//!
//! The running law and the new one are each run as a *shadow*, off the control thread, on
//! the same live input samples taken from the sensor board over a short window
//! ([`TRIAL_WINDOW_S`]). Both shadows start bumplessly from the measured recycle valve
//! position, so what differs between their recycle valve commands is what the change itself
//! adds. A re-based PI makes no step on the very cycle of the switch (its demand at the last
//! control variable is unchanged by construction); a gain edit steps the valve on the cycles
//! right after, through the proportional term acting on the next change of the control
//! variable. The window covers those cycles. If the two commands part by more than
//! [`BUMPLESS_STEP_LIMIT`] at any sample, the reload is refused with the step, the cycle and
//! both commands in the reason (the `config_rejected` event and the journal), unless the
//! operator overrode it (`antisurge reload --override`).
//!
//! The shadows are fresh controllers, not copies of the running one's state: on the control
//! thread nothing may be cloned or allocated. For the laws that carry their state over on a
//! reload (recycle-pi) that state cancels between the two shadows to first order; for the
//! others a reload restarts them from the applied outputs, which is what the shadows do.

use super::config::{self, Loaded, Problem};
use crate::control::core::ControlCore;
use crate::control::measurements::RawSensors;
use crate::control::model::ControlModel;
use crate::runtime::handoff::{monotonic_ns, SensorBoard};
use crate::vocab::signals::ActuatorId;
use crate::vocab::Mode;
use std::time::Duration;

/// The largest recycle valve command step a reload may cause, fraction of stroke (0.02 = 2 %).
///
/// Derivation. A valve positioner answers a small step with its linear (non-slewing) response,
/// so a step that small is one the valve actually follows in proportion; the bumpless gain-change
/// test (`tests/control/bumpless_gain_change.rs`) holds every law to 1 % of an actuator's range per cycle
/// for gains ×2 and ×½, which a sound edit meets, and this limit allows twice that for the
/// sum over the trial window. On the recycle side, recycle-pi's closing-rate limit is 0.1 of
/// stroke per second (`[controller.recycle_pi.closing] rate_per_s`), so a 2 % closing step is
/// what the law itself would take 0.2 s to make — never a jump; an opening step of 2 % moves
/// the operating point right (safe side) by roughly 2 % of the recycle flow at full opening,
/// within the margin between the control line and the trip line. A step larger than that is
/// not a retune but a disturbance the operator did not ask for.
pub const BUMPLESS_STEP_LIMIT: f64 = 0.02;

/// How long the live inputs are sampled for the trial, s (at least [`TRIAL_MIN_SAMPLES`]
/// control periods): the cycles right after the switch, where a gain edit acts.
pub const TRIAL_WINDOW_S: f64 = 0.2;

/// The fewest samples the trial takes (slow control rates).
pub const TRIAL_MIN_SAMPLES: usize = 20;

/// One live input sample: time since the trial began, s, and the readings with their ages.
#[derive(Debug, Clone, Copy)]
pub struct Sample {
    /// Seconds since the trial began.
    pub t_s: f64,
    /// The readings and their ages at `t_s`.
    pub raw: RawSensors,
}

/// The outcome of a trial.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepTrial {
    /// The largest |new − running| recycle valve command over the window, fraction.
    pub step: f64,
    /// Time into the window of the largest step, s (NaN: none compared).
    pub at_s: f64,
    /// The running law's command there, fraction.
    pub running: f64,
    /// The new law's command there, fraction.
    pub new: f64,
    /// Samples where both shadows ran a law (auto or manual).
    pub compared: usize,
}

/// Sample the sensor board every `period_s` for the trial window (async: the caller's task
/// keeps its other work waiting, no thread is blocked).
pub async fn sample_live(sensors: &SensorBoard, period_s: f64) -> Vec<Sample> {
    let period_s = period_s.clamp(1e-3, 1.0);
    let n = ((TRIAL_WINDOW_S / period_s).ceil() as usize).max(TRIAL_MIN_SAMPLES);
    let mut out = Vec::with_capacity(n);
    let mut tick = tokio::time::interval(Duration::from_secs_f64(period_s));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    // the time origin one period before the first sample (a core's first dt is 0 anyway)
    let t0 = monotonic_ns().saturating_sub((period_s * 1e9) as u64);
    for _ in 0..n {
        tick.tick().await;
        let now = monotonic_ns();
        out.push(Sample {
            t_s: now.saturating_sub(t0) as f64 * 1e-9,
            raw: sensors.raw(now),
        });
    }
    out
}

fn shadow(model: &ControlModel, l: &Loaded) -> Option<ControlCore> {
    let mut settings = l.core;
    // the shadow starts on the first healthy sample (the live controller is already running)
    settings.startup_grace_s = 0.0;
    let mut core = ControlCore::new(
        model.clone(),
        l.controller.clone(),
        settings,
        l.law,
        super::service::initial_torque_nm(l),
    )
    .ok()?;
    core.request_auto(l.config.control.mode == config::StartMode::Auto);
    Some(core)
}

/// Run the running and the new configuration as shadows over `samples` and measure how far
/// apart their recycle valve commands go. `None` when a shadow cannot be built (the caller's
/// other checks refuse such a configuration) or the machine has no recycle valve.
///
/// A pair is started at every sample of the window's first half (at least
/// [`TRIAL_MIN_SAMPLES`]/2 = 10 pairs) and the largest step of all is kept: a pair started on
/// a noisy sample sees the later samples move away from it in either direction, and when that
/// direction asks the valve to close, the closing-rate limit (or the valve at its stop) hides
/// the step a gain edit makes the other way. With four starts, kp ×100 passed the trial in
/// about one run in seven (one in two under a loaded machine); each further start halves the
/// chance that none moves the opening way.
pub fn valve_step(
    model: &ControlModel,
    running: &Loaded,
    new: &Loaded,
    samples: &[Sample],
) -> Option<StepTrial> {
    let n = samples.len();
    let mut worst: Option<StepTrial> = None;
    for k in 0..(n / 2).max(1) {
        let t = valve_step_from(model, running, new, &samples[k..])?;
        if worst.is_none_or(|w| t.step > w.step) {
            worst = Some(t);
        }
    }
    worst
}

fn valve_step_from(
    model: &ControlModel,
    running: &Loaded,
    new: &Loaded,
    samples: &[Sample],
) -> Option<StepTrial> {
    if !model.has_recycle_valve() {
        return None;
    }
    let (mut a, mut b) = (shadow(model, running)?, shadow(model, new)?);
    let (op_a, op_b) = (
        super::service::operator_inputs(running),
        super::service::operator_inputs(new),
    );
    let mut worst = StepTrial {
        step: 0.0,
        at_s: f64::NAN,
        running: f64::NAN,
        new: f64::NAN,
        compared: 0,
    };
    for s in samples {
        let (oa, ob) = (a.cycle(s.t_s, &s.raw, &op_a), b.cycle(s.t_s, &s.raw, &op_b));
        let law_runs = |m: Mode| matches!(m, Mode::Auto | Mode::Manual);
        if !(law_runs(oa.mode) && law_runs(ob.mode)) {
            continue;
        }
        let (ua, ub) = (
            oa.commands.get(ActuatorId::RecycleValve),
            ob.commands.get(ActuatorId::RecycleValve),
        );
        if !(ua.is_finite() && ub.is_finite()) {
            continue;
        }
        worst.compared += 1;
        let d = (ub - ua).abs();
        if d > worst.step || worst.at_s.is_nan() {
            worst = StepTrial {
                step: d,
                at_s: s.t_s,
                running: ua,
                new: ub,
                compared: worst.compared,
            };
        }
    }
    Some(worst)
}

/// The refusal of a trial whose step exceeds [`BUMPLESS_STEP_LIMIT`]; `None` if it does not.
/// The reason names the changed live keys (the first one locates it: file and line).
pub fn refusal(running: &Loaded, new: &Loaded, t: &StepTrial) -> Option<Problem> {
    if t.step <= BUMPLESS_STEP_LIMIT {
        return None;
    }
    let changed: Vec<&str> = running
        .flat
        .keys()
        .chain(new.flat.keys())
        .filter(|k| config::is_live_key(k) && running.flat.get(*k) != new.flat.get(*k))
        .map(String::as_str)
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .collect();
    let key = changed.first().copied().unwrap_or("control.law");
    let mut e = config::locate(
        &new.layers,
        key,
        format!(
            "dry run against the live inputs: the new settings ({}) would step the recycle valve command by {:.1} % of stroke ({:.1} % -> {:.1} %, {:.0} ms after applying), more than the bumpless limit of {:.1} %; nothing was applied, the controller runs on with the running settings",
            if changed.is_empty() { "plant file [controller]".to_string() } else { changed.join(", ") },
            100.0 * t.step,
            100.0 * t.running,
            100.0 * t.new,
            1e3 * t.at_s,
            100.0 * BUMPLESS_STEP_LIMIT
        ),
    );
    e.hint = Some(
        "change gains in smaller steps, or apply it anyway with `antisurge reload --override`"
            .into(),
    );
    Some(Problem::error(e))
}

/// The daemon's answer to the last reload, beside `running-config.json`: what
/// `antisurge reload` (the unit's `ExecReload`) waits for, so that `systemctl reload` exits
/// non-zero when the daemon refused the files.
pub const VERDICT_FILE: &str = "reload-result.json";

/// Present beside the record when the daemon reloads: skip the valve-step dry run for that
/// one reload (the daemon removes it). Written by `antisurge reload --override`.
pub const OVERRIDE_FILE: &str = "reload-override";

/// What came of a reload.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Verdict {
    /// Reloads answered since the daemon started (0: written at start, no reload yet).
    pub seq: u64,
    /// The daemon's process id.
    pub pid: u32,
    /// `started`, `applied`, `unchanged` or `refused`.
    pub outcome: String,
    /// The reason (refused), the changed keys (applied), or empty.
    pub message: String,
    /// The operator overrode the valve-step dry run for this reload.
    pub overridden: bool,
}

impl Verdict {
    /// Whether `systemctl reload` should succeed on it.
    pub fn ok(&self) -> bool {
        self.outcome != "refused"
    }

    /// Write to `path` (a temporary file renamed over it).
    pub fn save(&self, path: &std::path::Path) -> std::io::Result<()> {
        let tmp = path.with_extension(format!("json.{}.tmp", std::process::id()));
        let text = serde_json::to_string(self).map_err(std::io::Error::other)? + "\n";
        std::fs::write(&tmp, text)?;
        std::fs::rename(&tmp, path)
    }

    /// Read `path`; `None` if absent or unreadable.
    pub fn load(path: &std::path::Path) -> Option<Verdict> {
        serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()
    }
}
