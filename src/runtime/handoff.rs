//! Lock-free hand-off between the I/O tasks and the control thread.
//!
//! A [`SeqLock`] holds a few `f64`/`u64` words written by one writer and read by any number of
//! readers: the writer never waits, and a reader never waits for a write in progress either
//! (it reads the last completed of two buffers), whatever the threads' priorities and CPUs.
//! No mutex, no allocation, nothing that can block the control cycle.
//!
//! - [`SensorBoard`]: one slot per sensor with its value and the monotonic time it arrived;
//!   written by the bus task that owns the sensor, read by the control thread (which turns the
//!   arrival time into an age for the freshness check).
//! - [`OutputBoard`]: the control thread's latest setpoints, mode and law, read by the bus
//!   tasks that send them.
//! - [`Wakeup`]: an eventfd the control thread signals after publishing, so a sending task
//!   wakes without polling.

use crate::control::measurements::RawSensors;
use crate::vocab::signals::{ActuatorCommands, ActuatorId, SensorId, SensorSnapshot};
use crate::vocab::Mode;
use std::sync::atomic::{fence, AtomicU64, Ordering};

/// Single-writer, multi-reader sequence lock over `N` 64-bit words, double-buffered.
///
/// The writer fills the buffer readers are *not* directed to, then publishes it. A reader
/// therefore never waits for a write in progress: it reads the last published buffer and
/// retries only if the writer has meanwhile published again *and* begun overwriting that same
/// buffer (it lapped the read: possible only while the writer runs on another CPU, so the
/// retry ends). This matters when the reader outranks the writer on one CPU (the control
/// thread at SCHED_FIFO above the bus I/O thread, a single-core PLC-PC or both pinned to one
/// isolated core): with a plain seqlock a reader that preempts the writer mid-write spins on
/// the odd counter forever, because the writer can never run again. The HIL VM (one vCPU)
/// hung that way.
#[derive(Debug)]
pub struct SeqLock<const N: usize> {
    /// Completed writes; buffer `published & 1` holds the newest complete words.
    published: AtomicU64,
    bufs: [SeqBuffer<N>; 2],
}

/// One buffer of a [`SeqLock`], with its own sequence counter (odd while being written).
#[derive(Debug)]
struct SeqBuffer<const N: usize> {
    seq: AtomicU64,
    words: [AtomicU64; N],
}

impl<const N: usize> Default for SeqBuffer<N> {
    fn default() -> Self {
        SeqBuffer {
            seq: AtomicU64::new(0),
            words: std::array::from_fn(|_| AtomicU64::new(0)),
        }
    }
}

impl<const N: usize> Default for SeqLock<N> {
    fn default() -> Self {
        SeqLock {
            published: AtomicU64::new(0),
            bufs: [SeqBuffer::default(), SeqBuffer::default()],
        }
    }
}

impl<const N: usize> SeqLock<N> {
    /// Publish new words. Must only be called by the one writer of this lock.
    #[inline]
    pub fn write(&self, words: &[u64; N]) {
        let (n, buf) = self.begin_write();
        for (slot, w) in buf.words.iter().zip(words) {
            slot.store(*w, Ordering::Relaxed);
        }
        self.finish_write(n, buf);
    }

    /// Mark the buffer after the published one as being written (its counter becomes
    /// `2k − 1` for write number `k`); returns the number of writes published so far.
    #[inline]
    fn begin_write(&self) -> (u64, &SeqBuffer<N>) {
        let n = self.published.load(Ordering::Relaxed);
        let k = n.wrapping_add(1);
        let buf = &self.bufs[(k & 1) as usize];
        buf.seq
            .store(k.wrapping_mul(2).wrapping_sub(1), Ordering::Relaxed);
        fence(Ordering::Release);
        (n, buf)
    }

    /// Close the buffer (counter `2k`) and direct readers to it.
    #[inline]
    fn finish_write(&self, n: u64, buf: &SeqBuffer<N>) {
        let k = n.wrapping_add(1);
        buf.seq.store(k.wrapping_mul(2), Ordering::Release);
        self.published.store(k, Ordering::Release);
    }

