//! The plant file schema (`config/plants/*.toml`): one benchmark machine, every parameter with
//! its source in a comment in the file itself.

use crate::config::FileError;
use crate::machine::{DesignPoint, FailPosition, MachineDescription, RecycleValve};
use crate::physics::characteristic::MooreGreitzerCubic;
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;
use crate::physics::shaft::Shaft;
use crate::solver::StepSettings;
// The machine's parameters live in the machine description; the plant file embeds them.
pub use crate::machine::params::{
    DriveSpec, FeedSpec, ModelKind, PlenumDuctParams, RecycleParams, SpoolParams, ThrustRating,
    TipClearanceParams,
};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// How the compressor map is given.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum MapSpec {
    /// Moore–Greitzer cubic with fan-law speed scaling (seed 001 eq. 2.10).
    Cubic {
        /// Shut-off pressure ratio ψc0 at the reference speed.
        psi_c0: f64,
        /// Semi-height H.
        semi_height: f64,
        /// Semi-width W in flow units (kg/s or m³/s).
        semi_width: f64,
        /// Reference speed, rad/s.
        omega_ref_rad_s: f64,
        /// Flow coordinate of W.
        flow_coordinate: FlowCoordinate,
        /// Speed range over which the surge line is tabulated, rad/s.
        omega_range_rad_s: [f64; 2],
    },
    /// Speed-line points in a CSV file, fitted by least squares (seed 001 eq. 2.11,
    /// seed 002 App. A).
    Table {
        /// CSV file, relative to the plant file.
        file: PathBuf,
    },
}

/// Initial conditions: the sim starts from the steady state for these inputs.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InitialSpec {
    /// Throttle opening, fraction.
    pub throttle: f64,
    /// Recycle valve opening, fraction (recycle plants).
    #[serde(default)]
    pub recycle_valve: f64,
    /// Feed scale (fraction of nominal feed or feed-valve opening).
    #[serde(default = "one")]
    pub feed: f64,
}

fn one() -> f64 {
    1.0
}

/// A benchmark plant file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantFile {
    /// Short name (used in file names and summary.json).
    pub name: String,
    /// One-line description.
    pub description: String,
    /// Seed and section this plant reproduces.
    pub source: String,
    /// Which dynamic model.
    pub model: ModelKind,
    /// Gas properties.
    pub gas: Gas,
    /// Compressor map.
    pub map: MapSpec,
    /// Shaft (not used by the constant-speed tip-clearance plant's dynamics, but by its load
    /// torque figure).
    pub shaft: Shaft,
    /// The drive.
    pub drive: DriveSpec,
    /// Suction flow element.
    pub orifice: Orifice,
    /// Plenum/duct parameters (model = plenum_duct).
    #[serde(default)]
    pub plenum_duct: Option<PlenumDuctParams>,
    /// Recycle system parameters (model = recycle_system).
    #[serde(default)]
    pub recycle_system: Option<RecycleParams>,
    /// Tip-clearance plant parameters (model = tip_clearance).
    #[serde(default)]
    pub tip_clearance: Option<TipClearanceParams>,
    /// Spool model parameters (model = spool).
    #[serde(default)]
    pub spool: Option<SpoolParams>,
    /// Thrust bearing rating (tip-clearance plants).
    #[serde(default)]
    pub thrust_rating: Option<ThrustRating>,
    /// Initial inputs.
    pub initial: InitialSpec,
    /// Fixed-step integration for real time.
    #[serde(default)]
    pub integration: StepSettings,
    /// Controller settings tuned for this machine (defaults for the daemon's config).
    #[serde(default)]
    pub controller: crate::control::ControllerConfig,
}

/// A loaded plant file: the parsed content, its path and the built compressor map.
#[derive(Debug, Clone)]
pub struct PlantDescription {
    /// Parsed file.
    pub file: PlantFile,
    /// Where it came from.
    pub path: PathBuf,
    /// The compressor map (fitted or analytic) with its surge line.
    pub map: CompressorMap,
}

