//! The bad-config corpus: every `tests/bad_configs/*.toml` (and every case directory
//! `tests/bad_configs/<case>/antisurge.toml` with a `conf.d/`) must be refused with an error
//! that names the key, the file and — where the key is written in a file — its line.
//!
//! Each case starts with comment lines:
//!
//! ```text
//! # expect-key: <dotted key the error must name (contained in FileError.key)>
//! # expect-message: <substring of the message>
//! # expect-line: <line in the reported file>          (optional)
//! # expect-file: <reported file, relative to the case> (optional; default the case itself)
//! ```
//!
//! The good examples (`config/antisurge.toml`, `tests/good_configs/*.toml`) must load without
//! errors, and `antisurge check-config` must print the same located errors.

use crate::common;

use antisurge::config::toml_file::locate_key;
use antisurge::daemon::config::{load_with_env, Problem};
use std::path::{Path, PathBuf};
use std::process::Command;

#[derive(Debug)]
struct Case {
    path: PathBuf,
    key: String,
    message: String,
    line: Option<usize>,
    file: PathBuf,
}

fn header(text: &str, name: &str) -> Option<String> {
    text.lines()
        .take_while(|l| l.starts_with('#'))
        .find_map(|l| l.strip_prefix(&format!("# {name}:")))
        .map(|v| v.trim().to_string())
}

fn case(path: &Path) -> Case {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let key = header(&text, "expect-key")
        .unwrap_or_else(|| panic!("{}: no `# expect-key:` line", path.display()));
    let message = header(&text, "expect-message")
        .unwrap_or_else(|| panic!("{}: no `# expect-message:` line", path.display()));
    let line = header(&text, "expect-line").map(|l| {
        l.parse()
            .unwrap_or_else(|_| panic!("{}: bad expect-line {l:?}", path.display()))
    });
    let dir = path.parent().expect("dir");
    let file = header(&text, "expect-file").map_or_else(|| path.to_path_buf(), |f| dir.join(f));
    Case {
        path: path.to_path_buf(),
        key,
        message,
        line,
        file,
    }
}

fn bad_dir() -> PathBuf {
    common::root().join("tests/bad_configs")
}

/// The corpus: top-level `*.toml` files, then case directories (a main file with `conf.d/`).
fn corpus() -> Vec<Case> {
    let mut files = Vec::new();
    let mut dirs = Vec::new();
    for e in std::fs::read_dir(bad_dir()).expect("tests/bad_configs") {
        let p = e.expect("entry").path();
        if p.is_file() && p.extension().is_some_and(|x| x == "toml") {
            files.push(p);
        } else if p.join("conf.d").is_dir() && p.join("antisurge.toml").is_file() {
            dirs.push(p.join("antisurge.toml"));
        }
    }
    files.sort();
    dirs.sort();
    files.iter().chain(&dirs).map(|p| case(p)).collect()
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => a == b,
    }
}

/// Check one case; `Err` says what is wrong.
fn check_case(c: &Case) -> Result<(), String> {
    let problems: Vec<Problem> = match load_with_env(&c.path, &[]) {
        Ok(l) => {
            return Err(format!(
                "accepted (warnings: {:?})",
                l.warnings
                    .iter()
                    .map(ToString::to_string)
                    .collect::<Vec<_>>()
            ))
        }
        Err(p) => p,
    };
    let all = problems
        .iter()
        .map(|p| format!("    {p}"))
        .collect::<Vec<_>>()
        .join("\n");
    let Some(p) = problems.iter().find(|p| {
        !p.warning
            && p.error.key.contains(&c.key)
            && (p.error.message.contains(&c.message) || p.to_string().contains(&c.message))
    }) else {
        return Err(format!(
            "no error with key containing `{}` and message containing {:?}; got:\n{all}",
            c.key, c.message
        ));
    };
    let e = &p.error;
    if !same_file(&e.file, &c.file) {
        return Err(format!(
            "reported in {}, expected {}:\n{all}",
            e.file.display(),
            c.file.display()
        ));
    }
    let shown = p.to_string();
    let name = c.file.file_name().expect("name").to_string_lossy();
    if !shown.contains(name.as_ref()) {
        return Err(format!(
            "the message does not name the file {name}: {shown}"
        ));
    }
    if !shown.contains(&c.key) {
        return Err(format!(
            "the message does not name the key {}: {shown}",
            c.key
        ));
    }
    if let Some(line) = c.line {
        if e.line != line {
            return Err(format!("line {} instead of {line}: {shown}", e.line));
        }
    }
    // a key written in the reported file must come with its line
    let text = std::fs::read_to_string(&e.file).unwrap_or_default();
    let written = toml::from_str::<toml::Table>(&text)
        .ok()
        .is_some_and(|t| leaf_present(&t, &e.key));
    if (written || c.line.is_some()) && e.line == 0 {
        return Err(format!("no line for a key written in the file: {shown}"));
    }
    if written {
        let (line, _) = locate_key(&text, &e.key).expect("located");
        if line != e.line {
            return Err(format!(
                "line {} but the key is on line {line}: {shown}",
                e.line
            ));
        }
    }
    Ok(())
}

