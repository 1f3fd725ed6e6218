//! Tests of the pictures on a synthetic cubic map and a synthetic deep-surge trace.

use super::map::{N_SPEED_LINES, RUN_SPEED_COLOR, SPEED_LINE_COLOR, THROUGHPUT_COLOR};
use super::timeseries::{FAIL_SAFE_COLOR, MANUAL_COLOR, MARGIN_LIMIT_PCT, OFF_SCALE_COLOR};
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
                throttle_flow_kg_s: m,
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

fn hex(c: plotters::style::RGBColor) -> String {
    format!("#{:02X}{:02X}{:02X}", c.0, c.1, c.2)
}

/// Polylines stroked in colour `c`, legend swatches (two points) left out.
fn paths_of(svg: &str, c: plotters::style::RGBColor) -> usize {
    polylines_of(svg, c).len()
}

/// Speed-line paths: polylines stroked in the speed-line colour.
fn speed_line_paths(svg: &str) -> usize {
    paths_of(svg, SPEED_LINE_COLOR)
}

/// The value of attribute `name` in one SVG element's text.
fn attr<'a>(element: &'a str, name: &str) -> Option<&'a str> {
    let k = element.find(&format!(" {name}=\""))? + name.len() + 3;
    Some(&element[k..k + element[k..].find('"')?])
}

/// Points of the polylines stroked in `c`, in pixels, in drawing order.
fn polylines_of(svg: &str, c: plotters::style::RGBColor) -> Vec<Vec<(f64, f64)>> {
    let stroke = format!("stroke=\"{}\"", hex(c));
    svg.lines()
        .filter(|l| l.contains("<polyline") && l.contains(&stroke))
        .map(|l| {
            attr(l, "points")
                .unwrap_or("")
                .split_whitespace()
                .filter_map(|p| {
                    let (x, y) = p.split_once(',')?;
                    Some((x.parse().ok()?, y.parse().ok()?))
                })
                .collect::<Vec<(f64, f64)>>()
        })
        .filter(|p| p.len() > 2)
        .collect()
}

/// `<text>` elements whose content contains `needle`: (x, y, content).
fn texts_at(svg: &str, needle: &str) -> Vec<(f64, f64, String)> {
    svg.split("<text")
        .skip(1)
        .filter_map(|t| {
            let open = &t[..t.find('>')?];
            let body = &t[t.find('>')? + 1..];
            let body = body[..body.find("</text>")?].trim().to_string();
            if !body.contains(needle) {
                return None;
            }
            Some((
                attr(open, "x")?.parse().ok()?,
                attr(open, "y")?.parse().ok()?,
                body,
            ))
        })
        .collect()
}

