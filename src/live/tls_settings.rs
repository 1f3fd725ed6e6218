//! `[status.tls]` and the rules for where the operator services may listen.
//!
//! The web HMI carries operator actions, so it leaves loopback only over TLS and only with an
//! operator token in place: `status.hmi_listen` on a non-loopback address without
//! `[status.tls]`, or without a usable `status.operator_token_file`, is refused by
//! `check-config` (and so by `run` and `systemctl reload`). The metrics endpoint is read-only
//! and leaves loopback only with `status.metrics_allow_remote = true`.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::settings::StatusSection;
use crate::config::problem::KeyProblem;
use crate::live::{hmi, metrics, tls};

/// `[status.tls]`: serve the web HMI over HTTPS with this certificate and key (PEM files;
/// relative paths are taken from the main configuration file's directory).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TlsSection {
    /// The server certificate, PEM, leaf first then any intermediates
    /// (e.g. `/etc/antisurge/tls/hmi.crt`).
    pub cert_file: PathBuf,
    /// Its private key, PEM (PKCS#8, PKCS#1 or SEC1), readable by the service only
    /// (e.g. `/etc/antisurge/tls/hmi.key`, mode 0640 root:antisurge).
    pub key_file: PathBuf,
}

impl TlsSection {
    /// The same section with relative paths taken from `main`'s directory.
    pub fn resolved(&self, main: &Path) -> TlsSection {
        TlsSection {
            cert_file: crate::config::paths::resolve(main, &self.cert_file),
            key_file: crate::config::paths::resolve(main, &self.key_file),
        }
    }
}

/// The token file the daemon reads: `status.operator_token_file`, else the installed one.
pub fn token_file(status: &StatusSection) -> PathBuf {
    status
        .operator_token_file
        .clone()
        .unwrap_or_else(|| PathBuf::from(crate::live::DEFAULT_TOKEN_FILE))
}

/// Why the token file cannot protect operator actions (None: it can). Checks what can be
/// checked without reading a file the checking user may not be allowed to read: it exists,
/// is a regular file, is not readable by everyone, and is not empty.
pub fn token_file_problem(file: &Path) -> Option<String> {
    use std::os::unix::fs::MetadataExt;
    match std::fs::metadata(file) {
        Err(e) => Some(format!(
            "the operator token file {} is missing ({e})",
            file.display()
        )),
        Ok(m) if !m.is_file() => Some(format!(
            "the operator token file {} is not a file",
            file.display()
        )),
        Ok(m) if m.mode() & 0o004 != 0 => Some(format!(
            "the operator token file {} is readable by everyone",
            file.display()
        )),
        Ok(m) if m.len() == 0 => Some(format!(
            "the operator token file {} is empty",
            file.display()
        )),
        Ok(_) => None,
    }
}

/// The uid of the service account `antisurge`, if it exists.
fn service_account_uid() -> Option<u32> {
    let name = std::ffi::CString::new("antisurge").ok()?;
    let mut pw: libc::passwd = unsafe { std::mem::zeroed() };
    let mut buf = vec![0 as libc::c_char; 4096];
    let mut out: *mut libc::passwd = std::ptr::null_mut();
    // SAFETY: getpwnam_r writes into pw and buf (sizes given) and sets out to &pw or null.
    let r = unsafe {
        libc::getpwnam_r(
            name.as_ptr(),
            &mut pw,
            buf.as_mut_ptr(),
            buf.len(),
            &mut out,
        )
    };
    (r == 0 && !out.is_null()).then_some(pw.pw_uid)
}

/// Why an existing operator token file must not be trusted (None: it may be, or it does not
/// exist, in which case operator actions are simply refused). It must be owned by root, by
/// the user the daemon runs as, or by the service account `antisurge`, and writable by no
/// one but its owner: a file another user can rewrite lets that user choose the token.
/// Checked at start, at every reload and before every operator action.
pub fn token_file_unsafe(file: &Path) -> Option<String> {
    use std::os::unix::fs::MetadataExt;
    let m = std::fs::metadata(file).ok()?;
    // SAFETY: geteuid has no preconditions.
    let me = unsafe { libc::geteuid() };
    let owner = m.uid();
    if owner != 0 && owner != me && Some(owner) != service_account_uid() {
        return Some(format!(
            "the operator token file {} is owned by uid {owner}, not by root or the service user: \
             that user could choose the token (chown root:antisurge {0}; chmod 0640 {0})",
            file.display()
        ));
    }
    if m.mode() & 0o022 != 0 {
        return Some(format!(
            "the operator token file {} is writable by {} (mode {:04o}): they could choose the token \
             (chmod 0640 {})",
            file.display(),
            if m.mode() & 0o002 != 0 { "everyone" } else { "its group" },
            m.mode() & 0o7777,
            file.display()
        ));
    }
    None
}

