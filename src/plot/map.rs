//! The compressor map with speed lines, surge line, surge control line and the operating-point
//! trajectory of a run.

use super::common::{
    clip_polyline, clip_segment, de, draw_line, draw_note, finite_range, nice_step, pad, render,
    text_width, tick_label, union, Area, Bounds, Corner, DrawResult, Legend, LegendEntry, Pt,
    Swatch, DESC_SIZE, FONT, TICK_SIZE, TITLE_SIZE,
};
use super::PlotError;
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use crate::sim::trace::TraceRow;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

/// Stroke colour of the speed lines (tests count the lines by it).
pub(crate) const SPEED_LINE_COLOR: RGBColor = RGBColor(70, 90, 120);
const SPEED_LABEL_COLOR: RGBColor = RGBColor(40, 55, 80);
const SURGE_COLOR: RGBColor = RGBColor(205, 25, 25);
const SCL_COLOR: RGBColor = RGBColor(235, 135, 0);
const TRAJ_COLOR: RGBColor = RGBColor(31, 110, 190);
const START_COLOR: RGBColor = RGBColor(0, 165, 70);
const END_COLOR: RGBColor = RGBColor(20, 20, 20);
const REF_COLOR: RGBColor = RGBColor(150, 150, 150);
/// Stroke colour of the running-speed line(s) (tests find them by it).
pub(crate) const RUN_SPEED_COLOR: RGBColor = RGBColor(0, 125, 140);
/// Stroke colour of the throughput trajectory (tests find it by it).
pub(crate) const THROUGHPUT_COLOR: RGBColor = RGBColor(150, 60, 170);
/// Start and end markers closer than this, pixels, are drawn as one.
const SAME_POINT_PX: f64 = 14.0;

const SIZE: (u32, u32) = (1100, 800);
const MARGIN: u32 = 18;
const X_LABEL_AREA: u32 = 58;
const Y_LABEL_AREA: u32 = 78;
const TITLE_AREA: u32 = 42;
/// Speed lines drawn across the map's speed range.
pub(crate) const N_SPEED_LINES: usize = 6;
const SPEED_LINE_SAMPLES: usize = 600;
/// Most trajectory points drawn: a longer trace is drawn from every n-th row (the trace's own
/// bound, which the streaming trace keeps too).
pub use crate::sim::trace::MAX_TRAJ_POINTS;
/// Preferred label position: where a speed line has fallen (right of its surge point) to this
/// fraction of its height above ratio 1.
const LABEL_HEIGHT_FRACTION: f64 = 0.72;

/// One speed line to draw.
#[derive(Debug, Clone, Copy)]
struct SpeedLine {
    omega: f64,
    /// A speed the run ran at (at its start or end), drawn as its own line and labelled so.
    run: bool,
    /// Surge point (flow, ratio).
    peak: Pt,
}

/// Everything drawn, in data coordinates, for given axis bounds.
struct MapLayers {
    speed_lines: Vec<(SpeedLine, Vec<Pt>)>,
    surge_line: Vec<Vec<Pt>>,
    scl: Vec<Vec<Pt>>,
    trajectory: Vec<Vec<Pt>>,
    /// Flow to the process, where it differs from the compressor's (recycle plants).
    throughput: Vec<Vec<Pt>>,
}

/// Draw the compressor map with the operating-point trajectory of `trace` into an SVG at `path`.
///
/// Six speed lines span [`CompressorMap::omega_range`], each labelled in rad/s and rpm on its
/// own curve, from slightly negative flow to past choke; the speed the run ran at (start, and
/// end if different) is a line of its own in another colour. The derived surge line, the surge
/// control line `scl` (pressure ratio → flow, same coordinates) when given, and the trajectory
/// `flow_map` vs `pressure_ratio` with its start (circle) and end (square) are drawn over it;
/// start and end closer than a marker's size are one marker. Where recycle makes the flow to
/// the process (throttle flow) differ from the compressor's, it is drawn too, at the same
/// pressure ratio; the legend gives both at the end in kg/s, the summary's unit, whatever the
/// map's flow coordinate. Axis ranges cover both the map and the whole trajectory.
///
/// Errors: [`PlotError::NoData`] for an empty trace; drawing and write failures. A trace whose
/// flows or ratios are all NaN gives the map with a note instead of a trajectory.
pub fn map_svg(
    path: &Path,
    map: &CompressorMap,
    trace: &[TraceRow],
    scl: Option<&dyn Fn(f64) -> f64>,
    title: &str,
) -> Result<(), PlotError> {
    let stride = trace.len().div_ceil(MAX_TRAJ_POINTS).max(1);
    map_svg_strided(path, map, trace, stride, scl, title)
}

