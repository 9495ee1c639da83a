//! One process serving many sensors, with the real binaries: a shared publisher, estimator and
//! calibrator deliver to per-sensor subscribers exactly what a process per sensor delivers
//! (same seeds, same frames, same estimates, same forces); a broken calibration file of one
//! sensor leaves the others served and reloading; bad sensor lists are refused with one-line
//! errors; `taxel up` runs the shared layout, and a SIGKILLed shared calibrator is restarted
//! with every one of its sensors; `--realtime` puts each process under SCHED_FIFO.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;

use taxel_formats::{Record, RecordFileReader};
use taxel_msgs::force_flags;
use taxel_testkit::{pipeline, Pipeline, Role};

const SIM_CAL: &str = include_str!("../calibrations/sim-default.toml");
const LIMIT: Duration = Duration::from_secs(20);

/// The shipped calibration with a no-load reading of its own, so forces do not wait for an
/// estimate (and do not depend on when one arrives).
fn cal_with_zero() -> String {
    let zero = vec!["480"; 16].join(", ");
    SIM_CAL.replacen(
        "default_curvature_m1 = 0.0",
        &format!("default_curvature_m1 = 0.0\nno_load_reading = [{zero}]"),
        1,
    )
}

fn records(path: &Path) -> Vec<Record> {
    let mut r = RecordFileReader::open(path).expect("open recording");
    let mut out = Vec::new();
    while let Some(rec) = r.next_record() {
        out.push(rec);
    }
    out
}

/// What a recording holds, by (sensor, seq): raw counts, forces (total, first block, flags,
/// version), estimates (curvature, baseline).
#[derive(Default)]
struct Seen {
    raw: BTreeMap<(String, u64), Vec<f32>>,
    force: BTreeMap<(String, u64), (f32, f32, u32, u32)>,
    est: BTreeMap<(String, u64), (f32, Vec<f32>)>,
}

fn seen(path: &Path) -> Seen {
    let mut s = Seen::default();
    for r in records(path) {
        match r {
            Record::Raw(f) => {
                let id = taxel_msgs::sensor_id_str(&f.sensor).to_string();
                s.raw.insert((id, f.seq), f.counts[..f.n_nodes()].to_vec());
            }
            Record::Force(f) => {
                let id = taxel_msgs::sensor_id_str(&f.sensor).to_string();
                s.force.insert(
                    (id, f.seq),
                    (f.total_force_n, f.block_force_n[0], f.flags, f.cal_version),
                );
            }
            Record::Curvature(e) => {
                let id = taxel_msgs::sensor_id_str(&e.sensor).to_string();
                s.est.insert(
                    (id, e.seq),
                    (e.curvature_m1, e.baseline[..e.n_nodes()].to_vec()),
                );
            }
            Record::Reference(_) => {}
        }
    }
    s
}

/// Starts one layout of sensors a and b (simulated, seeds 11 and 12, 200 Hz for 2.5 s): a
/// logger, then calibrators (`with_calibrator`) or estimators, then the sources. Returns the
/// roles to stop after the sources end, and the sources. The shared consumers wait on the
/// wake-up group `w`; the shared publisher notifies it with calibrators, and without, with
/// estimators (their fallback poll must then find every frame all the same).
fn start_layout(p: &mut Pipeline, shared: bool, with_calibrator: bool) -> (Vec<Role>, Vec<Role>) {
    let rec = p.arg("run.taxrec");
    let cal = p.write("cal.toml", cal_with_zero());
    let mut consumers = vec![p.logger("a,b", &rec, &[])];
    let est = [
        "--curvature-m1",
        "40",
        "--window-frames",
        "20",
        "--min-interval-s",
        "0.15",
    ];
    let groups: &[&str] = if shared { &["a,b"] } else { &["a", "b"] };
    let wake: &[&str] = if shared { &["--wake-group", "w"] } else { &[] };
    for g in groups {
        consumers.push(if with_calibrator {
            p.calibrator(g, &cal, wake)
        } else {
            p.estimator(g, &[&est[..], wake].concat())
        });
    }
    let sim = |seed: &str| {
        vec![
            "--seconds".to_string(),
            "2.5".into(),
            "sim".into(),
            "--rate-hz".into(),
            "200".into(),
            "--seed".into(),
            seed.into(),
        ]
    };
    let mut sources = Vec::new();
    if shared {
        // One value for the list: sensor i has seed 11 + i.
        let mut a = sim("11");
        if with_calibrator {
            a.splice(0..0, ["--wake-group".to_string(), "w".into()]);
        }
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        sources.push(p.publisher_ready("a,b", &a));
    } else {
        for (sensor, seed) in [("a", "11"), ("b", "12")] {
            let a = sim(seed);
            let a: Vec<&str> = a.iter().map(String::as_str).collect();
            sources.push(p.publisher_ready(sensor, &a));
        }
    }
    (consumers, sources)
}

