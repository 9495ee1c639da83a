//! `taxel soak`: the simulated glove under the supervisor with a random process SIGKILLed every
//! `--kill-every` seconds and random valid calibration edits, while an in-process probe watches
//! every raw and force stream. Reports frames published, delivered, flagged and lost (lost
//! outside the killed calibrator's own downtime must be zero), restarts and peak memory per
//! process.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use taxel_msgs::{force_flags, raw_flags, ForceSample, RawFrame, Stream};
use taxel_runtime::ipc::{self, Ipc};
use taxel_runtime::process::{exit_code, init_tracing, Failure, ResultExt};
use taxel_runtime::{now_ns, Shutdown};

use crate::demo::{
    check_glove, demo_pipeline, out_dir, write_file, CURVATURE_MODEL, SIM_CALIBRATION,
};
use crate::supervise::{Outcome, Supervisor};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Length of the run (s).
    #[arg(long, default_value_t = 600.0)]
    pub seconds: f64,
    /// SIGKILL a random process this often (s).
    #[arg(long, default_value_t = 30.0)]
    pub kill_every: f64,
    /// Rewrite the calibration file (valid, random coefficients and a new version) about this
    /// often (s; the interval is randomized by +-50 %).
    #[arg(long, default_value_t = 10.0)]
    pub edit_every: f64,
    /// Number of sensors; 5 is the glove.
    #[arg(long, default_value_t = 5)]
    pub sensors: usize,
    /// Frame rate of each sensor (Hz).
    #[arg(long, default_value_t = 1000.0)]
    pub rate_hz: f64,
    /// Seed of the kill and edit schedule.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// iceoryx2 service prefix.
    #[arg(long, env = "TAXEL_PREFIX", default_value = "taxel_soak_")]
    pub prefix: String,
    /// Directory for the calibration and the recording (default: a fresh temp dir).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the result as one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Log filter for the child processes.
    #[arg(long, default_value = "warn")]
    pub log: String,
}

/// Small seeded generator (xorshift64*): the kill schedule is reproducible.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// What the probe saw of one sensor.
#[derive(Default)]
struct SensorLog {
    raw_seen: u64,
    raw_gap_flags: u64,
    /// Raw frames the probe itself missed (seq jumps within one publisher incarnation).
    raw_probe_missed: u64,
    last_raw_seq: Option<u64>,
    /// Force samples seen.
    delivered: u64,
    /// (seq, t_capture_ns) of the last force sample seen.
    last_force: Option<(u64, u64)>,
    /// Frames of the force stream's publisher incarnations, first to last seq seen.
    published: u64,
    /// Jumps in the force seq that the calibrator flagged GAP_BEFORE (it never produced those
    /// samples): (t_capture_ns of the sample after the jump, frames missing).
    flagged_gaps: Vec<(u64, u64)>,
    /// Jumps without the flag: the calibrator sent them, the probe did not read them in time.
    force_probe_missed: u64,
    flagged: u64,
    flag_counts: BTreeMap<&'static str, u64>,
}

const FLAGS: [(u32, &str); 4] = [
    (force_flags::GAP_BEFORE, "gap_before"),
    (force_flags::CURVATURE_STALE, "curvature_stale"),
    (force_flags::CURVATURE_DEFAULTED, "curvature_defaulted"),
    (force_flags::NO_BASELINE, "no_baseline"),
];

