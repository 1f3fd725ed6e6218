//! Stacked time-series panels of a run sharing one time axis.

use super::common::{
    clip_polyline, de, draw_line, finite_range, nice_step, pad, render, text_width, thin_min_max,
    tick_label, union, Area, Bounds, DrawResult, Legend, LegendEntry, Pt, Swatch, BAND_ALPHA,
    DESC_SIZE, FONT, LEGEND_SIZE, TICK_SIZE, TITLE_SIZE,
};
use super::{PlotError, TimeMarks};
use crate::sim::trace::TraceRow;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

const WIDTH: u32 = 1100;
const TITLE_H: u32 = 44;
const PLOT_H: u32 = 150;
const MARGIN_TOP: u32 = 10;
const MARGIN_BOTTOM: u32 = 4;
const MARGIN_LEFT: u32 = 10;
const MARGIN_RIGHT: u32 = 24;
const X_AXIS_H: u32 = 52;
const X_AXIS_H_INNER: u32 = 6;
const Y_LABEL_AREA: u32 = 92;
/// Buckets of the min/max thinning: about one per pixel column.
const THIN_BUCKETS: usize = 1000;

const BLUE: RGBColor = RGBColor(31, 110, 190);
const ORANGE: RGBColor = RGBColor(235, 125, 0);
const GREY: RGBColor = RGBColor(160, 160, 160);
const RED: RGBColor = RGBColor(205, 25, 25);
const GREEN: RGBColor = RGBColor(0, 140, 60);
const PURPLE: RGBColor = RGBColor(130, 60, 170);
const BROWN: RGBColor = RGBColor(140, 90, 40);
const SCL_ORANGE: RGBColor = RGBColor(235, 135, 0);
/// Off-scale markers of the margin panel (tests find them by it).
pub(crate) const OFF_SCALE_COLOR: RGBColor = RGBColor(120, 0, 120);
/// Fail-safe band (tests find it by it).
pub(crate) const FAIL_SAFE_COLOR: RGBColor = RGBColor(220, 30, 30);
/// Manual-mode band.
pub(crate) const MANUAL_COLOR: RGBColor = RGBColor(230, 170, 0);
/// Recorded commands beside replayed ones (tests find them by it).
pub(crate) const RECORDED_COLOR: RGBColor = RGBColor(40, 40, 40);
const EVENT_COLOR: RGBColor = RGBColor(90, 90, 90);
/// The margin panel shows ±100 % at most: beyond, it saturates and marks the samples (near zero
/// or reversed flow, the margin's denominator, the surge-line flow at a pressure ratio near 1,
/// tends to zero and the figure to ±∞, which says nothing an operator can use).
pub(crate) const MARGIN_LIMIT_PCT: f64 = 100.0;
/// Height of one row of event labels, pixels.
const EVENT_ROW_H: u32 = 20;
/// Most rows of event labels.
const EVENT_ROWS_MAX: usize = 3;

/// One line of a panel.
pub(crate) struct Series {
    pub(crate) name: &'static str,
    color: RGBColor,
    width: u32,
    dashed: bool,
    pub(crate) points: Vec<Pt>,
}

/// One panel: a y-axis title with unit and its lines.
pub(crate) struct Panel {
    pub(crate) y_desc: String,
    pub(crate) series: Vec<Series>,
    /// A range the axis always shows (e.g. 0..1 for valve openings).
    always: Option<(f64, f64)>,
    /// A dashed reference line at this value, with its legend label.
    reference: Option<(f64, &'static str)>,
    /// Samples beyond the panel's saturation, drawn as markers at the limit: (t, limit).
    pub(crate) off_scale: Vec<Pt>,
}

/// Line style of a series: (legend name, colour, width, dashed).
type Style = (&'static str, RGBColor, u32, bool);

/// A line of a panel: trace column, scale to the panel's unit, style.
type Line = (fn(&TraceRow) -> f64, f64, Style);

/// Collects panels, dropping series whose values are all NaN and panels left without series.
struct Builder<'a> {
    rows: &'a [TraceRow],
    t: Vec<f64>,
    panels: Vec<Panel>,
    /// Rows whose commands are drawn as "(recorded)" twins of the command lines.
    recorded: Option<&'a [TraceRow]>,
}

/// The legend name of a command line's recorded twin; `None` for lines that are not commands.
fn recorded_name(name: &str) -> Option<&'static str> {
    Some(match name {
        "recycle valve command" => "recycle valve command (recorded)",
        "throttle command" => "throttle command (recorded)",
        "drive command" => "drive command (recorded)",
        "command" => "command (recorded)",
        _ => return None,
    })
}

