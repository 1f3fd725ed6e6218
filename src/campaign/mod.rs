//! The robustness campaign (`antisurge campaign`, issue 22): random skids nobody tuned for, at
//! field-bus loop rates with bus latency, through four disturbances; recycle-pi against the
//! textbook baseline-pi and against a feasibility oracle on the identical skid, disturbance
//! and noise.
//!
//! - [`skid`]: the random skids (plant variations of the in-house recycle plants, the field,
//!   the disturbance), each range with its source;
//! - [`runner`]: the multi-rate run (plant at 1 ms, control core at the loop rate, latency both
//!   ways) and the oracle;
//! - [`report`]: classification, the summary table, the failing cases, JSON.
//!
//! A case is *feasible with margin* when the late oracle (two sample periods after the first
//! instant the transmitters could show the disturbance) holds it with zero surge cycles,
//! *feasible* when only the oracle does, *infeasible* when not even the oracle does: such a
//! case is reported, and kept out of the zero-surge line.
//!
//! Deterministic: case `k` of seed `S` is the same skid, noise and jitter on every machine;
//! cases run on std threads.

pub mod report;
pub mod runner;
pub mod skid;

use crate::config::FileError;
use crate::control::law::api::LawError;
use crate::control::LawId;
use crate::sim::case::PlantCase;
use crate::sim::SimError;
use runner::{Controller, RunResult};
use serde::Serialize;
use skid::SkidParams;
use std::path::Path;

/// Cases of the full campaign by default (issue 22: at least 200).
pub const DEFAULT_CASES: usize = 200;
/// Cases of the reduced campaign (`--reduced`, the CI test): the first 32 cases of the
/// campaign, which hold every loop rate × disturbance once on each base plant.
pub const REDUCED_CASES: usize = 32;
/// The campaign's default seed (fixed: the issue number and the year the campaign began).
pub const DEFAULT_SEED: u64 = 22_2026;
/// Control-line margin by default, % of surge-line flow (the recycle-pi default, and the
/// bench matrix's first margin).
pub const DEFAULT_MARGIN_PCT: f64 = 10.0;

/// Errors of a campaign.
#[derive(Debug, thiserror::Error)]
pub enum CampaignError {
    /// No base plant given.
    #[error("no base plant to vary")]
    NoBasePlant,
    /// A base plant that is not a recycle system.
    #[error("plant `{0}` is not a recycle_system plant")]
    NotRecycle(String),
    /// No draw of a case lay in the documented ranges.
    #[error("case {case}: no skid within the documented ranges after {draws} draws")]
    NoSkid {
        /// Case.
        case: usize,
        /// Draws tried.
        draws: u32,
    },
    /// The case's scenario did not validate.
    #[error("case {case}: scenario: {message}")]
    Scenario {
        /// Case.
        case: usize,
        /// What is wrong.
        message: String,
    },
    /// A base plant file.
    #[error(transparent)]
    File(#[from] FileError),
    /// The simulation.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// The law cannot run on the plant.
    #[error(transparent)]
    Law(#[from] LawError),
}

/// What a campaign runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CampaignOptions {
    /// Number of cases (0..cases).
    pub cases: usize,
    /// Campaign seed.
    pub seed: u64,
    /// Control-line margin, % of surge-line flow.
    pub margin_pct: f64,
    /// Run only this case.
    pub only_case: Option<usize>,
    /// Threads.
    pub threads: usize,
    /// Run every case at this loop rate instead of its own, Hz (to compare one case across
    /// rates).
    pub rate_hz: Option<f64>,
}

impl Default for CampaignOptions {
    fn default() -> Self {
        CampaignOptions {
            cases: DEFAULT_CASES,
            seed: DEFAULT_SEED,
            margin_pct: DEFAULT_MARGIN_PCT,
            only_case: None,
            threads: 1,
            rate_hz: None,
        }
    }
}

/// Whether an ideal valve action holds a case.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Feasibility {
    /// The late oracle holds it with zero surge cycles.
    FeasibleWithMargin,
    /// The oracle holds it, the late oracle does not.
    Feasible,
    /// Not even the oracle holds it.
    Infeasible,
}

impl Feasibility {
    /// Name in tables.
    pub fn name(self) -> &'static str {
        match self {
            Feasibility::FeasibleWithMargin => "feasible with margin",
            Feasibility::Feasible => "feasible",
            Feasibility::Infeasible => "infeasible",
        }
    }
}

/// One case: the skid and every controller's scores.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CaseResult {
    /// Case number (`antisurge campaign --case K`).
    pub case: usize,
    /// The case's own seed.
    pub seed: u64,
    /// The skid.
    pub skid: SkidParams,
    /// Class.
    pub class: Feasibility,
    /// recycle-pi.
    pub recycle_pi: RunResult,
    /// baseline-pi.
    pub baseline_pi: RunResult,
    /// The oracle.
    pub oracle: RunResult,
    /// The late oracle.
    pub late_oracle: RunResult,
    /// The valve held at its initial opening.
    pub held: RunResult,
}

/// A finished campaign.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Campaign {
    /// Seed.
    pub seed: u64,
    /// Control-line margin, %.
    pub margin_pct: f64,
    /// Whether it is the reduced campaign.
    pub reduced: bool,
    /// The loop rate every case ran at instead of its own, Hz (None: their own).
    pub rate_hz: Option<f64>,
    /// Cases, by case number.
    pub cases: Vec<CaseResult>,
}

/// Load the base plants ([`skid::BASE_PLANTS`]) from `config_dir/plants`.
pub fn load_bases(config_dir: &Path) -> Result<Vec<PlantCase>, CampaignError> {
    skid::BASE_PLANTS
        .iter()
        .map(|s| {
            PlantCase::load(&config_dir.join("plants").join(format!("{s}.toml")))
                .map_err(CampaignError::from)
        })
        .collect()
}

