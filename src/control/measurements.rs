//! Inputs of one control cycle: raw sensor readings with their age, operator inputs, and the
//! validated, derived measurements the laws see.

use crate::vocab::signals::{SensorId, SensorSnapshot, CYCLE_INPUTS};

/// Sensor readings as they arrived, with the age of each (time since it was last updated).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawSensors {
    /// Values in SI units (NaN: absent/invalid). For a measurement with redundant
    /// transmitters, transmitter `a` (the `[sensors]` binding).
    pub values: SensorSnapshot,
    /// Age of each value, s (∞: never received).
    pub age_s: [f64; SensorId::COUNT],
    /// Transmitters `b` and `c` of measurements with redundant transmitters (the signal
    /// map's `[vote.<sensor>]`), voted with `a` by [`crate::control::vote`].
    pub spare: SpareReadings,
    /// When each value was sampled, on its sender's own clock, s (any origin, one per
    /// sensor): the difference of two readings is the time the sender let pass between the
    /// two samples (CAN: alive-counter steps × the message's DBC cycle time). NaN where the
    /// source has no clock of its own (Modbus answers, the simulator's direct path): the
    /// core then takes the time between its cycles. The core integrates its observers and
    /// filters over this interval, not over its own wake-ups: a controller woken late, or
    /// a frame batch handed over at once, must not stretch or shrink the plant's time.
    pub sample_clock_s: [f64; SensorId::COUNT],
    /// How many samples of each value its source has delivered so far (the sensor board's
    /// publish count, the simulator's sample count): two readings with the same number are
    /// one sample, however their ages moved. 0: the source does not number its samples (a
    /// test's hand-made readings), and every cycle takes it as a new one.
    pub sample_seq: [u64; SensorId::COUNT],
}

/// Readings of the redundant transmitters `b` and `c` of each sensor (NaN and ∞ age where
/// none is bound).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpareReadings {
    /// Values, SI, `[sensor][0]` = `b`, `[sensor][1]` = `c`.
    pub values: [[f64; 2]; SensorId::COUNT],
    /// Ages, s.
    pub age_s: [[f64; 2]; SensorId::COUNT],
}

impl SpareReadings {
    /// No spare transmitter.
    pub const NONE: SpareReadings = SpareReadings {
        values: [[f64::NAN; 2]; SensorId::COUNT],
        age_s: [[f64::INFINITY; 2]; SensorId::COUNT],
    };

    /// Transmitter `slot` (1 = `b`, 2 = `c`) of `id`: value and age.
    #[inline]
    pub fn get(&self, id: SensorId, slot: usize) -> (f64, f64) {
        match slot {
            1 | 2 => (
                self.values[id.index()][slot - 1],
                self.age_s[id.index()][slot - 1],
            ),
            _ => (f64::NAN, f64::INFINITY),
        }
    }

    /// Set transmitter `slot` (1 = `b`, 2 = `c`) of `id`.
    #[inline]
    pub fn set(&mut self, id: SensorId, slot: usize, value: f64, age_s: f64) {
        if let 1 | 2 = slot {
            self.values[id.index()][slot - 1] = value;
            self.age_s[id.index()][slot - 1] = age_s;
        }
    }
}

impl Default for SpareReadings {
    fn default() -> Self {
        Self::NONE
    }
}

impl RawSensors {
    /// The newest sample of the [`CYCLE_INPUTS`] on their senders' clocks
    /// ([`sample_clock_s`](Self::sample_clock_s)), s: NaN unless every one of them that has
    /// arrived (finite age) has such a clock, so that a cycle never mixes a sender's time with
    /// its own. What the core integrates over, and what the black box keeps of the clocks.
    pub fn sender_clock_s(&self) -> f64 {
        let mut newest = f64::NAN;
        for s in CYCLE_INPUTS {
            if !self.age_s[s.index()].is_finite() {
                continue;
            }
            let c = self.sample_clock_s[s.index()];
            if !c.is_finite() {
                return f64::NAN;
            }
            newest = if newest.is_nan() { c } else { newest.max(c) };
        }
        newest
    }

    /// The sample numbers ([`sample_seq`](Self::sample_seq)) of the [`CYCLE_INPUTS`] that
    /// have arrived (finite age; 0 for the others): a cycle with the same numbers as the last
    /// one processed has no new sample. `None` when one of them is not numbered by its
    /// source, so that a cycle never takes an unnumbered reading for a repeated one.
    pub fn cycle_seq(&self) -> Option<[u64; CYCLE_INPUTS.len()]> {
        let mut seq = [0u64; CYCLE_INPUTS.len()];
        for (k, s) in CYCLE_INPUTS.into_iter().enumerate() {
            if !self.age_s[s.index()].is_finite() {
                continue;
            }
            match self.sample_seq[s.index()] {
                0 => return None,
                n => seq[k] = n,
            }
        }
        Some(seq)
    }

    /// No readings at all (every value NaN, never received).
    pub fn missing() -> Self {
        RawSensors {
            values: SensorSnapshot::default(),
            age_s: [f64::INFINITY; SensorId::COUNT],
            spare: SpareReadings::NONE,
            sample_clock_s: [f64::NAN; SensorId::COUNT],
            sample_seq: [0; SensorId::COUNT],
        }
    }

    /// Fresh readings (age 0), no redundant transmitters.
    pub fn fresh(values: SensorSnapshot) -> Self {
        RawSensors {
            values,
            age_s: [0.0; SensorId::COUNT],
            spare: SpareReadings::NONE,
            sample_clock_s: [f64::NAN; SensorId::COUNT],
            sample_seq: [0; SensorId::COUNT],
        }
    }

