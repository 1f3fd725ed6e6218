//! The pictures of a simulation run, as SVG: the compressor map with the operating-point
//! trajectory ([`map_svg`]) and stacked time series sharing one time axis ([`timeseries_svg`]).
//!
//! # Text without fonts
//!
//! plotters is built without a font backend (its `ttf` and `ab_glyph` features are off). It then
//! uses a built-in width estimate (about 0.7 em per byte) to lay out labels and never opens a
//! font, and its SVG backend writes every label as an SVG `<text>` element with
//! `font-family="sans-serif"`. The glyphs are chosen by whatever displays the file (browser,
//! Inkscape, rsvg), so the program needs no font file and no system fonts, and cannot fail for
//! lack of one. Layout that depends on text width (legend boxes, speed-line label backgrounds)
//! uses a generous estimate of its own, so labels still fit with common sans-serif fonts.
//!
//! Lines are clipped to the plotting area here (plotters does not clip paths), and long traces
//! are thinned (min/max per pixel column for time series) so files stay small without losing
//! the envelope of fast surge oscillations.

mod common;
mod map;
mod timeseries;

#[cfg(test)]
mod tests;

use std::path::PathBuf;

pub use map::{map_svg, map_svg_sampled, MAX_TRAJ_POINTS};
pub use timeseries::timeseries_svg;

use crate::sim::summary::Summary;

/// What the time series mark besides the trace's own columns.
#[derive(Default)]
pub struct TimeMarks<'a> {
    /// Scenario events: time, s, and what happened in words ([`crate::scenario::Scenario::event_labels`]).
    pub events: Vec<(f64, String)>,
    /// The surge control line as a surge margin (fraction of surge-line flow, like the trace's
    /// `surge_margin`) at a pressure ratio, for the margin panel; `None` where the law has none.
    pub control_line: Option<&'a dyn Fn(f64) -> f64>,
    /// The recycle trip line likewise.
    pub trip_line: Option<&'a dyn Fn(f64) -> f64>,
    /// Another run's commands to compare with this trace's (`antisurge replay` with changed
    /// settings: the recorded commands beside the replayed ones). Each command line of the
    /// valve, torque, tip-clearance and close-coupled-valve panels gets a "(recorded)" twin
    /// from these rows' `cmd_*` columns, at their own times.
    pub recorded: Option<&'a [crate::sim::trace::TraceRow]>,
}

/// Errors drawing or writing a picture; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// Nothing to draw: the trace is empty or holds no finite values to plot.
    #[error("{file}: nothing to plot: {reason}")]
    NoData {
        /// The picture that was not written.
        file: PathBuf,
        /// What is missing.
        reason: String,
    },
    /// plotters failed to lay out or draw the picture.
    #[error("{file}: drawing failed: {message}")]
    Draw {
        /// The picture.
        file: PathBuf,
        /// plotters' message.
        message: String,
    },
    /// The SVG could not be written.
    #[error("{file}: cannot write: {source}")]
    Write {
        /// The picture.
        file: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
}

/// A picture title from a run summary: plant, scenario and law, then whether the run ended
/// stable and the surge cycles counted (with their frequency when known).
pub fn title_from_summary(s: &Summary) -> String {
    let status = if s.stable { "stable" } else { "not stable" };
    let surge = match (s.surge_cycles, s.surge_frequency_hz) {
        (0, _) => "no surge cycles".to_string(),
        (1, _) => "1 surge cycle".to_string(),
        (n, Some(f)) if f.is_finite() => format!("{n} surge cycles at {f:.2} Hz"),
        (n, _) => format!("{n} surge cycles"),
    };
    format!(
        "{} · {} · {}: {status}, {surge}",
        s.plant, s.scenario, s.law
    )
}
