//! Engineering units of field devices, converted to the SI quantity of each signal.
//!
//! A binding (Modbus register or DBC signal) declares the unit its physical value is in
//! (`%`, `bar`, `kPa`, `psi`, `rpm`, `degC` …). The signal map checks it against the
//! quantity of the sensor or actuator it is bound to and folds the conversion into the
//! binding's scale and offset, so the rest of the code only sees SI values:
//!
//! ```text
//! SI = device_value × factor + offset      (e.g. % → fraction: × 0.01; °C → K: + 273.15)
//! ```

use crate::vocab::signals::{ActuatorId, SensorId};
use std::f64::consts::PI;

/// The physical quantity of a signal.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// Pressure, Pa.
    Pressure,
    /// Angular speed, rad/s.
    AngularSpeed,
    /// Temperature, K.
    Temperature,
    /// Fraction 0..1 (valve opening).
    Fraction,
    /// Length, m.
    Length,
    /// Torque, N·m.
    Torque,
    /// Dimensionless (pressure-rise units).
    Dimensionless,
}

impl Quantity {
    /// The quantity of a sensor.
    pub const fn of_sensor(s: SensorId) -> Quantity {
        match s {
            SensorId::PSuction | SensorId::PDischarge | SensorId::OrificeDp => Quantity::Pressure,
            SensorId::ShaftSpeed => Quantity::AngularSpeed,
            SensorId::TSuction => Quantity::Temperature,
            SensorId::RecycleValvePosition | SensorId::ThrottlePosition => Quantity::Fraction,
            SensorId::ThrustPosition => Quantity::Length,
            SensorId::DriveTorque => Quantity::Torque,
            SensorId::EsdInput => Quantity::Dimensionless,
        }
    }

    /// The quantity of an actuator.
    pub const fn of_actuator(a: ActuatorId) -> Quantity {
        match a {
            ActuatorId::DriveTorque => Quantity::Torque,
            ActuatorId::RecycleValve | ActuatorId::Throttle => Quantity::Fraction,
            ActuatorId::CloseCoupledValve => Quantity::Dimensionless,
            ActuatorId::TipClearance => Quantity::Length,
        }
    }

    /// Name, for messages.
    pub const fn name(self) -> &'static str {
        match self {
            Quantity::Pressure => "pressure (Pa)",
            Quantity::AngularSpeed => "angular speed (rad/s)",
            Quantity::Temperature => "temperature (K)",
            Quantity::Fraction => "fraction 0..1",
            Quantity::Length => "length (m)",
            Quantity::Torque => "torque (N·m)",
            Quantity::Dimensionless => "dimensionless",
        }
    }
}

/// A unit: its quantity and the affine map to SI.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Unit {
    /// Quantity measured.
    pub quantity: Quantity,
    /// SI per unit.
    pub factor: f64,
    /// SI value at zero of this unit.
    pub offset: f64,
}

/// Unit names accepted (case-sensitive, as printed in DBCs and manuals), with their meaning.
const UNITS: &[(&str, Quantity, f64, f64)] = &[
    ("Pa", Quantity::Pressure, 1.0, 0.0),
    ("hPa", Quantity::Pressure, 100.0, 0.0),
    ("mbar", Quantity::Pressure, 100.0, 0.0),
    ("kPa", Quantity::Pressure, 1e3, 0.0),
    ("MPa", Quantity::Pressure, 1e6, 0.0),
    ("bar", Quantity::Pressure, 1e5, 0.0),
    ("bara", Quantity::Pressure, 1e5, 0.0),
    ("psi", Quantity::Pressure, 6_894.757_293_168, 0.0),
    ("psia", Quantity::Pressure, 6_894.757_293_168, 0.0),
    ("rad/s", Quantity::AngularSpeed, 1.0, 0.0),
    ("rpm", Quantity::AngularSpeed, 2.0 * PI / 60.0, 0.0),
    ("1/min", Quantity::AngularSpeed, 2.0 * PI / 60.0, 0.0),
    ("Hz", Quantity::AngularSpeed, 2.0 * PI, 0.0),
    ("K", Quantity::Temperature, 1.0, 0.0),
    ("degC", Quantity::Temperature, 1.0, 273.15),
    ("°C", Quantity::Temperature, 1.0, 273.15),
    ("C", Quantity::Temperature, 1.0, 273.15),
    (
        "degF",
        Quantity::Temperature,
        5.0 / 9.0,
        273.15 - 32.0 * 5.0 / 9.0,
    ),
    (
        "°F",
        Quantity::Temperature,
        5.0 / 9.0,
        273.15 - 32.0 * 5.0 / 9.0,
    ),
    ("fraction", Quantity::Fraction, 1.0, 0.0),
    ("%", Quantity::Fraction, 0.01, 0.0),
    ("m", Quantity::Length, 1.0, 0.0),
    ("mm", Quantity::Length, 1e-3, 0.0),
    ("um", Quantity::Length, 1e-6, 0.0),
    ("µm", Quantity::Length, 1e-6, 0.0),
    ("N.m", Quantity::Torque, 1.0, 0.0),
    ("N·m", Quantity::Torque, 1.0, 0.0),
    ("Nm", Quantity::Torque, 1.0, 0.0),
    ("kN.m", Quantity::Torque, 1e3, 0.0),
    ("kNm", Quantity::Torque, 1e3, 0.0),
    ("", Quantity::Dimensionless, 1.0, 0.0),
    ("1", Quantity::Dimensionless, 1.0, 0.0),
    ("-", Quantity::Dimensionless, 1.0, 0.0),
];