fn finish_layout(p: &mut Pipeline, consumers: &[Role], sources: &[Role]) -> Seen {
    for s in sources {
        p.finish(*s, LIMIT);
    }
    p.stop(consumers);
    let s = seen(&p.path("run.taxrec"));
    p.assert_released(LIMIT);
    s
}

#[test]
fn a_shared_layout_delivers_what_a_process_per_sensor_delivers() {
    // Forces (publisher + calibrator) and estimates (publisher + estimator), each in both
    // layouts, the four pipelines side by side.
    let mut pipes: Vec<Pipeline> = (0..4).map(|_| pipeline!("sk")).collect();
    let mut started = Vec::new();
    for (i, p) in pipes.iter_mut().enumerate() {
        started.push(start_layout(p, i % 2 == 1, i < 2));
    }
    let mut got: Vec<Seen> = Vec::new();
    for (p, (consumers, sources)) in pipes.iter_mut().zip(&started) {
        got.push(finish_layout(p, consumers, sources));
    }
    for sensor in ["a", "b"] {
        for (what, k) in [("forces", 0), ("estimates", 2)] {
            let (own, shared) = (&got[k], &got[k + 1]);
            let raw = |s: &Seen| s.raw.keys().filter(|(x, _)| x == sensor).count();
            assert!(
                raw(own) > 300 && raw(shared) > 300,
                "{what} {sensor}: {} and {} frames recorded",
                raw(own),
                raw(shared)
            );
            // The same frames: same seeds, whichever process publishes them.
            let mut common = 0;
            for (key, counts) in own.raw.iter().filter(|((x, _), _)| x == sensor) {
                if let Some(c) = shared.raw.get(key) {
                    assert_eq!(counts, c, "{what}: raw frame {key:?} differs");
                    common += 1;
                }
            }
            assert!(common > 300, "{what} {sensor}: {common} frames in common");
        }
        // The same forces for the same frames.
        let (own, shared) = (&got[0], &got[1]);
        let mut common = 0;
        for (key, f) in own.force.iter().filter(|((x, _), _)| x == sensor) {
            if let Some(g) = shared.force.get(key) {
                assert_eq!(f, g, "force of {key:?} differs");
                assert!(f.0.is_finite(), "{key:?}: {f:?}");
                common += 1;
            }
        }
        assert!(common > 300, "forces of {sensor}: {common} in common");
        // The same estimates for the same windows, the first one in both.
        let (own, shared) = (&got[2], &got[3]);
        let first = |s: &Seen| s.est.keys().find(|(x, _)| x == sensor).cloned();
        let f = first(own).unwrap_or_else(|| panic!("no estimate of {sensor}"));
        assert_eq!(
            Some(&f),
            first(shared).as_ref(),
            "first estimate of {sensor}"
        );
        for (key, e) in own.est.iter().filter(|((x, _), _)| x == sensor) {
            if let Some(g) = shared.est.get(key) {
                assert_eq!(e, g, "estimate of window {key:?} differs");
            }
        }
    }
    // The two sensors of the shared publisher are different sensors (seeds 11 and 12).
    let s = &got[1].raw;
    let a: Vec<&Vec<f32>> = s
        .iter()
        .filter(|((x, _), _)| x == "a")
        .map(|(_, v)| v)
        .collect();
    let b: Vec<&Vec<f32>> = s
        .iter()
        .filter(|((x, _), _)| x == "b")
        .map(|(_, v)| v)
        .collect();
    assert_ne!(a[..50], b[..50]);
}