impl Builder<'_> {
    fn series(&self, get: fn(&TraceRow) -> f64, scale: f64, style: Style) -> Option<Series> {
        let y: Vec<f64> = self.rows.iter().map(|r| get(r) * scale).collect();
        if !y.iter().any(|v| v.is_finite()) {
            return None;
        }
        Some(Series {
            name: style.0,
            color: style.1,
            width: style.2,
            dashed: style.3,
            points: thin_min_max(&self.t, &y, THIN_BUCKETS),
        })
    }

    fn panel(
        &mut self,
        y_desc: impl Into<String>,
        lines: &[Line],
        always: Option<(f64, f64)>,
        reference: Option<(f64, &'static str)>,
    ) {
        let mut series: Vec<Series> = Vec::new();
        for &(get, scale, style) in lines {
            series.extend(self.series(get, scale, style));
            if let (Some(rec), Some(name)) = (self.recorded, recorded_name(style.0)) {
                // the recorded command: solid, thin, darker, under its own name
                let t: Vec<f64> = rec.iter().map(|r| r.t_s).collect();
                let y: Vec<f64> = rec.iter().map(|r| get(r) * scale).collect();
                if y.iter().any(|v| v.is_finite()) {
                    series.push(Series {
                        name,
                        color: RECORDED_COLOR,
                        width: 1,
                        dashed: false,
                        points: thin_min_max(&t, &y, THIN_BUCKETS),
                    });
                }
            }
        }
        if !series.is_empty() {
            self.panels.push(Panel {
                y_desc: y_desc.into(),
                series,
                always,
                reference,
                off_scale: Vec::new(),
            });
        }
    }
}

