//! The dynamic model data of a machine: what the model-based laws (drive-torque, ccv,
//! throttle-backstep, robust, tip-sliding, recycle-fl) read besides the surge line. A machine
//! file gives it as `[model]` (`family` plus one table per datum, SI units with the unit in
//! the key); a simulation plant file gives the same tables at its top level. Both go through
//! [`ModelData::check`] and [`super::MachineDescription::with_model`]: one way in.
//!
//! The speed-line map the model-based laws evaluate is built here too ([`MapSpec::build`]),
//! from a CSV of speed-line points or a Moore–Greitzer cubic.

use super::params::{
    ModelKind, PlenumDuctParams, RecycleParams, SpoolParams, ThrustRating, TipClearanceParams,
};
use crate::physics::characteristic::MooreGreitzerCubic;
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use crate::physics::shaft::Shaft;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// How the speed-line map is given.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum MapSpec {
    /// Moore–Greitzer cubic with fan-law speed scaling (seed 001 eq. 2.10).
    Cubic {
        /// Shut-off pressure ratio ψc0 at the reference speed (spool family: nondimensional).
        psi_c0: f64,
        /// Semi-height H.
        semi_height: f64,
        /// Semi-width W in flow units (kg/s or m³/s; spool family: φ).
        semi_width: f64,
        /// Reference speed, rad/s.
        omega_ref_rad_s: f64,
        /// Flow coordinate of W.
        flow_coordinate: FlowCoordinate,
        /// Speed range over which the surge line is tabulated, rad/s.
        omega_range_rad_s: [f64; 2],
    },
    /// Speed-line points in a CSV file, fitted by least squares (seed 001 eq. 2.11,
    /// seed 002 App. A); relative to the file that names it.
    Table {
        /// CSV file.
        file: PathBuf,
    },
}

impl MapSpec {
    /// Build the map; `base` is the directory of the file naming it. The spool family's cubic
    /// is nondimensional (seed 003 eq. 4–6): its SI image through the spool scales is the map.
    /// Errors: (key below the map's table, message).
    pub fn build(
        &self,
        base: &Path,
        spool: Option<&SpoolParams>,
    ) -> Result<CompressorMap, (&'static str, String)> {
        match self {
            MapSpec::Cubic {
                psi_c0,
                semi_height,
                semi_width,
                omega_ref_rad_s,
                flow_coordinate,
                omega_range_rad_s,
            } => {
                let cubic = MooreGreitzerCubic {
                    psi_c0: *psi_c0,
                    semi_height: *semi_height,
                    semi_width: *semi_width,
                    omega_ref: *omega_ref_rad_s,
                };
                match spool {
                    Some(sp) => sp.si_map(&cubic),
                    None => CompressorMap::cubic(
                        cubic,
                        *flow_coordinate,
                        omega_range_rad_s[0],
                        omega_range_rad_s[1],
                    ),
                }
                .map_err(|m| ("cubic", m))
            }
            MapSpec::Table { file } => {
                CompressorMap::from_csv(&base.join(file)).map_err(|e| ("table.file", e.to_string()))
            }
        }
    }
}

/// The model data of one family (a machine file's `[model]`; a plant file's top-level tables).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelData {
    /// The model family the data describe (the model-based law is written for it).
    pub family: ModelKind,
    /// Rotor data (plenum/duct family: the torque balance of seed 000 eq. 1c).
    #[serde(default)]
    pub shaft: Option<Shaft>,
    /// Plenum/duct data (seed 000 eq. 1).
    #[serde(default)]
    pub plenum_duct: Option<PlenumDuctParams>,
    /// Recycle-system data (seed 002 eq. 3.18, seed 001 eq. 2.26–2.27).
    #[serde(default)]
    pub recycle_system: Option<RecycleParams>,
    /// Tip-clearance data (seed 004 eq. 2–4).
    #[serde(default)]
    pub tip_clearance: Option<TipClearanceParams>,
    /// Thrust-bearing rating (seed 004).
    #[serde(default)]
    pub thrust_rating: Option<ThrustRating>,
    /// Spool data (seed 003 eq. 4–6).
    #[serde(default)]
    pub spool: Option<SpoolParams>,
}

/// A problem with model data: the key (below the model's table) and what is wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelProblem {
    /// Key path below the model table (`plenum_duct.duct_length_m`, `shaft`).
    pub key: String,
    /// What is wrong.
    pub message: String,
    /// How to fix it.
    pub hint: String,
}

impl ModelKind {
    /// The tables a family's model data must have, by key below the model table.
    pub fn required_tables(self) -> &'static [&'static str] {
        match self {
            ModelKind::PlenumDuct => &["plenum_duct", "shaft"],
            ModelKind::RecycleSystem => &["recycle_system"],
            ModelKind::TipClearance => &["tip_clearance", "thrust_rating"],
            ModelKind::Spool => &["spool"],
        }
    }

    /// The family's name in files (`plenum_duct`, …).
    pub fn key(self) -> &'static str {
        match self {
            ModelKind::PlenumDuct => "plenum_duct",
            ModelKind::RecycleSystem => "recycle_system",
            ModelKind::TipClearance => "tip_clearance",
            ModelKind::Spool => "spool",
        }
    }
}

impl ModelData {
    fn has_table(&self, table: &str) -> bool {
        match table {
            "shaft" => self.shaft.is_some(),
            "plenum_duct" => self.plenum_duct.is_some(),
            "recycle_system" => self.recycle_system.is_some(),
            "tip_clearance" => self.tip_clearance.is_some(),
            "thrust_rating" => self.thrust_rating.is_some(),
            "spool" => self.spool.is_some(),
            _ => false,
        }
    }

