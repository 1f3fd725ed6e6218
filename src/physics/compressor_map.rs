//! Compressor maps: the analytic Moore–Greitzer cubic or a polynomial fitted by least squares
//! to tabulated speed-line points, and the surge line derived from either.
//!
//! Polynomial map (seed 001 eq. 2.11; seed 002 App. A): each speed line is a cubic in flow,
//! Ψc(q, N) = C₃(N) q³ + C₂(N) q² + C₁(N) q + C₀(N), and each coefficient is a cubic in speed
//! (centred and scaled, as the MATLAB procedure of seed 002 App. A). Fitting is two-stage:
//! a least-squares cubic per speed line, then a least-squares cubic in speed per coefficient.
//!
//! The surge line is *derived*: the peak ∂Ψc/∂q = 0 of every speed line (seed 001 §3.3,
//! seed 002 §2.1.2), sampled over the map's speed range and tabulated for interpolation.
//!
//! Outside the data the map is continued physically: linearly (C¹) in flow beyond the fitted
//! flow range, and by the fan laws (q ∝ N, Ψ−1 ∝ N²) beyond the fitted speed range.

use super::characteristic::{MapPoint, MooreGreitzerCubic};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// What the flow axis of a map measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FlowCoordinate {
    /// Mass flow, kg/s.
    MassKgS,
    /// Volumetric flow at suction conditions, m³/s (invariant coordinate, seed 002 §2.3.1).
    InletVolumeM3S,
}

impl FlowCoordinate {
    /// Column header used in map CSV files.
    pub const fn csv_header(self) -> &'static str {
        match self {
            FlowCoordinate::MassKgS => "mass_flow_kg_s",
            FlowCoordinate::InletVolumeM3S => "volume_flow_m3_s",
        }
    }
    /// Unit for messages and plots.
    pub const fn unit(self) -> &'static str {
        match self {
            FlowCoordinate::MassKgS => "kg/s",
            FlowCoordinate::InletVolumeM3S => "m³/s",
        }
    }
}

/// Errors building a map.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    /// The CSV file cannot be read or parsed.
    #[error("{file}: {message}")]
    Csv {
        /// The file.
        file: PathBuf,
        /// What is wrong (with the line where known).
        message: String,
    },
    /// The data cannot support the fit.
    #[error("{file}: {message}")]
    Fit {
        /// The file.
        file: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// One tabulated point of a speed line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapSample {
    /// Shaft speed, rad/s.
    pub omega_rad_s: f64,
    /// Flow in the map's coordinate.
    pub flow: f64,
    /// Pressure ratio p_d/p_s.
    pub pressure_ratio: f64,
}

/// Read speed-line samples from a CSV file with header
/// `speed_rad_s,<mass_flow_kg_s|volume_flow_m3_s>,pressure_ratio` (lines starting with `#`
/// are comments).
pub fn read_map_csv(path: &Path) -> Result<(FlowCoordinate, Vec<MapSample>), MapError> {
    let err = |message: String| MapError::Csv {
        file: path.to_path_buf(),
        message,
    };
    let mut rdr = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_path(path)
        .map_err(|e| err(format!("cannot read: {e}")))?;
    let headers = rdr
        .headers()
        .map_err(|e| err(format!("bad header: {e}")))?
        .clone();
    let cols: Vec<&str> = headers.iter().collect();
    let coord = match cols.as_slice() {
        ["speed_rad_s", "mass_flow_kg_s", "pressure_ratio"] => FlowCoordinate::MassKgS,
        ["speed_rad_s", "volume_flow_m3_s", "pressure_ratio"] => FlowCoordinate::InletVolumeM3S,
        _ => {
            return Err(err(format!(
                "header must be `speed_rad_s,mass_flow_kg_s,pressure_ratio` or `speed_rad_s,volume_flow_m3_s,pressure_ratio`, found `{}`",
                cols.join(",")
            )))
        }
    };
    let mut out = Vec::new();
    for rec in rdr.records() {
        let rec = rec.map_err(|e| err(format!("{e}")))?;
        let line = rec.position().map_or(0, |p| p.line());
        let num = |i: usize| -> Result<f64, MapError> {
            rec.get(i)
                .and_then(|s| s.parse::<f64>().ok())
                .filter(|v| v.is_finite())
                .ok_or_else(|| err(format!("line {line}: column {} is not a number", i + 1)))
        };
        let s = MapSample {
            omega_rad_s: num(0)?,
            flow: num(1)?,
            pressure_ratio: num(2)?,
        };
        if s.omega_rad_s <= 0.0 {
            return Err(err(format!("line {line}: speed must be positive")));
        }
        if s.pressure_ratio <= 0.0 {
            return Err(err(format!("line {line}: pressure ratio must be positive")));
        }
        out.push(s);
    }
    Ok((coord, out))
}

