//! Tests of the pictures on a synthetic cubic map and a synthetic deep-surge trace.

use super::map::{N_SPEED_LINES, SPEED_LINE_COLOR};
use super::*;
use crate::physics::characteristic::MooreGreitzerCubic;
use crate::physics::compressor_map::{CompressorMap, FlowCoordinate};
use crate::sim::trace::TraceRow;
use std::path::Path;

fn cubic_map() -> CompressorMap {
    CompressorMap::cubic(
        MooreGreitzerCubic {
            psi_c0: 1.5,
            semi_height: 0.4,
            semi_width: 5.0,
            omega_ref: 2000.0,
        },
        FlowCoordinate::MassKgS,
        1400.0,
        2600.0,
    )
    .expect("map")
}

/// 10 s at 5 ms: steady near the surge line, then deep surge with flow reversal. Torque and
/// tip clearance are NaN unless `with_torque`.
fn trace(with_torque: bool) -> Vec<TraceRow> {
    let nan = f64::NAN;
    (0..2000)
        .map(|k| {
            let t = k as f64 * 0.005;
            let surge = t > 4.0;
            let m = if surge {
                6.0 + 9.0 * (2.0 * std::f64::consts::PI * 1.5 * t).sin()
            } else {
                14.0 - t
            };
            let ratio = if surge {
                2.0 + 0.15 * (2.0 * std::f64::consts::PI * 1.5 * t).cos()
            } else {
                1.9 + 0.08 * t
            };
            TraceRow {
                t_s: t,
                m_kg_s: m,
                flow_map: m,
                p_suction_pa: 101_325.0,
                p_discharge_pa: 101_325.0 * ratio,
                pressure_ratio: ratio,
                omega_rad_s: 2000.0 + 5.0 * (t * 3.0).sin(),
                recycle_valve_position: (t / 10.0).min(1.0),
                cmd_recycle_valve: (t / 8.0).min(1.0),
                throttle_position: 0.5,
                cmd_throttle: 0.5,
                drive_torque_nm: if with_torque { 900.0 + 10.0 * t } else { nan },
                cmd_drive_torque_nm: if with_torque { 950.0 } else { nan },
                load_torque_nm: nan,
                ccv: nan,
                cmd_ccv: nan,
                tip_clearance_m: nan,
                cmd_tip_clearance_m: nan,
                surge_margin: (m - 10.0) / 10.0,
                meas_m_kg_s: m + 0.3 * (t * 97.0).sin(),
                est_m_kg_s: m + 0.1,
                used_m_kg_s: m,
                ..Default::default()
            }
        })
        .collect()
}

fn read_svg(path: &Path) -> String {
    let s = std::fs::read_to_string(path).expect("svg written");
    assert!(
        s.starts_with("<svg"),
        "not an SVG: {}",
        &s[..s.len().min(80)]
    );
    assert!(s.trim_end().ends_with("</svg>"), "SVG not closed");
    assert_eq!(
        s.matches("<svg").count(),
        s.matches("</svg>").count(),
        "unbalanced svg tags"
    );
    s
}

/// The contents of every `<text>` element, trimmed.
fn texts(svg: &str) -> Vec<String> {
    svg.split("<text")
        .skip(1)
        .filter_map(|t| {
            let body = &t[t.find('>')? + 1..];
            Some(body[..body.find("</text>")?].trim().to_string())
        })
        .collect()
}

/// Whether some `<text>` element reads exactly `label`.
fn has_text(svg: &str, label: &str) -> bool {
    texts(svg).iter().any(|t| t == label)
}

/// Speed-line paths: polylines stroked in the speed-line colour.
fn speed_line_paths(svg: &str) -> usize {
    let stroke = format!(
        "stroke=\"#{:02X}{:02X}{:02X}\"",
        SPEED_LINE_COLOR.0, SPEED_LINE_COLOR.1, SPEED_LINE_COLOR.2
    );
    svg.lines()
        .filter(|l| l.contains("<polyline") && l.contains(&stroke))
        .count()
}

