//! What the controller knows about the machine: built from the same plant description the
//! simulator uses (on a real skid, the plant file describes the real machine).

use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;
use crate::plant::file::{
    DriveSpec, ModelKind, PlantDescription, PlenumDuctParams, RecycleParams, SpoolParams,
    ThrustRating, TipClearanceParams,
};

/// The controller's model of the machine.
#[derive(Debug, Clone)]
pub struct ControlModel {
    /// Plant name.
    pub name: String,
    /// Which model family.
    pub kind: ModelKind,
    /// Gas.
    pub gas: Gas,
    /// Suction flow element.
    pub orifice: Orifice,
    /// Compressor map (SI) with its surge line.
    pub map: CompressorMap,
    /// Drive data (rating, nominal speed, speed-loop gains).
    pub drive: DriveSpec,
    /// Plenum/duct data (seed 000 plants).
    pub plenum_duct: Option<PlenumDuctParams>,
    /// Recycle system data (seed 001/002 plants).
    pub recycle: Option<RecycleParams>,
    /// Tip-clearance plant data (seed 004).
    pub tip: Option<TipClearanceParams>,
    /// Thrust bearing rating (seed 004).
    pub thrust: Option<ThrustRating>,
    /// Spool model data (seed 003).
    pub spool: Option<SpoolParams>,
    /// Nominal suction temperature, K (used when the temperature sensor is absent).
    pub nominal_suction_temperature_k: f64,
}

impl ControlModel {
    /// Build from a plant description.
    pub fn from_plant(desc: &PlantDescription) -> ControlModel {
        let f = &desc.file;
        let t_s = f
            .plenum_duct
            .map(|p| p.ambient_temperature_k)
            .or(f.recycle_system.map(|r| r.suction_temperature_k))
            .or(f.tip_clearance.map(|t| t.ambient_temperature_k))
            .or(f.spool.map(|s| s.ambient_temperature_k))
            .unwrap_or(293.15);
        ControlModel {
            name: f.name.clone(),
            kind: f.model,
            gas: f.gas,
            orifice: f.orifice,
            map: desc.map,
            drive: f.drive,
            plenum_duct: f.plenum_duct,
            recycle: f.recycle_system,
            tip: f.tip_clearance,
            thrust: f.thrust_rating,
            spool: f.spool,
            nominal_suction_temperature_k: t_s,
        }
    }

    /// Flow in the map's coordinate for mass flow `m` at suction (p, T).
    #[inline]
    pub fn map_flow(&self, m_kg_s: f64, p_suction_pa: f64, t_suction_k: f64) -> f64 {
        match self.map.flow_coordinate {
            FlowCoordinate::MassKgS => m_kg_s,
            FlowCoordinate::InletVolumeM3S => {
                m_kg_s / self.gas.density_kg_m3(p_suction_pa, t_suction_k)
            }
        }
    }

    /// Relative surge margin (q − q_SL(R))/q_SL(R) of an operating point, from the derived
    /// surge line in invariant coordinates (seed 002 §2.3.1, eq. 2.4; seed 001 eq. 3.1).
    #[inline]
    pub fn surge_margin(&self, flow_map: f64, pressure_ratio: f64) -> f64 {
        let q_sl = self.map.surge_line.flow_at_ratio(pressure_ratio);
        if q_sl.abs() < 1e-12 {
            return f64::NAN;
        }
        (flow_map - q_sl) / q_sl
    }
}