/// Polynomial map: Ψ(q, ω) = Σᵢ Σⱼ aᵢⱼ (q/q_s)ⁱ ŝʲ, ŝ = (ω − ω_c)/ω_s, i, j ∈ 0..4.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PolynomialMap {
    /// aᵢⱼ: i = power of scaled flow, j = power of scaled speed.
    pub coeffs: [[f64; 4]; 4],
    /// Flow scale q_s (conditioning only).
    pub flow_scale: f64,
    /// Speed centre ω_c, rad/s.
    pub omega_center: f64,
    /// Speed scale ω_s, rad/s.
    pub omega_scale: f64,
    /// Lowest fitted speed, rad/s.
    pub omega_min: f64,
    /// Highest fitted speed, rad/s.
    pub omega_max: f64,
    /// Below this flow (map units) the speed line is continued linearly.
    pub flow_lo: f64,
    /// Above this flow (map units) the speed line is continued linearly.
    pub flow_hi: f64,
}

/// Least-squares fit; returns coefficients of 1, x, x², x³.
fn lstsq_cubic(xs: &[f64], ys: &[f64]) -> Option<[f64; 4]> {
    let n = xs.len();
    let a = DMatrix::from_fn(n, 4, |r, c| xs[r].powi(c as i32));
    let b = DVector::from_column_slice(ys);
    let sol = a.svd(true, true).solve(&b, 1e-12).ok()?;
    Some([sol[0], sol[1], sol[2], sol[3]])
}

impl PolynomialMap {
    /// The same map with its flows scaled by `flow_factor` and its pressure rise Ψ − 1 by
    /// `rise_factor` (a map that is off from the machine: the benchmark's and the campaign's
    /// "map off" cases).
    pub fn scaled(mut self, flow_factor: f64, rise_factor: f64) -> PolynomialMap {
        self.flow_scale *= flow_factor;
        self.flow_lo *= flow_factor;
        self.flow_hi *= flow_factor;
        for row in self.coeffs.iter_mut() {
            for c in row.iter_mut() {
                *c *= rise_factor;
            }
        }
        self.coeffs[0][0] += 1.0 - rise_factor;
        self
    }

