//! Input supervision: freshness, range and NaN checks per sensor. The one place that decides
//! whether an input is usable; the control core derives fallbacks and fail-safe from it.

use super::measurements::RawSensors;
use crate::vocab::faults::{FaultCategory, FaultSet};
use crate::vocab::signals::SensorId;
use serde::{Deserialize, Serialize};

/// Limits of one input.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputLimits {
    /// Lowest plausible value (SI).
    pub min: f64,
    /// Highest plausible value (SI).
    pub max: f64,
    /// Largest age before the value is stale, s.
    pub timeout_s: f64,
}

/// Why an input is not usable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputFault {
    /// Usable.
    None,
    /// Not a number.
    Nan,
    /// Outside [min, max].
    OutOfRange,
    /// Older than the timeout.
    Stale,
    /// Fresh and in range but repeating itself while related signals move (the control
    /// core's cross-check, [`crate::control::checks::cross_check`]).
    Frozen,
    /// Fresh, in range and moving, but disagreeing persistently with the observer and the
    /// speed-line flow (drifting or biased; the control core's cross-check,
    /// [`crate::control::checks::drift_check`]).
    Drift,
}

/// Validity of every input after one check.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Validity {
    /// Fault per sensor (None = usable).
    pub fault: [InputFault; SensorId::COUNT],
}

impl Validity {
    /// Whether a sensor is usable.
    #[inline]
    pub fn ok(&self, id: SensorId) -> bool {
        self.fault[id.index()] == InputFault::None
    }

    /// Input faults in categories. Sensors the supervisor does not use (no limits) are not
    /// faults: a healthy controller that reads only some sensors sends 0. Allocation-free.
    pub fn fault_set(&self, supervisor: &Supervisor) -> FaultSet {
        let mut f = FaultSet::NONE;
        for id in SensorId::ALL {
            if supervisor.limits[id.index()].is_none() {
                continue;
            }
            match self.fault[id.index()] {
                InputFault::None => {}
                InputFault::Stale => f.set(FaultCategory::SensorTimeout),
                InputFault::Nan
                | InputFault::OutOfRange
                | InputFault::Frozen
                | InputFault::Drift => f.set(FaultCategory::SensorImplausible),
            }
        }
        f
    }
}

/// Per-sensor limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Supervisor {
    /// Limits per sensor (None: sensor not used).
    pub limits: [Option<InputLimits>; SensorId::COUNT],
}

impl Supervisor {
    /// Raise every freshness timeout to at least `periods` × `poll_period_s` (inputs that
    /// arrive by polling are up to one poll period old between answers, plus the answer
    /// time). Timeouts already longer are kept.
    pub fn follow_poll_period(&mut self, poll_period_s: f64, periods: f64) {
        if !(poll_period_s.is_finite() && poll_period_s > 0.0) {
            return;
        }
        for l in self.limits.iter_mut().flatten() {
            l.timeout_s = l.timeout_s.max(periods * poll_period_s);
        }
    }

    /// [`follow_poll_period`](Self::follow_poll_period) for the inputs `ids` only (the
    /// sensors a polled bus delivers; inputs on CAN keep their own timeouts).
    pub fn follow_poll_period_of(&mut self, ids: &[SensorId], poll_period_s: f64, periods: f64) {
        if !(poll_period_s.is_finite() && poll_period_s > 0.0) {
            return;
        }
        for id in ids {
            if let Some(l) = self.limits[id.index()].as_mut() {
                l.timeout_s = l.timeout_s.max(periods * poll_period_s);
            }
        }
    }

    /// Check all inputs.
    pub fn check(&self, raw: &RawSensors) -> Validity {
        let mut fault = [InputFault::None; SensorId::COUNT];
        for id in SensorId::ALL {
            let i = id.index();
            fault[i] = self.check_one(id, raw.values.values[i], raw.age_s[i]);
        }
        Validity { fault }
    }

    /// Check one reading of `id` (value, age in s) against its limits: the same rule for an
    /// input and for each of its redundant transmitters ([`crate::control::vote`]).
    /// An input without limits (not used) is never usable.
    #[inline]
    pub fn check_one(&self, id: SensorId, v: f64, age_s: f64) -> InputFault {
        let Some(lim) = self.limits[id.index()] else {
            return InputFault::Nan;
        };
        if v.is_nan() {
            InputFault::Nan
        } else if age_s > lim.timeout_s {
            InputFault::Stale
        } else if v < lim.min || v > lim.max {
            InputFault::OutOfRange
        } else {
            InputFault::None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vocab::signals::SensorSnapshot;

    #[test]
    fn unused_sensors_are_not_faults_and_kinds_map_to_categories() {
        let lim = InputLimits {
            min: 0.0,
            max: 1.0,
            timeout_s: 0.1,
        };
        let mut limits = [None; SensorId::COUNT];
        limits[SensorId::PSuction.index()] = Some(lim);
        limits[SensorId::OrificeDp.index()] = Some(lim);
        let sup = Supervisor { limits };
        // thrust position (index 7) unused and "NaN": healthy, not 128 (config_error)
        let mut fault = [InputFault::None; SensorId::COUNT];
        fault[SensorId::ThrustPosition.index()] = InputFault::Nan;
        let v = Validity { fault };
        assert_eq!(v.fault_set(&sup), FaultSet::NONE);
        fault[SensorId::PSuction.index()] = InputFault::Stale;
        fault[SensorId::OrificeDp.index()] = InputFault::OutOfRange;
        let f = Validity { fault }.fault_set(&sup);
        assert_eq!(f.0, 1 | 8);
        let names: Vec<&str> = f.categories().map(|c| c.name()).collect();
        assert_eq!(names, ["sensor_timeout", "sensor_implausible"]);
    }

    #[test]
    fn classifies_faults() {
        let mut limits = [None; SensorId::COUNT];
        limits[SensorId::PSuction.index()] = Some(InputLimits {
            min: 1e4,
            max: 1e6,
            timeout_s: 0.01,
        });
        limits[SensorId::OrificeDp.index()] = Some(InputLimits {
            min: -1e3,
            max: 5e4,
            timeout_s: 0.01,
        });
        limits[SensorId::ShaftSpeed.index()] = Some(InputLimits {
            min: 0.0,
            max: 5e3,
            timeout_s: 0.01,
        });
        let sup = Supervisor { limits };
        let mut v = SensorSnapshot::default();
        v.set(SensorId::PSuction, 1e5);
        v.set(SensorId::OrificeDp, 9e4);
        let mut raw = RawSensors::fresh(v);
        raw.age_s[SensorId::PSuction.index()] = 0.005;
        let val = sup.check(&raw);
        assert!(val.ok(SensorId::PSuction));
        assert_eq!(
            val.fault[SensorId::OrificeDp.index()],
            InputFault::OutOfRange
        );
        assert_eq!(val.fault[SensorId::ShaftSpeed.index()], InputFault::Nan);
        raw.age_s[SensorId::PSuction.index()] = 0.02;
        assert_eq!(
            sup.check(&raw).fault[SensorId::PSuction.index()],
            InputFault::Stale
        );
        // an unused sensor is never usable
        assert!(!sup.check(&raw).ok(SensorId::ThrustPosition));
    }
}
