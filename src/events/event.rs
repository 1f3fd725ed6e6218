//! What the event log records: the [`Event`] enum, its payloads and the small vocabularies
//! (modes, laws, fallback reasons …) they use.
//!
//! Every event is one JSON object on one line, tagged by `"event"` with a snake_case kind.
//! Field names carry their unit (`_hz`, `_kg_s`, `_pct`, `_us`, `_ms`, `_s`) so a line reads
//! on its own during an incident review. Payloads without heap data are `Copy` structs
//! shared with the real-time [`RtEvent`](super::RtEvent).

use std::path::Path;

use serde::{Deserialize, Deserializer, Serialize};

pub use super::cause::{Cause, CauseKind};
use super::timestamp::Timestamp;
use crate::vocab::signals::SensorId;
use crate::vocab::Mode;

/// The control law: the controller's own identifier (one list of law names).
pub use crate::control::LawId as Law;

/// Why an input was declared bad.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FallbackReason {
    /// No fresh value within its timeout.
    Stale,
    /// Value outside its configured plausible range.
    OutOfRange,
    /// Value was NaN / missing.
    Nan,
    /// The sender's alive (rolling) counter stopped or jumped.
    AliveCounter,
    /// The CAN controller carrying the input went bus-off.
    BusOff,
    /// Fresh and in range, but frozen: no change beyond its noise floor while the related
    /// signals moved (cross-check).
    Frozen,
    /// Fresh, in range and moving, but drifting or biased: it disagreed persistently with the
    /// observer's flow and the speed-line flow (cross-check).
    Drift,
}

/// What stands in for a bad input while the fallback lasts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Replacement {
    /// A model-based estimate (state observer).
    Observer,
    /// The speed line's flow at the measured pressure ratio and speed, less the map's
    /// uncertainty (a machine with a speed-line map and no observer).
    SpeedLine,
    /// The last good value, held.
    LastGood,
    /// A redundant sensor measuring the same quantity.
    Redundant,
    /// The configured default value.
    ConfigDefault,
    /// Nothing: the controller went to fail-safe instead.
    None,
}

/// State of a field-bus interface.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BusState {
    /// Up and passing traffic.
    Up,
    /// Down (link lost, interface down).
    Down,
    /// CAN controller in bus-off after too many errors.
    BusOff,
    /// Trying to re-establish the link.
    Reconnecting,
}

/// Why the recycle valve was tripped fully open.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TripReason {
    /// A surge cycle was detected.
    SurgeDetected,
    /// The operating point approached the surge line faster than the trip rate.
    FastApproach,
    /// A required input failed with no usable replacement.
    InputFailure,
    /// The operator commanded the trip.
    Operator,
    /// Entering fail-safe mode.
    FailSafe,
    /// An external (hard-wired or DCS) trip request.
    External,
}

/// Why events were lost before they reached the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DropCause {
    /// The real-time ring buffer was full when the control thread pushed.
    QueueFull,
    /// Writing the line to the file failed (disk full, I/O error).
    WriteError,
}

/// Reads a float written as `null` (serde_json writes NaN and infinities that way) back as NaN.
fn f64_or_nan<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// A surge cycle was detected.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SurgeDetected {
    /// Surge counter after this detection (total since the counter was last reset).
    pub surge_count_total: u64,
    /// Dominant frequency of the flow/pressure oscillation, Hz (NaN if not estimated).
    #[serde(deserialize_with = "f64_or_nan")]
    pub frequency_hz: f64,
    /// Lowest mass flow seen during the cycle, kg/s (negative means reversed flow).
    #[serde(deserialize_with = "f64_or_nan")]
    pub min_flow_kg_s: f64,
    /// Whether flow reversed (deep surge) rather than only oscillated (mild surge).
    pub flow_reversal: bool,
}

/// The surge counter changed other than by a detection (e.g. reset by the operator).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SurgeCounter {
    /// Value before the change.
    pub previous_count: u64,
    /// Value after the change.
    pub count: u64,
}

/// The surge control line was moved right by a safety-on step after repeated surges.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SafetyOnShift {
    /// This step's added margin, % of the surge-line flow.
    #[serde(deserialize_with = "f64_or_nan")]
    pub margin_pct: f64,
    /// Total safety-on margin now in force, %.
    #[serde(deserialize_with = "f64_or_nan")]
    pub total_margin_pct: f64,
    /// How many safety-on steps are in force.
    pub count: u32,
}