    /// Read a consistent copy of the newest words and the number of writes so far (0 = never
    /// written). The copy is exactly write number `n` (its buffer's counter is `2n` before and
    /// after the copy), so successive reads never go back in time.
    #[inline]
    pub fn read(&self) -> ([u64; N], u64) {
        loop {
            let n = self.published.load(Ordering::Acquire);
            let buf = &self.bufs[(n & 1) as usize];
            let expect = n.wrapping_mul(2);
            if buf.seq.load(Ordering::Acquire) == expect {
                let mut out = [0u64; N];
                for (o, slot) in out.iter_mut().zip(&buf.words) {
                    *o = slot.load(Ordering::Relaxed);
                }
                fence(Ordering::Acquire);
                if buf.seq.load(Ordering::Relaxed) == expect {
                    return (out, n);
                }
            }
            // the writer lapped this read (it runs on another CPU): take the newer buffer
            std::hint::spin_loop();
        }
    }
}

/// Monotonic clock in nanoseconds (CLOCK_MONOTONIC), the time base of every stamp.
#[inline]
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes the timespec we pass; CLOCK_MONOTONIC always exists on Linux.
    unsafe {
        libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts);
    }
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Latest value of every sensor with its arrival time and, where the source has one, the
/// sample's time on its sender's clock ([`RawSensors::sample_clock_s`]).
#[derive(Debug, Default)]
pub struct SensorBoard {
    /// Per sensor: value bits, arrival (monotonic ns), sender clock (ns, [`NO_SAMPLE_CLOCK`]).
    slots: [SeqLock<3>; SensorId::COUNT],
    /// Redundant transmitters `b` and `c` of each sensor (the signal map's `[vote]`).
    spares: [[SeqLock<2>; 2]; SensorId::COUNT],
}

/// The sender-clock word of a reading whose source has no clock of its own.
pub const NO_SAMPLE_CLOCK: u64 = u64::MAX;

impl SensorBoard {
    /// Publish a reading that arrived at `t_ns` (monotonic), from a source without a clock of
    /// its own (Modbus answers). One writer per sensor.
    #[inline]
    pub fn publish(&self, id: SensorId, value: f64, t_ns: u64) {
        self.publish_sampled(id, value, t_ns, NO_SAMPLE_CLOCK);
    }

    /// Publish a reading that arrived at `t_ns` (monotonic) and was sampled at `sample_ns` on
    /// its sender's clock (any origin; [`NO_SAMPLE_CLOCK`]: none). One writer per sensor.
    #[inline]
    pub fn publish_sampled(&self, id: SensorId, value: f64, t_ns: u64, sample_ns: u64) {
        self.slots[id.index()].write(&[value.to_bits(), t_ns, sample_ns]);
    }

    /// Value and arrival time of one sensor (NaN and 0 if never received).
    #[inline]
    pub fn get(&self, id: SensorId) -> (f64, u64) {
        let ([v, t, _], seq) = self.slots[id.index()].read();
        if seq == 0 {
            (f64::NAN, 0)
        } else {
            (f64::from_bits(v), t)
        }
    }

    /// Every input of a control cycle at `now_ns`: values, ages, sample numbers, the redundant
    /// transmitters and the sender clocks. Allocation-free; the one way from the board to the core.
    pub fn raw(&self, now_ns: u64) -> RawSensors {
        let mut raw = RawSensors::missing();
        for id in SensorId::ALL {
            let ([v, t, c], seq) = self.slots[id.index()].read();
            if seq == 0 {
                continue;
            }
            raw.values.set(id, f64::from_bits(v));
            // the slot's write count is the sensor's sample number (the core's sample identity)
            raw.sample_seq[id.index()] = seq;
            if t > 0 {
                raw.age_s[id.index()] = now_ns.saturating_sub(t) as f64 * 1e-9;
            }
            if c != NO_SAMPLE_CLOCK {
                raw.sample_clock_s[id.index()] = c as f64 * 1e-9;
            }
        }
        raw.spare = self.spares(now_ns);
        raw
    }

    /// Publish a reading of transmitter `slot` (1 = `b`, 2 = `c`) of `id`; slot 0 is
    /// [`publish`](Self::publish). One writer per transmitter.
    #[inline]
    pub fn publish_transmitter(&self, id: SensorId, slot: usize, value: f64, t_ns: u64) {
        match slot {
            0 => self.publish(id, value, t_ns),
            1 | 2 => self.spares[id.index()][slot - 1].write(&[value.to_bits(), t_ns]),
            _ => {}
        }
    }