/// Check where the HMI and the metrics endpoint listen, and the TLS files.
pub fn bind_problems(status: &StatusSection) -> Vec<KeyProblem> {
    let mut out = Vec::new();
    if let Some(why) = token_file_unsafe(&token_file(status)) {
        out.push(
            KeyProblem::error("status.operator_token_file", why)
                .with_hint("deploy/install.sh creates it root:antisurge, mode 0640"),
        );
    }
    if let Some(t) = &status.tls {
        if let Err(e) = tls::load(t) {
            let key = if e.is_about_key() {
                "status.tls.key_file"
            } else {
                "status.tls.cert_file"
            };
            out.push(KeyProblem::error(key, e.to_string()).with_hint(
                "make a certificate and key as README.md \"The web HMI over HTTPS\" shows",
            ));
        }
    }
    match hmi::listen_addr(status.hmi_listen.as_deref(), status.tls.is_some()) {
        Err(e) => out.push(KeyProblem::error("status.hmi_listen", e).with_hint(
            "keep the HMI on 127.0.0.1, or add [status.tls] with cert_file and key_file",
        )),
        Ok(Some(addr)) if !addr.ip().is_loopback() => {
            if let Some(why) = token_file_problem(&token_file(status)) {
                out.push(
                    KeyProblem::error(
                        "status.hmi_listen",
                        format!(
                            "the HMI on {addr} beyond loopback needs the operator token, but {why}"
                        ),
                    )
                    .with_hint(
                        "run deploy/install.sh (it creates /etc/antisurge/operator.token), or set status.operator_token_file to a root-owned file of mode 0640",
                    ),
                );
            }
        }
        Ok(_) => {}
    }
    if let Err(e) = metrics::listen_addr(
        status.metrics_listen.as_deref(),
        status.metrics_allow_remote,
    ) {
        out.push(KeyProblem::error("status.metrics_listen", e).with_hint(
            "keep metrics on 127.0.0.1, or set status.metrics_allow_remote = true (read-only data)",
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    #[test]
    fn beyond_loopback_the_hmi_needs_tls_and_a_usable_token_file() {
        let dir = tempfile::tempdir().expect("tmp");
        let token = dir.path().join("operator.token");
        let mut s = StatusSection {
            hmi_listen: Some("0.0.0.0:9651".into()),
            operator_token_file: Some(token.clone()),
            ..StatusSection::default()
        };
        let keys = |s: &StatusSection| {
            bind_problems(s)
                .iter()
                .map(|p| format!("{}: {}", p.key, p.message))
                .collect::<Vec<_>>()
        };
        let p = keys(&s);
        assert!(
            p.len() == 1 && p[0].starts_with("status.hmi_listen") && p[0].contains("TLS"),
            "{p:?}"
        );

        let c = rcgen::generate_simple_self_signed(vec!["localhost".into()]).expect("cert");
        std::fs::write(dir.path().join("c.pem"), c.cert.pem()).expect("write");
        std::fs::write(dir.path().join("k.pem"), c.signing_key.serialize_pem()).expect("write");
        s.tls = Some(TlsSection {
            cert_file: dir.path().join("c.pem"),
            key_file: dir.path().join("k.pem"),
        });
        let p = keys(&s);
        assert!(p.len() == 1 && p[0].contains("missing"), "{p:?}");
        std::fs::write(&token, "").expect("write");
        std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o640)).expect("chmod");
        assert!(keys(&s)[0].contains("empty"), "{:?}", keys(&s));
        std::fs::write(&token, "t0ken\n").expect("write");
        std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o644)).expect("chmod");
        assert!(
            keys(&s)[0].contains("readable by everyone"),
            "{:?}",
            keys(&s)
        );
        std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o640)).expect("chmod");
        assert_eq!(keys(&s), Vec::<String>::new());

        // loopback needs neither
        let s = StatusSection {
            operator_token_file: Some(dir.path().join("none")),
            ..StatusSection::default()
        };
        assert_eq!(keys(&s), Vec::<String>::new());
        // metrics beyond loopback: refused without metrics_allow_remote, named
        let s = StatusSection {
            metrics_listen: Some("0.0.0.0:9650".into()),
            ..StatusSection::default()
        };
        assert!(
            keys(&s)[0].starts_with("status.metrics_listen"),
            "{:?}",
            keys(&s)
        );
    }
}