/// The panels of a trace, top to bottom.
pub(crate) fn panels(rows: &[TraceRow], marks: &TimeMarks<'_>) -> Vec<Panel> {
    let mut b = Builder {
        rows,
        t: rows.iter().map(|r| r.t_s).collect(),
        panels: Vec::new(),
        recorded: marks.recorded,
    };
    b.panel(
        "mass flow (kg/s)",
        &[
            (|r| r.meas_m_kg_s, 1.0, ("measured", GREY, 1, false)),
            (|r| r.m_kg_s, 1.0, ("true", BLUE, 2, false)),
            (|r| r.est_m_kg_s, 1.0, ("estimate", ORANGE, 2, true)),
        ],
        None,
        None,
    );
    let p_max = finite_range(
        rows.iter()
            .flat_map(|r| [r.p_suction_pa.abs(), r.p_discharge_pa.abs()]),
    )
    .map_or(0.0, |r| r.1);
    let (p_unit, p_scale) = if p_max >= 1e6 {
        ("MPa", 1e-6)
    } else {
        ("kPa", 1e-3)
    };
    b.panel(
        format!("pressure ({p_unit})"),
        &[
            (|r| r.p_suction_pa, p_scale, ("suction", BLUE, 2, false)),
            (|r| r.p_discharge_pa, p_scale, ("discharge", RED, 2, false)),
        ],
        None,
        None,
    );
    b.panel(
        "shaft speed (rad/s)",
        &[(|r| r.omega_rad_s, 1.0, ("shaft speed", BLUE, 2, false))],
        None,
        None,
    );
    b.panel(
        "valve opening (–)",
        &[
            (
                |r| r.recycle_valve_position,
                1.0,
                ("recycle valve position", GREEN, 2, false),
            ),
            (
                |r| r.cmd_recycle_valve,
                1.0,
                ("recycle valve command", GREEN, 1, true),
            ),
            (
                |r| r.throttle_position,
                1.0,
                ("throttle position", PURPLE, 2, false),
            ),
            (
                |r| r.cmd_throttle,
                1.0,
                ("throttle command", PURPLE, 1, true),
            ),
        ],
        Some((0.0, 1.0)),
        None,
    );
    b.panel(
        "torque (N·m)",
        &[
            (|r| r.load_torque_nm, 1.0, ("load", GREY, 1, false)),
            (
                |r| r.drive_torque_nm,
                1.0,
                ("drive delivered", RED, 2, false),
            ),
            (
                |r| r.cmd_drive_torque_nm,
                1.0,
                ("drive command", BROWN, 1, true),
            ),
        ],
        None,
        None,
    );
    b.panel(
        "tip clearance (µm)",
        &[
            (|r| r.tip_clearance_m, 1e6, ("delivered", BLUE, 2, false)),
            (|r| r.cmd_tip_clearance_m, 1e6, ("command", ORANGE, 1, true)),
        ],
        None,
        None,
    );
    b.panel(
        "close-coupled valve (–)",
        &[
            (|r| r.ccv, 1.0, ("applied", BLUE, 2, false)),
            (|r| r.cmd_ccv, 1.0, ("command", ORANGE, 1, true)),
        ],
        None,
        None,
    );
    if let Some(p) = margin_panel(rows, &b.t, marks) {
        b.panels.push(p);
    }
    b.panels
}

/// The surge-margin panel: the margin of the true state, saturated at ±[`MARGIN_LIMIT_PCT`]
/// with a marker where it is off scale; the control and trip lines (as margins at each row's
/// pressure ratio) when the law has them; the surge line at 0 %.
fn margin_panel(rows: &[TraceRow], t: &[f64], marks: &TimeMarks<'_>) -> Option<Panel> {
    let lim = MARGIN_LIMIT_PCT;
    let pct: Vec<f64> = rows.iter().map(|r| 100.0 * r.surge_margin).collect();
    if !pct.iter().any(|v| v.is_finite()) {
        return None;
    }
    let clamped: Vec<f64> = pct.iter().map(|v| v.clamp(-lim, lim)).collect();
    let mut series = vec![Series {
        name: "surge margin",
        color: BLUE,
        width: 2,
        dashed: false,
        points: thin_min_max(t, &clamped, THIN_BUCKETS),
    }];
    let line = |f: &dyn Fn(f64) -> f64| -> Vec<f64> {
        rows.iter()
            .map(|r| (100.0 * f(r.pressure_ratio)).clamp(-lim, lim))
            .collect()
    };
    for (name, color, f) in [
        ("control line", SCL_ORANGE, marks.control_line),
        ("trip line", RED, marks.trip_line),
    ] {
        if let Some(f) = f {
            let y = line(f);
            if y.iter().any(|v| v.is_finite()) {
                series.push(Series {
                    name,
                    color,
                    width: 1,
                    dashed: true,
                    points: thin_min_max(t, &y, THIN_BUCKETS),
                });
            }
        }
    }
    // one marker per 1/250 of the run at most
    let (t0, t1) = finite_range(t.iter().copied()).unwrap_or((0.0, 1.0));
    let bucket = ((t1 - t0) / 250.0).max(1e-12);
    let mut off_scale: Vec<Pt> = Vec::new();
    for (&ti, &v) in t.iter().zip(&pct) {
        if v.is_nan() || v.abs() <= lim || !ti.is_finite() {
            continue;
        }
        let y = lim.copysign(v);
        if off_scale
            .last()
            .is_some_and(|p| p.1 == y && ti - p.0 < bucket)
        {
            continue;
        }
        off_scale.push((ti, y));
    }
    Some(Panel {
        y_desc: "surge margin (%)".into(),
        series,
        always: None,
        reference: Some((0.0, "surge line (0 %)")),
        off_scale,
    })
}

