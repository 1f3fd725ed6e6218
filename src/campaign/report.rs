//! The campaign's report: the summary table (classes; per law the cases with surge and the
//! surge cycles among the cases feasible with margin; the cases where recycle-pi surges more
//! than baseline-pi; the recycle energy over the cases both laws hold, with its ratio), broken
//! down by loop rate and by disturbance, and the list of failing cases with what reproduces
//! each. Infeasible cases are listed too, and kept out of the zero-surge line.

use super::skid::{DisturbanceKind, DpFault, LOOP_RATES_HZ};
use super::{Campaign, CaseResult, Feasibility};
use std::fmt::Write as _;

/// One row of the summary: the tallies over a group of cases.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Tally {
    /// Cases.
    pub cases: usize,
    /// Feasible with margin.
    pub with_margin: usize,
    /// Feasible (only the oracle holds).
    pub feasible: usize,
    /// Infeasible.
    pub infeasible: usize,
    /// Cases where the valve held at its opening surges (the disturbance is a challenge).
    pub held_surges: usize,
    /// Among the feasible-with-margin cases: recycle-pi's cases with surge.
    pub rp_cases: usize,
    /// ... and its surge cycles.
    pub rp_cycles: u32,
    /// Among the feasible-with-margin cases: baseline-pi's cases with surge.
    pub bp_cases: usize,
    /// ... and its surge cycles.
    pub bp_cycles: u32,
    /// Cases (any class) where recycle-pi has more surge cycles than baseline-pi.
    pub rp_worse: usize,
    /// Cases (any class) where recycle-pi left automatic mode.
    pub rp_left_auto: usize,
    /// Cases both laws hold without surge.
    pub both_hold: usize,
    /// recycle-pi's recycle energy over those, J.
    pub rp_energy_j: f64,
    /// baseline-pi's recycle energy over those, J.
    pub bp_energy_j: f64,
}

impl Tally {
    /// Tally the cases.
    pub fn of<'a>(cases: impl IntoIterator<Item = &'a CaseResult>) -> Tally {
        let mut t = Tally::default();
        for c in cases {
            t.cases += 1;
            match c.class {
                Feasibility::FeasibleWithMargin => t.with_margin += 1,
                Feasibility::Feasible => t.feasible += 1,
                Feasibility::Infeasible => t.infeasible += 1,
            }
            if c.held.surge_cycles > 0 {
                t.held_surges += 1;
            }
            if c.class == Feasibility::FeasibleWithMargin {
                if c.recycle_pi.surge_cycles > 0 {
                    t.rp_cases += 1;
                    t.rp_cycles += c.recycle_pi.surge_cycles;
                }
                if c.baseline_pi.surge_cycles > 0 {
                    t.bp_cases += 1;
                    t.bp_cycles += c.baseline_pi.surge_cycles;
                }
            }
            if c.recycle_pi.surge_cycles > c.baseline_pi.surge_cycles {
                t.rp_worse += 1;
            }
            if !c.recycle_pi.stayed_auto {
                t.rp_left_auto += 1;
            }
            if c.recycle_pi.surge_cycles == 0 && c.baseline_pi.surge_cycles == 0 {
                t.both_hold += 1;
                t.rp_energy_j += c.recycle_pi.recycle_energy_j;
                t.bp_energy_j += c.baseline_pi.recycle_energy_j;
            }
        }
        t
    }
}

/// Whether a case fails a safety line of the campaign: recycle-pi surges in a case the late
/// oracle holds, or surges more than baseline-pi.
pub fn fails_safety(c: &CaseResult) -> bool {
    (c.class == Feasibility::FeasibleWithMargin && c.recycle_pi.surge_cycles > 0)
        || c.recycle_pi.surge_cycles > c.baseline_pi.surge_cycles
}

fn pct(x: f64) -> String {
    if x.is_finite() {
        format!("{:+.1} %", 100.0 * x)
    } else {
        "—".to_string()
    }
}

fn mj(x: f64) -> String {
    format!("{:.3}", x / 1e6)
}

