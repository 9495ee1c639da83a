//! Faults that must be survived, with the real binaries: `kill -9` of every process kind under
//! `taxel up` (survivors keep running, the supervisor cleans the dead node and restarts the
//! victim, the stream resumes with a flagged gap, the control loop goes to its safe state while
//! its force stream is down), a SIGKILLed logger leaves a recording readable up to its last
//! flush, and a short soak with random kills loses nothing outside the killed process's
//! downtime.

use std::path::Path;
use std::time::Duration;

use taxel_formats::{Record, RecordFileReader};
use taxel_msgs::{force_flags, raw_flags};
use taxel_testkit::{pipeline, shm_files, Proc};

const SIM_CAL: &str = include_str!("../calibrations/sim-default.toml");

fn alive(pid: u32) -> bool {
    // SAFETY: kill(2) with signal 0 only checks that the process exists.
    unsafe { libc::kill(pid as i32, 0) == 0 }
}

fn sigkill(pid: u32) {
    // SAFETY: kill(2) on a child of the supervisor we started.
    unsafe {
        libc::kill(pid as i32, libc::SIGKILL);
    }
}

/// The pid of the latest incarnation of `name` (from the supervisor's "started"/"restarted"
/// lines).
fn current_pid(p: &mut Proc, name: &str) -> u32 {
    let out = p.output();
    out.lines()
        .filter_map(|l| {
            let i = l
                .find(&format!("started {name} pid "))
                .map(|i| i + format!("started {name} pid ").len())?;
            l[i..].split_whitespace().next()?.parse().ok()
        })
        .next_back()
        .unwrap_or_else(|| panic!("no pid for {name}:\n{out}"))
}

/// Waits until `needle` has appeared more than `before` times.
fn wait_more(p: &mut Proc, needle: &str, before: usize, limit: Duration) {
    p.wait_count(needle, before + 1, limit);
}

fn read_records(path: &Path) -> Vec<Record> {
    let mut r = RecordFileReader::open(path).expect("open recording");
    let mut out = Vec::new();
    while let Some(rec) = r.next_record() {
        out.push(rec);
    }
    out
}

/// Every discontinuity of the sequence in `seq_flags` (seq, flags) must come with `gap_bit`.
fn gaps_are_flagged(seq_flags: &[(u64, u32)], gap_bit: u32, what: &str) -> usize {
    let mut gaps = 0;
    for w in seq_flags.windows(2) {
        let ((a, _), (b, flags)) = (w[0], w[1]);
        if b != a + 1 {
            gaps += 1;
            assert!(
                flags & gap_bit != 0,
                "{what}: seq {a} -> {b} without a gap flag (flags {flags:#x})"
            );
        }
    }
    gaps
}

