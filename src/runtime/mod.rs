//! The runtime: the fixed-deadline control thread and its lock-free hand-off to the I/O tasks.

pub mod handoff;
pub mod panic_log;
pub mod rt_loop;
