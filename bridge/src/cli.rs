//! `taxel bridge` / `taxel-bridge`: arguments, validation (exit 2 with one line naming the
//! flag), tracing, shutdown, and the final report on stdout; `taxel bridge certs` writes test
//! certificates.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::Shutdown;

use crate::certs::{CertsError, CertsSpec};
use crate::config::{BridgeConfig, DEFAULT_LEASE};
use crate::run::{run, BridgeError};
use crate::tls::{RefusalLayer, TlsFiles};

/// Relay chosen iceoryx2 services to other hosts over Zenoh, for observation and logging (not
/// for control: keep the control loop on the sensor's host). Run one on each host with the
/// same --allow globs; one --listen, the others --connect to it.
#[derive(Debug, Parser)]
#[command(name = "taxel-bridge", version, args_conflicts_with_subcommands = true)]
pub struct Args {
    #[command(subcommand)]
    pub command: Option<Command>,
    #[command(flatten)]
    pub common: CommonArgs,
    /// Service-name glob to bridge, repeatable: `*` matches any run of characters (also `/`),
    /// `?` one character. E.g. 'taxel/glove0/*' or 'taxel/*/force'.
    #[arg(long)]
    pub allow: Vec<String>,
    /// Zenoh endpoint to listen on, repeatable, e.g. tls/0.0.0.0:7447 (with --tls-*) or
    /// tcp/127.0.0.1:7447. tcp/ (and tls/ without mutual authentication): loopback only
    /// unless --insecure-listen.
    #[arg(long)]
    pub listen: Vec<String>,
    /// Listen on addresses other than loopback (tcp/0.0.0.0:7447, a LAN address) although the
    /// link is neither authenticated nor encrypted: anyone who reaches the port can read and
    /// inject the allowed streams.
    #[arg(long)]
    pub insecure_listen: bool,
    /// Zenoh endpoint of a peer bridge to connect to, repeatable, e.g. tls/glove-pc:7447 or
    /// tcp/127.0.0.1:7447.
    #[arg(long)]
    pub connect: Vec<String>,
    /// TLS with mutual authentication: this bridge's certificate (PEM), presented when it
    /// listens and when it connects (`taxel bridge certs` makes one). With --tls-key and
    /// --tls-ca.
    #[arg(long, value_name = "PEM")]
    pub tls_cert: Option<PathBuf>,
    /// The private key of --tls-cert (PEM).
    #[arg(long, value_name = "PEM")]
    pub tls_key: Option<PathBuf>,
    /// The CA certificate (PEM) every peer's certificate must be signed by; peers without one
    /// are refused.
    #[arg(long, value_name = "PEM")]
    pub tls_ca: Option<PathBuf>,
    /// Zenoh configuration file (JSON5) to start from (e.g. for access control, or TLS under
    /// transport.link.tls); --listen, --connect and --tls-* are added to it.
    #[arg(long)]
    pub zenoh_config: Option<PathBuf>,
    /// Send the link's batches uncompressed. By default both bridges compress them (LZ4,
    /// Zenoh's transport compression, negotiated per session: on only if both peers have it):
    /// a 4 x 4 raw frame fills 64 of its fixed 4 KiB of counts, so 1 kHz of raw frames is
    /// 33 Mbit/s uncompressed and about 1 Mbit/s compressed.
    #[arg(long)]
    pub no_compression: bool,
    /// Close a session whose link has been silent this long (seconds; Zenoh's lease) and open
    /// a new one: after a cut longer than this, fresh frames flow again about a second after
    /// the link returns, and frames sent during the cut are lost (each hole is a seq gap). Both
    /// bridges should use the same value.
    #[arg(long, default_value_t = DEFAULT_LEASE.as_secs_f64())]
    pub lease_s: f64,
    /// Log each stream's counts, losses and ages this often (seconds).
    #[arg(long, default_value_t = 5.0)]
    pub report_s: f64,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    pub seconds: Option<f64>,
}

#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Write a private CA, a server pair and a client pair (PEM) to try TLS with: ca.pem,
    /// ca.key, server.pem, server.key, client.pem, client.key.
    Certs(CertsArgs),
}

#[derive(Debug, clap::Args)]
pub struct CertsArgs {
    /// Directory to write the files to (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Another name of the listening host for the server certificate (DNS name or IP address),
    /// repeatable; localhost, 127.0.0.1 and ::1 are always in it. A bridge connecting to
    /// tls/HOST:PORT checks HOST against these names.
    #[arg(long)]
    pub host: Vec<String>,
    /// Validity of the certificates in days.
    #[arg(long, default_value_t = 365)]
    pub days: u32,
    /// Replace files that exist.
    #[arg(long)]
    pub force: bool,
}

fn seconds(flag: &'static str, s: f64) -> Result<Duration, Failure> {
    if s.is_finite() && s > 0.0 {
        Ok(Duration::from_secs_f64(s))
    } else {
        Err(Failure::config(anyhow::anyhow!(
            "--{flag} {s}: must be a positive number of seconds"
        )))
    }
}

