//! `[event_log]`: the type is the event log's own ([`EventLogConfig`]); its errors become
//! problems about `event_log.<key>` here.

use super::problem::KeyProblem;
use crate::events::{EventLogConfig, EventLogError};

/// The key path (`event_log.max_bytes`) of an event-log configuration error.
pub fn key_of(e: &EventLogError) -> String {
    match e {
        EventLogError::Setting { key, .. } => format!("event_log.{key}"),
        _ => "event_log".to_string(),
    }
}

/// The section's rules.
pub fn validate(c: &EventLogConfig) -> Vec<KeyProblem> {
    match c.validate() {
        Ok(()) => Vec::new(),
        Err(e) => vec![KeyProblem::error(key_of(&e), e.to_string())],
    }
}

/// The typed problem of a merged `[event_log]` table that deserialization refused for a value
/// (serde reports it at `event_log` as text only).
pub fn table_problem(table: &toml::Table) -> Option<KeyProblem> {
    let e = EventLogConfig::setting_error(table)?;
    Some(KeyProblem::error(key_of(&e), e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_name_their_key() {
        let mut c = EventLogConfig::default();
        assert!(validate(&c).is_empty());
        c.max_bytes = 10;
        assert_eq!(validate(&c)[0].key, "event_log.max_bytes");
        let t: toml::Table =
            toml::from_str("fsync = \"always\"\nfsync_interval_ms = 10").expect("toml");
        assert_eq!(
            table_problem(&t).expect("refused").key,
            "event_log.fsync_interval_ms"
        );
        let ok: toml::Table = toml::from_str("keep_files = 3").expect("toml");
        assert!(table_problem(&ok).is_none());
    }
}