    /// Two-stage least-squares fit of the samples (seed 002 App. A procedure).
    pub fn fit(samples: &[MapSample], file: &Path) -> Result<PolynomialMap, MapError> {
        let fit_err = |message: String| MapError::Fit {
            file: file.to_path_buf(),
            message,
        };
        // group by speed
        let mut speeds: Vec<f64> = Vec::new();
        for s in samples {
            if !speeds
                .iter()
                .any(|&w| (w - s.omega_rad_s).abs() <= 1e-9 * w.abs().max(1.0))
            {
                speeds.push(s.omega_rad_s);
            }
        }
        speeds.sort_by(f64::total_cmp);
        if speeds.len() < 4 {
            return Err(fit_err(format!(
                "need at least 4 speed lines for a cubic in speed, found {}",
                speeds.len()
            )));
        }
        let flow_scale = samples
            .iter()
            .map(|s| s.flow.abs())
            .fold(0.0, f64::max)
            .max(1e-12);
        let (mut q_min, mut q_max) = (f64::INFINITY, f64::NEG_INFINITY);
        // stage 1: a cubic per speed line
        let mut line_coeffs: Vec<[f64; 4]> = Vec::new();
        for &w in &speeds {
            let pts: Vec<&MapSample> = samples
                .iter()
                .filter(|s| (s.omega_rad_s - w).abs() <= 1e-9 * w.abs().max(1.0))
                .collect();
            if pts.len() < 4 {
                return Err(fit_err(format!(
                    "speed line {w} rad/s has {} points; a cubic needs at least 4",
                    pts.len()
                )));
            }
            for p in &pts {
                q_min = q_min.min(p.flow);
                q_max = q_max.max(p.flow);
            }
            let xs: Vec<f64> = pts.iter().map(|p| p.flow / flow_scale).collect();
            let ys: Vec<f64> = pts.iter().map(|p| p.pressure_ratio).collect();
            let c = lstsq_cubic(&xs, &ys)
                .ok_or_else(|| fit_err(format!("speed line {w} rad/s: singular fit")))?;
            line_coeffs.push(c);
        }
        // stage 2: each coefficient cubic in centred/scaled speed
        let n = speeds.len() as f64;
        let omega_center = speeds.iter().sum::<f64>() / n;
        let var = speeds
            .iter()
            .map(|w| (w - omega_center).powi(2))
            .sum::<f64>()
            / (n - 1.0);
        let omega_scale = var.sqrt().max(1e-9);
        let sh: Vec<f64> = speeds
            .iter()
            .map(|w| (w - omega_center) / omega_scale)
            .collect();
        let mut coeffs = [[0.0; 4]; 4];
        for (i, row) in coeffs.iter_mut().enumerate() {
            let ys: Vec<f64> = line_coeffs.iter().map(|c| c[i]).collect();
            *row = lstsq_cubic(&sh, &ys)
                .ok_or_else(|| fit_err(format!("coefficient {i}: singular fit in speed")))?;
        }
        let range = q_max - q_min;
        let map = PolynomialMap {
            coeffs,
            flow_scale,
            omega_center,
            omega_scale,
            omega_min: speeds[0],
            omega_max: speeds[speeds.len() - 1],
            flow_lo: q_min - 0.5 * range,
            flow_hi: q_max + 0.25 * range,
        };
        // every speed line inside the data must have a peak (a surge point)
        for &w in &speeds {
            if map.peak_inside(w).is_none() {
                return Err(fit_err(format!(
                    "speed line {w} rad/s has no pressure peak: cannot derive the surge line (add points left of the peak)"
                )));
            }
        }
        Ok(map)
    }

    /// Coefficients of the speed line at ω (inside the fitted speed range): c[i] for (q/q_s)ⁱ,
    /// and their derivatives with respect to ω.
    #[inline]
    fn line(&self, omega: f64) -> ([f64; 4], [f64; 4]) {
        let sh = (omega - self.omega_center) / self.omega_scale;
        let mut c = [0.0; 4];
        let mut dc = [0.0; 4];
        for i in 0..4 {
            let a = &self.coeffs[i];
            c[i] = a[0] + sh * (a[1] + sh * (a[2] + sh * a[3]));
            dc[i] = (a[1] + sh * (2.0 * a[2] + sh * 3.0 * a[3])) / self.omega_scale;
        }
        (c, dc)
    }

