//! The benchmark table of docs/benchmarks.md: for every plant and every law that applies to it, the
//! minimum stable flow reached versus open loop (operating range gained), the peak actuator
//! effort and the recycle energy over the throttle-closure scenario. `antisurge table` reruns it.

use super::trace::TraceRow;
use super::{run, SimError, SimOptions, Summary};
use crate::control::LawId;
use crate::scenario::{Action, Scenario};
use crate::sim::case::PlantCase;
use crate::vocab::signals::ActuatorId;
use std::fmt::Write as _;

/// One row of the table.
#[derive(Debug, Clone)]
pub struct TableRow {
    /// Plant name.
    pub plant: String,
    /// Law.
    pub law: LawId,
    /// Lowest throughput (flow delivered to the process) of a stable step of the sweep, kg/s.
    pub min_stable_flow_kg_s: f64,
    /// Compressor flow at that step, kg/s (higher than the throughput when gas is recycled).
    pub compressor_flow_kg_s: f64,
    /// The same throughput for open loop on this plant, kg/s.
    pub open_loop_min_stable_flow_kg_s: f64,
    /// Which sweep was used.
    pub sweep: String,
    /// Throttle-closure result.
    pub closure: Summary,
}

impl TableRow {
    /// Operating range gained: how much lower the minimum stable flow is than open loop, %.
    pub fn range_gained_pct(&self) -> f64 {
        100.0 * (self.open_loop_min_stable_flow_kg_s - self.min_stable_flow_kg_s)
            / self.open_loop_min_stable_flow_kg_s
    }

    /// The law's main actuator effort over the closure, as text.
    pub fn effort(&self) -> String {
        let p = &self.closure.actuator_peaks;
        // by the actuators the law drives (its registry entry), so a new law needs no line here
        let drives = |a: ActuatorId| self.law.actuators().contains(a);
        if drives(ActuatorId::CloseCoupledValve) {
            format!("CCV {:.3} (limit {:.2})", p.ccv, p.ccv_rating)
        } else if drives(ActuatorId::RecycleValve) {
            format!(
                "recycle valve {:.0} % open",
                100.0 * p.recycle_valve_opening
            )
        } else if drives(ActuatorId::Throttle) {
            "throttle trim".to_string()
        } else if drives(ActuatorId::TipClearance) {
            format!(
                "clearance {:.0} µm ({:.0} % of nominal), {:.0} N",
                1e6 * p.tip_clearance_m,
                100.0 * p.tip_clearance_m / p.tip_clearance_nominal_m,
                p.thrust_force_n
            )
        } else if drives(ActuatorId::DriveTorque) {
            // the law's own torque, not the total (which carries the load torque at t = 0)
            format!(
                "law torque ±{:.0} N·m on {:.0} nominal (rating {:.0})",
                p.law_drive_torque_nm, p.nominal_load_torque_nm, p.drive_torque_rating_nm
            )
        } else {
            format!(
                "torque {:.0} N·m ({:.1}× nominal, rating {:.0})",
                p.drive_torque_cmd_nm,
                p.drive_torque_cmd_nm / p.nominal_load_torque_nm,
                p.drive_torque_rating_nm
            )
        }
    }
}

/// Minimum stable throughput from a staircase scenario: each hold window (from the end of a
/// ramp to the start of the next event, skipping the first `settle_s`) is stable if the
/// compressor flow stays positive and within ±`band` of its mean. The result is the mean
/// throughput (throttle flow) and compressor flow of the last stable window before the first
/// unstable one.
pub fn min_stable_flow(
    trace: &[TraceRow],
    scenario: &Scenario,
    settle_s: f64,
    band: f64,
) -> (f64, f64) {
    let mut windows: Vec<(f64, f64)> = Vec::new();
    let mut starts: Vec<f64> = scenario.actions.iter().map(|(t, _)| *t).collect();
    starts.push(scenario.file.duration_s);
    for (i, (t, a)) in scenario.actions.iter().enumerate() {
        let end_of_change = match a {
            Action::Ramp(r) => t + r.over_s,
            _ => *t,
        };
        windows.push((end_of_change + settle_s, starts[i + 1]));
    }
    // the initial point, before the first event
    windows.insert(0, (settle_s.min(starts[0] * 0.5), starts[0]));
    let mut best = (f64::NAN, f64::NAN);
    for (a, b) in windows {
        let rows: Vec<&TraceRow> = trace.iter().filter(|r| r.t_s >= a && r.t_s <= b).collect();
        if rows.is_empty() {
            continue;
        }
        let n = rows.len() as f64;
        let mean = rows.iter().map(|r| r.m_kg_s).sum::<f64>() / n;
        let ok = rows
            .iter()
            .all(|r| r.m_kg_s > 0.0 && (r.m_kg_s - mean).abs() <= band * mean.abs());
        if !ok {
            break;
        }
        let through = rows.iter().map(|r| r.throttle_flow_kg_s).sum::<f64>() / n;
        best = (if through.is_finite() { through } else { mean }, mean);
    }
    best
}

