//! The one retry strategy of the field links: after a failure, wait `initial`, then twice as
//! long after each further failure, up to `max`; a working exchange starts over. The CAN task
//! waits it before reopening its socket, the Modbus client before reconnecting.

use std::time::Duration;

/// Exponential backoff: `initial`, `2·initial`, … capped at `max`; never zero (a zero wait
/// would reconnect in a busy loop).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Backoff {
    initial: Duration,
    max: Duration,
    next: Duration,
    last: Duration,
}

impl Backoff {
    /// A backoff from `initial` (at least 1 ms) doubling up to `max` (at least `initial`).
    pub fn new(initial: Duration, max: Duration) -> Backoff {
        let initial = initial.max(Duration::from_millis(1));
        Backoff {
            initial,
            max: max.max(initial),
            next: initial,
            last: Duration::ZERO,
        }
    }

    /// The wait after this failure; the next one doubles it (up to the cap).
    pub fn next_delay(&mut self) -> Duration {
        let d = self.next;
        self.last = d;
        self.next = (d * 2).min(self.max);
        d
    }

    /// The link worked: the next failure waits `initial` again.
    pub fn reset(&mut self) {
        self.next = self.initial;
    }

    /// The wait applied after the last failure (zero before the first).
    pub fn last(&self) -> Duration {
        self.last
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn doubles_to_the_cap_and_resets() {
        let ms = Duration::from_millis;
        let mut b = Backoff::new(ms(50), ms(2000));
        assert_eq!(b.last(), Duration::ZERO);
        let seq: Vec<u128> = (0..8).map(|_| b.next_delay().as_millis()).collect();
        assert_eq!(seq, [50, 100, 200, 400, 800, 1600, 2000, 2000]);
        assert_eq!(b.last(), ms(2000));
        b.reset();
        assert_eq!(b.last(), ms(2000), "the last wait stays for display");
        assert_eq!(b.next_delay(), ms(50));
        let mut b = Backoff::new(Duration::ZERO, Duration::ZERO);
        assert_eq!(b.next_delay(), ms(1), "never zero: no busy loop");
        let mut b = Backoff::new(ms(100), ms(10));
        assert_eq!(
            (b.next_delay(), b.next_delay()),
            (ms(100), ms(100)),
            "cap below start"
        );
    }
}
