//! The sender's clock of a periodic sensor message, rebuilt from its alive counter.
//!
//! A CAN sender samples and sends a cyclic message once per DBC cycle time
//! (`GenMsgCycleTime`) and adds one to the frame's alive counter each time
//! (`config/skid.dbc`). The time between two samples is therefore the counter's step × the
//! cycle time, whatever happened to the frames on their way: a receiver thread woken late, a
//! USB adapter handing over a batch of frames at once, a simulated plant whose host paused it
//! (the HIL suite's `timing` case, CI, 2026-11-29: the controller's clock moved 3.4 ms between
//! two samples 1 ms apart, the drive-torque law integrated its observer over 3.4 ms and the
//! plant surged). The arrival times carry all of those; the counter carries none.
//!
//! The counter wraps (4 bits on the skid bus: 16 frames), so a step d stands for d + k·2^bits
//! frames; k is the one that brings the step closest to the arrival gap in cycle times
//! (a 20-frame outage arrives as d = 4 after about 20 periods: k = 1). A gap longer than half
//! the counter's range (8 periods on the skid bus) therefore counts as frames lost while the
//! sender went on, which is what a real process does: a sender stopped for 64 ms is taken as
//! 65 ms of plant time. Only a simulated plant whose time stood still with it is wrong then
//! (the HIL `plant_pause` case keeps its stops under 8 ms for that reason). The clock starts
//! at the arrival time of the first frame (and again after a reset): only its differences
//! mean anything.
//!
//! The DBC's cycle time is the sender's promise, and a wrong one would scale every interval:
//! over each [`CHECK_WINDOW_NS`] of arrivals the clock must have advanced by the same time
//! within [`RATE_TOLERANCE`], or it is distrusted (until the link is reset) and the readings
//! go out without a sender clock: the core then takes its own cycle times, as for a source
//! without a counter. A pause of the sender (not of its frames) is not a reason: one of the
//! order of milliseconds per second stays well inside the tolerance.

use crate::io::can::e2e::AliveStatus;

/// Span of arrivals over which the clock's rate is checked, ns (1 s: long against the
/// millisecond cycle times and the pauses of a busy host, short against an operator noticing).
pub const CHECK_WINDOW_NS: u64 = 1_000_000_000;

/// Largest relative difference between the clock's advance and the arrivals' over a check
/// window: a DBC cycle time off by a factor of 1.25 or more (2 ms declared for a 1 ms
/// message: 100 %) is caught, while a sender paused for 100 ms in a second is not.
pub const RATE_TOLERANCE: f64 = 0.2;

/// The rebuilt clock of one message.
#[derive(Debug, Clone)]
pub struct SenderClock {
    period_ns: u64,
    modulus: u64,
    /// Arrival of the previous frame, ns (None before the first one).
    last_rx_ns: Option<u64>,
    clock_ns: u64,
    /// Start of the current check window: (arrival, clock), ns.
    window: (u64, u64),
    trusted: bool,
}

/// Why a clock stopped being trusted: the rates over the check window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateMismatch {
    /// Clock advance over the window, s.
    pub clock_s: f64,
    /// Arrival span of the window, s.
    pub arrivals_s: f64,
}

impl SenderClock {
    /// A clock for a message sent every `period_ns` with a counter modulo `modulus`.
    pub fn new(period_ns: u64, modulus: u64) -> SenderClock {
        SenderClock {
            period_ns: period_ns.max(1),
            modulus: modulus.max(1),
            last_rx_ns: None,
            clock_ns: 0,
            window: (0, 0),
            trusted: true,
        }
    }

    /// Forget the counter's history (after a reconnect): the next frame starts the clock
    /// again, trusted.
    pub fn reset(&mut self) {
        self.last_rx_ns = None;
        self.trusted = true;
    }