    /// The redundant transmitters' readings with their ages at `now_ns` (NaN and ∞ where
    /// none arrived). Allocation-free.
    pub fn spares(&self, now_ns: u64) -> crate::control::measurements::SpareReadings {
        let mut out = crate::control::measurements::SpareReadings::NONE;
        for id in SensorId::ALL {
            for slot in 1..=2 {
                let ([v, t], seq) = self.spares[id.index()][slot - 1].read();
                if seq != 0 {
                    let age = if t > 0 {
                        now_ns.saturating_sub(t) as f64 * 1e-9
                    } else {
                        f64::INFINITY
                    };
                    out.set(id, slot, f64::from_bits(v), age);
                }
            }
        }
        out
    }

    /// Snapshot of all sensors with their ages at `now_ns`, s (∞ if never received): the
    /// values and ages of [`raw`](Self::raw).
    pub fn snapshot(&self, now_ns: u64) -> (SensorSnapshot, [f64; SensorId::COUNT]) {
        let raw = self.raw(now_ns);
        (raw.values, raw.age_s)
    }
}

/// What the control thread publishes each cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outputs {
    /// Setpoints.
    pub commands: ActuatorCommands,
    /// Controller mode (on the wire and in the word it travels in, by [`Mode::code`]).
    pub mode: Mode,
    /// Active law code.
    pub law: u8,
    /// Fault bits for the heartbeat.
    pub faults: u32,
    /// Cycle counter.
    pub cycle: u64,
    /// Monotonic time the outputs were computed, ns.
    pub t_ns: u64,
}

const OUT_WORDS: usize = ActuatorId::COUNT + 3;

/// The control thread's latest outputs.
#[derive(Debug, Default)]
pub struct OutputBoard {
    lock: SeqLock<OUT_WORDS>,
}

impl OutputBoard {
    /// Publish (control thread only).
    #[inline]
    pub fn publish(&self, o: &Outputs) {
        let mut w = [0u64; OUT_WORDS];
        for (i, v) in o.commands.values.iter().enumerate() {
            w[i] = v.to_bits();
        }
        let n = ActuatorId::COUNT;
        w[n] = u64::from(o.mode.code()) | (u64::from(o.law) << 8) | (u64::from(o.faults) << 32);
        w[n + 1] = o.cycle;
        w[n + 2] = o.t_ns;
        self.lock.write(&w);
    }

    /// Latest outputs, or `None` if nothing was published yet.
    #[inline]
    pub fn latest(&self) -> Option<Outputs> {
        let (w, seq) = self.lock.read();
        if seq == 0 {
            return None;
        }
        let n = ActuatorId::COUNT;
        let mut commands = ActuatorCommands::default();
        for (c, word) in commands.values.iter_mut().zip(&w[..n]) {
            *c = f64::from_bits(*word);
        }
        Some(Outputs {
            commands,
            mode: Mode::from_code((w[n] & 0xff) as u8).unwrap_or(Mode::FailSafe),
            law: ((w[n] >> 8) & 0xff) as u8,
            faults: (w[n] >> 32) as u32,
            cycle: w[n + 1],
            t_ns: w[n + 2],
        })
    }
}

/// Latest actuator setpoints received from the controller, each with its arrival time (plant
/// side). One writer per actuator (the bus task that owns it).
#[derive(Debug, Default)]
pub struct CommandBoard {
    slots: [SeqLock<2>; ActuatorId::COUNT],
}

impl CommandBoard {
    /// Publish a received setpoint.
    #[inline]
    pub fn publish(&self, id: ActuatorId, value: f64, t_ns: u64) {
        self.slots[id.index()].write(&[value.to_bits(), t_ns]);
    }

    /// Setpoint and arrival time (NaN and 0 if never received).
    #[inline]
    pub fn get(&self, id: ActuatorId) -> (f64, u64) {
        let ([v, t], seq) = self.slots[id.index()].read();
        if seq == 0 {
            (f64::NAN, 0)
        } else {
            (f64::from_bits(v), t)
        }
    }
}

/// The controller's heartbeat as last received (plant side).
#[derive(Debug, Default)]
pub struct HeartbeatBoard {
    lock: SeqLock<3>,
}

