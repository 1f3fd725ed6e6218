//! A reload tried against the live inputs before it is applied (issue 25, item 6, first part).
//!
//! A configuration can pass every static check and still put the running compressor into
//! fail-safe the moment it is applied: an input range that refuses what the transmitter
//! reads now (a range typed in the wrong unit that no unit rule explains, a range tightened
//! past the operating point). [`inputs_refused`] compares the live reading of every
//! supervised input with the running and the new limits: a reading the running limits
//! accept and the new ones refuse refuses the reload, with the reading and the key in the
//! `config_rejected` event. The control thread is not involved: the readings come from the
//! sensor board, which any thread may read.

use super::{locate, Loaded, Problem};
use crate::vocab::signals::SensorId;

/// Problems of applying `new` over `running` given the live `reading` of each sensor (NaN:
/// none yet, not judged).
pub fn inputs_refused(
    running: &Loaded,
    new: &Loaded,
    reading: impl Fn(SensorId) -> f64,
) -> Vec<Problem> {
    let mut out = Vec::new();
    for id in SensorId::ALL {
        let v = reading(id);
        if !v.is_finite() {
            continue;
        }
        let (Some(old), Some(lim)) = (
            running.core.supervisor.limits[id.index()],
            new.core.supervisor.limits[id.index()],
        ) else {
            continue;
        };
        let accepted_now = old.min <= v && v <= old.max;
        let accepted_new = lim.min <= v && lim.max >= v;
        if accepted_now && !accepted_new {
            let key = if v > lim.max { "max" } else { "min" };
            let mut e = locate(
                &new.layers,
                &format!("inputs.{}.{key}", id.name()),
                format!(
                    "{} reads {v:.6e} {} now, outside the new range [{}, {}] (the running range accepts it): applying it would put the controller into fail-safe (recycle valve open); nothing was applied",
                    id.name(),
                    id.unit(),
                    lim.min,
                    lim.max
                ),
            );
            e.hint = Some(format!(
                "ranges are in SI units ({}); widen the range to include the operating point",
                id.unit()
            ));
            out.push(Problem::error(e));
        }
    }
    out
}
