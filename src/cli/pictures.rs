//! Pictures of a run (map and time series).

use antisurge::control::recycle_pi;
use antisurge::control::surge_control_line::SurgeControlLine;
use antisurge::plot;
use antisurge::scenario::Scenario;
use antisurge::sim::case::PlantCase;
use antisurge::sim::SimResult;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// Draw the pictures of a run of `scenario`; returns the files written.
pub fn draw(
    dir: &Path,
    desc: &PlantCase,
    scenario: &Scenario,
    result: &SimResult,
) -> Result<Vec<PathBuf>> {
    let title = plot::title_from_summary(&result.summary);
    draw_trace(dir, desc, &result.trace, &title, &scenario.event_labels())
}

/// Draw the pictures of a trace (from `sim`, or read back by `antisurge plot`) with the
/// scenario's `events` (time, words) marked on the time series.
pub fn draw_trace(
    dir: &Path,
    desc: &PlantCase,
    trace: &[antisurge::sim::trace::TraceRow],
    title: &str,
    events: &[(f64, String)],
) -> Result<Vec<PathBuf>> {
    let title = title.to_string();
    let map_path = dir.join("map.svg");
    let scl = desc.file.recycle_system.map(|_| {
        SurgeControlLine::new(desc.map.surge_line, desc.controller.recycle_pi.control_line)
    });
    let scl_fn = scl.map(|s| move |r: f64| s.flow_at_ratio(r));
    let scl_ref: Option<&dyn Fn(f64) -> f64> = scl_fn.as_ref().map(|f| f as &dyn Fn(f64) -> f64);
    plot::map_svg(&map_path, &desc.map, trace, scl_ref, &title)
        .with_context(|| format!("drawing {}", map_path.display()))?;
    // the control and trip lines as surge margins (fraction of surge-line flow, as the
    // trace's surge_margin), the trip line as the recycle-pi law places it
    let j = desc.map.surge_line;
    let control = scl.map(|s| {
        move |r: f64| {
            let q = j.flow_at_ratio(r);
            (s.flow_at_ratio(r) - q) / q
        }
    });
    let trip_pct = desc.controller.recycle_pi.trip_margin_pct;
    let trip = scl.map(|s| move |r: f64| recycle_pi::trip_margin_at(trip_pct, &s, r));
    let marks = plot::TimeMarks {
        events: events.to_vec(),
        control_line: control.as_ref().map(|f| f as &dyn Fn(f64) -> f64),
        trip_line: trip.as_ref().map(|f| f as &dyn Fn(f64) -> f64),
    };
    let ts_path = dir.join("timeseries.svg");
    plot::timeseries_svg(&ts_path, trace, &title, &marks)
        .with_context(|| format!("drawing {}", ts_path.display()))?;
    Ok(vec![map_path, ts_path])
}
