//! TLS termination (`serve --tls-cert FILE --tls-key FILE`): the server's certificate and key,
//! read from PEM files and read again when they change, so a renewed certificate (certbot, an
//! operator's `cp`) is served without a restart.
//!
//! [`ServerCert`] holds the certificate in use; rustls asks it for one at every handshake
//! ([`ResolvesServerCert`]), so a reload takes effect for the next connection and connections
//! already open keep theirs. [`ServerCert::reload_if_changed`] runs every
//! [`ServerCert::poll_interval`] ([`watch`]); `pathfarm serve` also reloads on SIGHUP
//! ([`ServerCert::reload`]). A new pair that cannot be used (unreadable, not PEM, a key that does
//! not match the certificate — as between the copies of the two files) is logged as an error and
//! the certificate in use is kept.
//!
//! The handshake itself runs on the connection's socket inside [`crate::connections`], where the
//! header timeout bounds it and the connection cap counts it. Behind a reverse proxy that
//! terminates TLS none of this is used: the proxy speaks plain HTTP to the server.

use rustls::crypto::CryptoProvider;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use rustls::server::{ClientHello, ResolvesServerCert};
use rustls::sign::CertifiedKey;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, RwLock};
use std::time::{Duration, SystemTime};

/// How often the files are checked for a change by default.
pub const DEFAULT_POLL_INTERVAL: Duration = Duration::from_secs(10);

/// A certificate or key file that cannot be used; the message names the flag and the file.
#[derive(Debug, thiserror::Error)]
#[error("{flag} {}: {reason}", path.display())]
pub struct TlsError {
    /// `--tls-cert` or `--tls-key`.
    pub flag: &'static str,
    pub path: PathBuf,
    pub reason: String,
}

/// The one crypto provider of the workspace (ring: reqwest, sqlx and rcgen use it too).
pub fn provider() -> Arc<CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// What identifies a file's version without reading it: its inode (a file replaced by a rename
/// has a new one), length and modification time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Stamp {
    inode: u64,
    len: u64,
    modified: Option<SystemTime>,
}

fn stamp(path: &Path) -> Option<Stamp> {
    let m = std::fs::metadata(path).ok()?;
    Some(Stamp {
        inode: m.ino(),
        len: m.len(),
        modified: m.modified().ok(),
    })
}

/// The server's certificate chain and key, reloadable (see the module's documentation).
pub struct ServerCert {
    cert_path: PathBuf,
    key_path: PathBuf,
    provider: Arc<CryptoProvider>,
    current: RwLock<Arc<CertifiedKey>>,
    /// The files' stamps when they were last read (successfully or not), so that a bad pair is
    /// reported once, not at every poll.
    seen: Mutex<(Option<Stamp>, Option<Stamp>)>,
    /// How often [`watch`] looks at the files.
    pub poll_interval: Duration,
}

impl std::fmt::Debug for ServerCert {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ServerCert")
            .field("cert_path", &self.cert_path)
            .field("key_path", &self.key_path)
            .field("poll_interval", &self.poll_interval)
            .finish_non_exhaustive()
    }
}

impl ServerCert {
    /// Reads the certificate chain (PEM, the server's certificate first) and its private key
    /// (PEM: PKCS#8, PKCS#1 or SEC1); fails, naming the file, on anything that would not serve.
    pub fn load(cert_path: &Path, key_path: &Path) -> Result<ServerCert, TlsError> {
        let provider = provider();
        let seen = (stamp(cert_path), stamp(key_path));
        let key = read_pair(cert_path, key_path, &provider)?;
        Ok(ServerCert {
            cert_path: cert_path.to_path_buf(),
            key_path: key_path.to_path_buf(),
            provider,
            current: RwLock::new(Arc::new(key)),
            seen: Mutex::new(seen),
            poll_interval: DEFAULT_POLL_INTERVAL,
        })
    }

    pub fn cert_path(&self) -> &Path {
        &self.cert_path
    }

    pub fn key_path(&self) -> &Path {
        &self.key_path
    }

