//! Bounded reading of configuration files: regular files only, at most
//! [`MAX_CONFIG_FILE_BYTES`], opened without blocking.
//!
//! Why: a config path that names a FIFO blocks `open`/`read` until a writer appears, a device
//! such as `/dev/zero` never ends, and a huge file costs its size in (locked) memory. Start,
//! reload and `check-config` all read through [`read_config_text`], so none of them can hang
//! on or be exhausted by a file (issue 12, item 1).

use std::io::{self, Read};
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;

/// Largest configuration file accepted (TOML, signal map, plant, scenario, DBC), bytes.
/// The shipped files are below 16 KiB; 4 MiB leaves room for generated maps.
pub const MAX_CONFIG_FILE_BYTES: u64 = 4 << 20;

/// Exit status of `antisurge run`, `plant` and `check-config` when the configuration is
/// invalid (`EX_CONFIG` of sysexits.h). The systemd unit lists it in
/// `RestartPreventExitStatus=`, so a bad config stops the restart loop instead of
/// restarting once a second forever.
pub const EX_CONFIG: u8 = 78;

/// A configuration error that must end the command with [`EX_CONFIG`]; the message is the
/// located, operator-readable text.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct ConfigInvalid(pub String);

fn kind_of(ft: std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if ft.is_dir() {
        "a directory"
    } else if ft.is_fifo() {
        "a FIFO (named pipe)"
    } else if ft.is_char_device() {
        "a character device"
    } else if ft.is_block_device() {
        "a block device"
    } else if ft.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

fn check_meta(meta: &std::fs::Metadata, limit: u64) -> io::Result<()> {
    if !meta.is_file() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "{}; configuration files must be regular files",
                kind_of(meta.file_type())
            ),
        ));
    }
    if meta.len() > limit {
        return Err(too_big(meta.len(), limit));
    }
    Ok(())
}

fn too_big(len: u64, limit: u64) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("{len} bytes, more than the {limit}-byte limit of a configuration file"),
    )
}

/// Read a UTF-8 text file of at most `limit` bytes that must be a regular file. Never blocks
/// on a FIFO or device: the type is checked before and after a non-blocking open.
pub fn read_text_bounded(path: &Path, limit: u64) -> io::Result<String> {
    check_meta(&std::fs::metadata(path)?, limit)?;
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)?;
    // the path may have been replaced between stat and open
    check_meta(&file.metadata()?, limit)?;
    let mut bytes = Vec::new();
    file.take(limit + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(too_big(bytes.len() as u64, limit));
    }
    String::from_utf8(bytes)
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, format!("not UTF-8 text ({e})")))
}

/// [`read_text_bounded`] with [`MAX_CONFIG_FILE_BYTES`].
pub fn read_config_text(path: &Path) -> io::Result<String> {
    read_text_bounded(path, MAX_CONFIG_FILE_BYTES)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    #[test]
    fn fifo_is_refused_at_once_without_a_writer() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("plant.toml");
        let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
        // SAFETY: mkfifo on a path we own.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let t0 = Instant::now();
        let e = read_config_text(&p).unwrap_err();
        assert!(t0.elapsed() < Duration::from_millis(500));
        assert!(e.to_string().contains("FIFO"), "{e}");
    }

    #[test]
    fn devices_and_directories_are_refused() {
        let e = read_config_text(Path::new("/dev/zero")).unwrap_err();
        assert!(e.to_string().contains("character device"), "{e}");
        let e = read_config_text(Path::new("/")).unwrap_err();
        assert!(e.to_string().contains("directory"), "{e}");
    }

    #[test]
    fn size_limit_holds_for_sparse_files() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("big.toml");
        let f = std::fs::File::create(&p).unwrap();
        f.set_len(128 << 20).unwrap(); // 128 MiB, sparse: costs no disk
        let t0 = Instant::now();
        let e = read_config_text(&p).unwrap_err();
        assert!(t0.elapsed() < Duration::from_millis(200));
        assert!(e.to_string().contains("limit"), "{e}");
        std::fs::write(&p, "a = 1\n").unwrap();
        assert_eq!(read_config_text(&p).unwrap(), "a = 1\n");
        assert!(read_text_bounded(&p, 3).is_err());
    }
}
