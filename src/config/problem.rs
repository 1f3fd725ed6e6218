//! A problem a configuration section finds in its own keys: the vocabulary every section's
//! `validate` speaks, wherever the section lives (the daemon's config, `live/`, the
//! Sparkplug node). `daemon::config::check` locates them into file:line problems.

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
