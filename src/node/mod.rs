//! The per-cycle real-time nodes: what runs on a real-time thread once per period, between the
//! boards the bus tasks fill and read. They own no socket, file or runtime; the daemon
//! ([`crate::daemon`]) wires them to the field and to the operator surfaces.
//!
//! - [`control`]: the control thread's cycle (the pure core, the boards, the event ring, the
//!   black box's records, the live snapshot).
//! - [`plant`]: the simulated plant's real-time step with its field devices' fail-safe.

pub mod control;
pub mod plant;
