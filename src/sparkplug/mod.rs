//! The Sparkplug B edge node (issue 26): the controller published to an MQTT broker for a
//! SCADA host (Ignition-style), off by default (`[sparkplug]`).
//!
//! - [`proto`]: the Sparkplug B payload, `prost` derives written from the specification;
//! - [`edge`]: topics, `seq`/`bdSeq`, births, data by exception, death, commands — pure;
//! - [`catalogue`]: the metrics, their units and ranges, their values from the snapshot;
//! - [`forward`]: events from the event log, the store-and-forward queue;
//! - [`task`]: the tokio task with the MQTT client (`rumqttc`, rustls with `ring`);
//! - [`settings`]: `[sparkplug]`, the node's own config section and its rules (the daemon's
//!   config re-exports it).
//!
//! The control thread is not involved: the node reads the lock-free snapshot the status
//! socket reads, at its own pace, on ordinary tokio threads.

pub mod catalogue;
pub mod edge;
pub mod fleet;
pub mod forward;
pub mod proto;
pub mod settings;
pub mod task;

pub use task::{spawn, EdgeInputs};