    /// Evaluate inside the fitted speed range (flow continued linearly outside its range).
    #[inline]
    fn eval_in_range(&self, q: f64, omega: f64) -> MapPoint {
        let (c, dc) = self.line(omega);
        let poly = |c: &[f64; 4], x: f64| c[0] + x * (c[1] + x * (c[2] + x * c[3]));
        let dpoly = |c: &[f64; 4], x: f64| c[1] + x * (2.0 * c[2] + x * 3.0 * c[3]);
        let qs = self.flow_scale;
        let x = q / qs;
        let xb = if q < self.flow_lo {
            Some(self.flow_lo / qs)
        } else if q > self.flow_hi {
            Some(self.flow_hi / qs)
        } else {
            None
        };
        match xb {
            None => MapPoint {
                value: poly(&c, x),
                d_dflow: dpoly(&c, x) / qs,
                d_domega: poly(&dc, x),
            },
            Some(xb) => {
                let slope = dpoly(&c, xb);
                let dslope_dw = dpoly(&dc, xb);
                MapPoint {
                    value: poly(&c, xb) + slope * (x - xb),
                    d_dflow: slope / qs,
                    d_domega: poly(&dc, xb) + dslope_dw * (x - xb),
                }
            }
        }
    }

    /// Pressure ratio and derivatives at flow `q` (map units) and speed ω (rad/s).
    #[inline]
    pub fn eval(&self, q: f64, omega: f64) -> MapPoint {
        let omega = omega.max(0.0);
        let wb = if omega < self.omega_min {
            self.omega_min
        } else if omega > self.omega_max {
            self.omega_max
        } else {
            return self.eval_in_range(q, omega);
        };
        // fan laws from the boundary speed line: Ψ = 1 + r² (Ψ_b(q/r) − 1), r = ω/ω_b
        let r = omega / wb;
        if r < 1e-9 {
            return MapPoint {
                value: 1.0,
                d_dflow: 0.0,
                d_domega: 0.0,
            };
        }
        let p = self.eval_in_range(q / r, wb);
        MapPoint {
            value: 1.0 + r * r * (p.value - 1.0),
            d_dflow: r * p.d_dflow,
            d_domega: (2.0 * r * (p.value - 1.0) - q * p.d_dflow) / wb,
        }
    }

    /// Peak of the speed line at ω inside the fitted speed range: (flow, ratio).
    fn peak_inside(&self, omega: f64) -> Option<(f64, f64)> {
        let (c, _) = self.line(omega);
        // d/dx: 3c3 x² + 2c2 x + c1 = 0, maximum where 6c3 x + 2c2 < 0
        let (a, b, cc) = (3.0 * c[3], 2.0 * c[2], c[1]);
        let mut best: Option<f64> = None;
        if a.abs() < 1e-14 {
            if b < 0.0 {
                best = Some(-cc / b);
            }
        } else {
            let disc = b * b - 4.0 * a * cc;
            if disc < 0.0 {
                return None;
            }
            let sq = disc.sqrt();
            for x in [(-b + sq) / (2.0 * a), (-b - sq) / (2.0 * a)] {
                if 6.0 * c[3] * x + 2.0 * c[2] < 0.0 {
                    best = Some(x);
                }
            }
        }
        let x = best?;
        let q = x * self.flow_scale;
        if q < self.flow_lo || q > self.flow_hi {
            return None;
        }
        Some((q, self.eval_in_range(q, omega).value))
    }

    /// Peak at any speed (fan laws outside the fitted range).
    pub fn peak(&self, omega: f64) -> Option<(f64, f64)> {
        let omega = omega.max(0.0);
        let wb = omega.clamp(self.omega_min, self.omega_max);
        let (q, v) = self.peak_inside(wb)?;
        let r = omega / wb;
        Some((q * r, 1.0 + r * r * (v - 1.0)))
    }
}

/// Number of tabulated surge-line points.
pub const SURGE_LINE_POINTS: usize = 65;

/// The surge line: peaks of the speed lines, tabulated over a speed range and monotone in
/// pressure ratio, so that q_SL = j(R_p) (seed 002 eq. 2.4) can be interpolated without
/// allocation in the control cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurgeLine {
    omega: [f64; SURGE_LINE_POINTS],
    flow: [f64; SURGE_LINE_POINTS],
    ratio: [f64; SURGE_LINE_POINTS],
}

