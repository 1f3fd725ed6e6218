//! Watch the config directory (not the file: editors save by writing a temporary file and
//! renaming it over the old one, which a watch on the file would lose) and its `conf.d/`.
//! Every relevant change sends one `()`; the service debounces.

use notify::{RecommendedWatcher, RecursiveMode, Watcher};
use std::path::Path;

/// Start watching; keep the returned watcher alive.
pub fn watch_config_dir(
    main: &Path,
    tx: tokio::sync::mpsc::Sender<()>,
) -> notify::Result<RecommendedWatcher> {
    let dir = main
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .to_path_buf();
    let main_name = main.file_name().map(|n| n.to_os_string());
    let conf_d = dir.join("conf.d");
    let conf_d2 = conf_d.clone();
    let mut w = notify::recommended_watcher(move |res: notify::Result<notify::Event>| {
        let Ok(ev) = res else { return };
        if matches!(ev.kind, notify::EventKind::Access(_)) {
            return;
        }
        let relevant = ev.paths.iter().any(|p| {
            p.file_name().map(|n| n.to_os_string()) == main_name
                || (p.starts_with(&conf_d2) && p.extension().is_some_and(|x| x == "toml"))
        });
        if relevant {
            let _ = tx.try_send(());
        }
    })?;
    w.watch(&dir, RecursiveMode::NonRecursive)?;
    if conf_d.is_dir() {
        w.watch(&conf_d, RecursiveMode::NonRecursive)?;
    }
    Ok(w)
}
