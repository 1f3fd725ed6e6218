//! Writing a run's files: `trace.csv`, `summary.json`, `map.svg`, `timeseries.svg` (a run kept
//! in memory; `sim::run_streamed` writes `trace.csv` as it goes).

use super::{SimResult, Summary};
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use std::path::{Path, PathBuf};

/// Errors writing outputs.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// File system error.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// Picture error.
    #[error("{0}")]
    Plot(String),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> OutputError + '_ {
    move |source| OutputError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Write the trace and summary into `dir` (created if needed); returns the files written.
pub fn write_data(
    dir: &Path,
    result: &SimResult,
    map: &CompressorMap,
) -> Result<Vec<PathBuf>, OutputError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let trace_path = dir.join("trace.csv");
    let f = std::fs::File::create(&trace_path).map_err(io(&trace_path))?;
    let mut w = std::io::BufWriter::new(f);
    super::trace::write_csv(
        &mut w,
        &result.trace,
        map.flow_coordinate == FlowCoordinate::InletVolumeM3S,
    )
    .and_then(|()| std::io::Write::flush(&mut w))
    .map_err(io(&trace_path))?;
    let summary_path = write_summary(dir, &result.summary)?;
    Ok(vec![trace_path, summary_path])
}

/// Write `dir/summary.json` (the directory exists); returns its path.
pub fn write_summary(dir: &Path, summary: &Summary) -> Result<PathBuf, OutputError> {
    let summary_path = dir.join("summary.json");
    let json = serde_json::to_string_pretty(summary).map_err(|e| OutputError::Io {
        path: summary_path.clone(),
        source: std::io::Error::other(e),
    })?;
    std::fs::write(&summary_path, json + "\n").map_err(io(&summary_path))?;
    Ok(summary_path)
}