impl SurgeLine {
    /// Tabulate from a peak function over [ω_lo, ω_hi]. Fails if a speed line has no peak or
    /// the peak ratio is not strictly increasing with speed.
    pub fn tabulate(
        omega_lo: f64,
        omega_hi: f64,
        peak: impl Fn(f64) -> Option<(f64, f64)>,
    ) -> Result<SurgeLine, String> {
        let mut sl = SurgeLine {
            omega: [0.0; SURGE_LINE_POINTS],
            flow: [0.0; SURGE_LINE_POINTS],
            ratio: [0.0; SURGE_LINE_POINTS],
        };
        for k in 0..SURGE_LINE_POINTS {
            let w = omega_lo + (omega_hi - omega_lo) * k as f64 / (SURGE_LINE_POINTS - 1) as f64;
            let (q, r) = peak(w).ok_or_else(|| format!("no surge point at {w:.1} rad/s"))?;
            sl.omega[k] = w;
            sl.flow[k] = q;
            sl.ratio[k] = r;
            if k > 0 && (r.is_nan() || r <= sl.ratio[k - 1]) {
                return Err(format!(
                    "surge-line pressure ratio does not increase with speed near {w:.1} rad/s"
                ));
            }
        }
        Ok(sl)
    }

    /// Lowest and highest tabulated speed, rad/s.
    pub fn omega_range(&self) -> (f64, f64) {
        (self.omega[0], self.omega[SURGE_LINE_POINTS - 1])
    }

    /// (flow, ratio) samples, for plots.
    pub fn points(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.flow.iter().copied().zip(self.ratio.iter().copied())
    }

    /// Surge flow at a pressure ratio: q_SL = j(R_p) (seed 002 eq. 2.4). Outside the table the
    /// fan laws are used (q ∝ √(R_p − 1)). Allocation-free.
    pub fn flow_at_ratio(&self, ratio: f64) -> f64 {
        let n = SURGE_LINE_POINTS;
        if ratio <= self.ratio[0] {
            let x = ((ratio - 1.0) / (self.ratio[0] - 1.0)).max(0.0);
            return self.flow[0] * x.sqrt();
        }
        if ratio >= self.ratio[n - 1] {
            let x = (ratio - 1.0) / (self.ratio[n - 1] - 1.0);
            return self.flow[n - 1] * x.sqrt();
        }
        let k = self.ratio.partition_point(|&r| r <= ratio).clamp(1, n - 1);
        let t = (ratio - self.ratio[k - 1]) / (self.ratio[k] - self.ratio[k - 1]);
        self.flow[k - 1] + t * (self.flow[k] - self.flow[k - 1])
    }

    /// Slope dq_SL/dR_p at a pressure ratio (for gain conditions and control lines).
    pub fn slope_at_ratio(&self, ratio: f64) -> f64 {
        let h = 1e-4 * ratio.abs().max(1.0);
        (self.flow_at_ratio(ratio + h) - self.flow_at_ratio(ratio - h)) / (2.0 * h)
    }

    /// Surge flow at a speed, by interpolation (fan laws outside the table).
    pub fn flow_at_speed(&self, omega: f64) -> f64 {
        let n = SURGE_LINE_POINTS;
        if omega <= self.omega[0] {
            return self.flow[0] * omega.max(0.0) / self.omega[0];
        }
        if omega >= self.omega[n - 1] {
            return self.flow[n - 1] * omega / self.omega[n - 1];
        }
        let k = self.omega.partition_point(|&w| w <= omega).clamp(1, n - 1);
        let t = (omega - self.omega[k - 1]) / (self.omega[k] - self.omega[k - 1]);
        self.flow[k - 1] + t * (self.flow[k] - self.flow[k - 1])
    }
}