/// Build the table: for every plant, open loop and every applicable law, the sweep and the
/// closure. `throttle_sweep` lowers the throughput by closing the throttle; plants whose feed is
/// a fixed mass flow (seed 002) get `feed_sweep` instead, since their throughput is the feed.
pub fn build(
    plants: &[PlantCase],
    throttle_sweep: &Scenario,
    feed_sweep: &Scenario,
    closure: &Scenario,
) -> Result<Vec<TableRow>, SimError> {
    let mut rows = Vec::new();
    for p in plants {
        let mass_feed = matches!(
            p.file.recycle_system.map(|r| r.feed),
            Some(crate::plant::file::FeedSpec::MassFlow { .. })
        );
        let sweep = if mass_feed {
            feed_sweep
        } else {
            throttle_sweep
        };
        let opts = |law| SimOptions {
            law,
            ..SimOptions::default()
        };
        let ol = run(p, sweep, opts(LawId::None), &mut |_| {})?;
        let ol_min = min_stable_flow(&ol.trace, sweep, 2.0, 0.02);
        for law in LawId::ALL {
            if !law.supports(p.file.model) {
                continue;
            }
            let s = if law == LawId::None {
                ol_min
            } else {
                let r = run(p, sweep, opts(law), &mut |_| {})?;
                min_stable_flow(&r.trace, sweep, 2.0, 0.02)
            };
            let c = run(p, closure, opts(law), &mut |_| {})?;
            rows.push(TableRow {
                plant: p.name().to_string(),
                law,
                min_stable_flow_kg_s: s.0,
                compressor_flow_kg_s: s.1,
                open_loop_min_stable_flow_kg_s: ol_min.0,
                sweep: sweep.name().to_string(),
                closure: c.summary,
            });
        }
    }
    Ok(rows)
}

