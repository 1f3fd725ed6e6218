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
        } else if p.extension().is_some_and(|x| x == "rs") && !is_test_module(&p) {
            out.push(p);
        }
    }
    out.sort();
    out
}

/// Whether `p` is a test module in a file of its own: a `tests.rs` its parent module declares
/// under `#[cfg(test)]` (`mod.rs` beside it, or `<dir>.rs` beside its folder).
fn is_test_module(p: &Path) -> bool {
    if p.file_name().is_none_or(|n| n != "tests.rs") {
        return false;
    }
    let Some(dir) = p.parent() else { return false };
    [dir.join("mod.rs"), dir.with_extension("rs")]
        .iter()
        .filter_map(|f| std::fs::read_to_string(f).ok())
        .any(|t| t.contains("#[cfg(test)]\nmod tests;"))
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
fn a_test_module_in_a_file_of_its_own_is_skipped_and_only_that() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    assert!(is_test_module(&src.join("control/core/tests.rs")));
    assert!(is_test_module(&src.join("io/modbus/link/tests.rs")));
    assert!(!is_test_module(&src.join("control/core/mod.rs")));
    assert!(!is_test_module(&src.join("io/can/bus/tests_missing.rs")));
    let files = rust_files(&src.join("control"));
    assert!(files.iter().any(|f| f.ends_with("control/core/mod.rs")));
    assert!(!files.iter().any(|f| f.ends_with("control/core/tests.rs")));
}

#[test]
fn the_scan_sees_a_violation_and_skips_test_modules() {
    let code = "use crate::plant::spool::SpoolPlant;\nfn f() {}\n#[cfg(test)]\nmod tests {\n    use crate::plant::file::PlantDescription;\n}\n";
    let kept = non_test_code(code);
    assert!(kept.contains("crate::plant::spool"));
    assert!(!kept.contains("PlantDescription"));
    assert!(!non_test_code("// see crate::plant::spool\nfn f() {}").contains("crate::plant"));
}

// ---------------------------------------------------------------------------------------------
// The layout (issue 27): the ground floor imports nothing, lower parts do not reach higher ones,
// and no two folders reach each other. The rules that do not hold yet are named, dated
// exceptions below; an exception that no longer occurs fails the test, so the list only shrinks.
// ---------------------------------------------------------------------------------------------

/// Known arrows from `live/` into `daemon/`: none (`live/` owns its `[status]` and TLS
/// settings since 2026-11-29, `live/settings.rs` and `live/tls_settings.rs`; the daemon's
/// config re-exports them).
const LIVE_TO_DAEMON: &[(&str, &str)] = &[];

/// Known arrows from `io/` into `control/`: none (the signal map's vote settings are
/// vocabulary since 2026-11-29, `vocab/vote.rs`).
const IO_TO_CONTROL: &[(&str, &str)] = &[];

/// Known pairs of folders that reach each other: none since 2026-11-29 (`live/` and
/// `sparkplug/` own their config sections; the daemon's config re-exports them).
const KNOWN_CIRCLES: &[(&str, &str)] = &[];

fn src_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// The `crate::a::b::c` paths a text names (identifiers joined by `::`, lower case only:
/// modules, not types).
fn crate_paths(code: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        let before = rest[..i].chars().last();
        rest = &rest[i + "crate::".len()..];
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue; // `antisurge_crate::` or similar
        }
        let mut segs = Vec::new();
        let mut s = rest;
        loop {
            let n = s
                .find(|c: char| !(c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_'))
                .unwrap_or(s.len());
            if n == 0 {
                break;
            }
            segs.push(s[..n].to_string());
            s = &s[n..];
            match s.strip_prefix("::") {
                Some(t) => s = t,
                None => break,
            }
        }
        if !segs.is_empty() {
            out.push(segs);
        }
    }
    out
}

/// The file a module path lands in (the deepest `a/b.rs` or `a/b/mod.rs` that exists).
fn module_file(segs: &[String]) -> Option<PathBuf> {
    let mut dir = src_root();
    let mut best = None;
    for s in segs {
        let file = dir.join(format!("{s}.rs"));
        let module = dir.join(s).join("mod.rs");
        if file.is_file() {
            best = Some(file);
        } else if module.is_file() {
            best = Some(module);
        } else {
            break;
        }
        dir = dir.join(s);
    }
    best
}

/// A file's folder below `src/` (`""` for the crate root's files).
fn folder_of(file: &Path) -> String {
    file.parent()
        .and_then(|p| p.strip_prefix(src_root()).ok())
        .map(|p| p.display().to_string())
        .unwrap_or_default()
}

/// Arrows between folders from the `crate::` paths of non-test code (test-only files named
/// `tests.rs` left out), with one example per arrow.
fn folder_graph() -> std::collections::BTreeMap<(String, String), String> {
    let mut arrows = std::collections::BTreeMap::new();
    for f in rust_files(&src_root()) {
        if f.file_name().is_some_and(|n| n == "tests.rs") {
            continue;
        }
        let code = non_test_code(&std::fs::read_to_string(&f).expect("read"));
        let from = folder_of(&f);
        for segs in crate_paths(&code) {
            let Some(target) = module_file(&segs) else {
                continue;
            };
            let to = folder_of(&target);
            if to != from {
                arrows
                    .entry((from.clone(), to))
                    .or_insert_with(|| format!("{} → crate::{}", f.display(), segs.join("::")));
            }
        }
    }
    arrows
}