#[test]
fn kill_9_of_each_process_kind_is_survived_under_taxel_up() {
    let mut p = pipeline!("f");
    p.write("cal.toml", SIM_CAL);
    let pipeline = p.write(
        "pipeline.toml",
        r#"
log = "info"
[supervision]
backoff_initial_ms = 100
backoff_max_ms = 2000
max_restarts = 3
restart_window_s = 60
deadline_ms = 5
watchdog_ms = 50

[[sensor]]
id = "s0"
calibration = "cal.toml"
curvature_m1 = 40
source = { kind = "sim", rate_hz = 500 }

[[control]]
sensor = "s0"

[logger]
out = "run.taxrec"
flush_ms = 100

[[latency]]
"#,
    );
    let limit = Duration::from_secs(20);
    let up = p.spawn("up", &["up", &pipeline]);
    let up = &mut p[up];
    up.wait_for("started publisher-s0 pid", limit);
    up.wait_for("publisher ready", limit);
    up.wait_for("first no-load baseline", limit);
    let names = [
        "logger",
        "latency",
        "control-s0",
        "estimator-s0",
        "calibrator-s0",
        "publisher-s0",
    ];
    let ready = [
        "logger ready",
        "latency probe ready",
        "control ready",
        "estimator ready",
        "calibrator ready",
        "publisher ready",
    ];
    // The logger goes first: its replacement records the rest of the run in run.1.taxrec.
    for (victim, ready_line) in names.iter().zip(ready) {
        let others: Vec<(&str, u32)> = names
            .iter()
            .filter(|n| *n != victim)
            .map(|n| (*n, current_pid(up, n)))
            .collect();
        let pid = current_pid(up, victim);
        let ready_before = up.count(ready_line);
        let safe_before = up.count("safe state");
        std::thread::sleep(Duration::from_millis(700));
        sigkill(pid);
        up.wait_for(
            &format!("{victim} pid {pid} died (SIGKILL); restart 1"),
            limit,
        );
        up.wait_for(&format!("restarted {victim} pid"), limit);
        // The replacement opened the same services: nothing stale blocked it.
        wait_more(up, ready_line, ready_before, limit);
        let line = up
            .output()
            .lines()
            .find(|l| l.contains(&format!("restarted {victim} pid")))
            .map(str::to_string)
            .expect("restart line");
        assert!(
            !line.contains("cleaned stale resources of 0 dead node"),
            "the dead node of {victim} was not cleaned before the restart: {line}"
        );
        if ["calibrator-s0", "publisher-s0"].contains(victim) {
            // No fresh force samples while it is down: the control loop holds its safe state.
            wait_more(up, "safe state", safe_before, limit);
        }
        for (name, opid) in &others {
            assert!(
                alive(*opid),
                "{name} (pid {opid}) did not survive the kill of {victim}"
            );
            assert_eq!(current_pid(up, name), *opid, "{name} was restarted");
        }
    }
    // The stream resumed: the control loop runs unflagged again after the last restart.
    let status_before = up.count(" ok");
    wait_more(up, " ok", status_before, limit);
    std::thread::sleep(Duration::from_millis(500));
    up.sigint();
    let st = up.wait_exit(Duration::from_secs(30));
    let out = up.output();
    assert!(st.success(), "taxel up exited {st}:\n{out}");
    for n in names {
        assert!(
            out.lines().any(|l| l.contains(&format!("  {n} "))
                && l.contains("exited 0")
                && l.contains("restarted 1 time(s); deaths: SIGKILL")),
            "{n}: no clean exit after one restart in the summary:\n{out}"
        );
    }
    assert!(out.contains("no iceoryx2 nodes left"), "{out}");
    assert_eq!(shm_files(&p.prefix), Vec::<String>::new());

    // The first logger's file is readable up to its last flush; the replacement recorded the
    // calibrator and publisher restarts, each a flagged gap.
    let first = read_records(&p.path("run.taxrec"));
    assert!(
        !first.is_empty(),
        "nothing readable in the killed logger's file"
    );
    let second = read_records(&p.path("run.1.taxrec"));
    let raw: Vec<(u64, u32)> = second
        .iter()
        .filter_map(|r| match r {
            Record::Raw(f) => Some((f.seq, f.flags)),
            _ => None,
        })
        .collect();
    let force: Vec<(u64, u32)> = second
        .iter()
        .filter_map(|r| match r {
            Record::Force(f) => Some((f.seq, f.flags)),
            _ => None,
        })
        .collect();
    // The publisher restarted from seq 0 with GAP_BEFORE on its first frame.
    assert_eq!(
        gaps_are_flagged(&raw, raw_flags::GAP_BEFORE, "raw"),
        1,
        "one restart of the publisher"
    );
    // Force: the calibrator's downtime and the publisher restart, both flagged.
    let gaps = gaps_are_flagged(&force, force_flags::GAP_BEFORE, "force");
    assert!(gaps >= 2, "{gaps} gap(s) in the force stream");
}

