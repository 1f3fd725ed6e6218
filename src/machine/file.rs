//! The machine file (`config/machines/*.toml`): vendor data, asking only for what the
//! controller uses. Every key and its unit is documented in `config/machines/vendor_example.toml`
//! and docs/commissioning.md ("Commissioning from vendor data").
//!
//! Errors are located (file:line, key) with a hint: too few or non-monotone surge points,
//! flows that look like m³/h where m³/s is expected, a flow element that puts the surge line
//! outside any plausible differential pressure, a missing or doubled surge-line form.

use super::surge_line::{self, FlowUnit, HeadAxis, SurgeLineForm};
use super::{DesignPoint, FailPosition, MachineDescription, RecycleValve, TransmitterRange};
use crate::config::FileError;
use crate::machine::model::{MapSpec, ModelData};
use crate::machine::params::{DriveSpec, ModelKind};
use crate::physics::compressor_map::FlowCoordinate;
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;
use crate::physics::valve::{Characteristic, ValveSpec};
use crate::vocab::signals::SensorId;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// `[gas]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GasToml {
    /// Molar mass, kg/mol.
    pub molar_mass_kg_mol: f64,
    /// κ = cp/cv. Asked only where used: a surge line stated in polytropic head
    /// (`head = "polytropic_head_kj_kg"` or `reduced_points`) converts head to pressure ratio
    /// with σ, whose default comes from κ; with `polytropic_exponent` given, or a line stated
    /// in pressure ratio, κ may be left out.
    #[serde(default)]
    pub heat_capacity_ratio: Option<f64>,
    /// Compressibility Z at suction (default 1).
    #[serde(default)]
    pub compressibility: Option<f64>,
    /// Polytropic exponent σ = (n − 1)/n (default (κ − 1)/(κ η_p) with η_p = 0.8).
    #[serde(default)]
    pub polytropic_exponent: Option<f64>,
}

/// `[surge_line]`: exactly one form.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct SurgeLineToml {
    /// Closed form q_SL = c √(R_p − 1), c in m³/s (actual inlet volume flow).
    #[serde(default)]
    pub sqrt_c_m3_s: Option<f64>,
    /// Points `[flow, head]`, lowest speed line first.
    #[serde(default)]
    pub points: Option<Vec<[f64; 2]>>,
    /// Unit of the points' flow column (`m3_s` default, or `m3_h`).
    #[serde(default)]
    pub flow_unit: FlowUnit,
    /// Meaning of the points' head column (`pressure_ratio` default, or
    /// `polytropic_head_kj_kg`).
    #[serde(default)]
    pub head: HeadAxis,
    /// Invariant points `[Δp_o/p_s, h_r]` (seed 002 §2.3.1).
    #[serde(default)]
    pub reduced_points: Option<Vec<[f64; 2]>>,
}

/// `[speed_line_map]`: the SLL derived from speed lines (today's plant-file path), as a CSV
/// of speed-line points or a Moore–Greitzer cubic (one of the two).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpeedLineMapToml {
    /// CSV of speed-line points (`speed_rad_s,volume_flow_m3_s|mass_flow_kg_s,pressure_ratio`),
    /// relative to the machine file.
    #[serde(default)]
    pub file: Option<PathBuf>,
    /// A Moore–Greitzer cubic (seed 001 eq. 2.10); for `[model] family = "spool"` in the
    /// spool model's nondimensional units (seed 003 eq. 4–6).
    #[serde(default)]
    pub cubic: Option<CubicToml>,
}

/// `[speed_line_map.cubic]`: ψ(q, ω) = (ω/ω_ref)² (ψc0 + H·g(q/(W·ω/ω_ref) − 1)).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CubicToml {
    /// Shut-off pressure ratio ψc0 at the reference speed.
    pub psi_c0: f64,
    /// Semi-height H.
    pub semi_height: f64,
    /// Semi-width W in flow units (kg/s or m³/s).
    pub semi_width: f64,
    /// Reference speed, rad/s.
    pub omega_ref_rad_s: f64,
    /// Flow coordinate of W (`mass_kg_s` or `inlet_volume_m3_s`).
    pub flow_coordinate: FlowCoordinate,
    /// Speed range over which the surge line is tabulated, rad/s.
    pub omega_range_rad_s: [f64; 2],
}

