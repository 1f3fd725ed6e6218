//! Typed configuration problems.
//!
//! Each section's `validate` returns [`KeyProblem`]s that carry the dotted key path they are
//! about from the start (`inputs.p_discharge.max`); [`super::check`] locates them (file:line
//! of the last layer that sets the key) into the [`Problem`]s that check-config prints.

use crate::config::FileError;

pub use crate::config::problem::{KeyProblem, Severity};

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
