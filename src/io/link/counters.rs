//! The field links' counters: one way to declare them ([`link_counters!`]: lock-free atomics
//! the link task updates and a plain copy anyone reads), and the one counters type every link
//! reports whatever its transport ([`LinkTraffic`]), which the status and the metrics show for
//! each link alike.

use serde::Serialize;

/// Declare a link's counters: `atomic Name` (relaxed `AtomicU64`s, updated by the link task,
/// monotonic since start unless documented as a gauge) and `plain NameCopy` (a copy, for the
/// statistics and logs), with `Name::snapshot`, `Name::inc` and `Name::add`.
macro_rules! link_counters {
    (
        $(#[$atomic_meta:meta])* atomic $atomic:ident;
        $(#[$plain_meta:meta])* plain $plain:ident;
        { $( $(#[doc = $doc:literal])* $field:ident ),* $(,)? }
    ) => {
        $(#[$atomic_meta])*
        #[derive(Debug, Default)]
        pub struct $atomic {
            $( $(#[doc = $doc])* pub $field: std::sync::atomic::AtomicU64, )*
        }

        $(#[$plain_meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
        pub struct $plain {
            $( $(#[doc = $doc])* pub $field: u64, )*
        }

        impl $atomic {
            /// A copy of every counter (each read atomically, relaxed: taken while the task
            /// runs, it is not one instant).
            pub fn snapshot(&self) -> $plain {
                $plain { $( $field: self.$field.load(std::sync::atomic::Ordering::Relaxed), )* }
            }

            /// One more.
            #[inline]
            #[allow(dead_code)]
            pub(crate) fn inc(c: &std::sync::atomic::AtomicU64) {
                c.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            }

            /// `n` more.
            #[inline]
            #[allow(dead_code)]
            pub(crate) fn add(c: &std::sync::atomic::AtomicU64, n: u64) {
                c.fetch_add(n, std::sync::atomic::Ordering::Relaxed);
            }
        }
    };
}
pub(crate) use link_counters;

/// What every field link counts, whatever its transport (monotonic since start). A CAN link
/// counts frames, a Modbus link requests and answers; the status (`links.<kind>.traffic`) and
/// the metrics (`antisurge_link_*_total{link=...}`) show these for each link alike, beside the
/// transport's own counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct LinkTraffic {
    /// Frames written (CAN) or requests sent (Modbus).
    pub sent: u64,
    /// Frames read (CAN) or answers received, exceptions included (Modbus).
    pub received: u64,
    /// What came wrong: frames refused (unknown identifier, wrong length, bad CRC, invalid
    /// value), error frames and refused writes (CAN); timeouts, exceptions, I/O and protocol
    /// errors (Modbus).
    pub errors: u64,
    /// Times the link went down (CAN: sessions ended by an error or bus-off; Modbus: the
    /// link's state turned down, a failed connection or a broken one).
    pub down: u64,
    /// Successful reconnects after the first open.
    pub reconnects: u64,
}

#[cfg(test)]
mod tests {
    link_counters! {
        /// Test counters.
        atomic Demo;
        /// Their copy.
        plain DemoCopy;
        {
            /// One.
            a,
            /// Two.
            b,
        }
    }

    #[test]
    fn the_copy_holds_what_was_counted() {
        let d = Demo::default();
        Demo::inc(&d.a);
        Demo::add(&d.b, 5);
        Demo::inc(&d.b);
        assert_eq!(d.snapshot(), DemoCopy { a: 1, b: 6 });
    }
}