/// Operating mode changed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ModeChanged {
    /// Mode before.
    pub from: Mode,
    /// Mode after.
    pub to: Mode,
    /// Why (which input, which fault, the value; or the operator).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cause: Option<Cause>,
}

/// Control law changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct LawChanged {
    /// Law before.
    pub from: Law,
    /// Law after.
    pub to: Law,
}

/// An input went bad and something stands in for it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FallbackEntered {
    /// The input that went bad.
    pub input: SensorId,
    /// Why it was declared bad.
    pub reason: FallbackReason,
    /// What replaces it.
    pub replaced_by: Replacement,
    /// For a drifting flow transmitter: its flow minus the observer's, filtered, % of the
    /// surge-line flow (the unit of the control margin; + reads more flow than the observer).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vs_observer_pct: Option<f64>,
    /// For a drifting flow transmitter: its flow minus the speed-line flow, filtered, % of
    /// the surge-line flow.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vs_speed_line_pct: Option<f64>,
}

/// A previously bad input is trusted again.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct FallbackLeft {
    /// The input that recovered.
    pub input: SensorId,
    /// What had replaced it.
    pub replaced_by: Replacement,
    /// How long the fallback lasted, ms.
    pub duration_ms: u64,
}

/// Control cycles finished late; reported at most once per rate-limit window.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DeadlineOverrun {
    /// Overruns since the previous report.
    pub count: u64,
    /// Worst lateness among them, µs.
    pub worst_lateness_us: u64,
    /// Time since the previous report (or since counting began), s.
    #[serde(deserialize_with = "f64_or_nan")]
    pub window_s: f64,
}

/// The recycle valve was tripped fully open.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RecycleTrip {
    /// Why.
    pub reason: TripReason,
    /// Detail: the surge margin and trip line, %.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cause: Option<Cause>,
    /// Which of the law's criteria fired (`trip_line`, `predicted_crossing`,
    /// `throttle_closure`, `speed_decay`); absent for trips from outside the law.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub criterion: Option<crate::control::law::api::TripCause>,
}

/// A redundant transmitter changed state (voted out and by which check, deviating, healthy
/// again), with the vote it belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Transmitter {
    /// The measurement.
    pub input: SensorId,
    /// The transmitter: `a` (the `[sensors]` binding), `b` or `c` (the `[vote]` bindings).
    pub transmitter: TransmitterName,
    /// `healthy`, `deviating` or `voted_out`.
    pub state: TransmitterStateName,
    /// The check that found it (`stale`, `nan`, `out_of_range`, `frozen`, `deviation`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub check: Option<TransmitterCheckName>,
    /// Its reading, SI unit of the input (NaN: none).
    #[serde(deserialize_with = "f64_or_nan")]
    pub value: f64,
    /// The vote, same unit (NaN: none).
    #[serde(deserialize_with = "f64_or_nan")]
    pub vote: f64,
    /// Its reading against the vote, % of the vote (NaN: either missing).
    #[serde(deserialize_with = "f64_or_nan")]
    pub deviation_pct: f64,
    /// Valid transmitters and transmitters bound, after the change.
    pub valid: u8,
    /// Transmitters bound.
    pub bound: u8,
    /// The vote's rule now: `median`, `conservative`, `hold_last` or `none`.
    pub rule: VoteRuleName,
}

/// A transmitter's name in its vote.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TransmitterName {
    /// The `[sensors]` binding.
    A,
    /// The `[vote]` table's `b`.
    B,
    /// The `[vote]` table's `c`.
    C,
}

impl TransmitterName {
    /// By slot (0 = a).
    pub fn of_slot(slot: usize) -> TransmitterName {
        match slot {
            0 => TransmitterName::A,
            1 => TransmitterName::B,
            _ => TransmitterName::C,
        }
    }
}

/// [`crate::control::vote::TransmitterState`] in the log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TransmitterStateName {
    /// Counted and agreeing.
    Healthy,
    /// Counted, but further from the vote than its threshold.
    Deviating,
    /// Not counted.
    VotedOut,
}

/// [`crate::control::vote::TransmitterCheck`] in the log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TransmitterCheckName {
    /// No fresh value.
    Stale,
    /// No value.
    Nan,
    /// Outside the plausible range.
    OutOfRange,
    /// Repeating itself (frozen-Δp check).
    Frozen,
    /// Away from the vote beyond the threshold.
    Deviation,
}