#[test]
fn a_sigkilled_logger_leaves_a_recording_readable_up_to_its_last_flush() {
    let mut p = pipeline!("k");
    let rec = p.path("run.taxrec");
    let rec_s = p.arg("run.taxrec");
    let flush_ms = 100u64;
    let logger = p.logger("s0", &rec_s, &["--flush-ms", &flush_ms.to_string()]);
    // 200 Hz: the logger's 256-sample buffer covers 1.3 s of scheduling stalls on a busy
    // machine, so a gap in the file can only come from the kill.
    let publisher = p.publisher_ready("s0", &["sim", "--rate-hz", "200"]);
    std::thread::sleep(Duration::from_millis(2500));
    let t_kill = taxel_runtime::now_ns();
    p[logger].child.kill().expect("SIGKILL the logger");
    let st = p[logger].wait_exit(Duration::from_secs(10));
    assert!(!st.success());

    let mut reader = RecordFileReader::open(&rec).expect("open");
    let mut raw = Vec::new();
    let mut total = 0usize;
    while let Some(r) = reader.next_record() {
        total += 1;
        if let Record::Raw(f) = r {
            raw.push((f.seq, f.t_capture_ns));
        }
    }
    assert!(raw.len() > 300, "only {} raw records", raw.len());
    for w in raw.windows(2) {
        assert_eq!(w[1].0, w[0].0 + 1, "raw seq not consecutive");
    }
    let last_t = raw.last().map(|r| r.1).unwrap_or(0);
    let lost_ms = t_kill.saturating_sub(last_t) as f64 / 1e6;
    eprintln!(
        "{total} intact records, {} raw; the last raw frame was captured {lost_ms:.1} ms before the SIGKILL (flush every {flush_ms} ms); torn tail: {:?}",
        raw.len(),
        reader.tail().map(|t| format!("{t:?}"))
    );
    // At most one flush interval (plus scheduling margin on a shared 2-core machine) is lost.
    assert!(
        lost_ms <= flush_ms as f64 + 150.0,
        "{lost_ms:.1} ms of data lost with --flush-ms {flush_ms}"
    );

    // The stream survived the dead subscriber; a new node under the prefix cleans it up.
    let run2 = p.arg("run2.taxrec");
    let second = p.spawn_ready(
        "logger2",
        &["logger", "record", "--sensor", "s0", "--out", &run2],
        "logger ready",
    );
    std::thread::sleep(Duration::from_millis(300));
    p.stop(&[second]);
    assert!(
        read_records(&p.path("run2.taxrec"))
            .iter()
            .any(|r| matches!(r, Record::Raw(_))),
        "the publisher kept streaming after the logger was killed"
    );
    p.stop(&[publisher]);
    // No node, dead or alive, is left; the prefix's management segment is released as a
    // launcher does (the killed logger prevented iceoryx2 from removing it by itself).
    assert_eq!(
        taxel_runtime::ipc::count_nodes(&p.prefix).expect("list"),
        (0, 0)
    );
    taxel_runtime::ipc::release_prefix(&p.prefix).expect("release");
    assert_eq!(shm_files(&p.prefix), Vec::<String>::new());
}

#[test]
fn a_short_soak_with_random_kills_loses_nothing_outside_downtime() {
    let mut p = pipeline!("s");
    let (prefix, out) = (p.prefix.clone(), p.dir().display().to_string());
    let soak = p.spawn(
        "soak",
        &[
            "soak",
            "--seconds",
            "16",
            "--kill-every",
            "5",
            "--edit-every",
            "3",
            "--sensors",
            "2",
            "--rate-hz",
            "500",
            "--seed",
            "3",
            "--json",
            "--prefix",
            &prefix,
            "--out",
            &out,
        ],
    );
    p.finish(soak, Duration::from_secs(90));
    let out = p[soak].output();
    let json = out
        .lines()
        .find(|l| l.starts_with("{\"seconds\""))
        .unwrap_or_else(|| panic!("no JSON line:\n{out}"));
    let field = |k: &str| -> f64 {
        let i = json.find(&format!("\"{k}\": ")).expect(k) + k.len() + 4;
        json[i..]
            .split([',', '}'])
            .next()
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or_else(|| panic!("{k} in {json}"))
    };
    eprintln!("{json}");
    let (published, delivered, lost, downtime, probe_missed) = (
        field("published"),
        field("delivered"),
        field("lost"),
        field("lost_in_downtime"),
        field("probe_missed"),
    );
    assert!(published > 5000.0, "{json}");
    // Every published frame is accounted for: delivered, or missing behind a flagged gap
    // (lost, or during the killed calibrator's downtime), or sent but missed by the probe.
    assert_eq!(
        published,
        delivered + lost + downtime + probe_missed,
        "{json}"
    );
    // Nothing is lost outside downtime unless the machine starved the processes: then the probe
    // (polling every 2 ms with a 256-sample buffer) overflows too, and the loss is still flagged.
    if probe_missed == 0.0 && field("raw_probe_missed") == 0.0 {
        assert_eq!(lost, 0.0, "{json}");
    }
    assert!(json.contains("\"kills\": [{"), "{json}");
    assert!(field("calibration_edits") >= 2.0, "{json}");
    assert_eq!(shm_files(&prefix), Vec::<String>::new());
}

