//! The ground floor: the words every layer shares (the controller's [`Mode`], the sensors and
//! actuators, the fault categories). This module imports nothing of the crate; every other
//! part may import it.

pub mod faults;
pub mod mode;
pub mod signals;
pub mod vote;

pub use mode::Mode;