/// [`crate::control::vote::VoteRule`] in the log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VoteRuleName {
    /// No valid transmitter.
    None,
    /// Median of three.
    Median,
    /// The conservative one of two.
    Conservative,
    /// One left: hold the last agreed value.
    HoldLast,
}

impl Transmitter {
    /// The event for transmitter `slot` of a vote.
    pub fn of(v: &crate::control::vote::VoteStatus, slot: usize) -> Option<Transmitter> {
        use crate::control::vote::{TransmitterCheck as C, TransmitterState as S, VoteRule as R};
        let st = *v.states.get(slot)?;
        let state = match st {
            S::Unbound => return None,
            S::Healthy => TransmitterStateName::Healthy,
            S::Deviating => TransmitterStateName::Deviating,
            S::VotedOut(_) => TransmitterStateName::VotedOut,
        };
        let check = st.reason().map(|c| match c {
            C::Stale => TransmitterCheckName::Stale,
            C::Nan => TransmitterCheckName::Nan,
            C::OutOfRange => TransmitterCheckName::OutOfRange,
            C::Frozen => TransmitterCheckName::Frozen,
            C::Deviation => TransmitterCheckName::Deviation,
        });
        let value = v.values[slot];
        Some(Transmitter {
            input: v.input,
            transmitter: TransmitterName::of_slot(slot),
            state,
            check,
            value,
            vote: v.value,
            deviation_pct: 100.0 * (value - v.value) / v.value.abs(),
            valid: v.valid,
            bound: v.bound,
            rule: match v.rule {
                R::None => VoteRuleName::None,
                R::Median => VoteRuleName::Median,
                R::Conservative => VoteRuleName::Conservative,
                R::HoldLast => VoteRuleName::HoldLast,
            },
        })
    }

    /// The transmitter's name as operators see it: `orifice_dp.b`.
    pub fn name(&self) -> String {
        let t = match self.transmitter {
            TransmitterName::A => "a",
            TransmitterName::B => "b",
            TransmitterName::C => "c",
        };
        format!("{}.{t}", self.input.name())
    }
}

/// One changed configuration key. Values are rendered as TOML/text; `None` means absent.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ConfigChange {
    /// Dotted key, e.g. `control.recycle.kp`.
    pub key: String,
    /// Value before (`null` when the key was added).
    pub old: Option<String>,
    /// Value after (`null` when the key was removed).
    pub new: Option<String>,
}