/// [`map_svg`] of rows already taken at the stride [`map_svg`] takes of a whole trace (every
/// n-th row with n = ⌈rows / [`MAX_TRAJ_POINTS`]⌉, and the last row): the map of the whole
/// trace, from a streamed run's bounded sample of it (`sim::stream::PictureTrace`).
pub fn map_svg_sampled(
    path: &Path,
    map: &CompressorMap,
    sample: &[TraceRow],
    scl: Option<&dyn Fn(f64) -> f64>,
    title: &str,
) -> Result<(), PlotError> {
    map_svg_strided(path, map, sample, 1, scl, title)
}

fn map_svg_strided(
    path: &Path,
    map: &CompressorMap,
    trace: &[TraceRow],
    stride: usize,
    scl: Option<&dyn Fn(f64) -> f64>,
    title: &str,
) -> Result<(), PlotError> {
    if trace.is_empty() {
        return Err(PlotError::NoData {
            file: path.to_path_buf(),
            reason: "the trace is empty".into(),
        });
    }
    let mut traj: Vec<Pt> = trace
        .iter()
        .step_by(stride)
        .map(|r| (r.flow_map, r.pressure_ratio))
        .collect();
    if !(trace.len() - 1).is_multiple_of(stride) {
        let r = &trace[trace.len() - 1];
        traj.push((r.flow_map, r.pressure_ratio));
    }
    let mut finite_rows = trace
        .iter()
        .filter(|r| r.flow_map.is_finite() && r.pressure_ratio.is_finite());
    let start = finite_rows.next().copied();
    let end = finite_rows.next_back().copied().or(start);

    let through = throughput_trajectory(trace, stride);
    let speeds = speed_lines(map, trace);
    let mut bounds = initial_bounds(map, &speeds, &traj);
    if let Some(xr) = finite_range(through.iter().filter(|p| p.1.is_finite()).map(|p| p.0)) {
        let (x0, _) = pad(xr, 0.03);
        bounds.x0 = bounds.x0.min(x0);
    }
    let plot_dim = (
        (SIZE.0 - 2 * MARGIN - Y_LABEL_AREA) as f64,
        (SIZE.1 - 2 * MARGIN - X_LABEL_AREA - TITLE_AREA) as f64,
    );
    let entries = legend_entries(
        scl.is_some(),
        &speeds,
        (start, end),
        !through.is_empty(),
        same_point(start, end, &bounds, plot_dim),
    );
    let legend = Legend::layout(&entries, 1e9, true);
    // legend in the emptiest corner; if every corner hides data, make headroom above it
    let mut layers = build_layers(map, &speeds, scl, &traj, &through, &bounds);
    let (mut corner, hidden) = legend.best_corner(&layers.all_points(), &bounds, plot_dim);
    if hidden > 0 {
        let f = legend.height_fraction(plot_dim.1);
        bounds.y1 += (bounds.y1 - bounds.y0) * f / (1.0 - f);
        layers = build_layers(map, &speeds, scl, &traj, &through, &bounds);
        corner = legend
            .best_corner(&layers.all_points(), &bounds, plot_dim)
            .0;
    }
    let one_marker = same_point(start, end, &bounds, plot_dim);

    let x_desc = match map.flow_coordinate {
        FlowCoordinate::MassKgS => format!("mass flow ({})", map.flow_coordinate.unit()),
        FlowCoordinate::InletVolumeM3S => {
            format!("inlet volume flow ({})", map.flow_coordinate.unit())
        }
    };
    let has_traj = start.is_some();
    render(path, SIZE, |root| {
        draw_map(
            root,
            title,
            &x_desc,
            &bounds,
            &layers,
            (start, end),
            has_traj,
            one_marker,
            &legend,
            corner,
        )
    })
}

