//! A simulation case: a plant file's machine (the plant models' [`PlantDescription`]) paired
//! with the controller settings tuned for it (the same file's `[controller]` table).
//!
//! The plant models never depend on the controller (issue 14, item 3): `plant::file` reads
//! every table except `[controller]`, and this composition layer reads that one from the same
//! text. `sim`, `plant`, `run`, the daemon's `[plant] file` and the benchmarks load plant
//! files through [`PlantCase::load`], so a mistake anywhere in the file, `[controller]`
//! included, is reported with its file, line and key path as before.

use crate::config::toml_file;
use crate::config::FileError;
use crate::control::ControllerConfig;
use crate::plant::file::{PlantDescription, PlantFile};
use serde::Deserialize;
use std::ops::{Deref, DerefMut};
use std::path::Path;

/// A plant file's plant and its tuned controller settings.
///
/// Dereferences to the [`PlantDescription`], so code that builds or inspects the plant takes
/// a `&PlantCase` where it took a plant description; only the composition (sim runner,
/// tables, daemon) reads [`controller`](Self::controller).
#[derive(Debug, Clone)]
pub struct PlantCase {
    /// The simulated machine (plant models' view of the file).
    pub plant: PlantDescription,
    /// The file's `[controller]` table: defaults for the daemon's `[controller]`, tuned for
    /// this machine (the schema's defaults when the table is absent).
    pub controller: ControllerConfig,
}

/// The one table of a plant file that belongs to the controller; every other key is the
/// plant's (checked by [`PlantFile`]'s own `deny_unknown_fields`).
#[derive(Deserialize)]
struct ControllerTable {
    #[serde(default)]
    controller: ControllerConfig,
}

impl PlantCase {
    /// Load and validate a plant file; errors name file, key and line.
    pub fn load(path: &Path) -> Result<PlantCase, FileError> {
        let (file, text): (PlantFile, String) = toml_file::load(path)?;
        Self::from_parsed(file, path, &text)
    }

    /// Parse and validate plant-file `text` already in memory; `path` names it in messages
    /// and places a relative map table (the fuzz target `plant_file` comes through here).
    pub fn from_text(text: &str, path: &Path) -> Result<PlantCase, FileError> {
        let file: PlantFile = toml_file::parse(text, path)?;
        Self::from_parsed(file, path, text)
    }

    /// The plant's schema errors first, then the `[controller]` table's, then the plant's
    /// range checks: the order in which one pass over the whole file reported them.
    fn from_parsed(file: PlantFile, path: &Path, text: &str) -> Result<PlantCase, FileError> {
        let ControllerTable { controller } = toml_file::parse(text, path)?;
        let plant = PlantDescription::from_file(file, path, text)?;
        Ok(PlantCase { plant, controller })
    }

    /// The controller's model of this plant: the machine description the plant file yields
    /// plus its tuned `[controller]` settings.
    pub fn control_model(&self) -> crate::control::model::ControlModel {
        crate::control::model::ControlModel::from_machine(
            &self.plant.machine(),
            self.controller.clone(),
        )
    }
}

impl Deref for PlantCase {
    type Target = PlantDescription;
    fn deref(&self) -> &PlantDescription {
        &self.plant
    }
}

impl DerefMut for PlantCase {
    fn deref_mut(&mut self) -> &mut PlantDescription {
        &mut self.plant
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PLANT: &str = "config/plants/kvangardsnes2009_recycle.toml";

    fn text() -> String {
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(PLANT)).unwrap()
    }

    #[test]
    fn the_controller_table_is_read_here_and_located() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(PLANT);
        let case = PlantCase::load(&path).expect("shipped plant");
        assert_ne!(
            case.controller,
            ControllerConfig::default(),
            "tuned gains read"
        );
        // a typo inside [controller] is located at its line with the full key path
        let t = text();
        let bad = t.replacen(
            "[controller.recycle_pi]\n",
            "[controller.recycle_pi]\nkp_per_map_flw = 1.0\n",
            1,
        );
        let typo_line = bad
            .lines()
            .position(|l| l.starts_with("kp_per_map_flw"))
            .unwrap()
            + 1;
        let e = PlantCase::from_text(&bad, &path).expect_err("typo");
        assert!(e.key.starts_with("controller.recycle_pi"), "{e}");
        assert!(e.message.contains("kp_per_map_flw"), "{e}");
        assert_eq!(e.line, typo_line, "{e}");
        // a [controller] that is not a table is refused, not ignored
        let head = &t[..t.find("\n[controller]").unwrap()];
        let not_table = format!("controller = 3\n{head}\n");
        let e = PlantCase::from_text(&not_table, &path).expect_err("controller = 3");
        assert_eq!((e.key.as_str(), e.line), ("controller", 1), "{e}");
    }
}
