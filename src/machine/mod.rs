//! The machine description: what the controller knows about *the machine*, separate from the
//! simulator's plant models.
//!
//! A controls engineer commissions from vendor data (`config/machines/*.toml`, [`file`]): the
//! surge limit line in one of the vendor forms ([`surge_line`]), the flow element, the gas,
//! the transmitter ranges, the design point and the actuators with their ratings. A simulation
//! plant file (`config/plants/*.toml`) yields the same [`MachineDescription`] (with its speed-
//! line map and the model data its model family adds), so `sim`, `plant` and `run` share one
//! way in. The controller (`control/`) depends on this module and on `physics/`, never on the
//! simulator's plant models (`plant/`); the plant models depend on this module, never on the
//! controller.

pub mod file;
pub mod model;
pub mod params;
pub mod plenum_duct;
pub mod surge_line;

use crate::physics::compressor_map::{CompressorMap, FlowCoordinate, SurgeLine};
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;
use crate::physics::shaft::Shaft;
use crate::physics::valve::ValveSpec;
use crate::vocab::signals::SensorId;
use params::{
    DriveSpec, ModelKind, PlenumDuctParams, RecycleParams, SpoolParams, ThrustRating,
    TipClearanceParams,
};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The machine's design (or rated) operating point: the suction conditions the surge line is
/// stated at, and where the machine normally runs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DesignPoint {
    /// Suction pressure, Pa absolute.
    pub suction_pressure_pa: f64,
    /// Suction temperature, K: the surge line's stated conditions.
    pub suction_temperature_k: f64,
    /// Pressure ratio p_d/p_s at the design point (absent: the middle of the surge line's range).
    #[serde(default)]
    pub pressure_ratio: Option<f64>,
    /// Shaft speed, rad/s (absent: unknown; the drive is not the controller's).
    #[serde(default)]
    pub speed_rad_s: Option<f64>,
}

/// A transmitter's calibrated range (4–20 mA = min–max), in the signal's SI unit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransmitterRange {
    /// Value at 4 mA (0 %).
    pub min: f64,
    /// Value at 20 mA (100 %).
    pub max: f64,
}

/// Where the recycle valve goes on loss of signal or air.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FailPosition {
    /// Fails open (the anti-surge valve's usual fail position).
    #[default]
    Open,
    /// Fails closed.
    Closed,
    /// Stays where it is.
    Last,
}

/// The recycle (anti-surge) valve as the controller sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecycleValve {
    /// Characteristic, capacity, stroke time and positioner (capacity may be unknown: NaN).
    pub spec: ValveSpec,
    /// Fail position.
    pub fail_position: FailPosition,
}

/// Everything the controller knows about the machine.
#[derive(Debug, Clone)]
pub struct MachineDescription {
    /// Short name.
    pub name: String,
    /// The dynamic model family the machine data describes, if any (model-based laws are
    /// written for one family); `None` for vendor data without a model.
    pub family: Option<ModelKind>,
    /// Gas (molar mass, κ, σ, Z).
    pub gas: Gas,
    /// The suction flow element as an orifice (a flow-element constant c_w becomes the
    /// equivalent c_f·A₂, seed 002 eq. 2.13).
    pub flow_element: Orifice,
    /// Flow coordinate of the surge line and map (vendor data: inlet volume flow).
    pub flow_coordinate: FlowCoordinate,
    /// The surge limit line, flow in `flow_coordinate` versus pressure ratio, at the reference
    /// suction temperature.
    pub surge_line: SurgeLine,
    /// Suction temperature the line and the flow element are referred to, K.
    pub reference_suction_temperature_k: f64,
    /// Speed-line map when known (the SLL is then derived from it; model-based laws need it).
    pub map: Option<CompressorMap>,
    /// Design point (suction conditions, ratio, speed), if given.
    pub design: Option<DesignPoint>,
    /// Transmitter ranges by sensor.
    pub transmitters: BTreeMap<SensorId, TransmitterRange>,
    /// The recycle valve, if the machine has one.
    pub recycle_valve: Option<RecycleValve>,
    /// The drive, if its data are known.
    pub drive: Option<DriveSpec>,
    /// Whether the controller owns the drive's speed loop (commands torque). Default false:
    /// drives usually run their own governor; taking over torque is a commissioning decision.
    pub owns_drive_speed_loop: bool,
    /// Rotor data (torque balance).
    pub shaft: Option<Shaft>,
    /// Model data of the plenum/duct family (seed 000).
    pub plenum_duct: Option<PlenumDuctParams>,
    /// Model data of the recycle-system family (seed 001/002).
    pub recycle: Option<RecycleParams>,
    /// Model data of the tip-clearance family (seed 004).
    pub tip: Option<TipClearanceParams>,
    /// Thrust bearing rating (seed 004).
    pub thrust: Option<ThrustRating>,
    /// Model data of the spool family (seed 003).
    pub spool: Option<SpoolParams>,
}

