//! Pictures of a run (map and time series).

use antisurge::control::surge_control_line::SurgeControlLine;
use antisurge::plant::file::PlantDescription;
use antisurge::plot;
use antisurge::sim::SimResult;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// Draw the pictures of a run; returns the files written.
pub fn draw(dir: &Path, desc: &PlantDescription, result: &SimResult) -> Result<Vec<PathBuf>> {
    let title = plot::title_from_summary(&result.summary);
    draw_trace(dir, desc, &result.trace, &title)
}

/// Draw the pictures of a trace (from `sim`, or read back by `antisurge plot`).
pub fn draw_trace(
    dir: &Path,
    desc: &PlantDescription,
    trace: &[antisurge::sim::trace::TraceRow],
    title: &str,
) -> Result<Vec<PathBuf>> {
    let title = title.to_string();
    let map_path = dir.join("map.svg");
    let scl = desc.file.recycle_system.map(|_| {
        SurgeControlLine::new(
            desc.map.surge_line,
            desc.file.controller.recycle_pi.control_line,
        )
    });
    let scl_fn = scl.map(|s| move |r: f64| s.flow_at_ratio(r));
    let scl_ref: Option<&dyn Fn(f64) -> f64> = scl_fn.as_ref().map(|f| f as &dyn Fn(f64) -> f64);
    plot::map_svg(&map_path, &desc.map, trace, scl_ref, &title)
        .with_context(|| format!("drawing {}", map_path.display()))?;
    let ts_path = dir.join("timeseries.svg");
    plot::timeseries_svg(&ts_path, trace, &title)
        .with_context(|| format!("drawing {}", ts_path.display()))?;
    Ok(vec![map_path, ts_path])
}
