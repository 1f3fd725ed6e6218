//! Integration tests, config: Configuration: bounds, the corpus of good and bad files, layers,
//! printing, the reference, fuzz regressions. One test binary for the area (link time); each former
//! `tests/<name>.rs` is a module, its tests named `<name>::<test>` (`cargo test --release --test
//! config <name>::`).

#[path = "../common/mod.rs"]
mod common;

mod config_bounds;
mod config_corpus;
mod config_layers;
mod config_print;
mod config_reference;
mod fuzz_regressions;
