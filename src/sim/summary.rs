//! `summary.json`: the numbers a run is judged by.

use super::trace::TraceRow;
use serde::Serialize;

/// Peak actuator efforts over the run (absolute values of commands and of what the actuator
/// delivered), next to the ratings the plant file states.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Default)]
pub struct ActuatorPeaks {
    /// Largest drive torque command, N·m.
    pub drive_torque_cmd_nm: f64,
    /// Largest torque delivered, N·m.
    pub drive_torque_nm: f64,
    /// The drive's rated torque, N·m.
    pub drive_torque_rating_nm: f64,
    /// Nominal (initial) load torque, N·m.
    pub nominal_load_torque_nm: f64,
    /// Largest recycle valve opening commanded, fraction.
    pub recycle_valve_opening: f64,
    /// Fastest recycle valve closing speed of the stem, 1/s.
    pub recycle_valve_closing_rate_per_s: f64,
    /// Largest |close-coupled valve| command.
    pub ccv: f64,
    /// Close-coupled valve limit.
    pub ccv_rating: f64,
    /// Largest |tip-clearance change| commanded, m.
    pub tip_clearance_cmd_m: f64,
    /// Largest |tip-clearance change| delivered, m.
    pub tip_clearance_m: f64,
    /// Nominal tip clearance, m.
    pub tip_clearance_nominal_m: f64,
    /// Largest |thrust force|, N.
    pub thrust_force_n: f64,
    /// Thrust force rating, N.
    pub thrust_force_rating_n: f64,
    /// Largest |thrust force slew|, N/s.
    pub thrust_slew_n_s: f64,
    /// Thrust slew rating, N/s.
    pub thrust_slew_rating_n_s: f64,
    /// Largest |drive torque| the active law itself commanded on top of the speed loop, N·m
    /// (0 when no law drives the torque). The total command also carries the load torque.
    pub law_drive_torque_nm: f64,
    /// Lowest and highest total drive torque commanded, N·m.
    pub drive_torque_cmd_range_nm: (f64, f64),
}

/// Events the law reported over the run (the daemon logs them; a run counts them).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Default)]
pub struct LawEventCounts {
    /// Recycle trips (open-loop step openings).
    pub recycle_trips: u32,
    /// Safety-on shifts of the control line.
    pub safety_on_shifts: u32,
    /// Total safety-on margin after the last shift, fraction of surge-line flow.
    pub safety_on_total_margin: f64,
}

/// A run is "stable" only if the controller spent less than this fraction of the control
/// cycles in fail-safe.
pub const MAX_FAILSAFE_FRACTION: f64 = 0.01;
/// … and its drive torque command sat at a limit (rating or floor) in less than this fraction
/// of the cycles.
pub const MAX_SATURATION_FRACTION: f64 = 0.20;

/// The closest approach to surge, measured from the start of the scenario's last event to the
/// end of the run (the t = 0 operating point does not count).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Default)]
pub struct ClosestApproach {
    /// Start of the window: the start of the last scenario event, s.
    pub from_s: f64,
    /// Lowest compressor mass flow in the window, kg/s.
    pub min_flow_kg_s: f64,
    /// When, s.
    pub min_flow_at_s: f64,
    /// Lowest surge margin in the window (negative: left of the surge line).
    pub min_surge_margin: f64,
    /// When, s.
    pub min_surge_margin_at_s: f64,
    /// Lowest throughput (flow to the process through the throttle) in the window, kg/s.
    pub min_throughput_kg_s: f64,
}

/// One period in which the controller took its flow from the observer instead of the
/// transmitter.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FlowFallback {
    /// Start, s.
    pub from_s: f64,
    /// End, s (null: until the end of the run).
    pub to_s: Option<f64>,
    /// Why, in words (the transmitter's fault as the input supervisor saw it).
    pub cause: String,
    /// Largest observer error against the true flow during the fallback, kg/s (signed).
    pub observer_max_error_kg_s: f64,
    /// The same, relative to the true flow at that instant.
    pub observer_max_error_fraction: f64,
}

/// Where the controller's flow came from over the run.
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct FlowSourceReport {
    /// The configured source (`orifice`, `observer`, `orifice_with_observer_fallback`), or
    /// `unknown` when the controller is on the far side of a bus.
    pub configured: String,
    /// Every fallback to the observer, with its time and cause.
    pub fallbacks: Vec<FlowFallback>,
}

