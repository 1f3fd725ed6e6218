//! The ESD stroke study: the longest recycle-valve stroke that holds an emergency shutdown,
//! with the trip seen in the speed decay or on the wired contact; the machine check's warning
//! and the plant variants.

use crate::control::LawId;
use crate::scenario::Scenario;
use crate::sim::case::PlantCase;
use crate::sim::SimError;
use std::fmt::Write as _;
use std::path::Path;

use super::*;

/// How the controller learns of the drive trip in an ESD rundown.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TripSignal {
    /// From the speed decay alone (recycle-pi's deceleration trip): no trip contact wired.
    SpeedDecay,
    /// The drive's trip contact wired as `esd_input`, read [`ESD_CONTACT_DELAY_S`] after the
    /// trip: the valve is commanded fully open then, whatever the law sees.
    Contact,
}

impl TripSignal {
    /// The field of the ESD case in this situation.
    pub fn case(self) -> Case {
        match self {
            TripSignal::SpeedDecay => ESD_CASE,
            TripSignal::Contact => Case {
                name: "ESD rundown, trip contact wired",
                scenario: "emergency-shutdown",
                fault: FieldFault::EsdContact {
                    delay_s: ESD_CONTACT_DELAY_S,
                },
            },
        }
    }
}

/// Resolution of the stroke-time search, s: the stroke named is the longest multiple of it
/// that holds (a valve's stroke is specified no finer, and a coarser grid keeps the named
/// stroke from moving with every retune of the law).
pub const ESD_STROKE_RESOLUTION_S: f64 = 0.05;
/// Shortest stroke time the search tries, s (a valve's positioner lag is of this order;
/// nothing faster is a recycle valve).
pub const ESD_STROKE_MIN_S: f64 = 0.05;
/// Latency assumed from the drive trip to the controller acting on a wired trip contact, s:
/// one 1 kHz control cycle (a contact read every cycle and the command written at once, as
/// in-process). A polled bus adds its poll and write periods (Modbus at 50 Hz: up to 20 ms
/// each way); [`EsdStroke::contact_latency_budget_s`] says how much the machine tolerates.
pub const ESD_CONTACT_DELAY_S: f64 = 0.001;
/// Longest contact latency the budget search tries, s (1 ms grid).
pub const ESD_CONTACT_LATENCY_MAX_S: f64 = 0.05;

/// Whether an ESD run holds: no surge cycle, and the true operating point never left of the
/// surge line (a brief excursion that the detector does not count as a cycle is no margin
/// to specify a valve on).
pub fn esd_holds(r: &CaseResult) -> bool {
    r.surge_cycles == 0 && r.min_margin_during.min(r.min_margin_after) >= 0.0
}

/// Whether the recycle valve's stroke suffices for an ESD rundown without surge (recycle-pi
/// with its defaults at one control-line margin), in both situations of [`TripSignal`], and
/// the longest stroke time that holds in each (bisection on the stroke, resolution
/// [`ESD_STROKE_RESOLUTION_S`], from [`ESD_STROKE_MIN_S`] to the plant's own stroke).
#[derive(Debug, Clone, PartialEq)]
pub struct EsdStroke {
    /// Plant name.
    pub plant: String,
    /// Control-line margin, %.
    pub margin_pct: f64,
    /// The plant's recycle-valve stroke time, s.
    pub stroke_time_s: f64,
    /// Surge cycles of the ESD with that stroke, trip seen in the speed decay only.
    pub surge_cycles: u32,
    /// Surge cycles of the ESD with that stroke and the trip contact wired.
    pub contact_surge_cycles: u32,
    /// With the plant's stroke, speed decay only: time from the drive trip to the first
    /// instant left of the surge line, s (NaN: never).
    pub surge_after_s: f64,
    /// Longest stroke that holds the ESD with zero surge cycles from the speed decay alone,
    /// s (the plant's own if it does; None: not even [`ESD_STROKE_MIN_S`]).
    pub longest_speed_decay_s: Option<f64>,
    /// Longest stroke that holds it with the trip contact wired, s (None: not even
    /// [`ESD_STROKE_MIN_S`]).
    pub longest_contact_s: Option<f64>,
    /// When the speed decay alone does not hold with any stroke: the longest latency from
    /// the drive trip to the wired contact's open command, on a 1 ms grid up to
    /// [`ESD_CONTACT_LATENCY_MAX_S`], with which the fastest valve ([`ESD_STROKE_MIN_S`])
    /// holds, s (None: not searched, or not even 1 ms).
    pub contact_latency_budget_s: Option<f64>,
}

