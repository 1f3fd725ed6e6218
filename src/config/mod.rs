//! Configuration files: loading with precise error locations.
//!
//! Every TOML file antisurge reads (plants, scenarios, the daemon's config) goes through
//! [`toml_file`], so an operator always sees file, key and line in an error.

pub mod bounded;
pub mod paths;
pub mod problem;
pub mod toml_file;

pub use bounded::{read_config_text, ConfigInvalid, EX_CONFIG, MAX_CONFIG_FILE_BYTES};
pub use toml_file::FileError;