/// One entry of the event log. Serialized internally tagged: `"event":"<kind>"` followed by
/// the variant's fields.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    /// The daemon started.
    Started {
        /// `antisurge` version.
        version: String,
        /// Configuration file in use.
        config_path: String,
        /// Control law selected at start.
        law: Law,
        /// What starts a control cycle: `deadline` (the fixed period) or `inputs: <messages>`
        /// (the arrival of these CAN messages, deadline as fallback). Absent in logs written
        /// before issue 9.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        cycle_trigger: Option<String>,
    },
    /// The daemon stopped (written on a clean stop only; a crash leaves no `stopped`).
    Stopped {
        /// Why, e.g. `SIGTERM`, `operator`, or an error message.
        reason: String,
    },
    /// A surge cycle was detected.
    SurgeDetected(SurgeDetected),
    /// The surge counter changed (reset or set) other than by a detection.
    SurgeCounter(SurgeCounter),
    /// The control line moved by a safety-on step.
    SafetyOnShift(SafetyOnShift),
    /// Operating mode changed.
    ModeChanged(ModeChanged),
    /// Control law changed.
    LawChanged(LawChanged),
    /// An input went bad; a replacement stands in.
    FallbackEntered(FallbackEntered),
    /// An input recovered.
    FallbackLeft(FallbackLeft),
    /// A configuration reload took effect.
    ConfigApplied {
        /// File that was reloaded.
        file: String,
        /// Keys that changed.
        diff: Vec<ConfigChange>,
    },
    /// A configuration reload was refused; the previous configuration stays in force.
    ConfigRejected {
        /// File that was reloaded.
        file: String,
        /// Offending key, when known.
        key: Option<String>,
        /// 1-based line in the file, when known.
        line: Option<u32>,
        /// What is wrong.
        message: String,
    },
    /// Changed keys that only take effect after a restart.
    RestartRequired {
        /// Dotted keys.
        keys: Vec<String>,
    },
    /// Control cycles finished late (rate-limited summary).
    DeadlineOverrun(DeadlineOverrun),
    /// A bus interface changed state.
    BusState {
        /// Interface name, e.g. `can0` or `modbus:10.0.0.5:502`.
        interface: String,
        /// New state.
        state: BusState,
    },
    /// A field fault (link, write, actuator feedback) was raised or cleared.
    FieldFault {
        /// Link or device, e.g. `modbus:127.0.0.1:5020` or `can0`.
        link: String,
        /// Category, as on the wire (the DBC's Faults bits).
        fault: crate::vocab::faults::FaultCategory,
        /// Raised (true) or cleared (false).
        active: bool,
        /// The cause in words, e.g. the Modbus exception code or the actuator and the
        /// difference between command and feedback.
        cause: String,
    },
    /// The recycle valve was tripped open.
    RecycleTrip(RecycleTrip),
    /// A redundant transmitter was voted out, found deviating, or is healthy again.
    Transmitter(Transmitter),
    /// Free text (operator notes, writer diagnostics).
    Note {
        /// The text.
        text: String,
    },
    /// A network server shed connections (the connection cap was reached, or `accept` ran
    /// out of descriptors); written at most every 10 s while it lasts.
    ConnectionsShed {
        /// The server, e.g. `dcs-modbus 0.0.0.0:502`.
        server: String,
        /// `connection_cap` or `descriptors_exhausted`.
        cause: String,
        /// Detail (the operating-system error), when there is one.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        detail: Option<String>,
        /// Connections open when reported.
        open: u64,
        /// Connections shed since the server started.
        shed_total: u64,
        /// `accept` failures for want of descriptors since the server started.
        accept_exhausted_total: u64,
    },
    /// Events were lost before reaching the file; written as soon as the loss is noticed.
    EventsDropped {
        /// How many were lost since the previous `events_dropped`.
        count: u64,
        /// Why.
        cause: DropCause,
    },
}

impl Event {
    /// `started` with this build's version.
    pub fn started(config_path: &Path, law: Law) -> Event {
        Event::Started {
            version: env!("CARGO_PKG_VERSION").to_string(),
            config_path: config_path.to_string_lossy().into_owned(),
            law,
            cycle_trigger: None,
        }
    }

    /// [`Event::started`] that also says what starts a control cycle.
    pub fn started_with_trigger(config_path: &Path, law: Law, cycle_trigger: String) -> Event {
        match Event::started(config_path, law) {
            Event::Started {
                version,
                config_path,
                law,
                ..
            } => Event::Started {
                version,
                config_path,
                law,
                cycle_trigger: Some(cycle_trigger),
            },
            other => other,
        }
    }

