//! Model-based laws from the machine description: a machine file with a `[model]` table (and a
//! speed-line map and an owned drive) runs drive-torque, ccv, throttle-backstep, robust,
//! tip-sliding and recycle-fl exactly as the plant file's own description does, because both
//! go through the same model data (`machine::model::ModelData`) into the same description.

use crate::common;

use antisurge::control::model::ControlModel;
use antisurge::control::LawId;
use antisurge::machine::file as machine_file;
use antisurge::scenario::Scenario;
use antisurge::sim::case::PlantCase;
use antisurge::sim::{SimOptions, Summary};
use common::{plant, root, scenario, PLANTS};
use std::path::Path;
use toml::Value;

/// A machine file for a shipped plant: its gas, map, flow element, drive (owned), design
/// point at the model's suction conditions and `[model]` with the family's tables, nothing of
/// the simulator (initial state, integration, controller settings).
fn machine_file_of(p: &PlantCase, dir: &Path) -> std::path::PathBuf {
    let text = std::fs::read_to_string(&p.path).expect("plant file");
    let v: toml::Table = toml::from_str(&text).expect("plant toml");
    let mut m = toml::Table::new();
    m.insert("name".into(), Value::String(format!("{}_model", p.name())));
    m.insert("gas".into(), v["gas"].clone());
    // the map: a CSV path is made absolute (the machine file lives elsewhere)
    let mut map = v["map"].as_table().expect("map").clone();
    if let Some(t) = map.get_mut("table").and_then(|t| t.as_table_mut()) {
        let f = t["file"].as_str().expect("file").to_string();
        let abs = p.path.parent().expect("dir").join(f);
        t.insert("file".into(), Value::String(abs.display().to_string()));
        map = t.clone();
    } else {
        map = toml::Table::from_iter([("cubic".to_string(), map["cubic"].clone())]);
    }
    m.insert("speed_line_map".into(), Value::Table(map));
    m.insert("flow_element".into(), v["orifice"].clone());
    let md = p.file.model_data();
    let (p_s, t_s) = md.suction_conditions();
    let mut design = toml::Table::new();
    design.insert(
        "suction_pressure_pa".into(),
        Value::Float(p_s.unwrap_or(1e5)),
    );
    design.insert(
        "suction_temperature_k".into(),
        Value::Float(t_s.expect("temperature")),
    );
    design.insert(
        "speed_rad_s".into(),
        Value::Float(p.file.drive.nominal_speed_rad_s),
    );
    m.insert("design".into(), Value::Table(design));
    let mut drive = v["drive"].as_table().expect("drive").clone();
    drive.insert("owned_by_controller".into(), Value::Boolean(true));
    m.insert("drive".into(), Value::Table(drive));
    if let Some(r) = &p.file.recycle_system {
        let mut rv = toml::Table::new();
        rv.insert(
            "stroke_time_s".into(),
            Value::Float(r.recycle_valve.stroke_time_s),
        );
        m.insert("recycle_valve".into(), Value::Table(rv));
    }
    let family = p.file.model;
    let mut model = toml::Table::new();
    model.insert("family".into(), Value::String(family.key().into()));
    model.insert("shaft".into(), v["shaft"].clone());
    for t in [
        "plenum_duct",
        "recycle_system",
        "tip_clearance",
        "thrust_rating",
        "spool",
    ] {
        if let Some(x) = v.get(t) {
            model.insert(t.into(), x.clone());
        }
    }
    m.insert("model".into(), Value::Table(model));
    let out = dir.join(format!("{}.toml", p.name()));
    std::fs::write(&out, toml::to_string(&m).expect("ser")).expect("write");
    out
}

fn run(p: &PlantCase, model: ControlModel, s: &Scenario, law: LawId) -> Summary {
    antisurge::sim::run_with_model(
        p,
        model,
        s,
        SimOptions {
            law,
            ..SimOptions::default()
        },
        &mut |_| {},
        &mut |_, _| {},
    )
    .unwrap_or_else(|e| panic!("{}: {law}: {e}", p.name()))
    .summary
}

