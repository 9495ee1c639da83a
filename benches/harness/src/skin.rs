//! The many-sensor cases: a glove and a skin of sensors at 1 kHz each, in the per-sensor layout
//! (a publisher and a calibrator, or a publisher, an estimator and a calibrator, per sensor)
//! and in the shared layout (one process per role for every sensor), measured by one latency
//! probe on every force stream. The skin cases also report each role's CPU and resident memory
//! (VmRSS, sampled while they run: after a warm-up and at the end), and `skin_max_sensors`
//! searches the largest sensor count the shared layout serves at 1 kHz with zero loss.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use taxel_runtime::sensors::MAX_SENSORS;

use crate::{cpu_of, field, from_json, json_line, s, taxel, wait_nodes, CaseResult, RoleStat};

/// `sensors` sensors at `rate` Hz each: publishers, calibrators (event) and one probe on all
/// their force streams; reports the summed samples and drops. (The original per-sensor skin
/// and glove cases, unchanged.)
pub(crate) fn many(
    case: &str,
    sensors: usize,
    secs: f64,
    rate: f64,
    n: usize,
    cal: &str,
) -> anyhow::Result<CaseResult> {
    let prefix = format!("txbench{}_{n}_", std::process::id());
    let names: Vec<String> = (0..sensors).map(|i| format!("b{i}")).collect();
    let mut cals = Vec::new();
    for name in &names {
        cals.push(taxel(
            &[
                s("calibrator"),
                s("run"),
                s("--sensor"),
                name.clone(),
                s("--calibration"),
                s(cal),
            ],
            &prefix,
        )?);
    }
    wait_nodes(&prefix, sensors);
    let probe = taxel(
        &[
            s("latency"),
            s("--sensor"),
            names.join(","),
            s("--seconds"),
            secs.to_string(),
            s("--json"),
        ],
        &prefix,
    )?;
    wait_nodes(&prefix, sensors + 1);
    let c0: Vec<f64> = cals.iter().map(|c| cpu_of(c.id())).collect();
    let mut pubs = Vec::new();
    for name in &names {
        pubs.push(taxel(
            &[
                s("publisher"),
                s("--sensor"),
                name.clone(),
                s("--seconds"),
                (secs + 1.0).to_string(),
                s("sim"),
                s("--rate-hz"),
                rate.to_string(),
            ],
            &prefix,
        )?);
    }
    let out = crate::output(probe);
    let mut cpu: Vec<f64> = cals
        .iter()
        .zip(&c0)
        .map(|(c, c0)| (cpu_of(c.id()) - c0).max(0.0) / secs * 100.0)
        .collect();
    for p in pubs.iter_mut() {
        let _ = p.wait();
    }
    for c in cals.iter_mut() {
        interrupt(c);
    }
    let _ = taxel_runtime::ipc::release_prefix(&prefix);
    let json = json_line(&out);
    cpu.push(field(&json, "cpu_s") / secs * 100.0);
    Ok(from_json(case, &json, &cpu))
}

/// SIGINT to a child and wait for it.
fn interrupt(c: &mut Child) {
    // SAFETY: kill(2) on our own child, not yet reaped.
    unsafe {
        libc::kill(c.id() as i32, libc::SIGINT);
    }
    let _ = c.wait();
}

/// The shared layout's wake-up group.
const WAKE_GROUP: &str = "skin";

/// What the probe skips before it measures (s).
const SKIP_S: f64 = 1.0;

/// Resident memory (VmRSS) and private memory (RssAnon) of a process in KiB, from /proc (0
/// when it is gone).
fn rss_kib(pid: u32) -> (u64, u64) {
    let st = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let kib = |key: &str| {
        st.lines()
            .find_map(|l| l.strip_prefix(key))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
            .unwrap_or(0)
    };
    (kib("VmRSS:"), kib("RssAnon:"))
}

/// The real-time priority (SCHED_FIFO, 1-99) of `skin_64_sensors_realtime`'s processes.
pub(crate) const REALTIME: u8 = 20;
/// How far above the case's priority the platform sleeper runs, so nothing of the case delays
/// it and its lateness is the platform's.
const PLATFORM_ABOVE: u8 = 10;

/// A skin case: how many sensors, in which layout.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Skin {
    pub sensors: usize,
    /// One process per role for every sensor (else a publisher, estimator and calibrator each).
    pub shared: bool,
    pub secs: f64,
    pub rate: f64,
    /// Real-time priority of every process of the case, the probe's included (`--realtime`).
    pub realtime: Option<u8>,
}

