//! The field faults the I/O tasks raise, as one handle the daemon creates and passes to every
//! link's reporter, to the control thread and (through it) to the operator surfaces.

use crate::vocab::faults::{FaultCategory, FaultSet, FieldLinkKind};
use std::sync::atomic::{AtomicU32, Ordering};

/// Field faults (links, writes, actuator feedback) raised by the I/O tasks: per category, how
/// many sources have it active, and per kind of link, how many links of it are down. The
/// control thread reads it every cycle: it ORs [`word`](Self::word) into the fault word of
/// the heartbeat and of the Modbus watchdog's `faults` register (so a PLC sees a refused write
/// or a valve that does not follow), names a down link as the root of the inputs it carries,
/// and widens the control line while a link is slow. Allocation-free, lock-free.
#[derive(Debug, Default)]
pub struct FieldFaults {
    active: [AtomicU32; FaultCategory::ALL.len()],
    links_down: [AtomicU32; FieldLinkKind::ALL.len()],
}

impl FieldFaults {
    /// One source raised `c` (pair with [`clear`](Self::clear)).
    pub fn raise(&self, c: FaultCategory) {
        self.active[usize::from(c.code())].fetch_add(1, Ordering::Relaxed);
    }

    /// One source cleared `c`.
    pub fn clear(&self, c: FaultCategory) {
        let _ = self.active[usize::from(c.code())].fetch_update(
            Ordering::Relaxed,
            Ordering::Relaxed,
            |n| n.checked_sub(1),
        );
    }

    /// A link of `kind` went down (`true`) or came back up (`false`; pair with a down).
    pub fn link_down(&self, kind: FieldLinkKind, down: bool) {
        let n = &self.links_down[usize::from(kind.code() - 1)];
        if down {
            n.fetch_add(1, Ordering::Relaxed);
        } else {
            let _ = n.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |n| n.checked_sub(1));
        }
    }

    fn is_down(&self, kind: FieldLinkKind) -> bool {
        self.links_down[usize::from(kind.code() - 1)].load(Ordering::Relaxed) > 0
    }

    /// The first kind of link that is down now, if any.
    pub fn down_link(&self) -> Option<FieldLinkKind> {
        FieldLinkKind::ALL.into_iter().find(|k| self.is_down(*k))
    }

    /// The first kind of link among `kinds` (bits of `1 << FieldLinkKind::code`) that is
    /// down now, if any.
    pub fn down_link_among(&self, kinds: u8) -> Option<FieldLinkKind> {
        first_down_among(kinds, |k| self.is_down(k))
    }

    /// The active field faults as a fault word.
    pub fn word(&self) -> u32 {
        let mut f = FaultSet::NONE;
        for c in FaultCategory::ALL {
            if self.active[usize::from(c.code())].load(Ordering::Relaxed) > 0 {
                f.set(c);
            }
        }
        f.0
    }
}

/// The first kind among `kinds` for which `down` holds.
fn first_down_among(kinds: u8, down: impl Fn(FieldLinkKind) -> bool) -> Option<FieldLinkKind> {
    FieldLinkKind::ALL
        .into_iter()
        .find(|k| kinds & (1 << k.code()) != 0 && down(*k))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_faults_count_their_sources() {
        let f = FieldFaults::default();
        let c = FaultCategory::FieldWriteFailed;
        f.raise(c);
        f.raise(c);
        f.clear(c);
        assert_eq!(f.word(), c.bit(), "one source still active");
        f.clear(c);
        f.clear(c);
        assert_eq!(f.word(), 0);
        let other = FieldFaults::default();
        other.raise(c);
        assert_eq!(f.word(), 0, "two handles share nothing");
    }

    #[test]
    fn a_link_down_roots_only_the_inputs_of_its_kind() {
        let f = FieldFaults::default();
        let can = 1 << FieldLinkKind::Can.code();
        let modbus = 1 << FieldLinkKind::Modbus.code();
        assert_eq!(f.down_link(), None);
        f.link_down(FieldLinkKind::Can, true);
        assert_eq!(f.down_link(), Some(FieldLinkKind::Can));
        assert_eq!(f.down_link_among(can), Some(FieldLinkKind::Can));
        assert_eq!(f.down_link_among(modbus), None, "a Modbus input");
        assert_eq!(f.down_link_among(can | modbus), Some(FieldLinkKind::Can));
        assert_eq!(f.down_link_among(0), None, "on no field link");
        assert_eq!(
            f.down_link_among(u8::MAX),
            Some(FieldLinkKind::Can),
            "not told: any link"
        );
        f.link_down(FieldLinkKind::Can, false);
        f.link_down(FieldLinkKind::Can, false);
        assert_eq!(f.down_link(), None, "an unpaired up does not go below zero");
        f.link_down(FieldLinkKind::Can, true);
        assert_eq!(f.down_link(), Some(FieldLinkKind::Can));
    }
}
