//! The controller's settings: flow source, observer, surge detection and every law's gains.
//!
//! One schema, used in two places: a plant file's `[controller]` table holds the tuned defaults
//! for that benchmark machine, and the daemon's config may override any key. Every field has a
//! default (from the seeds where they give one), so an absent table means "seed defaults".

use super::drive_torque::DriveTorqueConfig;
use super::observer::ObserverConfig;
use super::recycle_fl::RecycleFlConfig;
use super::recycle_pi::RecyclePiConfig;
use super::spool_laws::{CcvConfig, RobustConfig, ThrottleBackstepConfig};
use super::tip_sliding::TipSlidingConfig;
use crate::surge::DetectorConfig;
use serde::{Deserialize, Serialize};

/// Where the laws take the compressor mass flow from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FlowSource {
    /// The orifice (flow transmitter) only; a failed transmitter is an input failure.
    Orifice,
    /// The observer only (seed 000 eq. 15: pressure and speed only).
    Observer,
    /// The orifice, with the observer as fallback when the transmitter is stale, NaN or out
    /// of range.
    #[default]
    OrificeWithObserverFallback,
}

/// Controller settings (`[controller]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct ControllerConfig {
    /// Flow source.
    pub flow_source: FlowSource,
    /// Mass-flow observer (seed 000 eq. 14–17).
    pub observer: ObserverConfig,
    /// Surge detection.
    pub detector: DetectorConfig,
    /// Cut-off of the filtered pressure derivatives some laws use, Hz.
    #[serde(default = "default_derivative_hz")]
    pub derivative_filter_hz: f64,
    /// recycle-pi.
    pub recycle_pi: RecyclePiConfig,
    /// recycle-fl.
    pub recycle_fl: RecycleFlConfig,
    /// drive-torque.
    pub drive_torque: DriveTorqueConfig,
    /// ccv.
    pub ccv: CcvConfig,
    /// throttle-backstep.
    pub throttle_backstep: ThrottleBackstepConfig,
    /// robust.
    pub robust: RobustConfig,
    /// tip-sliding.
    pub tip_sliding: TipSlidingConfig,
}

fn default_derivative_hz() -> f64 {
    50.0
}
