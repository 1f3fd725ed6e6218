//! `[control]`: which law, in which mode, around which setpoints, and the fail-safe opening.

use super::problem::KeyProblem;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum StartMode {
    /// The selected law runs as soon as the inputs are healthy.
    #[default]
    Auto,
    /// Speed loop only; the recycle valve holds its position (manual station).
    Manual,
}

/// `[control]`: which law, in which mode, around which setpoints.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlSection {
    /// Surge law (`none`, `recycle-pi`, `recycle-fl`, `drive-torque`, `ccv`,
    /// `throttle-backstep`, `robust`, `tip-sliding`).
    pub law: String,
    /// Mode at start.
    #[serde(default)]
    pub mode: StartMode,
    /// Speed setpoint, rad/s; absent: the plant file's nominal speed.
    #[serde(default)]
    pub speed_setpoint_rad_s: Option<f64>,
    /// Mass-flow setpoint of flow-tracking laws (`recycle-fl`), kg/s; absent: hold the flow.
    #[serde(default)]
    pub flow_setpoint_kg_s: Option<f64>,
    /// Recycle-valve opening in fail-safe, percent (100: fully open, the usual safe state).
    #[serde(default = "d_failsafe_pct")]
    pub failsafe_recycle_opening_pct: f64,
    /// At start, how long to wait for healthy inputs before commanding the fail-safe state,
    /// ms. Meanwhile nothing is commanded: a controller restart on a running machine does not
    /// move its actuators, and the law takes over from the measured positions.
    #[serde(default = "d_startup_grace_ms")]
    pub startup_grace_ms: f64,
}

fn d_failsafe_pct() -> f64 {
    100.0
}

fn d_startup_grace_ms() -> f64 {
    1000.0
}

impl ControlSection {
    /// The section's own rules. `nominal_speed_rad_s` is the machine's nominal speed (the
    /// speed setpoint may not exceed 120 % of it).
    pub fn validate(&self, nominal_speed_rad_s: f64) -> Vec<KeyProblem> {
        let mut out = Vec::new();
        let f = self.failsafe_recycle_opening_pct;
        if !(f.is_finite() && (0.0..=100.0).contains(&f)) {
            out.push(
                KeyProblem::error(
                    "control.failsafe_recycle_opening_pct",
                    format!("{f} is outside 0–100 %"),
                )
                .with_hint("100 (fully open) is the usual safe state"),
            );
        }
        let g = self.startup_grace_ms;
        if !(g.is_finite() && (0.0..=60_000.0).contains(&g)) {
            out.push(
                KeyProblem::error(
                    "control.startup_grace_ms",
                    format!("{g} is outside 0–60000 ms"),
                )
                .with_hint(
                    "1000 gives the buses time to deliver the first readings; 0 goes fail-safe at once",
                ),
            );
        }
        if let Some(w) = self.speed_setpoint_rad_s {
            let nominal = nominal_speed_rad_s;
            if !(w.is_finite() && w > 0.0 && w <= 1.2 * nominal) {
                out.push(
                    KeyProblem::error(
                        "control.speed_setpoint_rad_s",
                        format!(
                            "{w} rad/s is outside (0, 120 % of the nominal {nominal:.1} rad/s]"
                        ),
                    )
                    .with_hint("leave it out to run at the plant's nominal speed"),
                );
            }
        }
        if let Some(m) = self.flow_setpoint_kg_s {
            if !(m.is_finite() && m > 0.0) {
                out.push(KeyProblem::error(
                    "control.flow_setpoint_kg_s",
                    format!("{m} kg/s must be a positive mass flow"),
                ));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn section() -> ControlSection {
        toml::from_str("law = \"recycle-pi\"").expect("control section")
    }

    #[test]
    fn defaults_pass() {
        let c = section();
        assert_eq!(c.failsafe_recycle_opening_pct, 100.0);
        assert_eq!(c.startup_grace_ms, 1000.0);
        assert!(c.validate(1000.0).is_empty());
    }

    #[test]
    fn each_rule_names_its_key() {
        let mut c = section();
        c.failsafe_recycle_opening_pct = 120.0;
        c.startup_grace_ms = -1.0;
        c.speed_setpoint_rad_s = Some(1300.0);
        c.flow_setpoint_kg_s = Some(0.0);
        let keys: Vec<String> = c.validate(1000.0).into_iter().map(|p| p.key).collect();
        assert_eq!(
            keys,
            [
                "control.failsafe_recycle_opening_pct",
                "control.startup_grace_ms",
                "control.speed_setpoint_rad_s",
                "control.flow_setpoint_kg_s"
            ]
        );
        c.speed_setpoint_rad_s = Some(1150.0);
        assert!(!c
            .validate(1000.0)
            .iter()
            .any(|p| p.key == "control.speed_setpoint_rad_s"));
    }
}