/// One received heartbeat.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HeartbeatSeen {
    /// Controller mode.
    pub mode: Mode,
    /// Active law code.
    pub law: u8,
    /// Alive counter.
    pub alive: u8,
    /// Fault bits.
    pub faults: u32,
    /// Arrival time, monotonic ns.
    pub t_ns: u64,
}

impl HeartbeatBoard {
    /// Publish a received heartbeat (one writer).
    #[inline]
    pub fn publish(&self, hb: &HeartbeatSeen) {
        let w0 = u64::from(hb.mode.code()) | (u64::from(hb.law) << 8) | (u64::from(hb.alive) << 16);
        self.lock.write(&[w0, u64::from(hb.faults), hb.t_ns]);
    }

    /// Last heartbeat, or `None` if none was received yet.
    #[inline]
    pub fn latest(&self) -> Option<HeartbeatSeen> {
        let ([w0, f, t], seq) = self.lock.read();
        if seq == 0 {
            return None;
        }
        Some(HeartbeatSeen {
            mode: Mode::from_code((w0 & 0xff) as u8).unwrap_or(Mode::FailSafe),
            law: ((w0 >> 8) & 0xff) as u8,
            alive: ((w0 >> 16) & 0xff) as u8,
            faults: f as u32,
            t_ns: t,
        })
    }
}

/// A sensor snapshot published by one writer (the plant node's real-time loop) for the tasks
/// that send it.
#[derive(Debug, Default)]
pub struct SnapshotBoard {
    lock: SeqLock<{ SensorId::COUNT + 2 }>,
}

impl SnapshotBoard {
    /// Publish a snapshot sampled at `t_ns` on the publisher's clock (the simulated plant's:
    /// its steps × its period, which a host that stops it does not advance) in cycle `cycle`.
    #[inline]
    pub fn publish(&self, s: &SensorSnapshot, cycle: u64, t_ns: u64) {
        let mut w = [0u64; SensorId::COUNT + 2];
        for (i, v) in s.values.iter().enumerate() {
            w[i] = v.to_bits();
        }
        w[SensorId::COUNT] = cycle;
        w[SensorId::COUNT + 1] = t_ns;
        self.lock.write(&w);
    }

    /// Latest snapshot with its cycle and time, or `None` before the first publish.
    #[inline]
    pub fn latest(&self) -> Option<(SensorSnapshot, u64, u64)> {
        let (w, seq) = self.lock.read();
        if seq == 0 {
            return None;
        }
        let mut s = SensorSnapshot::default();
        for (v, word) in s.values.iter_mut().zip(&w[..SensorId::COUNT]) {
            *v = f64::from_bits(*word);
        }
        Some((s, w[SensorId::COUNT], w[SensorId::COUNT + 1]))
    }
}

/// An eventfd: the control thread signals, an async task waits.
#[derive(Debug)]
pub struct Wakeup {
    fd: std::os::fd::OwnedFd,
}

impl Wakeup {
    /// A non-blocking eventfd.
    pub fn new() -> std::io::Result<Wakeup> {
        // SAFETY: eventfd returns a new descriptor or −1; we check and take ownership.
        let fd = unsafe { libc::eventfd(0, libc::EFD_NONBLOCK | libc::EFD_CLOEXEC) };
        if fd < 0 {
            return Err(std::io::Error::last_os_error());
        }
        // SAFETY: fd is a valid, newly created descriptor owned by nobody else.
        Ok(Wakeup {
            fd: unsafe { std::os::fd::FromRawFd::from_raw_fd(fd) },
        })
    }

    /// Signal (never blocks: an overflowing counter just stays signalled).
    #[inline]
    pub fn signal(&self) {
        let one: u64 = 1;
        // SAFETY: writes 8 bytes from a valid u64 to our own eventfd.
        unsafe {
            libc::write(
                std::os::fd::AsRawFd::as_raw_fd(&self.fd),
                (&one as *const u64).cast(),
                8,
            );
        }
    }

