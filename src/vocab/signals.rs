//! The vocabulary every layer shares: which sensors and actuators exist, in SI units.
//!
//! The plant (in-process or on a bus), the I/O adapters and the control core all speak in
//! [`SensorSnapshot`] and [`ActuatorCommands`]. The signal map in the configuration binds each
//! [`SensorId`] / [`ActuatorId`] to a CAN signal or a Modbus register; nothing else names them.

use serde::{Deserialize, Serialize};

/// A measured quantity the controller reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SensorId {
    /// Compressor suction (inlet) static pressure, Pa absolute.
    PSuction,
    /// Compressor discharge (plenum) static pressure, Pa absolute.
    PDischarge,
    /// Shaft speed, rad/s.
    ShaftSpeed,
    /// Differential pressure over the suction flow element (orifice), Pa.
    OrificeDp,
    /// Suction gas temperature, K.
    TSuction,
    /// Recycle (anti-surge) valve position feedback, fraction open 0..1.
    RecycleValvePosition,
    /// Throttle / discharge valve position feedback, fraction open 0..1.
    ThrottlePosition,
    /// Axial rotor position relative to nominal = tip-clearance change, m (positive: larger clearance).
    ThrustPosition,
    /// Torque the drive reports delivering (actual torque), N·m. After a fail-safe, when the
    /// drive ran on its own speed governor, the controller takes over from it without a bump.
    DriveTorque,
    /// Emergency-shutdown / drive-trip contact (typically a Modbus discrete input): 1 while
    /// the machine is being shut down, else 0. While it is set the control core opens the
    /// recycle valve fully at once (seed 002 §2.2.2: the response to ESD events).
    EsdInput,
}

/// The inputs every control cycle needs: suction and discharge pressure, shaft speed (the
/// speed only where it is bound). A cycle runs on a new sample of these.
pub const CYCLE_INPUTS: [SensorId; 3] = [
    SensorId::PSuction,
    SensorId::PDischarge,
    SensorId::ShaftSpeed,
];

impl SensorId {
    /// Every sensor, in a fixed order (used for arrays indexed by sensor).
    pub const ALL: [SensorId; 10] = [
        SensorId::PSuction,
        SensorId::PDischarge,
        SensorId::ShaftSpeed,
        SensorId::OrificeDp,
        SensorId::TSuction,
        SensorId::RecycleValvePosition,
        SensorId::ThrottlePosition,
        SensorId::ThrustPosition,
        SensorId::DriveTorque,
        SensorId::EsdInput,
    ];
    /// Number of sensors.
    pub const COUNT: usize = Self::ALL.len();

    /// Index into arrays of length [`SensorId::COUNT`].
    pub const fn index(self) -> usize {
        self as usize
    }

    /// The snake_case name used in config files, traces and the event log.
    pub const fn name(self) -> &'static str {
        match self {
            SensorId::PSuction => "p_suction",
            SensorId::PDischarge => "p_discharge",
            SensorId::ShaftSpeed => "shaft_speed",
            SensorId::OrificeDp => "orifice_dp",
            SensorId::TSuction => "t_suction",
            SensorId::RecycleValvePosition => "recycle_valve_position",
            SensorId::ThrottlePosition => "throttle_position",
            SensorId::ThrustPosition => "thrust_position",
            SensorId::DriveTorque => "drive_torque",
            SensorId::EsdInput => "esd_input",
        }
    }

    /// Unit of the SI value, for messages and plots.
    pub const fn unit(self) -> &'static str {
        match self {
            SensorId::PSuction | SensorId::PDischarge | SensorId::OrificeDp => "Pa",
            SensorId::ShaftSpeed => "rad/s",
            SensorId::TSuction => "K",
            SensorId::RecycleValvePosition | SensorId::ThrottlePosition => "fraction",
            SensorId::ThrustPosition => "m",
            SensorId::DriveTorque => "N·m",
            SensorId::EsdInput => "1 = active",
        }
    }

    /// Whether the sensor is an on/off contact (one bit: a coil or discrete input may carry
    /// it) rather than a measured value.
    pub const fn is_contact(self) -> bool {
        matches!(self, SensorId::EsdInput)
    }

    /// Parse the snake_case name.
    pub fn from_name(name: &str) -> Option<SensorId> {
        Self::ALL.iter().copied().find(|s| s.name() == name)
    }
}

/// A setpoint the controller writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ActuatorId {
    /// Drive (motor) torque command, N·m.
    DriveTorque,
    /// Recycle valve opening command, fraction 0..1.
    RecycleValve,
    /// Close-coupled valve command: pressure-rise reduction it imposes, in the plant's
    /// pressure-rise units (pressure ratio for dimensional plants, ψ for the spool model).
    CloseCoupledValve,
    /// Throttle / discharge valve opening command, fraction 0..1.
    Throttle,
    /// Tip-clearance change setpoint for the magnetic thrust bearing, m (positive: larger clearance).
    TipClearance,
}

