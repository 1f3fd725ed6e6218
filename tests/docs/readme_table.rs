//! docs/benchmarks.md's results table is the output of `antisurge table`, not a copy that can drift:
//! this test reruns the command and compares it with the block between the markers.

use crate::common;

use std::process::Command;

#[test]
fn readme_table_is_the_output_of_antisurge_table() {
    let readme = std::fs::read_to_string(common::root().join("docs/benchmarks.md"))
        .expect("docs/benchmarks.md");
    let begin = "<!-- table:begin -->\n";
    let end = "<!-- table:end -->";
    let start = readme
        .find(begin)
        .expect("docs/benchmarks.md lacks <!-- table:begin -->")
        + begin.len();
    let stop = readme[start..]
        .find(end)
        .expect("docs/benchmarks.md lacks <!-- table:end -->")
        + start;
    let in_readme = &readme[start..stop];

    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .arg("table")
        .arg("--config-dir")
        .arg(common::root().join("config"))
        .output()
        .expect("run antisurge table");
    assert!(
        out.status.success(),
        "antisurge table failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let fresh = String::from_utf8(out.stdout).expect("utf-8");
    assert!(fresh.lines().count() >= 3 + 5, "table too short:\n{fresh}");
    assert_eq!(
        in_readme, fresh,
        "docs/benchmarks.md's table differs from `antisurge table`: rerun `cargo run --release -- table` and paste its output between the markers"
    );
}

#[test]
fn readme_inertia_sweep_is_the_output_of_antisurge_table() {
    let readme = std::fs::read_to_string(common::root().join("docs/benchmarks.md"))
        .expect("docs/benchmarks.md");
    let begin = "<!-- inertia:begin -->\n";
    let start = readme
        .find(begin)
        .expect("docs/benchmarks.md lacks <!-- inertia:begin -->")
        + begin.len();
    let stop = readme[start..]
        .find("<!-- inertia:end -->")
        .expect("docs/benchmarks.md lacks <!-- inertia:end -->")
        + start;
    let out = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(["table", "--inertia-sweep", "bohagen2007", "--config-dir"])
        .arg(common::root().join("config"))
        .output()
        .expect("run antisurge table --inertia-sweep");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let fresh = String::from_utf8(out.stdout).expect("utf-8");
    assert_eq!(
        &readme[start..stop],
        fresh,
        "docs/benchmarks.md's inertia sweep differs: rerun `cargo run --release -- table --inertia-sweep bohagen2007`"
    );
}