    /// The snake_case kind written in the `"event"` field.
    pub fn kind(&self) -> &'static str {
        match self {
            Event::Started { .. } => "started",
            Event::Stopped { .. } => "stopped",
            Event::SurgeDetected(_) => "surge_detected",
            Event::SurgeCounter(_) => "surge_counter",
            Event::SafetyOnShift(_) => "safety_on_shift",
            Event::ModeChanged(_) => "mode_changed",
            Event::LawChanged(_) => "law_changed",
            Event::FallbackEntered(_) => "fallback_entered",
            Event::FallbackLeft(_) => "fallback_left",
            Event::ConfigApplied { .. } => "config_applied",
            Event::ConfigRejected { .. } => "config_rejected",
            Event::RestartRequired { .. } => "restart_required",
            Event::DeadlineOverrun(_) => "deadline_overrun",
            Event::BusState { .. } => "bus_state",
            Event::FieldFault { .. } => "field_fault",
            Event::RecycleTrip(_) => "recycle_trip",
            Event::Transmitter(_) => "transmitter",
            Event::Note { .. } => "note",
            Event::EventsDropped { .. } => "events_dropped",
            Event::ConnectionsShed { .. } => "connections_shed",
        }
    }

    /// Split an event whose line would be too long into two smaller events of the same kind
    /// (only list-carrying kinds can be split). `None` if it cannot be split.
    pub(crate) fn split_in_two(&self) -> Option<(Event, Event)> {
        match self {
            Event::ConfigApplied { file, diff } if diff.len() > 1 => {
                let (a, b) = diff.split_at(diff.len() / 2);
                Some((
                    Event::ConfigApplied {
                        file: file.clone(),
                        diff: a.to_vec(),
                    },
                    Event::ConfigApplied {
                        file: file.clone(),
                        diff: b.to_vec(),
                    },
                ))
            }
            Event::RestartRequired { keys } if keys.len() > 1 => {
                let (a, b) = keys.split_at(keys.len() / 2);
                Some((
                    Event::RestartRequired { keys: a.to_vec() },
                    Event::RestartRequired { keys: b.to_vec() },
                ))
            }
            _ => None,
        }
    }

    /// Shorten every free-text field to at most `max_bytes` (on a char boundary, marked
    /// with `…`). Returns whether anything was shortened.
    pub(crate) fn clip_text(&mut self, max_bytes: usize) -> bool {
        let mut clipped = false;
        let mut clip = |s: &mut String| clipped |= clip_string(s, max_bytes);
        match self {
            Event::Started {
                version,
                config_path,
                cycle_trigger,
                ..
            } => {
                clip(version);
                clip(config_path);
                if let Some(t) = cycle_trigger {
                    clip(t);
                }
            }
            Event::Stopped { reason } => clip(reason),
            Event::ConfigApplied { file, diff } => {
                clip(file);
                for c in diff {
                    clip(&mut c.key);
                    for s in [&mut c.old, &mut c.new].into_iter().flatten() {
                        clip(s);
                    }
                }
            }
            Event::ConfigRejected {
                file, key, message, ..
            } => {
                clip(file);
                if let Some(k) = key {
                    clip(k);
                }
                clip(message);
            }
            Event::RestartRequired { keys } => keys.iter_mut().for_each(&mut clip),
            Event::BusState { interface, .. } => clip(interface),
            Event::FieldFault { link, cause, .. } => {
                clip(link);
                clip(cause);
            }
            Event::Note { text } => clip(text),
            Event::ConnectionsShed { server, detail, .. } => {
                clip(server);
                if let Some(d) = detail {
                    clip(d);
                }
            }
            Event::SurgeDetected(_)
            | Event::SurgeCounter(_)
            | Event::SafetyOnShift(_)
            | Event::ModeChanged(_)
            | Event::LawChanged(_)
            | Event::FallbackEntered(_)
            | Event::FallbackLeft(_)
            | Event::DeadlineOverrun(_)
            | Event::RecycleTrip(_)
            | Event::Transmitter(_)
            | Event::EventsDropped { .. } => {}
        }
        clipped
    }
}

fn clip_string(s: &mut String, max_bytes: usize) -> bool {
    const MARK: &str = "…";
    if s.len() <= max_bytes {
        return false;
    }
    let mut cut = max_bytes.saturating_sub(MARK.len());
    while !s.is_char_boundary(cut) {
        cut -= 1;
    }
    s.truncate(cut);
    s.push_str(MARK);
    true
}

/// The shape of one line as written: `ts`, `seq`, then the tagged event's fields.
#[derive(Serialize)]
pub(crate) struct LineOut<'a> {
    pub(crate) ts: Timestamp,
    pub(crate) seq: u64,
    #[serde(flatten)]
    pub(crate) event: &'a Event,
}

