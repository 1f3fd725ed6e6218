//! Typed configuration problems.
//!
//! Each section's `validate` returns [`KeyProblem`]s that carry the dotted key path they are
//! about from the start (`inputs.p_discharge.max`); [`super::check`] locates them (file:line
//! of the last layer that sets the key) into the [`Problem`]s that check-config prints.

use crate::config::FileError;

/// How bad a problem is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Severity {
    /// The configuration is refused.
    Error,
    /// Printed; the configuration is accepted (legal but risky, likely a unit mistake).
    Warning,
}

/// A problem found by a section's own rules, about one key of the merged configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyProblem {
    /// Dotted key path in the merged configuration, e.g. `inputs.p_discharge.max`.
    pub key: String,
    /// Error or warning.
    pub severity: Severity,
    /// What is wrong, in words an operator understands.
    pub message: String,
    /// What to do about it, if there is something specific to say.
    pub hint: Option<String>,
}

impl KeyProblem {
    /// An error about `key`.
    pub fn error(key: impl Into<String>, message: impl Into<String>) -> KeyProblem {
        KeyProblem {
            key: key.into(),
            severity: Severity::Error,
            message: message.into(),
            hint: None,
        }
    }

    /// A warning about `key`.
    pub fn warning(key: impl Into<String>, message: impl Into<String>) -> KeyProblem {
        KeyProblem {
            severity: Severity::Warning,
            ..KeyProblem::error(key, message)
        }
    }

    /// The same problem with a hint (an empty hint is none).
    pub fn with_hint(mut self, hint: impl Into<String>) -> KeyProblem {
        let h = hint.into();
        self.hint = (!h.is_empty()).then_some(h);
        self
    }

    /// Is it a warning?
    pub fn is_warning(&self) -> bool {
        self.severity == Severity::Warning
    }
}

/// A configuration problem: an error (refused) or a warning (printed, accepted), located.
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    /// Located error message.
    pub error: FileError,
    /// A warning does not fail the check.
    pub warning: bool,
}

impl Problem {
    /// A located error.
    pub fn error(error: FileError) -> Problem {
        Problem {
            error,
            warning: false,
        }
    }
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.warning {
            write!(f, "warning: {}", self.error)
        } else {
            write!(f, "error: {}", self.error)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn key_problems_carry_key_severity_and_hint() {
        let p = KeyProblem::error("inputs.p_discharge.max", "empty range").with_hint("min < max");
        assert_eq!(p.key, "inputs.p_discharge.max");
        assert!(!p.is_warning());
        assert_eq!(p.hint.as_deref(), Some("min < max"));
        let w = KeyProblem::warning("control.failsafe_recycle_opening_pct", "low").with_hint("");
        assert!(w.is_warning());
        assert_eq!(w.hint, None);
    }

    #[test]
    fn problem_display_says_error_or_warning() {
        let e = FileError {
            file: "a.toml".into(),
            key: "cycle.rate_hz".into(),
            line: 3,
            column: 1,
            message: "too fast".into(),
            hint: None,
        };
        let p = Problem::error(e.clone());
        assert!(p.to_string().starts_with("error: "), "{p}");
        let w = Problem {
            error: e,
            warning: true,
        };
        assert!(w.to_string().starts_with("warning: "), "{w}");
    }
}