/// Intervals of a mode (code) in the trace: (start, end) times.
fn mode_intervals(rows: &[TraceRow], code: f64) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    let mut open: Option<f64> = None;
    for (i, r) in rows.iter().enumerate() {
        let on = r.mode == code;
        match (on, open) {
            (true, None) => open = Some(r.t_s),
            (false, Some(s)) => {
                out.push((s, r.t_s));
                open = None;
            }
            _ => {}
        }
        if i + 1 == rows.len() {
            if let Some(s) = open {
                out.push((s, r.t_s));
            }
        }
    }
    out
}

/// Shaded mode intervals: (colour, legend label, intervals).
type Bands = Vec<(RGBColor, &'static str, Vec<(f64, f64)>)>;

fn bands(rows: &[TraceRow]) -> Bands {
    [
        (FAIL_SAFE_COLOR, "fail-safe", 3.0),
        (MANUAL_COLOR, "manual", 1.0),
    ]
    .into_iter()
    .map(|(c, l, code)| (c, l, mode_intervals(rows, code)))
    .filter(|(_, _, v)| !v.is_empty())
    .collect()
}

/// Rows of event labels: each label in the first row where it does not overlap the previous
/// one; (x pixel, row, text).
fn event_rows(events: &[(f64, String)], x_of: impl Fn(f64) -> f64) -> Vec<(f64, usize, String)> {
    let mut ends = [f64::NEG_INFINITY; EVENT_ROWS_MAX];
    let mut out = Vec::new();
    for (t, text) in events {
        let x = x_of(*t);
        let w = text_width(text, LEGEND_SIZE) + 8.0;
        let row = (0..EVENT_ROWS_MAX)
            .find(|&k| ends[k] < x)
            .unwrap_or_else(|| {
                (0..EVENT_ROWS_MAX)
                    .min_by(|a, b| ends[*a].total_cmp(&ends[*b]))
                    .unwrap_or(0)
            });
        ends[row] = x + w;
        out.push((x, row, text.clone()));
    }
    out
}

/// Draw stacked panels of `trace` sharing the time axis into an SVG at `path`: mass flow (true,
/// measured, estimate), suction and discharge pressure (kPa or MPa by magnitude), shaft speed,
/// valve positions and commands, drive torque, tip clearance, close-coupled valve and surge
/// margin (saturated at ±100 % with markers where off scale, with the control and trip lines of
/// `marks`). Series whose values are all NaN are left out, and so are panels left empty; every
/// panel has its legend inside, in the corner hiding the least data. The scenario events of
/// `marks` are vertical lines through every panel, labelled above the first; the intervals
/// the controller spent in fail-safe or manual (the trace's `mode`) are shaded in every panel.
///
/// Errors: [`PlotError::NoData`] for an empty trace, non-finite times or no finite values at
/// all; drawing and write failures.
pub fn timeseries_svg(
    path: &Path,
    trace: &[TraceRow],
    title: &str,
    marks: &TimeMarks<'_>,
) -> Result<(), PlotError> {
    let no_data = |reason: &str| PlotError::NoData {
        file: path.to_path_buf(),
        reason: reason.to_string(),
    };
    if trace.is_empty() {
        return Err(no_data("the trace is empty"));
    }
    let (t0, t1) = finite_range(trace.iter().map(|r| r.t_s))
        .ok_or_else(|| no_data("the trace has no finite times"))?;
    let (t0, t1) = if t1 > t0 {
        (t0, t1)
    } else {
        (t0 - 0.5, t1 + 0.5)
    };
    let panels = panels(trace, marks);
    if panels.is_empty() {
        return Err(no_data("every plotted column of the trace is NaN"));
    }
    let bands = bands(trace);
    let events: Vec<(f64, String)> = marks
        .events
        .iter()
        .filter(|(t, _)| t.is_finite() && *t >= t0 && *t <= t1)
        .cloned()
        .collect();
    let plot_left = (MARGIN_LEFT + Y_LABEL_AREA) as f64;
    let plot_w = (WIDTH - MARGIN_LEFT - MARGIN_RIGHT - Y_LABEL_AREA) as f64;
    let labels = event_rows(&events, |t| plot_left + (t - t0) / (t1 - t0) * plot_w);
    let strip_h = labels
        .iter()
        .map(|(_, row, _)| (*row as u32 + 1) * EVENT_ROW_H + 4)
        .max()
        .unwrap_or(0);
    let n = panels.len() as u32;
    let inner_h = PLOT_H + MARGIN_TOP + MARGIN_BOTTOM + X_AXIS_H_INNER;
    let height =
        TITLE_H + strip_h + (n - 1) * inner_h + (PLOT_H + MARGIN_TOP + MARGIN_BOTTOM + X_AXIS_H);
    render(path, (WIDTH, height), |root| {
        let body = root.titled(title, (FONT, TITLE_SIZE)).map_err(de)?;
        let (strip, body) = body.split_vertically(strip_h);
        let style = TextStyle::from((FONT, LEGEND_SIZE).into_font())
            .color(&EVENT_COLOR)
            .pos(Pos::new(HPos::Left, VPos::Center));
        for (x, row, text) in &labels {
            let y = (*row as u32 * EVENT_ROW_H + EVENT_ROW_H / 2) as i32;
            strip
                .draw(&PathElement::new(
                    vec![(*x as i32, y), (*x as i32, strip_h as i32)],
                    EVENT_COLOR.stroke_width(1),
                ))
                .map_err(de)?;
            strip
                .draw(&Text::new(text.clone(), (*x as i32 + 4, y), style.clone()))
                .map_err(de)?;
        }
        let breaks: Vec<u32> = (1..n).map(|k| k * inner_h).collect();
        let areas = body.split_by_breakpoints::<u32, u32, _, _>([], breaks);
        for (k, (panel, area)) in panels.iter().zip(areas.iter()).enumerate() {
            let deco = Decorations {
                bands: &bands,
                events: &events,
                band_legend: k == 0,
            };
            draw_panel(area, panel, (t0, t1), k + 1 == panels.len(), &deco)?;
        }
        Ok(())
    })
}

/// What every panel shows besides its own lines.
struct Decorations<'a> {
    bands: &'a Bands,
    events: &'a [(f64, String)],
    /// Whether this panel's legend explains the bands.
    band_legend: bool,
}

