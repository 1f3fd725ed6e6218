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

const SIZE: (u32, u32) = (1100, 800);
const MARGIN: u32 = 18;
const X_LABEL_AREA: u32 = 58;
const Y_LABEL_AREA: u32 = 78;
const TITLE_AREA: u32 = 42;
/// Speed lines drawn across the map's speed range.
pub(crate) const N_SPEED_LINES: usize = 6;
const SPEED_LINE_SAMPLES: usize = 600;
const MAX_TRAJ_POINTS: usize = 20_000;
/// Candidate label positions, in order of preference: where a speed line has fallen (right of
/// its surge point) to this fraction of its height above ratio 1.
const LABEL_HEIGHT_FRACTIONS: [f64; 7] = [0.72, 0.85, 0.6, 0.5, 0.93, 0.4, 0.3];

/// One speed line to draw.
#[derive(Debug, Clone, Copy)]
struct SpeedLine {
    omega: f64,
    /// The run's speed outside the map's range (labelled as such).
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
}

/// Draw the compressor map with the operating-point trajectory of `trace` into an SVG at `path`.
///
/// Six speed lines span [`CompressorMap::omega_range`] (plus the run's speed when it lies
/// outside), each labelled in rad/s and rpm, from slightly negative flow to past choke. The
/// derived surge line, the surge control line `scl` (pressure ratio → flow, same coordinates)
/// when given, and the trajectory `flow_map` vs `pressure_ratio` with its start (circle) and end
/// (square) are drawn over it. Axis ranges cover both the map and the whole trajectory.
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
    if trace.is_empty() {
        return Err(PlotError::NoData {
            file: path.to_path_buf(),
            reason: "the trace is empty".into(),
        });
    }
    let stride = trace.len().div_ceil(MAX_TRAJ_POINTS).max(1);
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

    let speeds = speed_lines(map, trace);
    let mut bounds = initial_bounds(map, &speeds, &traj);
    let mut entries = vec![LegendEntry::line("surge line", SURGE_COLOR, 3, false)];
    if scl.is_some() {
        entries.push(LegendEntry::line("surge control line", SCL_COLOR, 2, true));
    }
    if let (Some(s), Some(e)) = (start, end) {
        entries.push(LegendEntry::line("operating point", TRAJ_COLOR, 2, false));
        entries.push(LegendEntry {
            label: format!("start (t = {})", fmt_time(s.t_s)),
            swatch: Swatch::Circle(START_COLOR),
        });
        entries.push(LegendEntry {
            label: format!("end (t = {})", fmt_time(e.t_s)),
            swatch: Swatch::Square(END_COLOR),
        });
    }
    let legend = Legend::layout(&entries, 1e9, true);
    let plot_dim = (
        (SIZE.0 - 2 * MARGIN - Y_LABEL_AREA) as f64,
        (SIZE.1 - 2 * MARGIN - X_LABEL_AREA - TITLE_AREA) as f64,
    );
    // legend in the emptiest corner; if every corner hides data, make headroom above it
    let mut layers = build_layers(map, &speeds, scl, &traj, &bounds);
    let (mut corner, hidden) = legend.best_corner(&layers.all_points(), &bounds, plot_dim);
    if hidden > 0 {
        let f = legend.height_fraction(plot_dim.1);
        bounds.y1 += (bounds.y1 - bounds.y0) * f / (1.0 - f);
        layers = build_layers(map, &speeds, scl, &traj, &bounds);
        corner = legend
            .best_corner(&layers.all_points(), &bounds, plot_dim)
            .0;
    }

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
            map,
            &legend,
            corner,
        )
    })
}