fn same_outcome(p: &PlantCase, machine: ControlModel, s: &Scenario, law: LawId) {
    let a = run(p, antisurge::sim::control_model(p), s, law);
    let b = run(p, machine, s, law);
    let what = format!("{} {} {law}", p.name(), s.name());
    assert_eq!(a.surge_cycles, b.surge_cycles, "{what}");
    assert_eq!(a.stable, b.stable, "{what}");
    for (x, y, name) in [
        (a.min_flow_kg_s, b.min_flow_kg_s, "min flow"),
        (a.final_flow_kg_s, b.final_flow_kg_s, "final flow"),
    ] {
        assert!(
            (x - y).abs() <= 1e-9 * x.abs().max(1.0),
            "{what}: {name} {x} with the plant file, {y} with the machine file"
        );
    }
}

/// The shipped `config/machines/bohagen2007_model.toml` alone runs drive-torque through the
/// throttle closure and step as the plant file does: no surge, identical trajectory.
#[test]
fn the_shipped_model_machine_file_runs_drive_torque_as_the_plant_file() {
    let p = plant("bohagen2007_plenum");
    let m = machine_file::load(&root().join("config/machines/bohagen2007_model.toml"))
        .unwrap_or_else(|e| panic!("{e}"));
    for stem in ["throttle_closure", "throttle_step"] {
        let s = scenario(stem);
        let model = ControlModel::from_machine(&m, p.controller.clone());
        same_outcome(&p, model, &s, LawId::DriveTorque);
        let b = run(
            &p,
            ControlModel::from_machine(&m, p.controller.clone()),
            &s,
            LawId::DriveTorque,
        );
        assert_eq!(
            b.surge_cycles, 0,
            "{stem}: drive-torque from the machine file surged"
        );
    }
}

/// Every shipped plant's model data, typed as a machine file's `[model]`, give the controller
/// the same model, and each model-based law the plant supports the same throttle closure.
#[test]
fn every_model_based_law_runs_from_a_machine_file_with_the_plants_model() {
    let dir = tempfile::tempdir().expect("tmp");
    let closure = scenario("throttle_closure");
    let mut laws_run = Vec::new();
    for stem in PLANTS {
        let p = plant(stem);
        let path = machine_file_of(&p, dir.path());
        let m = machine_file::load(&path).unwrap_or_else(|e| panic!("{stem}: {e}"));
        let from_plant = antisurge::sim::control_model(&p);
        let from_file = ControlModel::from_machine(&m, p.controller.clone());
        assert_eq!(from_file.kind, from_plant.kind, "{stem}");
        assert_eq!(from_file.plenum_duct, from_plant.plenum_duct, "{stem}");
        assert_eq!(from_file.recycle, from_plant.recycle, "{stem}");
        assert_eq!(from_file.tip, from_plant.tip, "{stem}");
        assert_eq!(from_file.thrust, from_plant.thrust, "{stem}");
        assert_eq!(from_file.spool, from_plant.spool, "{stem}");
        assert_eq!(from_file.shaft, from_plant.shaft, "{stem}");
        assert_eq!(from_file.drive, from_plant.drive, "{stem}");
        for law in LawId::ALL {
            let d = law.descriptor();
            if d.model_family != Some(p.file.model) {
                continue;
            }
            same_outcome(&p, from_file.clone(), &closure, law);
            laws_run.push(law);
        }
    }
    for law in [
        LawId::DriveTorque,
        LawId::Ccv,
        LawId::ThrottleBackstep,
        LawId::Robust,
        LawId::TipSliding,
        LawId::RecycleFl,
    ] {
        assert!(laws_run.contains(&law), "{law} was not exercised");
    }
}

/// A model family without one of its tables names the missing key in the machine file; the
/// registry's model data for drive-torque are asked for by key when `[model]` is absent.
#[test]
fn a_missing_model_table_is_named_with_its_key() {
    let cases = root().join("tests/bad_configs/machines");
    let e = machine_file::load(&cases.join("model_no_shaft.toml")).unwrap_err();
    assert_eq!(e.key, "model.shaft", "{e}");
    assert!(e.line > 0, "{e}");
    assert!(
        e.hint.as_deref().unwrap_or("").contains("[model.shaft]"),
        "{e}"
    );
    let m = machine_file::load(&cases.join("model_missing.toml")).unwrap_or_else(|e| panic!("{e}"));
    let model = ControlModel::from_machine(&m, Default::default());
    let missing = LawId::DriveTorque
        .missing_machine_data(&model)
        .expect("drive-torque needs the plenum/duct model");
    assert_eq!(missing.key(), "model");
    assert!(missing.describe().1.contains("[model.plenum_duct]"));
}
