//! antisurge: real-time anti-surge and active surge control for centrifugal compressor skids.
//!
//! Layers, from the inside out:
//! - [`physics`], [`plant`], [`solver`]: the compressor physics of the seed papers as pure,
//!   allocation-free functions and small structs (SI units).
//! - [`surge`]: surge detection (flow reversal, limit cycles), shared by simulation and daemon.
//! - [`scenario`], [`sim`], [`plot`]: scenario timelines, the in-process simulation that backs
//!   `antisurge sim`, its trace, summary and pictures.
//! - [`vocab`]: the ground floor, the words every layer shares: the sensors and actuators
//!   ([`vocab::signals`]), the fault categories ([`vocab::faults`]), the controller's
//!   [`vocab::Mode`]. It imports nothing of the crate.
//! - [`io`]: CAN (DBC) and Modbus adapters; [`events`]: the append-only event log.
#![forbid(unsafe_op_in_unsafe_fn)]

pub mod blackbox;
pub mod campaign;
pub mod config;
pub mod control;
pub mod daemon;
pub mod events;
pub mod faults;
pub mod io;
pub mod live;
pub mod machine;
pub mod node;
pub mod physics;
pub mod plant;
pub mod plot;
pub mod runtime;
pub mod scenario;
pub mod sim;
pub mod solver;
pub mod sparkplug;
pub mod surge;
pub mod vocab;
