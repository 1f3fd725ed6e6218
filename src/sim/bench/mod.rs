//! The control benchmark matrix (`antisurge bench-matrix`): recycle-pi against the textbook
//! `baseline-pi` on every recycle plant, at two control-line margins, through process events
//! (throttle closure and step, feed drop, speed ramp, emergency shutdown) and signal faults
//! (pressure and Δp noise, a frozen Δp, input blips, a link outage).
//!
//! Each case runs the simulated plant and a [`ControlCore`] in one loop, like `sim`, with the
//! field between them modelled here: noise on the readings, a Δp transmitter repeating its
//! last value (fresh, as a healthy Modbus server would), all inputs arriving late (blips), and
//! a link outage in which no input arrives and no command reaches the valve (the positioner
//! holds its last setpoint). Scored on the plant's true state: surge cycles, closest approach
//! to the surge line during and after the event, recycle mass and energy, valve travel, time
//! in fail-safe, and the largest valve step at a resume.
//!
//! The emergency shutdown is also run apart ([`esd_stroke`], the machine check's ESD stroke
//! warning): with the trip seen in the speed decay alone and with the drive's trip contact
//! wired as `esd_input` ([`FieldFault::EsdContact`]), searching the longest recycle-valve
//! stroke that holds in each.
//!
//! Deterministic (fixed noise seeds), allocation outside the cycle only, a few seconds for the
//! whole matrix on one core; cases run on std threads.
//!
//! - [`cases`]: the matrix's cases and the field faults they inject;
//! - [`runner`]: one case's closed loop and its scores, the whole matrix on threads;
//! - [`esd`]: the ESD stroke study (the check's warning, the plant variants);
//! - [`report`]: the Markdown tables and the energy sums of the README and the docs.

mod cases;
mod esd;
mod report;
mod runner;

pub use cases::*;
pub use esd::*;
pub use report::*;
pub use runner::*;
