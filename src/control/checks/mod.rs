//! Cross-checks of the flow transmitter against the rest of the machine: frozen
//! ([`cross_check`]) and drifting or biased ([`drift_check`]).

pub mod cross_check;
pub mod drift_check;
