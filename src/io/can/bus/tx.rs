//! Send side: board contents in, ready-to-write frames out. No socket, no allocation.

use std::time::Duration;

use socketcan::{CanDataFrame, EmbeddedFrame, Id};

use super::CanBusError;
use super::NotAvailable;
use crate::io::can::bits::MAX_PAYLOAD;
use crate::io::can::codec::{
    AliveCounters, CanCodec, MessageIndex, SignalTarget, SignalValues, TargetSet, MAX_TARGETS,
};
use crate::io::can::heartbeat::{Heartbeat, HeartbeatCodec};
use crate::runtime::handoff::Outputs;

/// How early a message may go before its slot on the DBC schedule, ns: half a 1 kHz wakeup
/// period (capped at half the message's own period).
const SLACK_NS: u64 = 500_000;

#[derive(Debug, Clone)]
struct TxMessage {
    index: MessageIndex,
    id: Id,
    dlc: usize,
    /// Last payload sent (unbound bits keep theirs from here).
    last: [u8; MAX_PAYLOAD],
    /// Alive counter in `last`.
    last_alive: u8,
    /// When `last` was sent (monotonic ns); `None` before the first frame.
    last_sent_ns: Option<u64>,
    /// The DBC cycle time (`GenMsgCycleTime`), ns; 0 for an event-driven message (sent on
    /// every call).
    period_ns: u64,
    /// When the next frame is due (monotonic ns) on the message's own schedule; `None`
    /// before the first frame.
    due_ns: Option<u64>,
    /// Targets bound to the message's signals.
    targets: TargetSet,
    /// Targets that have had a number (a computed command or a reading) at least once.
    given: TargetSet,
}

impl TxMessage {
    /// Whether the message is due at `now_ns`: event-driven, never sent, or its next slot on
    /// the DBC schedule is less than [`SLACK_NS`] (at most half the period) ahead: the
    /// callers' wakeups jitter, and a 1 ms message on a 1 ms wakeup that came 0.3 ms early
    /// must still go, while a 2 ms message must not go on the wakeup before its slot.
    fn due(&self, now_ns: u64) -> bool {
        match self.due_ns {
            Some(due) if self.period_ns > 0 => {
                now_ns.saturating_add(SLACK_NS.min(self.period_ns / 2)) > due
            }
            _ => true,
        }
    }

    /// Advance the schedule after a frame went out at `now_ns`: one period per frame, so the
    /// average rate is the DBC's whatever the wakeup jitter; a schedule that fell more than
    /// a period behind (no wakeups for a while) restarts from now instead of bursting.
    fn schedule_after_send(&mut self, now_ns: u64) {
        if self.period_ns == 0 {
            return;
        }
        let next = self
            .due_ns
            .map_or(now_ns, |d| d)
            .saturating_add(self.period_ns);
        self.due_ns = Some(if next.saturating_add(self.period_ns) <= now_ns {
            now_ns.saturating_add(self.period_ns)
        } else {
            next
        });
    }
}

/// Encodes a fixed list of messages from signal values. A NaN value ("not driven", "no
/// reading") goes out as the signal's "not available" pattern, never as a stale number.
///
/// Each message keeps the cycle time its DBC declares (`GenMsgCycleTime`): a 10 ms message
/// encoded on every 1 ms wakeup goes out every tenth call, so the bus carries the load that
/// check-config computed (src/io/can/busload.rs). Messages without a cycle time go out on
/// every call.
///
/// Nothing is sent for a message before one of its bound values is a number (no frame before
/// the first computed command). How "no value" goes on the wire is the device's convention
/// (`bus.can.not_available`, [`NotAvailable`]): `j1939` sends the reserved pattern (and fills
/// unbound data signals with it); `none` has no such pattern, so a message waits until every
/// bound value was a number once, a value that turns NaN later repeats the last number sent
/// (the last command the device was given), and an unbound data signal is refused at start.
#[derive(Debug, Clone)]
pub struct FrameEncoder {
    codec: CanCodec,
    messages: Vec<TxMessage>,
    alive: AliveCounters,
    on_change_only: bool,
    refresh_ns: u64,
    not_available: NotAvailable,
    /// Last number per target ([`SignalTarget::index`]), for `NotAvailable::None`.
    held: [f64; MAX_TARGETS],
    /// The alive counter counts cycle times elapsed, not frames sent
    /// ([`FrameEncoder::counting_sample_periods`]).
    count_periods: bool,
}

/// The values to encode: NaN replaced by the last number (`NotAvailable::None`) or kept.
struct Substituted<'a, V: ?Sized> {
    inner: &'a V,
    held: &'a [f64; MAX_TARGETS],
    hold: bool,
}

impl<V: SignalValues + ?Sized> SignalValues for Substituted<'_, V> {
    #[inline]
    fn value(&self, target: SignalTarget) -> f64 {
        let v = self.inner.value(target);
        if self.hold && v.is_nan() {
            self.held.get(target.index()).copied().unwrap_or(f64::NAN)
        } else {
            v
        }
    }
}

