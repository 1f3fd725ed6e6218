//! Range sanity from the physics (issue 25, item 5).
//!
//! - **Pressure ranges in the wrong unit.** `[inputs.p_suction]` / `[inputs.p_discharge]`
//!   ranges (and a machine file's transmitter ranges) are in Pa absolute. A range that
//!   excludes the machine's suction or discharge pressure, and would include it read in bar,
//!   kPa, MPa or psi, is an error naming that unit: every reading would be refused and the
//!   controller would hold fail-safe with the recycle valve open (issue 25: `min = 1,
//!   max = 120` for bar reached fail-safe 264 ms after a reload). The machine's pressures
//!   are its design point when the machine file states one, else the plant's (the recycle
//!   header, or ambient for the other configurations) with the design pressure ratio.
//! - **Percent or fraction.** A valve opening (command or position) is a fraction 0–1. A
//!   Modbus binding of one without `unit` is refused when its raw range could hold the
//!   opening in percent too (`u16` with `scale = 0.01`: 2000 is 20 % or 0.2 %?): the map
//!   must say `unit = "%"` or `unit = "fraction"`. A scale that fits only one reading
//!   (`u16`, `scale = 1e-4`: 10 000 = fully open) is taken as a fraction.

use super::{locate, Loaded, Problem};
use crate::io::modbus::{DataType, RegisterBinding};
use crate::io::signal_map::Binding;
use crate::io::units::Quantity;
use crate::vocab::signals::SensorId;

/// Units a pressure range may have been typed in, with their size in Pa.
pub const PRESSURE_UNITS: [(&str, f64); 4] =
    [("bar", 1e5), ("kPa", 1e3), ("MPa", 1e6), ("psi", 6894.757)];

/// The machine's (suction, discharge) pressure, Pa absolute: the design point if stated,
/// else the plant's pressures with the design ratio.
pub fn machine_pressures(l: &Loaded) -> Option<(f64, f64)> {
    let m = &l.model;
    let p_s = m.design_suction_pressure_pa.or_else(|| {
        if let Some(r) = &m.recycle {
            Some(r.downstream_pressure_pa)
        } else if let Some(p) = &m.plenum_duct {
            Some(p.ambient_pressure_pa)
        } else if let Some(t) = &m.tip {
            Some(t.ambient_pressure_pa)
        } else {
            m.spool.as_ref().map(|s| s.ambient_pressure_pa)
        }
    })?;
    let ratio = m.design_pressure_ratio;
    (p_s.is_finite() && p_s > 0.0 && ratio.is_finite() && ratio > 0.0).then_some((p_s, p_s * ratio))
}

/// The units in which `[min, max]` would hold `v` Pa when it does not hold it in Pa.
pub fn likely_units(min: f64, max: f64, v: f64) -> Vec<&'static str> {
    if min <= v && v <= max {
        return Vec::new();
    }
    PRESSURE_UNITS
        .iter()
        .filter(|(_, f)| min * f <= v && v <= max * f)
        .map(|(u, _)| *u)
        .collect()
}

/// Pressure ranges that look typed in another unit than Pa (errors).
pub fn pressure_ranges(l: &Loaded) -> Vec<Problem> {
    let mut out = Vec::new();
    let Some((p_s, p_d)) = machine_pressures(l) else {
        return out;
    };
    for (id, v, what) in [
        (SensorId::PSuction, p_s, "suction"),
        (SensorId::PDischarge, p_d, "discharge"),
    ] {
        let Some(s) = l.config.inputs.get(&id) else {
            continue;
        };
        let units = likely_units(s.min, s.max, v);
        let Some(first) = units.first() else {
            continue;
        };
        let factor = PRESSURE_UNITS
            .iter()
            .find(|(u, _)| u == first)
            .map_or(1.0, |(_, f)| *f);
        let mut e = locate(
            &l.layers,
            &format!("inputs.{}.max", id.name()),
            format!(
                "range [{}, {}] looks typed in {}: in Pa it excludes the machine's {what} pressure of {v:.4e} Pa, so every reading would be refused and the controller would hold fail-safe (recycle valve open)",
                s.min,
                s.max,
                units.join(" or "),
            ),
        );
        e.hint = Some(format!(
            "ranges are in Pa absolute: in {first} that is min = {:e}, max = {:e}",
            s.min * factor,
            s.max * factor
        ));
        out.push(Problem::error(e));
    }
    out
}

