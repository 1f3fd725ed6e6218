//! The config layers: main file, then `conf.d/*.toml` in file-name order, then
//! `ANTISURGE_<SECTION>__<KEY>` variables; later layers win key by key, and an error names the
//! layer (file and line, or the variable) that set the bad value.

use crate::common;

use antisurge::control::LawId;
use antisurge::daemon::config::{load_with_env, Loaded, Problem};
use std::path::{Path, PathBuf};

fn plant(stem: &str) -> String {
    common::root()
        .join("config/plants")
        .join(format!("{stem}.toml"))
        .display()
        .to_string()
}

/// A config directory: `antisurge.toml` and the given `conf.d/` files.
fn setup(main: &str, conf_d: &[(&str, &str)]) -> (tempfile::TempDir, PathBuf) {
    let tmp = tempfile::tempdir().expect("tempdir");
    let main_path = tmp.path().join("antisurge.toml");
    std::fs::write(&main_path, main).expect("write main");
    if !conf_d.is_empty() {
        let d = tmp.path().join("conf.d");
        std::fs::create_dir(&d).expect("conf.d");
        for (name, text) in conf_d {
            std::fs::write(d.join(name), text).expect("write drop-in");
        }
    }
    (tmp, main_path)
}

fn main_file(plant_stem: &str, law: &str) -> String {
    format!(
        "[plant]\nfile = \"{}\"\n\n[control]\nlaw = \"{law}\"\n\n[cycle]\nrate_hz = 1000.0\npriority = 80\n\n[controller.recycle_pi.pi]\nkp_per_map_flow = 10.0\n",
        plant(plant_stem)
    )
}

