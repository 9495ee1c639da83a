//! The bridge's configuration: which services cross (allow globs), where Zenoh listens and
//! connects, and the iceoryx2 configuration of the local domain with taxel's stream QoS as the
//! defaults (the link creates the mirror of a remote service with the local defaults, and taxel
//! processes then open it with their own settings, which must fit).

use std::path::PathBuf;
use std::time::Duration;

use iceoryx2::config::Config;
use iceoryx2_link_backend::AllowList;
use taxel_msgs::Stream;
use taxel_runtime::ipc::{MAX_NODES, MAX_PUBLISHERS, MAX_SUBSCRIBERS};

use crate::tls::{self, Roles, Source, TlsFiles, ZenohTls};

/// Why a configuration was refused (one line, naming the offending value).
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("--allow: give at least one service glob, e.g. --allow 'taxel/glove0/*'")]
    NoAllow,
    #[error("--allow {0:?}: {1}")]
    BadAllow(String, &'static str),
    #[error("--{0} {1:?}: {2}")]
    BadEndpoint(&'static str, String, String),
    #[error("give --listen, --connect or --zenoh-config: without them the bridge reaches nobody")]
    NoEndpoint,
    #[error("--zenoh-config {0}: {1}")]
    ZenohFile(PathBuf, String),
    #[error("zenoh configuration {0}: {1}")]
    Zenoh(String, String),
    #[error("--prefix {0:?}: {1}")]
    Prefix(String, String),
    #[error("--{0} {1}: must be a positive number of seconds")]
    Seconds(&'static str, f64),
    #[error("--lease-s {0}: give a lease between 0.1 and 3600 seconds")]
    Lease(f64),
    #[error("{0} {1:?}: not a loopback address, and nothing authenticates the peers there, so anyone who reaches it could read and inject streams; listen on 127.0.0.1 or [::1], on tls/HOST:PORT with --tls-cert, --tls-key and --tls-ca, or add --insecure-listen to listen there anyway")]
    OpenListen(String, String),
    #[error("--tls-cert, --tls-key and --tls-ca go together: {0} missing")]
    TlsIncomplete(String),
    #[error("{0} {1}: {2}")]
    TlsFile(String, PathBuf, String),
    #[error("--{0} {1:?}: a tls/ endpoint needs --tls-cert, --tls-key and --tls-ca (or transport/link/tls in --zenoh-config)")]
    TlsEndpoint(&'static str, String),
}

/// A validated bridge configuration.
#[derive(Debug, Clone)]
pub struct BridgeConfig {
    /// iceoryx2 service prefix of the local domain (`--prefix`, `TAXEL_PREFIX`).
    pub prefix: String,
    /// Service-name globs (`*` any run of characters including `/`, `?` one character).
    pub allow: Vec<String>,
    /// Zenoh endpoints to listen on (`tcp/ADDR:PORT`, `tls/ADDR:PORT`).
    pub listen: Vec<String>,
    /// Zenoh endpoints to connect to.
    pub connect: Vec<String>,
    /// A Zenoh configuration file (JSON5) to start from; `listen`/`connect` are added to it.
    pub zenoh_file: Option<PathBuf>,
    /// How often the statistics are logged.
    pub report_every: Duration,
    /// Stop after this long (None: until shutdown).
    pub run_for: Option<Duration>,
    /// Listen on addresses other than loopback although nothing authenticates or encrypts
    /// (`--insecure-listen`).
    pub insecure_listen: bool,
    /// TLS with mutual authentication (`--tls-cert`, `--tls-key`, `--tls-ca`).
    pub tls: Option<TlsFiles>,
    /// Compress the link's batches (LZ4; off with `--no-compression`).
    pub compression: bool,
    /// How long a silent link keeps its session (`--lease-s`): after it, both bridges close
    /// the session and the connecting one opens a new one (see [`RECONNECT_FIRST`]).
    pub lease: Duration,
}

/// The default `--lease-s`. TCP alone resumes a session after a cut only at its next
/// retransmission, and its back-off doubles from ~0.2 s: after a 3 s cut the next one may come
/// 3 s after the link returned, and one of them lost (as on a lossy link) doubles that again. A
/// session silent for longer than the lease is closed instead and a fresh connection opened.
pub const DEFAULT_LEASE: Duration = Duration::from_millis(1500);

/// Keep-alive messages per lease (Zenoh's default is 4): a peer that sends no data (the
/// listening bridge, typically) proves it is alive this often, so a lost keep-alive or two on
/// a lossy link does not end the session.
pub const KEEP_ALIVES_PER_LEASE: u32 = 8;

/// How often the connecting bridge tries to open a closed session again (Zenoh's connect retry
/// period: from the first, doubling up to the second, so a peer that refuses us is not hammered
/// and a returning link is found within half a second), and how long one attempt may take
/// (Zenoh's open timeout: TCP resends a lost SYN after 1 s, and a TLS open over a slow link
/// takes several round trips).
pub const RECONNECT_FIRST: Duration = Duration::from_millis(250);
pub const RECONNECT_MAX: Duration = Duration::from_millis(500);
pub const OPEN_TIMEOUT: Duration = Duration::from_millis(2000);

/// The kernel's send buffer of the link's socket. Left to autotuning it started near 64 KiB
/// (`ss -m`; about half a second of compressed raw frames at 1 kHz), and what a TCP stall on
/// a lossy link backs up beyond it lands in Zenoh's queue of 16 batches, which drops what it
/// cannot queue within 20 ms. 4 MiB (the kernel may cap it at `net.core.wmem_max`) leaves the
/// backlog to the kernel. Its effect alone was not measured.
pub const SEND_BUFFER: u32 = 4 << 20;

/// How often the link looks for new and vanished services on both sides.
pub const DISCOVERY_EVERY: Duration = Duration::from_millis(100);

/// Characters a service-name glob may hold: those of taxel service names, `*` and `?`.
fn glob_char_ok(c: char) -> bool {
    c.is_ascii_alphanumeric() || matches!(c, '/' | '_' | '-' | '.' | '*' | '?')
}

impl BridgeConfig {
    /// Checks every field; the error names the flag and the value.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.allow.is_empty() {
            return Err(ConfigError::NoAllow);
        }
        for a in &self.allow {
            if a.is_empty() {
                return Err(ConfigError::BadAllow(a.clone(), "empty glob"));
            }
            if !a.chars().all(glob_char_ok) {
                return Err(ConfigError::BadAllow(
                    a.clone(),
                    "use the characters of service names (A-Z a-z 0-9 / _ - .) and the wildcards * ?",
                ));
            }
        }
        for (flag, list) in [("listen", &self.listen), ("connect", &self.connect)] {
            for e in list {
                check_endpoint(e).map_err(|why| ConfigError::BadEndpoint(flag, e.clone(), why))?;
            }
        }
        if self.listen.is_empty() && self.connect.is_empty() && self.zenoh_file.is_none() {
            return Err(ConfigError::NoEndpoint);
        }
        let zc = self.zenoh()?;
        let zt = ZenohTls::read(&zc);
        self.check_tls(&zc, &zt)?;
        self.check_listen_on_loopback(&zt)?;
        taxel_runtime::ipc::config(&self.prefix)
            .map_err(|e| ConfigError::Prefix(self.prefix.clone(), e.detail))?;
        let s = self.report_every.as_secs_f64();
        if s <= 0.0 {
            return Err(ConfigError::Seconds("report-s", s));
        }
        let l = self.lease.as_secs_f64();
        if !(0.1..=3600.0).contains(&l) {
            return Err(ConfigError::Lease(l));
        }
        Ok(())
    }

    /// TLS: a `tls/` endpoint needs certificates to listen with (or a CA to connect with), and
    /// every TLS file is checked now (exit 2 naming the flag and the file) rather than when
    /// Zenoh opens the session.
    fn check_tls(&self, zc: &zenoh::Config, zt: &ZenohTls) -> Result<(), ConfigError> {
        let is_tls = |e: &String| e.starts_with("tls/");
        let listen = endpoints_in(&zc.get_json("listen/endpoints").unwrap_or_default());
        let connect = endpoints_in(&zc.get_json("connect/endpoints").unwrap_or_default());
        let roles = Roles {
            listen: listen.iter().any(is_tls),
            connect: connect.iter().any(is_tls),
        };
        if let Some(e) = listen
            .iter()
            .find(|e| is_tls(e))
            .filter(|_| !zt.can_listen())
        {
            return Err(ConfigError::TlsEndpoint("listen", e.clone()));
        }
        if let Some(e) = connect
            .iter()
            .find(|e| is_tls(e))
            .filter(|_| !zt.can_connect())
        {
            return Err(ConfigError::TlsEndpoint("connect", e.clone()));
        }
        match (&self.tls, &self.zenoh_file) {
            (Some(f), _) => tls::check(
                &Source::flag("--tls-cert", &f.cert),
                &Source::flag("--tls-key", &f.key),
                &Source::flag("--tls-ca", &f.ca),
                roles,
            ),
            (None, Some(file)) => zt.check_files(file, roles),
            (None, None) => Ok(()),
        }
    }

    /// Unless `--insecure-listen`, the bridge listens on loopback only, or on a `tls/`
    /// endpoint with mutual authentication: every `--listen` endpoint, and every endpoint a
    /// `--zenoh-config` file listens on (Zenoh's default when the file names none is every
    /// interface).
    fn check_listen_on_loopback(&self, zt: &ZenohTls) -> Result<(), ConfigError> {
        if self.insecure_listen {
            return Ok(());
        }
        let ok = |e: &str| {
            endpoint_is_loopback(e) || (e.starts_with("tls/") && zt.authenticates_peers())
        };
        for e in &self.listen {
            if !ok(e) {
                return Err(ConfigError::OpenListen("--listen".into(), e.clone()));
            }
        }
        if let Some(p) = &self.zenoh_file {
            let c = self.zenoh()?;
            let what = format!("--zenoh-config {}: listen endpoint", p.display());
            let json = c.get_json("listen/endpoints").unwrap_or_default();
            for e in endpoints_in(&json) {
                if !ok(&e) {
                    return Err(ConfigError::OpenListen(what, e));
                }
            }
        }
        Ok(())
    }

    /// The allow list the link filters service names with.
    pub fn allow_list(&self) -> AllowList {
        AllowList::new(&self.allow)
    }

    /// Whether a service name passes the allow list.
    pub fn allows(&self, name: &str) -> bool {
        self.allow_list().admits(name)
    }

    /// The iceoryx2 configuration of the local domain, with taxel's stream QoS as the defaults.
    pub fn iceoryx2(&self) -> Result<Config, ConfigError> {
        let mut c = taxel_runtime::ipc::config(&self.prefix)
            .map_err(|e| ConfigError::Prefix(self.prefix.clone(), e.detail))?;
        stream_defaults(&mut c);
        Ok(c)
    }

    /// The Zenoh configuration: the file (or Zenoh's defaults), peer mode, multicast scouting
    /// off (peers are named explicitly), the given endpoints.
    pub fn zenoh(&self) -> Result<zenoh::Config, ConfigError> {
        let mut c = match &self.zenoh_file {
            Some(p) => zenoh::Config::from_file(p)
                .map_err(|e| ConfigError::ZenohFile(p.clone(), one_line(&e.to_string())))?,
            None => {
                let mut c = zenoh::Config::default();
                set(&mut c, "mode", "\"peer\"")?;
                set(&mut c, "scouting/multicast/enabled", "false")?;
                // Without this a peer listens on every interface on a random port.
                set(&mut c, "listen/endpoints", "[]")?;
                c
            }
        };
        // Zenoh queues 2 batches (~30 raw frames) per priority and drops a message it cannot
        // queue within 1 ms: a scheduling hiccup of a few tens of ms on a loaded host then
        // loses frames. 16 batches (~240 raw frames, 1 MiB) and 20 ms ride such hiccups out.
        set(&mut c, "transport/link/tx/queue/size/data", "16")?;
        set(
            &mut c,
            "transport/link/tx/queue/congestion_control/drop/wait_before_drop",
            "20000",
        )?;
        // Fixed-size frames are mostly zeros: compressed, a 4 x 4 raw frame's 4 KiB of counts
        // cross as a few hundred bytes, which a lossy or slow link can carry at 1 kHz.
        set(
            &mut c,
            "transport/unicast/compression/enabled",
            if self.compression { "true" } else { "false" },
        )?;
        self.set_reconnection(&mut c)?;
        if let Some(f) = &self.tls {
            for (key, value) in tls::zenoh_settings(f) {
                set(&mut c, key, &value)?;
            }
        }
        if !self.listen.is_empty() {
            set(&mut c, "listen/endpoints", &json_list(&self.listen))?;
        }
        if !self.connect.is_empty() {
            set(&mut c, "connect/endpoints", &json_list(&self.connect))?;
        }
        Ok(c)
    }

    /// The lease, the reconnect period and open timeout, and the sockets' send buffers: a cut
    /// link costs the frames sent during it, and fresh frames flow again within about a
    /// second after it returns (docs/bridge.md, "When the link is cut").
    fn set_reconnection(&self, c: &mut zenoh::Config) -> Result<(), ConfigError> {
        let ms = |d: Duration| d.as_millis().to_string();
        set(c, "transport/link/tx/lease", &ms(self.lease))?;
        set(
            c,
            "transport/link/tx/keep_alive",
            &KEEP_ALIVES_PER_LEASE.to_string(),
        )?;
        set(c, "transport/unicast/open_timeout", &ms(OPEN_TIMEOUT))?;
        let (first, max) = (ms(RECONNECT_FIRST), ms(RECONNECT_MAX));
        set(
            c,
            "connect/retry",
            &format!(
                "{{period_init_ms: {first}, period_max_ms: {max}, period_increase_factor: 2.0}}"
            ),
        )?;
        for link in ["tcp", "tls"] {
            set(
                c,
                &format!("transport/link/{link}/so_sndbuf"),
                &SEND_BUFFER.to_string(),
            )?;
        }
        Ok(())
    }
}

fn set(c: &mut zenoh::Config, key: &str, value: &str) -> Result<(), ConfigError> {
    c.insert_json5(key, value)
        .map_err(|e| ConfigError::Zenoh(format!("{key} = {value}"), one_line(&e.to_string())))
}

fn json_list(items: &[String]) -> String {
    let quoted: Vec<String> = items
        .iter()
        .map(|s| serde_json::Value::String(s.clone()).to_string())
        .collect();
    format!("[{}]", quoted.join(","))
}

fn one_line(s: &str) -> String {
    s.replace('\n', " ")
}

/// Zenoh is built with TCP and TLS only: `tcp/HOST:PORT` or `tls/HOST:PORT`, HOST a name, an
/// IPv4 address or `[IPv6]`.
fn check_endpoint(e: &str) -> Result<(), String> {
    let Some(addr) = e.strip_prefix("tcp/").or_else(|| e.strip_prefix("tls/")) else {
        return Err(
            "use tcp/HOST:PORT or tls/HOST:PORT (the bridge is built with Zenoh's TCP and TLS transports only)".into(),
        );
    };
    let addr = addr.split('#').next().unwrap_or(addr);
    let Some((host, port)) = addr.rsplit_once(':') else {
        return Err("missing :PORT".into());
    };
    if host.is_empty() {
        return Err("missing HOST".into());
    }
    port.parse::<u16>()
        .map_err(|_| format!("port {port:?} is not a number from 0 to 65535"))?;
    Ok(())
}

/// Whether a `tcp/HOST:PORT` (or `tls/`) endpoint listens on loopback only: `localhost`,
/// 127.0.0.0/8 or `[::1]`.
fn endpoint_is_loopback(e: &str) -> bool {
    let addr = e
        .strip_prefix("tcp/")
        .or_else(|| e.strip_prefix("tls/"))
        .unwrap_or(e);
    let addr = addr.split('#').next().unwrap_or(addr);
    let Some((host, _port)) = addr.rsplit_once(':') else {
        return false;
    };
    let host = host.trim_start_matches('[').trim_end_matches(']');
    host.eq_ignore_ascii_case("localhost")
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

/// Every endpoint string (`proto/address`) in a JSON value: a list, or Zenoh's values per mode.
fn endpoints_in(json: &str) -> Vec<String> {
    fn walk(v: &serde_json::Value, out: &mut Vec<String>) {
        match v {
            serde_json::Value::String(s) if s.contains('/') => out.push(s.clone()),
            serde_json::Value::Array(a) => a.iter().for_each(|x| walk(x, out)),
            serde_json::Value::Object(m) => m.values().for_each(|x| walk(x, out)),
            _ => {}
        }
    }
    let mut out = Vec::new();
    if let Ok(v) = serde_json::from_str::<serde_json::Value>(json) {
        walk(&v, &mut out);
    }
    out
}

/// Makes taxel's stream settings (runtime/src/ipc.rs) the defaults, so a mirror the link
/// creates accepts taxel processes opening it: buffer, subscribers, publishers, nodes, safe
/// overflow, and the largest buffer and history of any stream (a process may ask for less).
pub fn stream_defaults(c: &mut Config) {
    let ps = &mut c.defaults.publish_subscribe;
    ps.subscriber_max_buffer_size = max_stream_buffer();
    ps.max_subscribers = MAX_SUBSCRIBERS;
    ps.max_publishers = MAX_PUBLISHERS;
    ps.max_nodes = MAX_NODES;
    ps.enable_safe_overflow = true;
    ps.publisher_history_size = Stream::ALL.iter().map(|s| s.history()).max().unwrap_or(0);
    let ev = &mut c.defaults.event;
    ev.max_nodes = MAX_NODES;
    ev.max_listeners = MAX_SUBSCRIBERS;
    ev.max_notifiers = MAX_PUBLISHERS * 2;
}

/// The largest subscriber buffer of any stream (`Stream::buffer`).
fn max_stream_buffer() -> usize {
    Stream::ALL.iter().map(|s| s.buffer()).max().unwrap_or(1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> BridgeConfig {
        BridgeConfig {
            prefix: "taxel_".into(),
            allow: vec!["taxel/glove0/*".into()],
            listen: vec!["tcp/127.0.0.1:7447".into()],
            connect: vec![],
            zenoh_file: None,
            report_every: Duration::from_secs(5),
            run_for: None,
            insecure_listen: false,
            tls: None,
            compression: true,
            lease: DEFAULT_LEASE,
        }
    }

    #[test]
    fn globs_match_taxel_streams() {
        let c = cfg();
        assert!(c.allows("taxel/glove0/raw"));
        assert!(c.allows("taxel/glove0/force"));
        assert!(!c.allows("taxel/glove1/raw"));
        let mut c = cfg();
        c.allow = vec!["taxel/*/raw".into(), "taxel/s?/force".into()];
        assert!(c.allows("taxel/glove1/raw"));
        assert!(c.allows("taxel/s1/force"));
        assert!(!c.allows("taxel/s10/force"));
    }

    #[test]
    fn bad_values_are_refused_with_the_flag_named() {
        let mut c = cfg();
        c.allow.clear();
        assert!(c
            .validate()
            .expect_err("refused")
            .to_string()
            .contains("--allow"));
        let mut c = cfg();
        c.allow = vec!["taxel/glove 0/*".into()];
        assert!(c
            .validate()
            .expect_err("refused")
            .to_string()
            .contains("--allow"));
        for bad in [
            "udp/1.2.3.4:5",
            "tcp/1.2.3.4",
            "tcp/:7447",
            "tcp/h:99999",
            "7447",
        ] {
            let mut c = cfg();
            c.listen = vec![bad.into()];
            let e = c.validate().expect_err("refused").to_string();
            assert!(e.starts_with("--listen"), "{bad}: {e}");
        }
        let mut c = cfg();
        c.listen.clear();
        assert!(matches!(c.validate(), Err(ConfigError::NoEndpoint)));
        let mut c = cfg();
        c.prefix = "a/b".into();
        assert!(c
            .validate()
            .expect_err("refused")
            .to_string()
            .contains("--prefix"));
        let mut c = cfg();
        c.connect = vec!["tcp/[::1]:7447".into(), "tcp/glove-pc.local:7447".into()];
        c.validate().expect("valid endpoints");
        c.zenoh().expect("zenoh accepts the endpoints");
    }

    #[test]
    fn the_lease_reconnect_period_and_send_buffers_reach_zenoh() {
        let mut c = cfg();
        c.lease = Duration::from_millis(2500);
        let z = c.zenoh().expect("zenoh");
        let get = |k: &str| z.get_json(k).expect(k);
        assert_eq!(get("transport/link/tx/lease"), "2500");
        assert_eq!(get("transport/unicast/open_timeout"), "2000");
        assert_eq!(get("transport/link/tx/keep_alive"), "8");
        let retry = get("connect/retry");
        assert!(retry.contains("\"period_init_ms\":250"), "{retry}");
        assert!(retry.contains("\"period_max_ms\":500"), "{retry}");
        assert!(retry.contains("\"period_increase_factor\":2.0"), "{retry}");
        assert_eq!(
            get("transport/link/tls/so_sndbuf"),
            (4u32 << 20).to_string()
        );
        assert_eq!(
            get("transport/link/tcp/so_sndbuf"),
            (4u32 << 20).to_string()
        );
        for bad in [0.05, 4000.0] {
            c.lease = Duration::from_secs_f64(bad);
            let e = c.validate().expect_err("refused").to_string();
            assert!(e.starts_with("--lease-s"), "{e}");
        }
    }

    #[test]
    fn without_tls_only_loopback_is_listened_on_unless_insecure() {
        for ok in [
            "tcp/127.0.0.1:7447",
            "tcp/127.3.2.1:1",
            "tcp/[::1]:7447",
            "tcp/localhost:7447",
        ] {
            let mut c = cfg();
            c.listen = vec![ok.into()];
            c.validate().unwrap_or_else(|e| panic!("{ok}: {e}"));
        }
        for open in [
            "tcp/0.0.0.0:7447",
            "tcp/[::]:7447",
            "tcp/192.168.1.4:7447",
            "tcp/glove-pc:7447",
        ] {
            let mut c = cfg();
            c.listen = vec![open.into()];
            let e = c.validate().expect_err("refused").to_string();
            assert!(
                e.starts_with("--listen") && e.contains("--insecure-listen"),
                "{open}: {e}"
            );
            c.insecure_listen = true;
            c.validate()
                .unwrap_or_else(|e| panic!("{open} with --insecure-listen: {e}"));
        }
        // Connecting out is not listening.
        let mut c = cfg();
        c.connect = vec!["tcp/192.168.1.4:7447".into()];
        c.validate().expect("connect to any host");
        // A Zenoh file: the endpoints it listens on, or Zenoh's default (every interface).
        let dir = tempfile::tempdir().expect("dir");
        for (text, open) in [
            (r#"{ listen: { endpoints: ["tcp/0.0.0.0:7447"] } }"#, true),
            (r#"{ mode: "peer" }"#, true),
            (
                r#"{ listen: { endpoints: ["tcp/127.0.0.1:7447"] } }"#,
                false,
            ),
            (r#"{ listen: { endpoints: [] } }"#, false),
        ] {
            let p = dir.path().join("z.json5");
            std::fs::write(&p, text).expect("write");
            let mut c = cfg();
            c.listen.clear();
            c.zenoh_file = Some(p);
            let r = c.validate();
            assert_eq!(r.is_err(), open, "{text}: {r:?}");
            if let Err(e) = r {
                assert!(e.to_string().starts_with("--zenoh-config"), "{e}");
            }
        }
    }

    #[test]
    fn tls_endpoints_need_certificates_and_may_listen_on_a_network() {
        let dir = tempfile::tempdir().expect("dir");
        let certs = dir.path().join("certs");
        crate::certs::make(&crate::certs::CertsSpec {
            out: certs.clone(),
            hosts: vec![],
            days: 2,
            force: false,
        })
        .expect("certificates");
        let files = TlsFiles {
            cert: certs.join("server.pem"),
            key: certs.join("server.key"),
            ca: certs.join("ca.pem"),
        };
        // A tls/ endpoint without certificates: refused, naming the flags.
        let mut c = cfg();
        c.listen = vec!["tls/0.0.0.0:7447".into()];
        let e = c.validate().expect_err("no certificates").to_string();
        assert!(e.starts_with("--listen") && e.contains("--tls-cert"), "{e}");
        c.connect = vec![];
        // With them: a network address is fine, and Zenoh gets mutual TLS.
        c.tls = Some(files.clone());
        c.validate().expect("mutual TLS on a network");
        let z = c.zenoh().expect("zenoh");
        let zt = ZenohTls::read(&z);
        assert!(zt.mtls && zt.authenticates_peers(), "{zt:?}");
        // TCP stays loopback-only, TLS or not.
        c.listen = vec!["tcp/0.0.0.0:7447".into()];
        let e = c.validate().expect_err("tcp on a network").to_string();
        assert!(e.contains("--insecure-listen"), "{e}");
        // A bad file: one line naming the flag and the file.
        let mut c = cfg();
        c.listen = vec!["tls/0.0.0.0:7447".into()];
        c.tls = Some(TlsFiles {
            key: certs.join("client.key"),
            ..files.clone()
        });
        let e = c.validate().expect_err("mismatched key").to_string();
        assert!(
            e.starts_with("--tls-key") && e.contains("client.key"),
            "{e}"
        );
        // The same through a Zenoh file: mutual TLS may listen on a network, TLS without
        // client certificates may not, and its files are checked, naming the key.
        let p = dir.path().join("z.json5");
        let q = |n: &str| certs.join(n).display().to_string();
        for (mtls, key, ok) in [
            (true, "server.key", true),
            (false, "server.key", false),
            (true, "client.key", false),
        ] {
            std::fs::write(
                &p,
                format!(
                    r#"{{ listen: {{ endpoints: ["tls/0.0.0.0:7447"] }}, transport: {{ link: {{ tls: {{ root_ca_certificate: "{}", listen_certificate: "{}", listen_private_key: "{}", enable_mtls: {mtls} }} }} }} }}"#,
                    q("ca.pem"),
                    q("server.pem"),
                    q(key)
                ),
            )
            .expect("write");
            let mut c = cfg();
            c.listen.clear();
            c.zenoh_file = Some(p.clone());
            let r = c.validate();
            assert_eq!(r.is_ok(), ok, "mtls {mtls}, {key}: {r:?}");
            if let Err(e) = r {
                let e = e.to_string();
                assert!(e.starts_with("--zenoh-config"), "{e}");
                if key == "client.key" {
                    assert!(
                        e.contains("listen_private_key") && e.contains("client.key"),
                        "{e}"
                    );
                }
            }
        }
    }

    #[test]
    fn mirrors_get_the_stream_qos() {
        let c = cfg().iceoryx2().expect("config");
        let ps = &c.defaults.publish_subscribe;
        assert_eq!(ps.subscriber_max_buffer_size, Stream::Raw.buffer());
        assert_eq!(ps.max_subscribers, MAX_SUBSCRIBERS);
        assert_eq!(ps.publisher_history_size, 1);
        assert!(ps.enable_safe_overflow);
    }

    #[test]
    fn the_link_is_compressed_unless_told_not_to() {
        let on = |c: &BridgeConfig| {
            c.zenoh()
                .expect("zenoh config")
                .get_json("transport/unicast/compression/enabled")
                .expect("key")
        };
        let mut c = cfg();
        assert_eq!(on(&c), "true");
        c.compression = false;
        assert_eq!(on(&c), "false");
    }
}
