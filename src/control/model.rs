//! What the controller knows about the machine: built from the same plant description the
//! simulator uses (on a real skid, the plant file describes the real machine).

use super::config::ControllerConfig;
use super::observer::ObserverPlant;
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;
use crate::physics::shaft::Shaft;
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
    /// Rotor data for the torque balance (seed 000 eq. 1c).
    pub shaft: Shaft,
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
    /// The controller settings tuned for this machine (the plant file's `[controller]`).
    pub controller: ControllerConfig,
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
            shaft: f.shaft,
            plenum_duct: f.plenum_duct,
            recycle: f.recycle_system,
            tip: f.tip_clearance,
            thrust: f.thrust_rating,
            spool: f.spool,
            nominal_suction_temperature_k: t_s,
            controller: f.controller.clone(),
        }
    }

    /// The outlet volume and duct the mass-flow observer copies (seed 000 eq. 1a–1b), if the
    /// machine has one: the plenum (seed 000), the discharge volume V2 (seed 001/002) or the
    /// plenum of the tip-clearance plant (seed 004).
    pub fn observer_plant(&self) -> Option<ObserverPlant> {
        if let Some(p) = &self.plenum_duct {
            return Some(ObserverPlant {
                area_over_length_m: p.duct_area_m2 / p.duct_length_m,
                volume_over_sonic2: p.plenum_volume_m3 / p.sonic_velocity_m_s.powi(2),
            });
        }
        if let Some(r) = &self.recycle {
            return Some(ObserverPlant {
                area_over_length_m: r.compressor_duct_area_m2 / r.compressor_duct_length_m,
                volume_over_sonic2: r.discharge_volume_m3 / r.discharge_sonic_velocity_m_s.powi(2),
            });
        }
        if let Some(t) = &self.tip {
            return Some(ObserverPlant {
                area_over_length_m: t.duct_area_m2 / t.duct_length_m,
                volume_over_sonic2: t.plenum_volume_m3 / t.sonic_velocity_m_s.powi(2),
            });
        }
        None
    }

    /// Mass flow leaving the outlet volume, computed from the valve equations and the valves'
    /// position feedback (NaN if a needed position is missing), kg/s. For the recycle system:
    /// recycle plus discharge-line flow (their quasi-steady values), with the header at its
    /// nominal pressure.
    pub fn outflow_kg_s(
        &self,
        p_suction_pa: f64,
        p_discharge_pa: f64,
        recycle_position: f64,
        throttle_position: f64,
    ) -> f64 {
        use crate::plant::{plenum_duct, recycle_system, tip_clearance};
        if let Some(p) = &self.plenum_duct {
            return plenum_duct::throttle_flow_kg_s(
                p,
                &self.gas,
                p_discharge_pa,
                throttle_position,
            );
        }
        if let Some(r) = &self.recycle {
            let wr = recycle_system::recycle_flow_steady_kg_s(
                r,
                &self.gas,
                p_suction_pa,
                p_discharge_pa,
                recycle_position,
            );
            let wt = recycle_system::throttle_flow_steady_kg_s(
                r,
                &self.gas,
                p_discharge_pa,
                r.downstream_pressure_pa,
                throttle_position,
            );
            return wr + wt;
        }
        if let Some(t) = &self.tip {
            return tip_clearance::throttle_flow_kg_s(
                t,
                &self.gas,
                p_discharge_pa,
                throttle_position,
            );
        }
        f64::NAN
    }

    /// Smallest observer gain c2 for exponential convergence over the operating region:
    /// p_in,max · sup ∂Ψc/∂m (seed 000 eq. 17 without its spurious factor 2, ERRATA.md), Pa per
    /// kg/s. The region is flows from −q_peak to 2.5 q_peak at 70–120 % of nominal speed; p_in,max
    /// is the highest inlet pressure the machine can see (ambient, or the discharge header for
    /// a recycle system). `None` if the machine has no observer.
    pub fn observer_min_gain(&self) -> Option<f64> {
        self.observer_plant()?;
        let w0 = self.drive.nominal_speed_rad_s;
        let (q_peak, _) = self.map.peak(w0)?;
        let slope = self
            .map
            .max_slope((0.7 * w0, 1.2 * w0), (-q_peak, 2.5 * q_peak));
        let (p_in, t_in) = if let Some(r) = &self.recycle {
            let p = match r.feed {
                crate::plant::file::FeedSpec::Valve {
                    upstream_pressure_pa,
                    ..
                } => upstream_pressure_pa.max(r.downstream_pressure_pa),
                crate::plant::file::FeedSpec::MassFlow { .. } => r.downstream_pressure_pa,
            };
            (p, r.suction_temperature_k)
        } else if let Some(p) = &self.plenum_duct {
            (p.ambient_pressure_pa, p.ambient_temperature_k)
        } else if let Some(t) = &self.tip {
            (t.ambient_pressure_pa, t.ambient_temperature_k)
        } else {
            return None;
        };
        // per kg/s: a volumetric map's slope is divided by the inlet density
        let per_kg = match self.map.flow_coordinate {
            FlowCoordinate::MassKgS => slope,
            FlowCoordinate::InletVolumeM3S => slope / self.gas.density_kg_m3(p_in, t_in),
        };
        Some(super::observer::min_gain(p_in, per_kg))
    }

    /// Compressor pressure ratio Ψc at mass flow `m`, with the tip-clearance effect of the
    /// measured rotor position where the machine has one (seed 004 eq. 3, corrected).
    #[inline]
    pub fn pressure_ratio_at(
        &self,
        m_kg_s: f64,
        p_suction_pa: f64,
        t_suction_k: f64,
        omega_rad_s: f64,
        clearance_m: f64,
    ) -> f64 {
        let psi_ss = self
            .map
            .eval(
                self.map_flow(m_kg_s, p_suction_pa, t_suction_k),
                omega_rad_s,
            )
            .value;
        match (&self.tip, clearance_m.is_finite()) {
            (Some(t), true) => t.effect.pressure_ratio(psi_ss, clearance_m),
            _ => psi_ss,
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
