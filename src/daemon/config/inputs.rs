//! `[inputs.<sensor>]`: plausibility range and freshness per sensor. Sensors not listed get
//! defaults derived from the machine (and its transmitter ranges).

use super::problem::KeyProblem;
use crate::vocab::signals::SensorId;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// One `[inputs.<sensor>]` table: plausibility range in the sensor's SI unit and freshness.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputSection {
    /// Lowest plausible value (Pa, rad/s, K, fraction or m, per sensor).
    pub min: f64,
    /// Highest plausible value, same unit.
    pub max: f64,
    /// The input is stale when no new value arrived for this long, ms.
    pub timeout_ms: f64,
}

/// The rules of every `[inputs.<sensor>]` table at the control rate `rate_hz`.
pub fn validate(inputs: &BTreeMap<SensorId, InputSection>, rate_hz: f64) -> Vec<KeyProblem> {
    let mut out = Vec::new();
    for (id, s) in inputs {
        let key = format!("inputs.{}", id.name());
        if !(s.min.is_finite() && s.max.is_finite() && s.min < s.max) {
            out.push(
                KeyProblem::error(
                    format!("{key}.max"),
                    format!(
                        "range [{}, {}] {} is empty or not finite (min must be below max)",
                        s.min,
                        s.max,
                        id.unit()
                    ),
                )
                .with_hint("min < max, in the sensor's SI unit"),
            );
        }
        let period_ms = 1e3 / rate_hz.max(1e-9);
        if !(s.timeout_ms.is_finite() && s.timeout_ms > period_ms) {
            out.push(
                KeyProblem::error(
                    format!("{key}.timeout_ms"),
                    format!(
                        "{} ms must be longer than one control period ({period_ms:.2} ms)",
                        s.timeout_ms
                    ),
                )
                .with_hint("a few sensor periods, e.g. 50"),
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_range_and_short_timeout_name_their_keys() {
        let mut m = BTreeMap::new();
        let ok = InputSection {
            min: 0.0,
            max: 2e6,
            timeout_ms: 50.0,
        };
        m.insert(SensorId::PSuction, ok);
        assert!(validate(&m, 1000.0).is_empty());
        m.insert(
            SensorId::PDischarge,
            InputSection {
                min: 120.0,
                max: 1.0,
                timeout_ms: 0.5,
            },
        );
        let keys: Vec<String> = validate(&m, 1000.0).into_iter().map(|p| p.key).collect();
        assert_eq!(
            keys,
            ["inputs.p_discharge.max", "inputs.p_discharge.timeout_ms"]
        );
        // 50 ms is shorter than one period at 10 Hz
        m.remove(&SensorId::PDischarge);
        let slow = validate(&m, 10.0);
        assert_eq!(slow.len(), 1);
        assert_eq!(slow[0].key, "inputs.p_suction.timeout_ms");
    }
}