/// `[flow_element]`: orifice geometry or a flow-element constant.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct FlowElementToml {
    /// c_w of w = c_w √(p₁ Δp), i.e. Δp = w²/(c_w² p₁), kg/s per Pa (seed 002 eq. 2.13), at
    /// the design suction temperature.
    #[serde(default)]
    pub c_w: Option<f64>,
    /// Flow coefficient c_f (discharge coefficient and 1/√(1 − β⁴), seed 002 eq. 2.10).
    #[serde(default)]
    pub flow_coefficient: Option<f64>,
    /// Bore diameter, m.
    #[serde(default)]
    pub bore_diameter_m: Option<f64>,
}

/// `[recycle_valve]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecycleValveToml {
    /// Inherent characteristic (default linear).
    #[serde(default = "linear")]
    pub characteristic: Characteristic,
    /// Full-stroke time, s.
    pub stroke_time_s: f64,
    /// Fail position (default open).
    #[serde(default)]
    pub fail_position: FailPosition,
    /// Capacity as an effective area, m² (optional: recycle-pi's throttle watch takes the
    /// throttle's share of the compressor flow from it; without it, the whole flow).
    #[serde(default)]
    pub cv_max_m2: Option<f64>,
}

fn linear() -> Characteristic {
    Characteristic::Linear
}

/// `[drive]`: whether the controller owns the speed loop, and the rating it then needs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveToml {
    /// The controller commands drive torque and runs the speed loop (default false: the
    /// drive's own governor keeps speed; taking over is a commissioning decision).
    #[serde(default)]
    pub owned_by_controller: bool,
    /// Rating and speed-loop gains (required when owned).
    #[serde(flatten, default)]
    pub spec: Option<DriveSpec>,
}

/// A machine file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MachineFile {
    /// Short name.
    pub name: String,
    /// Gas.
    pub gas: GasToml,
    /// Surge limit line.
    #[serde(default)]
    pub surge_line: Option<SurgeLineToml>,
    /// Speed-line map (the SLL derived from it).
    #[serde(default)]
    pub speed_line_map: Option<SpeedLineMapToml>,
    /// Flow element.
    pub flow_element: FlowElementToml,
    /// Design point (suction conditions of the SLL).
    pub design: DesignPoint,
    /// Transmitter ranges (4–20 mA) in SI units.
    #[serde(default)]
    pub transmitters: BTreeMap<SensorId, TransmitterRange>,
    /// Recycle valve.
    #[serde(default)]
    pub recycle_valve: Option<RecycleValveToml>,
    /// Drive.
    #[serde(default)]
    pub drive: Option<DriveToml>,
    /// Dynamic model data for the model-based laws (`family` plus the family's tables).
    #[serde(default)]
    pub model: Option<ModelData>,
}

/// Load a machine file; every error names file, line and key, with a hint.
pub fn load(path: &Path) -> Result<MachineDescription, FileError> {
    let (file, text): (MachineFile, String) = crate::config::toml_file::load(path)?;
    build(&file, path, &text)
}

fn positive(v: f64) -> bool {
    v.is_finite() && v > 0.0
}