impl PlantDescription {
    /// Load and validate a plant file; errors name file, key and line.
    pub fn load(path: &Path) -> Result<PlantDescription, FileError> {
        let (file, text): (PlantFile, String) = crate::config::toml_file::load(path)?;
        Self::from_file(file, path, &text)
    }

    /// Parse and validate plant-file `text` already in memory; `path` names it in messages
    /// and places a relative map table. Same checks as [`load`](Self::load) (the fuzz
    /// target `plant_file` parses from memory through here).
    pub fn from_text(text: &str, path: &Path) -> Result<PlantDescription, FileError> {
        let file: PlantFile = crate::config::toml_file::parse(text, path)?;
        Self::from_file(file, path, text)
    }

    fn from_file(file: PlantFile, path: &Path, text: &str) -> Result<PlantDescription, FileError> {
        let at = |key: &str, msg: String| FileError::at_key(path, text, key, msg);
        let section_present = match file.model {
            ModelKind::PlenumDuct => file.plenum_duct.is_some(),
            ModelKind::RecycleSystem => file.recycle_system.is_some(),
            ModelKind::TipClearance => file.tip_clearance.is_some(),
            ModelKind::Spool => file.spool.is_some(),
        };
        if !section_present {
            let section = match file.model {
                ModelKind::PlenumDuct => "plenum_duct",
                ModelKind::RecycleSystem => "recycle_system",
                ModelKind::TipClearance => "tip_clearance",
                ModelKind::Spool => "spool",
            };
            return Err(at(
                "model",
                format!("model is `{section}` but the [{section}] section is missing"),
            )
            .with_hint(format!("add a [{section}] table")));
        }
        if file.model == ModelKind::TipClearance && file.thrust_rating.is_none() {
            return Err(at(
                "model",
                "a tip-clearance plant needs a [thrust_rating] table".into(),
            ));
        }
        validate_positive(&file, &at)?;
        let map = match &file.map {
            MapSpec::Cubic { .. } if file.model == ModelKind::Spool => {
                // the spool model's cubic is nondimensional: its SI image is the map
                let Some(sp) = &file.spool else {
                    unreachable!("section presence checked above")
                };
                let MapSpec::Cubic {
                    psi_c0,
                    semi_height,
                    semi_width,
                    omega_ref_rad_s,
                    ..
                } = file.map
                else {
                    unreachable!()
                };
                let c = MooreGreitzerCubic {
                    psi_c0,
                    semi_height,
                    semi_width,
                    omega_ref: omega_ref_rad_s,
                };
                crate::plant::spool::si_map(&c, sp).map_err(|m| at("map.cubic", m))?
            }
            MapSpec::Cubic {
                psi_c0,
                semi_height,
                semi_width,
                omega_ref_rad_s,
                flow_coordinate,
                omega_range_rad_s,
            } => CompressorMap::cubic(
                MooreGreitzerCubic {
                    psi_c0: *psi_c0,
                    semi_height: *semi_height,
                    semi_width: *semi_width,
                    omega_ref: *omega_ref_rad_s,
                },
                *flow_coordinate,
                omega_range_rad_s[0],
                omega_range_rad_s[1],
            )
            .map_err(|m| at("map.cubic", m))?,
            MapSpec::Table { file: csv } => {
                let csv_path = path.parent().unwrap_or(Path::new(".")).join(csv);
                CompressorMap::from_csv(&csv_path)
                    .map_err(|e| at("map.table.file", e.to_string()))?
            }
        };
        Ok(PlantDescription {
            file,
            path: path.to_path_buf(),
            map,
        })
    }

