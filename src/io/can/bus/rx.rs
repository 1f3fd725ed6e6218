//! Receive side: one frame in, board updates and counter increments out. No socket, no
//! allocation, no panic: every malformed frame is counted and dropped.

use std::sync::Arc;

use socketcan::errors::{ControllerProblems, CAN_ERR_BUSOFF, CAN_ERR_CRTL, CAN_ERR_RESTARTED};
use socketcan::{CanAnyFrame, CanErrorFrame, EmbeddedFrame};

use super::{BusCodec, CanCounters};
use crate::io::can::codec::{AliveCheckers, SignalTarget};
use crate::io::can::dbc::FrameId;
use crate::io::can::e2e::{AliveChecker, AliveStatus, FrameError};
use crate::runtime::handoff::{
    CommandBoard, HeartbeatBoard, HeartbeatSeen, SensorBoard, NO_SAMPLE_CLOCK,
};
use crate::runtime::trigger::CycleTrigger;

/// What an error frame says about the CAN controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BusCondition {
    /// Bus-off: the controller stopped taking part in bus traffic.
    BusOff,
    /// Error-passive (an error counter ≥ 128).
    Passive,
    /// Error warning (an error counter ≥ 96).
    Warning,
    /// Back to error-active, or restarted after bus-off.
    Active,
    /// Anything else (protocol violation, lost arbitration, no ACK, …): counted only.
    Other,
}

/// Classify an error frame (`CAN_ERR_*` class bits in the id, controller state in data
/// byte 1). Bus-off wins over everything else in the same frame.
pub fn classify_error_frame(frame: &CanErrorFrame) -> BusCondition {
    let bits = frame.error_bits();
    if bits & CAN_ERR_BUSOFF != 0 {
        return BusCondition::BusOff;
    }
    if bits & CAN_ERR_CRTL != 0 {
        let byte = frame.data().get(1).copied().unwrap_or(0);
        let p = ControllerProblems::from_bits_truncate(byte);
        if p.intersects(ControllerProblems::RX_PASSIVE | ControllerProblems::TX_PASSIVE) {
            return BusCondition::Passive;
        }
        if p.intersects(ControllerProblems::RX_WARNING | ControllerProblems::TX_WARNING) {
            return BusCondition::Warning;
        }
        if p.contains(ControllerProblems::ACTIVE) {
            return BusCondition::Active;
        }
    }
    if bits & CAN_ERR_RESTARTED != 0 {
        return BusCondition::Active;
    }
    BusCondition::Other
}

/// Why a received frame was not published.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RxReject {
    /// Identifier not in the DBC.
    UnknownId,
    /// Known message, wrong length.
    WrongDlc,
    /// Known message, bad CRC.
    BadCrc,
    /// A value not finite or outside its value table.
    InvalidValue,
    /// A valid frame of a message this node does not consume.
    Foreign,
    /// Alive counter equal to the previous one: the sender is stuck, its values must go stale.
    AliveRepeated,
    /// Remote (RTR) frame.
    Remote,
    /// CAN FD frame.
    Fd,
}

/// Result of handling one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RxOutcome {
    /// Values published to the board(s).
    Published,
    /// Counted and dropped.
    Rejected(RxReject),
    /// An error frame, classified (the caller acts on bus-off and state changes).
    Bus(BusCondition),
}

/// Where received values go.
#[derive(Debug)]
enum Sink {
    /// Controller: sensor values.
    Sensors(Arc<SensorBoard>),
    /// Plant: actuator setpoints and the heartbeat.
    Commands {
        commands: Arc<CommandBoard>,
        heartbeat: Arc<HeartbeatBoard>,
        heartbeat_alive: Option<AliveChecker>,
    },
}

/// Frame handler of one node: decodes, checks, publishes, counts.
#[derive(Debug)]
pub struct RxHandler {
    codec: Arc<BusCodec>,
    /// Per message index: whether this node consumes it.
    consumes: Vec<bool>,
    checkers: AliveCheckers,
    /// Controller: per message index, the sender's clock rebuilt from the alive counter
    /// ([`super::SenderClock`]); empty on the plant side.
    clocks: Vec<Option<super::SenderClock>>,
    sink: Sink,
    counters: Arc<CanCounters>,
    /// Controller: the cycle trigger.
    trigger: Option<TriggerGate>,
}

/// How long the cycle trigger waits for the first frame of every sensor message after the
/// link came up before it fires anyway, ns.
pub const TRIGGER_WARMUP_NS: u64 = 1_000_000_000;

/// The controller's cycle trigger as the receive side drives it.
///
/// It notes the trigger messages only once every sensor message of the signal map arrived
/// once since the link came up (or [`TRIGGER_WARMUP_NS`] after the first trigger message):
/// the first healthy cycle takes over bumplessly from the *measured* valve position, which
/// travels in a message of its own (`config/skid.dbc`: `PLANT_Positions`, every 2 ms, sent
/// after the pressures). A first cycle fired by the pressures alone would start the law
/// from an unknown position. Until then the control thread runs on its deadline.
#[derive(Debug)]
struct TriggerGate {
    trigger: Arc<CycleTrigger>,
    /// Per message index: its trigger bit (0: not a trigger message).
    bits: Vec<u32>,
    /// Per message index: seen since the link came up (messages not consumed count as seen).
    seen: Vec<bool>,
    /// Consumed messages not seen yet.
    missing: usize,
    /// Arrival of the first trigger message since the link came up.
    first_ns: Option<u64>,
}

