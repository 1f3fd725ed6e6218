//! Actuator feedback supervision: does each actuator do what it was told?
//!
//! A device that refuses a write, a second master overwriting a setpoint or a stuck valve
//! all look normal on the wire; only the feedback catches them. For each supervised
//! actuator the commanded value is compared with its feedback sensor (recycle valve ↔
//! valve position, throttle ↔ throttle position, tip clearance ↔ thrust position, drive
//! torque ↔ delivered torque). A difference beyond `tolerance` (SI units of the actuator)
//! that lasts `time_ms` is the industry's valve feedback fault
//! ([`FaultCategory::ActuatorFeedbackMismatch`](crate::vocab::faults::FaultCategory)).
//! An actuator that is still travelling towards its command follows it: each time the
//! difference has shrunk by another `tolerance` the time starts again, so a slow-stroking
//! valve after a large step is no fault, while a stuck one (or one moving the wrong way) is
//! found `time_ms` after it stopped making progress. (The foreign Modbus skid's 2-s valve
//! took longer than its map's 500 ms to follow a 0.2 trip step when the machine was loaded,
//! and raised the fault on a healthy valve.)
//!
//! Where the machine file gives the valve's actuator (stroke time, positioner lag), the
//! feedback is compared with where that actuator *would* be: the command run through the
//! valve's own positioner model ([`ValveSpec::positioner_rate`], the plant's formula), so a
//! valve following a moving command within its stroke rate is never a mismatch (a resume
//! from fail-safe raised one every time), and a valve driven elsewhere by a second writer is
//! off by more than the tolerance within (tolerance × stroke time + `time_ms`). Without valve
//! data, the progress rule above.
//!
//! A mismatch is **latched**: it stays raised after the valve follows again, until the
//! operator acknowledges it ([`FeedbackSupervisor::acknowledge`]); then it clears as soon as
//! the valve follows.
//!
//! Configured per actuator in the signal map:
//!
//! ```toml
//! [feedback]
//! recycle_valve = { tolerance = 0.05, time_ms = 1000 }
//! ```
//!
//! Pure and allocation-free: [`FeedbackSupervisor::step`] takes the values and times.

use serde::{Deserialize, Serialize};

use crate::physics::valve::ValveSpec;
use crate::vocab::signals::{ActuatorId, SensorId};

/// Tolerance and time of one supervised actuator.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeedbackLimit {
    /// Largest accepted |command − feedback|, SI units of the actuator.
    pub tolerance: f64,
    /// How long the difference must last before it is a fault, ms.
    pub time_ms: f64,
    /// Read the actuator's own command register back (a Modbus holding register the device
    /// lets the controller read) every 100 ms: a value this controller did not write is
    /// "another writer", named with the register. Default false.
    #[serde(default)]
    pub readback: bool,
}

/// The sensor that reports what an actuator did.
pub const fn feedback_sensor(a: ActuatorId) -> Option<SensorId> {
    match a {
        ActuatorId::RecycleValve => Some(SensorId::RecycleValvePosition),
        ActuatorId::Throttle => Some(SensorId::ThrottlePosition),
        ActuatorId::TipClearance => Some(SensorId::ThrustPosition),
        ActuatorId::DriveTorque => Some(SensorId::DriveTorque),
        ActuatorId::CloseCoupledValve => None,
    }
}

/// A fault raised or cleared.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeedbackTransition {
    /// The actuator.
    pub actuator: ActuatorId,
    /// Raised (true) or cleared.
    pub active: bool,
    /// Commanded value, SI.
    pub commanded: f64,
    /// Measured value, SI.
    pub measured: f64,
    /// Tolerance in force, SI.
    pub tolerance: f64,
    /// How long the difference lasted, s.
    pub lasted_s: f64,
}

