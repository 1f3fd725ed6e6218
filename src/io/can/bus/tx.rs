//! Send side: board contents in, ready-to-write frames out. No socket, no allocation.

use std::time::Duration;

use socketcan::{CanDataFrame, EmbeddedFrame, Id};

use super::CanBusError;
use crate::io::can::bits::MAX_PAYLOAD;
use crate::io::can::codec::{AliveCounters, CanCodec, MessageIndex, SignalValues};
use crate::io::can::e2e::AliveCounter;
use crate::io::can::heartbeat::{ControllerMode, Heartbeat, HeartbeatCodec};
use crate::runtime::handoff::Outputs;

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
}

/// Encodes a fixed list of messages from signal values. A NaN value ("not driven", "no
/// reading") goes out as the signal's "not available" pattern, never as a stale number.
#[derive(Debug, Clone)]
pub struct FrameEncoder {
    codec: CanCodec,
    messages: Vec<TxMessage>,
    alive: AliveCounters,
    on_change_only: bool,
    refresh_ns: u64,
}

impl FrameEncoder {
    /// An encoder for `messages` of `codec`. With `on_change_only`, a message whose data bits
    /// did not change is skipped unless `refresh` passed since it was last sent.
    pub fn new(
        codec: &CanCodec,
        messages: &[MessageIndex],
        on_change_only: bool,
        refresh: Duration,
    ) -> Result<FrameEncoder, CanBusError> {
        let mut out = Vec::with_capacity(messages.len());
        for &index in messages {
            let name = codec.message_name(index).unwrap_or("?").to_string();
            let guard = codec.guard(index).ok_or_else(|| CanBusError::Config {
                key: "dbc",
                message: format!("message #{} missing from the codec", index.get()),
            })?;
            let id = guard.id().to_socketcan().ok_or(CanBusError::BadId {
                message: name,
                id: guard.id(),
            })?;
            out.push(TxMessage {
                index,
                id,
                dlc: usize::from(guard.dlc()),
                last: [0; MAX_PAYLOAD],
                last_alive: 0,
                last_sent_ns: None,
            });
        }
        Ok(FrameEncoder {
            codec: codec.clone(),
            messages: out,
            alive: codec.alive_counters(),
            on_change_only,
            refresh_ns: u64::try_from(refresh.as_nanos()).unwrap_or(u64::MAX),
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

    /// Encode message `i` (0..len) from `values` at time `now_ns` (monotonic): the next alive
    /// counter value, the CRC, NaN values holding their last bits. `None` if the message is
    /// skipped (unchanged under `on_change_only`) or `i` is out of range. The frame counts as
    /// sent: the caller must write it (a failed write shows up as a skipped counter value at
    /// the receiver, which is what it is).
    pub fn encode<V: SignalValues + ?Sized>(
        &mut self,
        i: usize,
        values: &V,
        now_ns: u64,
    ) -> Option<CanDataFrame> {
        let m = self.messages.get_mut(i)?;
        if self.on_change_only {
            if let Some(sent) = m.last_sent_ns {
                if now_ns.saturating_sub(sent) < self.refresh_ns {
                    // Same counter value → same bytes iff the data bits are unchanged.
                    let mut candidate = m.last;
                    self.codec
                        .encode_into(m.index, values, m.last_alive, &mut candidate)
                        .ok()?;
                    if candidate == m.last {
                        return None;
                    }
                }
            }
        }
        let alive = self.alive.next_value(m.index);
        self.codec
            .encode_into(m.index, values, alive, &mut m.last)
            .ok()?;
        m.last_alive = alive;
        m.last_sent_ns = Some(now_ns);
        CanDataFrame::new(m.id, m.last.get(..m.dlc)?)
    }
}

/// The controller heartbeat: mode, law and faults of the latest outputs, 8-bit alive counter.
#[derive(Debug, Clone)]
pub struct HeartbeatTx {
    codec: HeartbeatCodec,
    id: Id,
    alive: AliveCounter,
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
            alive: AliveCounter::new(codec.alive_bits().unwrap_or(8)),
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
            mode: ControllerMode::from_raw(o.mode).unwrap_or(ControllerMode::FailSafe),
            active_law: o.law,
            // input faults of the control thread and the field faults of the I/O tasks
            faults: o.faults | crate::faults::field::word(),
        };
        let data = self.codec.encode(&hb, self.alive.next_value());
        CanDataFrame::new(self.id, data.get(..usize::from(self.codec.dlc()))?)
    }
}