#[test]
fn map_has_axes_speed_lines_legend_and_scl() {
    let dir = tempfile::tempdir().expect("tempdir");
    let map = cubic_map();
    let path = dir.path().join("map.svg");
    // surge control line 10 % right of the surge line
    let sl = map.surge_line;
    let scl = move |r: f64| 1.1 * sl.flow_at_ratio(r);
    map_svg(&path, &map, &trace(true), Some(&scl), "synthetic map").expect("map");
    let svg = read_svg(&path);
    assert!(has_text(&svg, "mass flow (kg/s)"), "x axis title with unit");
    assert!(has_text(&svg, "pressure ratio p_d/p_s (–)"), "y axis title");
    assert!(has_text(&svg, "synthetic map"), "title");
    assert!(has_text(&svg, "surge line"), "surge line legend");
    assert!(has_text(&svg, "surge control line"), "scl legend");
    assert!(has_text(&svg, "operating point"));
    assert!(has_text(&svg, "start (t = 0.00 s)"));
    assert!(texts(&svg).iter().any(|t| t.starts_with("end (t = ")));
    // the run's speed is inside the map's range: exactly the regular speed lines
    assert_eq!(speed_line_paths(&svg), N_SPEED_LINES);
    // labelled in rad/s and rpm: 1400 rad/s = 13369 rpm, 2600 rad/s = 24828 rpm
    assert!(
        has_text(&svg, "1400 rad/s (13369 rpm)"),
        "lowest speed label"
    );
    assert!(
        has_text(&svg, "2600 rad/s (24828 rpm)"),
        "highest speed label"
    );
    let labels = texts(&svg)
        .iter()
        .filter(|t| t.contains(" rad/s ("))
        .count();
    assert_eq!(labels, N_SPEED_LINES);
}

#[test]
fn map_without_scl_has_no_scl_legend_and_adds_run_speed_outside_range() {
    let dir = tempfile::tempdir().expect("tempdir");
    let map = cubic_map();
    let path = dir.path().join("map.svg");
    let mut rows = trace(false);
    for r in &mut rows {
        r.omega_rad_s = 3000.0;
    }
    map_svg(&path, &map, &rows, None, "no scl").expect("map");
    let svg = read_svg(&path);
    assert!(has_text(&svg, "surge line"));
    assert!(!svg.contains("surge control line"));
    assert_eq!(speed_line_paths(&svg), N_SPEED_LINES + 1);
    assert!(has_text(&svg, "3000 rad/s (28648 rpm), run"));
}

#[test]
fn map_volumetric_axis_and_all_nan_trajectory_draws_map_with_note() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut map = cubic_map();
    map.flow_coordinate = FlowCoordinate::InletVolumeM3S;
    let path = dir.path().join("map.svg");
    let mut rows = trace(false);
    for r in &mut rows {
        r.flow_map = f64::NAN;
    }
    map_svg(&path, &map, &rows, None, "nan").expect("map");
    let svg = read_svg(&path);
    assert!(has_text(&svg, "inlet volume flow (m³/s)"));
    assert!(svg.contains("no finite operating points"));
    assert!(!has_text(&svg, "operating point"));
    assert_eq!(speed_line_paths(&svg), N_SPEED_LINES);
}

#[test]
fn timeseries_has_panels_units_and_legends() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("ts.svg");
    timeseries_svg(&path, &trace(true), "synthetic run").expect("timeseries");
    let svg = read_svg(&path);
    for label in [
        "time (s)",
        "mass flow (kg/s)",
        "pressure (kPa)",
        "shaft speed (rad/s)",
        "valve opening (–)",
        "torque (N·m)",
        "surge margin (%)",
        "true",
        "measured",
        "estimate",
        "suction",
        "discharge",
        "recycle valve position",
        "recycle valve command",
        "drive delivered",
        "drive command",
        "surge line (0 %)",
    ] {
        assert!(has_text(&svg, label), "missing {label:?}");
    }
    // all-NaN columns: no panel and no legend entry
    assert!(!svg.contains("tip clearance"));
    assert!(!svg.contains("close-coupled valve"));
    assert!(!has_text(&svg, "load"));
    // the time axis is titled once, on the bottom panel
    assert_eq!(texts(&svg).iter().filter(|t| *t == "time (s)").count(), 1);
}

#[test]
fn timeseries_without_torque_has_no_torque_panel() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("ts.svg");
    timeseries_svg(&path, &trace(false), "no torque").expect("timeseries");
    let svg = read_svg(&path);
    assert!(!svg.contains("torque (N·m)"));
    assert!(!svg.contains("drive"));
    assert!(has_text(&svg, "mass flow (kg/s)"));
}

#[test]
fn pressure_unit_follows_magnitude() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("ts.svg");
    let mut rows = trace(false);
    for r in &mut rows {
        r.p_suction_pa = 2.0e6;
        r.p_discharge_pa = 4.0e6;
    }
    timeseries_svg(&path, &rows, "high pressure").expect("timeseries");
    assert!(has_text(&read_svg(&path), "pressure (MPa)"));
}

