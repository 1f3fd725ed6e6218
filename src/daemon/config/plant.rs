//! `[plant]`: the simulated skid's plant file. Loading it (and deriving the controller's
//! machine description from it when there is no `[machine]`) is in [`super::machine`].

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// `[plant]`: the machine the controller runs (its model: map, volumes, drive, valves).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantSection {
    /// Plant description file (`config/plants/*.toml`), relative to the main config file.
    pub file: PathBuf,
}