/// One stay in the fail-safe mode.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ModeEpisode {
    /// Entered, s.
    pub from_s: f64,
    /// Left, s (null: still in it at the end).
    pub to_s: Option<f64>,
}

/// Result summary of one run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    /// Plant name.
    pub plant: String,
    /// Scenario name.
    pub scenario: String,
    /// Law name.
    pub law: String,
    /// Simulated duration, s.
    pub duration_s: f64,
    /// Whether the run is stable: no surge during or after the last scenario event (a rescue
    /// scenario may surge before its law switches in; the verdict then says so), steady at the end (no oscillation above threshold
    /// and no flow reversal in the final window), every state bounded and plausible, fail-safe
    /// below [`MAX_FAILSAFE_FRACTION`] and torque saturation below [`MAX_SATURATION_FRACTION`]
    /// of the cycles. [`Summary::verdict`] says which condition failed.
    pub stable: bool,
    /// The verdict in words, e.g. `STABLE — no surge` or `UNSTABLE — fail-safe 92 %, speed out
    /// of range`.
    pub verdict: String,
    /// Fraction of control cycles the controller spent in fail-safe (0 when unknown).
    pub failsafe_fraction: f64,
    /// Each stay in fail-safe.
    pub failsafe_episodes: Vec<ModeEpisode>,
    /// Fraction of control cycles with the drive torque command at its rating or floor.
    pub torque_saturation_fraction: f64,
    /// States that left their plausible range, in words (empty: all plausible). The ranges are
    /// the controller's own input plausibility limits (`CoreSettings::defaults_for`).
    pub implausible: Vec<String>,
    /// Closest approach during and after the last event.
    pub closest_approach: ClosestApproach,
    /// Flow source and its fallbacks.
    pub flow_source: FlowSourceReport,
    /// Whether the compressor flow reversed at any time.
    pub flow_reversal: bool,
    /// Flow-reversal episodes.
    pub flow_reversals: u32,
    /// Surge cycles counted by the detector.
    pub surge_cycles: u32,
    /// Frequency of the surge cycles, Hz (null if none).
    pub surge_frequency_hz: Option<f64>,
    /// Lowest compressor mass flow over the whole run (including t = 0), kg/s. See
    /// [`Summary::closest_approach`] for the event's.
    pub min_flow_kg_s: f64,
    /// Final compressor mass flow, kg/s.
    pub final_flow_kg_s: f64,
    /// Final pressure ratio.
    pub final_pressure_ratio: f64,
    /// Lowest surge margin (q − q_SL)/q_SL over the whole run (negative: left of the surge
    /// line).
    pub min_surge_margin: f64,
    /// Final surge margin.
    pub final_surge_margin: f64,
    /// Time after the last scenario event until the flow stays within ±2 % of its final
    /// value, s (null if it never settles).
    pub settle_time_s: Option<f64>,
    /// Recycle energy ∫ w_recycle · h_polytropic dt, J.
    pub recycle_energy_j: f64,
    /// Actuator peaks and ratings.
    pub actuator_peaks: ActuatorPeaks,
    /// Events the law reported.
    pub law_events: LawEventCounts,
    /// Wall-clock time of the simulation loop, s.
    pub wall_time_s: f64,
    /// Simulated seconds per wall-clock second.
    pub realtime_factor: f64,
    /// Plant node only: how often the field devices entered their own fail-safe because the
    /// controller's heartbeat stopped.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub field_failsafe_entries: Option<u64>,
    /// Plant node only: the device watchdog at the first field fail-safe entry (when and
    /// after which last heartbeat change), so a test can bound the watchdog's timing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device_watchdog: Option<DeviceWatchdogTrip>,
    /// Real-time plant (`antisurge run --out`, `antisurge plant`) only: trace rows the plant
    /// thread dropped because the trace writer's queue was full (the trace has gaps where
    /// this is not 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trace_rows_dropped: Option<u64>,
}

/// When the plant's device watchdog first failed the field devices safe, and when it last
/// saw the controller's heartbeat change before that.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DeviceWatchdogTrip {
    /// Plant time of the first fail-safe step, s.
    pub failsafe_t_s: f64,
    /// Plant time of the step that first saw the last heartbeat change, s.
    pub last_beat_t_s: f64,
    /// Wall-clock (Unix) time at which that last heartbeat change arrived, s.
    pub last_beat_unix_s: f64,
    /// Heartbeat age when the watchdog tripped (monotonic clock), s.
    pub age_s: f64,
}

