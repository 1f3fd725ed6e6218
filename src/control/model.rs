//! What the controller knows about the machine: built from the machine description
//! ([`crate::machine`]), whether it came from vendor data (`config/machines/*.toml`) or from a
//! simulation plant file. This module depends on the description and on `physics/`, never on
//! the simulator's plant models.

use super::config::ControllerConfig;
use super::observer::ObserverPlant;
use crate::machine::params::{
    DriveSpec, FeedSpec, ModelKind, PlenumDuctParams, RecycleParams, SpoolParams, ThrustRating,
    TipClearanceParams,
};
use crate::machine::{MachineDescription, RecycleValve};
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate, SurgeLine};
use crate::physics::gas::Gas;
use crate::physics::orifice::Orifice;
use crate::physics::shaft::Shaft;

/// The controller's model of the machine.
#[derive(Debug, Clone)]
pub struct ControlModel {
    /// Machine name.
    pub name: String,
    /// Which model family the machine data describe (`None`: vendor data without a model).
    pub kind: Option<ModelKind>,
    /// Gas.
    pub gas: Gas,
    /// Suction flow element.
    pub orifice: Orifice,
    /// The surge limit line (flow in `flow_coordinate` versus pressure ratio).
    pub surge_line: SurgeLine,
    /// Flow coordinate of the surge line and the map.
    pub flow_coordinate: FlowCoordinate,
    /// Speed-line map, when the description has one (model-based laws need it: the law
    /// registry refuses them on a machine without, so [`Self::speed_map`] never fails there).
    pub map: Option<CompressorMap>,
    /// Drive data (rating, nominal speed, speed-loop gains); a drive the controller does not
    /// own has zero rating and gains.
    pub drive: DriveSpec,
    /// Whether the controller runs the drive's speed loop and commands torque.
    pub owns_drive: bool,
    /// Rotor data for the torque balance (seed 000 eq. 1c), if known.
    pub shaft: Option<Shaft>,
    /// The recycle valve, if the machine has one.
    pub recycle_valve: Option<RecycleValve>,
    /// Plenum/duct data (seed 000 plants).
    pub plenum_duct: Option<PlenumDuctParams>,
    /// Recycle system model data (seed 001/002 plants).
    pub recycle: Option<RecycleParams>,
    /// Tip-clearance plant data (seed 004).
    pub tip: Option<TipClearanceParams>,
    /// Thrust bearing rating (seed 004).
    pub thrust: Option<ThrustRating>,
    /// Spool model data (seed 003).
    pub spool: Option<SpoolParams>,
    /// Nominal suction temperature, K (used when the temperature sensor is absent).
    pub nominal_suction_temperature_k: f64,
    /// Design pressure ratio (stated, or the middle of the surge line's range).
    pub design_pressure_ratio: f64,
    /// Design suction pressure, Pa absolute, if stated.
    pub design_suction_pressure_pa: Option<f64>,
    /// The controller settings tuned for this machine (defaults the daemon's config overrides).
    pub controller: ControllerConfig,
}

impl ControlModel {
    /// Build from a machine description and the controller settings tuned for it.
    pub fn from_machine(m: &MachineDescription, controller: ControllerConfig) -> ControlModel {
        let owns = m.owns_drive_speed_loop && m.drive.is_some();
        let drive = match (owns, m.drive) {
            (true, Some(d)) => d,
            _ => DriveSpec {
                rated_torque_nm: 0.0,
                min_torque_nm: 0.0,
                nominal_speed_rad_s: m
                    .drive
                    .map(|d| d.nominal_speed_rad_s)
                    .or(m.design.and_then(|d| d.speed_rad_s))
                    .unwrap_or(f64::NAN),
                speed_kp_nm_s_rad: 0.0,
                speed_ki_nm_rad: 0.0,
            },
        };
        ControlModel {
            name: m.name.clone(),
            kind: m.family,
            gas: m.gas,
            orifice: m.flow_element,
            surge_line: m.surge_line,
            flow_coordinate: m.flow_coordinate,
            map: m.map,
            drive,
            owns_drive: owns,
            shaft: m.shaft,
            recycle_valve: m.recycle_valve,
            plenum_duct: m.plenum_duct,
            recycle: m.recycle,
            tip: m.tip,
            thrust: m.thrust,
            spool: m.spool,
            nominal_suction_temperature_k: m.reference_suction_temperature_k,
            design_pressure_ratio: m.design_pressure_ratio(),
            design_suction_pressure_pa: m.design.map(|d| d.suction_pressure_pa),
            controller,
        }
    }

    /// The speed-line map. Only model-based laws call this; the law registry builds them only
    /// on a machine whose description has a map (`MachineData::SpeedLineMap`).
    #[inline]
    pub fn speed_map(&self) -> &CompressorMap {
        self.map
            .as_ref()
            .expect("law registry: a law that needs the speed-line map runs only with one")
    }

