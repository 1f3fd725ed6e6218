//! The field faults the I/O tasks raise (a process-wide tally, [`field`]) and the DBC value
//! table of the fault word. The vocabulary itself (the fault categories, the fault word, the
//! kinds of field link) is on the ground floor, [`crate::vocab::faults`].

use crate::vocab::faults::FaultCategory;

/// Field faults (links, writes, actuator feedback) raised by the I/O tasks, for the fault
/// word on the wire: per category, how many sources have it active. The control thread's
/// input faults and these are OR-ed into the heartbeat's `Faults` and the Modbus watchdog's
/// `faults` register, so a PLC sees a refused write or a valve that does not follow.
pub mod field {
    use crate::vocab::faults::FieldLinkKind;
    use crate::vocab::faults::{FaultCategory, FaultSet};
    use std::sync::atomic::{AtomicU32, Ordering};

    #[allow(clippy::declare_interior_mutable_const)]
    const ZERO: AtomicU32 = AtomicU32::new(0);
    static ACTIVE: [AtomicU32; FaultCategory::ALL.len()] = [ZERO; FaultCategory::ALL.len()];

    /// One source raised `c` (pair with [`clear`]).
    pub fn raise(c: FaultCategory) {
        ACTIVE[usize::from(c.code())].fetch_add(1, Ordering::Relaxed);
    }

    /// One source cleared `c`.
    pub fn clear(c: FaultCategory) {
        let _ =
            ACTIVE[usize::from(c.code())]
                .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |n| n.checked_sub(1));
    }

    static LINKS_DOWN: [AtomicU32; FieldLinkKind::ALL.len()] = [ZERO; 2];

    /// A link of `kind` went down (`true`) or came back up (`false`; pair with a down).
    pub fn link_down(kind: FieldLinkKind, down: bool) {
        let n = &LINKS_DOWN[usize::from(kind.code() - 1)];
        if down {
            n.fetch_add(1, Ordering::Relaxed);
        } else {
            let _ = n.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |n| n.checked_sub(1));
        }
    }

    /// The first kind of link that is down now, if any. Allocation-free.
    pub fn down_link() -> Option<FieldLinkKind> {
        FieldLinkKind::ALL
            .into_iter()
            .find(|k| LINKS_DOWN[usize::from(k.code() - 1)].load(Ordering::Relaxed) > 0)
    }

    /// The first kind of link among `kinds` (bits of `1 << FieldLinkKind::code`) that is
    /// down now, if any. Allocation-free.
    pub fn down_link_among(kinds: u8) -> Option<FieldLinkKind> {
        first_down_among(kinds, |k| {
            LINKS_DOWN[usize::from(k.code() - 1)].load(Ordering::Relaxed) > 0
        })
    }

    /// The first kind among `kinds` for which `down` holds.
    pub(crate) fn first_down_among(
        kinds: u8,
        down: impl Fn(FieldLinkKind) -> bool,
    ) -> Option<FieldLinkKind> {
        FieldLinkKind::ALL
            .into_iter()
            .find(|k| kinds & (1 << k.code()) != 0 && down(*k))
    }

    /// The active field faults as a fault word. Allocation-free.
    pub fn word() -> u32 {
        let mut f = FaultSet::NONE;
        for c in FaultCategory::ALL {
            if ACTIVE[usize::from(c.code())].load(Ordering::Relaxed) > 0 {
                f.set(c);
            }
        }
        f.0
    }
}

/// The DBC `VAL_` entries of a `Faults` signal: one value per single-bit word
/// (`1 "sensor_timeout" 2 "sensor_alive_error" …`), for message `id` and `signal`.
pub fn dbc_value_table(id: u32, signal: &str) -> String {
    let mut s = format!("VAL_ {id} {signal} 0 \"healthy\"");
    for c in FaultCategory::ALL {
        s += &format!(" {} \"{}\"", c.bit(), c.name());
    }
    s + " ;"
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vocab::faults::FieldLinkKind;

    #[test]
    fn shipped_dbc_documents_this_vocabulary() {
        let dbc = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/skid.dbc"),
        )
        .expect("skid.dbc");
        assert!(
            dbc.contains(&dbc_value_table(128, "Faults")),
            "config/skid.dbc must carry: {}",
            dbc_value_table(128, "Faults")
        );
        for c in FaultCategory::ALL {
            assert!(
                dbc.contains(&format!("bit {} {}", c.code(), c.name())),
                "{}",
                c.name()
            );
        }
    }

    #[test]
    fn field_faults_count_their_sources() {
        // (a category no other test raises)
        let c = FaultCategory::CycleOverrun;
        field::raise(c);
        field::raise(c);
        field::clear(c);
        assert_ne!(field::word() & c.bit(), 0, "one source still active");
        field::clear(c);
        field::clear(c);
        assert_eq!(field::word() & c.bit(), 0);
    }

    #[test]
    fn value_table_lists_every_category() {
        let t = dbc_value_table(128, "Faults");
        assert!(t.starts_with("VAL_ 128 Faults 0 \"healthy\" 1 \"sensor_timeout\""));
        assert!(t.contains("256 \"actuator_feedback_mismatch\""));
        assert!(t.ends_with(" ;"));
    }

    #[test]
    fn a_link_down_roots_only_the_inputs_of_its_kind() {
        use super::field::first_down_among;
        let can_down = |k: FieldLinkKind| k == FieldLinkKind::Can;
        let can = 1 << FieldLinkKind::Can.code();
        let modbus = 1 << FieldLinkKind::Modbus.code();
        assert_eq!(first_down_among(can, can_down), Some(FieldLinkKind::Can));
        assert_eq!(first_down_among(modbus, can_down), None, "a Modbus input");
        assert_eq!(
            first_down_among(can | modbus, can_down),
            Some(FieldLinkKind::Can)
        );
        assert_eq!(first_down_among(0, can_down), None, "on no field link");
        assert_eq!(
            first_down_among(u8::MAX, can_down),
            Some(FieldLinkKind::Can),
            "not told: any link"
        );
    }
}
