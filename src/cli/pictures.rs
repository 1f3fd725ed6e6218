//! Pictures of a run (map and time series).

use antisurge::plant::file::PlantDescription;
use antisurge::sim::SimResult;
use anyhow::Result;
use std::path::{Path, PathBuf};

/// Draw the pictures of a run; returns the files written.
pub fn draw(_dir: &Path, _desc: &PlantDescription, _result: &SimResult) -> Result<Vec<PathBuf>> {
    Ok(Vec::new())
}
