//! Configuration files: loading with precise error locations.
//!
//! Every TOML file antisurge reads (plants, scenarios, the daemon's config) goes through
//! [`toml_file`], so an operator always sees file, key and line in an error.

pub mod toml_file;

pub use toml_file::FileError;
