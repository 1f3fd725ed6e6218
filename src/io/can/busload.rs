//! Worst-case CAN bus load from the DBC's cycle times and the bit rate.
//!
//! A classic data frame with `n` payload bytes takes at most (worst-case bit stuffing,
//! interframe space included; Davis, Burns, Bril & Lukkien, "Controller Area Network (CAN)
//! schedulability analysis", Real-Time Systems 35, 2007, eq. 2)
//!
//! ```text
//! bits = g + 8n + 13 + ⌊(g + 8n − 1) / 4⌋,   g = 34 (11-bit id) or 54 (29-bit id)
//! ```
//!
//! i.e. 135 bits for 8 bytes with an 11-bit id, 160 with a 29-bit id. The load is the sum
//! over periodic messages of bits / cycle time, divided by the bit rate. Messages without a
//! cycle time (event-driven) are listed apart and not counted.

use super::dbc::{CanDatabase, FrameId};

/// Worst-case length of one classic frame on the wire, bits.
pub const fn frame_bits(extended: bool, dlc: u8) -> u32 {
    let g = if extended { 54 } else { 34 };
    let n8 = 8 * dlc as u32;
    g + n8 + 13 + (g + n8 - 1) / 4
}

/// The load a database puts on a bus.
#[derive(Debug, Clone, PartialEq)]
pub struct BusLoad {
    /// Worst-case bits per second of the periodic messages.
    pub bits_per_s: f64,
    /// Bit rate, bit/s.
    pub bitrate_bps: u64,
    /// Messages without a cycle time (not counted).
    pub unperiodic: Vec<String>,
}

impl BusLoad {
    /// Compute the load of `db` at `bitrate_bps`.
    pub fn of(db: &CanDatabase, bitrate_bps: u64) -> BusLoad {
        let mut bits_per_s = 0.0;
        let mut unperiodic = Vec::new();
        for m in db.messages() {
            let ext = matches!(m.id(), FrameId::Extended(_));
            match m.cycle_time_ms() {
                Some(ms) if ms > 0 => {
                    bits_per_s += f64::from(frame_bits(ext, m.dlc())) * 1000.0 / f64::from(ms)
                }
                _ => unperiodic.push(m.name().to_string()),
            }
        }
        BusLoad {
            bits_per_s,
            bitrate_bps,
            unperiodic,
        }
    }

    /// Load in percent of the bit rate.
    pub fn percent(&self) -> f64 {
        100.0 * self.bits_per_s / self.bitrate_bps.max(1) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_lengths() {
        assert_eq!(frame_bits(false, 8), 135);
        assert_eq!(frame_bits(true, 8), 160);
        assert_eq!(frame_bits(false, 0), 55);
    }

    /// The shipped DBC at the shipped bit rate (deploy/80-can0.network `BitRate=1M`, the
    /// default of `bus.can.bitrate_bps`) is under the default 70 % limit; the DBC as it was
    /// before 2026-11 (every frame at 1 ms, tests/bad_configs/maps/skid_1khz.dbc) is not.
    #[test]
    fn shipped_dbc_fits_the_shipped_bit_rate() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let db = CanDatabase::from_file(root.join("config/skid.dbc")).expect("skid.dbc");
        let l = BusLoad::of(&db, 1_000_000);
        assert_eq!(l.bits_per_s, 634_500.0);
        assert!(l.percent() < 70.0, "{}", l.percent());
        assert!(l.unperiodic.is_empty(), "{:?}", l.unperiodic);
        let net = std::fs::read_to_string(root.join("deploy/80-can0.network")).expect("net");
        assert!(
            net.lines().any(|l| l.trim() == "BitRate=1M"),
            "deploy/80-can0.network must set the bit rate the load was computed for"
        );
        let old = CanDatabase::from_file(root.join("tests/bad_configs/maps/skid_1khz.dbc"))
            .expect("old dbc");
        let at_1m = BusLoad::of(&old, 1_000_000).percent();
        let at_500k = BusLoad::of(&old, 500_000).percent();
        assert!((at_1m - 82.35).abs() < 0.01, "{at_1m}");
        assert!((at_500k - 164.7).abs() < 0.01, "{at_500k}");
    }

    #[test]
    fn load_of_a_small_database() {
        let db = CanDatabase::parse(
            "VERSION \"\"\nBU_: A B\nBO_ 1 M1: 8 A\n SG_ S : 0|8@1+ (1,0) [0|255] \"\" B\n\
             BO_ 2 M2: 8 A\n SG_ T : 0|8@1+ (1,0) [0|255] \"\" B\n\
             BA_DEF_ BO_ \"GenMsgCycleTime\" INT 0 65535;\nBA_ \"GenMsgCycleTime\" BO_ 1 1;\n",
            "t.dbc",
        )
        .expect("dbc");
        let l = BusLoad::of(&db, 500_000);
        assert_eq!(l.bits_per_s, 135_000.0);
        assert!((l.percent() - 27.0).abs() < 1e-9);
        assert_eq!(l.unperiodic, ["M2"]);
    }
}
