//! The plant file schema (`config/plants/*.toml`): one benchmark machine, every parameter with
//! its source in a comment in the file itself.

use crate::config::FileError;
use crate::physics::characteristic::MooreGreitzerCubic;
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;
use crate::physics::shaft::Shaft;
use crate::physics::thrust_bearing::ThrustBearingServo;
use crate::physics::tip_clearance::TipClearanceEffect;
use crate::physics::valve::ValveSpec;
use crate::solver::StepSettings;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Which dynamic model the plant uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelKind {
    /// Plenum/duct/shaft model (seed 000 eq. 1).
    PlenumDuct,
    /// Two-volume recycle system (seed 002 eq. 3.18, seed 001 eq. 2.26–2.27).
    RecycleSystem,
    /// Plenum/duct with tip-clearance actuation (seed 004 eq. 4).
    TipClearance,
    /// Nondimensional spool model (seed 003 eq. 4–6).
    Spool,
}

/// How the compressor map is given.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum MapSpec {
    /// Moore–Greitzer cubic with fan-law speed scaling (seed 001 eq. 2.10).
    Cubic {
        /// Shut-off pressure ratio ψc0 at the reference speed.
        psi_c0: f64,
        /// Semi-height H.
        semi_height: f64,
        /// Semi-width W in flow units (kg/s or m³/s).
        semi_width: f64,
        /// Reference speed, rad/s.
        omega_ref_rad_s: f64,
        /// Flow coordinate of W.
        flow_coordinate: FlowCoordinate,
        /// Speed range over which the surge line is tabulated, rad/s.
        omega_range_rad_s: [f64; 2],
    },
    /// Speed-line points in a CSV file, fitted by least squares (seed 001 eq. 2.11,
    /// seed 002 App. A).
    Table {
        /// CSV file, relative to the plant file.
        file: PathBuf,
    },
}

/// The compressor drive (motor) as an actuator.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveSpec {
    /// Largest motoring torque the drive delivers, N·m (its rating).
    pub rated_torque_nm: f64,
    /// Most negative (braking) torque, N·m; 0 for a drive without braking.
    #[serde(default)]
    pub min_torque_nm: f64,
    /// Nominal speed, rad/s: the speed setpoint at start.
    pub nominal_speed_rad_s: f64,
    /// Proportional gain of the drive's speed loop, N·m per rad/s (seed 002 eq. 3.7).
    pub speed_kp_nm_s_rad: f64,
    /// Integral gain of the speed loop, N·m per rad.
    pub speed_ki_nm_rad: f64,
}

/// Ratings of the actuators, so that laws are judged within real limits.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct ThrustRating {
    /// Peak force of the magnetic thrust bearing, N.
    pub force_max_n: f64,
    /// Force slew-rate limit, N/s.
    pub slew_max_n_s: f64,
    /// Nominal tip clearance, m.
    pub nominal_clearance_m: f64,
    /// Largest clearance modulation the auxiliary bearings allow, m (seed 004: 50 % of nominal).
    pub modulation_max_m: f64,
}

/// Plenum/duct/shaft plant (seed 000 eq. 1).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlenumDuctParams {
    /// Ambient (suction) stagnation pressure p01, Pa.
    pub ambient_pressure_pa: f64,
    /// Ambient temperature, K.
    pub ambient_temperature_k: f64,
    /// Speed of sound a01, m/s.
    pub sonic_velocity_m_s: f64,
    /// Plenum volume Vp, m³.
    pub plenum_volume_m3: f64,
    /// Duct through-flow area A1, m².
    pub duct_area_m2: f64,
    /// Duct length Lc, m.
    pub duct_length_m: f64,
    /// Throttle valve to ambient.
    pub throttle: ValveSpec,
    /// If set, the throttle flow uses this constant density (seed 000: m_t = k_t √(p − p01));
    /// otherwise the plenum density from the gas law.
    #[serde(default)]
    pub throttle_density_kg_m3: Option<f64>,
    /// Width of the smooth zero crossing of valve flows, Pa (1/ξ of seed 001 eq. 2.9).
    #[serde(default = "default_smoothing")]
    pub valve_smoothing_pa: f64,
}

