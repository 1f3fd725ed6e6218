//! Surge laws behind one interface, selectable by name.

use crate::signals::{ActuatorId, ActuatorSet};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The selectable laws.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LawId {
    /// No surge control: speed loop only, valves from their manual stations (open loop).
    None,
}

impl LawId {
    /// Every law.
    pub const ALL: [LawId; 1] = [LawId::None];

    /// Name used in config files and on the command line.
    pub const fn name(self) -> &'static str {
        match self {
            LawId::None => "none",
        }
    }

    /// Actuators the law drives (besides the drive's speed loop, which always runs).
    pub const fn actuators(self) -> ActuatorSet {
        match self {
            LawId::None => ActuatorSet::of(&[ActuatorId::DriveTorque]),
        }
    }
}

impl fmt::Display for LawId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Error for an unknown law name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown law `{0}`; known laws: {list}", list = LawId::ALL.iter().map(|l| l.name()).collect::<Vec<_>>().join(", "))]
pub struct UnknownLaw(pub String);

impl FromStr for LawId {
    type Err = UnknownLaw;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        LawId::ALL
            .iter()
            .copied()
            .find(|l| l.name() == s)
            .ok_or_else(|| UnknownLaw(s.to_string()))
    }
}