    /// A frame of the message, with the alive status its counter had and its arrival time.
    /// Returns the sample's time on the sender's clock (None: the clock is distrusted, see the
    /// module docs) and, once, the mismatch that made it distrusted.
    pub fn on_frame(
        &mut self,
        status: AliveStatus,
        rx_ns: u64,
    ) -> (Option<u64>, Option<RateMismatch>) {
        let step = match (status, self.last_rx_ns) {
            (AliveStatus::InSequence, Some(_)) => Some(1),
            (AliveStatus::Skipped { missed }, Some(_)) => Some(u64::from(missed) + 1),
            // first frame, or a repeated counter (never published): start again
            _ => None,
        };
        let mut mismatch = None;
        match (step, self.last_rx_ns) {
            (Some(d), Some(last)) => {
                // the wrap count k that brings d + k·modulus closest to the arrival gap
                let gap_periods = rx_ns.saturating_sub(last) as f64 / self.period_ns as f64;
                let k = ((gap_periods - d as f64) / self.modulus as f64)
                    .round()
                    .max(0.0) as u64;
                let frames = d + k * self.modulus;
                self.clock_ns = self
                    .clock_ns
                    .saturating_add(frames.saturating_mul(self.period_ns));
                let span = rx_ns.saturating_sub(self.window.0);
                if span >= CHECK_WINDOW_NS {
                    let clock = self.clock_ns.saturating_sub(self.window.1) as f64;
                    let ratio = clock / span as f64;
                    if self.trusted && (ratio - 1.0).abs() > RATE_TOLERANCE {
                        self.trusted = false;
                        mismatch = Some(RateMismatch {
                            clock_s: clock * 1e-9,
                            arrivals_s: span as f64 * 1e-9,
                        });
                    }
                    self.window = (rx_ns, self.clock_ns);
                }
            }
            _ => {
                self.clock_ns = rx_ns;
                self.window = (rx_ns, rx_ns);
            }
        }
        self.last_rx_ns = Some(rx_ns);
        (self.trusted.then_some(self.clock_ns), mismatch)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn clock() -> SenderClock {
        SenderClock::new(MS, 16)
    }

    #[test]
    fn a_late_frame_is_one_period_after_the_last_on_the_senders_clock() {
        let mut c = clock();
        let (t0, _) = c.on_frame(AliveStatus::First, 10 * MS);
        assert_eq!(t0, Some(10 * MS));
        // arrivals 3.4 ms, then 0.01 ms apart, the counter stepping by one each time
        let (t1, _) = c.on_frame(AliveStatus::InSequence, 13 * MS + 400_000);
        let (t2, _) = c.on_frame(AliveStatus::InSequence, 13 * MS + 410_000);
        assert_eq!(t1, Some(11 * MS));
        assert_eq!(t2, Some(12 * MS));
    }

    #[test]
    fn lost_frames_count_and_an_outage_longer_than_the_counter_unwraps() {
        let mut c = clock();
        c.on_frame(AliveStatus::First, 0);
        // 2 frames lost: the counter stepped by 3
        let (t, _) = c.on_frame(AliveStatus::Skipped { missed: 2 }, 3 * MS + 200_000);
        assert_eq!(t, Some(3 * MS));
        // a 20-frame outage: the 4-bit counter stepped by 4, the arrival gap says 20
        let (t, _) = c.on_frame(AliveStatus::Skipped { missed: 3 }, 23 * MS + 300_000);
        assert_eq!(t, Some(23 * MS));
        // without the arrival gap the step would have read 4 frames
        assert_ne!(t, Some(7 * MS));
    }

    #[test]
    fn a_reset_starts_the_clock_again_at_the_arrival() {
        let mut c = clock();
        c.on_frame(AliveStatus::First, 0);
        c.on_frame(AliveStatus::InSequence, MS);
        c.reset();
        let (t, _) = c.on_frame(AliveStatus::InSequence, 500 * MS);
        assert_eq!(
            t,
            Some(500 * MS),
            "after a reset the first frame anchors the clock"
        );
    }

    #[test]
    fn a_wrong_cycle_time_is_caught_within_a_window_and_the_clock_withdrawn() {
        // the DBC says 2 ms, the sender sends every 1 ms
        let mut c = SenderClock::new(2 * MS, 16);
        c.on_frame(AliveStatus::First, 0);
        let mut first_none = None;
        let mut reported = 0;
        for k in 1..=1500u64 {
            let (t, m) = c.on_frame(AliveStatus::InSequence, k * MS);
            if let Some(m) = m {
                reported += 1;
                assert!((m.clock_s / m.arrivals_s - 2.0).abs() < 0.01, "{m:?}");
            }
            if t.is_none() && first_none.is_none() {
                first_none = Some(k);
            }
        }
        assert_eq!(reported, 1, "the mismatch is reported once");
        assert_eq!(
            first_none,
            Some(1000),
            "withdrawn at the end of the first window"
        );
    }

    #[test]
    fn a_sender_paused_a_few_milliseconds_a_second_keeps_its_clock() {
        // a 1 ms sender whose host pauses it 4 ms once every 100 frames: 4 % of the arrivals'
        // time is not on the sender's clock, well inside the tolerance
        let mut c = clock();
        let mut rx = 0;
        c.on_frame(AliveStatus::First, rx);
        for k in 1..=3000u64 {
            rx += if k % 100 == 0 { 4 * MS } else { MS };
            let (t, m) = c.on_frame(AliveStatus::InSequence, rx);
            assert!(m.is_none());
            assert_eq!(t, Some(k * MS));
        }
    }
}
