//! Issue 25, items 3 and 4: the shipped unit, the Debian package's drop-in and check-config
//! agree.
//!
//! - `check-config` refuses a listen port the unit's capabilities cannot bind, naming
//!   `AmbientCapabilities` (the rule embeds `deploy/antisurge.service`).
//! - the package's drop-in replaces every unit line that names `/usr/local` (ExecStart,
//!   ExecReload, Documentation) with the packaged paths, and those paths are assets of the
//!   package (`[package.metadata.deb]`).

use crate::common;

use antisurge::daemon::config::unit::{grants_net_bind, unit_list, SHIPPED_UNIT};
use std::process::Command;

const DROP_IN: &str = include_str!("../../deploy/deb/usr-bin.conf");

fn lines<'a>(text: &'a str, key: &str) -> Vec<&'a str> {
    text.lines()
        .filter_map(|l| l.strip_prefix(key)?.strip_prefix('='))
        .collect()
}

#[test]
fn the_package_drop_in_replaces_every_usr_local_line() {
    for key in ["ExecStart", "ExecReload", "Documentation"] {
        let unit = lines(SHIPPED_UNIT, key);
        let drop = lines(DROP_IN, key);
        assert!(!unit.is_empty(), "{key} in the unit");
        assert_eq!(drop.first(), Some(&""), "the drop-in first clears {key}");
        let expected: Vec<String> = unit
            .iter()
            .map(|l| {
                l.replace("/usr/local/bin/", "/usr/bin/")
                    .replace("/usr/local/share/doc/", "/usr/share/doc/")
                    // /bin/kill is procps, not in a minimal Debian: the shell's kill
                    .replace(
                        "/bin/kill -HUP $MAINPID",
                        "/usr/bin/antisurge reload --pid $MAINPID /etc/antisurge/antisurge.toml",
                    )
            })
            .collect();
        let got: Vec<String> = drop[1..]
            .iter()
            .map(|l| l.replace(" man:antisurge(1)", ""))
            .collect();
        assert_eq!(got, expected, "{key}: the drop-in's lines");
        assert!(
            drop.iter().all(|l| !l.contains("/usr/local")),
            "{key}: {drop:?}"
        );
    }
    // what the drop-in names is installed by the package
    let cargo = std::fs::read_to_string(common::root().join("Cargo.toml")).expect("Cargo.toml");
    for asset in [
        r#"["target/release/antisurge", "usr/bin/""#,
        r#"["README.md", "usr/share/doc/antisurge/""#,
        r#"["target/deb-extra/antisurge.1.gz", "usr/share/man/man1/""#,
    ] {
        assert!(
            cargo.contains(asset),
            "Cargo.toml [package.metadata.deb] lacks {asset}"
        );
    }
    // the reload checks against the running configuration, then signals and waits for the
    // daemon's answer
    let reload = lines(DROP_IN, "ExecReload");
    assert_eq!(
        reload[1..],
        [
            "/usr/bin/antisurge check-config --against-running /etc/antisurge/antisurge.toml",
            "/usr/bin/antisurge reload --pid $MAINPID /etc/antisurge/antisurge.toml"
        ]
    );
    // the package grants no more than the unit
    assert!(unit_list([DROP_IN], "AmbientCapabilities").is_empty());
    assert!(!grants_net_bind(&[SHIPPED_UNIT, DROP_IN]));
}

fn check_config(dir: &std::path::Path, status: &str) -> (i32, String) {
    let cfg = dir.join("antisurge.toml");
    std::fs::write(
        &cfg,
        format!(
            "[plant]\nfile = \"{}\"\n[control]\nlaw = \"recycle-pi\"\n[status]\n{status}\n",
            common::daemon::shipped("plants/kvangardsnes2009_recycle.toml")
        ),
    )
    .expect("write");
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .arg("check-config")
        .arg(&cfg)
        .output()
        .expect("check-config");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn check_config_refuses_a_port_the_unit_cannot_bind() {
    let tmp = tempfile::tempdir().expect("tmp");
    let start: u16 = std::fs::read_to_string("/proc/sys/net/ipv4/ip_unprivileged_port_start")
        .ok()
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(1024);
    if start <= 502 {
        eprintln!("this kernel lets everyone bind port 502 (ip_unprivileged_port_start = {start}): nothing to refuse");
        return;
    }
    let (code, err) = check_config(tmp.path(), "modbus_listen = \"0.0.0.0:502\"");
    assert_eq!(code, 78, "{err}");
    assert!(
        err.contains("status.modbus_listen") && err.contains("AmbientCapabilities"),
        "{err}"
    );
    assert!(err.contains("CAP_NET_BIND_SERVICE"), "{err}");
    let (code, err) = check_config(tmp.path(), "modbus_listen = \"0.0.0.0:1502\"");
    assert_eq!(code, 0, "{err}");
}