fn row(s: &mut String, label: &str, t: &Tally) {
    let ratio = if t.bp_energy_j > 0.0 {
        format!("{:.3}", t.rp_energy_j / t.bp_energy_j)
    } else {
        "—".to_string()
    };
    let _ = writeln!(
        s,
        "| {label} | {} | {} / {} / {} | {} | {} ({} cycles) | {} ({} cycles) | {} | {} | {} | {} MJ / {} MJ = {ratio} |",
        t.cases,
        t.with_margin,
        t.feasible,
        t.infeasible,
        t.held_surges,
        t.rp_cases,
        t.rp_cycles,
        t.bp_cases,
        t.bp_cycles,
        t.rp_worse,
        t.rp_left_auto,
        t.both_hold,
        mj(t.rp_energy_j),
        mj(t.bp_energy_j),
    );
}

/// A case's skid in one line (what reproduces and explains it).
pub fn describe_case(c: &CaseResult) -> String {
    let p = &c.skid;
    let dp = match p.dp_fault {
        DpFault::Healthy => "Δp healthy".to_string(),
        DpFault::Frozen { from_s, for_s } => {
            format!("Δp frozen {from_s:.2}–{:.2} s", from_s + for_s)
        }
        DpFault::Bias { pct_span } => format!("Δp bias {pct_span:+.1} % of span"),
    };
    format!(
        "{}, {:.0} Hz, {}; latency {:.0} ms + ≤ {:.0} ms jitter, valve stroke {:.2} s + dead time {:.0} ms, \
         surge frequency {:.1} Hz, step-to-reversal {:.0} ms, V1 {:.3} m³, V2 {:.3} m³, L_c {:.2} m, \
         map ×{:.3} flow ×{:.3} rise, noise {:.2} / {:.2} % of span, {} bits, {dp}",
        p.base,
        p.rate_hz,
        p.disturbance.describe(),
        1e3 * p.latency_s,
        1e3 * p.jitter_s,
        p.recycle_stroke_time_s,
        1e3 * p.valve_dead_time_s,
        p.surge_frequency_hz,
        1e3 * p.step_to_reversal_s,
        p.suction_volume_m3,
        p.discharge_volume_m3,
        p.compressor_duct_length_m,
        p.map_flow_factor,
        p.map_rise_factor,
        p.pressure_noise_pct_span,
        p.dp_noise_pct_span,
        p.quantisation_bits,
    )
}

fn outcome(c: &CaseResult) -> String {
    format!(
        "recycle-pi {} cycles (closest {}{}), baseline-pi {} (closest {}), oracle {} (closest {}), late oracle {} (closest {}), valve held {}",
        c.recycle_pi.surge_cycles,
        pct(c.recycle_pi.min_margin),
        if c.recycle_pi.stayed_auto { "" } else { ", left auto" },
        c.baseline_pi.surge_cycles,
        pct(c.baseline_pi.min_margin),
        c.oracle.surge_cycles,
        pct(c.oracle.min_margin),
        c.late_oracle.surge_cycles,
        pct(c.late_oracle.min_margin),
        c.held.surge_cycles,
    )
}

/// The command that reruns a case.
pub fn reproduce(campaign: &Campaign, c: &CaseResult) -> String {
    let mut s = format!("antisurge campaign --case {}", c.case);
    if campaign.seed != super::DEFAULT_SEED {
        let _ = write!(s, " --seed {}", campaign.seed);
    }
    if let Some(r) = campaign.rate_hz {
        let _ = write!(s, " --rate-hz {r}");
    }
    if campaign.margin_pct != super::DEFAULT_MARGIN_PCT {
        let _ = write!(s, " --margin-pct {}", campaign.margin_pct);
    }
    s
}

