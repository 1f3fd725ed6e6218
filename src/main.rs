//! The `antisurge` binary: command-line edge over the library.
fn main() -> anyhow::Result<()> {
    Ok(())
}