impl Unit {
    /// Look a unit up by name (`None`: unknown).
    pub fn parse(name: &str) -> Option<Unit> {
        UNITS
            .iter()
            .find(|(n, ..)| *n == name.trim())
            .map(|&(_, quantity, factor, offset)| Unit {
                quantity,
                factor,
                offset,
            })
    }

    /// The accepted spelling of `name`, as a static string (`None`: unknown).
    pub fn static_name(name: &str) -> Option<&'static str> {
        UNITS
            .iter()
            .find(|(n, ..)| *n == name.trim())
            .map(|(n, ..)| *n)
    }

    /// Every accepted name, for hints.
    pub fn names() -> String {
        UNITS
            .iter()
            .filter(|(n, ..)| !n.is_empty())
            .map(|(n, ..)| *n)
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// Convert a value in this unit to SI.
    pub fn to_si(&self, v: f64) -> f64 {
        v * self.factor + self.offset
    }
}

/// Why a declared unit cannot be used for a signal.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UnitError {
    /// The unit is not known.
    #[error("unknown unit \"{unit}\" (known: {known})")]
    Unknown {
        /// As written.
        unit: String,
        /// The accepted names.
        known: String,
    },
    /// The unit measures another quantity than the signal.
    #[error("unit \"{unit}\" is a {found}, but the signal is a {expected}")]
    Mismatch {
        /// As written.
        unit: String,
        /// What the unit measures.
        found: &'static str,
        /// What the signal needs.
        expected: &'static str,
    },
}

/// Check `unit` against `quantity`: the conversion to SI, or why not. A dimensionless unit
/// (`""`) is accepted for a fraction (the DBC convention for ratios) as the SI fraction.
pub fn resolve(unit: &str, quantity: Quantity) -> Result<Unit, UnitError> {
    let u = Unit::parse(unit).ok_or_else(|| UnitError::Unknown {
        unit: unit.to_string(),
        known: Unit::names(),
    })?;
    let ok = u.quantity == quantity
        || (u.quantity == Quantity::Dimensionless && quantity == Quantity::Fraction);
    if !ok {
        return Err(UnitError::Mismatch {
            unit: unit.to_string(),
            found: u.quantity.name(),
            expected: quantity.name(),
        });
    }
    Ok(u)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conversions() {
        let q = |u: &str, quantity, v: f64| resolve(u, quantity).unwrap().to_si(v);
        assert_eq!(q("%", Quantity::Fraction, 37.5), 0.375);
        assert_eq!(q("bar", Quantity::Pressure, 1.2), 120_000.0);
        assert_eq!(q("kPa", Quantity::Pressure, 101.325), 101_325.0);
        assert!((q("psi", Quantity::Pressure, 14.5038) - 100_000.0).abs() < 1.0);
        assert!((q("rpm", Quantity::AngularSpeed, 60.0) - 2.0 * PI).abs() < 1e-12);
        assert!((q("degC", Quantity::Temperature, 20.0) - 293.15).abs() < 1e-9);
        assert!((q("degF", Quantity::Temperature, 212.0) - 373.15).abs() < 1e-9);
        assert_eq!(q("N.m", Quantity::Torque, 5.0), 5.0);
    }

    #[test]
    fn mismatch_and_unknown() {
        let e = resolve("bar", Quantity::Fraction).unwrap_err();
        assert!(e.to_string().contains("pressure"), "{e}");
        assert!(e.to_string().contains("fraction"), "{e}");
        let e = resolve("furlong", Quantity::Length).unwrap_err();
        assert!(matches!(e, UnitError::Unknown { .. }), "{e}");
        assert!(resolve("", Quantity::Fraction).is_ok());
        assert!(resolve("", Quantity::Pressure).is_err());
    }
}