/// What a run's record says about its health, for [`verdict`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Health<'a> {
    /// Surge cycles counted during and after the last event.
    pub surge_cycles: u32,
    /// Surge frequency, Hz.
    pub surge_frequency_hz: Option<f64>,
    /// Flow-reversal episodes.
    pub flow_reversals: u32,
    /// Whether the end of the run is steady.
    pub steady: bool,
    /// Fail-safe fraction of the cycles.
    pub failsafe_fraction: f64,
    /// Torque saturation fraction of the cycles.
    pub torque_saturation_fraction: f64,
    /// Implausible states, in words.
    pub implausible: &'a [String],
}

/// The verdict: (stable, words). Stable needs no surge, a steady end, plausible states,
/// fail-safe and saturation below their stated fractions; otherwise the words list each
/// condition that failed.
pub fn verdict(h: &Health<'_>) -> (bool, String) {
    let mut problems: Vec<String> = Vec::new();
    if h.failsafe_fraction >= MAX_FAILSAFE_FRACTION {
        problems.push(format!("fail-safe {:.0} %", 100.0 * h.failsafe_fraction));
    }
    if h.torque_saturation_fraction >= MAX_SATURATION_FRACTION {
        problems.push(format!(
            "drive torque saturated {:.0} %",
            100.0 * h.torque_saturation_fraction
        ));
    }
    problems.extend(h.implausible.iter().cloned());
    let surged = h.surge_cycles > 0 || h.flow_reversals > 0;
    if surged {
        let mut w = format!("SURGE — {} cycles", h.surge_cycles);
        if let Some(f) = h.surge_frequency_hz {
            w.push_str(&format!(" at {f:.2} Hz"));
        }
        if h.flow_reversals > 0 {
            w.push_str(&format!(", flow reversed {} times", h.flow_reversals));
        }
        for p in &problems {
            w.push_str(", ");
            w.push_str(p);
        }
        return (false, w);
    }
    if !problems.is_empty() {
        if !h.steady {
            problems.push("not settled at the end".into());
        }
        return (false, format!("UNSTABLE — {}", problems.join(", ")));
    }
    if !h.steady {
        return (
            false,
            "NOT SETTLED — no surge detected, but the flow still moves at the end".into(),
        );
    }
    (true, "STABLE — no surge".into())
}

/// Settling time of the flow after `t_event`: the time after which it stays within the band
/// ± max(`rel`·|final|, `abs_floor`) around its final value (mean of the last 0.5 s).
pub fn settle_time(rows: &[TraceRow], t_event: f64, rel: f64, abs_floor: f64) -> Option<f64> {
    let last = rows.last()?;
    let mut s = Settle::new(
        rows.iter()
            .filter(|r| r.t_s >= last.t_s - SETTLE_FINAL_WINDOW_S)
            .map(|r| r.m_kg_s),
        t_event,
        rel,
        abs_floor,
    );
    for r in rows.iter().filter(|r| r.t_s >= t_event) {
        s.row(r.t_s, r.m_kg_s);
    }
    s.finish(last.t_s)
}

/// The final value of the settle time is the mean flow of this last stretch of the run, s.
pub const SETTLE_FINAL_WINDOW_S: f64 = 0.5;

/// [`settle_time`] a row at a time (a streamed trace): the final flow first, then the rows
/// from the last event on, in order.
pub struct Settle {
    t_event: f64,
    fin: f64,
    band: f64,
    settle: f64,
}

impl Settle {
    /// Flows of the last [`SETTLE_FINAL_WINDOW_S`] of the run in `final_window`.
    pub fn new(
        final_window: impl Iterator<Item = f64>,
        t_event: f64,
        rel: f64,
        abs_floor: f64,
    ) -> Self {
        let tail: Vec<f64> = final_window.collect();
        let fin = tail.iter().sum::<f64>() / tail.len().max(1) as f64;
        Settle {
            t_event,
            fin,
            band: (rel * fin.abs()).max(abs_floor),
            settle: t_event,
        }
    }

    /// The next row at or after the last event.
    pub fn row(&mut self, t_s: f64, m_kg_s: f64) {
        if (m_kg_s - self.fin).abs() > self.band {
            self.settle = t_s;
        }
    }