    /// Does the machine data hold this kind of datum (law registry)?
    pub fn has(&self, d: crate::machine::MachineData) -> bool {
        use crate::machine::MachineData as D;
        match d {
            D::SurgeLine => true,
            D::SpeedLineMap => self.map.is_some(),
            D::RecycleValve => self.recycle_valve.is_some(),
            D::OwnedDrive => self.owns_drive,
            D::Model(k) => {
                self.kind == Some(k)
                    && match k {
                        ModelKind::PlenumDuct => self.plenum_duct.is_some() && self.shaft.is_some(),
                        ModelKind::RecycleSystem => self.recycle.is_some(),
                        ModelKind::TipClearance => self.tip.is_some() && self.thrust.is_some(),
                        ModelKind::Spool => self.spool.is_some(),
                    }
            }
        }
    }

    /// Whether the machine has a recycle valve the controller drives.
    #[inline]
    pub fn has_recycle_valve(&self) -> bool {
        self.recycle_valve.is_some()
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
        if let Some(p) = &self.plenum_duct {
            return p.throttle_flow_kg_s(&self.gas, p_discharge_pa, throttle_position);
        }
        if let Some(r) = &self.recycle {
            let wr = r.recycle_flow_steady_kg_s(
                &self.gas,
                p_suction_pa,
                p_discharge_pa,
                recycle_position,
            );
            let wt = r.throttle_flow_steady_kg_s(
                &self.gas,
                p_discharge_pa,
                r.downstream_pressure_pa,
                throttle_position,
            );
            return wr + wt;
        }
        if let Some(t) = &self.tip {
            return t.throttle_flow_kg_s(&self.gas, p_discharge_pa, throttle_position);
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
        let map = self.map.as_ref()?;
        let w0 = self.drive.nominal_speed_rad_s;
        let (q_peak, _) = map.peak(w0)?;
        let slope = map.max_slope((0.7 * w0, 1.2 * w0), (-q_peak, 2.5 * q_peak));
        let (p_in, t_in) = if let Some(r) = &self.recycle {
            let p = match r.feed {
                FeedSpec::Valve {
                    upstream_pressure_pa,
                    ..
                } => upstream_pressure_pa.max(r.downstream_pressure_pa),
                FeedSpec::MassFlow { .. } => r.downstream_pressure_pa,
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
        let per_kg = match self.flow_coordinate {
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
        let Some(map) = &self.map else {
            return f64::NAN;
        };
        let psi_ss = map
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

    /// The speed-line flow: the flow (map coordinate) at which the speed line at `omega_rad_s`
    /// gives the pressure ratio `ratio`, Ψc(q, ω) = R (the steady state of the duct equation,
    /// seed 000 eq. 1b: L/A dm/dt = Ψc p_s − p_d), with ∂Ψc/∂q there. Defined only right of
    /// the speed line's peak, where Ψc falls with the flow and one ratio gives one flow: `None`
    /// at or above the peak ratio, without a map, or with a tip-clearance effect (the map
    /// alone does not give the ratio there). Bisection between the peak and a bracket found by
    /// doubling: allocation-free, at most 70 map evaluations.
    pub fn speed_line_flow(&self, ratio: f64, omega_rad_s: f64) -> Option<(f64, f64)> {
        let map = self.map.as_ref()?;
        if self.tip.is_some() || !(ratio.is_finite() && omega_rad_s.is_finite()) {
            return None;
        }
        let (q_peak, r_peak) = map.peak(omega_rad_s)?;
        if !(ratio < r_peak && q_peak > 0.0) {
            return None;
        }
        let psi = |q: f64| map.eval(q, omega_rad_s).value;
        let (mut lo, mut hi) = (q_peak, 1.25 * q_peak);
        let mut k = 0;
        while psi(hi) > ratio {
            lo = hi;
            hi = q_peak + 2.0 * (hi - q_peak);
            k += 1;
            if k > 30 {
                return None;
            }
        }
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if psi(mid) > ratio {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let q = 0.5 * (lo + hi);
        Some((q, map.eval(q, omega_rad_s).d_dflow))
    }

    /// Flow in the map's coordinate for mass flow `m` at suction (p, T).
    #[inline]
    pub fn map_flow(&self, m_kg_s: f64, p_suction_pa: f64, t_suction_k: f64) -> f64 {
        match self.flow_coordinate {
            FlowCoordinate::MassKgS => m_kg_s,
            FlowCoordinate::InletVolumeM3S => {
                m_kg_s / self.gas.density_kg_m3(p_suction_pa, t_suction_k)
            }
        }
    }

    /// Mass flow of a flow in map coordinates, kg/s (the inverse of [`Self::map_flow`]).
    pub fn mass_flow_of_map(&self, q_map: f64, p_suction_pa: f64, t_suction_k: f64) -> f64 {
        match self.flow_coordinate {
            FlowCoordinate::MassKgS => q_map,
            FlowCoordinate::InletVolumeM3S => {
                q_map * self.gas.density_kg_m3(p_suction_pa, t_suction_k)
            }
        }
    }

    /// Relative surge margin (q − q_SL(R))/q_SL(R) of an operating point, from the derived
    /// surge line in invariant coordinates (seed 002 §2.3.1, eq. 2.4; seed 001 eq. 3.1).
    #[inline]
    pub fn surge_margin(&self, flow_map: f64, pressure_ratio: f64) -> f64 {
        let q_sl = self.surge_line.flow_at_ratio(pressure_ratio);
        if q_sl.abs() < 1e-12 {
            return f64::NAN;
        }
        (flow_map - q_sl) / q_sl
    }
}
