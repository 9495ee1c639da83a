//! The pipeline file of `taxel up` (TOML, docs/formats.md): sensors with their source,
//! curvature and calibration (a table may stand for `count` numbered sensors), the consumers,
//! the supervision policy, and the layout: a publisher, estimator and calibrator per sensor, or
//! shared by all sensors (`crate::layout`). Parsed with `deny_unknown_fields`, validated into
//! the list of processes the supervisor runs. `taxel demo` and `taxel soak` build the same
//! [`Pipeline`] in memory.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::supervise::{Policy, ProcSpec};
use taxel_runtime::sensors::MAX_SENSORS;

/// Stop stages: consumers stop first, sources last.
pub const STAGE_CONSUMER: u8 = 0;
pub const STAGE_CALIBRATOR: u8 = 1;
pub const STAGE_ESTIMATOR: u8 = 2;
pub const STAGE_SOURCE: u8 = 3;

/// A whole pipeline file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pipeline {
    /// iceoryx2 service prefix (`--prefix` / TAXEL_PREFIX override it).
    #[serde(default)]
    pub prefix: Option<String>,
    /// Log filter of the child processes (RUST_LOG syntax).
    #[serde(default = "default_log")]
    pub log: String,
    /// Which processes serve the sensors: a publisher, estimator and calibrator per sensor, or
    /// one of each for all sensors.
    #[serde(default)]
    pub layout: Layout,
    /// Real-time priority (SCHED_FIFO, 1-99) of the publishers, estimators, calibrators,
    /// control loops and latency probes (`--realtime`); none by default.
    #[serde(default)]
    pub realtime: Option<u8>,
    #[serde(default)]
    pub supervision: Supervision,
    #[serde(rename = "sensor")]
    pub sensors: Vec<Sensor>,
    #[serde(default, rename = "control")]
    pub controls: Vec<Control>,
    #[serde(default)]
    pub logger: Option<Logger>,
    #[serde(default, rename = "latency")]
    pub latencies: Vec<Latency>,
}

fn default_log() -> String {
    "warn".to_string()
}

/// Which processes serve the sensors.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Layout {
    /// A publisher, an estimator and a calibrator per sensor (restarting one touches one
    /// sensor).
    #[default]
    PerSensor,
    /// One estimator and one calibrator for every sensor, one publisher for the simulated
    /// sensors and one per group of replays with the same options (serial boards keep one
    /// publisher each); restarting one restarts all its sensors.
    Shared,
}

/// Restart policy and deadlines.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Supervision {
    /// First restart delay after a crash (ms); doubles with every crash up to the maximum.
    pub backoff_initial_ms: u64,
    pub backoff_max_ms: u64,
    /// Restart budget: at most this many restarts of one process ...
    pub max_restarts: u32,
    /// ... within this window (s); past the budget the process stays stopped.
    pub restart_window_s: f64,
    /// A process that ran this long without crashing starts again from the initial backoff (s).
    pub stable_after_s: f64,
    /// How long a stage may take to exit after SIGINT before it is killed (ms).
    pub stop_grace_ms: u64,
    /// Control loops: a ForceSample older than this is stale: flagged, never used (ms).
    pub deadline_ms: f64,
    /// Control loops: no sample for this long is the safe state (ms).
    pub watchdog_ms: f64,
}

impl Default for Supervision {
    fn default() -> Self {
        Supervision {
            backoff_initial_ms: 100,
            backoff_max_ms: 5_000,
            max_restarts: 5,
            restart_window_s: 60.0,
            stable_after_s: 10.0,
            stop_grace_ms: 5_000,
            deadline_ms: 5.0,
            watchdog_ms: 50.0,
        }
    }
}

