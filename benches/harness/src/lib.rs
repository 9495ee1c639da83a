//! taxel-bench owns `taxel bench`, the latency harness (the criterion micro-benchmarks sit
//! beside it, in `benches/`): latency of our pipeline against raw iceoryx2 and classic IPC, in
//! one run, as separate processes with the same payload (a RawFrame, 4 160 bytes), at 1 kHz.
//! Writes a Markdown table, one JSON object (`--json` on stdout) and a percentile plot. The
//! processes are `taxel` roles and `taxel bench-peer` (`peers`, the socket baselines) started
//! from the running executable, so this library only works inside the `taxel` launcher.

mod cases;
pub mod peers;
mod platform;
mod python;
mod report;
mod skin;

use std::io::Read;
use std::path::PathBuf;
use std::process::{Child, Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

use taxel_runtime::process::{exit_code, Failure, ResultExt};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// 3 s per case instead of 10 s.
    #[arg(long)]
    pub quick: bool,
    /// Print one JSON object on stdout (the table and plots are still written).
    #[arg(long)]
    pub json: bool,
    /// Directory for bench.md, bench.json and the latency plots (default: a fresh directory
    /// under the system temp dir, printed).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Stream rate (Hz).
    #[arg(long, default_value_t = 1000.0)]
    pub rate_hz: f64,
    /// Seconds per case (overrides --quick).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Run only these cases (comma-separated names, e.g. `iox2_event_1hop,force_path_adaptive`;
    /// default: all).
    #[arg(long, value_delimiter = ',')]
    pub cases: Vec<String>,
    /// The Python with the taxel package installed, for `python_subscriber_event` (skipped in
    /// a run of every case when it cannot import taxel).
    #[arg(long, env = "TAXEL_PYTHON", default_value = "python3")]
    pub python: String,
}

/// One case's measurement.
#[derive(Debug, Clone, Default)]
struct CaseResult {
    case: String,
    received: f64,
    dropped: f64,
    p50: f64,
    p90: f64,
    p99: f64,
    p999: f64,
    max: f64,
    /// CPU of the waiting processes (% of one core each, summed).
    cpu_pct: f64,
    /// The busiest waiting process's CPU (% of one core).
    cpu_pct_max_process: f64,
    /// Stream rate of the case (Hz).
    rate_hz: f64,
    /// Sensors of a many-sensor case (0: one stream).
    sensors: usize,
    /// Samples the probe's window should hold (0: not counted).
    expected: f64,
    /// CPU and memory per role (skin cases).
    roles: Vec<RoleStat>,
    /// A search's runs: sensor count, whether nothing was lost, what was seen.
    trials: Vec<(usize, bool, String)>,
    /// The platform's wake-up lateness over the same window (real-time cases).
    platform: Option<platform::Lateness>,
}

/// One role's processes in a case.
#[derive(Debug, Clone, Default)]
struct RoleStat {
    role: String,
    processes: usize,
    /// CPU of all its processes (% of one core, summed) and of the busiest one.
    cpu_pct: f64,
    cpu_pct_max_process: f64,
    /// Resident memory (VmRSS) at the end of the window, of all its processes and of the
    /// largest one (MB), and of all after the warm-up.
    rss_mb: f64,
    rss_mb_max_process: f64,
    rss_warm_mb: f64,
    /// Private memory (RssAnon: heap and stacks, not the shared-memory pools whose pages count
    /// in VmRSS as they are first touched) of all its processes after the warm-up and at the
    /// end (MB): a leak shows here.
    private_warm_mb: f64,
    private_mb: f64,
}

fn field(json: &str, key: &str) -> f64 {
    let k = format!("\"{key}\": ");
    json.find(&k)
        .and_then(|at| {
            json[at + k.len()..]
                .split([',', '}'])
                .next()
                .and_then(|v| v.trim().parse().ok())
        })
        .unwrap_or(f64::NAN)
}

fn taxel(args: &[String], prefix: &str) -> anyhow::Result<Child> {
    Ok(Command::new(std::env::current_exe()?)
        .args(args)
        .env("TAXEL_PREFIX", prefix)
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()?)
}

fn s(v: &str) -> String {
    v.to_string()
}

