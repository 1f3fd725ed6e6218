//! Command-line front end.

pub mod daemon;
pub mod locate;
pub mod pictures;
pub mod replay;
pub mod sim;
pub mod table;