#[test]
fn a_broken_calibration_of_one_sensor_leaves_the_others_served() {
    let mut p = pipeline!("sb");
    let cal_a = p.write("a.toml", SIM_CAL);
    let cal_b = p.write("b.toml", SIM_CAL);
    let rec = p.arg("run.taxrec");
    let logger = p.logger("a,b,c", &rec, &[]);
    let cals = format!("{cal_a},{cal_b},{cal_a}");
    let calibrator = p.calibrator("a,b,c", &cals, &[]);
    let estimator = p.estimator("a,b,c", &["--curvature-m1", "30"]);
    let publisher = p.publisher_ready("a,b,c", &["sim", "--rate-hz", "200"]);
    p[estimator].wait_for("first no-load baseline", LIMIT);

    // b's file turns into garbage, edited in place: refused, b keeps version 1.
    std::fs::write(&cal_b, "version = \"three\"\n\u{0}garbage").expect("garbage");
    p[calibrator].wait_for("calibration rejected for sensor(s) b,", LIMIT);
    // a's file (also c's) gets version 2: a and c switch, b does not.
    taxel_testkit::replace(
        Path::new(&cal_a),
        SIM_CAL.replacen("version = 1", "version = 2", 1).as_bytes(),
    );
    p[calibrator].wait_count("now serving reloaded calibration", 2, LIMIT);
    // A good file for b is picked up later.
    std::thread::sleep(Duration::from_millis(500));
    taxel_testkit::replace(
        Path::new(&cal_b),
        SIM_CAL.replacen("version = 1", "version = 3", 1).as_bytes(),
    );
    p[calibrator].wait_count("now serving reloaded calibration", 3, LIMIT);
    std::thread::sleep(Duration::from_millis(500));
    p.stop(&[publisher]);
    p.stop(&[calibrator, estimator, logger]);

    let out = p[calibrator].output();
    let rejected: Vec<&str> = out
        .lines()
        .filter(|l| l.contains("calibration rejected"))
        .collect();
    assert_eq!(rejected.len(), 1, "{out}");
    assert!(rejected[0].contains("b.toml"), "{}", rejected[0]);
    // Per sensor, the versions in seq order: a and c 1 -> 2, b 1 -> 3, every sensor to the end.
    let mut versions: BTreeMap<String, Vec<(u64, u32)>> = BTreeMap::new();
    for r in records(&p.path("run.taxrec")) {
        if let Record::Force(f) = r {
            let id = taxel_msgs::sensor_id_str(&f.sensor).to_string();
            versions.entry(id).or_default().push((f.seq, f.cal_version));
        }
    }
    let last = |s: &str| versions[s].iter().map(|x| x.0).max().unwrap_or(0);
    for (sensor, want) in [("a", [1, 2]), ("b", [1, 3]), ("c", [1, 2])] {
        let mut v = versions[sensor].clone();
        v.sort();
        let mut seen: Vec<u32> = v.iter().map(|x| x.1).collect();
        seen.dedup();
        assert_eq!(seen, want, "versions of {sensor}");
        assert!(
            last(sensor) + 20 >= last("a"),
            "{sensor} stopped at {} (a at {})",
            last(sensor),
            last("a")
        );
        let gaps = v.windows(2).filter(|w| w[1].0 != w[0].0 + 1).count();
        assert_eq!(gaps, 0, "{sensor} lost frames");
    }
    p.assert_released(LIMIT);
}

fn config_error(args: &[&str], needle: &str) {
    let (code, _out, err) = pipeline!("sc").run(args);
    assert_eq!(code, 2, "{args:?} exited {code}: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{args:?}: one line expected:\n{err}");
    assert!(
        lines[0].contains(needle) && lines[0].contains("error"),
        "{args:?}: expected {needle:?} in:\n{err}"
    );
}