/// Distance from a point to a polyline, pixels.
fn distance_to(p: (f64, f64), line: &[(f64, f64)]) -> f64 {
    line.windows(2)
        .map(|w| {
            let (a, b) = (w[0], w[1]);
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            let l2 = dx * dx + dy * dy;
            let t = if l2 > 0.0 {
                (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (p.0 - a.0 - t * dx).hypot(p.1 - a.1 - t * dy)
        })
        .fold(f64::INFINITY, f64::min)
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
    // the run's speed (2000 rad/s, steady) is a line of its own; no regular line is near it
    assert_eq!(speed_line_paths(&svg), N_SPEED_LINES);
    assert_eq!(paths_of(&svg, RUN_SPEED_COLOR), 1);
    assert!(has_text(&svg, "running speed"), "running speed legend");
    assert!(has_text(&svg, "2000 rad/s (19099 rpm), running"));
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
    assert_eq!(labels, N_SPEED_LINES + 1);
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
    assert_eq!(speed_line_paths(&svg), N_SPEED_LINES);
    assert_eq!(paths_of(&svg, RUN_SPEED_COLOR), 1);
    assert!(has_text(&svg, "3000 rad/s (28648 rpm), running"));
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
    timeseries_svg(&path, &trace(true), "synthetic run", &TimeMarks::default())
        .expect("timeseries");
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
    timeseries_svg(&path, &trace(false), "no torque", &TimeMarks::default()).expect("timeseries");
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
    timeseries_svg(&path, &rows, "high pressure", &TimeMarks::default()).expect("timeseries");
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
    let e = timeseries_svg(&path, &[], "empty", &TimeMarks::default()).unwrap_err();
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
    let e = timeseries_svg(&path, &rows, "all nan", &TimeMarks::default()).unwrap_err();
    assert!(matches!(e, PlotError::NoData { .. }), "{e:?}");
    // one row: drawn without panicking (a single point makes no line)
    let one = [TraceRow {
        m_kg_s: 5.0,
        ..rows[0]
    }];
    timeseries_svg(&path, &one, "one row", &TimeMarks::default()).expect("one row");
    read_svg(&path);
    map_svg(&dir.path().join("m.svg"), &cubic_map(), &rows, None, "nan").expect("map");
}

#[test]
fn unwritable_path_is_a_write_error_naming_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("missing-dir").join("ts.svg");
    let e = timeseries_svg(&path, &trace(false), "x", &TimeMarks::default()).unwrap_err();
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
        &TimeMarks::default(),
    )
    .expect("timeseries");
    // every benchmark plant through the throttle closure, no law
    let scenario =
        crate::scenario::Scenario::load(Path::new("config/scenarios/throttle_closure.toml"))
            .expect("scenario");
    for entry in std::fs::read_dir("config/plants").expect("plants") {
        let p = entry.expect("entry").path();
        let desc = crate::sim::case::PlantCase::load(&p).expect("plant");
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
        timeseries_svg(
            &dir.join(format!("{name}-ts.svg")),
            &res.trace,
            &title,
            &TimeMarks::default(),
        )
        .expect("ts");
    }
}

/// A crowded map: six speed lines within ±5 % of each other, a few pixels apart at their
/// peaks, and a run at one of them. Every label must be centred on its own curve: nearer to it
/// than to any other speed line.
#[test]
fn speed_labels_sit_on_their_own_curves_on_a_crowded_map() {
    let dir = tempfile::tempdir().expect("tempdir");
    let map = CompressorMap::cubic(
        MooreGreitzerCubic {
            psi_c0: 1.5,
            semi_height: 0.4,
            semi_width: 5.0,
            omega_ref: 2000.0,
        },
        FlowCoordinate::MassKgS,
        1900.0,
        2100.0,
    )
    .expect("map");
    let path = dir.path().join("crowded.svg");
    let mut rows = trace(false);
    for r in &mut rows {
        r.omega_rad_s = 2000.0;
    }
    map_svg(&path, &map, &rows, None, "crowded").expect("map");
    let svg = read_svg(&path);
    // lines and labels in the same order (by speed); the running line among them
    let regular = polylines_of(&svg, SPEED_LINE_COLOR);
    let running = polylines_of(&svg, RUN_SPEED_COLOR);
    assert_eq!(running.len(), 1, "one running-speed line");
    let mut labels = texts_at(&svg, " rad/s");
    assert_eq!(labels.len(), regular.len() + 1, "{labels:?}");
    let omega = |l: &str| -> f64 { l.split(' ').next().unwrap().parse().unwrap() };
    labels.sort_by(|a, b| omega(&a.2).total_cmp(&omega(&b.2)));
    let mut lines = regular.clone();
    let run_at = labels
        .iter()
        .position(|l| l.2.contains("running"))
        .expect("running label");
    lines.insert(run_at, running[0].clone());
    for (k, (x, y, text)) in labels.iter().enumerate() {
        let own = distance_to((*x, *y), &lines[k]);
        assert!(
            own < 2.5,
            "{text:?} at ({x}, {y}) is {own:.1} px off its curve"
        );
        for (j, other) in lines.iter().enumerate().filter(|(j, _)| *j != k) {
            let d = distance_to((*x, *y), other);
            assert!(
                d > own + 2.0,
                "{text:?} is as near line {j} ({d:.1} px) as its own"
            );
        }
    }
}

