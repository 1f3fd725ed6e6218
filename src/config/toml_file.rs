//! Loading TOML files so that every error names the file, the key path and the line.
//!
//! Deserialization goes through `serde_path_to_error` (the key path) over `toml`'s
//! deserializer (the byte span → line). Checks that run after deserialization (ranges,
//! cross-field rules) report a key path; [`locate_key`] finds its line with `toml_edit` spans.

use serde::de::DeserializeOwned;
use std::fmt;
use std::path::{Path, PathBuf};

/// A problem in a config file, located as precisely as possible.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct FileError {
    /// The file.
    pub file: PathBuf,
    /// Dotted key path (`recycle_system.v1_m3`, `event[2].at_s`); empty for syntax errors
    /// outside any key.
    pub key: String,
    /// 1-based line, 0 if unknown.
    pub line: usize,
    /// 1-based column, 0 if unknown.
    pub column: usize,
    /// What is wrong.
    pub message: String,
    /// How to fix it, when we can tell.
    pub hint: Option<String>,
}

impl fmt::Display for FileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if self.line > 0 {
            write!(f, ":{}:{}", self.line, self.column)?;
        }
        if !self.key.is_empty() {
            write!(f, ": key `{}`", self.key)?;
        }
        write!(f, ": {}", self.message)?;
        if let Some(h) = &self.hint {
            write!(f, "\n  hint: {h}")?;
        }
        Ok(())
    }
}

impl FileError {
    /// An error about `key` in the file whose text is `text`; the line is looked up.
    pub fn at_key(file: &Path, text: &str, key: &str, message: impl Into<String>) -> FileError {
        let (line, column) = locate_key(text, key).unwrap_or((0, 0));
        FileError {
            file: file.to_path_buf(),
            key: key.to_string(),
            line,
            column,
            message: message.into(),
            hint: None,
        }
    }

    /// Attach a hint.
    pub fn with_hint(mut self, hint: impl Into<String>) -> FileError {
        self.hint = Some(hint.into());
        self
    }
}

/// Read and deserialize a TOML file.
pub fn load<T: DeserializeOwned>(path: &Path) -> Result<(T, String), FileError> {
    let text = super::bounded::read_config_text(path).map_err(|e| FileError {
        file: path.to_path_buf(),
        key: String::new(),
        line: 0,
        column: 0,
        message: format!("cannot read: {e}"),
        hint: None,
    })?;
    let value = parse(&text, path)?;
    Ok((value, text))
}

/// Deserialize TOML text; `path` is only used in messages.
pub fn parse<T: DeserializeOwned>(text: &str, path: &Path) -> Result<T, FileError> {
    let de = toml::de::Deserializer::parse(text).map_err(|e| syntax_error(text, path, &e))?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let key = e.path().to_string();
        let key = if key == "." { String::new() } else { key };
        let inner = e.into_inner();
        let (mut line, mut column) = inner
            .span()
            .map(|s| line_col(text, s.start))
            .unwrap_or((0, 0));
        if line == 0 && !key.is_empty() {
            if let Some((l, c)) = locate_key(text, &key) {
                line = l;
                column = c;
            }
        }
        let message = inner.message().trim().to_string();
        let hint = hint_for(&message);
        FileError {
            file: path.to_path_buf(),
            key,
            line,
            column,
            message,
            hint,
        }
    })
}

fn syntax_error(text: &str, path: &Path, e: &toml::de::Error) -> FileError {
    let (line, column) = e.span().map(|s| line_col(text, s.start)).unwrap_or((0, 0));
    FileError {
        file: path.to_path_buf(),
        key: String::new(),
        line,
        column,
        message: format!("TOML syntax error: {}", e.message().trim()),
        hint: Some("check quotes, brackets and `key = value` pairs on that line".into()),
    }
}

fn hint_for(message: &str) -> Option<String> {
    if message.starts_with("unknown field") {
        // serde lists the expected fields; a typo in a unit suffix is the usual cause
        Some("keys carry their unit (`_pa`, `_kg_s`, `_m3`, `_s`, `_rad_s`); check spelling against the list above or the annotated config/antisurge.toml (every key with its unit)".into())
    } else if message.starts_with("missing field") {
        Some("add the key; see the commented examples under config/".into())
    } else if message.starts_with("invalid type") {
        Some("numbers without quotes, text in quotes, lists in [ ]".into())
    } else if message.starts_with("unknown variant") {
        Some("use one of the listed names".into())
    } else {
        None
    }
}

