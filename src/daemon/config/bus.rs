//! `[bus]`: transport, signal map and the settings of each field bus. The rules between the
//! signal map, the law and the buses (what must be bound, DBC, bus load) are cross-section
//! rules, in [`super::cross`].

use super::problem::KeyProblem;
use crate::io::can::bus::{CanBusConfig, CanBusError};
use crate::io::modbus::ModbusLinkConfig;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// How the daemon reaches the skid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Transport {
    /// The simulated plant runs in this process (no hardware; the embedded default).
    #[default]
    InProcess,
    /// Field buses: the signal map binds each signal to CAN (`[bus.can]`) or Modbus
    /// (`[bus.modbus]`).
    Field,
}

/// `[bus]`: transport, signal map and the bus settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusSection {
    /// `in_process` (simulated plant inside the daemon) or `field` (CAN and/or Modbus).
    #[serde(default)]
    pub transport: Transport,
    /// Signal map file (sensor/actuator ↔ CAN signal or Modbus register), relative to the
    /// main config file. Required for `field`.
    #[serde(default)]
    pub signal_map: Option<PathBuf>,
    /// SocketCAN settings (required if the map has CAN bindings).
    #[serde(default)]
    pub can: Option<CanBusConfig>,
    /// Modbus client settings (required if the map has Modbus bindings).
    #[serde(default)]
    pub modbus: Option<ModbusLinkConfig>,
}

pub(super) fn d_bus() -> BusSection {
    BusSection {
        transport: Transport::InProcess,
        signal_map: None,
        can: None,
        modbus: None,
    }
}

impl BusSection {
    /// Input freshness defaults follow the bus: inputs polled over Modbus may be up to a poll
    /// period (plus the answer) old between answers, so their default timeout becomes three
    /// poll periods (`[bus.modbus] poll_rate_hz`) for the signal map's Modbus sensors.
    /// Explicit `[inputs.<sensor>] timeout_ms` are applied afterwards and win.
    pub fn follow_poll_period(
        &self,
        map: &crate::io::signal_map::SignalMap,
        core: &mut crate::control::core::CoreSettings,
    ) {
        if let (Transport::Field, Some(m)) = (&self.transport, &self.modbus) {
            let polled: Vec<crate::vocab::signals::SensorId> =
                map.modbus_sensors().iter().map(|s| s.0).collect();
            core.follow_poll_period_of(&polled, 1.0 / m.poll_rate_hz);
        }
    }

    /// The bus settings that are present, checked whatever the transport.
    pub fn validate(&self) -> Vec<KeyProblem> {
        let mut out = Vec::new();
        if let Some(can) = &self.can {
            if let Err(e) = can.validate() {
                let key = match &e {
                    CanBusError::Config { key, .. } => format!("bus.can.{key}"),
                    _ => "bus.can".to_string(),
                };
                out.push(KeyProblem::error(key, e.to_string()));
            }
        }
        if let Some(m) = &self.modbus {
            if let Err(e) = m.validate() {
                let key = e
                    .config_key()
                    .map_or_else(|| "bus.modbus".to_string(), |k| format!("bus.modbus.{k}"));
                out.push(KeyProblem::error(key, e.to_string()));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_in_process_without_map() {
        let b = d_bus();
        assert_eq!(b.transport, Transport::InProcess);
        assert!(b.signal_map.is_none() && b.validate().is_empty());
    }

    #[test]
    fn modbus_errors_carry_their_key() {
        let mut link = ModbusLinkConfig::new(crate::io::modbus::ClientConfig::tcp(
            std::net::SocketAddr::from(([127, 0, 0, 1], 502)),
        ));
        link.poll_rate_hz = 0.0;
        let b = BusSection {
            modbus: Some(link),
            ..d_bus()
        };
        let p = b.validate();
        assert_eq!(p.len(), 1, "{p:?}");
        assert_eq!(p[0].key, "bus.modbus.poll_rate_hz");
        let mut b = b;
        let m = b.modbus.as_mut().expect("modbus");
        m.poll_rate_hz = 50.0;
        m.client.timeout_ms = 0;
        assert_eq!(b.validate()[0].key, "bus.modbus.client.timeout_ms");
    }

    #[test]
    fn can_errors_carry_their_key() {
        let mut b = d_bus();
        let mut can = CanBusConfig::new("can0", "skid.dbc");
        can.heartbeat_timeout_ms = 0;
        b.can = Some(can);
        let p = b.validate();
        assert_eq!(p.len(), 1, "{p:?}");
        assert!(p[0].key.starts_with("bus.can."), "{}", p[0].key);
        assert_ne!(p[0].key, "bus.can");
    }
}