impl TriggerGate {
    fn reset(&mut self, consumes: &[bool]) {
        self.seen = consumes.iter().map(|c| !c).collect();
        self.missing = consumes.iter().filter(|c| **c).count();
        self.first_ns = None;
    }

    /// Message `index` was published at `t_ns`.
    #[inline]
    fn published(&mut self, index: usize, t_ns: u64) {
        if self.missing > 0 {
            if let Some(s) = self.seen.get_mut(index) {
                if !*s {
                    *s = true;
                    self.missing -= 1;
                }
            }
        }
        let bit = self.bits.get(index).copied().unwrap_or(0);
        if bit == 0 {
            return;
        }
        let first = *self.first_ns.get_or_insert(t_ns);
        if self.missing == 0 || t_ns.saturating_sub(first) >= TRIGGER_WARMUP_NS {
            self.trigger.note(bit, t_ns);
        }
    }
}

impl RxHandler {
    /// Controller side: sensor frames go to `sensors`; everything else known is foreign.
    pub fn controller(
        codec: Arc<BusCodec>,
        sensors: Arc<SensorBoard>,
        counters: Arc<CanCounters>,
    ) -> RxHandler {
        let mut consumes = vec![false; codec.frames.len()];
        for m in codec.frames.sensor_messages() {
            if let Some(c) = consumes.get_mut(m.get()) {
                *c = true;
            }
        }
        RxHandler {
            checkers: codec.frames.alive_checkers(),
            clocks: codec.frames.sender_clocks(),
            consumes,
            sink: Sink::Sensors(sensors),
            codec,
            counters,
            trigger: None,
        }
    }

    /// Controller: arm `trigger` with `plan` and note each of its messages once its values
    /// are published (so the control thread woken by the last one reads them all), from the
    /// moment every sensor message arrived once ([`TriggerGate`]).
    pub fn with_trigger(mut self, trigger: Arc<CycleTrigger>, plan: &super::TriggerPlan) -> Self {
        trigger.arm(plan.required);
        let mut gate = TriggerGate {
            trigger,
            bits: plan.bits.clone(),
            seen: Vec::new(),
            missing: 0,
            first_ns: None,
        };
        gate.reset(&self.consumes);
        self.trigger = Some(gate);
        self
    }

    /// Plant side: actuator frames go to `commands`, the heartbeat to `heartbeat`.
    pub fn plant(
        codec: Arc<BusCodec>,
        commands: Arc<CommandBoard>,
        heartbeat: Arc<HeartbeatBoard>,
        counters: Arc<CanCounters>,
    ) -> RxHandler {
        let mut consumes = vec![false; codec.frames.len()];
        for m in codec.frames.actuator_messages() {
            if let Some(c) = consumes.get_mut(m.get()) {
                *c = true;
            }
        }
        RxHandler {
            checkers: codec.frames.alive_checkers(),
            clocks: Vec::new(),
            consumes,
            sink: Sink::Commands {
                commands,
                heartbeat,
                heartbeat_alive: codec.heartbeat.alive_bits().map(AliveChecker::new),
            },
            codec,
            counters,
            trigger: None,
        }
    }

    /// Forget the previous alive counters (after a reconnect the next frame is a "first") and,
    /// with a cycle trigger, wait again for every sensor message before it fires.
    pub fn reset_alive(&mut self) {
        self.checkers = self.codec.frames.alive_checkers();
        for c in self.clocks.iter_mut().flatten() {
            c.reset();
        }
        if let Some(gate) = &mut self.trigger {
            gate.reset(&self.consumes);
        }
        if let Sink::Commands {
            heartbeat_alive: Some(c),
            ..
        } = &mut self.sink
        {
            c.reset();
        }
    }

    /// Handle any frame read from the socket, received at `t_ns` (monotonic).
    pub fn handle_frame(&mut self, frame: &CanAnyFrame, t_ns: u64) -> RxOutcome {
        CanCounters::inc(&self.counters.rx_frames);
        match frame {
            CanAnyFrame::Normal(f) => self.handle_data(FrameId::from(f.id()), f.data(), t_ns),
            CanAnyFrame::Remote(_) => {
                CanCounters::inc(&self.counters.remote_frames);
                RxOutcome::Rejected(RxReject::Remote)
            }
            CanAnyFrame::Fd(_) => {
                CanCounters::inc(&self.counters.fd_frames);
                RxOutcome::Rejected(RxReject::Fd)
            }
            CanAnyFrame::Error(f) => {
                CanCounters::inc(&self.counters.error_frames);
                let condition = classify_error_frame(f);
                tracing::debug!(
                    target: "can",
                    error = %f.into_error(),
                    ?condition,
                    "error frame"
                );
                RxOutcome::Bus(condition)
            }
        }
    }