impl MapLayers {
    fn all_points(&self) -> Vec<&[Pt]> {
        self.speed_lines
            .iter()
            .map(|(_, s)| s.as_slice())
            .chain(self.surge_line.iter().map(|s| s.as_slice()))
            .chain(self.scl.iter().map(|s| s.as_slice()))
            .chain(self.trajectory.iter().map(|s| s.as_slice()))
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

/// Evenly spaced speeds across the map's range, plus the run's lowest/highest speed when they
/// lie outside it.
fn speed_lines(map: &CompressorMap, trace: &[TraceRow]) -> Vec<SpeedLine> {
    let (lo, hi) = map.omega_range();
    let mut out: Vec<SpeedLine> = (0..N_SPEED_LINES)
        .map(|k| {
            let omega = lo + (hi - lo) * k as f64 / (N_SPEED_LINES - 1) as f64;
            SpeedLine {
                omega,
                run: false,
                peak: surge_point(map, omega),
            }
        })
        .collect();
    if let Some((r_lo, r_hi)) = finite_range(trace.iter().map(|r| r.omega_rad_s)) {
        let tol = 0.02 * (hi - lo);
        let mut add = |omega: f64| {
            out.push(SpeedLine {
                omega,
                run: true,
                peak: surge_point(map, omega),
            })
        };
        if r_lo < lo - tol && r_lo > 0.1 * lo {
            add(r_lo);
        }
        if r_hi > hi + tol {
            add(r_hi);
        }
    }
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
    map: &CompressorMap,
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

    for (_, seg) in &layers.speed_lines {
        draw_line(&mut chart, seg, SPEED_LINE_COLOR.stroke_width(1), false)?;
    }
    let (w, h) = chart.plotting_area().dim_in_pixel();
    let legend_box = legend.pixel_box(corner, (w as f64, h as f64));
    draw_speed_labels(&chart, b, layers, map, legend_box)?;
    for seg in &layers.surge_line {
        draw_line(&mut chart, seg, SURGE_COLOR.stroke_width(3), false)?;
    }
    for seg in &layers.scl {
        draw_line(&mut chart, seg, SCL_COLOR.stroke_width(2), true)?;
    }
    for seg in &layers.trajectory {
        draw_line(&mut chart, seg, TRAJ_COLOR.stroke_width(2), false)?;
    }
    if let Some(s) = start {
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

/// Label every speed line with its speed, above the line right of its surge point, on a
/// translucent background. Of a few positions along the line's falling branch, the one crossing
/// the fewest drawn curves (trajectory, surge and control lines) and no other label or the
/// legend is taken.
fn draw_speed_labels(
    chart: &ChartContext<'_, SVGBackend<'_>, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    b: &Bounds,
    layers: &MapLayers,
    map: &CompressorMap,
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
    // obstacles: drawn curves as pixel segments
    let curves: Vec<(Pt, Pt)> = layers
        .trajectory
        .iter()
        .chain(&layers.surge_line)
        .chain(&layers.scl)
        .flat_map(|seg| seg.windows(2).map(|w| (to_px(w[0]), to_px(w[1]))))
        .collect();
    let overlaps = |a: (f64, f64, f64, f64), c: (f64, f64, f64, f64)| {
        a.0 < c.2 && c.0 < a.2 && a.1 < c.3 && c.1 < a.3
    };
    let mut placed: Vec<(f64, f64, f64, f64)> = vec![legend_box];
    let style = TextStyle::from((FONT, TICK_SIZE).into_font())
        .color(&SPEED_LABEL_COLOR)
        .pos(Pos::new(HPos::Left, VPos::Bottom));
    let th = TICK_SIZE / 1.24;
    let px_per_x = w_px / (b.x1 - b.x0);
    for (s, seg) in &layers.speed_lines {
        let mut label = format!("{:.0} rad/s ({:.0} rpm)", s.omega, rpm(s.omega));
        if s.run {
            label.push_str(", run");
        }
        let tw = text_width(&label, TICK_SIZE);
        // (text left, text baseline) for a label anchored where the line has fallen to `frac`
        let position = |frac: f64| -> Option<(f64, f64)> {
            let target = 1.0 + frac * (s.peak.1 - 1.0);
            let anchor = seg
                .iter()
                .find(|p| p.0 > s.peak.0 && p.1 <= target)
                .or(seg.last())?;
            let left = (to_px(*anchor).0 + 4.0).min(w_px - tw - 6.0).max(2.0);
            // highest point of the line under the label's span
            let (q_left, q_right) = (b.x0 + left / px_per_x, b.x0 + (left + tw) / px_per_x);
            let top = (0..=20)
                .map(|k| {
                    let q = q_left + (q_right - q_left) * k as f64 / 20.0;
                    map.pressure_ratio(q, s.omega)
                })
                .fold(f64::NEG_INFINITY, f64::max)
                .min(b.y1);
            let bottom = (to_px((q_left, top)).1 - 3.0).max(th + 2.0);
            Some((left, bottom))
        };
        let mut best: Option<(f64, (f64, f64))> = None;
        for (rank, frac) in LABEL_HEIGHT_FRACTIONS.into_iter().enumerate() {
            let Some((left, bottom)) = position(frac) else {
                continue;
            };
            let bx = (left - 2.0, bottom - th - 2.0, left + tw + 2.0, bottom + 2.0);
            let outside = bx.1 < 0.0 || bx.3 > h_px;
            let collide = placed.iter().any(|p| overlaps(bx, *p));
            let r = Bounds {
                x0: bx.0,
                x1: bx.2,
                y0: bx.1,
                y1: bx.3,
            };
            let crossings = curves
                .iter()
                .filter(|(a, c)| clip_segment(*a, *c, &r).is_some())
                .count();
            let score =
                crossings as f64 + if collide || outside { 1e6 } else { 0.0 } + 0.5 * rank as f64;
            if best.is_none_or(|(s0, _)| score < s0) {
                best = Some((score, (left, bottom)));
            }
        }
        let Some((_, (left, bottom))) = best else {
            continue;
        };
        let bx = (left - 2.0, bottom - th - 2.0, left + tw + 2.0, bottom + 2.0);
        placed.push(bx);
        let r = |x: f64, y: f64| (x.round() as i32, y.round() as i32);
        area.draw(&Rectangle::new(
            [r(bx.0, bx.1), r(bx.2, bx.3)],
            WHITE.mix(0.75).filled(),
        ))
        .map_err(de)?;
        area.draw(&Text::new(label, r(left, bottom), style.clone()))
            .map_err(de)?;
    }
    Ok(())
}
