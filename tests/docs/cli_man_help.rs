//! The manual pages and `--help`, generated from the command-line definition: `antisurge man
//! --out DIR` writes one page per command (the daemon's `antisurge-run.1` with FILES, EXIT
//! STATUS, ENVIRONMENT and SIGNALS from what the code does), the Debian package ships them,
//! and `antisurge --help` lists the operator's commands before the engineer's tools and the
//! developer's benchmarks.

use crate::common;

use std::process::Command;

fn antisurge(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(args)
        .output()
        .expect("run antisurge");
    assert!(
        out.status.success(),
        "antisurge {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("utf-8")
}

/// The subcommands `antisurge --help` lists, in its order.
fn help_commands() -> Vec<String> {
    let help = antisurge(&["--help"]);
    help.lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter(|l| !l.starts_with("   ")) // a wrapped description's continuation
        .filter_map(|l| l.split_whitespace().next().map(str::to_string))
        .filter(|c| c != "help")
        .collect()
}

#[test]
fn man_out_writes_a_page_per_command_and_the_daemon_page_has_the_four_sections() {
    let dir = tempfile::tempdir().expect("temp dir");
    antisurge(&["man", "--out", dir.path().to_str().expect("utf-8 path")]);
    let mut pages: Vec<String> = std::fs::read_dir(dir.path())
        .expect("read the pages")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    pages.sort();
    assert!(pages.contains(&"antisurge.1".to_string()), "{pages:?}");
    for c in help_commands() {
        assert!(
            pages.contains(&format!("antisurge-{c}.1")),
            "no page for `antisurge {c}`: {pages:?}"
        );
    }
    let run = std::fs::read_to_string(dir.path().join("antisurge-run.1")).expect("antisurge-run.1");
    for section in [
        ".SH \"FILES\"",
        ".SH \"EXIT STATUS\"",
        ".SH \"ENVIRONMENT\"",
        ".SH \"SIGNALS\"",
    ] {
        assert!(
            run.contains(section),
            "antisurge-run.1 lacks {section}:\n{run}"
        );
    }
    // the facts of the daemon's page: its exit statuses and the signals it handles
    for fact in [
        "\\fB78\\fR",
        "\\fB69\\fR",
        "SIGHUP",
        "SIGTERM",
        "/etc/antisurge/antisurge.toml",
    ] {
        let fact_roff = fact.replace('-', "\\-");
        assert!(
            run.contains(fact) || run.contains(&fact_roff),
            "antisurge-run.1 lacks {fact}:\n{run}"
        );
    }
    // every page carries the four sections, and the top-level page points at the others
    for p in &pages {
        let text = std::fs::read_to_string(dir.path().join(p)).expect("page");
        for section in ["FILES", "EXIT STATUS", "ENVIRONMENT", "SIGNALS"] {
            assert!(
                text.contains(&format!(".SH \"{section}\"")),
                "{p} lacks {section}"
            );
        }
    }
    let top = std::fs::read_to_string(dir.path().join("antisurge.1")).expect("antisurge.1");
    assert!(top.contains("\\fBantisurge\\-run\\fR(1)"), "{top}");
    // `antisurge man` alone still prints the top-level page (the .deb's antisurge.1)
    let printed = antisurge(&["man"]);
    assert_eq!(printed, top);
}

#[test]
fn help_lists_operator_commands_first_then_engineer_tools_then_benchmarks() {
    let cmds = help_commands();
    let pos = |c: &str| {
        cmds.iter()
            .position(|x| x == c)
            .unwrap_or_else(|| panic!("`antisurge --help` does not list {c}: {cmds:?}"))
    };
    let operator = [
        "run",
        "status",
        "operate",
        "events",
        "check-config",
        "reload",
        "sim",
    ];
    let engineer = ["plant", "replay", "plot", "completions", "man"];
    let developer = ["table", "bench-matrix", "campaign", "fleet-sim"];
    for w in operator.windows(2) {
        assert!(pos(w[0]) < pos(w[1]), "{cmds:?}");
    }
    let last = |group: &[&str]| group.iter().map(|c| pos(c)).max().expect("a group");
    let first = |group: &[&str]| group.iter().map(|c| pos(c)).min().expect("a group");
    assert!(last(&operator) < first(&engineer), "{cmds:?}");
    assert!(last(&engineer) < first(&developer), "{cmds:?}");
    assert_eq!(
        cmds.len(),
        operator.len() + engineer.len() + developer.len(),
        "a command is in no group: {cmds:?}"
    );
}

#[test]
fn the_debian_package_ships_a_page_per_command() {
    let toml = std::fs::read_to_string(common::root().join("Cargo.toml")).expect("Cargo.toml");
    assert!(
        toml.contains(r#"["target/deb-extra/man/antisurge-*.1.gz", "usr/share/man/man1/", "644"]"#),
        "[package.metadata.deb] assets lack the per-command pages"
    );
}