fn draw_panel(
    area: &Area<'_>,
    panel: &Panel,
    (t0, t1): (f64, f64),
    bottom: bool,
    deco: &Decorations<'_>,
) -> DrawResult<()> {
    let plot_dim = (
        (WIDTH - MARGIN_LEFT - MARGIN_RIGHT - Y_LABEL_AREA) as f64,
        PLOT_H as f64,
    );
    let mut yr = panel
        .series
        .iter()
        .map(|s| finite_range(s.points.iter().map(|p| p.1)))
        .fold(panel.always, union);
    if let Some((v, _)) = panel.reference {
        yr = union(yr, Some((v, v)));
    }
    let (y0, y1) = pad(yr.unwrap_or((0.0, 1.0)), 0.06);
    let mut b = Bounds {
        x0: t0,
        x1: t1,
        y0,
        y1,
    };
    let mut entries: Vec<LegendEntry> = panel
        .series
        .iter()
        .map(|s| LegendEntry::line(s.name, s.color, s.width, s.dashed))
        .collect();
    if let Some((_, label)) = panel.reference {
        entries.push(LegendEntry::line(label, RED, 1, true));
    }
    if !panel.off_scale.is_empty() {
        entries.push(LegendEntry {
            label: format!("off scale (beyond ±{MARGIN_LIMIT_PCT:.0} %)"),
            swatch: Swatch::Triangle(OFF_SCALE_COLOR),
        });
    }
    if deco.band_legend {
        for (c, label, _) in deco.bands {
            entries.push(LegendEntry {
                label: (*label).to_string(),
                swatch: Swatch::Band(*c),
            });
        }
    }
    let legend = Legend::layout(&entries, plot_dim.0 - 16.0, false);
    let pts: Vec<&[Pt]> = panel.series.iter().map(|s| s.points.as_slice()).collect();
    let (mut corner, hidden) = legend.best_corner(&pts, &b, plot_dim);
    if hidden > 0 {
        let f = legend.height_fraction(plot_dim.1);
        b.y1 += (b.y1 - b.y0) * f / (1.0 - f);
        corner = legend.best_corner(&pts, &b, plot_dim).0;
    }

    let mut chart = ChartBuilder::on(area)
        .margin_top(MARGIN_TOP)
        .margin_bottom(MARGIN_BOTTOM)
        .margin_left(MARGIN_LEFT)
        .margin_right(MARGIN_RIGHT)
        .x_label_area_size(if bottom { X_AXIS_H } else { X_AXIS_H_INNER })
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(b.x0..b.x1, b.y0..b.y1)
        .map_err(de)?;
    let (nx, ny) = (16, 5);
    let (sx, sy) = (nice_step((b.x0, b.x1), nx), nice_step((b.y0, b.y1), ny));
    let x_fmt = move |v: &f64| {
        if bottom {
            tick_label(*v, sx)
        } else {
            String::new()
        }
    };
    let y_fmt = |v: &f64| tick_label(*v, sy);
    let mut mesh = chart.configure_mesh();
    mesh.x_labels(nx)
        .y_labels(ny)
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .y_desc(panel.y_desc.as_str())
        .label_style((FONT, TICK_SIZE))
        .axis_desc_style((FONT, DESC_SIZE))
        .max_light_lines(1)
        .light_line_style(RGBColor(242, 242, 242))
        .bold_line_style(RGBColor(215, 215, 215));
    if bottom {
        mesh.x_desc("time (s)");
    }
    mesh.draw().map_err(de)?;

    for (c, _, spans) in deco.bands {
        chart
            .draw_series(
                spans.iter().map(|(a, z)| {
                    Rectangle::new([(*a, b.y0), (*z, b.y1)], c.mix(BAND_ALPHA).filled())
                }),
            )
            .map_err(de)?;
    }
    for (t, _) in deco.events {
        draw_line(
            &mut chart,
            &[(*t, b.y0), (*t, b.y1)],
            EVENT_COLOR.stroke_width(1),
            true,
        )?;
    }
    if let Some((v, _)) = panel.reference {
        draw_line(
            &mut chart,
            &[(b.x0, v), (b.x1, v)],
            RED.stroke_width(1),
            true,
        )?;
    }
    for s in &panel.series {
        for seg in clip_polyline(&s.points, &b) {
            draw_line(&mut chart, &seg, s.color.stroke_width(s.width), s.dashed)?;
        }
    }
    if !panel.off_scale.is_empty() {
        let c = OFF_SCALE_COLOR;
        chart
            .draw_series(panel.off_scale.iter().map(|&(t, y)| {
                // a triangle pointing off the scale, its tip on the limit
                let tip = if y > 0.0 { -1 } else { 1 };
                EmptyElement::at((t, y))
                    + Polygon::new(vec![(0, 0), (-4, -9 * tip), (4, -9 * tip)], c.filled())
            }))
            .map_err(de)?;
    }
    legend.draw(&chart.plotting_area().strip_coord_spec(), corner)
}
