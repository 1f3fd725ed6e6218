//! Command-line front end.

pub mod bench_matrix;
pub mod campaign;
pub mod daemon;
pub mod fleet;
pub mod locate;
pub mod man;
pub mod pictures;
pub mod plot;
pub mod replay;
pub mod sim;
pub mod status;
pub mod table;