    /// Clear the counter (after waking). Returns how many signals were pending.
    pub fn clear(&self) -> u64 {
        let mut v: u64 = 0;
        // SAFETY: reads 8 bytes into a valid u64 from our own non-blocking eventfd.
        let n = unsafe {
            libc::read(
                std::os::fd::AsRawFd::as_raw_fd(&self.fd),
                (&mut v as *mut u64).cast(),
                8,
            )
        };
        if n == 8 {
            v
        } else {
            0
        }
    }

    /// The raw descriptor (for `tokio::io::unix::AsyncFd`).
    pub fn fd(&self) -> std::os::fd::BorrowedFd<'_> {
        std::os::fd::AsFd::as_fd(&self.fd)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn seqlock_reads_are_never_torn() {
        let lock = Arc::new(SeqLock::<4>::default());
        let w = Arc::clone(&lock);
        let writer = std::thread::spawn(move || {
            for k in 1..200_000u64 {
                w.write(&[k, k, k, k]);
            }
        });
        let mut last = 0;
        while !writer.is_finished() || last < 199_999 {
            let (words, _) = lock.read();
            assert!(words.iter().all(|&x| x == words[0]), "torn read {words:?}");
            assert!(
                words[0] >= last,
                "went backwards: {} after {last}",
                words[0]
            );
            last = words[0];
            if writer.is_finished() && last == 0 {
                break;
            }
        }
        writer.join().expect("writer");
        assert_eq!(lock.read().0, [199_999; 4]);
    }

    #[test]
    fn a_reader_never_waits_for_a_stalled_writer() {
        // The writer is preempted mid-write (on one CPU, by the higher-priority reader) and
        // cannot run until the reader is done: the read must return the last complete words
        // at once. (A plain seqlock spins forever here; the read runs on a thread so that a
        // regression fails the test instead of hanging it.)
        let lock = Arc::new(SeqLock::<3>::default());
        lock.write(&[7, 7, 7]);
        let (n, buf) = lock.begin_write();
        buf.words[0].store(8, Ordering::Relaxed); // half-written
        let r = Arc::clone(&lock);
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || tx.send(r.read()).ok());
        let got = rx
            .recv_timeout(std::time::Duration::from_secs(5))
            .expect("read blocked behind a stalled writer");
        assert_eq!(got, ([7, 7, 7], 1));
        buf.words[1].store(8, Ordering::Relaxed);
        buf.words[2].store(8, Ordering::Relaxed);
        lock.finish_write(n, buf);
        assert_eq!(lock.read(), ([8, 8, 8], 2));
        // and the next write goes to the other buffer while this one stays readable
        let (n, buf) = lock.begin_write();
        assert_eq!(lock.read(), ([8, 8, 8], 2));
        lock.finish_write(n, buf);
    }

    #[test]
    fn sensor_board_ages_and_unknown() {
        let b = SensorBoard::default();
        b.publish(SensorId::PSuction, 1.5e5, 1_000_000_000);
        let (snap, age) = b.snapshot(1_020_000_000);
        assert_eq!(snap.get(SensorId::PSuction), 1.5e5);
        assert!((age[SensorId::PSuction.index()] - 0.02).abs() < 1e-12);
        assert!(snap.get(SensorId::ShaftSpeed).is_nan());
        assert!(age[SensorId::ShaftSpeed.index()].is_infinite());
    }

    #[test]
    fn output_board_round_trips() {
        let b = OutputBoard::default();
        assert!(b.latest().is_none());
        let mut c = ActuatorCommands::default();
        c.set(ActuatorId::RecycleValve, 0.42);
        let o = Outputs {
            commands: c,
            mode: Mode::Auto,
            law: 1,
            faults: 0xdead_beef,
            cycle: 7,
            t_ns: 99,
        };
        b.publish(&o);
        let r = b.latest().expect("published");
        assert_eq!(r.commands.get(ActuatorId::RecycleValve), 0.42);
        assert!(r.commands.get(ActuatorId::DriveTorque).is_nan());
        assert_eq!(
            (r.mode, r.law, r.faults, r.cycle, r.t_ns),
            (Mode::Auto, 1, 0xdead_beef, 7, 99)
        );
    }

    #[test]
    fn wakeup_counts_signals() {
        let w = Wakeup::new().expect("eventfd");
        assert_eq!(w.clear(), 0);
        w.signal();
        w.signal();
        assert_eq!(w.clear(), 2);
        assert_eq!(w.clear(), 0);
    }
}
