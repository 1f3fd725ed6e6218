//! Shared pieces of the pictures: rendering to a file, ranges, clipping, thinning, legends.

use super::PlotError;
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

/// A point in data coordinates.
pub(crate) type Pt = (f64, f64);

/// Drawing results inside a picture: plotters' errors as text.
pub(crate) type DrawResult<T> = Result<T, String>;

/// The root drawing area of an SVG picture.
pub(crate) type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// Font family of every label (resolved by the SVG viewer).
pub(crate) const FONT: &str = "sans-serif";
/// plotters font sizes (the SVG backend writes size / 1.24 as the CSS pixel size).
pub(crate) const TITLE_SIZE: f64 = 22.0;
pub(crate) const DESC_SIZE: f64 = 17.0;
pub(crate) const TICK_SIZE: f64 = 15.0;
pub(crate) const LEGEND_SIZE: f64 = 15.0;
pub(crate) const NOTE_SIZE: f64 = 18.0;

/// Convert any plotters error to text.
pub(crate) fn de<E: std::fmt::Display>(e: E) -> String {
    e.to_string()
}

/// Render a picture of `size` pixels with `draw` and write it to `path`.
pub(crate) fn render(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&Area<'_>) -> DrawResult<()>,
) -> Result<(), PlotError> {
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        let drawn = root
            .fill(&WHITE)
            .map_err(de)
            .and_then(|_| draw(&root))
            .and_then(|_| root.present().map_err(de));
        drawn.map_err(|message| PlotError::Draw {
            file: path.to_path_buf(),
            message,
        })?;
    }
    std::fs::write(path, buf).map_err(|source| PlotError::Write {
        file: path.to_path_buf(),
        source,
    })
}

/// Approximate rendered width of `text` at plotters font size `size`, pixels. Deliberately
/// generous (0.64 em per character) so boxes sized with it hold common sans-serif fonts.
pub(crate) fn text_width(text: &str, size: f64) -> f64 {
    text.chars().count() as f64 * 0.64 * size / 1.24
}

/// Smallest and largest finite value, if any.
pub(crate) fn finite_range(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    values
        .into_iter()
        .filter(|v| v.is_finite())
        .fold(None, |acc, v| match acc {
            None => Some((v, v)),
            Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
        })
}

/// Union of two optional ranges.
pub(crate) fn union(a: Option<(f64, f64)>, b: Option<(f64, f64)>) -> Option<(f64, f64)> {
    match (a, b) {
        (Some(a), Some(b)) => Some((a.0.min(b.0), a.1.max(b.1))),
        (a, None) => a,
        (None, b) => b,
    }
}

/// Widen a range by `frac` of its span on each side. A flat range gets a span of its own: 5 %
/// of its magnitude, or ±1 around zero.
pub(crate) fn pad((lo, hi): (f64, f64), frac: f64) -> (f64, f64) {
    let span = hi - lo;
    if span > 1e-9 * lo.abs().max(hi.abs()) && span > 0.0 {
        (lo - frac * span, hi + frac * span)
    } else {
        let m = lo.abs().max(hi.abs());
        let h = if m > 0.0 { 0.05 * m } else { 1.0 };
        (lo - h, hi + h)
    }
}

/// A rectangle in data coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Bounds {
    pub x0: f64,
    pub x1: f64,
    pub y0: f64,
    pub y1: f64,
}

/// Clip the segment a–b to the rectangle (Liang–Barsky); None if it lies outside.
pub(crate) fn clip_segment(a: Pt, b: Pt, r: &Bounds) -> Option<(Pt, Pt)> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [
        (-dx, a.0 - r.x0),
        (dx, r.x1 - a.0),
        (-dy, a.1 - r.y0),
        (dy, r.y1 - a.1),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                if t > t1 {
                    return None;
                }
                t0 = t0.max(t);
            } else {
                if t < t0 {
                    return None;
                }
                t1 = t1.min(t);
            }
        }
    }
    let at = |t: f64| {
        if t == 0.0 {
            a
        } else if t == 1.0 {
            b
        } else {
            (a.0 + t * dx, a.1 + t * dy)
        }
    };
    Some((at(t0), at(t1)))
}