/// Whether the dotted key is set, exactly, in a table.
fn leaf_present(t: &toml::Table, dotted: &str) -> bool {
    let mut cur = t;
    let parts: Vec<&str> = dotted.split('.').collect();
    for (i, p) in parts.iter().enumerate() {
        match cur.get(*p) {
            Some(toml::Value::Table(next)) if i + 1 < parts.len() => cur = next,
            Some(_) => return i + 1 == parts.len(),
            None => return false,
        }
    }
    false
}

#[test]
fn every_bad_config_is_refused_with_key_file_and_line() {
    let cases = corpus();
    let top_level = cases
        .iter()
        .filter(|c| c.path.parent() == Some(bad_dir().as_path()))
        .count();
    assert!(
        top_level >= 30,
        "the corpus has only {top_level} top-level files"
    );
    let failures: Vec<String> = cases
        .iter()
        .filter_map(|c| {
            check_case(c)
                .err()
                .map(|e| format!("{}: {e}", c.path.display()))
        })
        .collect();
    assert!(
        failures.is_empty(),
        "{} of {} bad configs fail:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}

fn good_configs() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(common::root().join("tests/good_configs"))
        .expect("tests/good_configs")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    v.sort();
    v.insert(0, common::root().join("config/antisurge.toml"));
    v
}

#[test]
fn good_configs_load_without_errors() {
    let goods = good_configs();
    assert!(goods.len() >= 4, "{goods:?}");
    for p in &goods {
        match load_with_env(p, &[]) {
            Ok(l) => {
                // the good examples are also free of warnings, except the one that shows one
                let name = p.file_name().expect("name").to_string_lossy();
                if !name.contains("warning") {
                    assert!(
                        l.warnings.is_empty(),
                        "{}: warnings {:?}",
                        p.display(),
                        l.warnings
                    );
                }
            }
            Err(problems) => panic!(
                "{} refused:\n{}",
                p.display(),
                problems
                    .iter()
                    .map(ToString::to_string)
                    .collect::<Vec<_>>()
                    .join("\n")
            ),
        }
    }
}

#[test]
fn good_configs_select_what_they_say() {
    use antisurge::control::LawId;
    use antisurge::daemon::config::Transport;
    let dir = common::root().join("tests/good_configs");
    let l = load_with_env(&dir.join("field_can_drive_torque.toml"), &[]).expect("can");
    assert_eq!(l.law, LawId::DriveTorque);
    assert_eq!(l.config.bus.transport, Transport::Field);
    assert!(l.signal_map.uses_can() && l.config.bus.can.is_some());
    let l = load_with_env(&dir.join("field_modbus_recycle_pi.toml"), &[]).expect("modbus");
    assert_eq!(l.law, LawId::RecyclePi);
    assert!(l.signal_map.uses_modbus() && l.config.bus.modbus.is_some());
    // three Δp transmitters: the core votes them (median of three, the map's settings)
    let l = load_with_env(&dir.join("field_modbus_three_dp.toml"), &[]).expect("three Δp");
    let v = l.core.vote.per_sensor[antisurge::vocab::signals::SensorId::OrificeDp.index()]
        .expect("orifice_dp voted");
    assert_eq!((v.transmitters, v.deviation, v.deviation_s), (3, 0.05, 0.5));
    assert_eq!(l.signal_map.modbus_spares().len(), 2);
    let l = load_with_env(&dir.join("in_process_tip_sliding.toml"), &[]).expect("tip");
    assert_eq!(l.law, LawId::TipSliding);
    assert_eq!(l.config.bus.transport, Transport::InProcess);
    // vendor data, recycle-pi bindings only: the drive is not the controller's, no observer
    let l = load_with_env(&dir.join("vendor_recycle_pi_minimal.toml"), &[]).expect("vendor");
    assert_eq!(l.law, LawId::RecyclePi);
    assert!(!l.model.owns_drive && l.model.map.is_none() && l.plant.is_none());
    assert!(l.warnings.is_empty(), "{:?}", l.warnings);
}

#[test]
fn a_pressure_range_in_bar_is_an_error_naming_the_unit() {
    // a warning until issue 25 (the range put a running compressor into fail-safe)
    let p = common::root().join("tests/bad_configs/vendor_discharge_range_in_bar.toml");
    let problems = match load_with_env(&p, &[]) {
        Ok(l) => panic!("accepted (warnings {:?})", l.warnings),
        Err(p) => p,
    };
    let e = problems
        .iter()
        .find(|e| e.error.key == "inputs.p_discharge.max")
        .unwrap_or_else(|| panic!("no range error: {problems:?}"));
    assert!(!e.warning, "{e}");
    assert!(e.error.message.contains("looks typed in bar"), "{e}");
    assert!(e.error.message.contains("fail-safe"), "{e}");
    assert!(
        e.error
            .hint
            .as_deref()
            .is_some_and(|h| h.contains("min = 1e5")),
        "{e}"
    );
    assert!(same_file(&e.error.file, &p), "{e}");
    assert_eq!(e.error.line, 12, "{e}");
    assert!(
        problems
            .iter()
            .all(|w| !w.warning || w.error.key != "inputs.p_discharge.max"),
        "the warning is not repeated: {problems:?}"
    );
}

#[test]
fn a_thin_surge_control_line_margin_is_a_warning_naming_the_key() {
    let p = common::root().join("tests/good_configs/warning_thin_margin.toml");
    let l = load_with_env(&p, &[]).unwrap_or_else(|e| panic!("refused: {e:?}"));
    let w = l
        .warnings
        .iter()
        .find(|w| w.error.message.contains("under 5 %"))
        .unwrap_or_else(|| panic!("no margin warning: {:?}", l.warnings));
    assert!(w.warning);
    assert_eq!(
        w.error.key, "controller.recycle_pi.control_line.margin.margin_pct",
        "{w}"
    );
    assert!(same_file(&w.error.file, &p), "{w}");
    let text = std::fs::read_to_string(&p).expect("read");
    let (line, _) = locate_key(&text, "controller.recycle_pi.control_line").expect("line");
    assert_eq!(w.error.line, line, "{w}");
    assert!(w.to_string().starts_with("warning: "), "{w}");
}

fn check_config(file: &Path) -> std::process::Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_antisurge"));
    cmd.arg("check-config")
        .arg(file)
        .current_dir(common::root());
    for (k, _) in std::env::vars() {
        if k.starts_with("ANTISURGE_") {
            cmd.env_remove(k);
        }
    }
    cmd.output().expect("run antisurge check-config")
}

