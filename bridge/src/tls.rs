//! TLS with mutual authentication, through Zenoh's own TLS transport (`tls/HOST:PORT`).
//!
//! `--tls-cert C --tls-key K --tls-ca CA` set Zenoh's `transport/link/tls` keys: the same pair is
//! this bridge's certificate when it listens and when it connects, the CA is the only issuer of
//! peer certificates it trusts (Zenoh also keeps the public Web PKI roots for servers it connects
//! to, see docs/bridge.md), and `enable_mtls` makes the listener ask every peer for a certificate
//! and refuse the handshake of one without a certificate the CA signed. The same keys can come
//! from a `--zenoh-config` file instead.
//!
//! Zenoh reads the files only when the session opens and reports a bad one as a runtime error.
//! The bridge checks them first, with the same rustls and ring provider Zenoh uses, so a missing,
//! unreadable or mismatched file is a configuration error (exit 2) naming the flag and the file.
//!
//! Zenoh logs a refused handshake as a warning of `zenoh_link_tls` (with a misleading hint
//! about open files); [`RefusalLayer`] catches those events so the bridge logs each refusal in
//! its own words and counts them in its report.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use rustls::pki_types::{CertificateDer, PrivateKeyDer, UnixTime};
use rustls::server::WebPkiClientVerifier;
use rustls::{CertificateError, RootCertStore};

use crate::config::ConfigError;

/// The three files of `--tls-cert`, `--tls-key` and `--tls-ca`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsFiles {
    /// This bridge's certificate chain (PEM), presented when it listens and when it connects.
    pub cert: PathBuf,
    /// Its private key (PEM: PKCS#8, PKCS#1 or SEC1).
    pub key: PathBuf,
    /// The CA certificate(s) (PEM) that must have signed every peer's certificate.
    pub ca: PathBuf,
}

impl TlsFiles {
    /// From the three optional flags: all three or none.
    pub fn from_flags(
        cert: Option<PathBuf>,
        key: Option<PathBuf>,
        ca: Option<PathBuf>,
    ) -> Result<Option<TlsFiles>, ConfigError> {
        match (cert, key, ca) {
            (None, None, None) => Ok(None),
            (Some(cert), Some(key), Some(ca)) => Ok(Some(TlsFiles { cert, key, ca })),
            (c, k, a) => {
                let missing: Vec<&str> = [
                    ("--tls-cert", c.is_none()),
                    ("--tls-key", k.is_none()),
                    ("--tls-ca", a.is_none()),
                ]
                .into_iter()
                .filter_map(|(f, m)| m.then_some(f))
                .collect();
                Err(ConfigError::TlsIncomplete(missing.join(", ")))
            }
        }
    }
}

/// Where one TLS file comes from, for error messages: a flag, or a key of a Zenoh file.
#[derive(Debug, Clone)]
pub struct Source {
    pub label: String,
    pub path: PathBuf,
}

impl Source {
    pub fn flag(flag: &str, path: &Path) -> Source {
        Source {
            label: flag.to_string(),
            path: path.to_path_buf(),
        }
    }

    fn err(&self, why: impl Into<String>) -> ConfigError {
        ConfigError::TlsFile(self.label.clone(), self.path.clone(), why.into())
    }

    fn read(&self) -> Result<Vec<u8>, ConfigError> {
        std::fs::read(&self.path).map_err(|e| self.err(format!("cannot read it: {e}")))
    }

    fn certs(&self) -> Result<Vec<CertificateDer<'static>>, ConfigError> {
        let bytes = self.read()?;
        let certs = rustls_pemfile::certs(&mut bytes.as_slice())
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| self.err(format!("not a PEM certificate file: {e}")))?;
        if certs.is_empty() {
            return Err(self.err("no PEM certificate in it (-----BEGIN CERTIFICATE-----)"));
        }
        Ok(certs)
    }

    fn key(&self) -> Result<PrivateKeyDer<'static>, ConfigError> {
        let bytes = self.read()?;
        rustls_pemfile::private_key(&mut bytes.as_slice())
            .map_err(|e| self.err(format!("not a PEM key file: {e}")))?
            .ok_or_else(|| self.err("no PEM private key in it (PKCS#8, PKCS#1 or SEC1)"))
    }
}