impl EsdStroke {
    /// Whether the plant's own stroke holds the ESD from the speed decay alone.
    pub fn holds_own(&self) -> bool {
        self.longest_speed_decay_s == Some(self.stroke_time_s)
    }

    /// What the check recommends when the plant's stroke does not hold from the speed decay
    /// alone: the stroke time, and whether the trip contact must be wired for it (None:
    /// nothing needed, or no stroke holds even with the contact).
    pub fn recommended(&self) -> Option<(f64, TripSignal)> {
        if self.holds_own() {
            return None;
        }
        match (self.longest_speed_decay_s, self.longest_contact_s) {
            (Some(t), _) => Some((t, TripSignal::SpeedDecay)),
            (None, Some(t)) => Some((t, TripSignal::Contact)),
            (None, None) => None,
        }
    }
}

/// Check the ESD stroke of every recycle plant at every margin of the matrix.
pub fn esd_strokes(plants: &[PlantCase], config_dir: &Path) -> Result<Vec<EsdStroke>, SimError> {
    let path = config_dir.join("scenarios").join("emergency_shutdown.toml");
    let sc = Scenario::load(&path).map_err(|e| SimError::Scenario {
        scenario: "emergency-shutdown".into(),
        message: e.to_string(),
    })?;
    let mut out = Vec::new();
    for p in plants
        .iter()
        .filter(|p| LawId::RecyclePi.supports(p.file.model))
    {
        for m in MARGINS_PCT {
            if let Some(v) = esd_stroke(p, &sc, m)? {
                out.push(v);
            }
        }
    }
    Ok(out)
}

/// The plant with another recycle-valve stroke time, s.
pub fn with_stroke(p: &PlantCase, stroke_time_s: f64) -> PlantCase {
    let mut v = p.clone();
    if let Some(rs) = v.file.recycle_system.as_mut() {
        rs.recycle_valve.stroke_time_s = stroke_time_s;
    }
    v
}

/// The ESD rundown (scenario `sc`) of plant `p`, recycle-pi with its defaults at
/// `margin_pct`, with the trip seen as `trip` says.
pub fn esd_run(
    p: &PlantCase,
    sc: &Scenario,
    margin_pct: f64,
    trip: TripSignal,
) -> Result<CaseResult, SimError> {
    run_case(p, sc, &trip.case(), LawId::RecyclePi, margin_pct)
}