impl From<SurgeDetected> for Event {
    fn from(p: SurgeDetected) -> Event {
        Event::SurgeDetected(p)
    }
}
impl From<SurgeCounter> for Event {
    fn from(p: SurgeCounter) -> Event {
        Event::SurgeCounter(p)
    }
}
impl From<SafetyOnShift> for Event {
    fn from(p: SafetyOnShift) -> Event {
        Event::SafetyOnShift(p)
    }
}
impl From<ModeChanged> for Event {
    fn from(p: ModeChanged) -> Event {
        Event::ModeChanged(p)
    }
}
impl From<LawChanged> for Event {
    fn from(p: LawChanged) -> Event {
        Event::LawChanged(p)
    }
}
impl From<FallbackEntered> for Event {
    fn from(p: FallbackEntered) -> Event {
        Event::FallbackEntered(p)
    }
}
impl From<FallbackLeft> for Event {
    fn from(p: FallbackLeft) -> Event {
        Event::FallbackLeft(p)
    }
}
impl From<DeadlineOverrun> for Event {
    fn from(p: DeadlineOverrun) -> Event {
        Event::DeadlineOverrun(p)
    }
}
impl From<RecycleTrip> for Event {
    fn from(p: RecycleTrip) -> Event {
        Event::RecycleTrip(p)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// One example of every kind, with the exact line the writer must produce for it.
    pub(crate) fn examples() -> Vec<(Event, &'static str)> {
        vec![
            (
                Event::Started {
                    version: "0.1.0".into(),
                    config_path: "/etc/antisurge/antisurge.toml".into(),
                    law: Law::RecyclePi,
                    cycle_trigger: None,
                },
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"started","version":"0.1.0","config_path":"/etc/antisurge/antisurge.toml","law":"recycle-pi"}"#,
            ),
            (
                Event::Stopped {
                    reason: "SIGTERM".into(),
                },
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"stopped","reason":"SIGTERM"}"#,
            ),
            (
                Event::SurgeDetected(SurgeDetected {
                    surge_count_total: 3,
                    frequency_hz: 8.5,
                    min_flow_kg_s: -0.42,
                    flow_reversal: true,
                }),
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"surge_detected","surge_count_total":3,"frequency_hz":8.5,"min_flow_kg_s":-0.42,"flow_reversal":true}"#,
            ),
            (
                Event::SurgeCounter(SurgeCounter {
                    previous_count: 3,
                    count: 0,
                }),
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"surge_counter","previous_count":3,"count":0}"#,
            ),
            (
                Event::SafetyOnShift(SafetyOnShift {
                    margin_pct: 2.5,
                    total_margin_pct: 5.0,
                    count: 2,
                }),
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"safety_on_shift","margin_pct":2.5,"total_margin_pct":5.0,"count":2}"#,
            ),
            (
                Event::ModeChanged(ModeChanged {
                    from: Mode::Auto,
                    to: Mode::FailSafe,
                    cause: None,
                }),
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"mode_changed","from":"auto","to":"fail_safe"}"#,
            ),
            (
                Event::LawChanged(LawChanged {
                    from: Law::RecyclePi,
                    to: Law::Ccv,
                }),
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"law_changed","from":"recycle-pi","to":"ccv"}"#,
            ),
            (
                Event::FallbackEntered(FallbackEntered {
                    input: SensorId::OrificeDp,
                    reason: FallbackReason::Stale,
                    replaced_by: Replacement::Observer,
                    vs_observer_pct: None,
                    vs_speed_line_pct: None,
                }),
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"fallback_entered","input":"orifice_dp","reason":"stale","replaced_by":"observer"}"#,
            ),
            (
                Event::FallbackLeft(FallbackLeft {
                    input: SensorId::OrificeDp,
                    replaced_by: Replacement::Observer,
                    duration_ms: 1520,
                }),
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"fallback_left","input":"orifice_dp","replaced_by":"observer","duration_ms":1520}"#,
            ),
            (
                Event::ConfigApplied {
                    file: "/etc/antisurge/antisurge.toml".into(),
                    diff: vec![
                        ConfigChange {
                            key: "control.recycle.kp".into(),
                            old: Some("0.8".into()),
                            new: Some("1.2".into()),
                        },
                        ConfigChange {
                            key: "surge.margin_pct".into(),
                            old: None,
                            new: Some("10.0".into()),
                        },
                    ],
                },
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"config_applied","file":"/etc/antisurge/antisurge.toml","diff":[{"key":"control.recycle.kp","old":"0.8","new":"1.2"},{"key":"surge.margin_pct","old":null,"new":"10.0"}]}"#,
            ),
            (
                Event::ConfigRejected {
                    file: "/etc/antisurge/antisurge.toml".into(),
                    key: Some("control.recycle.kp".into()),
                    line: Some(17),
                    message: "must be positive".into(),
                },
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"config_rejected","file":"/etc/antisurge/antisurge.toml","key":"control.recycle.kp","line":17,"message":"must be positive"}"#,
            ),
            (
                Event::RestartRequired {
                    keys: vec!["io.can.interface".into(), "control.period_us".into()],
                },
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"restart_required","keys":["io.can.interface","control.period_us"]}"#,
            ),
            (
                Event::DeadlineOverrun(DeadlineOverrun {
                    count: 12,
                    worst_lateness_us: 340,
                    window_s: 10.0,
                }),
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"deadline_overrun","count":12,"worst_lateness_us":340,"window_s":10.0}"#,
            ),
            (
                Event::BusState {
                    interface: "can0".into(),
                    state: BusState::BusOff,
                },
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"bus_state","interface":"can0","state":"bus_off"}"#,
            ),
            (
                Event::RecycleTrip(RecycleTrip {
                    reason: TripReason::SurgeDetected,
                    cause: None,
                    criterion: None,
                }),
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"recycle_trip","reason":"surge_detected"}"#,
            ),
            (
                Event::Note {
                    text: "operator: \"valve stroke test\"".into(),
                },
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"note","text":"operator: \"valve stroke test\""}"#,
            ),
            (
                Event::EventsDropped {
                    count: 7,
                    cause: DropCause::QueueFull,
                },
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"events_dropped","count":7,"cause":"queue_full"}"#,
            ),
            (
                // the Δp cross-check (issue 10): the transmitter and the check that caught it
                Event::FallbackEntered(FallbackEntered {
                    input: SensorId::OrificeDp,
                    reason: FallbackReason::Frozen,
                    replaced_by: Replacement::Observer,
                    vs_observer_pct: None,
                    vs_speed_line_pct: None,
                }),
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"fallback_entered","input":"orifice_dp","reason":"frozen","replaced_by":"observer"}"#,
            ),
            (
                // the drift cross-check: how far the transmitter is off each estimate
                Event::FallbackEntered(FallbackEntered {
                    input: SensorId::OrificeDp,
                    reason: FallbackReason::Drift,
                    replaced_by: Replacement::Observer,
                    vs_observer_pct: Some(12.5),
                    vs_speed_line_pct: Some(11.0),
                }),
                r#"{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"fallback_entered","input":"orifice_dp","reason":"drift","replaced_by":"observer","vs_observer_pct":12.5,"vs_speed_line_pct":11.0}"#,
            ),
        ]
    }

    fn line(e: &Event) -> String {
        serde_json::to_string(&LineOut {
            ts: Timestamp::from_unix_micros(1_714_566_896_123_456),
            seq: 42,
            event: e,
        })
        .expect("serialize")
    }

    #[test]
    fn exact_line_format_for_every_kind() {
        let ex = examples();
        for (event, expected) in &ex {
            assert_eq!(line(event), *expected, "kind {}", event.kind());
            assert!(expected.contains(&format!("\"event\":\"{}\"", event.kind())));
        }
        // Every kind has an example (a new variant must add one).
        let mut kinds: Vec<_> = ex.iter().map(|(e, _)| e.kind()).collect();
        kinds.sort_unstable();
        kinds.dedup();
        assert_eq!(kinds.len(), 17);
    }

    #[test]
    fn lines_parse_back_to_the_same_event() {
        for (event, text) in examples() {
            let back: Event = serde_json::from_str(text).expect(text);
            assert_eq!(back, event);
        }
    }

    #[test]
    fn nan_is_written_as_null_and_read_back_as_nan() {
        let e = Event::SurgeDetected(SurgeDetected {
            surge_count_total: 1,
            frequency_hz: f64::NAN,
            min_flow_kg_s: 0.1,
            flow_reversal: false,
        });
        let text = line(&e);
        assert!(text.contains(r#""frequency_hz":null"#), "{text}");
        match serde_json::from_str::<Event>(&text).expect("parse") {
            Event::SurgeDetected(s) => {
                assert!(s.frequency_hz.is_nan());
                assert_eq!(s.min_flow_kg_s, 0.1);
            }
            other => panic!("wrong kind {other:?}"),
        }
    }

    #[test]
    fn split_halves_lists_and_refuses_scalars() {
        let (e, _) = examples().swap_remove(9);
        let (a, b) = e.split_in_two().expect("two diff entries split");
        match (a, b) {
            (Event::ConfigApplied { diff: da, .. }, Event::ConfigApplied { diff: db, .. }) => {
                assert_eq!(da[0].key, "control.recycle.kp");
                assert_eq!(db[0].key, "surge.margin_pct");
            }
            other => panic!("{other:?}"),
        }
        assert!(Event::Note { text: "x".into() }.split_in_two().is_none());
    }

    #[test]
    fn clip_respects_char_boundaries() {
        let mut e = Event::Note {
            text: "ä".repeat(100),
        };
        assert!(e.clip_text(11));
        match &e {
            Event::Note { text } => {
                assert!(text.len() <= 11, "{}", text.len());
                assert!(text.ends_with('…'));
            }
            _ => unreachable!(),
        }
        assert!(!e.clip_text(100));
    }
}