    /// Readings with ages, no redundant transmitters.
    pub fn new(values: SensorSnapshot, age_s: [f64; SensorId::COUNT]) -> Self {
        RawSensors {
            values,
            age_s,
            spare: SpareReadings::NONE,
            sample_clock_s: [f64::NAN; SensorId::COUNT],
            sample_seq: [0; SensorId::COUNT],
        }
    }

    /// Transmitter `slot` of `id` (0 = `a`, the input itself; 1 = `b`; 2 = `c`): value, age.
    #[inline]
    pub fn transmitter(&self, id: SensorId, slot: usize) -> (f64, f64) {
        if slot == 0 {
            (self.values.get(id), self.age_s[id.index()])
        } else {
            self.spare.get(id, slot)
        }
    }
}

/// What the operator (or the DCS) asks for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OperatorInputs {
    /// Speed setpoint, rad/s.
    pub speed_setpoint_rad_s: f64,
    /// Throttle opening the process demands, fraction (NaN if unknown). Laws that do not drive
    /// the throttle ignore it; `throttle-backstep` adds its trim to it.
    pub throttle_demand: f64,
    /// Mass-flow setpoint for flow-tracking laws, kg/s (NaN: hold the current flow).
    pub flow_setpoint_kg_s: f64,
    /// Recycle valve opening from the manual station, fraction (used in manual mode).
    pub recycle_manual: f64,
}

/// Validated measurements and derived quantities for the laws (SI units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurements {
    /// Cycle time, s.
    pub t_s: f64,
    /// Suction pressure, Pa.
    pub p_suction_pa: f64,
    /// Discharge pressure, Pa.
    pub p_discharge_pa: f64,
    /// Shaft speed, rad/s.
    pub omega_rad_s: f64,
    /// Suction temperature, K (nominal if not measured).
    pub t_suction_k: f64,
    /// Compressor mass flow used by the laws (per the flow-source setting), kg/s.
    pub m_kg_s: f64,
    /// Flow from the orifice, kg/s (NaN if the transmitter is not healthy).
    pub m_measured_kg_s: f64,
    /// Flow from the observer, kg/s (NaN if no observer).
    pub m_observer_kg_s: f64,
    /// Flow in the map's coordinate (kg/s or m³/s at suction).
    pub flow_map: f64,
    /// Pressure ratio p_d/p_s.
    pub pressure_ratio: f64,
    /// Recycle valve position, fraction (NaN if absent).
    pub recycle_position: f64,
    /// Throttle position, fraction (NaN if absent).
    pub throttle_position: f64,
    /// Tip-clearance change (rotor axial position), m (NaN if absent).
    pub thrust_position_m: f64,
    /// Filtered time derivative of the suction pressure, Pa/s.
    pub dp_suction_dt_pa_s: f64,
    /// Filtered time derivative of the discharge pressure, Pa/s.
    pub dp_discharge_dt_pa_s: f64,
    /// Whether the flow comes from the observer because the transmitter failed.
    pub flow_fallback: bool,
}

impl Measurements {
    /// Nothing measured (every value NaN) at time `t_s`.
    pub fn unavailable(t_s: f64) -> Self {
        let n = f64::NAN;
        Measurements {
            t_s,
            p_suction_pa: n,
            p_discharge_pa: n,
            omega_rad_s: n,
            t_suction_k: n,
            m_kg_s: n,
            m_measured_kg_s: n,
            m_observer_kg_s: n,
            flow_map: n,
            pressure_ratio: n,
            recycle_position: n,
            throttle_position: n,
            thrust_position_m: n,
            dp_suction_dt_pa_s: n,
            dp_discharge_dt_pa_s: n,
            flow_fallback: false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sender_clock_counts_only_when_every_arrived_essential_has_one() {
        let mut raw = RawSensors::fresh(Default::default());
        assert!(raw.sender_clock_s().is_nan(), "no clocks: the cycle's time");
        raw.sample_clock_s[SensorId::PSuction.index()] = 2.0;
        raw.sample_clock_s[SensorId::PDischarge.index()] = 2.001;
        assert!(
            raw.sender_clock_s().is_nan(),
            "the speed arrived without a clock: never a mix of clocks"
        );
        raw.age_s[SensorId::ShaftSpeed.index()] = f64::INFINITY;
        assert_eq!(
            raw.sender_clock_s(),
            2.001,
            "an unbound speed does not count"
        );
        raw.age_s[SensorId::ShaftSpeed.index()] = 0.0;
        raw.sample_clock_s[SensorId::ShaftSpeed.index()] = 1.5;
        assert_eq!(raw.sender_clock_s(), 2.001, "the newest sample");
    }

    #[test]
    fn the_cycle_seq_is_the_arrived_inputs_numbers_and_none_for_an_unnumbered_one() {
        let mut raw = RawSensors::fresh(Default::default());
        assert_eq!(raw.cycle_seq(), None, "hand-made readings: not numbered");
        raw.sample_seq[SensorId::PSuction.index()] = 7;
        raw.sample_seq[SensorId::PDischarge.index()] = 9;
        assert_eq!(raw.cycle_seq(), None, "the speed arrived unnumbered");
        raw.age_s[SensorId::ShaftSpeed.index()] = f64::INFINITY;
        assert_eq!(
            raw.cycle_seq(),
            Some([7, 9, 0]),
            "an unbound speed does not count"
        );
        raw.age_s[SensorId::ShaftSpeed.index()] = 0.5;
        raw.sample_seq[SensorId::ShaftSpeed.index()] = 3;
        assert_eq!(raw.cycle_seq(), Some([7, 9, 3]));
        raw.sample_seq[SensorId::TSuction.index()] = 0;
        assert_eq!(
            raw.cycle_seq(),
            Some([7, 9, 3]),
            "only the cycle inputs count"
        );
    }
}
