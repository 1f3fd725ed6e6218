//! Safety-on (seed 002 §2.2.2, patent [13]: the "surge count bias" of the control line).
//!
//! Purpose: a surge the other parts could not prevent proves the control margin too small
//! for this machine's disturbances; each surge the core's detector reports (`crate::surge`,
//! which counts oscillation cycles of the measured flow between 1 and 10 Hz) moves the
//! control line right by `step_pct` of the surge-line flow, up to `max_pct`. The shift
//! outlives a restart (the daemon keeps the count) and is reported as
//! [`crate::control::law::api::LawEvent::SafetyOnShift`].

use serde::{Deserialize, Serialize};

/// Settings of safety-on (`[controller.recycle_pi.safety_on]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SafetyOnConfig {
    /// Control-line shift per detected surge, percent of surge-line flow (0 disables).
    /// Default 5 %: half the default control margin (10 %): a surge shows the margin was
    /// short, and half of it again is the smallest shift that matters against the flow
    /// noise of a Δp transmitter (1–2 % of flow).
    pub step_pct: f64,
    /// Largest total shift, percent of surge-line flow. Default 20 %: twice the default
    /// margin; beyond that the machine needs commissioning, not more margin.
    pub max_pct: f64,
}

impl Default for SafetyOnConfig {
    fn default() -> Self {
        SafetyOnConfig {
            step_pct: 5.0,
            max_pct: 20.0,
        }
    }
}

/// Safety-on's state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SafetyOn {
    step: f64,
    max: f64,
    /// Shifts so far.
    count: u32,
    /// Shift not yet reported.
    pending: bool,
}

impl SafetyOn {
    /// With these settings.
    pub fn new(cfg: &SafetyOnConfig) -> Self {
        SafetyOn {
            step: 0.01 * cfg.step_pct.max(0.0),
            max: 0.01 * cfg.max_pct.max(0.0),
            count: 0,
            pending: false,
        }
    }

    /// Shifts so far.
    pub fn count(&self) -> u32 {
        self.count
    }

    /// The control line's shift, fraction of surge-line flow.
    pub fn shift(&self) -> f64 {
        (self.step * f64::from(self.count)).min(self.max)
    }

    /// Restore a count kept across a restart, or carried over a change of settings.
    pub fn restore(&mut self, count: u32) {
        self.count = count;
    }

    /// A surge was detected: one more step unless at the cap. Returns whether the line moved.
    pub fn on_surge(&mut self) -> bool {
        if self.step > 0.0 && self.shift() + 1e-12 < self.max {
            self.count = self.count.saturating_add(1);
            self.pending = true;
            true
        } else {
            false
        }
    }

    /// A shift to report, once.
    pub fn take_pending(&mut self) -> bool {
        std::mem::take(&mut self.pending)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_step_per_surge_up_to_the_cap() {
        let mut s = SafetyOn::new(&SafetyOnConfig::default());
        for k in 1..=4 {
            assert!(s.on_surge());
            assert!((s.shift() - 0.05 * f64::from(k)).abs() < 1e-12);
            assert!(s.take_pending());
            assert!(!s.take_pending());
        }
        assert!(!s.on_surge(), "capped at 20 %");
        assert!((s.shift() - 0.20).abs() < 1e-12);
    }

    #[test]
    fn zero_step_is_off() {
        let mut s = SafetyOn::new(&SafetyOnConfig {
            step_pct: 0.0,
            ..SafetyOnConfig::default()
        });
        assert!(!s.on_surge());
        assert_eq!(s.shift(), 0.0);
    }
}
