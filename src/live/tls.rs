//! TLS for the web HMI (rustls with the `ring` provider, via tokio-rustls): the certificate
//! chain and private key of `[status.tls]`, read from PEM files once at start. Only TLS 1.2 and
//! 1.3 with rustls' safe defaults; no client certificates (operator actions are authorised by
//! the operator token, over the encrypted connection).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, PrivateKeyDer};
use tokio_rustls::rustls;

use crate::live::tls_settings::TlsSection;

/// Why the certificate or key cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    /// The certificate file.
    #[error("certificate {file}: {why}")]
    Cert {
        /// The file.
        file: PathBuf,
        /// What is wrong.
        why: String,
    },
    /// The key file, or a key that does not belong to the certificate.
    #[error("private key {file}: {why}")]
    Key {
        /// The file.
        file: PathBuf,
        /// What is wrong.
        why: String,
    },
}

impl TlsError {
    /// Is it about the key file (else the certificate)?
    pub fn is_about_key(&self) -> bool {
        matches!(self, TlsError::Key { .. })
    }
}

fn certs(file: &Path) -> Result<Vec<CertificateDer<'static>>, TlsError> {
    let err = |why: String| TlsError::Cert {
        file: file.to_path_buf(),
        why,
    };
    let certs = CertificateDer::pem_file_iter(file)
        .map_err(|e| err(format!("cannot read it ({e})")))?
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| err(format!("not a PEM certificate ({e})")))?;
    if certs.is_empty() {
        return Err(err(
            "holds no certificate (expected -----BEGIN CERTIFICATE-----)".into(),
        ));
    }
    Ok(certs)
}

/// Read `[status.tls]` and make the server configuration (the key must match the leaf
/// certificate).
pub fn load(t: &TlsSection) -> Result<Arc<rustls::ServerConfig>, TlsError> {
    let chain = certs(&t.cert_file)?;
    let key_err = |why: String| TlsError::Key {
        file: t.key_file.clone(),
        why,
    };
    let key = PrivateKeyDer::from_pem_file(&t.key_file).map_err(|e| {
        key_err(format!(
            "not a readable PEM private key ({e}); expected -----BEGIN PRIVATE KEY-----"
        ))
    })?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let cfg = rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| key_err(e.to_string()))?
        .with_no_client_auth()
        .with_single_cert(chain, key)
        .map_err(|e| match e {
            rustls::Error::InconsistentKeys(_) => key_err(format!(
                "does not belong to the certificate {}",
                t.cert_file.display()
            )),
            e => key_err(format!("cannot be used with the certificate: {e}")),
        })?;
    Ok(Arc::new(cfg))
}

/// The acceptor for the HMI's connections.
pub fn acceptor(t: &TlsSection) -> Result<tokio_rustls::TlsAcceptor, TlsError> {
    Ok(tokio_rustls::TlsAcceptor::from(load(t)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn section(dir: &Path, cert: &str, key: &str) -> TlsSection {
        std::fs::write(dir.join("c.pem"), cert).expect("write");
        std::fs::write(dir.join("k.pem"), key).expect("write");
        TlsSection {
            cert_file: dir.join("c.pem"),
            key_file: dir.join("k.pem"),
        }
    }

    #[test]
    fn loads_a_matching_pair_and_names_the_bad_file() {
        let dir = tempfile::tempdir().expect("tmp");
        let a = rcgen::generate_simple_self_signed(vec!["localhost".into()]).expect("cert");
        let b = rcgen::generate_simple_self_signed(vec!["localhost".into()]).expect("cert");
        let ok = section(dir.path(), &a.cert.pem(), &a.signing_key.serialize_pem());
        assert!(load(&ok).is_ok());

        let wrong = section(dir.path(), &a.cert.pem(), &b.signing_key.serialize_pem());
        let e = load(&wrong).unwrap_err();
        assert!(e.is_about_key(), "{e}");
        assert!(e.to_string().contains("does not belong"), "{e}");

        let swapped = section(dir.path(), &a.signing_key.serialize_pem(), &a.cert.pem());
        let e = load(&swapped).unwrap_err();
        assert!(!e.is_about_key(), "{e}");
        assert!(e.to_string().contains("no certificate"), "{e}");

        let missing = TlsSection {
            cert_file: dir.path().join("none.pem"),
            key_file: dir.path().join("k.pem"),
        };
        let e = load(&missing).unwrap_err();
        assert!(e.to_string().contains("none.pem"), "{e}");
    }
}
