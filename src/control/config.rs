//! The controller's settings: flow source, observer, surge detection and every law's gains.
//!
//! One schema, used in two places: a plant file's `[controller]` table holds the tuned defaults
//! for that benchmark machine, and the daemon's config may override any key. Every field has a
//! default (from the seeds where they give one), so an absent table means "seed defaults".

use super::checks::drift_check::DriftCheckConfig;
use super::law::api::LawSpec;
use super::law::list::laws;
use super::observer::ObserverConfig;
use crate::surge::DetectorConfig;
use serde::{Deserialize, Serialize};

/// Where the laws take the compressor mass flow from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FlowSource {
    /// The orifice (flow transmitter) only; a failed transmitter is an input failure.
    Orifice,
    /// The observer only (seed 000 eq. 15: pressure and speed only).
    Observer,
    /// The orifice, with the observer as fallback when the transmitter is stale, NaN or out
    /// of range.
    #[default]
    OrificeWithObserverFallback,
}

/// The controller settings: the fixed part, then one `[controller.<section>]` per law of the
/// list that has its own section, in list order.
macro_rules! controller_config {
    (@fields [$($fields:tt)*]) => {
        /// Controller settings (`[controller]`).
        #[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
        #[serde(deny_unknown_fields, default)]
        pub struct ControllerConfig {
            /// Flow source.
            pub flow_source: FlowSource,
            /// Mass-flow observer (seed 000 eq. 14–17).
            pub observer: ObserverConfig,
            /// Surge detection.
            pub detector: DetectorConfig,
            /// Cross-check of the flow transmitter against the observer and the speed-line flow
            /// (drifting or biased Δp).
            pub drift_check: DriftCheckConfig,
            /// Cut-off of the filtered pressure derivatives some laws use, Hz.
            #[serde(default = "default_derivative_hz")]
            pub derivative_filter_hz: f64,
            $($fields)*
        }
    };
    (@fields [$($fields:tt)*]
        $id:ident $code:literal $name:literal $scope:ident $($seg:ident)::+,
        ($section:ident : $($t:ident)::+);
        $($rest:tt)*
    ) => {
        controller_config!(@fields [
            $($fields)*
            #[doc = concat!("`", $name, "`.")]
            pub $section: crate::control::$($t)::+,
        ] $($rest)*);
    };
    (@fields [$($fields:tt)*]
        $id:ident $code:literal $name:literal $scope:ident $($seg:ident)::+, $settings:tt;
        $($rest:tt)*
    ) => {
        controller_config!(@fields [$($fields)*] $($rest)*);
    };
    ($($list:tt)*) => {
        controller_config!(@fields [] $($list)*);
    };
}

laws!(controller_config);

/// One law's own plausibility check of its section (laws that share another's section are
/// checked by that law).
macro_rules! law_problems {
    ($cfg:ident, $ty:path, ($section:ident : $($t:ident)::+)) => {
        <$ty as LawSpec>::settings_problems(&$cfg.$section)
    };
    ($cfg:ident, $ty:path, $settings:tt) => {
        Vec::<(String, String)>::new()
    };
}

macro_rules! law_settings_problems {
    ($($id:ident $code:literal $name:literal $scope:ident $($seg:ident)::+, $settings:tt;)*) => {
        impl ControllerConfig {
            /// Every law's [`LawSpec::settings_problems`] of its own section.
            fn law_settings_problems(&self) -> Vec<(String, String)> {
                let cfg = self;
                let mut out = Vec::new();
                $(out.extend(law_problems!(cfg, crate::control::$($seg)::+, $settings));)*
                out
            }
        }
    };
}

laws!(law_settings_problems);

fn default_derivative_hz() -> f64 {
    50.0
}

/// Gains whose plausible range is `0 ..= GAIN_HEADROOM × the seed default` (the defaults
/// of [`ControllerConfig::default`], from the seeds): a value outside is refused by
/// `check-config`, at start and on reload, before it can reach a running law.
pub const BOUNDED_GAINS: &[&str] = &[
    "recycle_pi.pi.kp_per_map_flow",
    "recycle_pi.pi.ki_per_map_flow_s",
    "recycle_fl.k_flow_per_s2",
    "recycle_fl.k_flow_rate_per_s",
    "recycle_fl.k_integral_per_s3",
    "drive_torque.k1_nm_s_rad",
    "ccv.x2_gain_nd",
    "ccv.speed_trim_kp_nm_s_per_rad",
    "ccv.speed_trim_ki_nm_per_rad",
    "throttle_backstep.x2_gain_nd",
    "throttle_backstep.xi_gain_nd",
    "throttle_backstep.speed_trim_kp_nm_s_per_rad",
    "throttle_backstep.speed_trim_ki_nm_per_rad",
    "robust.x2_gain_nd",
    "robust.speed_trim_kp_nm_s_per_rad",
    "robust.speed_trim_ki_nm_per_rad",
    "tip_sliding.reaching_gain_per_s",
];

