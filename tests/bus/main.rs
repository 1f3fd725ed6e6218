//! Integration tests, bus: The field buses: CAN DBC codecs, Modbus client/server links, the
//! foreign-map skid end to end. One test binary for the area (link time); each former
//! `tests/<name>.rs` is a module, its tests named `<name>::<test>` (`cargo test --release --test
//! bus <name>::`).

#[path = "../common/mod.rs"]
mod common;

/// One allocator per binary: the common counting allocator (per-thread counts for the
/// no-allocation tests, process-wide bytes for the memory bounds).
#[global_allocator]
static GLOBAL: common::counting_alloc::Counting = common::counting_alloc::Counting;

mod can_dbc_cantools;
mod can_foreign_dbc;
mod modbus_command_connection;
mod modbus_foreign_e2e;
mod modbus_link;
mod modbus_link_outage;
mod modbus_loopback;
mod modbus_write_allow_list;