/// Whether start and end of the trajectory would be drawn on top of each other.
fn same_point(start: Option<TraceRow>, end: Option<TraceRow>, b: &Bounds, dim: (f64, f64)) -> bool {
    let (Some(s), Some(e)) = (start, end) else {
        return false;
    };
    let dx = (e.flow_map - s.flow_map) / (b.x1 - b.x0) * dim.0;
    let dy = (e.pressure_ratio - s.pressure_ratio) / (b.y1 - b.y0) * dim.1;
    dx.hypot(dy) < SAME_POINT_PX
}

/// End flows in kg/s (the summary's unit): compressor, and throughput when it differs.
fn fmt_kg_s(v: f64) -> String {
    if v.abs() >= 100.0 {
        format!("{v:.1} kg/s")
    } else if v.abs() >= 1.0 {
        format!("{v:.2} kg/s")
    } else {
        format!("{v:.3} kg/s")
    }
}

fn legend_entries(
    has_scl: bool,
    speeds: &[SpeedLine],
    (start, end): (Option<TraceRow>, Option<TraceRow>),
    has_throughput: bool,
    one_marker: bool,
) -> Vec<LegendEntry> {
    let mut entries = vec![LegendEntry::line("surge line", SURGE_COLOR, 3, false)];
    if has_scl {
        entries.push(LegendEntry::line("surge control line", SCL_COLOR, 2, true));
    }
    if speeds.iter().any(|s| s.run) {
        entries.push(LegendEntry::line(
            "running speed",
            RUN_SPEED_COLOR,
            2,
            false,
        ));
    }
    if let (Some(s), Some(e)) = (start, end) {
        let end_flow = |what: &str, v: f64| {
            if v.is_finite() {
                format!(", {what} {}", fmt_kg_s(v))
            } else {
                String::new()
            }
        };
        entries.push(LegendEntry::line(
            format!(
                "operating point{}",
                if has_throughput { " (compressor)" } else { "" }
            ),
            TRAJ_COLOR,
            2,
            false,
        ));
        if has_throughput {
            entries.push(LegendEntry::line(
                "throughput (to the process)",
                THROUGHPUT_COLOR,
                2,
                true,
            ));
        }
        let mut end_label = format!("end (t = {})", fmt_time(e.t_s));
        end_label.push_str(&end_flow("compressor", e.m_kg_s));
        if has_throughput {
            end_label.push_str(&end_flow("throughput", e.throttle_flow_kg_s));
        }
        if one_marker {
            entries.push(LegendEntry {
                label: format!(
                    "start and end (t = {} and {}: the same point)",
                    fmt_time(s.t_s),
                    fmt_time(e.t_s)
                ),
                swatch: Swatch::Square(END_COLOR),
            });
            if end_label.contains(',') {
                entries.push(LegendEntry {
                    label: end_label,
                    swatch: Swatch::Square(WHITE),
                });
            }
        } else {
            entries.push(LegendEntry {
                label: format!("start (t = {})", fmt_time(s.t_s)),
                swatch: Swatch::Circle(START_COLOR),
            });
            entries.push(LegendEntry {
                label: end_label,
                swatch: Swatch::Square(END_COLOR),
            });
        }
    }
    entries
}

/// The throughput (throttle flow) in map coordinates at each row's pressure ratio, when it
/// differs from the compressor flow somewhere by more than 1 % (gas recycled); else empty.
/// Map coordinates from kg/s by each row's own ratio flow_map / m_kg_s (inlet density).
fn throughput_trajectory(trace: &[TraceRow], stride: usize) -> Vec<Pt> {
    let differs = trace.iter().any(|r| {
        r.throttle_flow_kg_s.is_finite()
            && r.m_kg_s.is_finite()
            && (r.m_kg_s - r.throttle_flow_kg_s).abs() > 0.01 * r.m_kg_s.abs().max(1e-9)
    });
    if !differs {
        return Vec::new();
    }
    let mut last_factor = f64::NAN;
    let mut out: Vec<Pt> = trace
        .iter()
        .enumerate()
        .filter(|(i, _)| i % stride == 0 || *i + 1 == trace.len())
        .map(|(_, r)| {
            if r.m_kg_s.abs() > 1e-6 && r.flow_map.is_finite() {
                last_factor = r.flow_map / r.m_kg_s;
            }
            (r.throttle_flow_kg_s * last_factor, r.pressure_ratio)
        })
        .collect();
    if !out.iter().any(|p| p.0.is_finite() && p.1.is_finite()) {
        out.clear();
    }
    out
}