/// Which model a map uses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MapModel {
    /// Moore–Greitzer cubic with speed scaling (seed 001 eq. 2.10).
    Cubic(MooreGreitzerCubic),
    /// Polynomial fitted to CSV data (seed 001 eq. 2.11, seed 002 App. A).
    Polynomial(PolynomialMap),
}

/// A compressor map (pressure ratio versus flow and speed) with its derived surge line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CompressorMap {
    /// The model.
    pub model: MapModel,
    /// What the flow axis measures.
    pub flow_coordinate: FlowCoordinate,
    /// The derived surge line.
    pub surge_line: SurgeLine,
}

impl CompressorMap {
    /// A cubic map; the surge line is tabulated over [ω_lo, ω_hi].
    pub fn cubic(
        cubic: MooreGreitzerCubic,
        flow_coordinate: FlowCoordinate,
        omega_lo: f64,
        omega_hi: f64,
    ) -> Result<CompressorMap, String> {
        let surge_line = SurgeLine::tabulate(omega_lo, omega_hi, |w| Some(cubic.peak(w, 1.0)))?;
        Ok(CompressorMap {
            model: MapModel::Cubic(cubic),
            flow_coordinate,
            surge_line,
        })
    }

    /// A map fitted to a CSV file of speed-line points.
    pub fn from_csv(path: &Path) -> Result<CompressorMap, MapError> {
        let (coord, samples) = read_map_csv(path)?;
        let poly = PolynomialMap::fit(&samples, path)?;
        let surge_line = SurgeLine::tabulate(poly.omega_min, poly.omega_max, |w| poly.peak(w))
            .map_err(|message| MapError::Fit {
                file: path.to_path_buf(),
                message,
            })?;
        Ok(CompressorMap {
            model: MapModel::Polynomial(poly),
            flow_coordinate: coord,
            surge_line,
        })
    }

    /// Pressure ratio and partial derivatives at (flow in map units, ω rad/s).
    #[inline]
    pub fn eval(&self, flow: f64, omega_rad_s: f64) -> MapPoint {
        match &self.model {
            MapModel::Cubic(c) => c.eval(flow, omega_rad_s, 1.0),
            MapModel::Polynomial(p) => p.eval(flow, omega_rad_s),
        }
    }

    /// Pressure ratio only.
    #[inline]
    pub fn pressure_ratio(&self, flow: f64, omega_rad_s: f64) -> f64 {
        self.eval(flow, omega_rad_s).value
    }

    /// Surge point at a speed: (flow, ratio), exact (not interpolated).
    pub fn peak(&self, omega_rad_s: f64) -> Option<(f64, f64)> {
        match &self.model {
            MapModel::Cubic(c) => Some(c.peak(omega_rad_s, 1.0)),
            MapModel::Polynomial(p) => p.peak(omega_rad_s),
        }
    }

    /// Speed range the map was built for, rad/s.
    pub fn omega_range(&self) -> (f64, f64) {
        self.surge_line.omega_range()
    }