/// The largest raw value a data type holds.
fn raw_max(t: DataType) -> f64 {
    match t {
        DataType::U16 => 65535.0,
        DataType::I16 => 32767.0,
        DataType::U32 => 4_294_967_295.0,
        DataType::I32 => 2_147_483_647.0,
        DataType::U64 | DataType::I64 | DataType::F32 | DataType::F64 => f64::MAX,
        DataType::Bool => 1.0,
    }
}

/// Whether a fraction binding without a unit could as well be in percent: fully open (100 %)
/// fits the raw type at this scale.
pub fn percent_or_fraction(r: &RegisterBinding) -> bool {
    r.unit.is_none()
        && r.data_type != DataType::Bool
        && r.scale != 0.0
        && ((100.0 - r.offset) / r.scale).abs() <= raw_max(r.data_type)
}

/// Valve openings bound without a unit where percent and fraction both fit (errors).
pub fn fraction_bindings(l: &Loaded) -> Vec<Problem> {
    let map = &l.signal_map;
    let sensors = map.sensors.iter().filter_map(|(id, b)| match b {
        Binding::Modbus(r) if Quantity::of_sensor(*id) == Quantity::Fraction => {
            Some((format!("sensors.{}.modbus", id.name()), id.name(), r))
        }
        _ => None,
    });
    let actuators = map.actuators.iter().filter_map(|(id, b)| match b {
        Binding::Modbus(r) if Quantity::of_actuator(*id) == Quantity::Fraction => {
            Some((format!("actuators.{}.modbus", id.name()), id.name(), r))
        }
        _ => None,
    });
    sensors
        .chain(actuators)
        .filter(|(_, _, r)| percent_or_fraction(r))
        .map(|(key, name, r)| {
            let raw = 0.2 / r.scale;
            let mut e = super::cross::map_error(
                l,
                &key,
                format!(
                    "`{name}` is a valve opening bound as {:?} with scale = {} and no unit: is it in percent or a fraction? 20 % open would be written as {raw} (the device reads {} % if it counts in percent)",
                    r.data_type,
                    r.scale,
                    raw * r.scale,
                ),
            );
            e.hint = Some(format!(
                "say which: unit = \"%\" (raw × {} is percent) or unit = \"fraction\" (raw × {} is 0–1)",
                r.scale, r.scale
            ));
            Problem::error(e)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::modbus::RegisterTable;

    #[test]
    fn a_range_in_bar_is_named() {
        // issue 25: p_discharge typed in bar
        assert_eq!(likely_units(1.0, 120.0, 4.0e6), ["bar", "MPa"]);
        assert!(likely_units(1e4, 1.2e7, 4.0e6).is_empty());
        assert_eq!(likely_units(10.0, 1200.0, 4.0e5), ["kPa", "psi"]);
        assert!(
            likely_units(1e9, 2e9, 4.0e5).is_empty(),
            "no unit explains it"
        );
    }

    #[test]
    fn percent_and_fraction_both_fitting_need_a_unit() {
        let mut b = RegisterBinding::new(1, RegisterTable::Holding, 0, DataType::U16);
        b.scale = 0.01;
        assert!(percent_or_fraction(&b), "2000 is 20 % or 0.2 %");
        b.scale = 1e-4;
        assert!(
            !percent_or_fraction(&b),
            "10 000 = fully open; 100 % would not fit"
        );
        b.scale = 0.01;
        b.unit = Some("%");
        assert!(!percent_or_fraction(&b));
        let f = RegisterBinding::new(1, RegisterTable::Holding, 0, DataType::F32);
        assert!(percent_or_fraction(&f), "a float holds either");
    }
}
