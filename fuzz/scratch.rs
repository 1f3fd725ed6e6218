//! A scratch directory per fuzzing process (the loaders under test take paths).
use std::path::PathBuf;
use std::sync::OnceLock;

/// `$TMPDIR/antisurge-fuzz-<pid>`, created once.
pub fn dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("antisurge-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("scratch dir");
        d
    })
}

/// Write `bytes` to `name` in the scratch directory and return its path.
pub fn write(name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir().join(name);
    std::fs::write(&p, bytes).expect("scratch write");
    p
}
