//! The in-process simulation behind `antisurge sim`: plant + scenario + control core, faster
//! than real time, with a trace, a summary and pictures.

pub mod output;
pub mod runner;
pub mod summary;
pub mod table;
pub mod trace;

pub use runner::{run, run_with, ControllerView, PlantRun, SimError, SimOptions, SimResult};
pub use summary::Summary;