impl MapLayers {
    fn all_points(&self) -> Vec<&[Pt]> {
        self.speed_lines
            .iter()
            .map(|(_, s)| s.as_slice())
            .chain(self.surge_line.iter().map(|s| s.as_slice()))
            .chain(self.scl.iter().map(|s| s.as_slice()))
            .chain(self.trajectory.iter().map(|s| s.as_slice()))
            .chain(self.throughput.iter().map(|s| s.as_slice()))
            .collect()
    }
}

fn fmt_time(t: f64) -> String {
    if t.abs() >= 100.0 {
        format!("{t:.0} s")
    } else if t.abs() >= 10.0 {
        format!("{t:.1} s")
    } else {
        format!("{t:.2} s")
    }
}

fn rpm(omega: f64) -> f64 {
    omega * 60.0 / (2.0 * std::f64::consts::PI)
}

/// Surge point at a speed, from the map or (if it has none there) the tabulated surge line.
fn surge_point(map: &CompressorMap, omega: f64) -> Pt {
    map.peak(omega)
        .filter(|p| p.0.is_finite() && p.1.is_finite())
        .unwrap_or_else(|| {
            let q = map.surge_line.flow_at_speed(omega);
            (q, map.pressure_ratio(q, omega))
        })
}

/// Evenly spaced speeds across the map's range, plus the speed the run ran at: at its start,
/// and at its end when that differs by more than 1 % of the range. A regular line within 3 %
/// of the range of a running speed is left out (the running line takes its place).
fn speed_lines(map: &CompressorMap, trace: &[TraceRow]) -> Vec<SpeedLine> {
    let (lo, hi) = map.omega_range();
    let finite: Vec<f64> = trace
        .iter()
        .map(|r| r.omega_rad_s)
        .filter(|w| w.is_finite() && *w > 0.05 * lo)
        .collect();
    let mut run: Vec<f64> = Vec::new();
    if let (Some(&first), Some(&last)) = (finite.first(), finite.last()) {
        run.push(first);
        if (last - first).abs() > 0.01 * (hi - lo) {
            run.push(last);
        }
    }
    let mut out: Vec<SpeedLine> = (0..N_SPEED_LINES)
        .map(|k| lo + (hi - lo) * k as f64 / (N_SPEED_LINES - 1) as f64)
        .filter(|w| run.iter().all(|r| (r - w).abs() > 0.03 * (hi - lo)))
        .map(|omega| SpeedLine {
            omega,
            run: false,
            peak: surge_point(map, omega),
        })
        .collect();
    out.extend(run.into_iter().map(|omega| SpeedLine {
        omega,
        run: true,
        peak: surge_point(map, omega),
    }));
    out.sort_by(|a, b| a.omega.total_cmp(&b.omega));
    out
}

/// Axis bounds holding the map (slightly negative flow to past choke of the fastest line,
/// ratio 1 to the highest peak) and the whole trajectory.
fn initial_bounds(map: &CompressorMap, speeds: &[SpeedLine], traj: &[Pt]) -> Bounds {
    let q_ref = speeds
        .iter()
        .map(|s| s.peak.0)
        .filter(|q| q.is_finite())
        .fold(0.0, f64::max);
    let q_ref = if q_ref > 0.0 { q_ref } else { 1.0 };
    let top = speeds
        .iter()
        .max_by(|a, b| a.omega.total_cmp(&b.omega))
        .copied()
        .expect("at least one speed line");
    // choke of the fastest line: where it falls to ratio 1
    let step = 0.005 * q_ref;
    let mut q = top.peak.0;
    let mut choke = None;
    while q < top.peak.0 + 8.0 * q_ref {
        q += step;
        if map.pressure_ratio(q, top.omega) <= 1.0 {
            choke = Some(q);
            break;
        }
    }
    let x_hi = choke.unwrap_or(top.peak.0 + 2.0 * q_ref) + 0.04 * q_ref;
    let x_lo = -0.12 * q_ref;
    let y_hi = speeds
        .iter()
        .map(|s| s.peak.1)
        .chain([map.pressure_ratio(x_lo, top.omega)])
        .filter(|v| v.is_finite())
        .fold(1.0, f64::max);
    let xr = union(
        Some((x_lo, x_hi)),
        finite_range(traj.iter().filter(|p| p.1.is_finite()).map(|p| p.0)),
    )
    .expect("map range");
    let yr = union(
        Some((1.0, y_hi)),
        finite_range(traj.iter().filter(|p| p.0.is_finite()).map(|p| p.1)),
    )
    .expect("map range");
    let (x0, x1) = pad(xr, 0.03);
    let (y0, _) = pad(yr, 0.04);
    let (_, y1) = pad(yr, 0.06);
    Bounds { x0, x1, y0, y1 }
}