/// Split a polyline into the pieces visible in the rectangle. Non-finite points break the
/// line; segments leaving the rectangle end at its border.
pub(crate) fn clip_polyline(points: &[Pt], r: &Bounds) -> Vec<Vec<Pt>> {
    let finite = |p: Pt| p.0.is_finite() && p.1.is_finite();
    let mut out: Vec<Vec<Pt>> = Vec::new();
    let mut cur: Vec<Pt> = Vec::new();
    let flush = |cur: &mut Vec<Pt>, out: &mut Vec<Vec<Pt>>| {
        if cur.len() >= 2 {
            out.push(std::mem::take(cur));
        } else {
            cur.clear();
        }
    };
    for w in points.windows(2) {
        let (a, b) = (w[0], w[1]);
        if !(finite(a) && finite(b)) {
            flush(&mut cur, &mut out);
            continue;
        }
        match clip_segment(a, b, r) {
            None => flush(&mut cur, &mut out),
            Some((p, q)) => {
                if cur.last() != Some(&p) {
                    flush(&mut cur, &mut out);
                    cur.push(p);
                }
                cur.push(q);
                if q != b {
                    flush(&mut cur, &mut out);
                }
            }
        }
    }
    flush(&mut cur, &mut out);
    out
}

/// Thin a time series to at most about `2 * buckets` points, keeping the smallest and largest
/// value of every bucket in time order (so oscillation envelopes survive). A bucket without
/// finite values yields a NaN point, which breaks the line there.
pub(crate) fn thin_min_max(t: &[f64], y: &[f64], buckets: usize) -> Vec<Pt> {
    let n = t.len().min(y.len());
    if n <= 2 * buckets.max(1) {
        return (0..n).map(|i| (t[i], y[i])).collect();
    }
    let size = n.div_ceil(buckets.max(1));
    let mut out = Vec::with_capacity(2 * buckets + 2);
    let mut start = 0;
    while start < n {
        let end = (start + size).min(n);
        let mut lo: Option<usize> = None;
        let mut hi: Option<usize> = None;
        for i in start..end {
            if !(y[i].is_finite() && t[i].is_finite()) {
                continue;
            }
            if lo.is_none_or(|k| y[i] < y[k]) {
                lo = Some(i);
            }
            if hi.is_none_or(|k| y[i] > y[k]) {
                hi = Some(i);
            }
        }
        match (lo, hi) {
            (Some(a), Some(b)) => {
                let (a, b) = (a.min(b), a.max(b));
                out.push((t[a], y[a]));
                if b != a {
                    out.push((t[b], y[b]));
                }
            }
            _ => out.push((t[start], f64::NAN)),
        }
        start = end;
    }
    out
}

/// Opacity of shaded time intervals (mode bands).
pub(crate) const BAND_ALPHA: f64 = 0.22;

/// How a legend entry is drawn.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Swatch {
    /// A line sample.
    Line {
        color: RGBColor,
        width: u32,
        dashed: bool,
    },
    /// A filled circle marker.
    Circle(RGBColor),
    /// A filled square marker.
    Square(RGBColor),
    /// A filled triangle marker (pointing up).
    Triangle(RGBColor),
    /// A translucent band (a shaded time interval).
    Band(RGBColor),
}

/// One legend entry.
#[derive(Debug, Clone)]
pub(crate) struct LegendEntry {
    pub label: String,
    pub swatch: Swatch,
}

impl LegendEntry {
    pub fn line(label: impl Into<String>, color: RGBColor, width: u32, dashed: bool) -> Self {
        LegendEntry {
            label: label.into(),
            swatch: Swatch::Line {
                color,
                width,
                dashed,
            },
        }
    }
}

/// Corner of the plotting area a legend sits in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Corner {
    UpperRight,
    UpperLeft,
    LowerRight,
    LowerLeft,
}

const SWATCH_W: f64 = 26.0;
const ENTRY_GAP: f64 = 18.0;
const ROW_H: f64 = 18.0;
const PAD: f64 = 6.0;
const INSET: f64 = 8.0;

