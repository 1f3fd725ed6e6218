//! The Modbus watchdog contract: which holding registers the controller writes so that a
//! device's own watchdog can tell a live controller from a dead one, configured in the
//! signal map (`[watchdog.modbus]`), not hard-coded.
//!
//! Each part is optional and bound to its own register; parts that are not contiguous are
//! written as separate requests (never merged with each other or with a setpoint):
//!
//! | key      | written value                                                            |
//! |----------|--------------------------------------------------------------------------|
//! | `alive`  | counter, +1 with every output set, wraps after `alive_max` (default: the largest value of its data type) to 0 |
//! | `toggle` | 0, 1, 0, 1 … with every output set; a holding register or a **coil** (`data_type = "bool"`, Modicon 0xxxx, written with 0x05) |
//! | `mode`   | controller mode: 0 init, 1 manual, 2 auto, 3 fail_safe, 4 shutdown      |
//! | `law`    | active law id (as in the DBC's ActiveLaw table)                          |
//! | `faults` | fault word of [`crate::faults`] (0 = healthy)                            |
//!
//! At least `alive` or `toggle` must be bound: those are what a device watchdog watches.
//! `timeout_ms` is the device's watchdog time (the plant node's device emulation uses it).
//!
//! ```toml
//! [watchdog.modbus]
//! alive = { unit_id = 1, register = 40004, data_type = "u16" }
//! timeout_ms = 300
//! ```
//!
//! A device whose watchdog watches a coil (a PLC's "controller alive" bit):
//!
//! ```toml
//! [watchdog.modbus]
//! toggle = { unit_id = 1, register = 1, data_type = "bool" }   # coil 00001
//! ```

use serde::{Deserialize, Serialize};

use super::register::{DataType, RegisterBinding, RegisterTable};

/// The Modbus watchdog contract (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct ModbusWatchdog {
    /// Alive counter register.
    #[serde(default)]
    pub alive: Option<RegisterBinding>,
    /// Largest counter value before it wraps to 0 (default: the data type's largest).
    #[serde(default)]
    pub alive_max: Option<u32>,
    /// Toggle register (0/1).
    #[serde(default)]
    pub toggle: Option<RegisterBinding>,
    /// Controller mode register.
    #[serde(default)]
    pub mode: Option<RegisterBinding>,
    /// Active law register.
    #[serde(default)]
    pub law: Option<RegisterBinding>,
    /// Fault word register.
    #[serde(default)]
    pub faults: Option<RegisterBinding>,
    /// The device's watchdog time, ms (used by the plant's device emulation).
    #[serde(default)]
    pub timeout_ms: Option<f64>,
}

/// One part of the contract.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WatchdogPart {
    /// Alive counter.
    Alive,
    /// Toggle.
    Toggle,
    /// Mode.
    Mode,
    /// Law.
    Law,
    /// Fault word.
    Faults,
}

impl WatchdogPart {
    /// Config key.
    pub const fn key(self) -> &'static str {
        match self {
            WatchdogPart::Alive => "alive",
            WatchdogPart::Toggle => "toggle",
            WatchdogPart::Mode => "mode",
            WatchdogPart::Law => "law",
            WatchdogPart::Faults => "faults",
        }
    }
}

impl ModbusWatchdog {
    /// The bound parts, in a fixed order.
    pub fn parts(&self) -> Vec<(WatchdogPart, RegisterBinding)> {
        [
            (WatchdogPart::Alive, self.alive),
            (WatchdogPart::Toggle, self.toggle),
            (WatchdogPart::Mode, self.mode),
            (WatchdogPart::Law, self.law),
            (WatchdogPart::Faults, self.faults),
        ]
        .into_iter()
        .filter_map(|(p, b)| b.map(|b| (p, b)))
        .collect()
    }

    /// Where the counter wraps: `alive_max`, else the data type's largest integer.
    pub fn alive_wrap(&self) -> u64 {
        if let Some(m) = self.alive_max {
            return u64::from(m);
        }
        match self.alive.map(|b| b.data_type) {
            Some(DataType::I16) => i16::MAX as u64,
            Some(DataType::U32) => u64::from(u32::MAX),
            Some(DataType::I32) => i32::MAX as u64,
            Some(DataType::F32) => 1 << 24,
            Some(DataType::U16) | None => u64::from(u16::MAX),
            Some(_) => 1 << 53,
        }
    }

