//! Actuator feedback supervision: does each actuator do what it was told?
//!
//! A device that refuses a write, a second master overwriting a setpoint or a stuck valve
//! all look normal on the wire; only the feedback catches them. For each supervised
//! actuator the commanded value is compared with its feedback sensor (recycle valve ↔
//! valve position, throttle ↔ throttle position, tip clearance ↔ thrust position, drive
//! torque ↔ delivered torque). A difference beyond `tolerance` (SI units of the actuator)
//! that lasts `time_ms` is the industry's valve feedback fault
//! ([`FaultCategory::ActuatorFeedbackMismatch`](crate::faults::FaultCategory)).
//! An actuator that is still travelling towards its command follows it: each time the
//! difference has shrunk by another `tolerance` the time starts again, so a slow-stroking
//! valve after a large step is no fault, while a stuck one (or one moving the wrong way) is
//! found `time_ms` after it stopped making progress. (The foreign Modbus skid's 2-s valve
//! took longer than its map's 500 ms to follow a 0.2 trip step when the machine was loaded,
//! and raised the fault on a healthy valve.)
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

use crate::signals::{ActuatorId, SensorId};

/// Tolerance and time of one supervised actuator.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeedbackLimit {
    /// Largest accepted |command − feedback|, SI units of the actuator.
    pub tolerance: f64,
    /// How long the difference must last before it is a fault, ms.
    pub time_ms: f64,
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
                })
            })
            .collect();
        FeedbackSupervisor { slots }
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
                continue;
            }
            let diff = (c - m).abs();
            let off = diff > s.limit.tolerance;
            let lasted_s = |since: Option<u64>| {
                since.map_or(0.0, |t0| now_ns.saturating_sub(t0) as f64 * 1e-9)
            };
            if off {
                // travelling towards the command by another tolerance: still following
                if s.since_ns.is_none() || diff < s.ref_diff - s.limit.tolerance {
                    s.since_ns = Some(now_ns);
                    s.ref_diff = diff;
                }
                let since = s.since_ns.unwrap_or(now_ns);
                let lasted = lasted_s(Some(since));
                if !s.active && lasted * 1e3 >= s.limit.time_ms {
                    s.active = true;
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
                if s.active {
                    s.active = false;
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
        // within tolerance: cleared once
        sup.step(500 * ms, |_| 0.4, |_| 0.38, |t| seen.push((50, t)));
        sup.step(510 * ms, |_| 0.4, |_| 0.38, |t| seen.push((51, t)));
        assert_eq!(seen.len(), 2);
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
                tolerance: 0.05,
                time_ms,
            },
        );
        limits
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