/// A legend laid out in rows no wider than a limit.
#[derive(Debug, Clone)]
pub(crate) struct Legend {
    rows: Vec<Vec<(LegendEntry, f64)>>,
    /// Box width and height, pixels.
    pub size: (f64, f64),
}

impl Legend {
    /// Lay out entries left to right, wrapping at `max_width` pixels; `one_per_row` stacks them.
    pub fn layout(entries: &[LegendEntry], max_width: f64, one_per_row: bool) -> Legend {
        let mut rows: Vec<Vec<(LegendEntry, f64)>> = Vec::new();
        let mut row_w = 0.0;
        let mut width: f64 = 0.0;
        for e in entries {
            let w = SWATCH_W + 6.0 + text_width(&e.label, LEGEND_SIZE);
            let need = if row_w > 0.0 { ENTRY_GAP + w } else { w };
            if rows.is_empty() || one_per_row || row_w + need > max_width - 2.0 * PAD {
                rows.push(Vec::new());
                row_w = w;
            } else {
                row_w += need;
            }
            width = width.max(row_w);
            rows.last_mut().expect("a row").push((e.clone(), w));
        }
        let size = (
            width + 2.0 * PAD,
            rows.len() as f64 * ROW_H + 2.0 * PAD - 2.0,
        );
        Legend { rows, size }
    }

    /// The legend's box in fractions of the plotting area (x from the left, y from the top).
    fn frac_box(&self, corner: Corner, dim: (f64, f64)) -> (f64, f64, f64, f64) {
        let (w, h) = (
            (self.size.0 + INSET) / dim.0.max(1.0),
            (self.size.1 + INSET) / dim.1.max(1.0),
        );
        match corner {
            Corner::UpperRight => (1.0 - w, 1.0, 0.0, h),
            Corner::UpperLeft => (0.0, w, 0.0, h),
            Corner::LowerRight => (1.0 - w, 1.0, 1.0 - h, 1.0),
            Corner::LowerLeft => (0.0, w, 1.0 - h, 1.0),
        }
    }

    /// The corner where the fewest data points would be hidden, and how many that is.
    /// `series` are in data coordinates of `bounds`; `dim` is the plotting area in pixels.
    pub fn best_corner(
        &self,
        series: &[&[Pt]],
        bounds: &Bounds,
        dim: (f64, f64),
    ) -> (Corner, usize) {
        let mut best = (Corner::UpperRight, usize::MAX);
        for corner in [
            Corner::UpperRight,
            Corner::UpperLeft,
            Corner::LowerRight,
            Corner::LowerLeft,
        ] {
            let (fx0, fx1, fy0, fy1) = self.frac_box(corner, dim);
            let hidden = series
                .iter()
                .flat_map(|s| s.iter())
                .filter(|p| {
                    let fx = (p.0 - bounds.x0) / (bounds.x1 - bounds.x0);
                    let fy = (bounds.y1 - p.1) / (bounds.y1 - bounds.y0);
                    fx >= fx0 && fx <= fx1 && fy >= fy0 && fy <= fy1
                })
                .count();
            if hidden < best.1 {
                best = (corner, hidden);
            }
        }
        best
    }

    /// Fraction of the plotting height the legend takes (for making headroom above data).
    pub fn height_fraction(&self, dim_h: f64) -> f64 {
        ((self.size.1 + INSET) / dim_h.max(1.0)).min(0.6)
    }

    /// The legend's box (x0, y0, x1, y1) in pixels of a plotting area of `dim` pixels.
    pub fn pixel_box(&self, corner: Corner, dim: (f64, f64)) -> (f64, f64, f64, f64) {
        let (bw, bh) = self.size;
        let x0 = match corner {
            Corner::UpperRight | Corner::LowerRight => dim.0 - INSET - bw,
            _ => INSET,
        };
        let y0 = match corner {
            Corner::UpperRight | Corner::UpperLeft => INSET,
            _ => dim.1 - INSET - bh,
        };
        let (x0, y0) = (x0.max(0.0), y0.max(0.0));
        (x0, y0, x0 + bw, y0 + bh)
    }