/// Feed into the suction volume of the recycle system.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum FeedSpec {
    /// A mass-flow source (seed 002: w_f is a disturbance), kg/s at scale 1.
    MassFlow {
        /// Nominal feed, kg/s.
        nominal_kg_s: f64,
    },
    /// A feed valve from an upstream header (seed 001 eq. 2.27).
    Valve {
        /// Upstream header pressure, Pa.
        upstream_pressure_pa: f64,
        /// The feed valve.
        valve: ValveSpec,
        /// Constant density for the valve equation (seed 001 uses w = A √Δp), kg/m³;
        /// otherwise the upstream density from the gas law.
        #[serde(default)]
        density_kg_m3: Option<f64>,
    },
}

/// Two-volume recycle system (seed 002 eq. 3.18 with seed 001's feed and throttle valves).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecycleParams {
    /// Suction volume V1, m³.
    pub suction_volume_m3: f64,
    /// Discharge volume V2, m³.
    pub discharge_volume_m3: f64,
    /// Speed of sound in the suction volume c1, m/s.
    pub suction_sonic_velocity_m_s: f64,
    /// Speed of sound in the discharge volume c2, m/s.
    pub discharge_sonic_velocity_m_s: f64,
    /// Suction temperature T1, K.
    pub suction_temperature_k: f64,
    /// Discharge temperature T2, K.
    pub discharge_temperature_k: f64,
    /// Compressor duct area Ac, m².
    pub compressor_duct_area_m2: f64,
    /// Compressor duct length Lc, m.
    pub compressor_duct_length_m: f64,
    /// Recycle line area Ar, m².
    pub recycle_duct_area_m2: f64,
    /// Recycle line length Lr, m.
    pub recycle_duct_length_m: f64,
    /// Discharge (check-valve) line area At, m².
    pub discharge_duct_area_m2: f64,
    /// Discharge line length Lt, m.
    pub discharge_duct_length_m: f64,
    /// Downstream header pressure p_a, Pa.
    pub downstream_pressure_pa: f64,
    /// Whether the discharge line has a check valve (seed 002 eq. 3.17).
    pub check_valve: bool,
    /// The feed.
    pub feed: FeedSpec,
    /// The recycle (anti-surge) valve.
    pub recycle_valve: ValveSpec,
    /// The throttle/discharge valve in the discharge line.
    pub throttle: ValveSpec,
    /// Width of the smooth zero crossing of the feed valve flow, Pa.
    #[serde(default = "default_smoothing")]
    pub valve_smoothing_pa: f64,
}

fn default_smoothing() -> f64 {
    50.0
}

/// Plenum/duct plant with tip-clearance actuation at constant speed (seed 004 eq. 4).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TipClearanceParams {
    /// Ambient pressure P01, Pa.
    pub ambient_pressure_pa: f64,
    /// Ambient temperature, K.
    pub ambient_temperature_k: f64,
    /// Speed of sound a01, m/s.
    pub sonic_velocity_m_s: f64,
    /// Plenum volume Vp, m³.
    pub plenum_volume_m3: f64,
    /// Duct area A, m².
    pub duct_area_m2: f64,
    /// Duct length Lc, m.
    pub duct_length_m: f64,
    /// Throttle valve to ambient.
    pub throttle: ValveSpec,
    /// Constant density for the throttle equation (seed 004: m_th = k_th √(P − P01)), kg/m³.
    #[serde(default)]
    pub throttle_density_kg_m3: Option<f64>,
    /// Tip-clearance effect (seed 004 eq. 2–3).
    pub effect: TipClearanceEffect,
    /// Thrust-bearing servo (seed 004: 3rd-order Butterworth, 70 Hz).
    pub servo: ThrustBearingServo,
    /// Width of the smooth zero crossing of the throttle flow, Pa.
    #[serde(default = "default_smoothing")]
    pub valve_smoothing_pa: f64,
}