#[test]
fn empty_trace_is_an_error_naming_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let map = cubic_map();
    let path = dir.path().join("empty-map.svg");
    let e = map_svg(&path, &map, &[], None, "empty").unwrap_err();
    assert!(matches!(e, PlotError::NoData { .. }), "{e:?}");
    assert!(e.to_string().contains("empty-map.svg"), "{e}");
    assert!(!path.exists());
    let path = dir.path().join("empty-ts.svg");
    let e = timeseries_svg(&path, &[], "empty").unwrap_err();
    assert!(matches!(e, PlotError::NoData { .. }), "{e:?}");
    assert!(e.to_string().contains("empty-ts.svg"), "{e}");
}

#[test]
fn all_nan_trace_and_single_row_do_not_panic() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("nan.svg");
    let rows: Vec<TraceRow> = (0..10)
        .map(|k| {
            let mut r = TraceRow::default();
            for v in [
                &mut r.m_kg_s,
                &mut r.flow_map,
                &mut r.p_suction_pa,
                &mut r.p_discharge_pa,
                &mut r.pressure_ratio,
                &mut r.omega_rad_s,
                &mut r.recycle_valve_position,
                &mut r.throttle_position,
                &mut r.drive_torque_nm,
                &mut r.load_torque_nm,
                &mut r.ccv,
                &mut r.tip_clearance_m,
                &mut r.surge_margin,
                &mut r.meas_m_kg_s,
                &mut r.est_m_kg_s,
                &mut r.cmd_drive_torque_nm,
                &mut r.cmd_recycle_valve,
                &mut r.cmd_ccv,
                &mut r.cmd_throttle,
                &mut r.cmd_tip_clearance_m,
            ] {
                *v = f64::NAN;
            }
            r.t_s = k as f64 * 0.005;
            r
        })
        .collect();
    let e = timeseries_svg(&path, &rows, "all nan").unwrap_err();
    assert!(matches!(e, PlotError::NoData { .. }), "{e:?}");
    // one row: drawn without panicking (a single point makes no line)
    let one = [TraceRow {
        m_kg_s: 5.0,
        ..rows[0]
    }];
    timeseries_svg(&path, &one, "one row").expect("one row");
    read_svg(&path);
    map_svg(&dir.path().join("m.svg"), &cubic_map(), &rows, None, "nan").expect("map");
}

#[test]
fn unwritable_path_is_a_write_error_naming_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("missing-dir").join("ts.svg");
    let e = timeseries_svg(&path, &trace(false), "x").unwrap_err();
    assert!(matches!(e, PlotError::Write { .. }), "{e:?}");
    assert!(e.to_string().contains("ts.svg"), "{e}");
}

/// Writes the pictures of the synthetic run for looking at them:
/// `ANTISURGE_PLOT_DIR=/tmp/p cargo test --lib plot::tests::write_examples -- --ignored`.
#[test]
#[ignore = "writes example pictures for visual inspection"]
fn write_examples() {
    let dir = std::path::PathBuf::from(
        std::env::var("ANTISURGE_PLOT_DIR").unwrap_or_else(|_| "target/plot-examples".into()),
    );
    std::fs::create_dir_all(&dir).expect("dir");
    let map = cubic_map();
    let sl = map.surge_line;
    let scl = move |r: f64| 1.1 * sl.flow_at_ratio(r);
    map_svg(
        &dir.join("map.svg"),
        &map,
        &trace(true),
        Some(&scl),
        "synthetic · deep surge",
    )
    .expect("map");
    timeseries_svg(
        &dir.join("timeseries.svg"),
        &trace(true),
        "synthetic · deep surge",
    )
    .expect("timeseries");
    // every benchmark plant through the throttle closure, no law
    let scenario =
        crate::scenario::Scenario::load(Path::new("config/scenarios/throttle_closure.toml"))
            .expect("scenario");
    for entry in std::fs::read_dir("config/plants").expect("plants") {
        let p = entry.expect("entry").path();
        let desc = crate::plant::file::PlantDescription::load(&p).expect("plant");
        let res = crate::sim::runner::run(
            &desc,
            &scenario,
            crate::sim::runner::SimOptions::default(),
            &mut |_| {},
        )
        .expect("run");
        let name = p.file_stem().unwrap().to_string_lossy().to_string();
        let title = title_from_summary(&res.summary);
        let sl = desc.map.surge_line;
        let scl = move |r: f64| 1.1 * sl.flow_at_ratio(r);
        map_svg(
            &dir.join(format!("{name}-map.svg")),
            &desc.map,
            &res.trace,
            Some(&scl),
            &title,
        )
        .expect("map");
        timeseries_svg(&dir.join(format!("{name}-ts.svg")), &res.trace, &title).expect("ts");
    }
}
