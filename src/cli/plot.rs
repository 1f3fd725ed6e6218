//! `antisurge plot TRACE.csv`: the map and time-series pictures `sim` draws, for a trace
//! written by `run` (in-process plant), `plant` or a HIL run (same `trace.csv` columns).

use super::locate;
use antisurge::sim::trace::{TraceRow, COLUMNS};
use anyhow::{anyhow, Context, Result};
use clap::Args;
use std::path::PathBuf;

/// Arguments of `antisurge plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// The trace (`trace.csv` of `sim`, `run --out`, `plant` or HIL).
    pub trace: PathBuf,
    /// The plant whose map to draw on (name in config/plants or a file).
    #[arg(long, default_value = "kvangardsnes2009_recycle")]
    pub plant: String,
    /// Where to write map.svg and timeseries.svg (default: beside the trace).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Directory holding plants/ (default: the usual config lookup).
    #[arg(long)]
    pub config_dir: Option<PathBuf>,
}

fn field<'a>(r: &'a mut TraceRow, name: &str) -> Option<&'a mut f64> {
    Some(match name {
        "t_s" => &mut r.t_s,
        "m_kg_s" => &mut r.m_kg_s,
        "flow_map" => &mut r.flow_map,
        "p_suction_pa" => &mut r.p_suction_pa,
        "p_discharge_pa" => &mut r.p_discharge_pa,
        "pressure_ratio" => &mut r.pressure_ratio,
        "omega_rad_s" => &mut r.omega_rad_s,
        "recycle_flow_kg_s" => &mut r.recycle_flow_kg_s,
        "throttle_flow_kg_s" => &mut r.throttle_flow_kg_s,
        "feed_flow_kg_s" => &mut r.feed_flow_kg_s,
        "recycle_valve_position" => &mut r.recycle_valve_position,
        "throttle_position" => &mut r.throttle_position,
        "drive_torque_nm" => &mut r.drive_torque_nm,
        "load_torque_nm" => &mut r.load_torque_nm,
        "ccv" => &mut r.ccv,
        "tip_clearance_m" => &mut r.tip_clearance_m,
        "thrust_force_n" => &mut r.thrust_force_n,
        "thrust_slew_n_s" => &mut r.thrust_slew_n_s,
        "surge_margin" => &mut r.surge_margin,
        "meas_p_suction_pa" => &mut r.meas_p_suction_pa,
        "meas_p_discharge_pa" => &mut r.meas_p_discharge_pa,
        "meas_omega_rad_s" => &mut r.meas_omega_rad_s,
        "meas_orifice_dp_pa" => &mut r.meas_orifice_dp_pa,
        "meas_m_kg_s" => &mut r.meas_m_kg_s,
        "est_m_kg_s" => &mut r.est_m_kg_s,
        "used_m_kg_s" => &mut r.used_m_kg_s,
        "cmd_drive_torque_nm" => &mut r.cmd_drive_torque_nm,
        "cmd_recycle_valve" => &mut r.cmd_recycle_valve,
        "cmd_ccv" => &mut r.cmd_ccv,
        "cmd_throttle" => &mut r.cmd_throttle,
        "cmd_tip_clearance_m" => &mut r.cmd_tip_clearance_m,
        "mode" => &mut r.mode,
        "law_diagnostic" => &mut r.law_diagnostic,
        _ => return None,
    })
}

/// Read a trace CSV (empty fields are NaN; unknown columns are ignored, missing ones NaN).
pub fn read_trace(path: &std::path::Path) -> Result<Vec<TraceRow>> {
    let mut rd =
        csv::Reader::from_path(path).with_context(|| format!("reading {}", path.display()))?;
    let header: Vec<String> = rd.headers()?.iter().map(str::to_string).collect();
    if !header.iter().any(|h| h == "t_s") || !header.iter().any(|h| h == "flow_map") {
        return Err(anyhow!(
            "{}: not a trace (expected the columns of trace.csv: {} …)",
            path.display(),
            COLUMNS[..4].join(", ")
        ));
    }
    let mut rows = Vec::new();
    for (n, rec) in rd.records().enumerate() {
        let rec = rec.with_context(|| format!("{}: line {}", path.display(), n + 2))?;
        let mut row = TraceRow::default();
        for name in COLUMNS {
            if let Some(f) = field(&mut row, name) {
                *f = f64::NAN;
            }
        }
        for (name, v) in header.iter().zip(rec.iter()) {
            if let Some(f) = field(&mut row, name) {
                if !v.is_empty() {
                    *f = v.parse().with_context(|| {
                        format!("{}: line {}, column {name}: `{v}`", path.display(), n + 2)
                    })?;
                }
            }
        }
        rows.push(row);
    }
    Ok(rows)
}

/// Draw the pictures of a trace.
pub fn run(args: &PlotArgs) -> Result<()> {
    let trace = read_trace(&args.trace)?;
    let cfg = locate::config_dir(args.config_dir.as_deref());
    let plant_path = locate::resolve(&cfg, "plants", &args.plant)?;
    let desc = antisurge::sim::case::PlantCase::load(&plant_path).map_err(|e| anyhow!("{e}"))?;
    let dir = args.out.clone().unwrap_or_else(|| {
        args.trace
            .parent()
            .map(|p| p.to_path_buf())
            .unwrap_or_default()
    });
    std::fs::create_dir_all(&dir)?;
    let title = format!(
        "{} · {}",
        desc.name(),
        args.trace.file_name().unwrap_or_default().to_string_lossy()
    );
    for f in super::pictures::draw_trace(&dir, &desc, &trace, &title, &[])? {
        println!("{}", f.display());
    }
    Ok(())
}