/// One measured process.
struct Proc {
    role: &'static str,
    child: Child,
    cpu0: f64,
    /// (VmRSS, RssAnon) in KiB.
    rss_warm: (u64, u64),
    rss_end: (u64, u64),
}

impl Proc {
    fn new(role: &'static str, child: Child) -> Proc {
        Proc {
            role,
            child,
            cpu0: 0.0,
            rss_warm: (0, 0),
            rss_end: (0, 0),
        }
    }
}

/// `role [run] --sensor LIST [--wake-group G] ARGS...` (one process per sensor, or one for all,
/// waking by group as `taxel up` starts a shared layout).
fn role_args(role: &str, group: &str, args: &[String]) -> Vec<String> {
    let mut a = vec![s(role)];
    if role != "publisher" {
        a.push(s("run"));
    }
    a.extend([s("--sensor"), s(group)]);
    if group.contains(',') {
        a.extend([s("--wake-group"), s(WAKE_GROUP)]);
    }
    a.extend_from_slice(args);
    a
}

fn start_role(
    procs: &mut Vec<Proc>,
    role: &'static str,
    groups: &[String],
    args: &[String],
    prefix: &str,
) -> anyhow::Result<()> {
    for g in groups {
        procs.push(Proc::new(role, taxel(&role_args(role, g, args), prefix)?));
    }
    Ok(())
}

/// Starts the publishers and waits (at most `limit`) until every one has opened its services
/// and sends: its "publisher ready" line on stderr (read to the end by a thread, so the pipe
/// never fills).
fn start_publishers(
    procs: &mut Vec<Proc>,
    groups: &[String],
    args: &[String],
    prefix: &str,
    limit: Duration,
) -> anyhow::Result<()> {
    let (tx, rx) = std::sync::mpsc::channel();
    for g in groups {
        let mut child = Command::new(std::env::current_exe()?)
            .args(role_args("publisher", g, args))
            .env("TAXEL_PREFIX", prefix)
            .env("RUST_LOG", "warn,taxel_publisher=info")
            .env("NO_COLOR", "1")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()?;
        let ready = if g.contains(',') {
            "publisher ready for every sensor"
        } else {
            "publisher ready on"
        };
        if let Some(err) = child.stderr.take() {
            let tx = tx.clone();
            std::thread::spawn(move || {
                for l in BufReader::new(err).lines().map_while(Result::ok) {
                    if l.contains(ready) {
                        let _ = tx.send(());
                    }
                }
            });
        }
        procs.push(Proc::new("publisher", child));
    }
    let t0 = Instant::now();
    for _ in groups {
        let left = limit.saturating_sub(t0.elapsed());
        rx.recv_timeout(left)
            .map_err(|_| anyhow::anyhow!("publishers not ready within {limit:?}"))?;
    }
    Ok(())
}

/// Runs a skin of `k.sensors` simulated 4 x 4 sensors at `k.rate` Hz: publishers, estimators
/// (configured curvature: the per-frame no-load detection, no model) and calibrators in the
/// layout asked for, then one probe on every force stream for `k.secs` once every publisher is
/// ready and the probe itself has joined (it skips its first second).
/// CPU is counted over the probe's window, resident memory sampled every `secs / 20` (at
/// least every 0.5 s): after a warm-up of a fifth of the window and at its end.
pub(crate) fn skin(case: &str, k: Skin, n: usize, cal: &str) -> anyhow::Result<CaseResult> {
    let prefix = format!("txbench{}_{n}_", std::process::id());
    let names: Vec<String> = (0..k.sensors).map(|i| format!("b{i}")).collect();
    let groups: Vec<String> = if k.shared {
        vec![names.join(",")]
    } else {
        names.clone()
    };
    let mut procs: Vec<Proc> = Vec::new();
    let r = run_skin(case, k, &prefix, &names, &groups, cal, &mut procs);
    // Sources first, then the rest; whatever happened above.
    for p in procs.iter_mut().filter(|p| p.role == "publisher") {
        interrupt(&mut p.child);
    }
    for p in procs.iter_mut().filter(|p| p.role != "publisher") {
        interrupt(&mut p.child);
    }
    let _ = taxel_runtime::ipc::clean_dead_nodes(&prefix);
    let _ = taxel_runtime::ipc::release_prefix(&prefix);
    r
}