#[test]
fn check_config_prints_file_line_and_key_and_exits_78() {
    for name in ["rate_hz_string", "unit_typo_rate_khz", "failsafe_150"] {
        let path = bad_dir().join(format!("{name}.toml"));
        let c = case(&path);
        let out = check_config(&path);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(78), "{name}: {stderr}");
        let text = std::fs::read_to_string(&path).expect("read");
        let (line, col) = locate_key(&text, &c.key).expect("key in file");
        let located = format!("{}:{line}:{col}: key `{}`", path.display(), c.key);
        assert!(
            stderr.contains(&located),
            "{name}: expected `{located}` in:\n{stderr}"
        );
        assert!(stderr.contains(&c.message), "{name}: {stderr}");
        assert!(stderr.contains("error(s)"), "{name}: {stderr}");
    }
}

#[test]
fn check_config_accepts_the_shipped_example() {
    let out = check_config(&common::root().join("config/antisurge.toml"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{stdout}\n{stderr}");
    assert!(stdout.contains("OK"), "{stdout}");
}

#[test]
fn check_config_prints_warnings_but_exits_0() {
    let p = common::root().join("tests/good_configs/warning_thin_margin.toml");
    let out = check_config(&p);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert!(stderr.contains("warning: "), "{stderr}");
    assert!(
        stderr.contains("controller.recycle_pi.control_line.margin.margin_pct"),
        "{stderr}"
    );
}
