//! The plant file schema (`config/plants/*.toml`): one benchmark machine, every parameter with
//! its source in a comment in the file itself.

use crate::config::FileError;
use crate::machine::{DesignPoint, FailPosition, MachineDescription, RecycleValve};
use crate::physics::compressor_map::CompressorMap;
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

pub use crate::machine::model::{MapSpec, ModelData};

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
    /// The file's `[controller]` table (tuned settings for the controller) is not the plant
    /// models' to read: the simulation layer (`sim::case::PlantCase`) parses it from the same
    /// text. Accepted here unread so the plant schema stays closed to every other key.
    #[serde(default, rename = "controller")]
    controller_table: Option<serde::de::IgnoredAny>,
}

impl PlantFile {
    /// The plant's model data, as a machine file's `[model]` gives them.
    pub fn model_data(&self) -> ModelData {
        ModelData {
            family: self.model,
            shaft: Some(self.shaft),
            plenum_duct: self.plenum_duct,
            recycle_system: self.recycle_system,
            tip_clearance: self.tip_clearance,
            thrust_rating: self.thrust_rating,
            spool: self.spool,
        }
    }
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
    /// Load and validate a plant file; errors name file, key and line. The `[controller]`
    /// table is not checked here: load through `sim::case::PlantCase` to read it.
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

    /// Validate a parsed plant file whose source is `text` (the checks after the schema); the
    /// simulation layer's loader parses the same text once more for `[controller]` in between.
    pub fn from_file(
        file: PlantFile,
        path: &Path,
        text: &str,
    ) -> Result<PlantDescription, FileError> {
        let at = |key: &str, msg: String| FileError::at_key(path, text, key, msg);
        validate_positive(&file, &at)?;
        // the model data: the same check a machine file's [model] goes through
        file.model_data().check("").map_err(|p| {
            let key = if p.key.contains('.') {
                p.key.clone()
            } else {
                "model".to_string()
            };
            let mut e = at(&key, p.message).with_hint(p.hint);
            e.key = key;
            e
        })?;
        let spool = (file.model == ModelKind::Spool)
            .then_some(file.spool.as_ref())
            .flatten();
        let map = file
            .map
            .build(path.parent().unwrap_or(Path::new(".")), spool)
            .map_err(|(k, m)| at(&format!("map.{k}"), m))?;
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
        let model = f.model_data();
        let (p_s, t_s) = model.suction_conditions();
        let t_s = t_s.unwrap_or(293.15);
        MachineDescription {
            name: f.name.clone(),
            family: None,
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
            shaft: None,
            plenum_duct: None,
            recycle: None,
            tip: None,
            thrust: None,
            spool: None,
        }
        .with_model(model)
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
    let checks: Vec<(&str, f64)> = vec![
        ("gas.molar_mass_kg_mol", file.gas.molar_mass_kg_mol),
        (
            "gas.heat_capacity_ratio",
            file.gas.heat_capacity_ratio - 1.0,
        ),
        ("gas.polytropic_exponent", file.gas.polytropic_exponent),
        ("drive.rated_torque_nm", file.drive.rated_torque_nm),
        ("drive.nominal_speed_rad_s", file.drive.nominal_speed_rad_s),
        ("orifice.bore_diameter_m", file.orifice.bore_diameter_m),
        ("orifice.flow_coefficient", file.orifice.flow_coefficient),
    ];
    for (key, v) in checks {
        if v.is_nan() || v <= 0.0 || !v.is_finite() {
            return Err(at(key, format!("must be a positive number, found {v}"))
                .with_hint("physical sizes, gains and ratings are positive"));
        }
    }
    Ok(())
}