/// How the bridge uses its certificate: presented when listening, when connecting, or both.
#[derive(Debug, Clone, Copy)]
pub struct Roles {
    pub listen: bool,
    pub connect: bool,
}

/// Checks a certificate, its key and the CA as Zenoh will use them: every file readable PEM,
/// the key the certificate's, the CA usable as a trust anchor, and the certificate signed by
/// the CA and valid now (for client authentication when the bridge connects).
pub fn check(cert: &Source, key: &Source, ca: &Source, roles: Roles) -> Result<(), ConfigError> {
    let chain = cert.certs()?;
    let private = key.key()?;
    let mut roots = RootCertStore::empty();
    for c in ca.certs()? {
        roots
            .add(c)
            .map_err(|e| ca.err(format!("not a usable CA certificate: {e}")))?;
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let verifier = WebPkiClientVerifier::builder_with_provider(Arc::new(roots), provider.clone())
        .build()
        .map_err(|e| ca.err(format!("not a usable CA: {e}")))?;
    rustls::ServerConfig::builder_with_provider(provider)
        .with_protocol_versions(&[&rustls::version::TLS13])
        .map_err(|e| cert.err(format!("{e}")))?
        .with_client_cert_verifier(verifier.clone())
        .with_single_cert(chain.clone(), private)
        .map_err(|e| {
            key.err(format!(
                "not the key of the certificate in {} ({}): {e}",
                cert.path.display(),
                cert.label
            ))
        })?;
    let (leaf, rest) = chain
        .split_first()
        .ok_or_else(|| cert.err("no certificate"))?;
    match verifier.verify_client_cert(leaf, rest, UnixTime::now()) {
        Ok(_) => Ok(()),
        // A certificate only for servers (extended key usage) is fine for a listener.
        Err(rustls::Error::InvalidCertificate(
            CertificateError::InvalidPurpose | CertificateError::InvalidPurposeContext { .. },
        )) if !roles.connect => Ok(()),
        Err(e) => Err(cert.err(format!(
            "not accepted by the CA in {} ({}): {e}",
            ca.path.display(),
            ca.label
        ))),
    }
}

/// The TLS settings of a Zenoh configuration, as the bridge reads them back.
#[derive(Debug, Clone, Default)]
pub struct ZenohTls {
    pub root_ca: Option<String>,
    pub listen_cert: Option<String>,
    pub listen_key: Option<String>,
    pub connect_cert: Option<String>,
    pub connect_key: Option<String>,
    /// Any of the `*_base64` variants is set (not checked by the bridge).
    pub base64: bool,
    pub mtls: bool,
}

impl ZenohTls {
    pub fn read(c: &zenoh::Config) -> ZenohTls {
        let s = |k: &str| {
            c.get_json(&format!("transport/link/tls/{k}"))
                .ok()
                .and_then(|j| serde_json::from_str::<Option<String>>(&j).ok())
                .flatten()
        };
        let base64 = [
            "root_ca_certificate_base64",
            "listen_certificate_base64",
            "listen_private_key_base64",
            "connect_certificate_base64",
            "connect_private_key_base64",
        ]
        .iter()
        .any(|k| {
            c.get_json(&format!("transport/link/tls/{k}"))
                .is_ok_and(|j| j != "null")
        });
        let mtls = c
            .get_json("transport/link/tls/enable_mtls")
            .ok()
            .and_then(|j| serde_json::from_str::<Option<bool>>(&j).ok())
            .flatten()
            .unwrap_or(false);
        ZenohTls {
            root_ca: s("root_ca_certificate"),
            listen_cert: s("listen_certificate"),
            listen_key: s("listen_private_key"),
            connect_cert: s("connect_certificate"),
            connect_key: s("connect_private_key"),
            base64,
            mtls,
        }
    }

    /// Whether a TLS listener refuses peers without a certificate of the CA: mutual TLS on,
    /// a CA, a certificate and a key to listen with.
    pub fn authenticates_peers(&self) -> bool {
        self.mtls && (self.base64 || (self.root_ca.is_some() && self.listen_cert.is_some()))
    }

    /// Whether a TLS endpoint can be used at all in `role`.
    pub fn can_listen(&self) -> bool {
        self.base64 || (self.listen_cert.is_some() && self.listen_key.is_some())
    }

    pub fn can_connect(&self) -> bool {
        self.base64 || self.root_ca.is_some()
    }

    /// Checks the files a `--zenoh-config` file names (the `*_base64` values are left to Zenoh).
    pub fn check_files(&self, file: &Path, roles: Roles) -> Result<(), ConfigError> {
        let src = |key: &str, path: &String| Source {
            label: format!(
                "--zenoh-config {}: transport/link/tls/{key}",
                file.display()
            ),
            path: PathBuf::from(path),
        };
        let Some(ca) = &self.root_ca else {
            return Ok(());
        };
        let ca = src("root_ca_certificate", ca);
        if let (true, Some(c), Some(k)) = (roles.listen, &self.listen_cert, &self.listen_key) {
            let r = Roles {
                listen: true,
                connect: false,
            };
            check(
                &src("listen_certificate", c),
                &src("listen_private_key", k),
                &ca,
                r,
            )?;
        }
        if let (true, true, Some(c), Some(k)) = (
            roles.connect,
            self.mtls,
            &self.connect_cert,
            &self.connect_key,
        ) {
            let r = Roles {
                listen: false,
                connect: true,
            };
            check(
                &src("connect_certificate", c),
                &src("connect_private_key", k),
                &ca,
                r,
            )?;
        }
        if self.listen_cert.is_none() && self.connect_cert.is_none() {
            ca.certs()?;
        }
        Ok(())
    }
}

/// Zenoh's TLS keys for the three files: one pair for listening and connecting, the CA, and
/// mutual authentication on.
pub fn zenoh_settings(f: &TlsFiles) -> Vec<(&'static str, String)> {
    let q = |p: &Path| serde_json::Value::String(p.display().to_string()).to_string();
    vec![
        ("transport/link/tls/root_ca_certificate", q(&f.ca)),
        ("transport/link/tls/listen_certificate", q(&f.cert)),
        ("transport/link/tls/listen_private_key", q(&f.key)),
        ("transport/link/tls/connect_certificate", q(&f.cert)),
        ("transport/link/tls/connect_private_key", q(&f.key)),
        ("transport/link/tls/enable_mtls", "true".into()),
    ]
}

/// Refusals seen since the last [`take_refusals`].
static REFUSALS: Mutex<Vec<String>> = Mutex::new(Vec::new());
/// At most this many refusals wait to be logged (a flood of bad handshakes keeps the first).
const MAX_PENDING: usize = 256;

/// A tracing layer that notices Zenoh's warning about a failed TLS handshake on a listener
/// (a peer without a certificate of the CA, a plain TCP peer, a timeout).
pub struct RefusalLayer;

struct Message(String);

impl tracing::field::Visit for Message {
    fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
}

impl<S: tracing::Subscriber> tracing_subscriber::Layer<S> for RefusalLayer {
    fn on_event(
        &self,
        event: &tracing::Event<'_>,
        _ctx: tracing_subscriber::layer::Context<'_, S>,
    ) {
        let m = event.metadata();
        if !m.target().starts_with("zenoh_link_tls") || *m.level() != tracing::Level::WARN {
            return;
        }
        let mut msg = Message(String::new());
        event.record(&mut msg);
        // Zenoh's accept loop logs a failed handshake as "<error>. Hint: increase the system
        // open file limit." (the hint is meant for failures to accept a socket).
        if let Some(why) = msg
            .0
            .strip_suffix(". Hint: increase the system open file limit.")
        {
            if let Ok(mut q) = REFUSALS.lock() {
                if q.len() < MAX_PENDING {
                    q.push(why.to_string());
                }
            }
        }
    }
}

/// The refusals noticed since the last call.
pub fn take_refusals() -> Vec<String> {
    REFUSALS
        .lock()
        .map(|mut q| std::mem::take(&mut *q))
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_three_flags_go_together() {
        let p = |s: &str| Some(PathBuf::from(s));
        assert_eq!(TlsFiles::from_flags(None, None, None).ok(), Some(None));
        assert!(TlsFiles::from_flags(p("c"), p("k"), p("a"))
            .expect("complete")
            .is_some());
        let e = TlsFiles::from_flags(p("c"), None, None)
            .expect_err("incomplete")
            .to_string();
        assert!(e.contains("--tls-key, --tls-ca"), "{e}");
    }
}