    /// The settle time of a run whose last row is at `t_last_s`.
    pub fn finish(&self, t_last_s: f64) -> Option<f64> {
        if self.settle >= t_last_s - SETTLE_FINAL_WINDOW_S {
            return None;
        }
        Some((self.settle - self.t_event).max(0.0))
    }
}

/// Whether the last `window_s` of the trace is steady: no reversal and peak-to-peak flow
/// within ±`rel` of the mean.
pub fn is_steady(rows: &[TraceRow], window_s: f64, rel: f64, abs_floor: f64) -> bool {
    let Some(last) = rows.last() else {
        return false;
    };
    steady_window(
        rows.iter()
            .filter(|r| r.t_s >= last.t_s - window_s)
            .map(|r| r.m_kg_s),
        rel,
        abs_floor,
    )
}

/// [`is_steady`] of the flows of the window, in order.
pub fn steady_window(window: impl Iterator<Item = f64>, rel: f64, abs_floor: f64) -> bool {
    let w: Vec<f64> = window.collect();
    if w.is_empty() || w.iter().any(|m| !m.is_finite()) {
        return false;
    }
    let mean = w.iter().sum::<f64>() / w.len() as f64;
    let (lo, hi) = w
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &m| {
            (a.min(m), b.max(m))
        });
    let band = (rel * mean.abs()).max(abs_floor);
    lo > 0.0 && hi - mean <= band && mean - lo <= band
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(f: impl Fn(f64) -> f64, t_end: f64) -> Vec<TraceRow> {
        (0..=(t_end / 0.01) as usize)
            .map(|k| {
                let t = k as f64 * 0.01;
                TraceRow {
                    t_s: t,
                    m_kg_s: f(t),
                    ..Default::default()
                }
            })
            .collect()
    }

    #[test]
    fn settle_time_of_exponential() {
        // m = 5 + 2 e^{-t}: within 2 % of 5 (0.1) when 2e^{-t} < 0.1 → t = ln 20 ≈ 3.0
        let r = rows(|t| 5.0 + 2.0 * (-t).exp(), 20.0);
        let s = settle_time(&r, 0.0, 0.02, 0.0).expect("settles");
        assert!((s - 20f64.ln()).abs() < 0.02, "{s}");
        assert!(is_steady(&r, 3.0, 0.02, 0.0));
    }

    fn healthy() -> Health<'static> {
        Health {
            surge_cycles: 0,
            surge_frequency_hz: None,
            flow_reversals: 0,
            steady: true,
            failsafe_fraction: 0.0,
            torque_saturation_fraction: 0.0,
            implausible: &[],
        }
    }

    #[test]
    fn verdict_names_every_failed_condition() {
        assert_eq!(verdict(&healthy()), (true, "STABLE — no surge".to_string()));
        let bad = ["speed out of range (max 616 000 rad/s)".to_string()];
        let h = Health {
            failsafe_fraction: 0.92,
            implausible: &bad,
            ..healthy()
        };
        assert_eq!(
            verdict(&h),
            (
                false,
                "UNSTABLE — fail-safe 92 %, speed out of range (max 616 000 rad/s)".to_string()
            )
        );
        let h = Health {
            torque_saturation_fraction: 0.74,
            ..healthy()
        };
        assert_eq!(verdict(&h).1, "UNSTABLE — drive torque saturated 74 %");
        let h = Health {
            surge_cycles: 3,
            surge_frequency_hz: Some(2.0),
            ..healthy()
        };
        assert_eq!(
            verdict(&h),
            (false, "SURGE — 3 cycles at 2.00 Hz".to_string())
        );
        let h = Health {
            steady: false,
            ..healthy()
        };
        assert!(!verdict(&h).0);
        // just under the stated fractions: still stable
        let h = Health {
            failsafe_fraction: 0.9 * MAX_FAILSAFE_FRACTION,
            torque_saturation_fraction: 0.9 * MAX_SATURATION_FRACTION,
            ..healthy()
        };
        assert!(verdict(&h).0);
    }

    #[test]
    fn oscillation_never_settles() {
        let r = rows(|t| 5.0 + (10.0 * t).sin(), 20.0);
        assert!(settle_time(&r, 0.0, 0.02, 0.0).is_none());
        assert!(!is_steady(&r, 3.0, 0.02, 0.0));
    }
}