#[test]
fn bad_sensor_lists_are_refused_with_one_line_errors() {
    let p = pipeline!("sl");
    let cal = p.write("cal.toml", SIM_CAL);
    let two = format!("{cal},{cal}");
    let missing = format!("{cal},/no/such/b.toml");
    config_error(
        &["publisher", "--sensor", "a,,b", "sim"],
        "entry 2 is empty",
    );
    config_error(
        &[
            "calibrator",
            "run",
            "--sensor",
            "a,b,a",
            "--calibration",
            &cal,
        ],
        "\"a\" is listed twice (entries 1 and 3)",
    );
    let group = ["--sensor", "a,b", "--wake-group", "no/slash"];
    for args in [
        [&["publisher"][..], &group, &["sim"]].concat(),
        [&["estimator", "run"][..], &group].concat(),
        [&["calibrator", "run"][..], &group, &["--calibration", &cal]].concat(),
    ] {
        config_error(&args, "--wake-group: wake-up group \"no/slash\"");
    }
    config_error(
        &["estimator", "run", "--sensor", "a,b c"],
        "--sensor: entry 2: invalid sensor id \"b c\"",
    );
    config_error(
        &[
            "calibrator",
            "run",
            "--sensor",
            "a,b,c",
            "--calibration",
            &two,
        ],
        "--calibration: 2 values for 3 sensor(s)",
    );
    config_error(
        &[
            "calibrator",
            "run",
            "--sensor",
            "a,b",
            "--calibration",
            &missing,
        ],
        "sensor \"b\": ",
    );
    config_error(
        &[
            "calibrator",
            "run",
            "--sensor",
            "a,b",
            "--calibration",
            &cal,
            "--wake",
            "busy",
        ],
        "several sensors wait event-driven only",
    );
    config_error(
        &["publisher", "--sensor", "a,b", "sim", "--seed", "1,2,3"],
        "--seed: 3 values for 2 sensor(s)",
    );
    config_error(
        &[
            "publisher",
            "--sensor",
            "a,b",
            "sim",
            "--preset",
            "default,nosuch",
        ],
        "sensor \"b\"",
    );
    config_error(
        &[
            "publisher",
            "--sensor",
            "a,b",
            "serial",
            "--port",
            "/dev/null",
        ],
        "serial publishes one sensor",
    );
    config_error(
        &[
            "estimator",
            "run",
            "--sensor",
            "a,b",
            "--curvature-m1",
            "40,-1",
        ],
        "sensor \"b\": --curvature-m1",
    );
}

#[test]
fn taxel_up_runs_the_shared_layout_and_restarts_a_shared_process_with_all_its_sensors() {
    let mut p = pipeline!("su");
    p.write("cal.toml", SIM_CAL);
    let pipeline = p.write(
        "skin.toml",
        r#"
log = "info"
layout = "shared"
[supervision]
backoff_initial_ms = 100
max_restarts = 3

[[sensor]]
id = "p"
count = 3
calibration = "cal.toml"
curvature_m1 = 40
source = { kind = "sim", rate_hz = 200, seed = 7 }

[logger]
out = "run.taxrec"
flush_ms = 100
"#,
    );
    let up = p.spawn("up", &["up", &pipeline]);
    let up = &mut p[up];
    up.wait_for("4 process(es) for 3 sensor(s)", LIMIT);
    up.wait_for("publisher ready for every sensor", LIMIT);
    up.wait_count("first no-load baseline", 3, LIMIT);
    std::thread::sleep(Duration::from_millis(500));
    let out = up.output();
    let pid: u32 = out
        .lines()
        .find_map(|l| {
            let i = l.find("started calibrator pid ")? + "started calibrator pid ".len();
            l[i..].split_whitespace().next()?.parse().ok()
        })
        .unwrap_or_else(|| panic!("no calibrator pid:\n{out}"));
    // SAFETY: kill(2) on the supervisor's child.
    unsafe {
        libc::kill(pid as i32, libc::SIGKILL);
    }
    up.wait_for("restarted calibrator pid", LIMIT);
    up.wait_count("calibrator ready", 6, LIMIT);
    std::thread::sleep(Duration::from_millis(800));
    up.sigint();
    let st = up.wait_exit(LIMIT);
    let out = up.output();
    assert!(st.success(), "taxel up exited {st}:\n{out}");
    for name in ["calibrator", "estimator", "publisher-sim", "logger"] {
        assert!(
            out.lines()
                .any(|l| l.trim_start().starts_with(name) && l.contains("exited 0")),
            "{name} not in the summary:\n{out}"
        );
    }
    // Each sensor's force stream resumed after the restart, behind a GAP_BEFORE flag.
    let mut force: BTreeMap<String, Vec<(u64, u32)>> = BTreeMap::new();
    for r in records(&p.path("run.taxrec")) {
        if let Record::Force(f) = r {
            let id = taxel_msgs::sensor_id_str(&f.sensor).to_string();
            force.entry(id).or_default().push((f.seq, f.flags));
        }
    }
    assert_eq!(force.len(), 3, "{:?}", force.keys());
    for (id, v) in &force {
        let restarts = v
            .windows(2)
            .filter(|w| w[1].1 & force_flags::GAP_BEFORE != 0 && w[1].0 > w[0].0)
            .count();
        assert!(restarts >= 1, "{id}: no flagged resumption");
        for w in v.windows(2) {
            if w[1].0 != w[0].0 + 1 {
                assert!(
                    w[1].1 & force_flags::GAP_BEFORE != 0,
                    "{id}: {} -> {} unflagged",
                    w[0].0,
                    w[1].0
                );
            }
        }
    }
    p.assert_released(LIMIT);
}