impl FrameEncoder {
    /// The alive counter of each cyclic message counts the cycle times elapsed on the
    /// caller's clock (the `now_ns` given to [`encode`](Self::encode)), not the frames sent:
    /// a sample the sender took but could not send (its task late) reaches the receiver as a
    /// lost frame, so the receiver's sender clock (`bus::SenderClock`) still counts every
    /// sample period. For a sender whose clock is its sampling: the simulated plant, which
    /// encodes on its own step time.
    pub fn counting_sample_periods(mut self) -> FrameEncoder {
        self.count_periods = true;
        self
    }

    /// An encoder for `messages` of `codec`. With `on_change_only`, a message whose data bits
    /// did not change is skipped unless `refresh` passed since it was last sent.
    pub fn new(
        codec: &CanCodec,
        messages: &[MessageIndex],
        on_change_only: bool,
        refresh: Duration,
    ) -> Result<FrameEncoder, CanBusError> {
        Self::with_not_available(
            codec,
            messages,
            on_change_only,
            refresh,
            NotAvailable::J1939,
        )
    }

    /// [`FrameEncoder::new`] for a device with the `not_available` convention. Errors if the
    /// device has no "not available" pattern and a message leaves a data signal unbound (the
    /// frame would carry a value nobody computed).
    pub fn with_not_available(
        codec: &CanCodec,
        messages: &[MessageIndex],
        on_change_only: bool,
        refresh: Duration,
        not_available: NotAvailable,
    ) -> Result<FrameEncoder, CanBusError> {
        // "follow the DBC": J1939 where the DBC declares it, else the start values
        let start_values = not_available == NotAvailable::Dbc && !codec.declares_j1939();
        let not_available = match not_available {
            NotAvailable::Dbc if codec.declares_j1939() => NotAvailable::J1939,
            NotAvailable::Dbc => NotAvailable::None,
            other => other,
        };
        let mut out = Vec::with_capacity(messages.len());
        for &index in messages {
            let name = codec.message_name(index).unwrap_or("?").to_string();
            let guard = codec.guard(index).ok_or_else(|| CanBusError::Config {
                key: "dbc",
                message: format!("message #{} missing from the codec", index.get()),
            })?;
            let id = guard
                .id()
                .to_socketcan()
                .ok_or_else(|| CanBusError::BadId {
                    message: name.clone(),
                    id: guard.id(),
                })?;
            let mut last = [0u8; MAX_PAYLOAD];
            for (signal, layout, start_raw) in codec.unbound_signals(index) {
                match (not_available, start_raw) {
                    (NotAvailable::J1939, _) => layout.pack(&mut last, layout.raw_not_available()),
                    (_, Some(raw)) if start_values => {
                        if !(layout.raw_min()..=layout.raw_max()).contains(raw) {
                            return Err(CanBusError::Config {
                                key: "dbc",
                                message: format!(
                                    "signal {name}.{signal}: start value (GenSigStartValue) {raw} does not fit the signal's {} bits",
                                    layout.size()
                                ),
                            });
                        }
                        layout.pack(&mut last, *raw)
                    }
                    (_, None) if start_values => {
                        return Err(CanBusError::Config {
                            key: "not_available",
                            message: format!(
                                "signal {name}.{signal} is bound to nothing, the DBC gives it no start value (GenSigStartValue) and declares no J1939 network: every frame would carry a value nobody chose; bind it in the signal map, give it a GenSigStartValue in the DBC, or set not_available = \"j1939\" if the device reads all ones as no value"
                            ),
                        })
                    }
                    _ => {
                        return Err(CanBusError::Config {
                            key: "not_available",
                            message: format!(
                                "signal {name}.{signal} is bound to nothing and the device has no \"not available\" value (not_available = \"none\"): every frame would carry a command nobody computed; bind it in the signal map"
                            ),
                        })
                    }
                }
            }
            out.push(TxMessage {
                index,
                id,
                dlc: usize::from(guard.dlc()),
                last,
                last_alive: 0,
                last_sent_ns: None,
                period_ns: u64::from(codec.cycle_time_ms(index).unwrap_or(0)) * 1_000_000,
                due_ns: None,
                targets: codec.targets(index),
                given: TargetSet::default(),
            });
        }
        Ok(FrameEncoder {
            codec: codec.clone(),
            messages: out,
            alive: codec.alive_counters(),
            on_change_only,
            refresh_ns: u64::try_from(refresh.as_nanos()).unwrap_or(u64::MAX),
            not_available,
            held: [f64::NAN; MAX_TARGETS],
            count_periods: false,
        })
    }

    /// Number of messages.
    pub fn len(&self) -> usize {
        self.messages.len()
    }

    /// Whether there are no messages.
    pub fn is_empty(&self) -> bool {
        self.messages.is_empty()
    }

    /// Whether message `i` is due at `now_ns` on its DBC cycle time (false if `i` is out of
    /// range).
    pub fn is_due(&self, i: usize, now_ns: u64) -> bool {
        self.messages.get(i).is_some_and(|m| m.due(now_ns))
    }

