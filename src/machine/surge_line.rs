//! The surge limit line (SLL) in the forms vendors supply, converted to the one form the
//! controller uses: actual inlet volume flow q versus pressure ratio R_p at the machine's
//! reference suction temperature, tabulated as a [`SurgeLine`].
//!
//! Invariant coordinates (seed 002 §2.3.1): reduced flow q_r = q/√(Z R T_s/M) (eq. 2.1) and
//! reduced head h_r = (R_p^σ − 1)/σ (eq. 2.2). With a flow element, q = c_q √(Δp_o/p_s) and
//! c_q = c_f A₂ √(2 Z R T/M) (eq. 2.14), so q_r² = Δp_o/p_s up to the constant 2 (c_f A₂)²: the
//! line "Δp_o/p_s versus h_r" needs neither the gas density nor the temperature, and holds across
//! speeds, gases and suction conditions. A line stated at suction temperature T_ref moves to
//! q(T) = q(T_ref) √(T/T_ref) at another temperature (eq. 2.1 at constant q_r).

use crate::physics::compressor_map::SurgeLine;
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;

/// Unit of the flow column of surge-line points.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FlowUnit {
    /// Actual inlet volume flow, m³/s.
    #[default]
    M3S,
    /// Actual inlet volume flow, m³/h (as most vendor curves print it).
    M3H,
}

impl FlowUnit {
    /// Factor to m³/s.
    pub const fn to_m3_s(self) -> f64 {
        match self {
            FlowUnit::M3S => 1.0,
            FlowUnit::M3H => 1.0 / 3600.0,
        }
    }
}

/// What the head column of surge-line points measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum HeadAxis {
    /// Pressure ratio p_d/p_s.
    #[default]
    PressureRatio,
    /// Polytropic head, kJ/kg.
    PolytropicHeadKjKg,
}

/// A surge limit line as the vendor gave it, with the conditions it was stated at.
#[derive(Debug, Clone, PartialEq)]
pub enum SurgeLineForm {
    /// q_SL = c √(R_p − 1), q in m³/s at the stated suction temperature (seed 002 eq. 4.2 form).
    Sqrt {
        /// c, m³/s.
        c_m3_s: f64,
    },
    /// Points (flow, head) in the given units at the stated suction temperature.
    Points {
        /// (flow, head) pairs as written.
        points: Vec<[f64; 2]>,
        /// Unit of the flow column.
        flow_unit: FlowUnit,
        /// Meaning of the head column.
        head: HeadAxis,
    },
    /// Invariant points (q_r² = Δp_o/p_s, h_r = (R_p^σ − 1)/σ) (seed 002 §2.3.1); needs the
    /// flow element to become a volume flow.
    Reduced {
        /// (Δp_o/p_s, h_r) pairs.
        points: Vec<[f64; 2]>,
    },
}

/// Why a surge line cannot be used; `key` is the offending key below `[surge_line]`.
#[derive(Debug, Clone, PartialEq)]
pub struct SurgeLineError {
    /// Key below `surge_line` (e.g. `points`).
    pub key: &'static str,
    /// What is wrong.
    pub message: String,
    /// How to fix it.
    pub hint: String,
}

/// Lowest and highest pressure ratio the closed form is tabulated over (outside, the table
/// continues by the fan laws, q ∝ √(R_p − 1), which is the closed form itself).
const SQRT_RATIO_RANGE: (f64, f64) = (1.05, 6.0);