/// CPU seconds (user + system) of a process so far, from /proc.
fn cpu_of(pid: u32) -> f64 {
    let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
        return 0.0;
    };
    let after = stat.rfind(')').map_or("", |i| &stat[i + 2..]);
    let f: Vec<&str> = after.split_whitespace().collect();
    // Fields 14 and 15 of stat (utime, stime) are 12 and 13 after the command name.
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
    (ticks(11) + ticks(12)) / hz
}

fn wait_nodes(prefix: &str, n: usize) {
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(5) {
        if taxel_runtime::ipc::count_nodes(prefix).map_or(0, |c| c.0) >= n {
            std::thread::sleep(Duration::from_millis(200));
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn output(mut c: Child) -> String {
    let mut out = String::new();
    if let Some(mut so) = c.stdout.take() {
        let _ = so.read_to_string(&mut out);
    }
    let _ = c.wait();
    out
}

/// A case's result from the receiving probe's JSON and the CPU of each waiting process (% of
/// a core).
fn from_json(case: &str, json: &str, cpu: &[f64]) -> CaseResult {
    CaseResult {
        case: case.to_string(),
        received: field(json, "received"),
        dropped: field(json, "dropped"),
        p50: field(json, "p50_us"),
        p90: field(json, "p90_us"),
        p99: field(json, "p99_us"),
        p999: field(json, "p999_us"),
        max: field(json, "max_us"),
        cpu_pct: cpu.iter().sum(),
        cpu_pct_max_process: cpu.iter().copied().fold(0.0, f64::max),
        ..CaseResult::default()
    }
}

/// A latency probe on sensor `b`'s `stream`, printing its JSON after `secs`.
fn probe(prefix: &str, stream: &str, wake: &str, secs: f64) -> anyhow::Result<Child> {
    taxel(
        &[
            s("latency"),
            s("--sensor"),
            s("b"),
            s("--stream"),
            s(stream),
            s("--wake"),
            s(wake),
            s("--seconds"),
            secs.to_string(),
            s("--json"),
        ],
        prefix,
    )
}

/// The simulated sensor `b` at `rate` Hz for a second longer than the measurement.
fn publisher(prefix: &str, secs: f64, rate: f64) -> anyhow::Result<Child> {
    taxel(
        &[
            s("publisher"),
            s("--sensor"),
            s("b"),
            s("--seconds"),
            (secs + 1.0).to_string(),
            s("sim"),
            s("--rate-hz"),
            rate.to_string(),
        ],
        prefix,
    )
}

/// The JSON line of a probe's output.
fn json_line(out: &str) -> String {
    out.lines()
        .find(|l| l.starts_with('{'))
        .unwrap_or("{}")
        .to_string()
}

/// Raw iceoryx2, one hop: the publisher's RawFrames into a latency probe.
fn iox2(case: &str, wake: &str, secs: f64, rate: f64, n: usize) -> anyhow::Result<CaseResult> {
    let prefix = format!("txbench{}_{n}_", std::process::id());
    let probe = probe(&prefix, "raw", wake, secs)?;
    wait_nodes(&prefix, 1);
    let pid = probe.id();
    let c0 = cpu_of(pid);
    let mut publisher = publisher(&prefix, secs, rate)?;
    let out = output(probe);
    let json = json_line(&out);
    let cpu = (field(&json, "cpu_s") - c0).max(0.0) / secs * 100.0;
    let _ = publisher.wait();
    let _ = taxel_runtime::ipc::release_prefix(&prefix);
    Ok(from_json(case, &json, &[cpu]))
}

/// Arguments of a `bench-peer` process.
fn peer_args(
    transport: &str,
    role: &str,
    addr: &str,
    to: Option<&str>,
    rate: f64,
    secs: f64,
) -> Vec<String> {
    let mut v = vec![
        s("bench-peer"),
        s("--transport"),
        s(transport),
        s("--role"),
        s(role),
        s("--addr"),
        s(addr),
        s("--rate-hz"),
        rate.to_string(),
        s("--seconds"),
        secs.to_string(),
    ];
    if let Some(t) = to {
        v.extend([s("--to"), s(t)]);
    }
    v
}

/// Waits until a listening peer prints "ready" (or exits).
fn wait_ready(c: &mut Child) {
    let mut ready = [0u8; 6];
    if let Some(so) = c.stdout.as_mut() {
        let _ = so.read_exact(&mut ready);
    }
}

/// Unix socket or TCP loopback, one hop.
fn socket(
    case: &str,
    transport: &str,
    role: &str,
    secs: f64,
    rate: f64,
    n: usize,
) -> anyhow::Result<CaseResult> {
    let addr = if transport == "uds" {
        std::env::temp_dir()
            .join(format!("taxel-bench-{}-{n}.sock", std::process::id()))
            .display()
            .to_string()
    } else {
        (41000 + (std::process::id() % 1000) as u16 * 10 + n as u16).to_string()
    };
    let mut recv = taxel(
        &peer_args(transport, role, &addr, None, rate, secs),
        "unused_",
    )?;
    wait_ready(&mut recv);
    let mut send = taxel(
        &peer_args(transport, "send", &addr, None, rate, secs),
        "unused_",
    )?;
    let out = output(recv);
    let _ = send.kill();
    let _ = send.wait();
    let json = json_line(&out);
    let cpu = field(&json, "cpu_s") / secs * 100.0;
    if transport == "uds" {
        let _ = std::fs::remove_file(&addr);
    }
    Ok(from_json(case, &json, &[cpu]))
}

/// The machine's timer floor: how late `clock_nanosleep` to an absolute deadline (timer slack
/// 1 ns) returns, at `rate` Hz, in this process. Any waiter that sleeps, the adaptive wake-up
/// included, inherits this tail; the case's "latency" is the overshoot.
fn timer_overshoot(case: &str, secs: f64, rate: f64) -> anyhow::Result<CaseResult> {
    use taxel_consumers::age::AgeHistogram;
    taxel_runtime::clock::fine_timer_slack();
    let mut h = AgeHistogram::new();
    let period = (1e9 / rate) as u64;
    let n = (secs * rate) as u64;
    let cpu0 = taxel_runtime::process::cpu_seconds();
    let mut due = taxel_runtime::now_ns() + period;
    for _ in 0..n {
        taxel_runtime::clock::sleep_until_ns(due);
        h.record_ns(taxel_runtime::now_ns().saturating_sub(due));
        due += period;
    }
    let cpu = (taxel_runtime::process::cpu_seconds() - cpu0) / secs * 100.0;
    let json = taxel_consumers::age::json_report(n, 0, &h, &[]);
    Ok(from_json(case, &json, &[cpu]))
}

/// Unix sockets, two hops: sender -> relay (blocking) -> receiver (blocking), the classic-IPC
/// shape of our two-hop force path.
fn uds_two_hops(case: &str, secs: f64, rate: f64, n: usize) -> anyhow::Result<CaseResult> {
    let sock = |k: usize| {
        std::env::temp_dir()
            .join(format!("taxel-bench-{}-{n}-{k}.sock", std::process::id()))
            .display()
            .to_string()
    };
    let (a, b) = (sock(0), sock(1));
    let mut recv = taxel(
        &peer_args("uds", "recv-block", &b, None, rate, secs),
        "unused_",
    )?;
    wait_ready(&mut recv);
    let relay_args = peer_args("uds", "relay-block", &a, Some(&b), rate, secs);
    let mut relay = taxel(&relay_args, "unused_")?;
    wait_ready(&mut relay);
    let mut send = taxel(&peer_args("uds", "send", &a, None, rate, secs), "unused_")?;
    let out = output(recv);
    let _ = send.kill();
    let _ = send.wait();
    let relay_out = output(relay);
    let json = json_line(&out);
    let cpu = [
        field(&json_line(&relay_out), "cpu_s") / secs * 100.0,
        field(&json, "cpu_s") / secs * 100.0,
    ];
    for f in [&a, &b] {
        let _ = std::fs::remove_file(f);
    }
    Ok(from_json(case, &json, &cpu))
}

/// Our force path: publisher -> calibrator -> consumer, both waiting in `wake` mode.
fn force_path(
    case: &str,
    wake: &str,
    secs: f64,
    rate: f64,
    n: usize,
    cal: &str,
) -> anyhow::Result<CaseResult> {
    force_path_reloading(case, wake, secs, rate, n, cal, 0)
}

/// The force path while the calibration file is replaced (atomic rename, new version)
/// `reloads` times, evenly over the measurement.
fn force_path_reloading(
    case: &str,
    wake: &str,
    secs: f64,
    rate: f64,
    n: usize,
    cal: &str,
    reloads: usize,
) -> anyhow::Result<CaseResult> {
    let prefix = format!("txbench{}_{n}_", std::process::id());
    let mut calibrator = taxel(
        &[
            s("calibrator"),
            s("run"),
            s("--sensor"),
            s("b"),
            s("--calibration"),
            s(cal),
            s("--wake"),
            s(wake),
        ],
        &prefix,
    )?;
    wait_nodes(&prefix, 1);
    let probe = probe(&prefix, "force", wake, secs)?;
    wait_nodes(&prefix, 2);
    let cal_pid = calibrator.id();
    let c0 = cpu_of(cal_pid);
    let mut publisher = publisher(&prefix, secs, rate)?;
    let reloader = (reloads > 0).then(|| {
        let path = PathBuf::from(cal);
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        std::thread::spawn(move || {
            let every = Duration::from_secs_f64(secs / (reloads as f64 + 1.0));
            for v in 0..reloads {
                std::thread::sleep(every);
                let tmp = path.with_extension("tmp");
                let body = text.replacen("version = 1", &format!("version = {}", v + 2), 1);
                if std::fs::write(&tmp, body).is_ok() {
                    let _ = std::fs::rename(&tmp, &path);
                }
            }
        })
    });
    let out = output(probe);
    if let Some(r) = reloader {
        let _ = r.join();
    }
    let cal_cpu = (cpu_of(cal_pid) - c0).max(0.0);
    let _ = publisher.wait();
    // SAFETY: kill(2) on our own child.
    unsafe {
        libc::kill(cal_pid as i32, libc::SIGINT);
    }
    let _ = calibrator.wait();
    let _ = taxel_runtime::ipc::release_prefix(&prefix);
    let json = json_line(&out);
    let cpu = [cal_cpu / secs * 100.0, field(&json, "cpu_s") / secs * 100.0];
    Ok(from_json(case, &json, &cpu))
}

pub fn main(a: Args) -> ExitCode {
    exit_code("taxel bench", run(a))
}

/// `taxel bench-peer`: one socket peer of a bench case.
pub fn peer_main(a: peers::PeerArgs) -> ExitCode {
    exit_code("taxel bench-peer", peers::run(&a).runtime_err())
}

fn run(a: Args) -> Result<(), Failure> {
    let bad = |m: &str| Err(Failure::config(anyhow::anyhow!("{m}")));
    if !(a.rate_hz.is_finite() && a.rate_hz > 0.0 && a.rate_hz <= 100_000.0) {
        return bad("--rate-hz must be in (0, 100000]");
    }
    let secs = a.seconds.unwrap_or(if a.quick { 3.0 } else { 10.0 });
    if !(secs.is_finite() && (0.2..=3600.0).contains(&secs)) {
        return bad("--seconds must be 0.2..=3600");
    }
    let (out, cal_s, dynamic_s) = prepare_out(&a)?;
    let rate = a.rate_hz;
    let mut cases = Vec::new();
    let steps = cases::cases_table(secs, rate, &cal_s, &dynamic_s);
    if let Some(bad) = a
        .cases
        .iter()
        .find(|c| *c != python::CASE && !steps.iter().any(|(name, _)| name == c))
    {
        let known: Vec<&str> = steps
            .iter()
            .map(|(name, _)| *name)
            .chain([python::CASE])
            .collect();
        return Err(Failure::config(anyhow::anyhow!(
            "--cases: unknown case {bad:?} (known: {})",
            known.join(", ")
        )));
    }
    for (i, (name, f)) in steps.iter().enumerate() {
        if !a.cases.is_empty() && !a.cases.iter().any(|c| c == name) {
            continue;
        }
        if a.cases.is_empty() && ON_REQUEST.contains(name) {
            eprintln!("taxel bench: {name} skipped (it runs when named: --cases {name})");
            continue;
        }
        eprintln!("taxel bench: {name} ({secs} s at {rate} Hz) ...");
        let mut c = f(i).runtime_err()?;
        if c.rate_hz == 0.0 {
            c.rate_hz = rate;
        }
        cases.push(c);
    }
    run_python(&a, secs, rate, steps.len(), &cal_s, &mut cases)?;
    let (md, json) = report::write(&out, rate, secs, &cases)?;
    if a.json {
        println!("{json}");
    } else {
        println!("{md}\nwritten to {}", out.display());
    }
    Ok(())
}

type Case = Box<dyn Fn(usize) -> anyhow::Result<CaseResult>>;

/// Cases a run of every case leaves out (said on stderr): they run only when named in
/// `--cases`. The per-process skin starts 193 processes, the search for the largest skin
/// runs up to nine skins of up to 2 048 sensors, minutes on a small machine, and the
/// real-time skin needs the right to real-time priority (root or CAP_SYS_NICE).
const ON_REQUEST: [&str; 3] = [
    "skin_64_sensors_per_process",
    "skin_max_sensors",
    "skin_64_sensors_realtime",
];

/// The output directory (named, or a fresh one under the temp dir, said on stderr) with the
/// two calibrations the force-path cases serve: the shipped one, and the same with every
/// dynamic term on.
fn prepare_out(a: &Args) -> Result<(PathBuf, String, String), Failure> {
    let out = match &a.out {
        Some(d) => d.clone(),
        None => std::env::temp_dir().join(format!("taxel-bench-{}", std::process::id())),
    };
    std::fs::create_dir_all(&out)
        .map_err(|e| anyhow::anyhow!("--out {}: {e}", out.display()))
        .config_err()?;
    if a.out.is_none() {
        eprintln!(
            "taxel bench: writing to {} (--out DIR to choose)",
            out.display()
        );
    }
    let cal = out.join("bench-calibration.toml");
    std::fs::write(&cal, include_str!("../../../calibrations/sim-default.toml"))
        .map_err(|e| anyhow::anyhow!("{}: {e}", cal.display()))
        .config_err()?;
    // The same calibration with every dynamic term on both blocks (bounded force creep of five
    // time constants, six plays): the force path with the terms, beside the static one.
    let dynamic = out.join("bench-calibration-dynamic.toml");
    std::fs::write(
        &dynamic,
        with_dynamic_terms(include_str!("../../../calibrations/sim-default.toml")),
    )
    .map_err(|e| anyhow::anyhow!("{}: {e}", dynamic.display()))
    .config_err()?;
    Ok((
        out,
        cal.display().to_string(),
        dynamic.display().to_string(),
    ))
}

/// The Python case, when asked for or (on a run of every case) when that Python can import
/// taxel; said on stderr when skipped.
fn run_python(
    a: &Args,
    secs: f64,
    rate: f64,
    index: usize,
    cal_s: &str,
    cases: &mut Vec<CaseResult>,
) -> Result<(), Failure> {
    let want_python = a.cases.iter().any(|c| c == python::CASE);
    if a.cases.is_empty() || want_python {
        match python::unavailable(&a.python) {
            Some(why) if !want_python => {
                eprintln!("taxel bench: {} skipped: {why}", python::CASE)
            }
            _ => {
                eprintln!("taxel bench: {} ({secs} s at {rate} Hz) ...", python::CASE);
                let found = python::case(&a.python, secs, rate, index, cal_s);
                for mut c in found.runtime_err()? {
                    c.rate_hz = rate;
                    cases.push(c);
                }
            }
        }
    }
    Ok(())
}

/// `cal` with creep and hysteresis terms after every block's range line.
fn with_dynamic_terms(cal: &str) -> String {
    let terms = "creep = { tau_s = [0.5, 2, 8, 32, 128], share = [0.02, 0.04, 0.04, 0.03, 0.02], domain = \"force\", bounded = true }\nhysteresis = { threshold_n = [0.05, 0.15, 0.4, 0.8, 1.5, 2.5], weight = [0.05, 0.05, 0.1, 0.1, 0.05, 0.05] }\n";
    let mut out = String::new();
    for line in cal.lines() {
        out.push_str(line);
        out.push('\n');
        if line.starts_with("range = ") {
            out.push_str(terms);
        }
    }
    out
}