/// Nondimensional spool model (seed 003 eq. 4–6) with the scales that map it to SI units.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpoolParams {
    /// ā of eq. 4 (spool inertia parameter).
    pub a_bar: f64,
    /// b̄ of eq. 5 (Greitzer B).
    pub b_bar: f64,
    /// c̄ of eq. 6 (1/B).
    pub c_bar: f64,
    /// Torque coefficient σ: Γ(φ, ω̃) = σ φ ω̃ (seed 003 eq. 48, after [3]).
    pub torque_coefficient: f64,
    /// Throttle gain at full opening: F(γ, ψ) = γ √ψ with γ = gamma_max · opening.
    pub gamma_max: f64,
    /// Time unit of the nondimensional model (1/ω_H), s.
    pub time_scale_s: f64,
    /// Pressure per unit ψ, Pa.
    pub pressure_scale_pa: f64,
    /// Mass flow per unit φ, kg/s.
    pub flow_scale_kg_s: f64,
    /// Shaft speed per unit ω̃, rad/s.
    pub speed_scale_rad_s: f64,
    /// Torque per unit τ, N·m.
    pub torque_scale_nm: f64,
    /// Ambient (suction) pressure, Pa.
    pub ambient_pressure_pa: f64,
    /// Ambient temperature, K.
    pub ambient_temperature_k: f64,
    /// The throttle valve's positioner (its capacity is gamma_max).
    pub throttle: ValveSpec,
    /// Close-coupled valve authority: |u₂| ≤ this (seed 003 §IV uses 0.1 and 0.2).
    pub ccv_max: f64,
    /// Matched model uncertainty of seed 003 eq. 53 in the plant, off by default: amplitude A
    /// of Δf = ΔCss = A sin(k x₂), which enters eq. 4 as ā Δf and eq. 5 as b̄ ΔCss (seed 003
    /// eq. 38, 41–42; §IV uses A = 0.1). x₂ = φ − φ⁰ with φ⁰ the nominal steady state of the
    /// plant's current throttle position at nominal speed, so the equilibrium is unchanged.
    #[serde(default)]
    pub uncertainty_amplitude: f64,
    /// k of eq. 53 (per unit φ; seed 003 §IV: 10).
    #[serde(default = "default_uncertainty_frequency")]
    pub uncertainty_frequency: f64,
}

fn default_uncertainty_frequency() -> f64 {
    10.0
}

/// Initial conditions: the sim starts from the steady state for these inputs.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InitialSpec {
    /// Throttle opening, fraction.
    pub throttle: f64,
    /// Recycle valve opening, fraction (recycle plants).
    #[serde(default)]
    pub recycle_valve: f64,
    /// Feed scale (fraction of nominal feed or feed-valve opening).
    #[serde(default = "one")]
    pub feed: f64,
}

fn one() -> f64 {
    1.0
}

/// A benchmark plant file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantFile {
    /// Short name (used in file names and summary.json).
    pub name: String,
    /// One-line description.
    pub description: String,
    /// Seed and section this plant reproduces.
    pub source: String,
    /// Which dynamic model.
    pub model: ModelKind,
    /// Gas properties.
    pub gas: Gas,
    /// Compressor map.
    pub map: MapSpec,
    /// Shaft (not used by the constant-speed tip-clearance plant's dynamics, but by its load
    /// torque figure).
    pub shaft: Shaft,
    /// The drive.
    pub drive: DriveSpec,
    /// Suction flow element.
    pub orifice: Orifice,
    /// Plenum/duct parameters (model = plenum_duct).
    #[serde(default)]
    pub plenum_duct: Option<PlenumDuctParams>,
    /// Recycle system parameters (model = recycle_system).
    #[serde(default)]
    pub recycle_system: Option<RecycleParams>,
    /// Tip-clearance plant parameters (model = tip_clearance).
    #[serde(default)]
    pub tip_clearance: Option<TipClearanceParams>,
    /// Spool model parameters (model = spool).
    #[serde(default)]
    pub spool: Option<SpoolParams>,
    /// Thrust bearing rating (tip-clearance plants).
    #[serde(default)]
    pub thrust_rating: Option<ThrustRating>,
    /// Initial inputs.
    pub initial: InitialSpec,
    /// Fixed-step integration for real time.
    #[serde(default)]
    pub integration: StepSettings,
    /// Controller settings tuned for this machine (defaults for the daemon's config).
    #[serde(default)]
    pub controller: crate::control::ControllerConfig,
}