/// The summary table and the failing cases, as Markdown.
pub fn markdown(campaign: &Campaign) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Campaign seed {}, {} cases{}, control line {} % right of the surge line (recycle-pi with its defaults, baseline-pi on the same line).\n",
        campaign.seed,
        campaign.cases.len(),
        if campaign.reduced { " (reduced)" } else { "" },
        campaign.margin_pct
    );
    s.push_str(
        "| cases | n | feasible with margin / feasible / infeasible | valve held surges | recycle-pi surges (feasible with margin) | baseline-pi surges (feasible with margin) | recycle-pi > baseline-pi | recycle-pi left auto | both hold | recycle energy recycle-pi / baseline-pi where both hold |\n",
    );
    s.push_str("|---|---|---|---|---|---|---|---|---|---|\n");
    row(&mut s, "all", &Tally::of(&campaign.cases));
    for r in LOOP_RATES_HZ {
        let t = Tally::of(campaign.cases.iter().filter(|c| c.skid.rate_hz == r));
        if t.cases > 0 {
            row(&mut s, &format!("{r:.0} Hz"), &t);
        }
    }
    for d in DisturbanceKind::ALL {
        let t = Tally::of(
            campaign
                .cases
                .iter()
                .filter(|c| c.skid.disturbance.kind() == d),
        );
        if t.cases > 0 {
            row(&mut s, d.name(), &t);
        }
    }
    let failing: Vec<&CaseResult> = campaign.cases.iter().filter(|c| fails_safety(c)).collect();
    let _ = writeln!(
        s,
        "\nFailing cases (recycle-pi surges where the late oracle holds, or more than baseline-pi): {}\n",
        failing.len()
    );
    for c in &failing {
        let _ = writeln!(
            s,
            "- case {} ({}): {}. {}. `{}`",
            c.case,
            c.class.name(),
            describe_case(c),
            outcome(c),
            reproduce(campaign, c)
        );
    }
    let infeasible: Vec<&CaseResult> = campaign
        .cases
        .iter()
        .filter(|c| c.class == Feasibility::Infeasible)
        .collect();
    let _ = writeln!(
        s,
        "\nInfeasible cases (the oracle itself surges; not in the zero-surge line): {}\n",
        infeasible.len()
    );
    for c in &infeasible {
        let _ = writeln!(
            s,
            "- case {}: {}. {}. `{}`",
            c.case,
            describe_case(c),
            outcome(c),
            reproduce(campaign, c)
        );
    }
    s
}

/// One case in detail (`--case K`).
pub fn case_detail(campaign: &Campaign, c: &CaseResult) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "case {} (seed {}): {}", c.case, c.seed, c.class.name());
    let _ = writeln!(s, "  skid: {}", describe_case(c));
    for (name, r) in [
        ("recycle-pi", &c.recycle_pi),
        ("baseline-pi", &c.baseline_pi),
        ("oracle", &c.oracle),
        ("oracle +2 T", &c.late_oracle),
        ("valve held", &c.held),
    ] {
        let _ = writeln!(
            s,
            "  {name:<12} surge cycles {:>3}, flow reversals {:>3}, closest approach {:>9}, recycle energy {} MJ{}",
            r.surge_cycles,
            r.flow_reversals,
            pct(r.min_margin),
            mj(r.recycle_energy_j),
            if r.stayed_auto { "" } else { ", left auto" }
        );
    }
    let _ = writeln!(s, "  reproduce: {}", reproduce(campaign, c));
    s
}

/// Every case in one table row: class, per controller surge cycles and closest approach,
/// recycle energy of both laws, whether recycle-pi stayed in automatic mode.
pub fn per_case_markdown(campaign: &Campaign) -> String {
    let mut s = String::from(
        "| case | base | rate | disturbance | class | recycle-pi cycles / closest / MJ | baseline-pi cycles / closest / MJ | oracle | late oracle | valve held | recycle-pi auto |\n|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for c in &campaign.cases {
        let law = |r: &super::runner::RunResult| {
            format!(
                "{} / {} / {}",
                r.surge_cycles,
                pct(r.min_margin),
                mj(r.recycle_energy_j)
            )
        };
        let oracle =
            |r: &super::runner::RunResult| format!("{} / {}", r.surge_cycles, pct(r.min_margin));
        let _ = writeln!(
            s,
            "| {} | {} | {:.0} Hz | {} | {} | {} | {} | {} | {} | {} | {} |",
            c.case,
            c.skid.base,
            c.skid.rate_hz,
            c.skid.disturbance.describe(),
            c.class.name(),
            law(&c.recycle_pi),
            law(&c.baseline_pi),
            oracle(&c.oracle),
            oracle(&c.late_oracle),
            c.held.surge_cycles,
            if c.recycle_pi.stayed_auto {
                "yes"
            } else {
                "no"
            },
        );
    }
    s
}