/// Near-zero and reversed flow: the margin reaches +25 000 % and −400 %. The panel stays within
/// ±100 %, marks the samples beyond, and carries the control and trip lines.
#[test]
fn margin_panel_is_bounded_with_off_scale_marks_and_the_control_and_trip_lines() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut rows = trace(false);
    for (k, r) in rows.iter_mut().enumerate() {
        if k % 40 == 0 && r.t_s > 4.0 {
            r.surge_margin = 250.0;
        }
        if k % 40 == 20 && r.t_s > 4.0 {
            r.surge_margin = -4.0;
        }
    }
    let control = |_r: f64| 0.10;
    let trip = |_r: f64| 0.05;
    let marks = TimeMarks {
        events: vec![],
        control_line: Some(&control),
        trip_line: Some(&trip),
        recorded: None,
    };
    let panels = super::timeseries::panels(&rows, &marks);
    let m = panels
        .iter()
        .find(|p| p.y_desc == "surge margin (%)")
        .expect("margin panel");
    let names: Vec<&str> = m.series.iter().map(|s| s.name).collect();
    assert_eq!(names, ["surge margin", "control line", "trip line"]);
    for s in &m.series {
        for p in &s.points {
            assert!(p.1.abs() <= MARGIN_LIMIT_PCT, "{} at {p:?}", s.name);
        }
    }
    let line_at = |name: &str| m.series.iter().find(|s| s.name == name).unwrap().points[0].1;
    assert!((line_at("control line") - 10.0).abs() < 1e-9);
    assert!((line_at("trip line") - 5.0).abs() < 1e-9);
    assert!(m.off_scale.iter().any(|p| p.1 == MARGIN_LIMIT_PCT));
    assert!(m.off_scale.iter().any(|p| p.1 == -MARGIN_LIMIT_PCT));
    assert!(m.off_scale.iter().all(|p| p.0 > 4.0));
    let path = dir.path().join("ts.svg");
    timeseries_svg(&path, &rows, "spikes", &marks).expect("timeseries");
    let svg = read_svg(&path);
    for label in ["control line", "trip line", "off scale (beyond ±100 %)"] {
        assert!(has_text(&svg, label), "missing {label:?}");
    }
    let marker = format!("fill=\"{}\"", hex(OFF_SCALE_COLOR));
    let n = svg
        .lines()
        .filter(|l| l.contains("<polygon") && l.contains(&marker))
        .count();
    assert!(n > 10, "{n} off-scale markers");
    // without spikes: no marker, no legend entry
    let path = dir.path().join("quiet.svg");
    let mut quiet = trace(false);
    for r in &mut quiet {
        r.surge_margin = 0.2;
    }
    timeseries_svg(&path, &quiet, "quiet", &marks).expect("timeseries");
    assert!(!read_svg(&path).contains("off scale"));
}

