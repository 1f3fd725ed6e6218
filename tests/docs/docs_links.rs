//! The documents readers look at stay usable: README.md is short (at most 300 lines), every
//! relative link in README.md and docs/*.md reaches a file of the repository (and, with
//! `#anchor`, a heading of that file, by GitHub's slug rules), and no document cites a
//! tracker number ("issue 12") or a path outside the repository (`../shared/...`): they say
//! what the thing is instead.

use crate::common;

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};

/// The documents checked: README.md and every docs/*.md.
fn documents(root: &Path) -> Vec<PathBuf> {
    let mut docs = vec![root.join("README.md")];
    let mut more: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .expect("docs/")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .collect();
    more.sort();
    assert!(!more.is_empty(), "docs/ holds no .md file");
    docs.extend(more);
    docs
}

/// The lines of a Markdown text outside fenced code blocks, with their 1-based numbers.
fn prose_lines(text: &str) -> Vec<(usize, &str)> {
    let mut out = Vec::new();
    let mut fence: Option<&str> = None;
    for (i, line) in text.lines().enumerate() {
        let t = line.trim_start();
        let marker = if t.starts_with("```") {
            Some("```")
        } else if t.starts_with("~~~") {
            Some("~~~")
        } else {
            None
        };
        match (fence, marker) {
            (None, Some(m)) => fence = Some(m),
            (Some(f), Some(m)) if f == m => fence = None,
            (None, None) => out.push((i + 1, line)),
            _ => {}
        }
    }
    out
}

/// GitHub's anchor for a heading: lower case; letters, digits, `-` and `_` kept, spaces made
/// `-`, everything else dropped (inline code keeps its text, not its backticks).
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| {
            if c.is_alphanumeric() || c == '-' || c == '_' {
                Some(c)
            } else if c == ' ' {
                Some('-')
            } else {
                None
            }
        })
        .collect()
}

/// Every anchor of a Markdown text: its headings' slugs, repeated ones numbered `-1`, `-2` ….
fn anchors(text: &str) -> Vec<String> {
    let mut seen: HashMap<String, usize> = HashMap::new();
    let mut out = Vec::new();
    for (_, line) in prose_lines(text) {
        let t = line.trim_start();
        if !t.starts_with('#') {
            continue;
        }
        let level = t.chars().take_while(|&c| c == '#').count();
        let rest = &t[level..];
        if level > 6 || !(rest.is_empty() || rest.starts_with(' ')) {
            continue;
        }
        let s = slug(rest.trim().trim_end_matches('#'));
        let n = seen.entry(s.clone()).or_insert(0);
        out.push(if *n == 0 {
            s.clone()
        } else {
            format!("{s}-{n}")
        });
        *n += 1;
    }
    out
}

/// The targets of the inline links `[text](target)` of a line (inline code spans skipped).
fn link_targets(line: &str) -> Vec<String> {
    // drop inline code spans: a `[x](y)` inside backticks is not a link
    let mut prose = String::new();
    let mut in_code = false;
    for c in line.chars() {
        if c == '`' {
            in_code = !in_code;
            prose.push(' ');
        } else if !in_code {
            prose.push(c);
        } else {
            prose.push(' ');
        }
    }
    let mut out = Vec::new();
    let b = prose.as_bytes();
    let mut i = 0;
    while let Some(p) = prose[i..].find("](") {
        let open = i + p + 2;
        // the link text must have an opening bracket before it on the line
        if prose[..i + p].contains('[') {
            if let Some(close) = prose[open..].find(')') {
                let target = prose[open..open + close].trim();
                // `[text](target "title")`: the target is the first word
                let target = target.split_whitespace().next().unwrap_or("");
                if !target.is_empty() {
                    out.push(target.to_string());
                }
                i = open + close;
                continue;
            }
        }
        i = open;
        if i >= b.len() {
            break;
        }
    }
    out
}

/// Lexically resolved `base/rel` (no file system access), `None` if it climbs above `/`.
fn resolve(base: &Path, rel: &str) -> Option<PathBuf> {
    let mut out = PathBuf::new();
    for c in base.join(rel).components() {
        match c {
            Component::ParentDir => {
                if !out.pop() {
                    return None;
                }
            }
            Component::CurDir => {}
            other => out.push(other.as_os_str()),
        }
    }
    Some(out)
}