fn run_skin(
    case: &str,
    k: Skin,
    prefix: &str,
    names: &[String],
    groups: &[String],
    cal: &str,
    procs: &mut Vec<Proc>,
) -> anyhow::Result<CaseResult> {
    let consumers = 2 * groups.len();
    let patience =
        Duration::from_secs_f64(10.0 + 0.2 * (3 * groups.len()) as f64 + 0.1 * k.sensors as f64);
    let rt: Vec<String> = k
        .realtime
        .map(|r| vec![s("--realtime"), r.to_string()])
        .unwrap_or_default();
    let with_rt = |args: &[String]| [args, &rt].concat();
    start_role(
        procs,
        "calibrator",
        groups,
        &with_rt(&[s("--calibration"), s(cal)]),
        prefix,
    )?;
    start_role(
        procs,
        "estimator",
        groups,
        &with_rt(&[s("--curvature-m1"), s("40")]),
        prefix,
    )?;
    wait_nodes_for(prefix, consumers, patience);
    // The publisher's own options come before its source's subcommand.
    let sim = [
        rt.clone(),
        vec![s("sim"), s("--rate-hz"), k.rate.to_string()],
    ]
    .concat();
    start_publishers(procs, groups, &sim, prefix, patience)?;
    // The probe measures the streams once they flow, and skips its own joining (the
    // calibrators connect it to their force streams while they send).
    std::thread::sleep(Duration::from_millis(500));
    let mut args = vec![
        s("latency"),
        s("--sensor"),
        names.join(","),
        s("--seconds"),
        k.secs.to_string(),
        s("--skip-s"),
        SKIP_S.to_string(),
        s("--json"),
    ];
    if k.shared {
        // A consumer of the whole skin, as the shared calibrator's group lets it wait.
        args.extend([s("--wake-group"), s(WAKE_GROUP)]);
    }
    args.extend(rt.iter().cloned());
    let mut probe = taxel(&args, prefix)?;
    wait_nodes_for(prefix, consumers + groups.len() + 1, patience);
    std::thread::sleep(Duration::from_secs_f64(SKIP_S));
    let t0 = Instant::now();
    for p in procs.iter_mut() {
        p.cpu0 = cpu_of(p.child.id());
    }
    let probe_cpu0 = cpu_of(probe.id());
    // At real-time priority, the platform's own wake-up lateness over the same window, from a
    // sleeper above the case's priority (crate::platform).
    let sleeper = k
        .realtime
        .map(|r| crate::platform::Sleeper::start(r.saturating_add(PLATFORM_ABOVE).min(99)));
    let every = Duration::from_secs_f64((k.secs / 20.0).max(0.5));
    let warm = Duration::from_secs_f64(k.secs * 0.2);
    let mut warm_taken = false;
    let mut died = None;
    loop {
        if probe.try_wait()?.is_some() {
            break;
        }
        let rss: Vec<(u64, u64)> = procs.iter().map(|p| rss_kib(p.child.id())).collect();
        for (p, r) in procs.iter_mut().zip(&rss) {
            if !warm_taken && t0.elapsed() >= warm {
                p.rss_warm = *r;
            }
            if r.0 > 0 {
                p.rss_end = *r;
            }
        }
        warm_taken |= t0.elapsed() >= warm;
        for p in procs.iter_mut() {
            if died.is_none() && matches!(p.child.try_wait(), Ok(Some(_))) {
                died = Some(p.role);
            }
        }
        std::thread::sleep(every.min(Duration::from_millis(500)));
    }
    let wall = t0.elapsed().as_secs_f64().max(1e-3);
    let platform = sleeper.map(crate::platform::Sleeper::finish);
    let cpu: Vec<f64> = procs
        .iter()
        .map(|p| (cpu_of(p.child.id()) - p.cpu0).max(0.0) / wall * 100.0)
        .collect();
    let out = crate::output(probe);
    let json = json_line(&out);
    let probe_cpu = (field(&json, "cpu_s") - probe_cpu0).max(0.0) / wall * 100.0;
    if let Some(role) = died {
        anyhow::bail!("a {role} process exited during the measurement");
    }
    let waiting: Vec<f64> = procs
        .iter()
        .zip(&cpu)
        .filter(|(p, _)| p.role != "publisher")
        .map(|(_, c)| *c)
        .chain([probe_cpu])
        .collect();
    let mut res = from_json(case, &json, &waiting);
    res.sensors = k.sensors;
    res.expected = k.sensors as f64 * k.rate * field(&json, "seconds");
    res.platform = platform;
    for role in ["publisher", "estimator", "calibrator"] {
        let mb = |of: &[(&Proc, f64)], f: fn(&Proc) -> u64| {
            of.iter().map(|(p, _)| f(p)).sum::<u64>() as f64 / 1024.0
        };
        let of: Vec<(&Proc, f64)> = procs
            .iter()
            .zip(&cpu)
            .filter(|(p, _)| p.role == role)
            .map(|(p, c)| (p, *c))
            .collect();
        res.roles.push(RoleStat {
            role: role.to_string(),
            processes: of.len(),
            cpu_pct: of.iter().map(|(_, c)| c).sum(),
            cpu_pct_max_process: of.iter().map(|(_, c)| *c).fold(0.0, f64::max),
            rss_mb: mb(&of, |p| p.rss_end.0),
            rss_mb_max_process: of.iter().map(|(p, _)| p.rss_end.0).max().unwrap_or(0) as f64
                / 1024.0,
            rss_warm_mb: mb(&of, |p| p.rss_warm.0),
            private_warm_mb: mb(&of, |p| p.rss_warm.1),
            private_mb: mb(&of, |p| p.rss_end.1),
        });
    }
    res.roles.push(RoleStat {
        role: "latency probe".to_string(),
        processes: 1,
        cpu_pct: probe_cpu,
        cpu_pct_max_process: probe_cpu,
        ..RoleStat::default()
    });
    Ok(res)
}