    /// Draw the legend in a corner of a plotting area given in pixels.
    pub fn draw(&self, area: &Area<'_>, corner: Corner) -> DrawResult<()> {
        let (w, h) = area.dim_in_pixel();
        let (bw, bh) = self.size;
        let (x0, y0, _, _) = self.pixel_box(corner, (w as f64, h as f64));
        let px = |x: f64, y: f64| (x.round() as i32, y.round() as i32);
        area.draw(&Rectangle::new(
            [px(x0, y0), px(x0 + bw, y0 + bh)],
            WHITE.mix(0.85).filled(),
        ))
        .map_err(de)?;
        area.draw(&Rectangle::new(
            [px(x0, y0), px(x0 + bw, y0 + bh)],
            RGBColor(120, 120, 120).stroke_width(1),
        ))
        .map_err(de)?;
        let style = TextStyle::from((FONT, LEGEND_SIZE).into_font())
            .color(&BLACK)
            .pos(Pos::new(HPos::Left, VPos::Center));
        for (r, row) in self.rows.iter().enumerate() {
            let yc = y0 + PAD + (r as f64 + 0.5) * ROW_H - 1.0;
            let mut x = x0 + PAD;
            for (e, ew) in row {
                match e.swatch {
                    Swatch::Line {
                        color,
                        width,
                        dashed,
                    } => {
                        let st = color.stroke_width(width);
                        if dashed {
                            for (a, b) in [(0.0, 9.0), (13.0, 22.0)] {
                                area.draw(&PathElement::new(
                                    vec![px(x + a, yc), px(x + b, yc)],
                                    st,
                                ))
                                .map_err(de)?;
                            }
                        } else {
                            area.draw(&PathElement::new(
                                vec![px(x, yc), px(x + SWATCH_W - 4.0, yc)],
                                st,
                            ))
                            .map_err(de)?;
                        }
                    }
                    Swatch::Circle(c) => {
                        area.draw(&Circle::new(px(x + 11.0, yc), 5, c.filled()))
                            .map_err(de)?;
                        area.draw(&Circle::new(px(x + 11.0, yc), 5, BLACK.stroke_width(1)))
                            .map_err(de)?;
                    }
                    Swatch::Square(c) => {
                        area.draw(&Rectangle::new(
                            [px(x + 6.0, yc - 5.0), px(x + 16.0, yc + 5.0)],
                            c.filled(),
                        ))
                        .map_err(de)?;
                    }
                    Swatch::Triangle(c) => {
                        area.draw(&Polygon::new(
                            vec![
                                px(x + 5.0, yc + 5.0),
                                px(x + 17.0, yc + 5.0),
                                px(x + 11.0, yc - 6.0),
                            ],
                            c.filled(),
                        ))
                        .map_err(de)?;
                    }
                    Swatch::Band(c) => {
                        area.draw(&Rectangle::new(
                            [px(x, yc - 7.0), px(x + SWATCH_W - 4.0, yc + 7.0)],
                            c.mix(BAND_ALPHA).filled(),
                        ))
                        .map_err(de)?;
                    }
                }
                area.draw(&Text::new(
                    e.label.clone(),
                    px(x + SWATCH_W + 6.0, yc),
                    style.clone(),
                ))
                .map_err(de)?;
                x += ew + ENTRY_GAP;
            }
        }
        Ok(())
    }
}

/// A note centred in an area (e.g. "no data").
pub(crate) fn draw_note(area: &Area<'_>, text: &str) -> DrawResult<()> {
    let (w, h) = area.dim_in_pixel();
    let style = TextStyle::from((FONT, NOTE_SIZE).into_font())
        .color(&RGBColor(110, 110, 110))
        .pos(Pos::new(HPos::Center, VPos::Center));
    area.draw(&Text::new(
        text.to_string(),
        ((w / 2) as i32, (h / 2) as i32),
        style,
    ))
    .map_err(de)
}