#[test]
fn a_process_that_keeps_dying_exhausts_its_restart_budget_and_the_others_keep_running() {
    let mut p = pipeline!("b");
    p.write("cal.toml", SIM_CAL);
    // s1 replays a file with a bad row: its publisher exits 2 at every start.
    p.write("bad.csv", "t_s,n0\n0.0,abc\n");
    let pipeline = p.write(
        "pipeline.toml",
        r#"
log = "info"
[supervision]
backoff_initial_ms = 100
backoff_max_ms = 300
max_restarts = 3
restart_window_s = 60

[[sensor]]
id = "s0"
calibration = "cal.toml"
curvature_m1 = 40
source = { kind = "sim", rate_hz = 200 }

[[sensor]]
id = "s1"
calibration = "cal.toml"
curvature_m1 = 40
source = { kind = "replay", file = "bad.csv" }

[[control]]
sensor = "s0"
"#,
    );
    let limit = Duration::from_secs(20);
    let up = p.spawn("up", &["up", &pipeline]);
    let prefix = p.prefix.clone();
    let up = &mut p[up];
    up.wait_for("publisher-s1 pid", limit);
    // Backoff doubles up to its maximum, then the budget runs out.
    up.wait_for("died (exit 2); restart 1 in 100 ms", limit);
    up.wait_for("died (exit 2); restart 2 in 200 ms", limit);
    up.wait_for("died (exit 2); restart 3 in 300 ms", limit);
    up.wait_for(
        "died (exit 2); restart budget exhausted (3 restarts within 60 s): it stays stopped, the others keep running",
        limit,
    );
    let out = up.output();
    assert!(
        out.contains("is not a number"),
        "the child's reason is visible:\n{out}"
    );
    let survivors: Vec<(&str, u32)> = [
        "control-s0",
        "calibrator-s0",
        "estimator-s0",
        "publisher-s0",
    ]
    .iter()
    .map(|n| (*n, current_pid(up, n)))
    .collect();
    // s0 keeps streaming: its control loop prints fresh status lines.
    let status = up.count("[s0] ");
    wait_more(up, "[s0] ", status + 1, limit);
    for (n, pid) in &survivors {
        assert!(alive(*pid), "{n} died");
        assert_eq!(current_pid(up, n), *pid, "{n} was restarted");
    }
    up.sigint();
    let st = up.wait_exit(Duration::from_secs(30));
    let out = up.output();
    assert_eq!(
        st.code(),
        Some(1),
        "a process given up on makes the exit code 1:\n{out}"
    );
    assert!(
        out.lines()
            .any(|l| l.contains("publisher-s1") && l.contains("gave up (exit 2)")),
        "{out}"
    );
    // The reason for the exit code, in one line.
    assert!(
        out.lines()
            .any(|l| l
                .starts_with("taxel up: error: 1 process(es) did not end cleanly: publisher-s1")),
        "{out}"
    );
    for (n, _) in &survivors {
        assert!(
            out.lines()
                .any(|l| l.contains(&format!("  {n} ")) && l.contains("exited 0")),
            "{n} did not exit 0:\n{out}"
        );
    }
    assert_eq!(shm_files(&prefix), Vec::<String>::new());
}