impl Args {
    pub fn config(&self) -> Result<BridgeConfig, Failure> {
        let cfg = BridgeConfig {
            prefix: self.common.prefix.clone(),
            allow: self.allow.clone(),
            listen: self.listen.clone(),
            connect: self.connect.clone(),
            zenoh_file: self.zenoh_config.clone(),
            report_every: seconds("report-s", self.report_s)?,
            run_for: self.seconds.map(|s| seconds("seconds", s)).transpose()?,
            insecure_listen: self.insecure_listen,
            compression: !self.no_compression,
            lease: seconds("lease-s", self.lease_s)?,
            tls: TlsFiles::from_flags(
                self.tls_cert.clone(),
                self.tls_key.clone(),
                self.tls_ca.clone(),
            )
            .config_err()?,
        };
        cfg.validate().config_err()?;
        Ok(cfg)
    }
}

/// The Zenoh module that logs why a session's link stopped ("TX task failed: ...").
pub const SESSION_END: &str = "zenoh_transport::unicast::universal::link";

pub fn main(args: Args) -> ExitCode {
    // Zenoh logs its own start-up at info; keep it to warnings unless asked for. Why a session
    // ended (its link's TX or RX task failed: a lease that expired, a peer that closed, a TLS
    // error) Zenoh says only at debug, once per session: keep that.
    let filter = if args.common.log.contains("zenoh") {
        args.common.log.clone()
    } else {
        format!(
            "{},zenoh=warn,zenoh_transport=warn,{SESSION_END}=debug,zenoh_link_tcp=warn,zenoh_link_tls=warn",
            args.common.log
        )
    };
    if let Some(Command::Certs(c)) = &args.command {
        init_tracing(&filter);
        return exit_code("taxel-bridge certs", certs(c));
    }
    taxel_runtime::process::init_tracing_with(&filter, Some(Box::new(RefusalLayer)));
    exit_code("taxel-bridge", main_inner(&args))
}

fn certs(a: &CertsArgs) -> Result<(), Failure> {
    let spec = CertsSpec {
        out: a.out.clone(),
        hosts: a.host.clone(),
        days: a.days,
        force: a.force,
    };
    let files = match crate::certs::make(&spec) {
        Ok(f) => f,
        Err(e @ (CertsError::Io(..) | CertsError::Rcgen(_))) => return Err(Failure::runtime(e)),
        Err(e) => return Err(Failure::config(e)),
    };
    for f in &files {
        println!("wrote {}", f.display());
    }
    let d = a.out.display();
    println!(
        "listening host:  taxel bridge --allow GLOB --listen tls/0.0.0.0:7447 --tls-cert {d}/server.pem --tls-key {d}/server.key --tls-ca {d}/ca.pem"
    );
    println!(
        "connecting host: taxel bridge --allow GLOB --connect tls/HOST:7447 --tls-cert {d}/client.pem --tls-key {d}/client.key --tls-ca {d}/ca.pem"
    );
    println!("keep ca.key off both hosts (it signs new certificates); HOST must be one of the server certificate's names (--host)");
    Ok(())
}

fn main_inner(args: &Args) -> Result<(), Failure> {
    let cfg = args.config()?;
    tracing::info!("effective configuration: {cfg:?}");
    if cfg.insecure_listen {
        tracing::warn!(
            "--insecure-listen: listening without authentication or encryption; anyone who reaches {:?} can read and inject the allowed streams",
            cfg.listen
        );
    } else if let Some(t) = &cfg.tls {
        tracing::info!(
            "TLS with mutual authentication: peers need a certificate signed by {}",
            t.ca.display()
        );
    } else if !cfg.listen.is_empty() || cfg.zenoh_file.is_some() {
        tracing::info!(
            "without TLS: listening on loopback only (tls/ with --tls-cert, --tls-key and --tls-ca, or --insecure-listen, to listen on a network)"
        );
    }
    if cfg.tls.is_some()
        && !cfg
            .listen
            .iter()
            .chain(&cfg.connect)
            .any(|e| e.starts_with("tls/"))
    {
        tracing::warn!("--tls-cert, --tls-key and --tls-ca are set but no --listen or --connect endpoint is tls/HOST:PORT");
    }
    let shutdown = Shutdown::install().runtime_err()?;
    let report = match run(&cfg, &shutdown) {
        Ok(r) => r,
        Err(e @ BridgeError::Config(_)) => return Err(Failure::config(e)),
        Err(e) => return Err(Failure::runtime(e)),
    };
    println!(
        "taxel bridge: {:.1} s, {} stream(s) bridged",
        report.seconds,
        report.streams.len()
    );
    for l in report.lines() {
        println!("  {l}");
    }
    if report.refused > 0 {
        println!("  refused TLS peers: {}", report.refused);
    }
    Ok(())
}
