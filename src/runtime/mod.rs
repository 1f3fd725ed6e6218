//! The runtime: the control thread (fixed deadline, or driven by its inputs with the deadline
//! as fallback) and its lock-free hand-off to the I/O tasks.

pub mod handoff;
pub mod panic_log;
pub mod rt_loop;
pub mod trigger;