    /// sup over the region {ω ∈ [ω_lo, ω_hi], flow ∈ [q_lo, q_hi]} of ∂Ψ/∂flow, on a grid;
    /// used for the observer gain condition (seed 000 eq. 17).
    pub fn max_slope(&self, omega: (f64, f64), flow: (f64, f64)) -> f64 {
        let mut best = f64::NEG_INFINITY;
        for i in 0..=40 {
            let w = omega.0 + (omega.1 - omega.0) * i as f64 / 40.0;
            for j in 0..=200 {
                let q = flow.0 + (flow.1 - flow.0) * j as f64 / 200.0;
                best = best.max(self.eval(q, w).d_dflow);
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn synthetic_samples() -> Vec<MapSample> {
        // speed lines generated from a known cubic with fan-law scaling
        let truth = MooreGreitzerCubic {
            psi_c0: 1.6,
            semi_height: 0.35,
            semi_width: 2.0,
            omega_ref: 1000.0,
        };
        let mut v = Vec::new();
        for &w in &[700.0, 850.0, 1000.0, 1150.0, 1300.0] {
            let s = w / 1000.0;
            for k in 0..10 {
                let q = (-0.5 + 6.0 * k as f64 / 9.0) * s;
                v.push(MapSample {
                    omega_rad_s: w,
                    flow: q,
                    pressure_ratio: truth.eval(q, w, 1.0).value,
                });
            }
        }
        v
    }

    #[test]
    fn fit_reproduces_points_and_peak() {
        let samples = synthetic_samples();
        let m = PolynomialMap::fit(&samples, Path::new("synthetic")).expect("fit");
        for s in &samples {
            let v = m.eval(s.flow, s.omega_rad_s).value;
            assert!(
                (v - s.pressure_ratio).abs() / s.pressure_ratio < 5e-3,
                "{s:?} -> {v}"
            );
        }
        // fan-law scaling makes the cubic's coefficients go as 1/s in speed, so the cubic in
        // speed is an approximation: the peak is found within a few per mille
        let (q, r) = m.peak(1000.0).expect("peak");
        assert!((q - 4.0).abs() < 0.02, "{q}");
        assert!((r - 2.3).abs() < 0.005, "{r}");
    }

    #[test]
    fn derivatives_match_finite_differences_inside_and_outside() {
        let m = PolynomialMap::fit(&synthetic_samples(), Path::new("s")).expect("fit");
        for &(q, w) in &[
            (2.0, 900.0),
            (-2.0, 1000.0),
            (12.0, 1100.0),
            (1.0, 400.0),
            (3.0, 1600.0),
        ] {
            let p = m.eval(q, w);
            let dq = (m.eval(q + 1e-6, w).value - m.eval(q - 1e-6, w).value) / 2e-6;
            let dw = (m.eval(q, w + 1e-4).value - m.eval(q, w - 1e-4).value) / 2e-4;
            assert!(
                (p.d_dflow - dq).abs() < 1e-5 * (1.0 + dq.abs()),
                "q {q} w {w}: {} vs {dq}",
                p.d_dflow
            );
            assert!(
                (p.d_domega - dw).abs() < 1e-5 * (1.0 + dw.abs()),
                "q {q} w {w}: {} vs {dw}",
                p.d_domega
            );
        }
    }

    #[test]
    fn too_few_speed_lines_is_an_error() {
        let samples: Vec<MapSample> = synthetic_samples()
            .into_iter()
            .filter(|s| s.omega_rad_s < 1100.0)
            .collect();
        let e = PolynomialMap::fit(&samples, Path::new("f.csv")).unwrap_err();
        assert!(e.to_string().contains("at least 4 speed lines"), "{e}");
    }

    #[test]
    fn surge_line_interpolates_and_extrapolates_by_fan_laws() {
        let cubic = MooreGreitzerCubic {
            psi_c0: 1.6,
            semi_height: 0.35,
            semi_width: 2.0,
            omega_ref: 1000.0,
        };
        let map = CompressorMap::cubic(cubic, FlowCoordinate::MassKgS, 600.0, 1400.0).expect("map");
        // at ref speed, peak ratio 2.3 at flow 4
        assert!((map.surge_line.flow_at_ratio(2.3) - 4.0).abs() < 1e-3);
        assert!((map.surge_line.flow_at_speed(1000.0) - 4.0).abs() < 1e-9);
        // beyond the table: fan laws are exact for this map
        let (q, r) = cubic.peak(2000.0, 1.0);
        assert!((map.surge_line.flow_at_ratio(r) - q).abs() < 1e-9);
        let (q, r) = cubic.peak(300.0, 1.0);
        assert!((map.surge_line.flow_at_ratio(r) - q).abs() < 1e-9);
    }
}