impl FeedbackTransition {
    /// The cause in words: actuator, command, feedback and the difference.
    pub fn cause(&self) -> String {
        let a = self.actuator;
        if self.active {
            format!(
                "{} does not follow its command: commanded {:.4} {u}, measured {:.4} {u}, difference {:.4} {u} beyond the tolerance {:.4} {u} for {:.2} s",
                a.name(),
                self.commanded,
                self.measured,
                (self.commanded - self.measured).abs(),
                self.tolerance,
                self.lasted_s,
                u = a.unit()
            )
        } else {
            format!(
                "{} follows its command again: commanded {:.4} {u}, measured {:.4} {u}",
                a.name(),
                self.commanded,
                self.measured,
                u = a.unit()
            )
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Slot {
    actuator: ActuatorId,
    sensor: SensorId,
    limit: FeedbackLimit,
    since_ns: Option<u64>,
    /// |command − feedback| when the time last (re)started, SI: shrinking below it by a
    /// tolerance is progress, and restarts the time.
    ref_diff: f64,
    active: bool,
    /// The actuator's positioner (None: the progress rule).
    valve: Option<ValveSpec>,
    /// Where the positioner would be now, and when it was last advanced (NaN/None: not yet).
    expected: f64,
    last_ns: Option<u64>,
    /// The operator acknowledged the raised mismatch: it clears once the valve follows.
    acknowledged: bool,
}

/// Supervises the configured actuators.
#[derive(Debug, Clone, Default)]
pub struct FeedbackSupervisor {
    slots: Vec<Slot>,
}

impl FeedbackSupervisor {
    /// Supervise `limits` (actuators without a feedback sensor are ignored).
    pub fn new<'a>(
        limits: impl IntoIterator<Item = (&'a ActuatorId, &'a FeedbackLimit)>,
    ) -> FeedbackSupervisor {
        let slots = limits
            .into_iter()
            .filter_map(|(a, l)| {
                feedback_sensor(*a).map(|sensor| Slot {
                    actuator: *a,
                    sensor,
                    limit: *l,
                    since_ns: None,
                    ref_diff: f64::INFINITY,
                    active: false,
                    valve: None,
                    expected: f64::NAN,
                    last_ns: None,
                    acknowledged: false,
                })
            })
            .collect();
        FeedbackSupervisor { slots }
    }

    /// Compare `actuator`'s feedback with where its positioner `valve` would be (see the
    /// module doc).
    pub fn with_valve(mut self, actuator: ActuatorId, valve: ValveSpec) -> FeedbackSupervisor {
        for s in self.slots.iter_mut().filter(|s| s.actuator == actuator) {
            s.valve = Some(valve);
        }
        self
    }

    /// The operator acknowledged: every raised mismatch clears once its actuator follows.
    pub fn acknowledge(&mut self) {
        for s in &mut self.slots {
            s.acknowledged = s.active;
        }
    }

    /// Actuators with a raised (latched) mismatch now.
    pub fn active(&self) -> impl Iterator<Item = ActuatorId> + '_ {
        self.slots.iter().filter(|s| s.active).map(|s| s.actuator)
    }

    /// Whether anything is supervised.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// One check at `now_ns`. `command(a)` is the latest command (NaN: not driven);
    /// `feedback(s)` the latest fresh value (NaN: none or stale: no judgement). Calls
    /// `report` for every transition.
    pub fn step(
        &mut self,
        now_ns: u64,
        command: impl Fn(ActuatorId) -> f64,
        feedback: impl Fn(SensorId) -> f64,
        mut report: impl FnMut(FeedbackTransition),
    ) {
        for s in &mut self.slots {
            let c = command(s.actuator);
            let m = feedback(s.sensor);
            if !(c.is_finite() && m.is_finite()) {
                s.since_ns = None;
                s.expected = f64::NAN;
                s.last_ns = None;
                continue;
            }
            // the positioner model: from the measured position at the first judgement (a
            // start or resume takes over wherever the valve is), then the command through
            // the valve's own positioner
            let reference = match s.valve {
                Some(v) => {
                    let dt_s = s
                        .last_ns
                        .map_or(0.0, |t0| now_ns.saturating_sub(t0) as f64 * 1e-9);
                    if !s.expected.is_finite() {
                        s.expected = m;
                    }
                    // (sub-steps of at most the positioner lag keep the first-order lag stable)
                    let h = v.positioner_lag_s.max(1e-3);
                    let mut left = dt_s;
                    while left > 0.0 {
                        let step = left.min(h);
                        s.expected =
                            (s.expected + v.positioner_rate(c, s.expected) * step).clamp(0.0, 1.0);
                        left -= step;
                    }
                    s.last_ns = Some(now_ns);
                    s.expected
                }
                None => c,
            };
            let diff = (reference - m).abs();
            let off = diff > s.limit.tolerance;
            let lasted_s = |since: Option<u64>| {
                since.map_or(0.0, |t0| now_ns.saturating_sub(t0) as f64 * 1e-9)
            };
            if off {
                if s.valve.is_some() {
                    // the model already follows the stroke: off since it first went off
                    if s.since_ns.is_none() {
                        s.since_ns = Some(now_ns);
                    }
                } else if s.since_ns.is_none() || diff < s.ref_diff - s.limit.tolerance {
                    // travelling towards the command by another tolerance: still following
                    s.since_ns = Some(now_ns);
                    s.ref_diff = diff;
                }
                let since = s.since_ns.unwrap_or(now_ns);
                let lasted = lasted_s(Some(since));
                if !s.active && lasted * 1e3 >= s.limit.time_ms {
                    s.active = true;
                    s.acknowledged = false;
                    report(FeedbackTransition {
                        actuator: s.actuator,
                        active: true,
                        commanded: c,
                        measured: m,
                        tolerance: s.limit.tolerance,
                        lasted_s: lasted,
                    });
                }
            } else {
                s.since_ns = None;
                // latched: cleared only once acknowledged
                if s.active && s.acknowledged {
                    s.active = false;
                    s.acknowledged = false;
                    report(FeedbackTransition {
                        actuator: s.actuator,
                        active: false,
                        commanded: c,
                        measured: m,
                        tolerance: s.limit.tolerance,
                        lasted_s: 0.0,
                    });
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    #[test]
    fn mismatch_is_raised_after_the_time_and_cleared_when_following() {
        let mut limits = BTreeMap::new();
        limits.insert(
            ActuatorId::RecycleValve,
            FeedbackLimit {
                readback: false,
                tolerance: 0.05,
                time_ms: 300.0,
            },
        );
        let mut sup = FeedbackSupervisor::new(&limits);
        let mut seen = Vec::new();
        let ms = 1_000_000u64;
        // commanded 0.4, valve held at 0 by someone else
        for k in 0..=40u64 {
            sup.step(k * 10 * ms, |_| 0.4, |_| 0.0, |t| seen.push((k, t)));
        }
        assert_eq!(seen.len(), 1, "{seen:?}");
        let (k, t) = seen[0];
        assert_eq!(k, 30, "raised after 300 ms");
        assert!(t.active);
        let cause = t.cause();
        assert!(cause.contains("recycle_valve"), "{cause}");
        assert!(cause.contains("difference 0.4000"), "{cause}");
        // within tolerance: latched until acknowledged, then cleared once
        sup.step(500 * ms, |_| 0.4, |_| 0.38, |t| seen.push((50, t)));
        assert_eq!(seen.len(), 1, "latched: {seen:?}");
        assert_eq!(sup.active().collect::<Vec<_>>(), [ActuatorId::RecycleValve]);
        sup.acknowledge();
        sup.step(505 * ms, |_| 0.4, |_| 0.38, |t| seen.push((50, t)));
        sup.step(510 * ms, |_| 0.4, |_| 0.38, |t| seen.push((51, t)));
        assert_eq!(seen.len(), 2);
        assert_eq!(sup.active().count(), 0);
        assert!(!seen[1].1.active);
        // a short excursion (valve stroking) is no fault
        for k in 0..20u64 {
            sup.step((600 + k * 10) * ms, |_| 0.8, |_| 0.4, |t| seen.push((k, t)));
        }
        assert_eq!(seen.len(), 2);
        // no feedback: no judgement
        sup.step(900 * ms, |_| 0.8, |_| f64::NAN, |t| seen.push((0, t)));
        assert_eq!(seen.len(), 2);
    }

    fn valve_limit(time_ms: f64) -> BTreeMap<ActuatorId, FeedbackLimit> {
        let mut limits = BTreeMap::new();
        limits.insert(
            ActuatorId::RecycleValve,
            FeedbackLimit {
                readback: false,
                tolerance: 0.05,
                time_ms,
            },
        );
        limits
    }

    fn spec(stroke_time_s: f64) -> ValveSpec {
        ValveSpec {
            cv_max_m2: 1e-3,
            characteristic: crate::physics::valve::Characteristic::Linear,
            min_opening: 1e-3,
            stroke_time_s,
            positioner_lag_s: 0.05,
        }
    }

    /// A valve whose positioner lags more than the machine file says (0.1 s for 0.05 s).
    fn real_valve(pos: f64, cmd: f64, dt_s: f64, stroke_time_s: f64) -> f64 {
        let rate = ((cmd - pos) / 0.1).clamp(-1.0 / stroke_time_s, 1.0 / stroke_time_s);
        (pos + rate * dt_s).clamp(0.0, 1.0)
    }

    #[test]
    fn a_valve_following_a_moving_command_within_its_stroke_rate_is_never_a_mismatch() {
        let ms = 1_000_000u64;
        // ten fail-safe exits: the command at 100 %, then at each resume the measured
        // position (the valve on its way), then a closing ramp at 1 /s, faster than the
        // 2-s valve strokes (0.5 /s); with the progress rule alone these raised mismatches
        for model in [true, false] {
            let mut sup = FeedbackSupervisor::new(&valve_limit(150.0));
            if model {
                sup = sup.with_valve(ActuatorId::RecycleValve, spec(2.0));
            }
            let mut seen = 0;
            let mut pos = 0.2;
            let mut k = 0u64;
            for _exit in 0..10 {
                // fail-safe for 0.5 s
                for _ in 0..50 {
                    pos = real_valve(pos, 1.0, 0.01, 2.0);
                    sup.step(k * 10 * ms, |_| 1.0, |_| pos, |_| seen += 1);
                    k += 1;
                }
                // resume from the measured position, then close at 1 /s to 0.1
                let mut cmd = pos;
                for _ in 0..150 {
                    cmd = (cmd - 0.01).max(0.1);
                    pos = real_valve(pos, cmd, 0.01, 2.0);
                    sup.step(k * 10 * ms, |_| cmd, |_| pos, |_| seen += 1);
                    k += 1;
                }
            }
            if model {
                assert_eq!(seen, 0, "mismatches with the positioner model");
            } else {
                assert!(
                    seen > 0,
                    "the progress rule alone raises them (why the model exists)"
                );
            }
        }
    }

    #[test]
    fn a_second_writer_is_found_within_300_ms_and_latched() {
        let ms = 1_000_000u64;
        let mut sup = FeedbackSupervisor::new(&valve_limit(150.0))
            .with_valve(ActuatorId::RecycleValve, spec(2.0));
        let mut raised = Vec::new();
        let mut pos = 0.2;
        // the controller commands 20 %; from t = 1 s another master writes 0 for 4 s
        for k in 0..800u64 {
            let t = k as f64 * 0.01;
            let written = if (1.0..5.0).contains(&t) { 0.0 } else { 0.2 };
            pos = real_valve(pos, written, 0.01, 2.0);
            sup.step(
                k * 10 * ms,
                |_| 0.2,
                |_| pos,
                |tr| raised.push((t, tr.active)),
            );
        }
        assert_eq!(raised.len(), 1, "raised once, latched after: {raised:?}");
        let (t, active) = raised[0];
        assert!(active);
        assert!(
            (1.0..1.3).contains(&(t - 0.0)),
            "found {:.0} ms after the first write",
            1e3 * (t - 1.0)
        );
        assert_eq!(sup.active().count(), 1, "still latched at 8 s");
    }

    #[test]
    fn a_valve_stroking_slowly_towards_a_large_step_follows_and_a_stuck_one_does_not() {
        let ms = 1_000_000u64;
        // a 2-s stroke valve (0.5 /s) after a step from 0 to 0.8: 1.6 s to get there, far
        // longer than the 500 ms: no fault while it travels
        let mut sup = FeedbackSupervisor::new(&valve_limit(500.0));
        let mut seen = Vec::new();
        for k in 0..=300u64 {
            let pos = (0.5 * k as f64 * 0.01).min(0.8);
            sup.step(k * 10 * ms, |_| 0.8, |_| pos, |t| seen.push((k, t)));
        }
        assert!(seen.is_empty(), "{seen:?}");
        // the same valve sticking at 0.3 on its way: found 500 ms after its last progress
        let mut sup = FeedbackSupervisor::new(&valve_limit(500.0));
        let mut seen = Vec::new();
        for k in 0..=300u64 {
            let pos = (0.5 * k as f64 * 0.01).min(0.3);
            sup.step(k * 10 * ms, |_| 0.8, |_| pos, |t| seen.push((k, t)));
        }
        assert_eq!(seen.len(), 1, "{seen:?}");
        let (k, t) = seen[0];
        assert!(t.active);
        // progress by more than a tolerance restarts the time every 11 steps (k = 11, 22,
        // …, 55: difference 0.525); stuck from k = 60 at a difference of 0.5, no further
        // progress: raised at k = 105, 500 ms after the last restart
        assert_eq!(k, 105, "{seen:?}");
        assert!(t.cause().contains("measured 0.3000"), "{}", t.cause());
        // a valve moving the wrong way makes no progress: raised after 500 ms
        let mut sup = FeedbackSupervisor::new(&valve_limit(500.0));
        let mut seen = Vec::new();
        for k in 0..=100u64 {
            let pos = (0.4 - 0.5 * k as f64 * 0.01).max(0.0);
            sup.step(k * 10 * ms, |_| 0.8, |_| pos, |t| seen.push((k, t)));
        }
        assert_eq!(seen.iter().map(|(k, _)| *k).collect::<Vec<_>>(), vec![50]);
    }
}
