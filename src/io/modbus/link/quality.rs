//! Link quality of a controller link: the poll period it achieves and how long the device
//! takes to answer, over sliding windows in seconds (never in samples), so the figures mean the
//! same at 10 Hz and at 1 kHz.
//!
//! - **Achieved poll period**: the mean interval between polls answered in full over the last
//!   [`PERIOD_WINDOW_S`] (the interval at which the inputs are renewed, what their freshness
//!   budget is about), and never less than the time since the last one (a device that answers
//!   late, or times out, makes the period grow while nothing completes).
//! - **Answer latency** p50 and p99 over the requests of the last [`LATENCY_WINDOW_S`]: each
//!   answer (normal or exception), and each timeout with the time waited, a lower bound of
//!   its latency (the link task decides what counts).
//!
//! Fixed-size rings, no allocation after construction.

/// Window of the achieved poll period, s: one second, the time within which a slow device
/// must be reported (issue 23), and ten polls even at a 10 Hz link.
pub const PERIOD_WINDOW_S: f64 = 1.0;

/// Window of the latency percentiles, s: ten seconds, a hundred answers at a 10 Hz link, so
/// the p99 rests on more than one sample.
pub const LATENCY_WINDOW_S: f64 = 10.0;

/// Poll starts kept (1 s at up to 1 kHz, one more for the interval).
const POLLS: usize = 1025;
/// Answers kept (10 s at 100 requests/s; a faster link's window is the last 2048 answers).
const ANSWERS: usize = 2048;

/// The figures of a link, µs (0: not known yet).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Quality {
    /// Achieved poll period, µs.
    pub poll_period_us: u64,
    /// Answer latency, median, µs.
    pub latency_p50_us: u64,
    /// Answer latency, 99th percentile, µs.
    pub latency_p99_us: u64,
}

/// The sliding windows.
#[derive(Debug, Clone)]
pub struct QualityWindow {
    polls_ns: Box<[u64; POLLS]>,
    poll_at: usize,
    poll_len: usize,
    answers: Box<[(u64, u32); ANSWERS]>,
    answer_at: usize,
    answer_len: usize,
    scratch: Box<[u32; ANSWERS]>,
}

impl Default for QualityWindow {
    fn default() -> Self {
        QualityWindow {
            polls_ns: Box::new([0; POLLS]),
            poll_at: 0,
            poll_len: 0,
            answers: Box::new([(0, 0); ANSWERS]),
            answer_at: 0,
            answer_len: 0,
            scratch: Box::new([0; ANSWERS]),
        }
    }
}

fn secs_ns(s: f64) -> u64 {
    (s * 1e9) as u64
}

impl QualityWindow {
    /// A poll was answered in full at `t_ns` (monotonic).
    pub fn poll_answered(&mut self, t_ns: u64) {
        self.poll_at = (self.poll_at + 1) % POLLS;
        self.polls_ns[self.poll_at] = t_ns;
        self.poll_len = (self.poll_len + 1).min(POLLS);
    }

    /// A request sent at `sent_ns` was answered at `answered_ns`.
    pub fn answered(&mut self, sent_ns: u64, answered_ns: u64) {
        let us = u32::try_from(answered_ns.saturating_sub(sent_ns) / 1000).unwrap_or(u32::MAX);
        self.answer_at = (self.answer_at + 1) % ANSWERS;
        self.answers[self.answer_at] = (answered_ns, us);
        self.answer_len = (self.answer_len + 1).min(ANSWERS);
    }

    /// The figures at `now_ns`.
    pub fn quality(&mut self, now_ns: u64) -> Quality {
        let mut q = Quality::default();
        if self.poll_len > 0 {
            let newest = self.polls_ns[self.poll_at];
            let from = now_ns.saturating_sub(secs_ns(PERIOD_WINDOW_S));
            let mut oldest = newest;
            let mut n = 0u64;
            for k in 1..self.poll_len {
                let t = self.polls_ns[(self.poll_at + POLLS - k) % POLLS];
                if t < from {
                    break;
                }
                oldest = t;
                n += 1;
            }
            let mean_ns = (newest - oldest).checked_div(n).unwrap_or(0);
            q.poll_period_us = mean_ns.max(now_ns.saturating_sub(newest)) / 1000;
        }
        let from = now_ns.saturating_sub(secs_ns(LATENCY_WINDOW_S));
        let mut n = 0;
        for k in 0..self.answer_len {
            let (t, us) = self.answers[(self.answer_at + ANSWERS - k) % ANSWERS];
            if t < from {
                break;
            }
            self.scratch[n] = us;
            n += 1;
        }
        if n > 0 {
            let s = &mut self.scratch[..n];
            s.sort_unstable();
            // nearest rank
            let rank = |p: f64| ((p * n as f64).ceil() as usize).clamp(1, n) - 1;
            q.latency_p50_us = u64::from(s[rank(0.50)]);
            q.latency_p99_us = u64::from(s[rank(0.99)]);
        }
        q
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn the_period_is_the_mean_over_the_last_second_and_grows_while_nothing_comes() {
        let mut w = QualityWindow::default();
        // 2 s at 100 Hz, then 118 ms per poll (a device 90 ms late), for 2 s
        let mut t = 0;
        for _ in 0..200 {
            w.poll_answered(t);
            t += 10 * MS;
        }
        assert_eq!(w.quality(t - 10 * MS).poll_period_us, 10_000);
        for _ in 0..17 {
            w.poll_answered(t);
            t += 118 * MS;
        }
        let q = w.quality(t - 118 * MS);
        assert_eq!(q.poll_period_us, 118_000, "{q:?}");
        // nothing for 3 s: the period is the time since the last poll
        let last = t - 118 * MS;
        assert_eq!(w.quality(last + 3000 * MS).poll_period_us, 3_000_000);
    }

    #[test]
    fn latency_percentiles_over_the_last_ten_seconds() {
        let mut w = QualityWindow::default();
        // 100 answers at 2 ms, then 1 at 95 ms: p50 2 ms, p99 2 ms (rank 100 of 101 is 2 ms)
        let mut t = 0;
        for _ in 0..100 {
            w.answered(t, t + 2 * MS);
            t += 10 * MS;
        }
        w.answered(t, t + 95 * MS);
        let q = w.quality(t + 95 * MS);
        assert_eq!((q.latency_p50_us, q.latency_p99_us), (2_000, 2_000));
        // 20 more answers at 90 ms: 21 of 121 slow, p50 fast, p99 the 120th of 121 (90 ms)
        for _ in 0..20 {
            t += 118 * MS;
            w.answered(t, t + 90 * MS);
        }
        let q = w.quality(t + 90 * MS);
        assert_eq!((q.latency_p50_us, q.latency_p99_us), (2_000, 90_000));
        // 11 s later the window is empty again
        assert_eq!(w.quality(t + 11_000 * MS).latency_p99_us, 0);
    }
}
