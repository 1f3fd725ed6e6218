//! Field-bus adapters: CAN signals defined in a DBC file, and Modbus registers.
//!
//! Adapters translate between bytes on a bus and [`crate::vocab::signals`] values in SI units.
//! They know nothing of the control laws.

pub mod can;
pub mod feedback;
pub mod link;
pub mod modbus;
pub mod signal_map;
pub mod units;
