//! Integration tests, control: The control laws, the core, the simulator and the plant models:
//! closed-loop acceptance, no allocation per cycle, analysis. One test binary for the area (link
//! time); each former `tests/<name>.rs` is a module, its tests named `<name>::<test>` (`cargo test
//! --release --test control <name>::`).

#[path = "../common/mod.rs"]
mod common;

/// One allocator per binary: the common counting allocator (per-thread counts for the
/// no-allocation tests, process-wide bytes for the memory bounds).
#[global_allocator]
static GLOBAL: common::counting_alloc::Counting = common::counting_alloc::Counting;

mod bumpless_gain_change;
mod campaign;
mod conservation_and_fit;
mod cycle_no_alloc;
mod drift_check;
mod esd_stroke_check;
mod input_freshness;
mod law_drive_torque;
mod law_recycle_fl;
mod law_recycle_pi;
mod law_spool;
mod law_spool_alloc;
mod law_tip_sliding;
mod machine_description;
mod machine_model;
mod manual_station;
mod observer;
mod open_loop_surge;
mod reconfigure_no_alloc;
mod recycle_pi_noise;
mod stability_analysis;
mod stiff_integration;
mod vendor_machine;
mod verdict;
