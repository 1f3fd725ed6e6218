//! Operator actions handed to the control thread: a wait-free ring (`rtrb`) of plain
//! `Copy` commands, applied at the next cycle boundary. Producers (status socket, HMI) check
//! the operator token first and record each action in the event log with what changed.

/// One operator action.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OperatorCommand {
    /// Automatic (true) or the manual station (false); bumpless both ways.
    SetAuto(bool),
    /// Manual-station valve output, fraction 0..1 (the law's protection stays a floor).
    ManualOutput(f64),
    /// Reset the surge counter to 0 (kept across restarts otherwise).
    ResetSurgeCounter,
    /// Acknowledge the shown cause of the last fault (clears it once inputs are healthy).
    Acknowledge,
}

impl OperatorCommand {
    /// Parse the words of a command: `auto`, `manual [PCT]`, `output PCT`,
    /// `reset-surge-counter`, `ack`. A manual with a percentage yields two commands.
    pub fn parse(words: &[&str]) -> Result<Vec<OperatorCommand>, String> {
        let pct = |s: &str| -> Result<f64, String> {
            let v: f64 = s
                .trim_end_matches('%')
                .parse()
                .map_err(|_| format!("`{s}` is not a percentage"))?;
            if (0.0..=100.0).contains(&v) {
                Ok(v * 0.01)
            } else {
                Err(format!("output {v} % is outside 0…100 %"))
            }
        };
        match words {
            ["auto"] => Ok(vec![OperatorCommand::SetAuto(true)]),
            ["manual"] => Ok(vec![OperatorCommand::SetAuto(false)]),
            // manual first (the station starts from the current output), then the new output
            ["manual", p] => Ok(vec![
                OperatorCommand::SetAuto(false),
                OperatorCommand::ManualOutput(pct(p)?),
            ]),
            ["output", p] => Ok(vec![OperatorCommand::ManualOutput(pct(p)?)]),
            ["reset-surge-counter"] => Ok(vec![OperatorCommand::ResetSurgeCounter]),
            ["ack"] => Ok(vec![OperatorCommand::Acknowledge]),
            _ => Err(format!(
                "unknown operator command `{}`; known: auto | manual [PCT] | output PCT | reset-surge-counter | ack",
                words.join(" ")
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_refuses() {
        assert_eq!(
            OperatorCommand::parse(&["manual", "20"]),
            Ok(vec![
                OperatorCommand::SetAuto(false),
                OperatorCommand::ManualOutput(0.2)
            ])
        );
        assert_eq!(
            OperatorCommand::parse(&["auto"]),
            Ok(vec![OperatorCommand::SetAuto(true)])
        );
        assert!(OperatorCommand::parse(&["output", "120"])
            .unwrap_err()
            .contains("outside"));
        assert!(OperatorCommand::parse(&["open-all"])
            .unwrap_err()
            .contains("known"));
    }
}