/// The table as Markdown.
pub fn markdown(rows: &[TableRow]) -> String {
    let mut s = String::new();
    s.push_str("| plant | law | sweep | min. stable throughput, kg/s (open loop) | compressor flow there, kg/s | range gained | throttle closure 60 → 20 % | peak actuator effort | recycle energy |\n");
    s.push_str("|---|---|---|---|---|---|---|---|---|\n");
    for r in rows {
        let c = &r.closure;
        let closure = if c.surge_cycles == 0 && !c.flow_reversal && !c.stable {
            // no surge, but fail-safe, saturation or implausible states: say which
            c.verdict.clone()
        } else if c.surge_cycles == 0 && !c.flow_reversal {
            match c.settle_time_s {
                Some(t) => format!("no surge, settles in {t:.2} s"),
                None => "no surge, not settled".to_string(),
            }
        } else {
            format!(
                "surge: {} cycles{}",
                c.surge_cycles,
                c.surge_frequency_hz
                    .map(|f| format!(" at {f:.1} Hz"))
                    .unwrap_or_default()
            )
        };
        let energy = if c.recycle_energy_j > 0.0 {
            format!("{:.2} MJ", c.recycle_energy_j / 1e6)
        } else {
            "—".to_string()
        };
        let gained = if r.law == LawId::None {
            "—".to_string()
        } else {
            format!("{:+.0} %", r.range_gained_pct())
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.3} ({:.3}) | {:.3} | {} | {} | {} | {} |",
            r.plant,
            r.law.name(),
            r.sweep,
            r.min_stable_flow_kg_s,
            r.open_loop_min_stable_flow_kg_s,
            r.compressor_flow_kg_s,
            gained,
            closure,
            r.effort(),
            energy
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn min_stable_flow_stops_at_the_first_unstable_window() {
        let text = "name='s'\ndescription='d'\nduration_s=12\n[[event]]\nat_s=4\nramp={signal='throttle', to=0.5, over_s=1}\n[[event]]\nat_s=8\nramp={signal='throttle', to=0.4, over_s=1}\n";
        let path = std::path::Path::new("s.toml");
        let file = crate::config::toml_file::parse(text, path).expect("parse");
        let sc = Scenario::from_file(file, path, text).expect("valid");
        // steady 10, then steady 8, then oscillating around 6
        let trace: Vec<TraceRow> = (0..1200)
            .map(|k| {
                let t = k as f64 * 0.01;
                let m = if t < 4.5 {
                    10.0
                } else if t < 8.5 {
                    8.0
                } else {
                    6.0 + 2.0 * (20.0 * t).sin()
                };
                TraceRow {
                    t_s: t,
                    m_kg_s: m,
                    // 10 % of the compressor flow recycled: the throughput is 90 %
                    throttle_flow_kg_s: 0.9 * m,
                    ..Default::default()
                }
            })
            .collect();
        let (through, m) = min_stable_flow(&trace, &sc, 0.5, 0.02);
        assert!((m - 8.0).abs() < 1e-9, "{m}");
        assert!((through - 7.2).abs() < 1e-9, "{through}");
    }
}

/// One row of the drive-torque inertia sweep.
#[derive(Debug, Clone)]
pub struct InertiaRow {
    /// Rotor inertia, kg·m².
    pub inertia_kg_m2: f64,
    /// K1 used (scaled with J to keep the plant file's K1·h/J), N·m·s/rad.
    pub k1_nm_s_rad: f64,
    /// Minimum stable throughput of the sweep, kg/s.
    pub min_stable_flow_kg_s: f64,
    /// Open loop's, kg/s.
    pub open_loop_min_stable_flow_kg_s: f64,
    /// Throttle-closure result.
    pub closure: Summary,
}

/// Drive-torque against rotor inertia: the same plant with J from `inertias_kg_m2`, K1 scaled
/// to keep the plant file's K1·h/J (the sampled speed loop), every other gain as tuned. The
/// active law needs torque ≈ J c1 × the flow deviation's rate of change (seed 000 eq. 1c, 4):
/// a heavier rotor needs proportionally more, and the drive's rating caps it.
pub fn inertia_sweep(
    plant: &PlantCase,
    sweep: &Scenario,
    closure: &Scenario,
    inertias_kg_m2: &[f64],
) -> Result<Vec<InertiaRow>, SimError> {
    let opts = |law| SimOptions {
        law,
        ..SimOptions::default()
    };
    let ol = run(plant, sweep, opts(LawId::None), &mut |_| {})?;
    let ol_min = min_stable_flow(&ol.trace, sweep, 2.0, 0.02).0;
    let j0 = plant.file.shaft.inertia_kg_m2;
    let k0 = plant.controller.drive_torque.k1_nm_s_rad;
    let mut rows = Vec::new();
    for &j in inertias_kg_m2 {
        let mut p = plant.clone();
        p.file.shaft.inertia_kg_m2 = j;
        p.controller.drive_torque.k1_nm_s_rad = k0 * j / j0;
        let r = run(&p, sweep, opts(LawId::DriveTorque), &mut |_| {})?;
        let s = min_stable_flow(&r.trace, sweep, 2.0, 0.02).0;
        let c = run(&p, closure, opts(LawId::DriveTorque), &mut |_| {})?;
        rows.push(InertiaRow {
            inertia_kg_m2: j,
            k1_nm_s_rad: k0 * j / j0,
            min_stable_flow_kg_s: s,
            open_loop_min_stable_flow_kg_s: ol_min,
            closure: c.summary,
        });
    }
    Ok(rows)
}

/// The inertia sweep as Markdown.
pub fn inertia_markdown(plant: &str, rows: &[InertiaRow]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "| {plant}: rotor inertia J, kg·m² | K1, N·m·s/rad | min. stable throughput, kg/s (open loop) | range gained | throttle closure 60 → 20 % | law torque peak, N·m (rating) | torque saturated |");
    s.push_str("|---|---|---|---|---|---|---|\n");
    for r in rows {
        let p = &r.closure.actuator_peaks;
        let gained = 100.0 * (r.open_loop_min_stable_flow_kg_s - r.min_stable_flow_kg_s)
            / r.open_loop_min_stable_flow_kg_s;
        let _ = writeln!(
            s,
            "| {:.1} | {:.0} | {:.3} ({:.3}) | {:+.0} % | {} | ±{:.0} ({:.0}) | {:.0} % of cycles |",
            r.inertia_kg_m2,
            r.k1_nm_s_rad,
            r.min_stable_flow_kg_s,
            r.open_loop_min_stable_flow_kg_s,
            gained,
            r.closure.verdict,
            p.law_drive_torque_nm,
            p.drive_torque_rating_nm,
            100.0 * r.closure.torque_saturation_fraction
        );
    }
    s
}
