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
    /// Whether the run ends in a steady operating point (no oscillation above threshold and no
    /// flow reversal in the final window).
    pub stable: bool,
    /// Whether the compressor flow reversed at any time.
    pub flow_reversal: bool,
    /// Flow-reversal episodes.
    pub flow_reversals: u32,
    /// Surge cycles counted by the detector.
    pub surge_cycles: u32,
    /// Frequency of the surge cycles, Hz (null if none).
    pub surge_frequency_hz: Option<f64>,
    /// Lowest compressor mass flow, kg/s.
    pub min_flow_kg_s: f64,
    /// Final compressor mass flow, kg/s.
    pub final_flow_kg_s: f64,
    /// Final pressure ratio.
    pub final_pressure_ratio: f64,
    /// Lowest surge margin (q − q_SL)/q_SL over the run (negative: left of the surge line).
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
}

/// Settling time of the flow after `t_event`: the time after which it stays within the band
/// ± max(`rel`·|final|, `abs_floor`) around its final value (mean of the last 0.5 s).
pub fn settle_time(rows: &[TraceRow], t_event: f64, rel: f64, abs_floor: f64) -> Option<f64> {
    let last = rows.last()?;
    let tail: Vec<f64> = rows
        .iter()
        .filter(|r| r.t_s >= last.t_s - 0.5)
        .map(|r| r.m_kg_s)
        .collect();
    let fin = tail.iter().sum::<f64>() / tail.len().max(1) as f64;
    let band = (rel * fin.abs()).max(abs_floor);
    let mut settle = t_event;
    for r in rows.iter().filter(|r| r.t_s >= t_event) {
        if (r.m_kg_s - fin).abs() > band {
            settle = r.t_s;
        }
    }
    if settle >= last.t_s - 0.5 {
        return None;
    }
    Some((settle - t_event).max(0.0))
}

/// Whether the last `window_s` of the trace is steady: no reversal and peak-to-peak flow
/// within ±`rel` of the mean.
pub fn is_steady(rows: &[TraceRow], window_s: f64, rel: f64, abs_floor: f64) -> bool {
    let Some(last) = rows.last() else {
        return false;
    };
    let w: Vec<f64> = rows
        .iter()
        .filter(|r| r.t_s >= last.t_s - window_s)
        .map(|r| r.m_kg_s)
        .collect();
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

    #[test]
    fn oscillation_never_settles() {
        let r = rows(|t| 5.0 + (10.0 * t).sin(), 20.0);
        assert!(settle_time(&r, 0.0, 0.02, 0.0).is_none());
        assert!(!is_steady(&r, 3.0, 0.02, 0.0));
    }
}
