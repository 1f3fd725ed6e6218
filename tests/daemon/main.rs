//! Integration tests, daemon: The daemon as processes: `antisurge run`/`plant` end to end, faults,
//! reloads, the event log, traces, the black box, Sparkplug, the fault campaign (ignored). One test
//! binary for the area (link time); each former `tests/<name>.rs` is a module, its tests named
//! `<name>::<test>` (`cargo test --release --test daemon <name>::`).

#[path = "../common/mod.rs"]
mod common;

/// One allocator per binary: the common counting allocator (per-thread counts for the
/// no-allocation tests, process-wide bytes for the memory bounds).
#[global_allocator]
static GLOBAL: common::counting_alloc::Counting = common::counting_alloc::Counting;

mod blackbox_candump;
mod blackbox_replay;
mod daemon_e2e;
mod daemon_faults;
mod daemon_trace_stream;
mod deploy_unit;
mod event_log_crash;
mod event_log_rt_alloc;
mod fault_campaign;
mod field_faults_node;
mod journal_fields;
mod live_no_alloc;
mod panic_log_rate;
mod reload_dry_run;
mod reload_half_file;
mod sparkplug_rt;
mod trace_stream;
