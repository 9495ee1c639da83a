//! `taxel bridge certs --out DIR`: a private CA, a server pair and a client pair (PEM, ECDSA
//! P-256) to try the bridge's mutual TLS with. The server certificate names `localhost`,
//! 127.0.0.1, ::1 and every `--host` (Zenoh checks the name a bridge connects to against it)
//! and may also connect out (server and client authentication), the client certificate only
//! connects. Keys are written with mode 0600; nothing is overwritten without `--force`.

use std::io::Write;
use std::path::{Path, PathBuf};

use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa,
    Issuer, KeyPair, KeyUsagePurpose,
};
use time::{Duration, OffsetDateTime};

/// Why the certificates could not be made (one line).
#[derive(Debug, thiserror::Error)]
pub enum CertsError {
    #[error("--host {0:?}: not a DNS name or an IP address")]
    BadHost(String),
    #[error("--days {0}: give 1 to 36500 days")]
    BadDays(u32),
    #[error("--out {0}: {1} exists (add --force to replace the files)")]
    Exists(PathBuf, String),
    #[error("--out {0}: {1}")]
    Io(PathBuf, String),
    #[error("generating the certificates: {0}")]
    Rcgen(String),
}

/// What to make.
#[derive(Debug, Clone)]
pub struct CertsSpec {
    pub out: PathBuf,
    /// Extra names (DNS names or IP addresses) for the server certificate.
    pub hosts: Vec<String>,
    /// How long the certificates are valid.
    pub days: u32,
    /// Replace existing files.
    pub force: bool,
}

/// The files written, in order: CA certificate and key, server pair, client pair.
pub const FILES: [&str; 6] = [
    "ca.pem",
    "ca.key",
    "server.pem",
    "server.key",
    "client.pem",
    "client.key",
];

fn rc(e: rcgen::Error) -> CertsError {
    CertsError::Rcgen(e.to_string())
}

fn params(cn: &str, sans: Vec<String>, days: u32) -> Result<CertificateParams, CertsError> {
    let mut p = CertificateParams::new(sans).map_err(rc)?;
    let mut dn = DistinguishedName::new();
    dn.push(DnType::OrganizationName, "taxel bridge");
    dn.push(DnType::CommonName, cn);
    p.distinguished_name = dn;
    let now = OffsetDateTime::now_utc();
    p.not_before = now - Duration::hours(1);
    p.not_after = now + Duration::days(i64::from(days));
    Ok(p)
}

/// A DNS name (letters, digits, `-`, `.`) or an IP address.
fn host_ok(h: &str) -> bool {
    h.parse::<std::net::IpAddr>().is_ok()
        || (!h.is_empty()
            && h.len() <= 253
            && h.split('.').all(|l| {
                !l.is_empty()
                    && l.len() <= 63
                    && l.chars().all(|c| c.is_ascii_alphanumeric() || c == '-')
            }))
}