/// Scenario events are labelled above the panels; fail-safe and manual intervals are shaded
/// in every panel and explained once.
#[test]
fn events_and_modes_are_marked_on_the_time_panels() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut rows = trace(false);
    for r in &mut rows {
        r.mode = if (5.0..6.0).contains(&r.t_s) {
            3.0
        } else if (7.0..8.0).contains(&r.t_s) {
            1.0
        } else {
            2.0
        };
    }
    let marks = TimeMarks {
        events: vec![
            (4.0, "throttle → 20 % over 2 s".to_string()),
            (4.1, "pressure NaN".to_string()),
        ],
        ..TimeMarks::default()
    };
    let path = dir.path().join("ts.svg");
    timeseries_svg(&path, &rows, "events", &marks).expect("timeseries");
    let svg = read_svg(&path);
    let a = texts_at(&svg, "throttle → 20 % over 2 s");
    let b = texts_at(&svg, "pressure NaN");
    assert_eq!((a.len(), b.len()), (1, 1));
    // close together: on different rows, not on top of each other
    assert!((a[0].1 - b[0].1).abs() >= 15.0, "{a:?} {b:?}");
    assert!(b[0].0 > a[0].0, "later event further right");
    assert_eq!(texts(&svg).iter().filter(|t| *t == "fail-safe").count(), 1);
    assert_eq!(texts(&svg).iter().filter(|t| *t == "manual").count(), 1);
    let panels = super::timeseries::panels(&rows, &marks).len();
    for c in [FAIL_SAFE_COLOR, MANUAL_COLOR] {
        let fill = format!("fill=\"{}\"", hex(c));
        let bands = svg
            .lines()
            .filter(|l| l.contains("<rect") && l.contains(&fill))
            .count();
        // one band per panel plus the legend swatch
        assert_eq!(bands, panels + 1, "{c:?}");
    }
    // no mode change, no events: nothing of the kind
    let path = dir.path().join("plain.svg");
    timeseries_svg(&path, &trace(false), "plain", &TimeMarks::default()).expect("ts");
    let svg = read_svg(&path);
    assert!(!has_text(&svg, "fail-safe") && !has_text(&svg, "manual"));
}

/// A recycle run that ends where it started (the compressor held on its control line while
/// the throughput falls): one marker, not two overlapping; the throughput drawn and given in
/// kg/s.
#[test]
fn recycle_map_has_one_dot_and_the_throughput_in_kg_per_s() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rows: Vec<TraceRow> = (0..=2000)
        .map(|k| {
            let t = k as f64 * 0.005;
            let wobble = 0.05 * (t * 2.0).sin() * (-t).exp();
            let through = 10.0 - 0.6 * t.min(7.5);
            TraceRow {
                t_s: t,
                m_kg_s: 10.0 + wobble,
                // a volumetric map: 0.8 m³/s per kg/s
                flow_map: 0.8 * (10.0 + wobble),
                pressure_ratio: 1.95,
                omega_rad_s: 2000.0,
                throttle_flow_kg_s: through,
                recycle_flow_kg_s: 10.0 - through,
                surge_margin: 0.1,
                ..Default::default()
            }
        })
        .collect();
    let mut map = cubic_map();
    map.flow_coordinate = FlowCoordinate::InletVolumeM3S;
    let path = dir.path().join("map.svg");
    map_svg(&path, &map, &rows, None, "recycle").expect("map");
    let svg = read_svg(&path);
    assert!(
        texts(&svg)
            .iter()
            .any(|t| t.starts_with("start and end (t = 0.00 s and 10.0 s")),
        "one marker legend"
    );
    assert!(!texts(&svg).iter().any(|t| t.starts_with("start (t = ")));
    let start_fill = format!("fill=\"{}\"", hex(plotters::style::RGBColor(0, 165, 70)));
    assert!(
        !svg.lines()
            .any(|l| l.contains("<circle") && l.contains(&start_fill)),
        "no separate start circle"
    );
    assert!(
        paths_of(&svg, THROUGHPUT_COLOR) > 0,
        "throughput trajectory (dashed)"
    );
    assert!(has_text(&svg, "throughput (to the process)"));
    // the end in the summary's unit: kg/s, not the map's m³/s
    assert!(
        has_text(
            &svg,
            "end (t = 10.0 s), compressor 10.00 kg/s, throughput 5.50 kg/s"
        ),
        "{:?}",
        texts(&svg)
    );
    // its line reaches the throughput's map flow: 0.8 × 5.5 = 4.4 m³/s, left of the start
    let line = polylines_of(&svg, THROUGHPUT_COLOR);
    let traj = polylines_of(&svg, plotters::style::RGBColor(31, 110, 190));
    let min_x = line
        .iter()
        .flatten()
        .map(|p| p.0)
        .fold(f64::INFINITY, f64::min);
    let traj_min_x = traj
        .iter()
        .flatten()
        .map(|p| p.0)
        .fold(f64::INFINITY, f64::min);
    assert!(min_x < traj_min_x - 100.0, "{min_x} vs {traj_min_x}");
}