/// A loaded plant file: the parsed content, its path and the built compressor map.
#[derive(Debug, Clone)]
pub struct PlantDescription {
    /// Parsed file.
    pub file: PlantFile,
    /// Where it came from.
    pub path: PathBuf,
    /// The compressor map (fitted or analytic) with its surge line.
    pub map: CompressorMap,
}

impl PlantDescription {
    /// Load and validate a plant file; errors name file, key and line.
    pub fn load(path: &Path) -> Result<PlantDescription, FileError> {
        let (file, text): (PlantFile, String) = crate::config::toml_file::load(path)?;
        let at = |key: &str, msg: String| FileError::at_key(path, &text, key, msg);
        let section_present = match file.model {
            ModelKind::PlenumDuct => file.plenum_duct.is_some(),
            ModelKind::RecycleSystem => file.recycle_system.is_some(),
            ModelKind::TipClearance => file.tip_clearance.is_some(),
            ModelKind::Spool => file.spool.is_some(),
        };
        if !section_present {
            let section = match file.model {
                ModelKind::PlenumDuct => "plenum_duct",
                ModelKind::RecycleSystem => "recycle_system",
                ModelKind::TipClearance => "tip_clearance",
                ModelKind::Spool => "spool",
            };
            return Err(at(
                "model",
                format!("model is `{section}` but the [{section}] section is missing"),
            )
            .with_hint(format!("add a [{section}] table")));
        }
        if file.model == ModelKind::TipClearance && file.thrust_rating.is_none() {
            return Err(at(
                "model",
                "a tip-clearance plant needs a [thrust_rating] table".into(),
            ));
        }
        validate_positive(&file, &at)?;
        let map = match &file.map {
            MapSpec::Cubic { .. } if file.model == ModelKind::Spool => {
                // the spool model's cubic is nondimensional: its SI image is the map
                let Some(sp) = &file.spool else {
                    unreachable!("section presence checked above")
                };
                let MapSpec::Cubic {
                    psi_c0,
                    semi_height,
                    semi_width,
                    omega_ref_rad_s,
                    ..
                } = file.map
                else {
                    unreachable!()
                };
                let c = MooreGreitzerCubic {
                    psi_c0,
                    semi_height,
                    semi_width,
                    omega_ref: omega_ref_rad_s,
                };
                crate::plant::spool::si_map(&c, sp).map_err(|m| at("map.cubic", m))?
            }
            MapSpec::Cubic {
                psi_c0,
                semi_height,
                semi_width,
                omega_ref_rad_s,
                flow_coordinate,
                omega_range_rad_s,
            } => CompressorMap::cubic(
                MooreGreitzerCubic {
                    psi_c0: *psi_c0,
                    semi_height: *semi_height,
                    semi_width: *semi_width,
                    omega_ref: *omega_ref_rad_s,
                },
                *flow_coordinate,
                omega_range_rad_s[0],
                omega_range_rad_s[1],
            )
            .map_err(|m| at("map.cubic", m))?,
            MapSpec::Table { file: csv } => {
                let csv_path = path.parent().unwrap_or(Path::new(".")).join(csv);
                CompressorMap::from_csv(&csv_path)
                    .map_err(|e| at("map.table.file", e.to_string()))?
            }
        };
        Ok(PlantDescription {
            file,
            path: path.to_path_buf(),
            map,
        })
    }

