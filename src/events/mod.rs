//! The append-only JSON Lines event log.