    /// Problems as `(key, message)`: no alive/toggle, a part outside the holding table (the
    /// toggle: holding or coil), a bad `timeout_ms`, an `alive_max` of 0.
    pub fn problems(&self) -> Vec<(String, String)> {
        let mut out = Vec::new();
        if self.alive.is_none() && self.toggle.is_none() {
            out.push((
                "watchdog.modbus".to_string(),
                "bind `alive` or `toggle`: that register is what the device's watchdog watches"
                    .to_string(),
            ));
        }
        for (p, b) in self.parts() {
            if p == WatchdogPart::Toggle && b.table == RegisterTable::Coil {
                // one bit that flips: a coil is the natural home of a toggle
            } else if b.table != RegisterTable::Holding {
                out.push((
                    format!("watchdog.modbus.{}", p.key()),
                    if p == WatchdogPart::Toggle {
                        "must be a holding register (4xxxx) or a coil (0xxxx): the controller writes it"
                    } else {
                        "must be a holding register (4xxxx): the controller writes it"
                    }
                    .to_string(),
                ));
            }
            if let Err(e) = b.validate() {
                out.push((format!("watchdog.modbus.{}", p.key()), e.to_string()));
            }
        }
        if self.alive_max == Some(0) {
            out.push((
                "watchdog.modbus.alive_max".into(),
                "must be at least 1".into(),
            ));
        }
        if let Some(t) = self.timeout_ms {
            if !(t.is_finite() && t > 0.0) {
                out.push((
                    "watchdog.modbus.timeout_ms".into(),
                    format!("{t} ms must be positive"),
                ));
            }
        }
        out
    }
}

/// The values the controller writes for one output set, advancing `alive`/`toggle`.
#[derive(Debug, Clone, Copy, Default)]
pub struct WatchdogWriter {
    alive: u64,
    toggle: bool,
}

impl WatchdogWriter {
    /// Next values for `parts` (same order as [`ModbusWatchdog::parts`]) into `out`.
    /// `advance = false` repeats the previous alive/toggle value (the watchdog is withheld).
    pub fn values(
        &mut self,
        wd: &ModbusWatchdog,
        mode: u8,
        law: u8,
        faults: u32,
        advance: bool,
        out: &mut [f64],
    ) {
        if advance {
            let wrap = wd.alive_wrap();
            self.alive = if self.alive >= wrap {
                0
            } else {
                self.alive + 1
            };
            self.toggle = !self.toggle;
        }
        for (k, (p, _)) in wd.parts().iter().enumerate() {
            if k >= out.len() {
                break;
            }
            out[k] = match p {
                WatchdogPart::Alive => self.alive as f64,
                WatchdogPart::Toggle => f64::from(u8::from(self.toggle)),
                WatchdogPart::Mode => f64::from(mode),
                WatchdogPart::Law => f64::from(law),
                WatchdogPart::Faults => f64::from(faults),
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn single_counter_contract_from_toml_and_wrap() {
        let wd: ModbusWatchdog = toml::from_str(
            "alive = { unit_id = 1, register = 40004, data_type = \"u16\" }\nalive_max = 3\ntimeout_ms = 300\n",
        )
        .unwrap();
        let a = wd.alive.unwrap();
        assert_eq!((a.table, a.address), (RegisterTable::Holding, 3));
        assert!(wd.problems().is_empty(), "{:?}", wd.problems());
        let mut w = WatchdogWriter::default();
        let mut out = [0.0];
        let mut seen = Vec::new();
        for _ in 0..5 {
            w.values(&wd, 2, 1, 0, true, &mut out);
            seen.push(out[0]);
        }
        assert_eq!(seen, [1.0, 2.0, 3.0, 0.0, 1.0]);
        w.values(&wd, 2, 1, 0, false, &mut out);
        assert_eq!(out[0], 1.0, "withheld: the counter stands still");
    }

    #[test]
    fn a_toggle_may_live_on_a_coil_a_counter_may_not() {
        let wd: ModbusWatchdog =
            toml::from_str("toggle = { unit_id = 1, register = 1, data_type = \"bool\" }\n")
                .unwrap();
        let t = wd.toggle.unwrap();
        assert_eq!((t.table, t.address), (RegisterTable::Coil, 0));
        assert!(wd.problems().is_empty(), "{:?}", wd.problems());
        let mut w = WatchdogWriter::default();
        let mut out = [0.0];
        let mut words = Vec::new();
        for _ in 0..4 {
            w.values(&wd, 2, 1, 0, true, &mut out);
            let mut word = [9u16];
            let _ = t.encode(out[0], &mut word).unwrap();
            words.push(word[0]);
        }
        assert_eq!(words, [1, 0, 1, 0], "the coil flips with every output set");
        let bad: ModbusWatchdog = toml::from_str(
            "alive = { unit_id = 1, register = 2, data_type = \"bool\" }\nmode = { unit_id = 1, register = 3, data_type = \"bool\" }\n",
        )
        .unwrap();
        let p = bad.problems();
        for key in ["watchdog.modbus.alive", "watchdog.modbus.mode"] {
            assert!(
                p.iter()
                    .any(|(k, m)| k == key && m.contains("holding register (4xxxx):")),
                "{key}: {p:?}"
            );
        }
    }

    #[test]
    fn needs_alive_or_toggle_in_holding() {
        let wd: ModbusWatchdog =
            toml::from_str("mode = { unit_id = 1, register = 30001, data_type = \"u16\" }\n")
                .unwrap();
        let p = wd.problems();
        assert!(p.iter().any(|(k, _)| k == "watchdog.modbus"), "{p:?}");
        assert!(
            p.iter()
                .any(|(k, m)| k == "watchdog.modbus.mode" && m.contains("holding")),
            "{p:?}"
        );
    }
}