/// The problems of one document: broken links and anchors, tracker numbers, outside paths.
fn problems(root: &Path, doc: &Path, text: &str) -> Vec<String> {
    let name = doc.strip_prefix(root).unwrap_or(doc).display().to_string();
    let dir = doc.parent().expect("a document has a folder");
    let mut out = Vec::new();
    for (n, line) in prose_lines(text) {
        for target in link_targets(line) {
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            let (path, anchor) = match target.split_once('#') {
                Some((p, a)) => (p, Some(a)),
                None => (target.as_str(), None),
            };
            let file = if path.is_empty() {
                doc.to_path_buf()
            } else {
                match resolve(dir, path) {
                    Some(f) => f,
                    None => {
                        out.push(format!(
                            "{name}:{n}: link {target} climbs out of the file system"
                        ));
                        continue;
                    }
                }
            };
            if !file.starts_with(root) {
                out.push(format!("{name}:{n}: link {target} leaves the repository"));
                continue;
            }
            if file != doc && !file.exists() {
                out.push(format!(
                    "{name}:{n}: link {target}: {} does not exist",
                    file.display()
                ));
                continue;
            }
            if let Some(a) = anchor {
                let target_text = if file == doc {
                    text.to_string()
                } else if file.is_file() {
                    std::fs::read_to_string(&file).unwrap_or_default()
                } else {
                    String::new()
                };
                let is_markdown = file.extension().is_some_and(|x| x == "md");
                if !is_markdown || !anchors(&target_text).iter().any(|h| h == a) {
                    out.push(format!(
                        "{name}:{n}: link {target}: no heading with the anchor #{a} in {}",
                        file.strip_prefix(root).unwrap_or(&file).display()
                    ));
                }
            }
        }
    }
    // tracker numbers and outside paths, anywhere (code blocks included)
    for (i, line) in text.lines().enumerate() {
        let lower = line.to_lowercase();
        let mut from = 0;
        while let Some(p) = lower[from..].find("issue") {
            let after = &lower[from + p + "issue".len()..];
            let after = after.strip_prefix('s').unwrap_or(after).trim_start();
            let after = after.strip_prefix('#').unwrap_or(after);
            if after.starts_with(|c: char| c.is_ascii_digit()) {
                out.push(format!(
                    "{name}:{}: cites a tracker number (say what it is instead): {}",
                    i + 1,
                    line.trim()
                ));
            }
            from += p + "issue".len();
        }
        if line.contains("../shared") {
            out.push(format!(
                "{name}:{}: a path outside the repository: {}",
                i + 1,
                line.trim()
            ));
        }
    }
    out
}

#[test]
fn readme_is_at_most_300_lines() {
    let text = std::fs::read_to_string(common::root().join("README.md")).expect("README.md");
    let n = text.lines().count();
    assert!(
        n <= 300,
        "README.md has {n} lines: keep it for the operator and move the rest into docs/"
    );
}

#[test]
fn every_relative_link_resolves_and_no_document_cites_a_tracker_or_an_outside_path() {
    let root = common::root()
        .canonicalize()
        .expect("the repository's root");
    let mut all = Vec::new();
    for doc in documents(&root) {
        let text = std::fs::read_to_string(&doc).expect("document");
        all.extend(problems(&root, &doc, &text));
    }
    assert!(
        all.is_empty(),
        "{} problems:\n{}",
        all.len(),
        all.join("\n")
    );
}

/// The checks can fail: a broken link, a missing anchor, a tracker number and an outside path
/// in a document written here are each reported.
#[test]
fn the_checks_find_what_they_are_for() {
    let root = common::root()
        .canonicalize()
        .expect("the repository's root");
    let doc = root.join("docs").join("made-up.md");
    let text = "# Title\n\n## A `code` heading: × and more\n\n\
                [ok](#a-code-heading--and-more) [ok](../README.md#the-two-commands) \
                [ok](operator-guide.md)\n\
                [bad](no-such-file.md) [bad](operator-guide.md#no-such-heading) [bad](#nowhere)\n\
                see issue 12, and (issue #7)\n\
                `../shared/seeds/ERRATA.md`\n\
                ```\n[in a fence](not-checked.md)\n```\n";
    let found = problems(&root, &doc, text);
    let count = |s: &str| found.iter().filter(|p| p.contains(s)).count();
    assert_eq!(count("no-such-file.md"), 1, "{found:#?}");
    assert_eq!(count("#no-such-heading"), 1, "{found:#?}");
    assert_eq!(count("#nowhere"), 1, "{found:#?}");
    assert_eq!(count("tracker number"), 2, "{found:#?}");
    assert_eq!(count("outside the repository"), 1, "{found:#?}");
    assert_eq!(found.len(), 6, "{found:#?}");
}

#[test]
fn slugs_follow_github() {
    assert_eq!(
        slug("Results: every plant × every law"),
        "results-every-plant--every-law"
    );
    assert_eq!(
        slug("Commissioning from vendor data (`config/machines/`)"),
        "commissioning-from-vendor-data-configmachines"
    );
    assert_eq!(
        slug("ESD: the valve's stroke and the drive's trip contact"),
        "esd-the-valves-stroke-and-the-drives-trip-contact"
    );
    assert_eq!(
        anchors("# A\n## A\n```\n# not a heading\n```\n## A\n"),
        ["a", "a-1", "a-2"]
    );
}