/// 1-based (line, column) of a byte offset.
pub fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.rfind('\n').map_or(offset, |nl| offset - nl - 1) + 1;
    (line, col)
}

/// Find the (line, column) where a dotted key path (`a.b[2].c`) is written in `text`.
/// Falls back to the nearest existing parent key.
pub fn locate_key(text: &str, key: &str) -> Option<(usize, usize)> {
    enum Node<'a> {
        Item(&'a toml_edit::Item),
        Table(&'a toml_edit::Table),
    }
    let doc = toml_edit::Document::parse(text).ok()?;
    let mut node = Node::Table(doc.as_table());
    let mut best: Option<usize> = None;
    for seg in split_path(key) {
        match seg {
            Seg::Key(k) => {
                let table: &dyn toml_edit::TableLike = match node {
                    Node::Item(i) => match i.as_table_like() {
                        Some(t) => t,
                        None => break,
                    },
                    Node::Table(t) => t,
                };
                let Some((kk, next)) = table.get_key_value(k) else {
                    break;
                };
                if let Some(span) = kk.span() {
                    best = Some(span.start);
                }
                node = Node::Item(next);
            }
            Seg::Index(i) => {
                let Node::Item(item) = node else { break };
                if let Some(arr) = item.as_array_of_tables() {
                    let Some(t) = arr.get(i) else { break };
                    if let Some(span) = t.span() {
                        best = Some(span.start);
                    }
                    node = Node::Table(t);
                } else if let Some(arr) = item.as_array() {
                    if let Some(span) = arr.get(i).and_then(|v| v.span()) {
                        best = Some(span.start);
                    }
                    break;
                } else {
                    break;
                }
            }
        }
    }
    best.map(|o| line_col(text, o))
}

enum Seg<'a> {
    Key(&'a str),
    Index(usize),
}

fn split_path(path: &str) -> Vec<Seg<'_>> {
    let mut out = Vec::new();
    for part in path.split('.') {
        if part.is_empty() {
            continue;
        }
        match part.find('[') {
            Some(b) => {
                if b > 0 {
                    out.push(Seg::Key(&part[..b]));
                }
                let mut rest = &part[b..];
                while let Some(stripped) = rest.strip_prefix('[') {
                    let end = match stripped.find(']') {
                        Some(e) => e,
                        None => break,
                    };
                    if let Ok(i) = stripped[..end].parse() {
                        out.push(Seg::Index(i));
                    }
                    rest = &stripped[end + 1..];
                }
            }
            None => out.push(Seg::Key(part)),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Inner {
        volume_m3: f64,
    }
    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Outer {
        name: String,
        plenum: Inner,
    }

    #[test]
    fn unknown_key_names_path_and_line() {
        let text = "name = \"x\"\n\n[plenum]\nvolume_m = 3.0\n";
        let err = parse::<Outer>(text, Path::new("p.toml")).unwrap_err();
        assert_eq!(err.line, 4, "{err}");
        assert!(err.message.contains("unknown field `volume_m`"), "{err}");
        assert!(err.to_string().starts_with("p.toml:4:"), "{err}");
        assert!(err.hint.is_some());
    }

    #[test]
    fn wrong_type_names_key() {
        let text = "name = \"x\"\n[plenum]\nvolume_m3 = \"big\"\n";
        let err = parse::<Outer>(text, Path::new("p.toml")).unwrap_err();
        assert_eq!(err.key, "plenum.volume_m3", "{err}");
        assert_eq!(err.line, 3, "{err}");
    }

    #[test]
    fn syntax_error_has_line() {
        let text = "name = \"x\"\n[plenum\nvolume_m3 = 1\n";
        let err = parse::<Outer>(text, Path::new("p.toml")).unwrap_err();
        assert_eq!(err.line, 2, "{err}");
        assert!(err.message.contains("syntax"));
    }

    #[test]
    fn locate_nested_key() {
        let text = "a = 1\n[b]\nc = 2\n[b.d]\ne = 3\n";
        assert_eq!(locate_key(text, "b.c"), Some((3, 1)));
        assert_eq!(locate_key(text, "b.d.e"), Some((5, 1)));
        // missing leaf falls back to parent
        assert_eq!(locate_key(text, "b.d.zz"), Some((4, 4)));
    }

    #[test]
    fn locate_in_array_of_tables() {
        let text = "[[event]]\nat_s = 1\n\n[[event]]\nat_s = 2\n";
        let (line, _) = locate_key(text, "event[1].at_s").expect("found");
        assert_eq!(line, 5, "the key itself, inside the second [[event]]");
    }
}
