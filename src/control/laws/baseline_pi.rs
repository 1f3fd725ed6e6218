//! `baseline-pi`: the yardstick. A textbook symmetric PI on the normalised deviation from the
//! surge control line, with conditional integration, as open-source skid simulators and simple
//! field controllers do it. No rate limits, no trip, no safety-on, no transmitter checks.
//!
//! Available in `antisurge sim` and the control benchmark matrix only; the daemon does not
//! offer it (its name does not parse as a daemon law, see [`LawId::parse_sim`](crate::control::law::api::LawId::parse_sim)).
//! recycle-pi must beat it: zero surge where it surges, and less recycle energy.
//!
//! Normalised deviation (positive = safe): d = (q − c(R))/c(R), q the compressor flow in the
//! map's coordinate, c(R) the control-line flow at the measured pressure ratio (the same
//! control line as recycle-pi's `[controller.recycle_pi] control_line`, seed 002 eq. 4.1/4.2).
//! Valve opening u = Kp·e + I, e = −d (left of the line opens), İ = Ki·e, clamped to
//! [min opening, 1], d through a first-order 1 Hz filter (the usual flow-signal damping); the
//! integrator stops while the output is saturated and the error pushes
//! further into the limit (conditional integration).

use crate::control::law::api::{LawError, LawNeeds, LawSpec};
use crate::control::law::api::{LawInputs, LawOutput, SurgeLaw};
use crate::control::model::ControlModel;
use crate::control::laws::recycle_pi::RecyclePiConfig;
use crate::control::surge_control_line::SurgeControlLine;
use crate::machine::MachineData;
use crate::vocab::signals::ActuatorSet;
use crate::vocab::signals::{ActuatorCommands, ActuatorId};

/// Proportional gain: valve fraction per unit of normalised deviation (a 5 % deviation moves
/// the valve 5 %). Chosen as the largest round gains that close the throttle closure without a
/// limit cycle on both recycle plants (2/2 at 2 Hz limit-cycles on hemchi2016).
pub const BASELINE_KP: f64 = 1.0;
/// Integral gain: valve fraction per unit of normalised deviation and second (integral time
/// Kp/Ki = 0.5 s).
pub const BASELINE_KI_PER_S: f64 = 2.0;

/// Cut-off of the first-order filter on the deviation, Hz.
pub const BASELINE_FILTER_HZ: f64 = 1.0;

/// Law state.
#[derive(Debug, Clone)]
pub struct BaselinePi {
    scl: SurgeControlLine,
    kp: f64,
    ki_per_s: f64,
    min_opening: f64,
    integ: f64,
    /// Filtered deviation.
    d_f: f64,
    filter_hz: f64,
    started: bool,
}

impl BaselinePi {
    /// On a control line (recycle-pi's, so both laws keep the same margin), with the
    /// textbook gains.
    pub fn new(scl: SurgeControlLine, min_opening: f64) -> Self {
        BaselinePi {
            scl,
            kp: BASELINE_KP,
            ki_per_s: BASELINE_KI_PER_S,
            min_opening: min_opening.clamp(0.0, 1.0),
            integ: 0.0,
            d_f: f64::NAN,
            filter_hz: BASELINE_FILTER_HZ,
            started: false,
        }
    }

    /// Normalised deviation d = (q − c(R))/c(R), positive = safe side.
    #[inline]
    pub fn deviation(&self, flow_map: f64, pressure_ratio: f64) -> f64 {
        let c = self.scl.flow_at_ratio(pressure_ratio);
        if c > 0.0 {
            (flow_map - c) / c
        } else {
            f64::NAN
        }
    }
}

impl SurgeLaw for BaselinePi {
    fn start(&mut self, inputs: &LawInputs<'_>, current: &ActuatorCommands) {
        let m = inputs.m;
        let mut u0 = current.get(ActuatorId::RecycleValve);
        if !u0.is_finite() {
            u0 = m.recycle_position;
        }
        if !u0.is_finite() {
            u0 = self.min_opening;
        }
        let d = self.deviation(m.flow_map, m.pressure_ratio);
        self.d_f = d;
        let e = -d;
        self.integ = if e.is_finite() { u0 - self.kp * e } else { u0 };
        self.started = true;
    }

    fn update(&mut self, inputs: &LawInputs<'_>, dt_s: f64) -> LawOutput {
        if !self.started {
            self.start(inputs, &ActuatorCommands::default());
        }
        let m = inputs.m;
        let d = self.deviation(m.flow_map, m.pressure_ratio);
        let mut out = LawOutput::idle();
        if !d.is_finite() {
            return out;
        }
        // first-order measurement filter, as field controllers put on the flow signal
        if self.d_f.is_finite() && self.filter_hz > 0.0 {
            let a = 1.0 - (-2.0 * std::f64::consts::PI * self.filter_hz * dt_s.max(0.0)).exp();
            self.d_f += a * (d - self.d_f);
        } else {
            self.d_f = d;
        }
        let e = -self.d_f;
        let (lo, hi) = (self.min_opening, 1.0);
        let u_raw = self.integ + self.kp * e;
        // conditional integration: not while saturated with the error pushing further out
        let saturated_hi = u_raw >= hi && e > 0.0;
        let saturated_lo = u_raw <= lo && e < 0.0;
        if !(saturated_hi || saturated_lo) {
            self.integ += self.ki_per_s * e * dt_s.max(0.0);
        }
        // keep the integrator itself inside the valve's range
        self.integ = self.integ.clamp(lo, hi);
        let u = (self.integ + self.kp * e).clamp(lo, hi);
        out.commands.set(ActuatorId::RecycleValve, u);
        out.diagnostic = -e;
        out
    }
}

impl LawSpec for BaselinePi {
    type Settings = RecyclePiConfig;
    const NEEDS: LawNeeds = LawNeeds {
        summary:
            "textbook symmetric PI on the normalised deviation (simulation and benchmarks only)",
        actuators: ActuatorSet::of(&[ActuatorId::RecycleValve]),
        sensors: &[],
        needs_flow: true,
        machine_data: &[MachineData::SurgeLine, MachineData::RecycleValve],
        model_family: None,
    };
    fn build(settings: &Self::Settings, model: &ControlModel) -> Result<Self, LawError> {
        // the same control line as recycle-pi (with its checks), textbook gains
        let rp = crate::control::laws::recycle_pi::RecyclePi::new(settings, model)?;
        Ok(BaselinePi::new(*rp.control_line(), settings.min_opening))
    }
}