    /// Short name.
    pub fn name(&self) -> &str {
        &self.file.name
    }
}

fn validate_positive(
    file: &PlantFile,
    at: &dyn Fn(&str, String) -> FileError,
) -> Result<(), FileError> {
    let mut checks: Vec<(&str, f64)> = vec![
        ("gas.molar_mass_kg_mol", file.gas.molar_mass_kg_mol),
        (
            "gas.heat_capacity_ratio",
            file.gas.heat_capacity_ratio - 1.0,
        ),
        ("gas.polytropic_exponent", file.gas.polytropic_exponent),
        ("shaft.inertia_kg_m2", file.shaft.inertia_kg_m2),
        ("shaft.impeller_radius_m", file.shaft.impeller_radius_m),
        ("drive.rated_torque_nm", file.drive.rated_torque_nm),
        ("drive.nominal_speed_rad_s", file.drive.nominal_speed_rad_s),
        ("orifice.bore_diameter_m", file.orifice.bore_diameter_m),
        ("orifice.flow_coefficient", file.orifice.flow_coefficient),
    ];
    if let Some(p) = &file.plenum_duct {
        checks.extend([
            ("plenum_duct.plenum_volume_m3", p.plenum_volume_m3),
            ("plenum_duct.duct_area_m2", p.duct_area_m2),
            ("plenum_duct.duct_length_m", p.duct_length_m),
            ("plenum_duct.sonic_velocity_m_s", p.sonic_velocity_m_s),
            ("plenum_duct.ambient_pressure_pa", p.ambient_pressure_pa),
            ("plenum_duct.throttle.cv_max_m2", p.throttle.cv_max_m2),
        ]);
    }
    if let Some(r) = &file.recycle_system {
        checks.extend([
            ("recycle_system.suction_volume_m3", r.suction_volume_m3),
            ("recycle_system.discharge_volume_m3", r.discharge_volume_m3),
            (
                "recycle_system.compressor_duct_area_m2",
                r.compressor_duct_area_m2,
            ),
            (
                "recycle_system.compressor_duct_length_m",
                r.compressor_duct_length_m,
            ),
            (
                "recycle_system.recycle_duct_area_m2",
                r.recycle_duct_area_m2,
            ),
            (
                "recycle_system.recycle_duct_length_m",
                r.recycle_duct_length_m,
            ),
            (
                "recycle_system.discharge_duct_area_m2",
                r.discharge_duct_area_m2,
            ),
            (
                "recycle_system.discharge_duct_length_m",
                r.discharge_duct_length_m,
            ),
            (
                "recycle_system.downstream_pressure_pa",
                r.downstream_pressure_pa,
            ),
            (
                "recycle_system.recycle_valve.cv_max_m2",
                r.recycle_valve.cv_max_m2,
            ),
            ("recycle_system.throttle.cv_max_m2", r.throttle.cv_max_m2),
        ]);
    }
    if let Some(t) = &file.tip_clearance {
        checks.extend([
            ("tip_clearance.plenum_volume_m3", t.plenum_volume_m3),
            ("tip_clearance.duct_area_m2", t.duct_area_m2),
            ("tip_clearance.duct_length_m", t.duct_length_m),
            (
                "tip_clearance.effect.blade_height_m",
                t.effect.blade_height_m,
            ),
            ("tip_clearance.servo.bandwidth_hz", t.servo.bandwidth_hz),
        ]);
    }
    if let Some(s) = &file.spool {
        checks.extend([
            ("spool.a_bar", s.a_bar),
            ("spool.b_bar", s.b_bar),
            ("spool.c_bar", s.c_bar),
            ("spool.time_scale_s", s.time_scale_s),
            ("spool.gamma_max", s.gamma_max),
        ]);
    }
    for (key, v) in checks {
        if v.is_nan() || v <= 0.0 || !v.is_finite() {
            return Err(at(key, format!("must be a positive number, found {v}"))
                .with_hint("physical sizes, gains and ratings are positive"));
        }
    }
    Ok(())
}