/// The longest stroke time, on the [`ESD_STROKE_RESOLUTION_S`] grid between
/// [`ESD_STROKE_MIN_S`] and `up_to_s`, with which `p` holds the ESD without a surge cycle
/// and never left of the surge line ([`esd_holds`]; bisection: a slower valve is assumed to
/// do no better, which a scan in 10 ms steps bore out on the shipped plants); None if not
/// even the shortest does. `own_holds`: the result at
/// `up_to_s`, if already known.
fn longest_holding_stroke(
    p: &PlantCase,
    sc: &Scenario,
    margin_pct: f64,
    trip: TripSignal,
    up_to_s: f64,
    own_holds: bool,
) -> Result<Option<f64>, SimError> {
    if own_holds {
        return Ok(Some(up_to_s));
    }
    // grid point k is k / steps_per_s seconds (a division: 0.3, not 0.30000000000000004)
    let steps_per_s = (1.0 / ESD_STROKE_RESOLUTION_S).round();
    let at = |k: u32| f64::from(k) / steps_per_s;
    let holds = |k: u32| -> Result<bool, SimError> {
        let v = with_stroke(p, at(k));
        Ok(esd_holds(&esd_run(&v, sc, margin_pct, trip)?))
    };
    let mut lo = (ESD_STROKE_MIN_S * steps_per_s).round() as u32;
    // the largest grid point below the plant's own stroke (which fails)
    let mut hi = ((up_to_s * steps_per_s - 1e-9).ceil() as u32).saturating_sub(1);
    if hi <= lo || !holds(lo)? {
        return Ok(None);
    }
    if holds(hi)? {
        return Ok(Some(at(hi)));
    }
    // invariant: lo holds, hi does not
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if holds(mid)? {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(Some(at(lo)))
}

/// The ESD stroke verdict of one plant (None: no recycle valve) under the scenario `sc` (a
/// drive trip), recycle-pi with its defaults at `margin_pct`, in both situations of
/// [`TripSignal`].
pub fn esd_stroke(
    p: &PlantCase,
    sc: &Scenario,
    margin_pct: f64,
) -> Result<Option<EsdStroke>, SimError> {
    let Some(rs) = p.file.recycle_system else {
        return Ok(None);
    };
    let stroke = rs.recycle_valve.stroke_time_s;
    let own = esd_run(p, sc, margin_pct, TripSignal::SpeedDecay)?;
    let own_contact = esd_run(p, sc, margin_pct, TripSignal::Contact)?;
    let longest_speed_decay_s = longest_holding_stroke(
        p,
        sc,
        margin_pct,
        TripSignal::SpeedDecay,
        stroke,
        esd_holds(&own),
    )?;
    let longest_contact_s = longest_holding_stroke(
        p,
        sc,
        margin_pct,
        TripSignal::Contact,
        stroke,
        esd_holds(&own_contact),
    )?;
    let contact_latency_budget_s = if longest_speed_decay_s.is_none() {
        esd_contact_latency_s(&with_stroke(p, ESD_STROKE_MIN_S), sc, margin_pct)?
    } else {
        None
    };
    Ok(Some(EsdStroke {
        plant: p.name().to_string(),
        margin_pct,
        stroke_time_s: stroke,
        surge_cycles: own.surge_cycles,
        contact_surge_cycles: own_contact.surge_cycles,
        surge_after_s: own.surge_after_s,
        longest_speed_decay_s,
        longest_contact_s,
        contact_latency_budget_s,
    }))
}

/// The longest latency from the drive trip to the controller acting on the wired trip
/// contact with which plant `p` holds the ESD ([`esd_holds`]), on a 1 ms grid up to
/// [`ESD_CONTACT_LATENCY_MAX_S`] (None: not even 1 ms). Tells whether a polled contact
/// (Modbus at 50 Hz: up to 20 ms to read, as much to write) is fast enough.
pub fn esd_contact_latency_s(
    p: &PlantCase,
    sc: &Scenario,
    margin_pct: f64,
) -> Result<Option<f64>, SimError> {
    let mut best = None;
    let max_ms = (ESD_CONTACT_LATENCY_MAX_S * 1e3).round() as u32;
    for ms in 1..=max_ms {
        let case = Case {
            name: "ESD rundown, trip contact wired",
            scenario: "emergency-shutdown",
            fault: FieldFault::EsdContact {
                delay_s: f64::from(ms) * 1e-3,
            },
        };
        if !esd_holds(&run_case(p, sc, &case, LawId::RecyclePi, margin_pct)?) {
            break;
        }
        best = Some(f64::from(ms) * 1e-3);
    }
    Ok(best)
}

/// The built-in emergency-shutdown scenario (a copy of `config/scenarios/emergency_shutdown.toml`
/// compiled in, so that the machine check needs no config directory).
pub fn builtin_esd_scenario() -> Result<Scenario, SimError> {
    const TEXT: &str = include_str!("../../../config/scenarios/emergency_shutdown.toml");
    let e = |m: String| SimError::Scenario {
        scenario: "emergency-shutdown".into(),
        message: m,
    };
    let file = toml::from_str(TEXT).map_err(|x| e(x.to_string()))?;
    Scenario::from_file(file, Path::new("emergency_shutdown.toml"), TEXT)
        .map_err(|x| e(x.to_string()))
}

fn esd_verdict(r: &EsdStroke) -> String {
    let wired = format!(
        "with the drive's trip contact wired as esd_input (acted on within {:.0} ms of the trip)",
        1e3 * ESD_CONTACT_DELAY_S
    );
    let contact = match r.longest_contact_s {
        Some(t) if t == r.stroke_time_s => format!("{wired} it holds"),
        Some(t) => format!(
            "{wired} it still surges ({}), and a ≤ {} s stroke holds",
            cycles(r.contact_surge_cycles),
            secs(t)
        ),
        None => format!(
            "{wired} it still surges ({}), and no stroke down to {} s holds",
            cycles(r.contact_surge_cycles),
            secs(ESD_STROKE_MIN_S)
        ),
    };
    let crossed = if r.surge_after_s.is_finite() {
        format!(
            "the machine crosses its surge line {:.0} ms after the drive trip",
            1e3 * r.surge_after_s
        )
    } else {
        "the machine comes too close to its surge line".to_string()
    };
    if r.holds_own() {
        return format!("suffices from the speed decay alone (no surge cycle); {contact}");
    }
    let own = format!(
        "is too slow ({}{}, the trip seen in the speed decay alone)",
        cycles(r.surge_cycles),
        if r.surge_cycles == 0 {
            ", but left of the surge line"
        } else {
            ""
        }
    );
    match (r.longest_speed_decay_s, r.longest_contact_s) {
        (Some(t), _) => format!(
            "{own}; a ≤ {} s stroke holds the ESD without surge from the speed decay alone; \
             {contact}",
            secs(t)
        ),
        (None, Some(t)) => format!(
            "{own}, and no stroke down to {} s holds without the trip contact: {crossed}, \
             before the speed decay identifies the trip; a ≤ {} s stroke holds it {wired}{}",
            secs(ESD_STROKE_MIN_S),
            secs(t),
            match r.contact_latency_budget_s {
                Some(l) => format!(
                    "; the open command must reach the valve within {:.0} ms of the trip \
                     however fast the valve (a 50 Hz Modbus poll and write take up to 40 ms)",
                    1e3 * l
                ),
                None => String::new(),
            }
        ),
        (None, None) => format!(
            "{own}, and no stroke down to {} s holds, not even with the drive's trip contact \
             wired as esd_input: {crossed}; it needs a wider control margin",
            secs(ESD_STROKE_MIN_S),
        ),
    }
}

/// The machine check's warning on the ESD stroke of a simulated plant, with recycle-pi at a
/// `margin_pct` control line: None if the valve's stroke holds an ESD (drive trip) without
/// surge from the speed decay alone (or the plant has no recycle valve), else one line naming
/// the longest stroke time that would, and whether the drive's trip contact must be wired
/// as `esd_input` for it.
pub fn esd_stroke_warning(p: &PlantCase, margin_pct: f64) -> Result<Option<String>, SimError> {
    esd_stroke_warning_as_wired(p, margin_pct, None)
}

/// [`esd_stroke_warning`] for a controller whose configuration binds the trip contact
/// (`esd_input` in the signal map) with a worst-case latency `contact_latency_s` from the
/// drive trip to the open command at the valve (read period + control cycle + write
/// period): the warning then also says whether the plant's own stroke holds the ESD with the
/// contact as configured. None: the contact is not bound (the warning is
/// [`esd_stroke_warning`]'s).
pub fn esd_stroke_warning_as_wired(
    p: &PlantCase,
    margin_pct: f64,
    contact_latency_s: Option<f64>,
) -> Result<Option<String>, SimError> {
    let sc = builtin_esd_scenario()?;
    let Some(v) = esd_stroke(p, &sc, margin_pct)? else {
        return Ok(None);
    };
    if v.holds_own() {
        return Ok(None);
    }
    let configured = match contact_latency_s {
        Some(d) => {
            let case = Case {
                name: "ESD rundown, trip contact as configured",
                scenario: "emergency-shutdown",
                fault: FieldFault::EsdContact { delay_s: d },
            };
            let r = run_case(p, &sc, &case, LawId::RecyclePi, margin_pct)?;
            format!(
                ". As configured, esd_input is bound and acted on up to {:.0} ms after the trip: \
                 with it the {} s stroke {}",
                1e3 * d,
                secs(v.stroke_time_s),
                if esd_holds(&r) {
                    "holds the ESD".to_string()
                } else {
                    format!("does not hold the ESD ({})", failure(&r))
                }
            )
        }
        None => String::new(),
    };
    Ok(Some(format!(
        "recycle_system.recycle_valve.stroke_time_s: in an emergency shutdown (drive trip, simulated, recycle-pi at a {margin_pct} % margin) the recycle valve's {} s stroke {}{configured}",
        secs(v.stroke_time_s),
        esd_verdict(&v)
    )))
}

/// The ESD verdicts as Markdown lines.
pub fn esd_markdown(rows: &[EsdStroke]) -> String {
    let mut s = String::new();
    for r in rows {
        let _ = writeln!(
            s,
            "- {} at {:.0} %: the recycle valve's {} s stroke {}.",
            r.plant,
            r.margin_pct,
            secs(r.stroke_time_s),
            esd_verdict(r)
        );
    }
    s
}

/// The ESD rundown on the plant variants in `config_dir/plants/variants` (the shipped plants
/// with a recycle-valve stroke the ESD check names), recycle-pi at every margin of the
/// matrix, in both situations of [`TripSignal`], as Markdown lines. Whether the trip contact
/// is wired is the controller's configuration (the signal map binds `esd_input`), not the
/// plant's: every simulated plant closes its contact when its drive trips.
pub fn esd_variants_markdown(config_dir: &Path) -> Result<String, SimError> {
    let sc = builtin_esd_scenario()?;
    let mut s = String::new();
    for (f, p) in esd_variants(config_dir)? {
        let Some(rs) = p.file.recycle_system else {
            continue;
        };
        let mut parts = Vec::new();
        for m in MARGINS_PCT {
            for (trip, what) in [
                (TripSignal::SpeedDecay, "speed decay alone"),
                (TripSignal::Contact, "trip contact wired"),
            ] {
                let r = esd_run(&p, &sc, m, trip)?;
                parts.push(format!(
                    "at {m:.0} % with the {what} {} (closest approach {})",
                    cycles(r.surge_cycles),
                    pct(r.min_margin_during.min(r.min_margin_after))
                ));
            }
        }
        let _ = writeln!(
            s,
            "- variant {} (`plants/variants/{}`, recycle valve stroke {} s): {}.",
            p.name(),
            f.file_name()
                .map_or(String::new(), |n| n.to_string_lossy().into_owned()),
            secs(rs.recycle_valve.stroke_time_s),
            parts.join(", ")
        );
    }
    Ok(s)
}

/// The plant variants in `config_dir/plants/variants`, sorted by file name (none if the
/// folder is absent).
pub fn esd_variants(config_dir: &Path) -> Result<Vec<(std::path::PathBuf, PlantCase)>, SimError> {
    let dir = config_dir.join("plants").join("variants");
    let mut files: Vec<_> = match std::fs::read_dir(&dir) {
        Ok(rd) => rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "toml"))
            .collect(),
        Err(_) => return Ok(Vec::new()),
    };
    files.sort();
    files
        .into_iter()
        .map(|f| {
            let p = PlantCase::load(&f).map_err(|e| SimError::Scenario {
                scenario: "emergency-shutdown".into(),
                message: e.to_string(),
            })?;
            Ok((f, p))
        })
        .collect()
}