fn build_layers(
    map: &CompressorMap,
    speeds: &[SpeedLine],
    scl: Option<&dyn Fn(f64) -> f64>,
    traj: &[Pt],
    through: &[Pt],
    b: &Bounds,
) -> MapLayers {
    let speed_lines = speeds
        .iter()
        .filter_map(|s| {
            let pts: Vec<Pt> = (0..=SPEED_LINE_SAMPLES)
                .map(|k| {
                    let q = b.x0 + (b.x1 - b.x0) * k as f64 / SPEED_LINE_SAMPLES as f64;
                    (q, map.pressure_ratio(q, s.omega))
                })
                .collect();
            let segs = clip_polyline(&pts, b);
            // the visible piece through the surge point (one path per speed line)
            let seg = segs
                .iter()
                .find(|seg| seg[0].0 <= s.peak.0 && seg[seg.len() - 1].0 >= s.peak.0)
                .or_else(|| segs.iter().max_by_key(|seg| seg.len()))?
                .clone();
            Some((*s, seg))
        })
        .collect();
    let mut sl: Vec<Pt> = map.surge_line.points().collect();
    for s in speeds.iter().filter(|s| s.run) {
        if sl.first().is_some_and(|p| s.peak.1 < p.1) {
            sl.insert(0, s.peak);
        } else if sl.last().is_some_and(|p| s.peak.1 > p.1) {
            sl.push(s.peak);
        }
    }
    let surge_line = clip_polyline(&sl, b);
    let scl = scl
        .map(|f| {
            let r0 = b.y0.max(1.0 + 1e-9);
            let pts: Vec<Pt> = (0..=300)
                .map(|k| {
                    let r = r0 + (b.y1 - r0) * k as f64 / 300.0;
                    (f(r), r)
                })
                .collect();
            clip_polyline(&pts, b)
        })
        .unwrap_or_default();
    MapLayers {
        speed_lines,
        surge_line,
        scl,
        trajectory: clip_polyline(traj, b),
        throughput: clip_polyline(through, b),
    }
}

