//! The daemon: `antisurge run` (the controller service) and `antisurge plant` (the simulated
//! skid as a bus node).
//!
//! - [`config`]: the one schema, layered loading, located errors, cross-field checks.
//! - the per-cycle real-time nodes it runs are in [`crate::node`].
//! - [`field`]: the CAN and Modbus tasks of both nodes.
//! - [`service`], [`plant_service`]: wiring, signals, reload, shutdown.

pub mod config;
pub mod field;
pub mod notify;
pub mod plant_service;
pub mod reload_trial;
pub mod reload_watch;
pub mod service;

/// The machine section of the configuration (moved to [`config::machine`]).
pub use config::machine as config_machine;
/// `check-config --print` (moved to [`config::print`]).
pub use config::print as config_print;