    /// Reads the files again and serves the new pair from the next handshake on; on an error the
    /// pair in use is kept.
    pub fn reload(&self) -> Result<(), TlsError> {
        let seen = (stamp(&self.cert_path), stamp(&self.key_path));
        *self.seen.lock().unwrap_or_else(|e| e.into_inner()) = seen;
        let key = read_pair(&self.cert_path, &self.key_path, &self.provider)?;
        *self.current.write().unwrap_or_else(|e| e.into_inner()) = Arc::new(key);
        tracing::info!(
            cert = %self.cert_path.display(),
            key = %self.key_path.display(),
            "TLS certificate loaded"
        );
        Ok(())
    }

    /// [`ServerCert::reload`] when either file changed since it was last read; `Ok(false)` when
    /// neither did.
    pub fn reload_if_changed(&self) -> Result<bool, TlsError> {
        let now = (stamp(&self.cert_path), stamp(&self.key_path));
        if *self.seen.lock().unwrap_or_else(|e| e.into_inner()) == now {
            return Ok(false);
        }
        self.reload().map(|()| true)
    }

    /// The rustls configuration that serves this certificate (HTTP/1.1 over TLS 1.2 or 1.3).
    pub fn server_config(self: &Arc<Self>) -> Result<rustls::ServerConfig, rustls::Error> {
        let mut config = rustls::ServerConfig::builder_with_provider(self.provider.clone())
            .with_safe_default_protocol_versions()?
            .with_no_client_auth()
            .with_cert_resolver(self.clone());
        // The server speaks HTTP/1.1 only (axum's http2 feature is off).
        config.alpn_protocols = vec![b"http/1.1".to_vec()];
        Ok(config)
    }
}

impl ResolvesServerCert for ServerCert {
    fn resolve(&self, _hello: ClientHello<'_>) -> Option<Arc<CertifiedKey>> {
        Some(
            self.current
                .read()
                .unwrap_or_else(|e| e.into_inner())
                .clone(),
        )
    }
}

fn read_pair(
    cert_path: &Path,
    key_path: &Path,
    provider: &CryptoProvider,
) -> Result<CertifiedKey, TlsError> {
    let cert_err = |reason: String| TlsError {
        flag: "--tls-cert",
        path: cert_path.to_path_buf(),
        reason,
    };
    let key_err = |reason: String| TlsError {
        flag: "--tls-key",
        path: key_path.to_path_buf(),
        reason,
    };
    let cert_pem = std::fs::read(cert_path).map_err(|e| cert_err(format!("cannot read: {e}")))?;
    let chain = CertificateDer::pem_slice_iter(&cert_pem)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| cert_err(format!("not a PEM certificate chain: {e}")))?;
    if chain.is_empty() {
        return Err(cert_err(
            "no PEM certificate (BEGIN CERTIFICATE) in it".into(),
        ));
    }
    let key_pem = std::fs::read(key_path).map_err(|e| key_err(format!("cannot read: {e}")))?;
    let key = PrivateKeyDer::from_pem_slice(&key_pem)
        .map_err(|e| key_err(format!("no usable PEM private key in it: {e}")))?;
    CertifiedKey::from_der(chain, key, provider).map_err(|e| match e {
        rustls::Error::InconsistentKeys(_) => key_err(format!(
            "the key does not belong to the certificate of {} ({e})",
            cert_path.display()
        )),
        rustls::Error::General(_) => key_err(format!("unusable private key: {e}")),
        other => cert_err(format!("unusable certificate: {other}")),
    })
}

/// Reloads `cert` whenever its files change, every [`ServerCert::poll_interval`] (never when it
/// is zero: SIGHUP only), until the task is aborted. Errors are logged and the certificate in use
/// is kept.
pub async fn watch(cert: Arc<ServerCert>) {
    if cert.poll_interval.is_zero() {
        return;
    }
    let mut tick = tokio::time::interval(cert.poll_interval.max(Duration::from_millis(10)));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tick.tick().await;
    loop {
        tick.tick().await;
        let c = cert.clone();
        match tokio::task::spawn_blocking(move || c.reload_if_changed()).await {
            Ok(Ok(_)) => {}
            Ok(Err(e)) => {
                tracing::error!(error = %e, "TLS certificate not reloaded; keeping the one in use")
            }
            Err(e) => tracing::error!(error = %e, "TLS certificate reload failed"),
        }
    }
}