impl ActuatorId {
    /// Every actuator, in a fixed order.
    pub const ALL: [ActuatorId; 5] = [
        ActuatorId::DriveTorque,
        ActuatorId::RecycleValve,
        ActuatorId::CloseCoupledValve,
        ActuatorId::Throttle,
        ActuatorId::TipClearance,
    ];
    /// Number of actuators.
    pub const COUNT: usize = Self::ALL.len();

    /// Index into arrays of length [`ActuatorId::COUNT`].
    pub const fn index(self) -> usize {
        self as usize
    }

    /// The snake_case name used in config files, traces and the event log.
    pub const fn name(self) -> &'static str {
        match self {
            ActuatorId::DriveTorque => "drive_torque",
            ActuatorId::RecycleValve => "recycle_valve",
            ActuatorId::CloseCoupledValve => "close_coupled_valve",
            ActuatorId::Throttle => "throttle",
            ActuatorId::TipClearance => "tip_clearance",
        }
    }

    /// Unit of the SI value.
    pub const fn unit(self) -> &'static str {
        match self {
            ActuatorId::DriveTorque => "N·m",
            ActuatorId::RecycleValve | ActuatorId::Throttle => "fraction",
            ActuatorId::CloseCoupledValve => "pressure-rise units",
            ActuatorId::TipClearance => "m",
        }
    }

    /// Parse the snake_case name.
    pub fn from_name(name: &str) -> Option<ActuatorId> {
        Self::ALL.iter().copied().find(|a| a.name() == name)
    }
}

/// A set of actuators, e.g. the ones a law needs. Bit `i` is `ActuatorId::ALL[i]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub struct ActuatorSet(u8);

impl ActuatorSet {
    /// The empty set.
    pub const EMPTY: ActuatorSet = ActuatorSet(0);

    /// A set from a list.
    pub const fn of(list: &[ActuatorId]) -> ActuatorSet {
        let mut bits = 0u8;
        let mut i = 0;
        while i < list.len() {
            bits |= 1 << (list[i] as u8);
            i += 1;
        }
        ActuatorSet(bits)
    }

    /// Whether `a` is in the set.
    pub const fn contains(self, a: ActuatorId) -> bool {
        self.0 & (1 << (a as u8)) != 0
    }

    /// The members, in [`ActuatorId::ALL`] order.
    pub fn iter(self) -> impl Iterator<Item = ActuatorId> {
        ActuatorId::ALL
            .into_iter()
            .filter(move |a| self.contains(*a))
    }
}

/// One reading of every sensor, SI units. `NaN` means "no value" (absent or failed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorSnapshot {
    /// Values indexed by [`SensorId::index`].
    pub values: [f64; SensorId::COUNT],
}

impl Default for SensorSnapshot {
    fn default() -> Self {
        SensorSnapshot {
            values: [f64::NAN; SensorId::COUNT],
        }
    }
}

impl SensorSnapshot {
    /// Value of one sensor (NaN if absent).
    #[inline]
    pub fn get(&self, id: SensorId) -> f64 {
        self.values[id.index()]
    }
    /// Set one sensor.
    #[inline]
    pub fn set(&mut self, id: SensorId, v: f64) {
        self.values[id.index()] = v;
    }
}

/// Setpoints for every actuator, SI units. `NaN` means "not commanded" (the device keeps
/// its last setpoint or its own default).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActuatorCommands {
    /// Values indexed by [`ActuatorId::index`].
    pub values: [f64; ActuatorId::COUNT],
}

impl Default for ActuatorCommands {
    fn default() -> Self {
        ActuatorCommands {
            values: [f64::NAN; ActuatorId::COUNT],
        }
    }
}

impl ActuatorCommands {
    /// Setpoint of one actuator (NaN if not commanded).
    #[inline]
    pub fn get(&self, id: ActuatorId) -> f64 {
        self.values[id.index()]
    }
    /// Set one setpoint.
    #[inline]
    pub fn set(&mut self, id: ActuatorId, v: f64) {
        self.values[id.index()] = v;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for s in SensorId::ALL {
            assert_eq!(SensorId::from_name(s.name()), Some(s));
        }
        for a in ActuatorId::ALL {
            assert_eq!(ActuatorId::from_name(a.name()), Some(a));
        }
        assert_eq!(SensorId::from_name("p_sucton"), None);
    }

    #[test]
    fn indices_match_order() {
        for (i, s) in SensorId::ALL.iter().enumerate() {
            assert_eq!(s.index(), i);
        }
        for (i, a) in ActuatorId::ALL.iter().enumerate() {
            assert_eq!(a.index(), i);
        }
    }

    #[test]
    fn actuator_set_membership() {
        let set = ActuatorSet::of(&[ActuatorId::DriveTorque, ActuatorId::TipClearance]);
        assert!(set.contains(ActuatorId::DriveTorque));
        assert!(set.contains(ActuatorId::TipClearance));
        assert!(!set.contains(ActuatorId::RecycleValve));
        assert_eq!(set.iter().count(), 2);
    }
}