/// A kind of machine data a law may need (the law registry lists them per law).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MachineData {
    /// A surge limit line (every description has one).
    SurgeLine,
    /// A speed-line map (pressure ratio versus flow and speed).
    SpeedLineMap,
    /// The recycle valve.
    RecycleValve,
    /// The drive's rating with the speed loop owned by the controller.
    OwnedDrive,
    /// The model data of a model family.
    Model(ModelKind),
}

impl MachineData {
    /// The machine file key that supplies it.
    pub fn key(self) -> &'static str {
        match self {
            MachineData::SurgeLine => "surge_line",
            MachineData::SpeedLineMap => "speed_line_map",
            MachineData::RecycleValve => "recycle_valve",
            MachineData::OwnedDrive => "drive.owned_by_controller",
            MachineData::Model(_) => "model",
        }
    }

    /// What it is, in words, and how to supply it.
    pub fn describe(self) -> (&'static str, &'static str) {
        match self {
            MachineData::SurgeLine => ("a surge limit line", "[surge_line]"),
            MachineData::SpeedLineMap => (
                "a speed-line map (pressure ratio versus flow and speed)",
                "[speed_line_map] file = \"map.csv\" (or [speed_line_map.cubic])",
            ),
            MachineData::RecycleValve => ("a recycle valve", "[recycle_valve]"),
            MachineData::OwnedDrive => (
                "a drive whose speed loop the controller owns",
                "[drive] with owned_by_controller = true and its rating",
            ),
            MachineData::Model(ModelKind::PlenumDuct) => (
                "the plenum/duct model data (seed 000: plenum volume, duct, throttle, rotor)",
                "[model] family = \"plenum_duct\" with [model.plenum_duct] and [model.shaft] (config/machines/bohagen2007_model.toml)",
            ),
            MachineData::Model(ModelKind::RecycleSystem) => (
                "the recycle-system model data (seed 002: volumes, line lengths, valves)",
                "[model] family = \"recycle_system\" with [model.recycle_system]",
            ),
            MachineData::Model(ModelKind::TipClearance) => (
                "the tip-clearance model data (seed 004: plenum, duct, throttle, tip effect, servo, thrust rating)",
                "[model] family = \"tip_clearance\" with [model.tip_clearance] and [model.thrust_rating]",
            ),
            MachineData::Model(ModelKind::Spool) => (
                "the spool model data (seed 003: ā, b̄, c̄, scales, throttle)",
                "[model] family = \"spool\" with [model.spool] and the nondimensional [speed_line_map.cubic]",
            ),
        }
    }
}

impl MachineDescription {
    /// Add a model family's data (a machine file's `[model]`, a plant file's tables): the
    /// one way model data enter the description. The data must have passed
    /// [`model::ModelData::check`].
    pub fn with_model(mut self, m: model::ModelData) -> MachineDescription {
        self.family = Some(m.family);
        self.shaft = m.shaft;
        self.plenum_duct = m.plenum_duct;
        self.recycle = m.recycle_system;
        self.tip = m.tip_clearance;
        self.thrust = m.thrust_rating;
        self.spool = m.spool;
        self
    }

    /// The design pressure ratio: stated, else the middle of the surge line's range.
    pub fn design_pressure_ratio(&self) -> f64 {
        if let Some(r) = self.design.and_then(|d| d.pressure_ratio) {
            return r;
        }
        let mut pts = self.surge_line.points();
        let lo = pts.next().map_or(2.0, |p| p.1);
        let hi = pts.last().map_or(lo, |p| p.1);
        0.5 * (lo + hi)
    }
}
