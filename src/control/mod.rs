//! The control part: measurement handling, the mass-flow observer, the speed loop, the surge
//! laws and the control cycle that ties them together ([`core::ControlCore`]).
//!
//! Everything here is pure and deterministic: functions of (state, measurements, dt) with no
//! I/O, no clock and no allocation inside a cycle. The simulation, the HIL plant and the daemon
//! drive the same [`core::ControlCore`].

pub mod checks;
pub mod config;
pub mod core;
pub mod law;
pub mod laws;
pub mod measurements;
pub mod model;
pub mod observer;
pub mod speed_loop;
pub mod supervisor;
pub mod surge_control_line;
pub mod vote;

pub use config::ControllerConfig;
pub use law::api::LawId;