/// Pairs of folders that reach each other, each once (a, b) with a < b.
fn circles(
    arrows: &std::collections::BTreeMap<(String, String), String>,
) -> std::collections::BTreeSet<(String, String)> {
    use std::collections::{BTreeMap, BTreeSet};
    let mut next: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for (a, b) in arrows.keys() {
        next.entry(a).or_default().push(b);
    }
    let reach = |start: &str| {
        let mut seen = BTreeSet::new();
        let mut todo = vec![start.to_string()];
        while let Some(x) = todo.pop() {
            for y in next.get(x.as_str()).into_iter().flatten() {
                if seen.insert(y.to_string()) {
                    todo.push(y.to_string());
                }
            }
        }
        seen
    };
    let folders: BTreeSet<&str> = arrows
        .keys()
        .flat_map(|(a, b)| [a.as_str(), b.as_str()])
        .collect();
    let reached: BTreeMap<&str, BTreeSet<String>> =
        folders.iter().map(|f| (*f, reach(f))).collect();
    let mut out = BTreeSet::new();
    for (a, ra) in &reached {
        for b in ra {
            if *a < b.as_str() && reached.get(b.as_str()).is_some_and(|rb| rb.contains(*a)) {
                out.insert((a.to_string(), b.clone()));
            }
        }
    }
    out
}

/// `violations` with named exceptions, and the exceptions that no longer occur.
fn rule(dir: &str, forbidden: &[&str], known: &[(&str, &str)]) -> (Vec<String>, Vec<String>) {
    let found = violations(dir, forbidden, known);
    let all = violations(dir, forbidden, &[]);
    let stale = known
        .iter()
        .filter(|(file, what)| !all.iter().any(|v| v.starts_with(file) && v.contains(what)))
        .map(|(file, what)| format!("{file}: {what}"))
        .collect();
    (found, stale)
}

#[test]
fn the_ground_floor_imports_nothing_of_the_crate() {
    let v = violations("vocab", &["crate::", "super::super"], &[]);
    assert!(
        v.is_empty(),
        "vocab/ must import nothing of the crate:\n{}",
        v.join("\n")
    );
}

#[test]
fn live_does_not_reach_into_the_daemon() {
    let (v, stale) = rule("live", &["crate::daemon"], LIVE_TO_DAEMON);
    assert!(
        v.is_empty(),
        "live/ uses daemon/ (the daemon composes live/, not the reverse):\n{}",
        v.join("\n")
    );
    assert!(
        stale.is_empty(),
        "fixed, remove from LIVE_TO_DAEMON:\n{}",
        stale.join("\n")
    );
}

#[test]
fn the_real_time_nodes_do_not_use_the_daemon_or_a_runtime() {
    // node/ is the per-cycle body of a real-time thread: the daemon wires it, never the
    // reverse, and no async runtime, socket or file enters it
    let v = violations(
        "node",
        &["crate::daemon", "tokio", "std::net", "std::fs::"],
        &[],
    );
    assert!(
        v.is_empty(),
        "node/ reaches out of its cycle:\n{}",
        v.join("\n")
    );
}

#[test]
fn the_field_buses_do_not_reach_into_the_controller() {
    let (v, stale) = rule("io", &["crate::control"], IO_TO_CONTROL);
    assert!(v.is_empty(), "io/ uses control/:\n{}", v.join("\n"));
    assert!(
        stale.is_empty(),
        "fixed, remove from IO_TO_CONTROL:\n{}",
        stale.join("\n")
    );
}

#[test]
fn no_two_folders_reach_each_other() {
    let arrows = folder_graph();
    assert!(
        arrows.len() > 20,
        "the scan sees the crate's arrows: {}",
        arrows.len()
    );
    let found = circles(&arrows);
    let known: std::collections::BTreeSet<(String, String)> = KNOWN_CIRCLES
        .iter()
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect();
    let example = |a: &str, b: &str| {
        let k = (a.to_string(), b.to_string());
        arrows
            .get(&k)
            .cloned()
            .unwrap_or_else(|| format!("{a} → … → {b}"))
    };
    let new: Vec<String> = found
        .difference(&known)
        .map(|(a, b)| format!("{a} ⇄ {b}: {} / {}", example(a, b), example(b, a)))
        .collect();
    assert!(
        new.is_empty(),
        "folders that reach each other:\n{}",
        new.join("\n")
    );
    let stale: Vec<String> = known
        .difference(&found)
        .map(|(a, b)| format!("{a} ⇄ {b}"))
        .collect();
    assert!(
        stale.is_empty(),
        "fixed, remove from KNOWN_CIRCLES:\n{}",
        stale.join("\n")
    );
}

#[test]
fn the_folder_scan_resolves_paths_and_sees_a_circle() {
    let p = crate_paths(
        "use crate::control::law::api::{LawId, LawInputs};\nlet x = crate::vocab::Mode::Auto;",
    );
    assert_eq!(p[0], ["control", "law", "api"]);
    assert_eq!(p[1], ["vocab"]);
    let f = module_file(&p[0]).expect("file");
    assert_eq!(folder_of(&f), "control/law");
    let mut arrows = std::collections::BTreeMap::new();
    arrows.insert(("a".to_string(), "b".to_string()), String::new());
    arrows.insert(("b".to_string(), "c".to_string()), String::new());
    assert!(circles(&arrows).is_empty());
    arrows.insert(("c".to_string(), "a".to_string()), String::new());
    assert_eq!(circles(&arrows).len(), 3, "a, b, c reach each other");
}
