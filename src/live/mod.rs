//! What the operator sees and does on a running controller.
//!
//! - [`snapshot`]: the live state, published by the control thread each cycle (lock-free).
//! - [`commands`]: operator actions handed to the control thread (wait-free ring).
//! - [`persist`]: surge counter, safety-on steps and last mode kept across restarts.
//! - [`server`]: the status socket (`antisurge status`) and the operator actions on it.
//! - [`metrics`]: the Prometheus/OpenMetrics endpoint.

pub mod commands;
pub mod persist;
pub mod snapshot;