/// The scheduling policy and real-time priority of process `pid`, from /proc/PID/stat
/// (fields 41 and 40, counted after the command name's closing parenthesis).
fn policy(pid: u32) -> (u32, u32) {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).expect("stat");
    let rest = &stat[stat.rfind(')').expect("comm") + 2..];
    let f: Vec<&str> = rest.split(' ').collect();
    // `rest` starts at field 3 (state).
    (
        f[41 - 3].parse().expect("policy"),
        f[40 - 3].parse().expect("rt_priority"),
    )
}

#[test]
fn realtime_processes_run_under_sched_fifo_or_refuse_with_one_line_errors() {
    // An out-of-range priority is clap's error (with its usual hint line), exit 2.
    let (code, _, err) =
        pipeline!("rt0").run(&["publisher", "--sensor", "a", "--realtime", "0", "sim"]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.starts_with("error: invalid value '0' for '--realtime"),
        "{err}"
    );
    config_error(
        &[
            "latency",
            "--sensor",
            "a",
            "--realtime",
            "5",
            "--wake",
            "busy",
        ],
        "--realtime 5 with --wake busy",
    );
    let mut p = pipeline!("rt");
    let cal = p.write("cal.toml", SIM_CAL);
    // A probe with nothing to measure: refused priority is exit 2 and says so; granted, it
    // runs and finds no samples (exit 1).
    let (code, _, err) = p.run(&[
        "latency",
        "--sensor",
        "none",
        "--realtime",
        "5",
        "--seconds",
        "0.2",
    ]);
    if code == 2 {
        assert!(
            err.contains("the system refused real-time priority"),
            "{err}"
        );
        // Without the right (not root, no CAP_SYS_NICE), the refusal above is the behaviour.
        println!("real-time priority refused here: {err}");
        return;
    }
    assert!(err.contains("no samples"), "{code}: {err}");
    let cal_role = p.calibrator("a,b", &cal, &["--realtime", "7"]);
    let est = p.estimator("a,b", &["--curvature-m1", "40", "--realtime", "6"]);
    let publ = p.publisher_ready("a,b", &["--realtime", "8", "sim", "--rate-hz", "200"]);
    let probe = p.latency("probe", "a,b", &["--realtime", "9", "--seconds", "2"]);
    const SCHED_FIFO: u32 = 1;
    for (role, prio) in [(cal_role, 7), (est, 6), (publ, 8), (probe, 9)] {
        assert_eq!(policy(p[role].child.id()), (SCHED_FIFO, prio));
    }
    p.finish(probe, LIMIT);
    let out = p[probe].output();
    assert!(
        out.contains("taxel/a,b/force: ") && out.contains(", dropped 0"),
        "{out}"
    );
}