/// Resolve a parsed machine file (paths relative to `path`).
pub fn build(f: &MachineFile, path: &Path, text: &str) -> Result<MachineDescription, FileError> {
    let at = |key: &str, msg: String| FileError::at_key(path, text, key, msg);
    // gas
    let g = &f.gas;
    if !positive(g.molar_mass_kg_mol) || g.molar_mass_kg_mol > 1.0 {
        return Err(at(
            "gas.molar_mass_kg_mol",
            format!("{} kg/mol is not a molar mass", g.molar_mass_kg_mol),
        )
        .with_hint("in kg/mol: air 0.029, natural gas ≈ 0.018–0.022 (not g/mol)"));
    }
    // κ and σ: σ converts a head axis to pressure ratio; nothing else of the controller
    // uses either, so they are asked for only when the surge line is stated in head
    let sl_given = f.surge_line.clone().unwrap_or_default();
    let sigma_used = sl_given.reduced_points.is_some()
        || (sl_given.points.is_some() && sl_given.head == HeadAxis::PolytropicHeadKjKg);
    let kappa = match g.heat_capacity_ratio {
        Some(k) if !(k.is_finite() && k > 1.0 && k < 2.0) => {
            return Err(at(
                "gas.heat_capacity_ratio",
                format!("κ = {k} must lie in (1, 2)"),
            )
            .with_hint("air 1.4, natural gas ≈ 1.3"));
        }
        Some(k) => k,
        None if sigma_used && g.polytropic_exponent.is_none() => {
            return Err(at(
                "gas",
                "the surge line is stated in polytropic head: gas.heat_capacity_ratio (κ) or \
                 gas.polytropic_exponent (σ) is needed to convert it to pressure ratio"
                    .into(),
            )
            .with_hint("heat_capacity_ratio = 1.3 (natural gas), 1.4 (air), from the data sheet"));
        }
        // (not used by anything this machine file describes)
        None => f64::NAN,
    };
    let gas = Gas {
        molar_mass_kg_mol: g.molar_mass_kg_mol,
        heat_capacity_ratio: kappa,
        compressibility: g.compressibility.unwrap_or(1.0),
        polytropic_exponent: g
            .polytropic_exponent
            .unwrap_or((kappa - 1.0) / (kappa * 0.8)),
    };
    if !(positive(gas.compressibility) && gas.compressibility <= 1.5) {
        return Err(at(
            "gas.compressibility",
            format!("Z = {} is not a compressibility", gas.compressibility),
        ));
    }
    if (g.polytropic_exponent.is_some() || sigma_used)
        && !(positive(gas.polytropic_exponent) && gas.polytropic_exponent < 1.0)
    {
        return Err(at(
            "gas.polytropic_exponent",
            format!("σ = {} must lie in (0, 1)", gas.polytropic_exponent),
        )
        .with_hint("σ = (n − 1)/n; ≈ (κ − 1)/(κ η_p), e.g. 0.3 for air"));
    }
    // design
    let d = f.design;
    if !(positive(d.suction_pressure_pa) && d.suction_pressure_pa > 1e3) {
        return Err(at(
            "design.suction_pressure_pa",
            format!(
                "{} Pa is not an absolute suction pressure",
                d.suction_pressure_pa
            ),
        )
        .with_hint("absolute pressure in Pa: 1 bar = 1e5 Pa, add the atmosphere to barg"));
    }
    if !(d.suction_temperature_k.is_finite() && (150.0..=700.0).contains(&d.suction_temperature_k))
    {
        return Err(at(
            "design.suction_temperature_k",
            format!("{} K is not a suction temperature", d.suction_temperature_k),
        )
        .with_hint("in kelvin: °C + 273.15"));
    }
    if let Some(r) = d.pressure_ratio {
        if !(r.is_finite() && r > 1.0) {
            return Err(at("design.pressure_ratio", format!("{r} must exceed 1")));
        }
    }
    let t_ref = d.suction_temperature_k;
    // flow element
    let fe = f.flow_element;
    let flow_element = match (fe.c_w, fe.flow_coefficient, fe.bore_diameter_m) {
        (Some(c_w), None, None) => {
            if !positive(c_w) {
                return Err(at("flow_element.c_w", format!("{c_w} must be positive")));
            }
            // c_w = c_f A₂ √(2M/(ZRT)) (seed 002 eq. 2.13): the orifice equations need only the
            // product c_f·A₂, carried as a unit coefficient and the equivalent bore
            let cf_a2 = c_w / (2.0 / (gas.specific_constant_j_kg_k() * t_ref)).sqrt();
            Orifice {
                flow_coefficient: 1.0,
                bore_diameter_m: (4.0 * cf_a2 / std::f64::consts::PI).sqrt(),
            }
        }
        (None, Some(cf), Some(d)) => {
            if !(positive(cf) && cf <= 1.5) {
                return Err(at(
                    "flow_element.flow_coefficient",
                    format!("{cf} is not a flow coefficient"),
                )
                .with_hint("c_f = C_d/√(1 − β⁴), typically 0.6–0.7 for an orifice"));
            }
            if !(positive(d) && d < 5.0) {
                return Err(at(
                    "flow_element.bore_diameter_m",
                    format!("{d} m is not a bore diameter"),
                )
                .with_hint("in metres: 187 mm = 0.187"));
            }
            Orifice {
                flow_coefficient: cf,
                bore_diameter_m: d,
            }
        }
        _ => {
            return Err(at(
                "flow_element",
                "give either `c_w` or both `flow_coefficient` and `bore_diameter_m`".into(),
            )
            .with_hint(
                "c_w from the data sheet: w = c_w·√(p₁·Δp) with w in kg/s and pressures in Pa",
            ))
        }
    };
    // surge line: exactly one of the forms, or a speed-line map
    let sl = f.surge_line.clone().unwrap_or_default();
    let forms: Vec<(&str, SurgeLineForm)> = [
        sl.sqrt_c_m3_s
            .map(|c| ("surge_line.sqrt_c_m3_s", SurgeLineForm::Sqrt { c_m3_s: c })),
        sl.points.clone().map(|p| {
            (
                "surge_line.points",
                SurgeLineForm::Points {
                    points: p,
                    flow_unit: sl.flow_unit,
                    head: sl.head,
                },
            )
        }),
        sl.reduced_points.clone().map(|p| {
            (
                "surge_line.reduced_points",
                SurgeLineForm::Reduced { points: p },
            )
        }),
    ]
    .into_iter()
    .flatten()
    .collect();
    // model data: checked before the map (a spool family's cubic needs the spool scales)
    if let Some(m) = &f.model {
        m.check("model.").map_err(|p| {
            let key = format!("model.{}", p.key);
            let mut e = FileError::at_key(path, text, &key, p.message.clone());
            if e.line == 0 {
                e = FileError::at_key(path, text, "model.family", p.message);
            }
            e.key = key;
            e.with_hint(p.hint)
        })?;
    }
    let map = match &f.speed_line_map {
        Some(m) => {
            let spec = match (&m.file, &m.cubic) {
                (Some(file), None) => MapSpec::Table { file: file.clone() },
                (None, Some(c)) => MapSpec::Cubic {
                    psi_c0: c.psi_c0,
                    semi_height: c.semi_height,
                    semi_width: c.semi_width,
                    omega_ref_rad_s: c.omega_ref_rad_s,
                    flow_coordinate: c.flow_coordinate,
                    omega_range_rad_s: c.omega_range_rad_s,
                },
                _ => {
                    return Err(at(
                        "speed_line_map",
                        "give the speed-line map either as `file` (CSV) or as `cubic`".into(),
                    )
                    .with_hint("[speed_line_map]\nfile = \"map.csv\""))
                }
            };
            let spool = f
                .model
                .as_ref()
                .filter(|m| m.family == ModelKind::Spool)
                .and_then(|m| m.spool.as_ref());
            Some(
                spec.build(path.parent().unwrap_or(Path::new(".")), spool)
                    .map_err(|(k, e)| {
                        let key = if k == "table.file" { "file" } else { k };
                        at(&format!("speed_line_map.{key}"), e)
                    })?,
            )
        }
        None => None,
    };
    let (surge_line, flow_coordinate) = match (forms.as_slice(), &map) {
        ([], Some(m)) => (m.surge_line, m.flow_coordinate),
        ([(key, form)], None) => {
            let pts = surge_line::ratio_flow_points(form, &gas, &flow_element, t_ref).map_err(
                |e| at(&format!("surge_line.{}", e.key), e.message).with_hint(e.hint),
            )?;
            check_units(&pts, form, &gas, &flow_element, &d, key, &at)?;
            let line = surge_line::tabulate(&pts).map_err(|m| at(key, m))?;
            (line, FlowCoordinate::InletVolumeM3S)
        }
        ([], None) => {
            return Err(at("surge_line", "the machine has no surge limit line".into()).with_hint(
                "add [surge_line] with sqrt_c_m3_s, points or reduced_points, or [speed_line_map]",
            ))
        }
        ([(key, _)], Some(_)) | ([(key, _), ..], _) => {
            return Err(at(
                key,
                "give the surge line in one form only (sqrt_c_m3_s, points, reduced_points or a [speed_line_map])".into(),
            )
            .with_hint("keep the form the vendor supplied and delete the others"))
        }
    };
    // transmitters
    for (id, r) in &f.transmitters {
        if !(r.min.is_finite() && r.max.is_finite() && r.min < r.max) {
            return Err(at(
                &format!("transmitters.{}.max", id.name()),
                format!(
                    "range [{}, {}] is empty (min must be below max)",
                    r.min, r.max
                ),
            )
            .with_hint(format!("in {}, the values at 4 mA and 20 mA", id.unit())));
        }
    }
    let recycle_valve = match f.recycle_valve {
        Some(v) => {
            if !positive(v.stroke_time_s) {
                return Err(at(
                    "recycle_valve.stroke_time_s",
                    format!("{} s must be positive", v.stroke_time_s),
                )
                .with_hint("anti-surge valves stroke fully in about 1–2 s"));
            }
            Some(RecycleValve {
                spec: ValveSpec {
                    cv_max_m2: v.cv_max_m2.unwrap_or(f64::NAN),
                    characteristic: v.characteristic,
                    min_opening: 1e-3,
                    stroke_time_s: v.stroke_time_s,
                    positioner_lag_s: 0.05,
                },
                fail_position: v.fail_position,
            })
        }
        None => None,
    };
    let (drive, owns) = match f.drive {
        Some(dr) => {
            if dr.owned_by_controller && dr.spec.is_none() {
                return Err(at(
                    "drive.owned_by_controller",
                    "the controller cannot own a drive whose rating and speed-loop gains it does not know".into(),
                )
                .with_hint("add rated_torque_nm, nominal_speed_rad_s, speed_kp_nm_s_rad, speed_ki_nm_rad"));
            }
            (dr.spec, dr.owned_by_controller)
        }
        None => (None, false),
    };
    let desc = MachineDescription {
        name: f.name.clone(),
        family: None,
        gas,
        flow_element,
        flow_coordinate,
        surge_line,
        reference_suction_temperature_k: t_ref,
        map,
        design: Some(d),
        transmitters: f.transmitters.clone(),
        recycle_valve,
        drive,
        owns_drive_speed_loop: owns,
        shaft: None,
        plenum_duct: None,
        recycle: None,
        tip: None,
        thrust: None,
        spool: None,
    };
    Ok(match f.model {
        Some(m) => desc.with_model(m),
        None => desc,
    })
}

