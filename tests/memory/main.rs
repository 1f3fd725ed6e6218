//! Integration tests, memory: Process-wide heap bounds (the counting allocator's process figures):
//! its own binary, so no other test's allocations count, and its tests one at a time. One test
//! binary for the area (link time); each former `tests/<name>.rs` is a module, its tests named
//! `<name>::<test>` (`cargo test --release --test memory <name>::`).

#[path = "../common/mod.rs"]
mod common;

/// One allocator per binary: the common counting allocator (per-thread counts for the
/// no-allocation tests, process-wide bytes for the memory bounds).
#[global_allocator]
static GLOBAL: common::counting_alloc::Counting = common::counting_alloc::Counting;

mod daemon_trace_memory;
mod trace_stream_memory;