/// Tick label: a short decimal with as many digits as the tick spacing `step` needs.
pub(crate) fn tick_label(v: f64, step: f64) -> String {
    if !v.is_finite() {
        return String::new();
    }
    let step = step.abs();
    let decimals = if step > 0.0 && step.is_finite() {
        (-(step.log10().floor()) as i32).clamp(0, 6) as usize
    } else {
        2
    };
    let v = if v.abs() < step * 1e-6 { 0.0 } else { v };
    format!("{v:.decimals$}")
}

/// The tick spacing plotters chooses for at most `n` labels over `range`: the smallest of
/// 1, 2, 5 × 10ᵏ with no more than `n` of its multiples inside the range (plotters counts the
/// ticks that fall inside, not the range over the step: 0.5 s ticks over 0.001–8.017 s are 16,
/// not 17). Labels formatted for this step show every digit that distinguishes them.
pub(crate) fn nice_step((lo, hi): (f64, f64), n: usize) -> f64 {
    let (lo, hi) = (lo.min(hi), lo.max(hi));
    let raw = (hi - lo) / n.max(1) as f64;
    if !(raw > 0.0 && raw.is_finite()) {
        return 1.0;
    }
    let inside = |s: f64| (hi / s).floor() - (lo / s).ceil() + 1.0;
    // the step lies within a decade below the range over n (more multiples fit inside than
    // the quotient says by at most one)
    let mut mag = 10f64.powf(raw.log10().floor() - 1.0);
    loop {
        for f in [1.0, 2.0, 5.0] {
            let s = f * mag;
            if inside(s) <= n.max(1) as f64 {
                return s;
            }
        }
        mag *= 10.0;
    }
}

/// A solid or dashed line through `points` in chart coordinates.
pub(crate) fn draw_line<DB, CT>(
    chart: &mut ChartContext<'_, DB, CT>,
    points: &[Pt],
    style: ShapeStyle,
    dashed: bool,
) -> DrawResult<()>
where
    DB: DrawingBackend,
    CT: CoordTranslate<From = (f64, f64)>,
{
    if dashed {
        chart
            .draw_series(std::iter::once(DashedPathElement::new(
                points.iter().copied(),
                7,
                5,
                style,
            )))
            .map_err(de)?;
    } else {
        chart
            .draw_series(LineSeries::new(points.iter().copied(), style))
            .map_err(de)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clipping_splits_and_ends_at_the_border() {
        let r = Bounds {
            x0: 0.0,
            x1: 10.0,
            y0: 0.0,
            y1: 1.0,
        };
        let pts = [
            (1.0, 0.5),
            (2.0, 0.5),
            (3.0, 2.0), // leaves through the top at x = 2 + 1/3
            (4.0, 0.5), // re-enters
            (5.0, f64::NAN),
            (6.0, 0.5),
            (7.0, 0.5),
        ];
        let segs = clip_polyline(&pts, &r);
        assert_eq!(segs.len(), 3, "{segs:?}");
        assert_eq!(segs[0][0], (1.0, 0.5));
        let exit = *segs[0].last().unwrap();
        assert!((exit.0 - (2.0 + 1.0 / 3.0)).abs() < 1e-12 && exit.1 == 1.0);
        assert_eq!(segs[1].last(), Some(&(4.0, 0.5)));
        assert_eq!(segs[2], vec![(6.0, 0.5), (7.0, 0.5)]);
    }

    #[test]
    fn thinning_keeps_the_envelope() {
        let t: Vec<f64> = (0..100_000).map(|i| i as f64 * 1e-3).collect();
        let y: Vec<f64> = t
            .iter()
            .map(|t| (2.0 * std::f64::consts::PI * 7.0 * t).sin())
            .collect();
        let p = thin_min_max(&t, &y, 500);
        assert!(p.len() <= 1002);
        let (lo, hi) = finite_range(p.iter().map(|p| p.1)).unwrap();
        assert!(lo < -0.99 && hi > 0.99);
        assert!(p.windows(2).all(|w| w[0].0 <= w[1].0));
    }

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick_label(0.30000000000000004, 0.1), "0.3");
        assert_eq!(tick_label(1500.0, 500.0), "1500");
        assert_eq!(tick_label(-1e-17, 0.05), "0.00");
    }
}