fn probe(
    prefix: &str,
    sensors: &[String],
    stop: &AtomicBool,
    ready: &AtomicBool,
) -> anyhow::Result<Vec<SensorLog>> {
    let ipc = Ipc::open(prefix, "soak-probe")?;
    let mut subs = Vec::new();
    for s in sensors {
        subs.push((
            ipc.subscriber::<RawFrame>(s, Stream::Raw)?,
            ipc.subscriber::<ForceSample>(s, Stream::Force)?,
        ));
    }
    let mut logs: Vec<SensorLog> = sensors.iter().map(|_| SensorLog::default()).collect();
    ready.store(true, Ordering::SeqCst);
    while !stop.load(Ordering::SeqCst) {
        for ((raw, force), log) in subs.iter().zip(logs.iter_mut()) {
            raw.poll_each(|f| {
                log.raw_seen += 1;
                if f.flags & raw_flags::GAP_BEFORE != 0 {
                    log.raw_gap_flags += 1;
                }
                if let Some(l) = log.last_raw_seq {
                    if f.seq > l + 1 {
                        log.raw_probe_missed += f.seq - l - 1;
                    }
                }
                log.last_raw_seq = Some(f.seq);
                Ok(())
            })?;
            force.poll_each(|f| {
                log.delivered += 1;
                match log.last_force {
                    // Same publisher incarnation (a restarted one counts from 0 again).
                    Some((l, _)) if f.seq > l => {
                        log.published += f.seq - l;
                        let missing = f.seq - l - 1;
                        if missing > 0 {
                            if f.flags & force_flags::GAP_BEFORE != 0 {
                                log.flagged_gaps.push((f.t_capture_ns, missing));
                            } else {
                                log.force_probe_missed += missing;
                            }
                        }
                    }
                    _ => log.published += 1,
                }
                log.last_force = Some((f.seq, f.t_capture_ns));
                if f.flags & FLAGS.iter().fold(0, |a, (b, _)| a | b) != 0 {
                    log.flagged += 1;
                    for (bit, name) in FLAGS {
                        if f.flags & bit != 0 {
                            *log.flag_counts.entry(name).or_default() += 1;
                        }
                    }
                }
                Ok(())
            })?;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    Ok(logs)
}

/// Rewrites the calibration with every coefficient scaled by a random factor in [0.98, 1.02]
/// and a new version, atomically (write + rename, as editors do).
fn edit_calibration(path: &Path, version: u32, rng: &mut Rng) -> anyhow::Result<()> {
    let mut out = String::new();
    for line in SIM_CALIBRATION.lines() {
        if line.starts_with("version = ") {
            out.push_str(&format!("version = {version}\n"));
            continue;
        }
        let mut l = line.to_string();
        if let Some(i) = l.find("coef = ") {
            let start = i + "coef = ".len();
            let end = l[start..].find(' ').map_or(l.len(), |e| start + e);
            if let Ok(v) = l[start..end].parse::<f64>() {
                let scaled = v * (0.98 + 0.04 * rng.unit());
                l.replace_range(start..end, &format!("{scaled:e}"));
            }
        }
        out.push_str(&l);
        out.push('\n');
    }
    let tmp = path.with_extension("toml.tmp");
    std::fs::write(&tmp, out).map_err(|e| anyhow::anyhow!("{}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(())
}

pub fn main(a: Args) -> ExitCode {
    init_tracing("info");
    exit_code("taxel soak", run(a))
}

/// A SIGKILL the soak sent.
struct Kill {
    at_s: f64,
    at_ns: u64,
    name: String,
}

fn run(a: Args) -> Result<(), Failure> {
    for (v, what) in [
        (a.seconds, "--seconds"),
        (a.kill_every, "--kill-every"),
        (a.edit_every, "--edit-every"),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(Failure::config(anyhow::anyhow!(
                "{what} must be a positive number, got {v}"
            )));
        }
    }
    check_glove(a.sensors, a.rate_hz, &a.prefix)?;
    let out = out_dir(&a.out, "soak")?;
    let cal = out.join("calibration.toml");
    write_file(&cal, SIM_CALIBRATION.as_bytes())?;
    let model = out.join("curvature.taxcrv");
    write_file(&model, CURVATURE_MODEL)?;
    let recording = out.join("soak.taxrec");
    let mut pipeline = demo_pipeline(a.sensors, a.rate_hz, &cal, &model, &recording, &a.log);
    for c in &mut pipeline.controls {
        c.status = false;
    }
    let ids: Vec<String> = pipeline.sensors.iter().map(|s| s.id.clone()).collect();
    let shutdown = Shutdown::install().runtime_err()?;
    ipc::clean_dead_nodes(&a.prefix).ok();

    // The probe subscribes before anything publishes.
    let stop = Arc::new(AtomicBool::new(false));
    let probe_thread = start_probe(&a.prefix, &ids, &stop)?;
    eprintln!(
        "taxel soak: {} sensor(s) at {} Hz for {} s, a random SIGKILL every {} s, calibration edits every ~{} s, prefix {:?}, files in {}",
        ids.len(),
        a.rate_hz,
        a.seconds,
        a.kill_every,
        a.edit_every,
        a.prefix,
        out.display()
    );
    let mut sup = Supervisor::start(
        &a.prefix,
        &a.log,
        pipeline.policy(),
        pipeline.processes().config_err()?,
    )
    .runtime_err()?;
    let mut chaos = Chaos::new(&a, &cal);
    let until = chaos.t0 + Duration::from_secs_f64(a.seconds);
    sup.run(&shutdown, Some(until), |sup| chaos.step(sup));
    let outcome = sup.stop();
    stop.store(true, Ordering::SeqCst);
    let logs = match probe_thread.join() {
        Ok(r) => r.map_err(|e| e.context("soak probe")).runtime_err()?,
        Err(_) => return Err(Failure::runtime(anyhow::anyhow!("soak probe panicked"))),
    };
    let (sm_line, sm_clean) = sup.shared_memory_report();
    let report = count(&ids, &logs, &sup, &chaos.kills);
    let totals = Totals {
        ids: &ids,
        chaos: &chaos,
        outcome: &outcome,
        report: &report,
        sm_clean,
    };
    if a.json {
        println!("{}", totals.json(&a, &sup));
    } else {
        totals.print(&sup, &sm_line);
    }
    totals.verdict()
}

type ProbeThread = std::thread::JoinHandle<anyhow::Result<Vec<SensorLog>>>;

/// Starts the probe thread and waits (at most 10 s) until it has subscribed to every sensor.
fn start_probe(
    prefix: &str,
    ids: &[String],
    stop: &Arc<AtomicBool>,
) -> Result<ProbeThread, Failure> {
    let ready = Arc::new(AtomicBool::new(false));
    let probe_thread = {
        let (prefix, ids, stop, ready) = (
            prefix.to_string(),
            ids.to_vec(),
            stop.clone(),
            ready.clone(),
        );
        std::thread::spawn(move || probe(&prefix, &ids, &stop, &ready))
    };
    let t_ready = Instant::now();
    while !ready.load(Ordering::SeqCst) {
        if probe_thread.is_finished() || t_ready.elapsed() > Duration::from_secs(10) {
            stop.store(true, Ordering::SeqCst);
            return Err(Failure::runtime(match probe_thread.join() {
                Ok(Err(e)) => e.context("soak probe"),
                _ => anyhow::anyhow!("soak probe did not start within 10 s"),
            }));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    Ok(probe_thread)
}

/// What the soak does to the running pipeline: a SIGKILL to a random process every
/// `--kill-every` seconds (none in the last 2 s, so every victim is back before the stop) and a
/// calibration edit about every `--edit-every` seconds.
struct Chaos<'a> {
    cal: &'a Path,
    seconds: f64,
    kill_every: f64,
    edit_every: f64,
    rng: Rng,
    t0: Instant,
    next_kill: Duration,
    next_edit: Duration,
    kills: Vec<Kill>,
    edits: u32,
    edit_errors: u32,
}

impl<'a> Chaos<'a> {
    fn new(a: &Args, cal: &'a Path) -> Self {
        let mut rng = Rng(a.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
        let next_edit = Duration::from_secs_f64(a.edit_every * (0.5 + rng.unit()));
        Chaos {
            cal,
            seconds: a.seconds,
            kill_every: a.kill_every,
            edit_every: a.edit_every,
            rng,
            t0: Instant::now(),
            next_kill: Duration::from_secs_f64(a.kill_every),
            next_edit,
            kills: Vec::new(),
            edits: 0,
            edit_errors: 0,
        }
    }

    /// Called by the supervisor on every turn of its loop.
    fn step(&mut self, sup: &mut Supervisor) {
        let el = self.t0.elapsed();
        let closing = el.as_secs_f64() > self.seconds - 2.0;
        if el >= self.next_kill && !closing {
            self.next_kill += Duration::from_secs_f64(self.kill_every);
            self.kill_one(sup, el);
        }
        if el >= self.next_edit {
            self.next_edit += Duration::from_secs_f64(self.edit_every * (0.5 + self.rng.unit()));
            self.edits += 1;
            if let Err(e) = edit_calibration(self.cal, self.edits + 1, &mut self.rng) {
                self.edit_errors += 1;
                eprintln!("taxel soak: calibration edit failed: {e:#}");
            }
        }
    }

    fn kill_one(&mut self, sup: &mut Supervisor, el: Duration) {
        let running: Vec<String> = sup
            .slots
            .iter()
            .filter(|s| s.pid().is_some())
            .map(|s| s.spec.name.clone())
            .collect();
        if running.is_empty() {
            return;
        }
        let name = running[self.rng.below(running.len())].clone();
        let at_ns = now_ns();
        if let Some(pid) = sup.signal(&name, libc::SIGKILL) {
            eprintln!(
                "taxel soak: t={:.1} s SIGKILL {name} (pid {pid})",
                el.as_secs_f64()
            );
            self.kills.push(Kill {
                at_s: el.as_secs_f64(),
                at_ns,
                name,
            });
        }
    }
}

/// Everything the soak's report says.
struct Totals<'a> {
    ids: &'a [String],
    chaos: &'a Chaos<'a>,
    outcome: &'a Outcome,
    report: &'a Report,
    sm_clean: bool,
}

impl Totals<'_> {
    fn peaks(sup: &Supervisor) -> Vec<String> {
        sup.slots
            .iter()
            .map(|s| format!("\"{}\": {:.1}", s.spec.name, s.peak_kib as f64 / 1024.0))
            .collect()
    }

    fn flags(&self) -> Vec<String> {
        self.report
            .flag_counts
            .iter()
            .map(|(k, v)| format!("\"{k}\": {v}"))
            .collect()
    }

    /// The `--json` object.
    fn json(&self, a: &Args, sup: &Supervisor) -> String {
        let (report, chaos) = (self.report, self.chaos);
        let restarts: Vec<String> = sup
            .slots
            .iter()
            .filter(|s| s.restarts > 0 || !s.deaths.is_empty())
            .map(|s| format!("\"{}\": {}", s.spec.name, s.restarts))
            .collect();
        let kill_list: Vec<String> = chaos
            .kills
            .iter()
            .map(|k| format!("{{\"t_s\": {:.1}, \"process\": \"{}\"}}", k.at_s, k.name))
            .collect();
        format!(
            "{{\"seconds\": {:.1}, \"sensors\": {}, \"rate_hz\": {}, \"kills\": [{}], \"restarts\": {{{}}}, \"calibration_edits\": {}, \"published\": {}, \"delivered\": {}, \"flagged\": {}, \"flags\": {{{}}}, \"lost\": {}, \"lost_in_downtime\": {}, \"probe_missed\": {}, \"raw_probe_missed\": {}, \"raw_gap_flags\": {}, \"peak_rss_mb\": {{{}}}, \"exit_ok\": {}, \"shm_clean\": {}}}",
            chaos.t0.elapsed().as_secs_f64(),
            self.ids.len(),
            a.rate_hz,
            kill_list.join(", "),
            restarts.join(", "),
            chaos.edits,
            report.published,
            report.delivered,
            report.flagged,
            self.flags().join(", "),
            report.lost,
            report.lost_in_downtime,
            report.probe_missed,
            report.raw_probe_missed,
            report.raw_gap_flags,
            Self::peaks(sup).join(", "),
            self.outcome.all_ok,
            self.sm_clean,
        )
    }

    /// The human-readable report.
    fn print(&self, sup: &Supervisor, sm_line: &str) {
        let (report, chaos) = (self.report, self.chaos);
        println!(
            "taxel soak after {:.1} s: {} kill(s), {} restart(s), {} calibration edit(s)",
            chaos.t0.elapsed().as_secs_f64(),
            chaos.kills.len(),
            self.outcome.restarts,
            chaos.edits
        );
        println!(
            "  frames published {} | delivered {} | flagged {} ({}) | lost {} (+ {} during the killed calibrator's downtime) | sent but missed by the probe {}",
            report.published,
            report.delivered,
            report.flagged,
            self.flags().join(", "),
            report.lost,
            report.lost_in_downtime,
            report.probe_missed
        );
        for l in sup.summary_lines() {
            println!("{l}");
        }
        println!(
            "  peak memory (VmHWM, MB): {}",
            Self::peaks(sup).join(", ").replace('"', "")
        );
        println!("{sm_line}");
    }

    /// Passed, or why not.
    fn verdict(&self) -> Result<(), Failure> {
        let mut why = Vec::new();
        if !self.outcome.all_ok {
            why.push("a process did not end cleanly (see the summary)".to_string());
        }
        if !self.sm_clean {
            why.push("iceoryx2 nodes are left under the prefix".to_string());
        }
        if self.report.lost > 0 {
            why.push(format!(
                "{} frame(s) lost outside the killed calibrator's downtime",
                self.report.lost
            ));
        }
        if self.chaos.edit_errors > 0 {
            why.push(format!(
                "{} calibration edit(s) failed",
                self.chaos.edit_errors
            ));
        }
        if why.is_empty() {
            return Ok(());
        }
        Err(Failure::runtime(anyhow::anyhow!(
            "the soak failed: {}",
            why.join("; ")
        )))
    }
}

#[derive(Default)]
struct Report {
    published: u64,
    delivered: u64,
    flagged: u64,
    flag_counts: BTreeMap<&'static str, u64>,
    lost: u64,
    lost_in_downtime: u64,
    probe_missed: u64,
    raw_probe_missed: u64,
    raw_gap_flags: u64,
}

/// Frames in flight in a calibrator when it is killed: captured up to this long before the kill.
const IN_FLIGHT_NS: u64 = 50_000_000;

/// Counts per sensor on the force stream, whose `seq` is the publisher's frame number: every
/// frame from the first to the last force sample the probe saw of each publisher incarnation
/// was published. A frame missing from the force stream behind a sample flagged `GAP_BEFORE`
/// was never produced by the calibrator: lost, or lost during downtime when that sample is the
/// first of a restarted calibrator (captured between [`IN_FLIGHT_NS`] before the kill and the
/// replacement's first sample). A missing frame behind an unflagged sample was produced but
/// not read in time by the probe itself (its 256-sample buffer overflowed): `probe_missed`.
fn count(ids: &[String], logs: &[SensorLog], sup: &Supervisor, kills: &[Kill]) -> Report {
    let mut r = Report::default();
    for (id, log) in ids.iter().zip(logs) {
        let cal_name = format!("calibrator-{id}");
        // Each calibrator death starts a downtime; the first flagged gap after it (the
        // replacement's first sample) is that downtime.
        let mut downtime_gap = vec![false; log.flagged_gaps.len()];
        for d in sup
            .slots
            .iter()
            .filter(|s| s.spec.name == cal_name)
            .flat_map(|s| s.downtimes.iter())
        {
            let killed = kills
                .iter()
                .filter(|k| k.name == cal_name && k.at_ns <= d.died_ns)
                .map(|k| k.at_ns)
                .next_back()
                .unwrap_or(d.died_ns);
            let start = killed.saturating_sub(IN_FLIGHT_NS);
            if let Some(i) = log.flagged_gaps.iter().position(|&(t, _)| t >= start) {
                downtime_gap[i] = true;
            }
        }
        for (&(_, missing), downtime) in log.flagged_gaps.iter().zip(downtime_gap) {
            if downtime {
                r.lost_in_downtime += missing;
            } else {
                r.lost += missing;
            }
        }
        r.published += log.published;
        r.delivered += log.delivered;
        r.flagged += log.flagged;
        for (k, v) in &log.flag_counts {
            *r.flag_counts.entry(k).or_default() += v;
        }
        r.probe_missed += log.force_probe_missed;
        r.raw_probe_missed += log.raw_probe_missed;
        r.raw_gap_flags += log.raw_gap_flags;
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calibration_edits_stay_valid_and_change_the_version() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("cal.toml");
        let mut rng = Rng(7);
        for v in 2..5 {
            edit_calibration(&p, v, &mut rng).expect("edit");
            let c = taxel_calibrator::calibration::Calibration::load(&p).expect("valid");
            assert_eq!(c.version, v);
        }
        let text = std::fs::read_to_string(&p).expect("read");
        assert_ne!(text, SIM_CALIBRATION);
    }
}
