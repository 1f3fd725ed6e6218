//! `[controller]`: overrides of the tuned controller settings (law gains, observer, detector),
//! applied over the plant file's `[controller]` table (or the schema's defaults for a machine
//! file), and their documented plausibility bounds.

use super::layers::{hint_for, locate, serde_error_key, Layer};
use super::problem::KeyProblem;
use crate::config::FileError;
use crate::control::config::ControllerConfig;

/// Deep-merge `over` into `base` (a fully serialized settings table). A one-key table of
/// `base` whose key `over` does not repeat is an enum variant (`control_line = { sqrt = … }`)
/// and is replaced by the other variant, not merged with it.
pub(super) fn deep_merge(base: &mut toml::Table, over: &toml::Table) {
    for (k, v) in over {
        match (base.get_mut(k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o))
                if !(b.len() == 1 && b.keys().all(|bk| !o.contains_key(bk))) =>
            {
                deep_merge(b, o)
            }
            _ => {
                base.insert(k.clone(), v.clone());
            }
        }
    }
}

/// The plant file's controller settings with the `[controller]` overrides applied.
pub fn controller_settings(
    layers: &[Layer],
    base: &ControllerConfig,
    over: &toml::Table,
) -> Result<ControllerConfig, FileError> {
    if over.is_empty() {
        return Ok(base.clone());
    }
    let mut table = toml::Table::try_from(base).map_err(|e| FileError {
        file: layers[0].path.clone(),
        key: "controller".into(),
        line: 0,
        column: 0,
        message: format!("cannot represent the plant's controller settings: {e}"),
        hint: None,
    })?;
    deep_merge(&mut table, over);
    let text = toml::to_string(&table).unwrap_or_default();
    let de = toml::de::Deserializer::parse(&text).map_err(|e| FileError {
        file: layers[0].path.clone(),
        key: "controller".into(),
        line: 0,
        column: 0,
        message: e.to_string(),
        hint: None,
    })?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let key = format!("controller.{}", e.path());
        let message = e.into_inner().message().trim().to_string();
        let key = serde_error_key(layers, &key, &message);
        let mut err = locate(layers, &key, message.clone());
        err.hint = hint_for(&message, &key);
        err
    })
}

/// The documented plausibility bounds of the effective settings (`control/config.rs`),
/// before any law sees them.
pub fn validate(c: &ControllerConfig) -> Vec<KeyProblem> {
    c.plausibility_problems()
        .into_iter()
        .map(|(key, message)| {
            KeyProblem::error(format!("controller.{key}"), message).with_hint(
                "the seed defaults are in the plant files; change a gain by a factor of 2 at a time",
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(text: &str) -> toml::Table {
        toml::from_str(text).expect("toml")
    }

    #[test]
    fn deep_merge_merges_tables_and_replaces_enum_variants() {
        let mut base = t("[a]\nx = 1\ny = 2\n[a.line]\nsqrt = { c = 1.0 }\n");
        deep_merge(
            &mut base,
            &t("[a]\ny = 3\n[a.line]\nmargin = { margin_pct = 10.0 }\n"),
        );
        assert_eq!(base["a"]["x"].as_integer(), Some(1));
        assert_eq!(base["a"]["y"].as_integer(), Some(3));
        let line = base["a"]["line"].as_table().expect("line");
        assert!(
            line.contains_key("margin") && !line.contains_key("sqrt"),
            "{line:?}"
        );
    }

    #[test]
    fn defaults_are_plausible() {
        let c: ControllerConfig = toml::from_str("").expect("defaults");
        assert!(validate(&c).is_empty(), "{:?}", validate(&c));
    }
}
