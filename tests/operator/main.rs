//! Integration tests, operator: The operator surfaces: the web HMI, the status API, TLS, the
//! station under attack, the CLI commands. One test binary for the area (link time); each former
//! `tests/<name>.rs` is a module, its tests named `<name>::<test>` (`cargo test --release --test
//! operator <name>::`).

#[path = "../common/mod.rs"]
mod common;

mod cli_events;
mod cli_plot;
mod cli_sim;
mod hmi_field_lamps;
mod hmi_input_links;
mod hmi_tls;
mod operator_live;
mod station_attack;
