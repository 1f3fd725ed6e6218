//! The in-process simulation behind `antisurge sim`: plant + scenario + control core, faster
//! than real time, with a trace, a summary and pictures.

pub mod bench;
pub mod case;
pub mod output;
pub mod runner;
pub mod stream;
pub mod summary;
pub mod table;
pub mod trace;
pub mod trace_handoff;

pub use case::PlantCase;
pub use runner::{
    operator_inputs, run, run_streamed, run_with, run_with_model, ControllerView, PlantRun,
    SimError, SimOptions, SimResult, StreamedTrace,
};
pub use summary::Summary;

/// The controller's model of a simulation plant: the machine description the plant file
/// yields plus its tuned `[controller]` settings. The one way from a plant file to the
/// controller (`sim`, `plant` and `run` all come through here).
pub fn control_model(case: &case::PlantCase) -> crate::control::model::ControlModel {
    case.control_model()
}
