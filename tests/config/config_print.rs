//! `antisurge check-config --print`: the effective configuration with the source of every
//! value, one value from each layer (main file, conf.d drop-in, environment, plant file's
//! `[controller]`, default) and the machine file's own lines.

use crate::common;

use std::process::Command;

#[test]
fn print_names_the_source_of_a_value_from_each_layer() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let plant = common::root().join("config/plants/kvangardsnes2009_recycle.toml");
    std::fs::write(
        dir.join("antisurge.toml"),
        format!(
            "[plant]\nfile = \"{}\"\n\n[control]\nlaw = \"recycle-pi\"\n[cycle]\nrate_hz = 500.0\n",
            plant.display()
        ),
    )
    .unwrap();
    std::fs::create_dir(dir.join("conf.d")).unwrap();
    std::fs::write(
        dir.join("conf.d/20-status.toml"),
        "# drop-in\n[status]\nlog_interval_s = 3.0\n",
    )
    .unwrap();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_antisurge"));
    for (k, _) in std::env::vars() {
        if k.starts_with("ANTISURGE_") {
            cmd.env_remove(k);
        }
    }
    let out = cmd
        .args(["check-config", "--print"])
        .arg(dir.join("antisurge.toml"))
        .env("ANTISURGE_CYCLE__RATE_HZ", "250")
        .output()
        .expect("run");
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let line = |key: &str| -> String {
        text.lines()
            .find(|l| l.starts_with(&format!("{key} = ")))
            .unwrap_or_else(|| panic!("no {key}:\n{text}"))
            .to_string()
    };
    // main file, with its line
    let l = line("control.law");
    assert!(
        l.contains("\"recycle-pi\"") && l.ends_with("antisurge.toml:5"),
        "{l}"
    );
    // conf.d drop-in, with its line
    let l = line("status.log_interval_s");
    assert!(
        l.contains("3.0") && l.ends_with("conf.d/20-status.toml:3"),
        "{l}"
    );
    // environment beats the main file
    let l = line("cycle.rate_hz");
    assert!(
        l.contains("250") && l.ends_with("# environment (ANTISURGE_CYCLE__RATE_HZ)"),
        "{l}"
    );
    // the plant file's tuned [controller] table, with its line
    let l = line("controller.recycle_pi.pi.kp_per_map_flow");
    let plant_text = std::fs::read_to_string(&plant).unwrap();
    let n = plant_text
        .lines()
        .position(|x| x.starts_with("kp_per_map_flow"))
        .unwrap()
        + 1;
    assert!(
        l.contains("10.0")
            && l.ends_with(&format!("kvangardsnes2009_recycle.toml:{n} [controller]")),
        "{l}"
    );
    // untouched: the schema default
    let l = line("control.startup_grace_ms");
    assert!(l.ends_with("# default"), "{l}");
}

#[test]
fn print_lists_the_machine_file_values_with_their_lines() {
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(["check-config", "--print"])
        .arg(common::root().join("config/vendor_example.toml"))
        .env_remove("ANTISURGE_CYCLE__RATE_HZ")
        .output()
        .expect("run");
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(out.status.success(), "{text}");
    let l = text
        .lines()
        .find(|l| l.starts_with("surge_line.sqrt_c_m3_s = 0.354"))
        .unwrap_or_else(|| panic!("{text}"));
    let machine =
        std::fs::read_to_string(common::root().join("config/machines/vendor_example.toml"))
            .unwrap();
    let n = machine
        .lines()
        .position(|x| x.starts_with("sqrt_c_m3_s"))
        .unwrap()
        + 1;
    assert!(l.ends_with(&format!("vendor_example.toml:{n}")), "{l}");
}