    /// The machine description this plant file yields: the same type a vendor machine file
    /// gives, with the speed-line map (the SLL derived from it) and the model family's data.
    /// The simulator's machine is one the controller knows fully; the controller gets it only
    /// through this description.
    pub fn machine(&self) -> MachineDescription {
        let f = &self.file;
        let t_s = f
            .plenum_duct
            .map(|p| p.ambient_temperature_k)
            .or(f.recycle_system.map(|r| r.suction_temperature_k))
            .or(f.tip_clearance.map(|t| t.ambient_temperature_k))
            .or(f.spool.map(|s| s.ambient_temperature_k))
            .unwrap_or(293.15);
        let p_s = f
            .plenum_duct
            .map(|p| p.ambient_pressure_pa)
            .or(f.tip_clearance.map(|t| t.ambient_pressure_pa))
            .or(f.spool.map(|s| s.ambient_pressure_pa));
        MachineDescription {
            name: f.name.clone(),
            family: Some(f.model),
            gas: f.gas,
            flow_element: f.orifice,
            flow_coordinate: self.map.flow_coordinate,
            surge_line: self.map.surge_line,
            reference_suction_temperature_k: t_s,
            map: Some(self.map),
            design: p_s.map(|p| DesignPoint {
                suction_pressure_pa: p,
                suction_temperature_k: t_s,
                pressure_ratio: None,
                speed_rad_s: Some(f.drive.nominal_speed_rad_s),
            }),
            transmitters: Default::default(),
            recycle_valve: f.recycle_system.map(|r| RecycleValve {
                spec: r.recycle_valve,
                fail_position: FailPosition::Open,
            }),
            drive: Some(f.drive),
            // the benchmark plants' drives have no governor of their own: the controller's
            // speed loop is their governor (seed 000 eq. 7, seed 002 eq. 3.7)
            owns_drive_speed_loop: true,
            shaft: Some(f.shaft),
            plenum_duct: f.plenum_duct,
            recycle: f.recycle_system,
            tip: f.tip_clearance,
            thrust: f.thrust_rating,
            spool: f.spool,
        }
    }

    /// Short name.
    pub fn name(&self) -> &str {
        &self.file.name
    }
}

fn validate_positive(
    file: &PlantFile,
    at: &dyn Fn(&str, String) -> FileError,
) -> Result<(), FileError> {
    let mut checks: Vec<(&str, f64)> = vec![
        ("gas.molar_mass_kg_mol", file.gas.molar_mass_kg_mol),
        (
            "gas.heat_capacity_ratio",
            file.gas.heat_capacity_ratio - 1.0,
        ),
        ("gas.polytropic_exponent", file.gas.polytropic_exponent),
        ("shaft.inertia_kg_m2", file.shaft.inertia_kg_m2),
        ("shaft.impeller_radius_m", file.shaft.impeller_radius_m),
        ("drive.rated_torque_nm", file.drive.rated_torque_nm),
        ("drive.nominal_speed_rad_s", file.drive.nominal_speed_rad_s),
        ("orifice.bore_diameter_m", file.orifice.bore_diameter_m),
        ("orifice.flow_coefficient", file.orifice.flow_coefficient),
    ];
    if let Some(p) = &file.plenum_duct {
        checks.extend([
            ("plenum_duct.plenum_volume_m3", p.plenum_volume_m3),
            ("plenum_duct.duct_area_m2", p.duct_area_m2),
            ("plenum_duct.duct_length_m", p.duct_length_m),
            ("plenum_duct.sonic_velocity_m_s", p.sonic_velocity_m_s),
            ("plenum_duct.ambient_pressure_pa", p.ambient_pressure_pa),
            ("plenum_duct.throttle.cv_max_m2", p.throttle.cv_max_m2),
        ]);
    }
    if let Some(r) = &file.recycle_system {
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
    if let Some(t) = &file.tip_clearance {
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
    if let Some(s) = &file.spool {
        checks.extend([
            ("spool.a_bar", s.a_bar),
            ("spool.b_bar", s.b_bar),
            ("spool.c_bar", s.c_bar),
            ("spool.time_scale_s", s.time_scale_s),
            ("spool.gamma_max", s.gamma_max),
        ]);
    }
    for (key, v) in checks {
        if v.is_nan() || v <= 0.0 || !v.is_finite() {
            return Err(at(key, format!("must be a positive number, found {v}"))
                .with_hint("physical sizes, gains and ratings are positive"));
        }
    }
    Ok(())
}