/// One sensor: its source, curvature and calibration.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sensor {
    pub id: String,
    /// This table stands for `count` sensors `<id>0` .. `<id><count-1>` (sim sources: sensor k
    /// has seed and build seed + k; the seed defaults to the scenario's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub count: Option<usize>,
    pub source: Source,
    /// Calibration TOML served by the calibrator (hot-reloaded).
    pub calibration: PathBuf,
    /// Curvature model (.taxcrv) for the estimator ...
    #[serde(default)]
    pub model: Option<PathBuf>,
    /// ... or a configured mounting curvature (1/m).
    #[serde(default)]
    pub curvature_m1: Option<f64>,
}

/// Where a sensor's frames come from (the options of `taxel publisher <kind>`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "lowercase")]
pub enum Source {
    Sim {
        #[serde(default)]
        scenario: Option<PathBuf>,
        #[serde(default)]
        preset: Option<String>,
        #[serde(default)]
        build_seed: Option<u64>,
        #[serde(default)]
        seed: Option<u64>,
        #[serde(default)]
        rate_hz: Option<f64>,
        #[serde(default)]
        curvature_m1: Option<f64>,
    },
    Replay {
        file: PathBuf,
        #[serde(default)]
        speed: Option<f64>,
        #[serde(default, rename = "loop")]
        repeat: bool,
        #[serde(default)]
        rows: Option<usize>,
        #[serde(default)]
        cols: Option<usize>,
    },
    Serial {
        port: PathBuf,
        #[serde(default)]
        baud: Option<u32>,
        #[serde(default)]
        format: Option<String>,
        #[serde(default)]
        rows: Option<usize>,
        #[serde(default)]
        cols: Option<usize>,
    },
}

/// A control loop on one sensor.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Control {
    pub sensor: String,
    #[serde(default)]
    pub target_n: Option<f64>,
    #[serde(default)]
    pub wake: Option<String>,
    /// Print the once-a-second status line (default true).
    #[serde(default = "yes")]
    pub status: bool,
}

fn yes() -> bool {
    true
}

/// The logger (records every stream of its sensors).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Logger {
    pub out: PathBuf,
    /// Sensors to record (default: all).
    #[serde(default)]
    pub sensors: Vec<String>,
    #[serde(default)]
    pub flush_ms: Option<u64>,
}

/// A latency probe.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Latency {
    /// Sensors to probe (default: all).
    #[serde(default)]
    pub sensors: Vec<String>,
    #[serde(default)]
    pub stream: Option<String>,
    #[serde(default)]
    pub wake: Option<String>,
}

pub(crate) fn s(v: impl ToString) -> String {
    v.to_string()
}

fn check_pos(v: f64, what: &str) -> anyhow::Result<()> {
    anyhow::ensure!(
        v.is_finite() && v > 0.0,
        "{what} must be a positive number, got {v}"
    );
    Ok(())
}