/// (R_p, q m³/s) points of a form at its stated suction temperature, sorted by R_p, checked.
pub fn ratio_flow_points(
    form: &SurgeLineForm,
    gas: &Gas,
    element: &Orifice,
    t_ref_k: f64,
) -> Result<Vec<(f64, f64)>, SurgeLineError> {
    let sigma = gas.polytropic_exponent;
    let ratio_of_head = |h_r: f64| (1.0 + sigma * h_r).max(0.0).powf(1.0 / sigma);
    let pts: Vec<(f64, f64)> = match form {
        SurgeLineForm::Sqrt { c_m3_s } => {
            if !(c_m3_s.is_finite() && *c_m3_s > 0.0) {
                return Err(SurgeLineError {
                    key: "sqrt_c_m3_s",
                    message: format!("must be a positive flow coefficient, found {c_m3_s}"),
                    hint: "q_SL = c·√(Rp − 1) with q in m³/s at suction, e.g. 0.354".into(),
                });
            }
            let (lo, hi) = SQRT_RATIO_RANGE;
            (0..=16)
                .map(|k| {
                    let r = lo + (hi - lo) * k as f64 / 16.0;
                    (r, c_m3_s * (r - 1.0).sqrt())
                })
                .collect()
        }
        SurgeLineForm::Points {
            points,
            flow_unit,
            head,
        } => points
            .iter()
            .map(|[q, h]| {
                let r = match head {
                    HeadAxis::PressureRatio => *h,
                    HeadAxis::PolytropicHeadKjKg => {
                        ratio_of_head(h * 1e3 / (gas.specific_constant_j_kg_k() * t_ref_k))
                    }
                };
                (r, q * flow_unit.to_m3_s())
            })
            .collect(),
        SurgeLineForm::Reduced { points } => {
            // q = c_q √(Δp/p_s), c_q = c_f A₂ √(2 Z R T/M) (seed 002 eq. 2.14)
            let c_q = element.flow_coefficient
                * element.bore_area_m2()
                * (2.0 * gas.specific_constant_j_kg_k() * t_ref_k).sqrt();
            points
                .iter()
                .map(|[q_r2, h_r]| (ratio_of_head(*h_r), c_q * q_r2.max(0.0).sqrt()))
                .collect()
        }
    };
    let key = match form {
        SurgeLineForm::Sqrt { .. } => "sqrt_c_m3_s",
        SurgeLineForm::Points { .. } => "points",
        SurgeLineForm::Reduced { .. } => "reduced_points",
    };
    if pts.len() < 3 {
        return Err(SurgeLineError {
            key,
            message: format!(
                "{} point(s): a surge line needs at least 3 (one per speed line)",
                pts.len()
            ),
            hint: "give the surge point of at least 3 speed lines, or the closed form sqrt_c_m3_s"
                .into(),
        });
    }
    for (i, (r, q)) in pts.iter().enumerate() {
        if !(r.is_finite() && *r > 1.0 && q.is_finite() && *q > 0.0) {
            return Err(SurgeLineError {
                key,
                message: format!(
                    "point {} gives pressure ratio {r:.4} and flow {q:.4} m³/s: need ratio > 1 and flow > 0",
                    i + 1
                ),
                hint: "each point is [flow, head] with a positive flow and a head above zero".into(),
            });
        }
        if i > 0 {
            let (r0, q0) = pts[i - 1];
            if !(*r > r0 && *q > q0) {
                return Err(SurgeLineError {
                    key,
                    message: format!(
                        "points {} and {} are not increasing (flow {q0:.4} → {q:.4} m³/s, ratio {r0:.4} → {r:.4}): a surge line rises in both flow and head",
                        i,
                        i + 1
                    ),
                    hint: "list the surge points from the lowest speed line to the highest".into(),
                });
            }
        }
    }
    Ok(pts)
}

/// Tabulate (R_p, q) points as a [`SurgeLine`], linear between points in the fan-law
/// coordinate s = √(R_p − 1) (so that the closed form c √(R_p − 1) is reproduced exactly). The
/// tabulation parameter s plays the role of an equivalent speed (fan laws: R_p − 1 ∝ N²), so
/// the table is monotone; beyond the points the line continues as q ∝ √(R_p − 1).
pub fn tabulate(points: &[(f64, f64)]) -> Result<SurgeLine, String> {
    let n = points.len();
    let s_of = |r: f64| (r - 1.0).max(0.0).sqrt();
    let s_lo = s_of(points[0].0);
    let s_hi = s_of(points[n - 1].0);
    SurgeLine::tabulate(s_lo, s_hi, |s| {
        let s = s.clamp(s_lo, s_hi);
        let k = points.partition_point(|p| s_of(p.0) <= s).clamp(1, n - 1);
        let (r0, q0) = points[k - 1];
        let (r1, q1) = points[k];
        let t = (s - s_of(r0)) / (s_of(r1) - s_of(r0));
        Some((q0 + t * (q1 - q0), 1.0 + s * s))
    })
}