#[allow(clippy::too_many_arguments)]
fn draw_map(
    root: &Area<'_>,
    title: &str,
    x_desc: &str,
    b: &Bounds,
    layers: &MapLayers,
    (start, end): (Option<TraceRow>, Option<TraceRow>),
    has_traj: bool,
    one_marker: bool,
    legend: &Legend,
    corner: Corner,
) -> DrawResult<()> {
    let mut chart = ChartBuilder::on(root)
        .caption(title, (FONT, TITLE_SIZE))
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(b.x0..b.x1, b.y0..b.y1)
        .map_err(de)?;
    let (nx, ny) = (12, 10);
    let (sx, sy) = (nice_step((b.x0, b.x1), nx), nice_step((b.y0, b.y1), ny));
    chart
        .configure_mesh()
        .x_labels(nx)
        .y_labels(ny)
        .x_label_formatter(&|v| tick_label(*v, sx))
        .y_label_formatter(&|v| tick_label(*v, sy))
        .x_desc(x_desc)
        .y_desc("pressure ratio p_d/p_s (–)")
        .label_style((FONT, TICK_SIZE))
        .axis_desc_style((FONT, DESC_SIZE))
        .max_light_lines(1)
        .light_line_style(RGBColor(240, 240, 240))
        .bold_line_style(RGBColor(215, 215, 215))
        .draw()
        .map_err(de)?;

    // zero flow and ratio 1, for orientation
    if b.x0 < 0.0 && b.x1 > 0.0 {
        draw_line(
            &mut chart,
            &[(0.0, b.y0), (0.0, b.y1)],
            REF_COLOR.stroke_width(1),
            true,
        )?;
        let note = TextStyle::from((FONT, TICK_SIZE).into_font())
            .color(&REF_COLOR)
            .pos(Pos::new(HPos::Right, VPos::Bottom));
        // the root area is in backend pixels, as `backend_coord` returns
        let (x, y) = chart.backend_coord(&(0.0, b.y0));
        root.draw(&Text::new("← reverse flow", (x - 5, y - 4), note))
            .map_err(de)?;
    }
    if b.y0 < 1.0 && b.y1 > 1.0 {
        draw_line(
            &mut chart,
            &[(b.x0, 1.0), (b.x1, 1.0)],
            REF_COLOR.stroke_width(1),
            true,
        )?;
    }

    for (s, seg) in &layers.speed_lines {
        let style = if s.run {
            RUN_SPEED_COLOR.stroke_width(2)
        } else {
            SPEED_LINE_COLOR.stroke_width(1)
        };
        draw_line(&mut chart, seg, style, false)?;
    }
    let (w, h) = chart.plotting_area().dim_in_pixel();
    let legend_box = legend.pixel_box(corner, (w as f64, h as f64));
    draw_speed_labels(&chart, layers, legend_box)?;
    for seg in &layers.surge_line {
        draw_line(&mut chart, seg, SURGE_COLOR.stroke_width(3), false)?;
    }
    for seg in &layers.scl {
        draw_line(&mut chart, seg, SCL_COLOR.stroke_width(2), true)?;
    }
    for seg in &layers.throughput {
        draw_line(&mut chart, seg, THROUGHPUT_COLOR.stroke_width(2), true)?;
    }
    for seg in &layers.trajectory {
        draw_line(&mut chart, seg, TRAJ_COLOR.stroke_width(2), false)?;
    }
    if let Some(e) = end.filter(|_| !layers.throughput.is_empty()) {
        let p = (
            e.throttle_flow_kg_s * e.flow_map / e.m_kg_s,
            e.pressure_ratio,
        );
        if p.0.is_finite() && p.1.is_finite() {
            chart
                .draw_series(std::iter::once(
                    EmptyElement::at(p)
                        + Rectangle::new([(-5, -5), (5, 5)], THROUGHPUT_COLOR.filled()),
                ))
                .map_err(de)?;
        }
    }
    if let Some(s) = start.filter(|_| !one_marker) {
        let p = (s.flow_map, s.pressure_ratio);
        chart
            .draw_series([
                Circle::new(p, 7, START_COLOR.filled()),
                Circle::new(p, 7, BLACK.stroke_width(1)),
            ])
            .map_err(de)?;
    }
    if let Some(e) = end {
        let p = (e.flow_map, e.pressure_ratio);
        chart
            .draw_series(std::iter::once(
                EmptyElement::at(p) + Rectangle::new([(-6, -6), (6, 6)], END_COLOR.filled()),
            ))
            .map_err(de)?;
    }
    let area = chart.plotting_area().strip_coord_spec();
    if !has_traj {
        draw_note(&area, "no finite operating points in the trace")?;
    }
    legend.draw(&area, corner)
}

/// A box in pixels: (left, top, right, bottom).
type PxBox = (f64, f64, f64, f64);

