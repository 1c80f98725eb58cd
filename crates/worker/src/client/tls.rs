//! TLS setup: the crypto provider and the extra CA certificates of `--ca-cert`.

use super::SetupError;
use std::path::Path;

/// Installs ring as the process's rustls crypto provider, which reqwest's `rustls-no-provider`
/// feature needs before any `reqwest::Client` is built (it panics without one). ring is the
/// workspace's one provider: sqlx and the server's TLS use it too; reqwest's own default,
/// aws-lc-rs, would add a long C build. [`ApiClient`] calls it; code that builds a reqwest client
/// of its own calls it first. Harmless when a provider is installed already.
pub fn install_crypto_provider() {
    let _ = rustls::crypto::ring::default_provider().install_default();
}

/// The certificates of a PEM file, for [`ApiClient::with_ca_cert`].
pub(super) fn read_ca_certs(path: &Path) -> Result<Vec<reqwest::Certificate>, SetupError> {
    let bad = |reason: String| SetupError::CaCert {
        path: path.to_path_buf(),
        reason,
    };
    let pem = std::fs::read(path).map_err(|e| bad(format!("cannot read: {e}")))?;
    let certs = reqwest::Certificate::from_pem_bundle(&pem)
        .map_err(|e| bad(format!("not a PEM certificate file: {e}")))?;
    if certs.is_empty() {
        return Err(bad("no PEM certificate (BEGIN CERTIFICATE) in it".into()));
    }
    Ok(certs)
}
