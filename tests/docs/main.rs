//! Integration tests, docs and layout: the import rules of the crate, the man pages and help,
//! the links of every Markdown file, and the documents' tables that are a command's output.
//! One test binary for the area (link time); each former `tests/<name>.rs` is a module, its
//! tests named `<name>::<test>` (`cargo test --release --test docs <name>::`).

#[path = "../common/mod.rs"]
mod common;

/// One allocator per binary: the common counting allocator.
#[global_allocator]
static GLOBAL: common::counting_alloc::Counting = common::counting_alloc::Counting;

mod architecture;
mod cli_man_help;
mod docs_links;
mod readme_matrix;
mod readme_table;
