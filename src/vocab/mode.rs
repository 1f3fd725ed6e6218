//! The controller's operating mode: one enum for the control core, the event log, the CAN
//! heartbeat, the Modbus heartbeat block and the black box. Its numeric code is what the
//! codecs put on the wire or in a file ([`Mode::code`], [`Mode::from_code`]); its name is the
//! event log's and the DBC value table's text ([`Mode::name`], serde's snake_case).

use std::fmt;

use serde::{Deserialize, Serialize};

/// Operating mode of the controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// 0: starting, no valid inputs yet. Nothing is commanded (the field devices hold), for at
    /// most the start-up grace; then fail-safe.
    Init,
    /// 1: manual: recycle valve from the manual station, speed loop only.
    Manual,
    /// 2: automatic: the selected law runs.
    Auto,
    /// 3: inputs lost: outputs at their safe positions (recycle open).
    FailSafe,
    /// 4: controlled stop (the daemon's last word on SIGTERM/SIGINT; the core never enters it).
    Shutdown,
}

impl Mode {
    /// Every mode, by code.
    pub const ALL: [Mode; 5] = [
        Mode::Init,
        Mode::Manual,
        Mode::Auto,
        Mode::FailSafe,
        Mode::Shutdown,
    ];

    /// Name for traces, the event log and the DBC value table.
    pub const fn name(self) -> &'static str {
        match self {
            Mode::Init => "init",
            Mode::Manual => "manual",
            Mode::Auto => "auto",
            Mode::FailSafe => "fail_safe",
            Mode::Shutdown => "shutdown",
        }
    }

    /// Numeric code (trace column, heartbeat frame and register, black-box column).
    pub const fn code(self) -> u8 {
        match self {
            Mode::Init => 0,
            Mode::Manual => 1,
            Mode::Auto => 2,
            Mode::FailSafe => 3,
            Mode::Shutdown => 4,
        }
    }

    /// Mode of a numeric code (`None` for an unknown code).
    pub fn from_code(code: u8) -> Option<Mode> {
        Self::ALL.get(usize::from(code)).copied()
    }
}

impl fmt::Display for Mode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_and_names_round_trip() {
        for (i, m) in Mode::ALL.into_iter().enumerate() {
            assert_eq!(usize::from(m.code()), i);
            assert_eq!(Mode::from_code(m.code()), Some(m));
            let json = serde_json::to_string(&m).unwrap();
            assert_eq!(json, format!("\"{}\"", m.name()));
        }
        assert_eq!(Mode::from_code(5), None);
        assert_eq!(Mode::FailSafe.to_string(), "fail_safe");
    }
}