/// With another run's commands to compare (replay with changed settings), each command line
/// has a "(recorded)" twin drawn from those rows; without, none.
#[test]
fn recorded_commands_are_drawn_beside_the_trace_commands() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rows = trace(false);
    let mut recorded = rows.clone();
    for r in &mut recorded {
        r.cmd_recycle_valve = 0.9;
    }
    let marks = TimeMarks {
        recorded: Some(&recorded),
        ..TimeMarks::default()
    };
    let panels = super::timeseries::panels(&rows, &marks);
    let valve = panels
        .iter()
        .find(|p| p.y_desc == "valve opening (–)")
        .expect("valve panel");
    let twin = valve
        .series
        .iter()
        .find(|s| s.name == "recycle valve command (recorded)")
        .expect("recorded twin");
    assert!(
        twin.points.iter().all(|p| p.1 == 0.9),
        "{:?}",
        &twin.points[..3]
    );
    let path = dir.path().join("ts.svg");
    timeseries_svg(&path, &rows, "compare", &marks).expect("timeseries");
    let svg = read_svg(&path);
    assert!(has_text(&svg, "recycle valve command (recorded)"));
    assert!(svg.contains(&hex(super::timeseries::RECORDED_COLOR)));
    let path = dir.path().join("alone.svg");
    timeseries_svg(&path, &rows, "alone", &TimeMarks::default()).expect("timeseries");
    assert!(!read_svg(&path).contains("(recorded)"));
}

/// The tick step the labels are formatted for is the one plotters draws: over 0.001–8.017 s
/// with 16 labels plotters puts ticks every 0.5 s (16 inside), so the labels need a decimal
/// (formatted for 1 s they read "0, 1, 2, 2, 2, 3 …").
#[test]
fn tick_step_matches_the_ticks_plotters_draws() {
    use super::common::{nice_step, tick_label};
    let step = |lo: f64, hi: f64, n: usize| {
        let s = nice_step((lo, hi), n);
        // to 9 significant digits: the step is a power of ten times 1, 2 or 5
        let m = 10f64.powf(s.log10().floor());
        (s / m * 1e6).round() / 1e6 * m
    };
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs();
    assert!(close(step(0.001, 8.017, 16), 0.5));
    assert_eq!(tick_label(2.5, nice_step((0.001, 8.017), 16)), "2.5");
    assert!(close(step(0.0, 10.0, 16), 1.0));
    // 0, 0.5, …, 8 would be 17 ticks
    assert!(close(step(0.0, 8.0, 16), 1.0));
    assert!(close(step(-0.5, 0.5, 5), 0.2));
    assert!(close(step(990.0, 1010.0, 5), 5.0));
    // whatever the range, no more than n multiples of the step fall inside it, and the next
    // smaller nice step would put more
    let inside = |lo: f64, hi: f64, s: f64| (hi / s).floor() - (lo / s).ceil() + 1.0;
    for (lo, hi, n) in [
        (0.3, 7.9, 16),
        (-3.3, 41.0, 5),
        (1e-4, 3e-3, 5),
        (0.0, 1.0, 16),
    ] {
        let s = step(lo, hi, n);
        assert!(inside(lo, hi, s) <= n as f64, "{lo}..{hi}: step {s}");
        let mantissa = (s / 10f64.powf(s.log10().floor())).round();
        let smaller = if mantissa == 5.0 { s * 0.4 } else { s / 2.0 };
        assert!(
            inside(lo, hi, smaller) > n as f64,
            "{lo}..{hi}: {smaller} fits too"
        );
    }
}
