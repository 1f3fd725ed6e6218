//! Pictures of a run (map and time series).

use antisurge::control::laws::recycle_pi;
use antisurge::control::surge_control_line::{ControlLineForm, SurgeControlLine};
use antisurge::physics::compressor_map::{CompressorMap, SurgeLine};
use antisurge::plot;
use antisurge::scenario::Scenario;
use antisurge::sim::case::PlantCase;
use antisurge::sim::stream::PictureTrace;
use antisurge::sim::trace::TraceRow;
use antisurge::sim::Summary;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// What a run's pictures are drawn against.
pub struct Machine<'a> {
    /// The speed-line map (`None`: a machine described by its surge line only; no map.svg).
    pub map: Option<&'a CompressorMap>,
    /// The surge line (flow in the map's coordinate versus pressure ratio).
    pub surge_line: SurgeLine,
    /// With a recycle system: the recycle law's control-line form and trip margin, %.
    pub recycle: Option<(ControlLineForm, f64)>,
}

/// Draw the pictures of a streamed run of `scenario` from its bounded picture (every row of a
/// short run: the pictures of the whole trace; a long run's thinned rows); returns the files
/// written.
pub fn draw_streamed(
    dir: &Path,
    desc: &PlantCase,
    scenario: &Scenario,
    summary: &Summary,
    pictures: &PictureTrace,
) -> Result<Vec<PathBuf>> {
    let title = plot::title_from_summary(summary);
    draw_split(
        dir,
        &machine_of(desc),
        MapRows::Sampled(pictures.map_rows()),
        &pictures.series_rows(),
        (&title, &scenario.event_labels()),
        None,
    )
}

/// Draw the pictures of a trace (from `sim`, or read back by `antisurge plot`) with the
/// scenario's `events` (time, words) marked on the time series.
pub fn draw_trace(
    dir: &Path,
    desc: &PlantCase,
    trace: &[TraceRow],
    title: &str,
    events: &[(f64, String)],
) -> Result<Vec<PathBuf>> {
    draw_run(dir, &machine_of(desc), trace, title, events, None)
}

/// What a simulation plant's pictures are drawn against.
fn machine_of(desc: &PlantCase) -> Machine<'_> {
    let rp = &desc.controller.recycle_pi;
    Machine {
        map: Some(&desc.map),
        surge_line: desc.map.surge_line,
        recycle: desc
            .file
            .recycle_system
            .map(|_| (rp.control_line, rp.trip.margin_pct)),
    }
}

/// Draw map.svg (when the machine has a map) and timeseries.svg of `trace` into `dir`, with
/// `events` marked and, when given, `recorded` commands beside the trace's (replay with
/// changed settings). The one place the CLI's pictures are drawn (`sim`, `plot`, `replay`).
pub fn draw_run(
    dir: &Path,
    machine: &Machine<'_>,
    trace: &[TraceRow],
    title: &str,
    events: &[(f64, String)],
    recorded: Option<&[TraceRow]>,
) -> Result<Vec<PathBuf>> {
    draw_split(
        dir,
        machine,
        MapRows::Whole(trace),
        trace,
        (title, events),
        recorded,
    )
}

/// The rows a map is drawn from.
enum MapRows<'a> {
    /// The whole trace (the map takes every n-th row of a long one).
    Whole(&'a [TraceRow]),
    /// A streamed run's rows already taken at that stride.
    Sampled(&'a [TraceRow]),
}

/// [`draw_run`] with the map's trajectory and the time series drawn from rows of their own
/// (a long streamed run: the rows the map would take of the whole trace, and the min/max
/// envelope for the time series).
fn draw_split(
    dir: &Path,
    machine: &Machine<'_>,
    map_rows: MapRows<'_>,
    trace: &[TraceRow],
    (title, events): (&str, &[(f64, String)]),
    recorded: Option<&[TraceRow]>,
) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    let scl = machine
        .recycle
        .map(|(form, _)| SurgeControlLine::new(machine.surge_line, form));
    if let Some(map) = machine.map {
        let map_path = dir.join("map.svg");
        let scl_fn = scl.map(|s| move |r: f64| s.flow_at_ratio(r));
        let scl_ref: Option<&dyn Fn(f64) -> f64> =
            scl_fn.as_ref().map(|f| f as &dyn Fn(f64) -> f64);
        match map_rows {
            MapRows::Whole(rows) => plot::map_svg(&map_path, map, rows, scl_ref, title),
            MapRows::Sampled(rows) => plot::map_svg_sampled(&map_path, map, rows, scl_ref, title),
        }
        .with_context(|| format!("drawing {}", map_path.display()))?;
        files.push(map_path);
    }
    // the control and trip lines as surge margins (fraction of surge-line flow, as the
    // trace's surge_margin), the trip line as the recycle-pi law places it
    let j = machine.surge_line;
    let control = scl.map(|s| {
        move |r: f64| {
            let q = j.flow_at_ratio(r);
            (s.flow_at_ratio(r) - q) / q
        }
    });
    let trip = scl
        .zip(machine.recycle)
        .map(|(s, (_, trip_pct))| move |r: f64| recycle_pi::trip_margin_at(trip_pct, &s, r));
    let marks = plot::TimeMarks {
        events: events.to_vec(),
        control_line: control.as_ref().map(|f| f as &dyn Fn(f64) -> f64),
        trip_line: trip.as_ref().map(|f| f as &dyn Fn(f64) -> f64),
        recorded,
    };
    let ts_path = dir.join("timeseries.svg");
    plot::timeseries_svg(&ts_path, trace, title, &marks)
        .with_context(|| format!("drawing {}", ts_path.display()))?;
    files.push(ts_path);
    Ok(files)
}