/// Label every speed line with its speed, centred *on* its own curve (as contour labels are),
/// on a translucent background: a label beside its line can land on the neighbouring line of a
/// crowded map, one centred on it cannot. Of the points along the visible line (the falling
/// branch right of the surge point preferred, at about 70 % of its height above ratio 1), the
/// one whose label box crosses the fewest other drawn curves (other speed lines, trajectory,
/// surge and control lines), stays inside the plotting area and overlaps no other label or the
/// legend is taken. A label that fits nowhere in full is tried without its rpm.
fn draw_speed_labels(
    chart: &ChartContext<'_, SVGBackend<'_>, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    layers: &MapLayers,
    legend_box: (f64, f64, f64, f64),
) -> DrawResult<()> {
    let area = chart.plotting_area().strip_coord_spec();
    let (w_px, h_px) = area.dim_in_pixel();
    let (w_px, h_px) = (w_px as f64, h_px as f64);
    let (xr, yr) = chart.plotting_area().get_pixel_range();
    let to_px = |p: Pt| {
        let (x, y) = chart.backend_coord(&p);
        ((x - xr.start) as f64, (y - yr.start) as f64)
    };
    let segments = |segs: &[Vec<Pt>]| -> Vec<(Pt, Pt)> {
        segs.iter()
            .flat_map(|seg| seg.windows(2).map(|w| (to_px(w[0]), to_px(w[1]))))
            .collect()
    };
    // obstacles: drawn curves as pixel segments; each speed line's own kept apart
    let others: Vec<(Pt, Pt)> = segments(&layers.trajectory)
        .into_iter()
        .chain(segments(&layers.surge_line))
        .chain(segments(&layers.scl))
        .chain(segments(&layers.throughput))
        .collect();
    let speed_px: Vec<Vec<(Pt, Pt)>> = layers
        .speed_lines
        .iter()
        .map(|(_, seg)| segments(std::slice::from_ref(seg)))
        .collect();
    let overlaps = |a: (f64, f64, f64, f64), c: (f64, f64, f64, f64)| {
        a.0 < c.2 && c.0 < a.2 && a.1 < c.3 && c.1 < a.3
    };
    let mut placed: Vec<(f64, f64, f64, f64)> = vec![legend_box];
    let style = TextStyle::from((FONT, TICK_SIZE).into_font())
        .color(&SPEED_LABEL_COLOR)
        .pos(Pos::new(HPos::Center, VPos::Center));
    let th = TICK_SIZE / 1.24;
    for (k, (s, seg)) in layers.speed_lines.iter().enumerate() {
        let full = format!(
            "{:.0} rad/s ({:.0} rpm){}",
            s.omega,
            rpm(s.omega),
            if s.run { ", running" } else { "" }
        );
        let short = format!(
            "{:.0} rad/s{}",
            s.omega,
            if s.run { ", running" } else { "" }
        );
        let height = s.peak.1 - 1.0;
        let mut chosen: Option<(String, PxBox, Pt)> = None;
        for label in [full, short] {
            let tw = text_width(&label, TICK_SIZE);
            let mut best: Option<(f64, PxBox, Pt)> = None;
            for p in seg.iter() {
                let c = to_px(*p);
                let bx = (
                    c.0 - tw / 2.0 - 3.0,
                    c.1 - th / 2.0 - 3.0,
                    c.0 + tw / 2.0 + 3.0,
                    c.1 + th / 2.0 + 3.0,
                );
                if bx.0 < 0.0 || bx.1 < 0.0 || bx.2 > w_px || bx.3 > h_px {
                    continue;
                }
                if placed.iter().any(|q| overlaps(bx, *q)) {
                    continue;
                }
                let r = Bounds {
                    x0: bx.0,
                    x1: bx.2,
                    y0: bx.1,
                    y1: bx.3,
                };
                let crossings = others
                    .iter()
                    .chain(
                        speed_px
                            .iter()
                            .enumerate()
                            .filter(|(j, _)| *j != k)
                            .flat_map(|(_, v)| v.iter()),
                    )
                    .filter(|(a, b)| clip_segment(*a, *b, &r).is_some())
                    .count();
                // preference: the falling branch, near LABEL_HEIGHT_FRACTION of the height
                let frac = if height > 0.0 {
                    (p.1 - 1.0) / height
                } else {
                    0.5
                };
                let branch = if p.0 >= s.peak.0 { 0.0 } else { 2.0 };
                let score =
                    100.0 * crossings as f64 + branch + (frac - LABEL_HEIGHT_FRACTION).abs();
                if best.is_none_or(|(b, _, _)| score < b) {
                    best = Some((score, bx, c));
                }
            }
            if let Some((_, bx, c)) = best {
                chosen = Some((label, bx, c));
                break;
            }
        }
        let Some((label, bx, c)) = chosen else {
            continue;
        };
        placed.push(bx);
        let r = |x: f64, y: f64| (x.round() as i32, y.round() as i32);
        area.draw(&Rectangle::new(
            [r(bx.0, bx.1), r(bx.2, bx.3)],
            WHITE.mix(0.8).filled(),
        ))
        .map_err(de)?;
        area.draw(&Text::new(label, r(c.0, c.1), style.clone()))
            .map_err(de)?;
    }
    Ok(())
}
