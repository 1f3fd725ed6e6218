//! Modbus: register encoding and client/server helpers.