/// The mass flow a volume flow `q_m3_s` at suction (p, T) produces through the flow element,
/// and its Δp, Pa (seed 002 eq. 2.12–2.13 inverted as eq. 3.19).
pub fn element_dp_pa(element: &Orifice, gas: &Gas, q_m3_s: f64, p_s_pa: f64, t_k: f64) -> f64 {
    let w = q_m3_s * gas.density_kg_m3(p_s_pa, t_k);
    element.dp_pa(gas, w, p_s_pa, t_k)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GAS: Gas = Gas {
        molar_mass_kg_mol: 0.022,
        heat_capacity_ratio: 1.3,
        compressibility: 1.0,
        polytropic_exponent: 0.25,
    };
    const EL: Orifice = Orifice {
        flow_coefficient: 0.6,
        bore_diameter_m: 0.187,
    };

    #[test]
    fn closed_form_is_reproduced_by_the_table_and_beyond() {
        let pts =
            ratio_flow_points(&SurgeLineForm::Sqrt { c_m3_s: 0.354 }, &GAS, &EL, 300.0).unwrap();
        let sl = tabulate(&pts).unwrap();
        for r in [1.2, 1.8, 2.5, 4.0, 8.0] {
            let q = 0.354 * (r - 1.0_f64).sqrt();
            let got = sl.flow_at_ratio(r);
            assert!((got - q).abs() < 2e-3 * q, "R {r}: {got} vs {q}");
        }
    }

    #[test]
    fn head_points_and_reduced_points_give_the_same_line() {
        let t = 300.0;
        let rs = [1.5, 2.0, 2.6, 3.2];
        let q = |r: f64| 0.354 * (r - 1.0).sqrt();
        let zrt = GAS.specific_constant_j_kg_k() * t;
        let s = GAS.polytropic_exponent;
        let head: Vec<[f64; 2]> = rs
            .iter()
            .map(|&r| [q(r) * 3600.0, zrt * (r.powf(s) - 1.0) / s / 1e3])
            .collect();
        let a = ratio_flow_points(
            &SurgeLineForm::Points {
                points: head,
                flow_unit: FlowUnit::M3H,
                head: HeadAxis::PolytropicHeadKjKg,
            },
            &GAS,
            &EL,
            t,
        )
        .unwrap();
        // Δp_o/p_s from the element: eq. 2.14 inverted
        let reduced: Vec<[f64; 2]> = rs
            .iter()
            .map(|&r| {
                let p_s = 2e6;
                let dp = element_dp_pa(&EL, &GAS, q(r), p_s, t);
                [dp / p_s, (r.powf(s) - 1.0) / s]
            })
            .collect();
        let b =
            ratio_flow_points(&SurgeLineForm::Reduced { points: reduced }, &GAS, &EL, t).unwrap();
        for ((ra, qa), (rb, qb)) in a.iter().zip(&b) {
            assert!(
                (ra - rb).abs() < 1e-9 && (qa - qb).abs() < 1e-9 * qa,
                "{ra} {qa} {rb} {qb}"
            );
        }
        for (k, &r) in rs.iter().enumerate() {
            assert!((a[k].0 - r).abs() < 1e-9);
            assert!((a[k].1 - q(r)).abs() < 1e-12);
        }
    }

    #[test]
    fn too_few_and_non_monotone_points_are_refused() {
        let e = ratio_flow_points(
            &SurgeLineForm::Points {
                points: vec![[0.3, 1.5], [0.4, 2.0]],
                flow_unit: FlowUnit::M3S,
                head: HeadAxis::PressureRatio,
            },
            &GAS,
            &EL,
            300.0,
        )
        .unwrap_err();
        assert!(e.message.contains("at least 3"), "{}", e.message);
        let e = ratio_flow_points(
            &SurgeLineForm::Points {
                points: vec![[0.3, 1.5], [0.45, 2.0], [0.4, 2.5]],
                flow_unit: FlowUnit::M3S,
                head: HeadAxis::PressureRatio,
            },
            &GAS,
            &EL,
            300.0,
        )
        .unwrap_err();
        assert!(e.message.contains("points 2 and 3"), "{}", e.message);
    }
}
