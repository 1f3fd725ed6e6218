//! The surge control line (SCL): the surge line moved right by a safety margin, in invariant
//! coordinates (flow in the map's coordinate versus pressure ratio, seed 002 §2.3.1–2.3.2).
//!
//! Two forms:
//! - `margin`: q_SCL(R) = (1 + b1) j(R) + b0, with j the *derived* surge line (seed 002
//!   eq. 4.1 with b1 a percentage of flow as in eq. 4.17/4.36; seed 001 eq. 3.1–3.3). Eq. 4.17
//!   prints "1 + b1 j(R)"; eq. 4.36 prints "[1 + b1] j(R)" for the same construction ("a margin in
//!   percentage of flow"): we use the latter.
//! - `sqrt`: q_SCL(R) = c0 √(R − 1) (seed 002 eq. 4.2; App. A uses c0 = 0.6).
//!
//! Safety-on shifts the line further right by a step after each detected surge (seed 002
//! §2.2.2, patent [13]'s surge-count bias).

use crate::physics::compressor_map::SurgeLine;
use serde::{Deserialize, Serialize};

/// How the control line is defined.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum ControlLineForm {
    /// (1 + margin) × surge-line flow + offset.
    Margin {
        /// Margin b1 in percent of the surge-line flow.
        margin_pct: f64,
        /// Offset b0 in map flow units (kg/s or m³/s).
        #[serde(default)]
        offset: f64,
    },
    /// c0 √(R − 1) in map flow units.
    Sqrt {
        /// c0.
        c0: f64,
    },
}

impl Default for ControlLineForm {
    fn default() -> Self {
        ControlLineForm::Margin {
            margin_pct: 10.0,
            offset: 0.0,
        }
    }
}

/// A surge control line bound to a machine's derived surge line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurgeControlLine {
    surge_line: SurgeLine,
    form: ControlLineForm,
    /// Extra margin from safety-on shifts, fraction of surge-line flow.
    pub shift: f64,
}

impl SurgeControlLine {
    /// Bind a form to a surge line.
    pub fn new(surge_line: SurgeLine, form: ControlLineForm) -> Self {
        SurgeControlLine {
            surge_line,
            form,
            shift: 0.0,
        }
    }

    /// The surge line it is built on.
    pub fn surge_line(&self) -> &SurgeLine {
        &self.surge_line
    }

    /// Control-line flow at a pressure ratio (map flow units). Allocation-free.
    #[inline]
    pub fn flow_at_ratio(&self, ratio: f64) -> f64 {
        let j = self.surge_line.flow_at_ratio(ratio);
        let base = match self.form {
            ControlLineForm::Margin { margin_pct, offset } => {
                (1.0 + 0.01 * margin_pct) * j + offset
            }
            ControlLineForm::Sqrt { c0 } => c0 * (ratio - 1.0).max(0.0).sqrt(),
        };
        base + self.shift * j
    }

    /// Slope dq_SCL/dR, map flow units per unit pressure ratio.
    pub fn slope_at_ratio(&self, ratio: f64) -> f64 {
        let h = 1e-4 * ratio.abs().max(1.0);
        (self.flow_at_ratio(ratio + h) - self.flow_at_ratio(ratio - h)) / (2.0 * h)
    }

    /// Check that the control line lies right of the surge line (by at least `min_margin`,
    /// fraction) at every pressure ratio in `ratios`; returns the worst ratio and its margin if
    /// not.
    pub fn check_right_of_surge_line(
        &self,
        ratios: (f64, f64),
        min_margin: f64,
    ) -> Result<(), (f64, f64)> {
        for k in 0..=200 {
            let r = ratios.0 + (ratios.1 - ratios.0) * k as f64 / 200.0;
            let j = self.surge_line.flow_at_ratio(r);
            let margin = (self.flow_at_ratio(r) - j) / j;
            if margin.is_nan() || margin < min_margin {
                return Err((r, margin));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::characteristic::MooreGreitzerCubic;
    use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};

    fn map() -> CompressorMap {
        CompressorMap::cubic(
            MooreGreitzerCubic {
                psi_c0: 1.6,
                semi_height: 0.3,
                semi_width: 2.0,
                omega_ref: 1000.0,
            },
            FlowCoordinate::MassKgS,
            600.0,
            1400.0,
        )
        .expect("map")
    }

    #[test]
    fn margin_line_is_percent_right_of_surge_line() {
        let m = map();
        let mut scl = SurgeControlLine::new(
            m.surge_line,
            ControlLineForm::Margin {
                margin_pct: 10.0,
                offset: 0.0,
            },
        );
        let r = 2.2;
        let j = m.surge_line.flow_at_ratio(r);
        assert!((scl.flow_at_ratio(r) - 1.1 * j).abs() < 1e-12);
        scl.shift = 0.05;
        assert!((scl.flow_at_ratio(r) - 1.15 * j).abs() < 1e-12);
        assert!(scl.check_right_of_surge_line((1.5, 3.0), 0.1).is_ok());
    }

    #[test]
    fn sqrt_line_left_of_surge_line_is_caught() {
        let m = map();
        // this cubic's surge line is q = 4 √((R−1)/1.2): c0 = 3 lies left of it
        let scl = SurgeControlLine::new(m.surge_line, ControlLineForm::Sqrt { c0: 3.0 });
        let (r, margin) = scl.check_right_of_surge_line((1.5, 3.0), 0.0).unwrap_err();
        assert!(margin < 0.0 && r >= 1.5, "{r} {margin}");
        let ok = SurgeControlLine::new(m.surge_line, ControlLineForm::Sqrt { c0: 4.5 });
        assert!(ok.check_right_of_surge_line((1.5, 3.0), 0.1).is_ok());
    }
}