    /// Every table the family needs is there and every size, gain and rating is positive.
    /// `prefix` is where the tables live in the file (`"model."` in a machine file, `""` in a
    /// plant file), for the message.
    pub fn check(&self, prefix: &str) -> Result<(), ModelProblem> {
        if let Some(t) = self
            .family
            .required_tables()
            .iter()
            .find(|t| !self.has_table(t))
        {
            return Err(ModelProblem {
                key: (*t).to_string(),
                message: format!(
                    "the {} model needs the [{prefix}{t}] table, which is missing",
                    self.family.key()
                ),
                hint: format!(
                    "add a [{prefix}{t}] table (config/machines/bohagen2007_model.toml shows the plenum/duct family's keys)"
                ),
            });
        }
        let mut checks: Vec<(&str, f64)> = Vec::new();
        if let Some(s) = &self.shaft {
            checks.extend([
                ("shaft.inertia_kg_m2", s.inertia_kg_m2),
                ("shaft.impeller_radius_m", s.impeller_radius_m),
            ]);
        }
        if let Some(p) = &self.plenum_duct {
            checks.extend([
                ("plenum_duct.plenum_volume_m3", p.plenum_volume_m3),
                ("plenum_duct.duct_area_m2", p.duct_area_m2),
                ("plenum_duct.duct_length_m", p.duct_length_m),
                ("plenum_duct.sonic_velocity_m_s", p.sonic_velocity_m_s),
                ("plenum_duct.ambient_pressure_pa", p.ambient_pressure_pa),
                ("plenum_duct.throttle.cv_max_m2", p.throttle.cv_max_m2),
            ]);
        }
        if let Some(r) = &self.recycle_system {
            checks.extend([
                ("recycle_system.suction_volume_m3", r.suction_volume_m3),
                ("recycle_system.discharge_volume_m3", r.discharge_volume_m3),
                (
                    "recycle_system.compressor_duct_area_m2",
                    r.compressor_duct_area_m2,
                ),
                (
                    "recycle_system.compressor_duct_length_m",
                    r.compressor_duct_length_m,
                ),
                (
                    "recycle_system.recycle_duct_area_m2",
                    r.recycle_duct_area_m2,
                ),
                (
                    "recycle_system.recycle_duct_length_m",
                    r.recycle_duct_length_m,
                ),
                (
                    "recycle_system.discharge_duct_area_m2",
                    r.discharge_duct_area_m2,
                ),
                (
                    "recycle_system.discharge_duct_length_m",
                    r.discharge_duct_length_m,
                ),
                (
                    "recycle_system.downstream_pressure_pa",
                    r.downstream_pressure_pa,
                ),
                (
                    "recycle_system.recycle_valve.cv_max_m2",
                    r.recycle_valve.cv_max_m2,
                ),
                ("recycle_system.throttle.cv_max_m2", r.throttle.cv_max_m2),
            ]);
        }
        if let Some(t) = &self.tip_clearance {
            checks.extend([
                ("tip_clearance.plenum_volume_m3", t.plenum_volume_m3),
                ("tip_clearance.duct_area_m2", t.duct_area_m2),
                ("tip_clearance.duct_length_m", t.duct_length_m),
                (
                    "tip_clearance.effect.blade_height_m",
                    t.effect.blade_height_m,
                ),
                ("tip_clearance.servo.bandwidth_hz", t.servo.bandwidth_hz),
            ]);
        }
        if let Some(s) = &self.spool {
            checks.extend([
                ("spool.a_bar", s.a_bar),
                ("spool.b_bar", s.b_bar),
                ("spool.c_bar", s.c_bar),
                ("spool.time_scale_s", s.time_scale_s),
                ("spool.gamma_max", s.gamma_max),
            ]);
        }
        for (key, v) in checks {
            if !(v.is_finite() && v > 0.0) {
                return Err(ModelProblem {
                    key: key.to_string(),
                    message: format!("must be a positive number, found {v}"),
                    hint: "physical sizes, gains and ratings are positive".into(),
                });
            }
        }
        Ok(())
    }

    /// Suction conditions the model states (ambient of a plenum, tip or spool model; the
    /// suction temperature of a recycle system): (pressure if stated, Pa; temperature, K).
    pub fn suction_conditions(&self) -> (Option<f64>, Option<f64>) {
        let t = self
            .plenum_duct
            .map(|p| p.ambient_temperature_k)
            .or(self.recycle_system.map(|r| r.suction_temperature_k))
            .or(self.tip_clearance.map(|t| t.ambient_temperature_k))
            .or(self.spool.map(|s| s.ambient_temperature_k));
        let p = self
            .plenum_duct
            .map(|p| p.ambient_pressure_pa)
            .or(self.tip_clearance.map(|t| t.ambient_pressure_pa))
            .or(self.spool.map(|s| s.ambient_pressure_pa));
        (p, t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_family_without_its_table_names_the_missing_key() {
        let m = ModelData {
            family: ModelKind::TipClearance,
            shaft: None,
            plenum_duct: None,
            recycle_system: None,
            tip_clearance: None,
            thrust_rating: Some(ThrustRating::default()),
            spool: None,
        };
        let e = m.check("model.").unwrap_err();
        assert_eq!(e.key, "tip_clearance");
        assert!(
            e.message
                .contains("tip_clearance model needs the [model.tip_clearance] table"),
            "{e:?}"
        );
        let m = ModelData {
            family: ModelKind::Spool,
            ..m
        };
        assert_eq!(m.check("").unwrap_err().key, "spool");
    }
}