/// Units and consistency of the line with the flow element: at the design suction pressure,
/// the line's flows must give a flow-element Δp well below the suction pressure. A line 3600×
/// too large (m³/h typed as m³/s) or a flow element off by orders of magnitude fails here.
fn check_units(
    pts: &[(f64, f64)],
    form: &SurgeLineForm,
    gas: &Gas,
    element: &Orifice,
    d: &DesignPoint,
    key: &str,
    at: &dyn Fn(&str, String) -> FileError,
) -> Result<(), FileError> {
    if matches!(form, SurgeLineForm::Reduced { .. }) {
        return Ok(()); // already in flow-element units
    }
    let (p_s, t) = (d.suction_pressure_pa, d.suction_temperature_k);
    let q_max = pts.iter().map(|p| p.1).fold(0.0, f64::max);
    let dp = surge_line::element_dp_pa(element, gas, q_max, p_s, t);
    let ratio = dp / p_s;
    let m3h = matches!(
        form,
        SurgeLineForm::Points {
            flow_unit: FlowUnit::M3S,
            ..
        } | SurgeLineForm::Sqrt { .. }
    );
    if ratio > 0.5 {
        let as_m3h = ratio / 3600f64.powi(2);
        if m3h && (1e-4..0.3).contains(&as_m3h) {
            return Err(at(
                key,
                format!(
                    "surge flow {q_max:.4} m³/s would drop {dp:.3e} Pa over the flow element at the design suction pressure {p_s:.3e} Pa: these flows look like m³/h"
                ),
            )
            .with_hint("divide by 3600, or set flow_unit = \"m3_h\" for points"));
        }
        return Err(at(
            key,
            format!(
                "surge flow {q_max:.4} m³/s would drop {dp:.3e} Pa over the flow element, more than half the design suction pressure {p_s:.3e} Pa: the flow element and the surge line do not fit together"
            ),
        )
        .with_hint("check the flow element (c_w in kg/s per Pa, bore in m) against the line's units (m³/s at suction)"));
    }
    if ratio < 1e-7 {
        return Err(at(
            key,
            format!(
                "surge flow {q_max:.4e} m³/s would drop only {dp:.3e} Pa over the flow element at {p_s:.3e} Pa suction: too small to measure; the line and the flow element do not fit together"
            ),
        )
        .with_hint("flows in m³/s at suction (not m³/h divided twice, not kg/s); c_w in kg/s per Pa"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, body: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, body).unwrap();
        p
    }

    const BASE: &str = r#"name = "t"
[gas]
molar_mass_kg_mol = 0.0195
heat_capacity_ratio = 1.28
[flow_element]
c_w = 3.0e-5
[design]
suction_pressure_pa = 2.0e6
suction_temperature_k = 300.0
"#;

    #[test]
    fn vendor_closed_form_loads() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(
            dir.path(),
            "m.toml",
            &format!("{BASE}[surge_line]\nsqrt_c_m3_s = 0.354\n"),
        );
        let m = load(&p).unwrap();
        let q = m.surge_line.flow_at_ratio(2.0);
        assert!((q - 0.354).abs() < 1e-3, "{q}");
        assert!(!m.owns_drive_speed_loop);
        // the equivalent orifice reproduces c_w at the design temperature
        let cw = m.flow_element.c_w(&m.gas, 300.0);
        assert!((cw - 3.0e-5).abs() < 1e-12, "{cw}");
    }

    #[test]
    fn heat_capacity_ratio_is_asked_only_where_the_surge_line_needs_it() {
        let dir = tempfile::tempdir().unwrap();
        let no_kappa = BASE.replace("heat_capacity_ratio = 1.28\n", "");
        // a line in pressure ratio: κ unused, not asked for
        let p = write(
            dir.path(),
            "a.toml",
            &format!("{no_kappa}[surge_line]\nsqrt_c_m3_s = 0.354\n"),
        );
        let m = load(&p).unwrap();
        assert!((m.surge_line.flow_at_ratio(2.0) - 0.354).abs() < 1e-3);
        // a line in polytropic head: κ (or σ) converts it, and the refusal names both
        let head = "[surge_line]\nhead = \"polytropic_head_kj_kg\"\npoints = [[0.25, 40.0], [0.35, 70.0], [0.45, 100.0]]\n";
        let p = write(dir.path(), "b.toml", &format!("{no_kappa}{head}"));
        let e = load(&p).unwrap_err();
        assert_eq!(e.key, "gas", "{e}");
        assert!(
            e.message.contains("heat_capacity_ratio") && e.message.contains("polytropic_exponent"),
            "{e}"
        );
        let with_sigma = no_kappa.replace(
            "[flow_element]",
            "polytropic_exponent = 0.3\n[flow_element]",
        );
        let p = write(dir.path(), "c.toml", &format!("{with_sigma}{head}"));
        let by_sigma = load(&p).unwrap();
        let p = write(dir.path(), "d.toml", &format!("{BASE}{head}"));
        let by_kappa = load(&p).unwrap();
        assert!(by_sigma.surge_line.flow_at_ratio(2.0).is_finite());
        assert!(by_kappa.surge_line.flow_at_ratio(2.0).is_finite());
    }

    #[test]
    fn m3_h_typed_as_m3_s_is_caught_with_a_hint() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(
            dir.path(),
            "m.toml",
            &format!("{BASE}[surge_line]\npoints = [[900.0, 1.5], [1270.0, 2.0], [1560.0, 2.5]]\n"),
        );
        let e = load(&p).unwrap_err();
        assert_eq!(e.key, "surge_line.points");
        assert!(e.line == 11, "{e}");
        assert!(e.message.contains("look like m³/h"), "{e}");
        assert!(e.hint.as_deref().unwrap().contains("3600"), "{e}");
    }

    #[test]
    fn two_forms_and_no_form_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(
            dir.path(),
            "m.toml",
            &format!("{BASE}[surge_line]\nsqrt_c_m3_s = 0.354\nreduced_points = [[0.01, 0.5], [0.02, 0.8], [0.03, 1.0]]\n"),
        );
        let e = load(&p).unwrap_err();
        assert!(e.message.contains("one form only"), "{e}");
        let p = write(dir.path(), "n.toml", BASE);
        let e = load(&p).unwrap_err();
        assert!(e.message.contains("no surge limit line"), "{e}");
    }

    #[test]
    fn flow_element_inconsistent_with_the_line_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        // c_w 1000× too small: the surge flow would need Δp far above the suction pressure
        let body = BASE.replace("c_w = 3.0e-5", "c_w = 1.0e-6");
        let p = write(
            dir.path(),
            "m.toml",
            &format!("{body}[surge_line]\nsqrt_c_m3_s = 0.354\n"),
        );
        let e = load(&p).unwrap_err();
        assert!(e.message.contains("do not fit together"), "{e}");
        assert_eq!(e.key, "surge_line.sqrt_c_m3_s");
    }
}