fn vars(v: &[(&str, &str)]) -> Vec<(String, String)> {
    v.iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

fn ok(main: &Path, env: &[(String, String)]) -> Loaded {
    load_with_env(main, env).unwrap_or_else(|p| panic!("refused:\n{}", show(&p)))
}

fn refused(main: &Path, env: &[(String, String)]) -> Vec<Problem> {
    match load_with_env(main, env) {
        Ok(l) => panic!("accepted: {:?}", l.flat),
        Err(p) => {
            assert!(p.iter().any(|p| !p.warning), "only warnings: {}", show(&p));
            p
        }
    }
}

fn show(p: &[Problem]) -> String {
    p.iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("\n")
}

fn name(p: &Path) -> String {
    p.file_name().expect("name").to_string_lossy().into_owned()
}

#[test]
fn conf_d_overrides_the_main_file_in_file_name_order() {
    let (tmp, main) = setup(
        &main_file("kvangardsnes2009_recycle", "recycle-pi"),
        &[
            // 50 sorts after 10: its rate wins
            ("50-site.toml", "[cycle]\nrate_hz = 500.0\n"),
            (
                "10-tuning.toml",
                "[cycle]\nrate_hz = 200.0\n\n[controller.recycle_pi.pi]\nki_per_map_flow_s = 12.0\n",
            ),
            // not a .toml file: ignored
            ("README.md", "rate_hz = \"not toml\"\n"),
        ],
    );
    let l = ok(&main, &[]);
    assert_eq!(l.config.cycle.rate_hz, 500.0);
    // keys the drop-ins do not set keep the main file's values
    assert_eq!(l.config.cycle.priority, Some(80));
    assert_eq!(l.law, LawId::RecyclePi);
    // controller overrides merge key by key across layers, over the plant file's values
    assert_eq!(l.controller.recycle_pi.pi.kp_per_map_flow, 10.0);
    assert_eq!(l.controller.recycle_pi.pi.ki_per_map_flow_s, 12.0);
    assert_eq!(
        l.controller.recycle_pi.trip.margin_pct, 10.0,
        "the plant file's value"
    );
    let layers: Vec<String> = l.layers.iter().map(|x| name(&x.path)).collect();
    assert_eq!(
        layers,
        ["antisurge.toml", "10-tuning.toml", "50-site.toml"],
        "main first, then conf.d in name order"
    );
    assert_eq!(
        l.flat.get("cycle.rate_hz").map(String::as_str),
        Some("500.0")
    );
    drop(tmp);
}

#[test]
fn environment_overrides_conf_d() {
    let (_tmp, main) = setup(
        &main_file("bohagen2007_plenum", "none"),
        &[(
            "50-site.toml",
            "[control]\nlaw = \"none\"\n\n[cycle]\nrate_hz = 500.0\n\n[event_log]\nmax_bytes = 1048576\n",
        )],
    );
    let env = vars(&[
        ("ANTISURGE_CONTROL__LAW", "drive-torque"),
        ("ANTISURGE_CYCLE__RATE_HZ", "2000"),
        ("ANTISURGE_EVENT_LOG__MAX_BYTES", "2097152"),
        (
            "ANTISURGE_CONTROLLER__DRIVE_TORQUE__C1_RAD_S_PER_KG_S",
            "200.0",
        ),
        // not config keys: the tools' own variables and other programs' variables
        ("ANTISURGE_LOG", "debug"),
        ("ANTISURGE_CONFIG_DIR", "/nowhere"),
        ("PATH", "/usr/bin"),
    ]);
    let l = ok(&main, &env);
    assert_eq!(l.law, LawId::DriveTorque);
    assert_eq!(l.config.control.law, "drive-torque");
    assert_eq!(
        l.config.cycle.rate_hz, 2000.0,
        "an integer variable is a number"
    );
    assert_eq!(l.config.event_log.max_bytes, 2_097_152);
    assert_eq!(l.controller.drive_torque.c1_rad_s_per_kg_s, 200.0);
    assert_eq!(l.config.cycle.priority, Some(80), "main file, untouched");
    let last = l.layers.last().expect("layers");
    assert_eq!(last.path, Path::new("environment"));
    assert_eq!(l.layers.len(), 3);

    // without the variables, conf.d wins over the main file
    let l = ok(&main, &[]);
    assert_eq!(l.law, LawId::None);
    assert_eq!(l.config.cycle.rate_hz, 500.0);
}

#[test]
fn an_invalid_environment_value_names_the_variable() {
    let (_tmp, main) = setup(&main_file("kvangardsnes2009_recycle", "recycle-pi"), &[]);

    // wrong type
    let p = refused(&main, &vars(&[("ANTISURGE_CYCLE__RATE_HZ", "fast")]));
    let e = p
        .iter()
        .find(|p| p.error.key == "cycle.rate_hz")
        .unwrap_or_else(|| panic!("{}", show(&p)));
    let shown = e.to_string();
    assert!(
        shown.contains("environment (ANTISURGE_CYCLE__RATE_HZ)"),
        "{shown}"
    );
    assert!(shown.contains("invalid type"), "{shown}");

    // right type, value out of range (a cross-field rule)
    let p = refused(&main, &vars(&[("ANTISURGE_CYCLE__PRIORITY", "120")]));
    let shown = show(&p);
    assert!(
        shown.contains("environment (ANTISURGE_CYCLE__PRIORITY)")
            && shown.contains("cycle.priority"),
        "{shown}"
    );

    // a variable for a key that does not exist
    let p = refused(&main, &vars(&[("ANTISURGE_CYCLE__RATE_KHZ", "1")]));
    let shown = show(&p);
    assert!(
        shown.contains("environment (ANTISURGE_CYCLE__RATE_KHZ)")
            && shown.contains("cycle.rate_khz")
            && shown.contains("unknown field"),
        "{shown}"
    );

    // an unknown law
    let p = refused(&main, &vars(&[("ANTISURGE_CONTROL__LAW", "recycle_pi")]));
    let shown = show(&p);
    assert!(
        shown.contains("environment (ANTISURGE_CONTROL__LAW)") && shown.contains("unknown law"),
        "{shown}"
    );
}

#[test]
fn a_conf_d_file_with_an_unknown_key_is_named_with_its_line() {
    let (_tmp, main) = setup(
        &main_file("kvangardsnes2009_recycle", "recycle-pi"),
        &[
            ("10-ok.toml", "[cycle]\nrate_hz = 500.0\n"),
            (
                "50-typo.toml",
                "# site overrides\n\n[cycle]\nrate_hz = 500.0\ntimeout_s = 1.0\n",
            ),
        ],
    );
    let p = refused(&main, &[]);
    let e = &p
        .iter()
        .find(|p| p.error.key == "cycle.timeout_s")
        .unwrap_or_else(|| panic!("{}", show(&p)))
        .error;
    assert_eq!(name(&e.file), "50-typo.toml", "{e}");
    assert_eq!(e.line, 5, "{e}");
    assert!(e.message.contains("unknown field `timeout_s`"), "{e}");
    assert!(e.to_string().contains("conf.d/50-typo.toml:5:"), "{e}");
}

#[test]
fn a_bad_value_in_conf_d_names_the_drop_in_not_the_main_file() {
    let (_tmp, main) = setup(
        &main_file("kvangardsnes2009_recycle", "recycle-pi"),
        &[(
            "50-site.toml",
            "[control]\nfailsafe_recycle_opening_pct = 150.0\n",
        )],
    );
    let p = refused(&main, &[]);
    let e = &p
        .iter()
        .find(|p| p.error.key == "control.failsafe_recycle_opening_pct" && !p.warning)
        .unwrap_or_else(|| panic!("{}", show(&p)))
        .error;
    assert_eq!(name(&e.file), "50-site.toml", "{e}");
    assert_eq!(e.line, 2, "{e}");
}

#[test]
fn a_syntax_error_in_conf_d_names_the_drop_in_line_and_key() {
    let (_tmp, main) = setup(
        &main_file("kvangardsnes2009_recycle", "recycle-pi"),
        &[("50-site.toml", "[cycle]\nrate_hz = 500.0\npriority = \n")],
    );
    let p = refused(&main, &[]);
    let e = &p[0].error;
    assert_eq!(name(&e.file), "50-site.toml", "{e}");
    assert_eq!(e.line, 3, "{e}");
    assert_eq!(e.key, "cycle.priority", "{e}");
    assert!(e.message.contains("syntax"), "{e}");
}