/// Classify a case by its oracles.
pub fn classify(oracle: &RunResult, late: &RunResult) -> Feasibility {
    if oracle.surge_cycles > 0 {
        Feasibility::Infeasible
    } else if late.surge_cycles == 0 {
        Feasibility::FeasibleWithMargin
    } else {
        Feasibility::Feasible
    }
}

/// Run case `k`: draw its skid (at the loop rate `rate_hz` instead of its own, if given) and
/// run every controller on it.
pub fn run_case(
    bases: &[PlantCase],
    seed: u64,
    k: usize,
    margin_pct: f64,
    rate_hz: Option<f64>,
) -> Result<CaseResult, CampaignError> {
    let mut s = skid::draw_skid(bases, seed, k)?;
    if let Some(r) = rate_hz {
        s.params.rate_hz = r;
    }
    run_skid(&s, margin_pct)
}

/// The skid the oracles and the held valve run on: `s` with its recycle valve starting at the
/// larger of the openings the two laws held when the disturbance came (`laws`: their runs),
/// i.e. on the control line they are asked to hold. The question the oracle answers is
/// whether a controller *at that operating point* could have held the disturbance by acting
/// in time. From the skid's initial opening (drawn with at least 15 % margin, often 30 %) it
/// answered for a machine with two to three times the laws' margin, and called cases feasible
/// that no causal controller on the control line can hold. The larger opening: a law that sat
/// left of the other (less margin) cannot make a case look infeasible by doing so.
///
/// A law whose compressor flow reversed before the disturbance was recovering from a surge of
/// its own when it came, its valve opened wide by the surge: its opening is not the control
/// line's and does not count, unless both laws surged before the disturbance (then the larger
/// opening, as before). Without this rule a baseline-pi that surged at 3 s held 0.75 at 5 s,
/// and the oracle judged a throttle step from three times the margin on the line.
pub fn on_the_control_line(s: &skid::Skid, laws: [&runner::RunResult; 2]) -> skid::Skid {
    let mut on = s.clone();
    let larger = |settled_only: bool| {
        laws.iter()
            .filter(|r| !(settled_only && r.reversed_before_event))
            .map(|r| r.opening_at_event)
            .filter(|u| u.is_finite())
            .reduce(f64::max)
    };
    if let Some(u) = larger(true).or_else(|| larger(false)) {
        on.plant.file.initial.recycle_valve = u.clamp(0.0, 1.0);
    }
    on
}

/// The skid `c` runs on in the campaign: the oracles and the held valve on the control line
/// ([`on_the_control_line`], from the laws' runs), the laws on `s` itself.
pub fn skid_for<'a>(
    c: Controller,
    s: &'a skid::Skid,
    laws: [&runner::RunResult; 2],
) -> std::borrow::Cow<'a, skid::Skid> {
    match c {
        Controller::Law(_) => std::borrow::Cow::Borrowed(s),
        Controller::Oracle { .. } | Controller::Held => {
            std::borrow::Cow::Owned(on_the_control_line(s, laws))
        }
    }
}

/// Run every controller on a skid.
pub fn run_skid(s: &skid::Skid, margin_pct: f64) -> Result<CaseResult, CampaignError> {
    let recycle_pi = runner::run(s, Controller::Law(LawId::RecyclePi), margin_pct)?;
    let baseline_pi = runner::run(s, Controller::Law(LawId::BaselinePi), margin_pct)?;
    let r =
        |c: Controller| runner::run(&skid_for(c, s, [&recycle_pi, &baseline_pi]), c, margin_pct);
    let oracle = r(Controller::Oracle { late_periods: 0 })?;
    let late_oracle = r(Controller::Oracle {
        late_periods: runner::LATE_ORACLE_PERIODS,
    })?;
    let held = r(Controller::Held)?;
    Ok(CaseResult {
        case: s.index,
        seed: s.seed,
        class: classify(&oracle, &late_oracle),
        skid: s.params.clone(),
        recycle_pi,
        baseline_pi,
        oracle,
        late_oracle,
        held,
    })
}

/// Run the cases `indices` of `opts.seed` on up to `opts.threads` threads, in case order.
pub fn run_cases(
    bases: &[PlantCase],
    opts: &CampaignOptions,
    indices: &[usize],
) -> Result<Vec<CaseResult>, CampaignError> {
    let threads = opts.threads;
    let next = std::sync::atomic::AtomicUsize::new(0);
    type Slot = (usize, Result<CaseResult, CampaignError>);
    let results: std::sync::Mutex<Vec<Slot>> = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..threads.clamp(1, indices.len().max(1)) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(&k) = indices.get(i) else {
                    break;
                };
                let r = run_case(bases, opts.seed, k, opts.margin_pct, opts.rate_hz);
                if let Ok(mut g) = results.lock() {
                    g.push((i, r));
                }
            });
        }
    });
    let mut all = results.into_inner().unwrap_or_default();
    all.sort_by_key(|(i, _)| *i);
    all.into_iter().map(|(_, r)| r).collect()
}

/// Run a campaign.
pub fn run_campaign(
    bases: &[PlantCase],
    opts: &CampaignOptions,
    reduced: bool,
) -> Result<Campaign, CampaignError> {
    let indices: Vec<usize> = match opts.only_case {
        Some(k) => vec![k],
        None => (0..opts.cases).collect(),
    };
    let cases = run_cases(bases, opts, &indices)?;
    Ok(Campaign {
        seed: opts.seed,
        margin_pct: opts.margin_pct,
        reduced,
        rate_hz: opts.rate_hz,
        cases,
    })
}
