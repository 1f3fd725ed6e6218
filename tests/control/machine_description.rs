//! One way in: every shipped plant file yields its machine description through the same code a
//! vendor machine file goes through, and the surge line the controller gets is today's.

use crate::common;

use antisurge::machine::file as machine_file;
use antisurge::physics::compressor_map::{FlowCoordinate, SurgeLine};
use common::{plant, root, PLANTS};

/// Largest relative difference of two surge lines over `n` pressure ratios of `a`'s range.
fn worst_difference(a: &SurgeLine, b: &SurgeLine) -> (f64, f64) {
    let pts: Vec<(f64, f64)> = a.points().collect();
    let (lo, hi) = (pts[0].1, pts[pts.len() - 1].1);
    let mut worst = (0.0, lo);
    for k in 0..=100 {
        let r = lo + (hi - lo) * k as f64 / 100.0;
        let (qa, qb) = (a.flow_at_ratio(r), b.flow_at_ratio(r));
        let d = (qb - qa).abs() / qa.abs();
        if d > worst.0 {
            worst = (d, r);
        }
    }
    worst
}

#[test]
fn every_shipped_plant_gives_the_controller_todays_surge_line() {
    for stem in PLANTS {
        let p = plant(stem);
        let model = antisurge::sim::control_model(&p);
        let (d, r) = worst_difference(&p.map.surge_line, &model.surge_line);
        assert!(d < 0.005, "{stem}: {:.3} % at R = {r:.3}", 100.0 * d);
        assert_eq!(model.flow_coordinate, p.map.flow_coordinate, "{stem}");
        assert_eq!(model.kind, Some(p.file.model), "{stem}");
    }
}

/// A machine file with the plant's speed-line CSV (`[speed_line_map]`) and its flow element:
/// the SLL derived through the vendor path equals the plant's within 0.5 %; for the volumetric
/// map, six of its surge points typed as vendor points do too.
#[test]
fn a_machine_file_with_the_speed_line_map_or_six_surge_points_gives_the_same_line() {
    let dir = tempfile::tempdir().expect("tmp");
    let mut checked = 0;
    for stem in PLANTS {
        let p = plant(stem);
        let antisurge::plant::file::MapSpec::Table { file } = &p.file.map else {
            continue;
        };
        let csv = p.path.parent().expect("dir").join(file);
        let t = p.machine().reference_suction_temperature_k;
        let head = format!(
            r#"name = "{stem}"
[gas]
molar_mass_kg_mol = {m}
heat_capacity_ratio = {k}
polytropic_exponent = {s}
[flow_element]
flow_coefficient = {cf}
bore_diameter_m = {d}
[design]
suction_pressure_pa = 1.0e5
suction_temperature_k = {t}
"#,
            m = p.file.gas.molar_mass_kg_mol,
            k = p.file.gas.heat_capacity_ratio,
            s = p.file.gas.polytropic_exponent,
            cf = p.file.orifice.flow_coefficient,
            d = p.file.orifice.bore_diameter_m,
        );
        let path = dir.path().join(format!("{stem}_map.toml"));
        std::fs::write(
            &path,
            format!("{head}[speed_line_map]\nfile = \"{}\"\n", csv.display()),
        )
        .unwrap();
        let m = machine_file::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let (d, r) = worst_difference(&p.map.surge_line, &m.surge_line);
        assert!(d < 0.005, "{stem} map: {:.3} % at R = {r:.3}", 100.0 * d);
        checked += 1;
        if p.map.flow_coordinate == FlowCoordinate::InletVolumeM3S {
            let all: Vec<(f64, f64)> = p.map.surge_line.points().collect();
            let six: Vec<String> = (0..6)
                .map(|i| all[i * (all.len() - 1) / 5])
                .map(|(q, r)| format!("[{q}, {r}]"))
                .collect();
            let design = format!("[design]\nsuction_pressure_pa = {}\n", 2.0e6);
            let body = head.replace("[design]\nsuction_pressure_pa = 1.0e5\n", &design);
            let path = dir.path().join(format!("{stem}_points.toml"));
            std::fs::write(
                &path,
                format!("{body}[surge_line]\npoints = [{}]\n", six.join(", ")),
            )
            .unwrap();
            let m = machine_file::load(&path).unwrap_or_else(|e| panic!("{e}"));
            let (d, r) = worst_difference(&p.map.surge_line, &m.surge_line);
            assert!(d < 0.005, "{stem} points: {:.3} % at R = {r:.3}", 100.0 * d);
            checked += 1;
        }
    }
    assert!(checked >= 4, "{checked}");
}

/// The CAN heartbeat's `ActiveLaw` value table in the shipped DBC is the law registry's.
#[test]
fn the_dbc_value_table_of_active_law_comes_from_the_law_registry() {
    let dbc = std::fs::read_to_string(root().join("config/skid.dbc")).expect("dbc");
    let line = antisurge::control::law::dbc_value_table(128);
    let found: Vec<&str> = dbc
        .lines()
        .filter(|l| l.starts_with("VAL_ 128 ActiveLaw"))
        .collect();
    assert_eq!(
        found,
        vec![line.as_str()],
        "regenerate the line from control::law::REGISTRY"
    );
    for d in antisurge::control::law::REGISTRY {
        assert_eq!(d.id.code(), d.code);
        assert_eq!(d.name.parse::<antisurge::control::LawId>(), Ok(d.id));
    }
}
