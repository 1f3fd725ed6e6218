//! Helpers for the robustness campaign tests (issue 22, tests/control/campaign.rs): the base plants,
//! the reduced campaign run once per test binary and shared, and the failing-case lines.

use antisurge::campaign::{self, report, Campaign, CampaignOptions, CaseResult};
use antisurge::sim::case::PlantCase;
use std::sync::OnceLock;

/// The in-house recycle plants the skids vary.
pub fn bases() -> Vec<PlantCase> {
    campaign::load_bases(&super::root().join("config")).unwrap_or_else(|e| panic!("{e}"))
}

/// Threads for the campaign in tests (the CI machine has two cores).
pub const THREADS: usize = 2;

/// The reduced campaign (`antisurge campaign --reduced`), run once per test binary.
pub fn reduced() -> &'static Campaign {
    static REDUCED: OnceLock<Campaign> = OnceLock::new();
    REDUCED.get_or_init(|| {
        let opts = CampaignOptions {
            cases: campaign::REDUCED_CASES,
            threads: THREADS,
            ..CampaignOptions::default()
        };
        campaign::run_campaign(&bases(), &opts, true).unwrap_or_else(|e| panic!("{e}"))
    })
}

/// One line per case: what it is, how every controller did, how to rerun it.
pub fn case_line(c: &Campaign, r: &CaseResult, why: &str) -> String {
    format!(
        "case {} ({}): {why}; {}; rerun: {}",
        r.case,
        r.class.name(),
        report::describe_case(r),
        report::reproduce(c, r)
    )
}