#[test]
fn a_bad_pipeline_file_is_refused_before_anything_starts() {
    let pl = pipeline!("e");
    let ps = pl.write(
        "bad.toml",
        "[[sensor]]\nid = \"s0\"\ncalibration = \"nope.toml\"\ncurvature_m1 = 1\nsource = { kind = \"sim\" }\n",
    );
    let (code, out, err) = pl.run(&["up", &ps]);
    assert_eq!(code, 2, "{out}{err}");
    assert!(
        err.contains("bad.toml") && err.contains("nope.toml"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
    pl.write("bad.toml", "[supervision]\nbackof_ms = 3\n");
    let (code, _, err) = pl.run(&["up", &ps]);
    assert_eq!(code, 2);
    assert!(err.contains("backof_ms"), "{err}");
    let (code, _, err) = pl.run(&["up", "/nonexistent/pipeline.toml"]);
    assert_eq!(code, 2);
    assert!(err.contains("/nonexistent/pipeline.toml"), "{err}");
    assert_eq!(shm_files(&pl.prefix), Vec::<String>::new());
}

#[test]
fn a_calibrator_with_dynamic_terms_restarted_after_kill_9_flags_its_state_until_it_is_known() {
    // The shipped simulator calibration with creep and hysteresis terms on both blocks.
    let terms = "creep = { tau_s = [0.5, 1.5], share = [0.02, 0.03], domain = \"force\" }\nhysteresis = { threshold_n = [0.2, 0.5], weight = [0.05, 0.05] }";
    let mut cal = String::new();
    for line in SIM_CAL.lines() {
        cal.push_str(line);
        cal.push('\n');
        if line.starts_with("range = ") {
            cal.push_str(terms);
            cal.push('\n');
        }
    }
    assert_eq!(cal.matches("hysteresis = ").count(), 2, "{cal}");
    let mut p = pipeline!("fk");
    p.write("cal.toml", &cal);
    let pipeline = p.write(
        "pipeline.toml",
        r#"
log = "info"
[supervision]
backoff_initial_ms = 100
max_restarts = 3

[[sensor]]
id = "s0"
calibration = "cal.toml"
curvature_m1 = 40
source = { kind = "sim", rate_hz = 200 }

[logger]
out = "run.taxrec"
flush_ms = 100
"#,
    );
    let limit = Duration::from_secs(20);
    let up = p.spawn("up", &["up", &pipeline]);
    let up = &mut p[up];
    up.wait_for("calibrator ready", limit);
    up.wait_for("first no-load baseline", limit);
    std::thread::sleep(Duration::from_millis(2500));
    let pid = current_pid(up, "calibrator-s0");
    sigkill(pid);
    up.wait_for("restarted calibrator-s0 pid", limit);
    up.wait_count("calibrator ready", 2, limit);
    std::thread::sleep(Duration::from_millis(4000));
    up.sigint();
    let st = up.wait_exit(Duration::from_secs(30));
    assert!(st.success(), "taxel up exited {st}:\n{}", up.output());
    let force: Vec<(u64, u32)> = read_records(&p.path("run.taxrec"))
        .iter()
        .filter_map(|r| match r {
            Record::Force(f) => Some((f.seq, f.flags)),
            _ => None,
        })
        .collect();
    let warming = |f: &u32| f & force_flags::DYNAMICS_WARMING != 0;
    // The replacement's first sample follows the gap (without a baseline until the estimate
    // reaches it: NaN forces); from its first force on its state is flagged until the force
    // has swept the plays, then never again.
    let restart = force
        .iter()
        .rposition(|(_, f)| f & force_flags::GAP_BEFORE != 0)
        .expect("the restarted calibrator's first sample");
    let after: Vec<u32> = force[restart..]
        .iter()
        .map(|x| x.1)
        .filter(|f| f & force_flags::NO_BASELINE == 0)
        .collect();
    assert!(
        !after.is_empty() && warming(&after[0]),
        "first force after the restart: {:#x?}",
        after.first()
    );
    let known = after
        .iter()
        .position(|f| !warming(f))
        .expect("the state became known after the restart");
    assert!(
        after[known..].iter().all(|f| !warming(f)),
        "flagged again later"
    );
    eprintln!(
        "after the restart: warming for {known} of {} samples",
        after.len()
    );
}
