//! Command-line front end.

pub mod bench_matrix;
pub mod daemon;
pub mod locate;
pub mod pictures;
pub mod sim;
pub mod table;