    /// The DBC cycle time of message `i`, ns (0: event-driven, sent on every call).
    pub fn period_ns(&self, i: usize) -> Option<u64> {
        self.messages.get(i).map(|m| m.period_ns)
    }

    /// Encode message `i` (0..len) from `values` at time `now_ns` (monotonic): the next alive
    /// counter value, the CRC, NaN values holding their last bits. `None` if the message is
    /// not due on its cycle time ([`FrameEncoder::is_due`]), skipped (unchanged under
    /// `on_change_only`) or `i` is out of range. The frame counts as sent: the caller must
    /// write it (a failed write shows up as a skipped counter value at the receiver, which is
    /// what it is).
    pub fn encode<V: SignalValues + ?Sized>(
        &mut self,
        i: usize,
        values: &V,
        now_ns: u64,
    ) -> Option<CanDataFrame> {
        let FrameEncoder {
            codec,
            messages,
            alive: counters,
            on_change_only,
            refresh_ns,
            not_available,
            held,
            count_periods,
        } = self;
        let m = messages.get_mut(i)?;
        if !m.due(now_ns) {
            return None;
        }
        for t in m.targets.iter() {
            let v = values.value(t);
            if v.is_finite() {
                m.given.insert(t);
                if let Some(h) = held.get_mut(t.index()) {
                    *h = v;
                }
            }
        }
        let hold = *not_available == NotAvailable::None;
        // nothing before the first number; without a "not available" value, nothing before
        // every bound signal had one
        if m.given.is_empty() || (hold && m.given != m.targets) {
            return None;
        }
        let values = Substituted {
            inner: values,
            held,
            hold,
        };
        if *on_change_only {
            if let Some(sent) = m.last_sent_ns {
                if now_ns.saturating_sub(sent) < *refresh_ns {
                    // Same counter value → same bytes iff the data bits are unchanged.
                    let mut candidate = m.last;
                    codec
                        .encode_into(m.index, &values, m.last_alive, &mut candidate)
                        .ok()?;
                    if candidate == m.last {
                        return None;
                    }
                }
            }
        }
        if *count_periods && m.period_ns > 0 {
            if let Some(sent) = m.last_sent_ns {
                // the periods between the last frame and this one whose samples went unsent
                let periods = (now_ns.saturating_sub(sent) + m.period_ns / 2) / m.period_ns;
                for _ in 1..periods.min(255) {
                    counters.next_value(m.index);
                }
            }
        }
        let alive = counters.next_value(m.index);
        codec
            .encode_into(m.index, &values, alive, &mut m.last)
            .ok()?;
        m.last_alive = alive;
        m.last_sent_ns = Some(now_ns);
        m.schedule_after_send(now_ns);
        CanDataFrame::new(m.id, m.last.get(..m.dlc)?)
    }
}

/// The controller heartbeat: mode, law and faults of the latest outputs (those signals the
/// configuration names), and an alive counter as wide as its DBC signal (+1 per frame,
/// wrapping at 2^width − 1 → 0).
#[derive(Debug, Clone)]
pub struct HeartbeatTx {
    codec: HeartbeatCodec,
    id: Id,
    /// Next counter value.
    alive: u32,
    /// 2^width − 1 of the counter signal.
    alive_max: u32,
    last_cycle: Option<u64>,
}

impl HeartbeatTx {
    /// A heartbeat sender for `codec`'s message.
    pub fn new(codec: &HeartbeatCodec) -> Result<HeartbeatTx, CanBusError> {
        let id = codec.frame_id().to_socketcan().ok_or(CanBusError::BadId {
            message: "heartbeat".into(),
            id: codec.frame_id(),
        })?;
        Ok(HeartbeatTx {
            codec: *codec,
            id,
            alive: 0,
            alive_max: match codec.alive_bits().unwrap_or(8) {
                b if b >= 32 => u32::MAX,
                b => (1u32 << b) - 1,
            },
            last_cycle: None,
        })
    }

    /// The next heartbeat frame, or `None` (withheld) when there are no outputs yet or the
    /// control thread published nothing since the previous heartbeat: a heartbeat vouches for a
    /// running control loop, so a hung control thread must stop it. A mode code the DBC cannot
    /// carry is sent as `fail_safe`.
    pub fn next_frame(&mut self, latest: Option<&Outputs>) -> Option<CanDataFrame> {
        let o = latest?;
        if self.last_cycle == Some(o.cycle) {
            return None;
        }
        self.last_cycle = Some(o.cycle);
        let hb = Heartbeat {
            mode: o.mode,
            active_law: o.law,
            // input faults of the control thread and the field faults of the I/O tasks (the
            // control thread ORs those in, crate::io::link::FieldFaults)
            faults: o.faults,
        };
        let alive = self.alive;
        self.alive = if alive >= self.alive_max {
            0
        } else {
            alive + 1
        };
        let data = self.codec.encode(&hb, alive);
        CanDataFrame::new(self.id, data.get(..usize::from(self.codec.dlc()))?)
    }
}