    /// Handle a classic data frame `id` / `data` received at `t_ns` (monotonic). Does not count
    /// it in `rx_frames` ([`RxHandler::handle_frame`] does).
    pub fn handle_data(&mut self, id: FrameId, data: &[u8], t_ns: u64) -> RxOutcome {
        if let Sink::Commands {
            heartbeat,
            heartbeat_alive,
            ..
        } = &mut self.sink
        {
            if id == self.codec.heartbeat.frame_id() {
                return match self.codec.heartbeat.decode(data) {
                    Err(e) => self.reject_error(e),
                    Ok((hb, alive)) => {
                        let status = match (heartbeat_alive.as_mut(), alive) {
                            (Some(c), Some(a)) => Some(c.check(a)),
                            _ => None,
                        };
                        if let Some(r) = alive_gate(&self.counters, status) {
                            return r;
                        }
                        heartbeat.publish(&HeartbeatSeen {
                            mode: hb.mode,
                            law: hb.active_law,
                            alive: alive.unwrap_or(0),
                            faults: hb.faults,
                            t_ns,
                        });
                        CanCounters::inc(&self.counters.rx_published);
                        RxOutcome::Published
                    }
                };
            }
        }
        let frame = match self.codec.frames.decode(id, data) {
            Ok(f) => f,
            Err(e) => return self.reject_error(e),
        };
        if !self
            .consumes
            .get(frame.message().get())
            .copied()
            .unwrap_or(false)
        {
            CanCounters::inc(&self.counters.foreign);
            return RxOutcome::Rejected(RxReject::Foreign);
        }
        // a NaN value is the sender's "not available" (a failed transmitter, an actuator not
        // driven): published as NaN, so the controller's supervisor rejects that input at
        // once while the frame's other signals stay fresh, and the plant's field device falls
        // back to its own setpoint
        let status = self.checkers.check(&frame);
        if let Some(r) = alive_gate(&self.counters, status) {
            return r;
        }
        match &self.sink {
            Sink::Sensors(board) => {
                let index = frame.message().get();
                let sampled = match (self.clocks.get_mut(index), status) {
                    (Some(Some(clock)), Some(status)) => {
                        let (at, mismatch) = clock.on_frame(status, t_ns);
                        if let Some(m) = mismatch {
                            CanCounters::inc(&self.counters.sender_clock_distrusted);
                            tracing::warn!(
                                target: "can",
                                message = self.codec.frames.message_name(frame.message()).unwrap_or("?"),
                                "the alive counter of this message advanced {:.3} s of its DBC \
                                 cycle time over {:.3} s of arrivals: the DBC's GenMsgCycleTime \
                                 does not match the sender; its samples are timed by their \
                                 arrival until the link is reset",
                                m.clock_s,
                                m.arrivals_s
                            );
                        }
                        at.unwrap_or(NO_SAMPLE_CLOCK)
                    }
                    _ => NO_SAMPLE_CLOCK,
                };
                for (target, v) in frame.values() {
                    if let SignalTarget::Sensor(s) = target {
                        board.publish_sampled(*s, *v, t_ns, sampled);
                    }
                }
            }
            Sink::Commands { commands, .. } => {
                for (target, v) in frame.values() {
                    if let SignalTarget::Actuator(a) = target {
                        commands.publish(*a, *v, t_ns);
                    }
                }
            }
        }
        if let Some(gate) = &mut self.trigger {
            gate.published(frame.message().get(), t_ns);
        }
        CanCounters::inc(&self.counters.rx_published);
        RxOutcome::Published
    }

    fn reject_error(&self, e: FrameError) -> RxOutcome {
        let (counter, reason) = match e {
            FrameError::UnknownId { .. } => (&self.counters.unknown_id, RxReject::UnknownId),
            FrameError::WrongDlc { .. } => (&self.counters.wrong_dlc, RxReject::WrongDlc),
            FrameError::BadCrc { .. } => (&self.counters.bad_crc, RxReject::BadCrc),
            FrameError::InvalidValue { .. } => {
                (&self.counters.invalid_value, RxReject::InvalidValue)
            }
        };
        CanCounters::inc(counter);
        tracing::trace!(target: "can", error = %e, "frame dropped");
        RxOutcome::Rejected(reason)
    }
}

/// Count the alive status; `Some(outcome)` if the frame must not be published.
fn alive_gate(counters: &CanCounters, status: Option<AliveStatus>) -> Option<RxOutcome> {
    match status {
        Some(AliveStatus::Repeated) => {
            CanCounters::inc(&counters.alive_repeated);
            Some(RxOutcome::Rejected(RxReject::AliveRepeated))
        }
        Some(AliveStatus::Skipped { missed }) => {
            CanCounters::inc(&counters.alive_skipped);
            CanCounters::add(&counters.frames_lost, u64::from(missed));
            None
        }
        Some(AliveStatus::First | AliveStatus::InSequence) | None => None,
    }
}
