//! The process skeleton shared by every taxel binary: common flags, tracing, the shutdown flag
//! and the mapping of results to exit codes.

use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Environment variable a launcher sets to its own pid: a child whose parent goes away shuts
/// down instead of running on as an orphan.
pub const PARENT_PID_ENV: &str = "TAXEL_PARENT_PID";

/// Environment variable a supervisor sets on a restarted process (its restart count): sources
/// and the calibrator flag their first sample after a restart with a gap.
pub const RESTART_ENV: &str = "TAXEL_RESTART";

/// Whether this process was started by a supervisor as the replacement of a dead one.
pub fn restarted() -> bool {
    std::env::var_os(RESTART_ENV).is_some_and(|v| !v.is_empty() && v != "0")
}

/// Flags every process takes.
#[derive(Debug, Clone, clap::Args)]
pub struct CommonArgs {
    /// iceoryx2 service prefix: processes only see services of the same prefix (isolates tests
    /// and parallel pipelines).
    #[arg(long, env = "TAXEL_PREFIX", default_value = "taxel_", global = true)]
    pub prefix: String,
    /// Log filter (tracing EnvFilter syntax, e.g. `debug` or `info,taxel_calibrator=trace`);
    /// RUST_LOG wins when set.
    #[arg(long, default_value = "info", global = true)]
    pub log: String,
}

/// Why a process failed: bad configuration (exit 2) or a runtime failure (exit 1).
#[derive(Debug)]
pub enum Failure {
    Config(anyhow::Error),
    Runtime(anyhow::Error),
}

impl Failure {
    pub fn config(e: impl Into<anyhow::Error>) -> Failure {
        Failure::Config(e.into())
    }
    pub fn runtime(e: impl Into<anyhow::Error>) -> Failure {
        Failure::Runtime(e.into())
    }
}

/// Extension to tag errors as configuration or runtime failures.
pub trait ResultExt<T> {
    fn config_err(self) -> Result<T, Failure>;
    fn runtime_err(self) -> Result<T, Failure>;
}

impl<T, E: Into<anyhow::Error>> ResultExt<T> for Result<T, E> {
    fn config_err(self) -> Result<T, Failure> {
        self.map_err(Failure::config)
    }
    fn runtime_err(self) -> Result<T, Failure> {
        self.map_err(Failure::runtime)
    }
}

/// Prints a failure as one line on stderr and returns the exit code.
pub fn exit_code(program: &str, r: Result<(), Failure>) -> ExitCode {
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure::Config(e)) => {
            eprintln!("{program}: error: {}", one_line(&e));
            ExitCode::from(2)
        }
        Err(Failure::Runtime(e)) => {
            eprintln!("{program}: error: {}", one_line(&e));
            ExitCode::from(1)
        }
    }
}

fn one_line(e: &anyhow::Error) -> String {
    format!("{e:#}").replace('\n', " ")
}

/// Installs the one tracing subscriber of this process (stderr). iceoryx2's own log output is
/// gated at `warn` unless the filter asks for more.
pub fn init_tracing(filter: &str) {
    init_tracing_with(filter, None);
}

/// A tracing layer a process adds to the standard output (e.g. the bridge, to notice refused
/// TLS peers in Zenoh's log events).
pub type ExtraLayer =
    Box<dyn tracing_subscriber::Layer<tracing_subscriber::Registry> + Send + Sync>;

/// [`init_tracing`] with one more layer, which sees the events the filter lets through.
pub fn init_tracing_with(filter: &str, extra: Option<ExtraLayer>) {
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    use tracing_subscriber::EnvFilter;
    let base = std::env::var("RUST_LOG").unwrap_or_else(|_| filter.to_string());
    let with_iox = if base.contains("iceoryx2") {
        base.clone()
    } else {
        format!("{base},iceoryx2_bb_loggers=warn")
    };
    let env = EnvFilter::try_new(&with_iox).unwrap_or_else(|_| EnvFilter::new("info"));
    match extra {
        None => {
            let _ = tracing_subscriber::fmt()
                .with_env_filter(env)
                .with_writer(std::io::stderr)
                .with_target(false)
                .compact()
                .try_init();
        }
        Some(extra) => {
            let fmt = tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                .with_target(false)
                .compact();
            let _ = tracing_subscriber::registry()
                .with(extra)
                .with(env)
                .with(fmt)
                .try_init();
        }
    }
    let level = if with_iox.contains("iceoryx2_bb_loggers=trace") {
        iceoryx2::prelude::LogLevel::Trace
    } else if with_iox.contains("iceoryx2_bb_loggers=debug") {
        iceoryx2::prelude::LogLevel::Debug
    } else if with_iox.contains("iceoryx2_bb_loggers=info") {
        iceoryx2::prelude::LogLevel::Info
    } else {
        iceoryx2::prelude::LogLevel::Warn
    };
    iceoryx2::prelude::set_log_level(level);
}

/// The shutdown flag. One owner of SIGINT/SIGTERM per process (ctrlc with `termination`); every
/// loop checks the flag at least every ~100 ms.
#[derive(Debug, Clone, Default)]
pub struct Shutdown(Arc<AtomicBool>);

impl Shutdown {
    /// A flag nobody but the caller sets (tests, embedded use).
    pub fn manual() -> Shutdown {
        Shutdown::default()
    }

    /// Installs the SIGINT/SIGTERM handler and, when launched by a taxel launcher, a watch on
    /// the parent process. Call once per process.
    pub fn install() -> anyhow::Result<Shutdown> {
        let s = Shutdown::default();
        let flag = s.0.clone();
        ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst))
            .map_err(|e| anyhow::anyhow!("cannot install the signal handler: {e}"))?;
        if let Some(ppid) = std::env::var(PARENT_PID_ENV)
            .ok()
            .and_then(|v| v.parse::<u32>().ok())
        {
            let flag = s.0.clone();
            std::thread::Builder::new()
                .name("parent-watch".into())
                .spawn(move || loop {
                    if std::os::unix::process::parent_id() != ppid {
                        tracing::warn!("launcher {ppid} is gone; shutting down");
                        flag.store(true, Ordering::SeqCst);
                        return;
                    }
                    if flag.load(Ordering::Relaxed) {
                        return;
                    }
                    std::thread::sleep(Duration::from_millis(200));
                })?;
        }
        Ok(s)
    }

    pub fn requested(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }

    pub fn request(&self) {
        self.0.store(true, Ordering::SeqCst)
    }
}

/// CPU time (user + system) this process has used (s).
pub fn cpu_seconds() -> f64 {
    // SAFETY: getrusage fills the struct we own.
    let mut r: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe {
        libc::getrusage(libc::RUSAGE_SELF, &mut r);
    }
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    tv(r.ru_utime) + tv(r.ru_stime)
}