/// Makes the CA and the two pairs and writes them to `spec.out` (created if missing).
pub fn make(spec: &CertsSpec) -> Result<Vec<PathBuf>, CertsError> {
    if spec.days == 0 || spec.days > 36500 {
        return Err(CertsError::BadDays(spec.days));
    }
    for h in &spec.hosts {
        if !host_ok(h) {
            return Err(CertsError::BadHost(h.clone()));
        }
    }
    let io = |e: std::io::Error| CertsError::Io(spec.out.clone(), e.to_string());
    std::fs::create_dir_all(&spec.out).map_err(io)?;
    if !spec.force {
        if let Some(f) = FILES.iter().find(|f| spec.out.join(f).exists()) {
            return Err(CertsError::Exists(spec.out.clone(), f.to_string()));
        }
    }

    // The CA: signs certificates only. It lives a little longer than what it signs.
    let ca_key = KeyPair::generate().map_err(rc)?;
    let mut ca = params("taxel bridge CA", vec![], spec.days.saturating_add(1))?;
    ca.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    ca.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
    let ca_cert = ca.self_signed(&ca_key).map_err(rc)?;
    let issuer = Issuer::new(ca, &ca_key);

    let mut names: Vec<String> = vec!["localhost".into(), "127.0.0.1".into(), "::1".into()];
    for h in &spec.hosts {
        if !names.contains(h) {
            names.push(h.clone());
        }
    }
    let leaf = |cn: &str, sans: Vec<String>, eku: Vec<ExtendedKeyUsagePurpose>| {
        let key = KeyPair::generate().map_err(rc)?;
        let mut p = params(cn, sans, spec.days)?;
        p.is_ca = IsCa::ExplicitNoCa;
        p.key_usages = vec![KeyUsagePurpose::DigitalSignature];
        p.extended_key_usages = eku;
        p.use_authority_key_identifier_extension = true;
        let cert = p.signed_by(&key, &issuer).map_err(rc)?;
        Ok::<_, CertsError>((cert.pem(), key.serialize_pem()))
    };
    let (server_pem, server_key) = leaf(
        "taxel bridge server",
        names,
        vec![
            ExtendedKeyUsagePurpose::ServerAuth,
            ExtendedKeyUsagePurpose::ClientAuth,
        ],
    )?;
    let (client_pem, client_key) = leaf(
        "taxel bridge client",
        vec![],
        vec![ExtendedKeyUsagePurpose::ClientAuth],
    )?;

    let contents = [
        ca_cert.pem(),
        ca_key.serialize_pem(),
        server_pem,
        server_key,
        client_pem,
        client_key,
    ];
    let mut written = Vec::new();
    for (name, text) in FILES.iter().zip(contents) {
        let p = spec.out.join(name);
        write_file(&p, &text, name.ends_with(".key")).map_err(io)?;
        written.push(p);
    }
    Ok(written)
}

/// Writes `text` to `p`, readable by the owner only when `secret` (created so, never briefly
/// open to others).
fn write_file(p: &Path, text: &str, secret: bool) -> std::io::Result<()> {
    use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
    let mode = if secret { 0o600 } else { 0o644 };
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(mode)
        .open(p)?;
    // An existing file keeps its mode through open(): set it.
    f.set_permissions(std::fs::Permissions::from_mode(mode))?;
    f.write_all(text.as_bytes())?;
    f.sync_all()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tls::{check, Roles, Source};

    #[test]
    fn the_pairs_pass_the_bridges_own_checks() {
        let dir = tempfile::tempdir().expect("dir");
        let spec = CertsSpec {
            out: dir.path().join("certs"),
            hosts: vec!["glove-pc.local".into(), "10.0.0.2".into()],
            days: 30,
            force: false,
        };
        let files = make(&spec).expect("made");
        assert_eq!(files.len(), 6);
        let f = |n: &str| Source::flag("--x", &spec.out.join(n));
        let both = Roles {
            listen: true,
            connect: true,
        };
        check(&f("server.pem"), &f("server.key"), &f("ca.pem"), both).expect("server pair");
        check(&f("client.pem"), &f("client.key"), &f("ca.pem"), both).expect("client pair");
        // A key of another pair, a CA of another run: refused, naming the file.
        let e = check(&f("server.pem"), &f("client.key"), &f("ca.pem"), both)
            .expect_err("mismatched key")
            .to_string();
        assert!(e.contains("client.key"), "{e}");
        let other = CertsSpec {
            out: dir.path().join("other"),
            ..spec.clone()
        };
        make(&other).expect("second CA");
        let e = check(
            &f("client.pem"),
            &f("client.key"),
            &Source::flag("--tls-ca", &other.out.join("ca.pem")),
            both,
        )
        .expect_err("another CA")
        .to_string();
        assert!(e.contains("client.pem") && e.contains("--tls-ca"), "{e}");
        // Existing files are kept unless --force; keys are private.
        assert!(matches!(make(&spec), Err(CertsError::Exists(..))));
        make(&CertsSpec {
            force: true,
            ..spec.clone()
        })
        .expect("forced");
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(spec.out.join("server.key"))
            .expect("key")
            .permissions()
            .mode();
        assert_eq!(mode & 0o777, 0o600);
        assert!(matches!(
            make(&CertsSpec {
                hosts: vec!["bad host".into()],
                ..spec.clone()
            }),
            Err(CertsError::BadHost(_))
        ));
    }
}