impl Pipeline {
    /// Reads and validates `path`; relative paths inside are resolved against its directory.
    pub fn load(path: &Path) -> anyhow::Result<Pipeline> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let mut p: Pipeline = toml::from_str(&text).map_err(|e| {
            anyhow::anyhow!(
                "{}: {}",
                path.display(),
                e.to_string().trim().replace('\n', " ")
            )
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        p.resolve(base);
        p.expand()
            .and_then(|_| p.validate())
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Ok(p)
    }

    /// Replaces every table with a `count` by its numbered sensors.
    pub fn expand(&mut self) -> anyhow::Result<()> {
        let mut out = Vec::with_capacity(self.sensors.len());
        for (i, sn) in self.sensors.iter().enumerate() {
            let Some(count) = sn.count else {
                out.push(sn.clone());
                continue;
            };
            let at = format!("sensor[{i}] ({:?})", sn.id);
            anyhow::ensure!(
                (1..=MAX_SENSORS).contains(&count),
                "{at}: count must be 1..={MAX_SENSORS}, got {count}"
            );
            anyhow::ensure!(
                !matches!(sn.source, Source::Serial { .. }),
                "{at}: count needs a sim or replay source (a serial board is one sensor)"
            );
            for k in 0..count {
                let mut one = sn.clone();
                one.id = format!("{}{k}", sn.id);
                one.count = None;
                if let Source::Sim {
                    scenario,
                    seed,
                    build_seed,
                    ..
                } = &mut one.source
                {
                    let base = match seed {
                        Some(s) => *s,
                        None => scenario_seed(scenario.as_deref())
                            .map_err(|e| anyhow::anyhow!("{at}: {e}"))?,
                    };
                    *seed = Some(base.wrapping_add(k as u64));
                    *build_seed = build_seed.map(|b| b.wrapping_add(k as u64));
                }
                out.push(one);
            }
        }
        self.sensors = out;
        Ok(())
    }

    fn resolve(&mut self, base: &Path) {
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        for sn in &mut self.sensors {
            fix(&mut sn.calibration);
            if let Some(m) = &mut sn.model {
                fix(m);
            }
            match &mut sn.source {
                Source::Sim {
                    scenario: Some(sc), ..
                } => fix(sc),
                Source::Replay { file, .. } => fix(file),
                _ => {}
            }
        }
        if let Some(l) = &mut self.logger {
            fix(&mut l.out);
        }
    }

    /// Checks everything a process would refuse at start, so a bad file fails before anything
    /// runs (with the field named).
    pub fn validate(&self) -> anyhow::Result<()> {
        let sv = &self.supervision;
        anyhow::ensure!(!self.sensors.is_empty(), "no [[sensor]]");
        if let Some(r) = self.realtime {
            anyhow::ensure!((1..=99).contains(&r), "realtime = {r}: must be 1 to 99");
        }
        anyhow::ensure!(
            sv.backoff_initial_ms >= 1 && sv.backoff_initial_ms <= sv.backoff_max_ms,
            "supervision: need 1 <= backoff_initial_ms <= backoff_max_ms"
        );
        check_pos(sv.restart_window_s, "supervision.restart_window_s")?;
        check_pos(sv.stable_after_s, "supervision.stable_after_s")?;
        check_pos(sv.deadline_ms, "supervision.deadline_ms")?;
        check_pos(sv.watchdog_ms, "supervision.watchdog_ms")?;
        anyhow::ensure!(
            sv.stop_grace_ms >= 1,
            "supervision.stop_grace_ms must be >= 1"
        );
        let mut ids: Vec<&str> = Vec::new();
        for (i, sn) in self.sensors.iter().enumerate() {
            let at = format!("sensor[{i}] ({:?})", sn.id);
            taxel_msgs::sensor_id_bytes(&sn.id).map_err(|e| anyhow::anyhow!("{at}: {e}"))?;
            anyhow::ensure!(!ids.contains(&sn.id.as_str()), "{at}: duplicate id");
            ids.push(&sn.id);
            anyhow::ensure!(
                sn.model.is_some() != sn.curvature_m1.is_some(),
                "{at}: give exactly one of model or curvature_m1"
            );
            if let Some(c) = sn.curvature_m1 {
                anyhow::ensure!(c.is_finite(), "{at}: curvature_m1 must be finite");
            }
            taxel_calibrator::calibration::Calibration::load(&sn.calibration)
                .map_err(|e| anyhow::anyhow!("{at}: calibration: {e}"))?;
            if let Some(m) = &sn.model {
                anyhow::ensure!(m.is_file(), "{at}: model {} is not a file", m.display());
            }
            match &sn.source {
                Source::Sim {
                    rate_hz, scenario, ..
                } => {
                    if let Some(r) = rate_hz {
                        check_pos(*r, &format!("{at}: source.rate_hz"))?;
                    }
                    if let Some(sc) = scenario {
                        anyhow::ensure!(
                            sc.is_file(),
                            "{at}: scenario {} is not a file",
                            sc.display()
                        );
                    }
                }
                Source::Replay { file, speed, .. } => {
                    anyhow::ensure!(
                        file.is_file(),
                        "{at}: replay file {} is not a file",
                        file.display()
                    );
                    if let Some(v) = speed {
                        check_pos(*v, &format!("{at}: source.speed"))?;
                    }
                }
                Source::Serial { .. } => {}
            }
        }
        let known = |s: &String, what: &str| -> anyhow::Result<()> {
            anyhow::ensure!(
                ids.contains(&s.as_str()),
                "{what}: unknown sensor {s:?} (sensors: {})",
                ids.join(", ")
            );
            Ok(())
        };
        for (i, c) in self.controls.iter().enumerate() {
            known(&c.sensor, &format!("control[{i}]"))?;
            if let Some(t) = c.target_n {
                anyhow::ensure!(
                    t.is_finite() && t >= 0.0,
                    "control[{i}]: target_n must be >= 0"
                );
            }
        }
        if let Some(l) = &self.logger {
            for x in &l.sensors {
                known(x, "logger")?;
            }
            if let Some(f) = l.flush_ms {
                anyhow::ensure!(
                    (1..=60_000).contains(&f),
                    "logger: flush_ms must be 1..=60000"
                );
            }
        }
        for (i, l) in self.latencies.iter().enumerate() {
            for x in &l.sensors {
                known(x, &format!("latency[{i}]"))?;
            }
        }
        Ok(())
    }

    /// The supervisor's policy.
    pub fn policy(&self) -> Policy {
        let sv = &self.supervision;
        Policy {
            backoff_initial: Duration::from_millis(sv.backoff_initial_ms),
            backoff_max: Duration::from_millis(sv.backoff_max_ms),
            max_restarts: sv.max_restarts,
            window: Duration::from_secs_f64(sv.restart_window_s),
            stable_after: Duration::from_secs_f64(sv.stable_after_s),
            stop_grace: Duration::from_millis(sv.stop_grace_ms),
        }
    }

    fn all_ids(&self) -> Vec<String> {
        self.sensors.iter().map(|x| x.id.clone()).collect()
    }

    /// The processes, as `taxel <role> ...` argument lists, in start order (consumers first,
    /// sources last, so nothing published is missed). Fails when a shared layout cannot say
    /// what a sensor needs (a scenario file it cannot read for its seed, a path with a comma).
    pub fn processes(&self) -> anyhow::Result<Vec<ProcSpec>> {
        let sv = &self.supervision;
        let mut out = Vec::new();
        if let Some(l) = &self.logger {
            let sensors = if l.sensors.is_empty() {
                self.all_ids()
            } else {
                l.sensors.clone()
            };
            let mut args = vec![
                s("logger"),
                s("record"),
                s("--sensor"),
                sensors.join(","),
                s("--out"),
                l.out.display().to_string(),
            ];
            if let Some(f) = l.flush_ms {
                args.extend([s("--flush-ms"), f.to_string()]);
            }
            let mut spec = ProcSpec::new("logger", STAGE_CONSUMER, args);
            // A restarted logger must not truncate what its predecessor recorded.
            spec.numbered_output = Some(5);
            out.push(spec);
        }
        for (i, l) in self.latencies.iter().enumerate() {
            let sensors = if l.sensors.is_empty() {
                self.all_ids()
            } else {
                l.sensors.clone()
            };
            let mut args = vec![s("latency"), s("--sensor"), sensors.join(",")];
            if let Some(v) = &l.stream {
                args.extend([s("--stream"), v.clone()]);
            }
            if let Some(v) = &l.wake {
                args.extend([s("--wake"), v.clone()]);
            }
            let name = if self.latencies.len() == 1 {
                s("latency")
            } else {
                format!("latency-{i}")
            };
            out.push(ProcSpec::new(&name, STAGE_CONSUMER, args));
        }
        for c in &self.controls {
            let mut args = vec![
                s("control"),
                s("--sensor"),
                c.sensor.clone(),
                s("--deadline-ms"),
                sv.deadline_ms.to_string(),
                s("--watchdog-ms"),
                sv.watchdog_ms.to_string(),
            ];
            if let Some(t) = c.target_n {
                args.extend([s("--target-n"), t.to_string()]);
            }
            if let Some(w) = &c.wake {
                args.extend([s("--wake"), w.clone()]);
            }
            if !c.status {
                args.push(s("--quiet"));
            }
            out.push(ProcSpec::new(
                &format!("control-{}", c.sensor),
                STAGE_CONSUMER,
                args,
            ));
        }
        match self.layout {
            Layout::PerSensor => out.extend(self.per_sensor_processes()),
            Layout::Shared => out.extend(crate::layout::shared_processes(self)?),
        }
        if let Some(r) = self.realtime {
            let hot = ["publisher", "estimator", "calibrator", "control", "latency"];
            for p in out.iter_mut().filter(|p| hot.contains(&p.args[0].as_str())) {
                // An option of the role (after `run`), before a publisher's source subcommand.
                let at = if p.args.get(1).is_some_and(|a| a == "run") {
                    2
                } else {
                    1
                };
                p.args
                    .splice(at..at, [s("--realtime"), r.to_string()])
                    .for_each(drop);
            }
        }
        Ok(out)
    }

    /// A calibrator, an estimator and a publisher per sensor.
    fn per_sensor_processes(&self) -> Vec<ProcSpec> {
        let mut out = Vec::new();
        for sn in &self.sensors {
            out.push(ProcSpec::new(
                &format!("calibrator-{}", sn.id),
                STAGE_CALIBRATOR,
                vec![
                    s("calibrator"),
                    s("run"),
                    s("--sensor"),
                    sn.id.clone(),
                    s("--calibration"),
                    sn.calibration.display().to_string(),
                ],
            ));
            let mut est = vec![s("estimator"), s("run"), s("--sensor"), sn.id.clone()];
            if let Some(m) = &sn.model {
                est.extend([s("--model"), m.display().to_string()]);
            }
            if let Some(c) = sn.curvature_m1 {
                est.extend([s("--curvature-m1"), c.to_string()]);
            }
            out.push(ProcSpec::new(
                &format!("estimator-{}", sn.id),
                STAGE_ESTIMATOR,
                est,
            ));
        }
        for sn in &self.sensors {
            out.push(ProcSpec::new(
                &format!("publisher-{}", sn.id),
                STAGE_SOURCE,
                publisher_args(&sn.id, &sn.source),
            ));
        }
        out
    }
}

/// The seed of a scenario file (None: the built-in demo scenario's).
pub fn scenario_seed(scenario: Option<&Path>) -> anyhow::Result<u64> {
    match scenario {
        None => Ok(taxel_sim::Scenario::demo(0.0, 1).seed),
        Some(p) => {
            let text =
                std::fs::read_to_string(p).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
            let sc = taxel_sim::Scenario::from_toml_str(&text)
                .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
            Ok(sc.seed)
        }
    }
}

pub(crate) fn publisher_args(id: &str, src: &Source) -> Vec<String> {
    let mut a = vec![s("publisher"), s("--sensor"), s(id)];
    let opt = |a: &mut Vec<String>, flag: &str, v: Option<String>| {
        if let Some(v) = v {
            a.extend([s(flag), v]);
        }
    };
    match src {
        Source::Sim {
            scenario,
            preset,
            build_seed,
            seed,
            rate_hz,
            curvature_m1,
        } => {
            a.push(s("sim"));
            opt(
                &mut a,
                "--scenario",
                scenario.as_ref().map(|p| p.display().to_string()),
            );
            opt(&mut a, "--preset", preset.clone());
            opt(&mut a, "--build-seed", build_seed.map(s));
            opt(&mut a, "--seed", seed.map(s));
            opt(&mut a, "--rate-hz", rate_hz.map(s));
            opt(&mut a, "--curvature-m1", curvature_m1.map(s));
        }
        Source::Replay {
            file,
            speed,
            repeat,
            rows,
            cols,
        } => {
            a.extend([s("replay"), file.display().to_string()]);
            opt(&mut a, "--speed", speed.map(s));
            opt(&mut a, "--rows", rows.map(s));
            opt(&mut a, "--cols", cols.map(s));
            if *repeat {
                a.push(s("--loop"));
            }
        }
        Source::Serial {
            port,
            baud,
            format,
            rows,
            cols,
        } => {
            a.extend([s("serial"), s("--port"), port.display().to_string()]);
            opt(&mut a, "--baud", baud.map(s));
            opt(&mut a, "--format", format.clone());
            opt(&mut a, "--rows", rows.map(s));
            opt(&mut a, "--cols", cols.map(s));
        }
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    const CAL: &str = include_str!("../../calibrations/sim-default.toml");

    fn write(dir: &Path, body: &str) -> PathBuf {
        std::fs::write(dir.join("cal.toml"), CAL).expect("cal");
        let p = dir.join("p.toml");
        std::fs::write(&p, body).expect("pipeline");
        p
    }

    #[test]
    fn a_pipeline_becomes_processes_in_stop_order() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = write(
            dir.path(),
            r#"
[supervision]
max_restarts = 3
[[sensor]]
id = "a"
calibration = "cal.toml"
curvature_m1 = 40
source = { kind = "sim", rate_hz = 500 }
[[control]]
sensor = "a"
[logger]
out = "run.taxrec"
flush_ms = 100
"#,
        );
        let pl = Pipeline::load(&p).expect("load");
        assert_eq!(pl.policy().max_restarts, 3);
        let procs = pl.processes().expect("processes");
        let names: Vec<&str> = procs.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "logger",
                "control-a",
                "calibrator-a",
                "estimator-a",
                "publisher-a"
            ]
        );
        let publ = &procs[4].args;
        assert!(
            publ.windows(2).any(|w| w == ["--rate-hz", "500"]),
            "{publ:?}"
        );
        assert_eq!(
            procs[0].args_for(1)[5],
            dir.path().join("run.1.taxrec").display().to_string()
        );
        let cal = &procs[2].args;
        assert!(cal
            .iter()
            .any(|a| a.ends_with("cal.toml") && a.starts_with('/')));
    }

    #[test]
    fn bad_pipelines_are_refused_with_the_field_named() {
        let dir = tempfile::tempdir().expect("tempdir");
        for (body, needle) in [
            ("[[sensor]]\nid = \"a\"\ncalibration = \"cal.toml\"\ncurvature_m1 = 1\nsource = { kind = \"sim\" }\nbogus = 1\n", "bogus"),
            ("[[sensor]]\nid = \"a\"\ncalibration = \"cal.toml\"\nsource = { kind = \"sim\" }\n", "exactly one of model"),
            ("[[sensor]]\nid = \"a\"\ncalibration = \"cal.toml\"\ncurvature_m1 = 1\nsource = { kind = \"sim\" }\n[[control]]\nsensor = \"b\"\n", "unknown sensor \"b\""),
            ("[[sensor]]\nid = \"a\"\ncalibration = \"missing.toml\"\ncurvature_m1 = 1\nsource = { kind = \"sim\" }\n", "missing.toml"),
            ("[supervision]\nbackoff_initial_ms = 0\n[[sensor]]\nid = \"a\"\ncalibration = \"cal.toml\"\ncurvature_m1 = 1\nsource = { kind = \"sim\" }\n", "backoff_initial_ms"),
            ("[[sensor]]\nid = \"a\"\ncalibration = \"cal.toml\"\ncurvature_m1 = 1\nsource = { kind = \"usb\" }\n", "usb"),
        ] {
            let p = write(dir.path(), body);
            let e = format!("{:#}", Pipeline::load(&p).expect_err(body));
            assert!(e.contains(needle), "{needle:?} not in {e}");
            assert!(e.contains("p.toml"), "{e}");
            assert!(!e.contains('\n'), "{e}");
        }
    }
}