/// Upper bound of a [`BOUNDED_GAINS`] entry, as a multiple of its seed default.
pub const GAIN_HEADROOM: f64 = 100.0;

/// Largest magnitude any other number of `[controller]` may have: no setting of this
/// controller is meaningful at 1e9 in its SI unit, and such values overflow the laws' arithmetic.
pub const ABSURD_MAGNITUDE: f64 = 1.0e9;

fn number_at<'a>(t: &'a toml::Table, dotted: &str) -> Option<f64> {
    let mut cur = t;
    let mut parts = dotted.split('.').peekable();
    while let Some(p) = parts.next() {
        let v: &'a toml::Value = cur.get(p)?;
        if parts.peek().is_none() {
            return v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
        }
        cur = v.as_table()?;
    }
    None
}

fn walk_numbers(prefix: &str, v: &toml::Value, out: &mut Vec<(String, f64)>) {
    match v {
        toml::Value::Float(x) => out.push((prefix.to_string(), *x)),
        toml::Value::Integer(i) => out.push((prefix.to_string(), *i as f64)),
        toml::Value::Table(t) => {
            for (k, v) in t {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                walk_numbers(&key, v, out);
            }
        }
        toml::Value::Array(a) => {
            for (i, v) in a.iter().enumerate() {
                walk_numbers(&format!("{prefix}[{i}]"), v, out);
            }
        }
        _ => {}
    }
}

impl ControllerConfig {
    /// Plausibility of the settings (issue 12, item 4): every [`BOUNDED_GAINS`] entry within
    /// `0 ..= GAIN_HEADROOM × default`, no number beyond [`ABSURD_MAGNITUDE`], and recycle-pi
    /// not with both gains 0 (a law that never moves the valve). Returns `(key, message)`
    /// with the key relative to `[controller]`.
    pub fn plausibility_problems(&self) -> Vec<(String, String)> {
        let mut out = Vec::new();
        let (Ok(mine), Ok(defaults)) = (
            toml::Table::try_from(self),
            toml::Table::try_from(ControllerConfig::default()),
        ) else {
            return out;
        };
        for key in BOUNDED_GAINS {
            let (Some(v), Some(d)) = (number_at(&mine, key), number_at(&defaults, key)) else {
                continue;
            };
            let max = GAIN_HEADROOM * d.abs();
            if !(v.is_finite() && v >= 0.0 && (d == 0.0 || v <= max)) {
                out.push((
                    key.to_string(),
                    format!(
                        "{v} is outside the plausible range 0 … {max} ({GAIN_HEADROOM} × the seed default {d})"
                    ),
                ));
            }
        }
        let mut numbers = Vec::new();
        walk_numbers("", &toml::Value::Table(mine), &mut numbers);
        for (key, v) in numbers {
            if v.abs() > ABSURD_MAGNITUDE && !out.iter().any(|(k, _)| *k == key) {
                out.push((
                    key,
                    format!("{v} is beyond ±{ABSURD_MAGNITUDE:e}: not a plausible setting"),
                ));
            }
        }
        for p in self.drift_check.problems() {
            if !out.iter().any(|(k, _)| *k == p.0) {
                out.push(p);
            }
        }
        // each law's own checks (recycle-pi: not both gains 0)
        out.extend(self.law_settings_problems());
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_defaults_are_plausible() {
        assert!(ControllerConfig::default()
            .plausibility_problems()
            .is_empty());
    }

    #[test]
    fn absurd_and_zero_gains_are_refused() {
        let mut c = ControllerConfig::default();
        c.recycle_pi.pi.kp_per_map_flow = 1e308;
        let p = c.plausibility_problems();
        assert_eq!(p.len(), 1, "{p:?}");
        assert_eq!(p[0].0, "recycle_pi.pi.kp_per_map_flow");
        assert!(p[0].1.contains("plausible range"), "{p:?}");

        let mut c = ControllerConfig::default();
        c.recycle_pi.pi.kp = 0.0;
        c.recycle_pi.pi.ki_per_s = 0.0;
        let p = c.plausibility_problems();
        assert!(p.iter().any(|(_, m)| m.contains("both 0")), "{p:?}");

        let c = ControllerConfig {
            derivative_filter_hz: 1e12,
            ..ControllerConfig::default()
        };
        let p = c.plausibility_problems();
        assert_eq!(p[0].0, "derivative_filter_hz", "{p:?}");
    }
}