/// Like `wait_nodes`, with a deadline for many processes starting on a loaded machine.
fn wait_nodes_for(prefix: &str, n: usize, limit: Duration) {
    let t0 = Instant::now();
    while t0.elapsed() < limit {
        if taxel_runtime::ipc::count_nodes(prefix).map_or(0, |c| c.0) >= n {
            std::thread::sleep(Duration::from_millis(200));
            return;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    wait_nodes(prefix, n);
}

/// Zero loss: nothing dropped and at least 99 % of the frames the window should hold (a
/// sensor whose frames stop arriving is a loss too).
fn zero_loss(r: &CaseResult) -> bool {
    r.dropped == 0.0 && r.received >= 0.99 * r.expected
}

/// `skin_max_sensors`: the shared layout at 64 sensors, doubling while nothing is lost (up to
/// the most one process serves), then bisecting between the last count without loss and the
/// first with (to within 1/8 of it), at most 9 runs of up to 5 s; the largest count without
/// loss.
pub(crate) fn max_sensors(secs: f64, rate: f64, n: usize, cal: &str) -> anyhow::Result<CaseResult> {
    let secs = secs.min(5.0);
    let mut trials: Vec<(usize, bool, String)> = Vec::new();
    let mut run = |sensors: usize, k: usize| -> (Option<CaseResult>, bool) {
        let spec = Skin {
            sensors,
            shared: true,
            secs,
            rate,
            realtime: None,
        };
        match skin("skin_max_sensors", spec, 200 + n * 20 + k, cal) {
            Ok(r) => {
                let ok = zero_loss(&r);
                let what = format!(
                    "{} received of {:.0}, {} dropped, p99 {:.0} us",
                    r.received, r.expected, r.dropped, r.p99
                );
                eprintln!(
                    "  {sensors} sensors: {}: {what}",
                    if ok { "no loss" } else { "LOSS" }
                );
                trials.push((sensors, ok, what));
                (Some(r), ok)
            }
            Err(e) => {
                eprintln!("  {sensors} sensors: failed: {e:#}");
                trials.push((sensors, false, format!("failed: {e:#}")));
                (None, false)
            }
        }
    };
    let (mut good, mut bad): (Option<(usize, CaseResult)>, Option<usize>) = (None, None);
    let mut count = 64;
    let mut k = 0;
    // Doubling while nothing is lost (halving when 64 already loses), to a bracket.
    while k < 9 {
        let (r, ok) = run(count, k);
        k += 1;
        match (ok, r) {
            (true, Some(r)) => {
                good = Some((count, r));
                if bad.is_some() || count * 2 > MAX_SENSORS {
                    break;
                }
                count *= 2;
            }
            _ => {
                bad = Some(count);
                if good.is_some() || count <= 1 {
                    break;
                }
                count /= 2;
            }
        }
    }
    // Bisecting.
    while k < 9 {
        let (Some(g), Some(b)) = (good.as_ref().map(|(g, _)| *g), bad) else {
            break;
        };
        if b - g <= (g / 8).max(1) {
            break;
        }
        let mid = (g + b) / 2;
        let (r, ok) = run(mid, k);
        k += 1;
        match (ok, r) {
            (true, Some(r)) => good = Some((mid, r)),
            _ => bad = Some(mid),
        }
    }
    let Some((_, mut best)) = good else {
        anyhow::bail!("no sensor count served at {rate} Hz without loss: {trials:?}");
    };
    best.trials = trials;
    Ok(best)
}
