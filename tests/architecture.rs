//! The dependency direction of issue 14, item 3: the controller depends on the machine
//! description and physics, never on the simulator's plant models; the plant models never on
//! the controller; physics and the machine description on neither. Test-only code
//! (`#[cfg(test)] mod …` at the end of a file) may use the plant to build fixtures.

use std::path::{Path, PathBuf};

/// Every `.rs` file under `dir`.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).expect("read_dir") {
        let p = e.expect("entry").path();
        if p.is_dir() {
            out.extend(rust_files(&p));
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
    out.sort();
    out
}

/// The file's text before its test module (a `#[cfg(test)]` line followed by `mod`), with
/// comments removed.
fn non_test_code(text: &str) -> String {
    let lines: Vec<&str> = text.lines().collect();
    let end = lines
        .windows(2)
        .position(|w| {
            w[0].trim() == "#[cfg(test)]"
                && (w[1].trim_start().starts_with("mod ")
                    || w[1].trim_start().starts_with("pub mod "))
        })
        .unwrap_or(lines.len());
    lines[..end]
        .iter()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// (file:line, line) of every non-test line under `src/<dir>` naming one of `forbidden`.
fn violations(dir: &str, forbidden: &[&str], allowed: &[(&str, &str)]) -> Vec<String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src").join(dir);
    let mut out = Vec::new();
    for f in rust_files(&root) {
        let text = std::fs::read_to_string(&f).expect("read");
        let rel = f
            .strip_prefix(env!("CARGO_MANIFEST_DIR"))
            .unwrap_or(&f)
            .display()
            .to_string();
        for (i, line) in non_test_code(&text).lines().enumerate() {
            let hit = forbidden.iter().any(|p| line.contains(p));
            let excused = allowed
                .iter()
                .any(|(file, what)| rel.ends_with(file) && line.contains(what));
            if hit && !excused {
                out.push(format!("{rel}:{}: {}", i + 1, line.trim()));
            }
        }
    }
    out
}

#[test]
fn the_controller_does_not_use_the_plant_models() {
    let v = violations("control", &["crate::plant", "crate::sim"], &[]);
    assert!(
        v.is_empty(),
        "control/ uses the simulator (move the shared equations to machine/ or physics/):\n{}",
        v.join("\n")
    );
}

#[test]
fn physics_and_the_machine_description_use_neither_plant_nor_controller() {
    for dir in ["physics", "machine"] {
        let v = violations(dir, &["crate::plant", "crate::control", "crate::sim"], &[]);
        assert!(v.is_empty(), "{dir}/ depends upward:\n{}", v.join("\n"));
    }
}

#[test]
fn the_plant_models_do_not_use_the_controller() {
    // No exception: a plant file's `[controller]` table is read by the simulation layer
    // (`sim::case::PlantCase`), which pairs it with the plant description.
    let v = violations(
        "plant",
        &["crate::control", "crate::daemon", "crate::sim"],
        &[],
    );
    assert!(
        v.is_empty(),
        "plant/ uses the controller (the sim/runner or daemon composes plant + controller):\n{}",
        v.join("\n")
    );
}

#[test]
fn the_scan_sees_a_violation_and_skips_test_modules() {
    let code = "use crate::plant::spool::SpoolPlant;\nfn f() {}\n#[cfg(test)]\nmod tests {\n    use crate::plant::file::PlantDescription;\n}\n";
    let kept = non_test_code(code);
    assert!(kept.contains("crate::plant::spool"));
    assert!(!kept.contains("PlantDescription"));
    assert!(!non_test_code("// see crate::plant::spool\nfn f() {}").contains("crate::plant"));
}
