//! `taxel bench --json` prints one JSON object with the documented cases and fields, and writes
//! its table and plots. (Speed is reported, never asserted: only the shape and zero loss.)

use taxel_testkit::pipeline;

#[test]
fn bench_json_has_every_case() {
    let p = pipeline!("b");
    let out = p.dir().display().to_string();
    let (code, stdout, err) = p.run(&["bench", "--json", "--seconds", "0.6", "--out", &out]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 1, "one JSON object: {stdout}");
    let j = lines[0];
    assert!(j.starts_with("{\"machine\": \""), "{j}");
    for case in [
        "iox2_busy_1hop",
        "iox2_event_1hop",
        "uds_block_1hop",
        "uds_spin_1hop",
        "tcp_block_1hop",
        "uds_block_2hop",
        "timer_wake_overshoot",
        "force_path_event",
        "force_path_dynamic_event",
        "force_path_busy",
        "force_path_adaptive",
    ] {
        let at = j
            .find(&format!("\"case\": \"{case}\""))
            .unwrap_or_else(|| panic!("{case} missing: {j}"));
        let obj = &j[at..at + j[at..].find('}').expect("end of case")];
        for key in [
            "\"p50_us\": ",
            "\"p99_us\": ",
            "\"p999_us\": ",
            "\"max_us\": ",
            "\"dropped\": 0",
            "\"cpu_pct\": ",
        ] {
            assert!(obj.contains(key), "{case}: {key} in {obj}");
        }
        assert!(
            !obj.contains("\"received\": 0,"),
            "{case} received nothing: {obj}"
        );
    }
    // The shared skin reports every role's CPU and memory; the heavy skins only run when
    // named (speed and loss are measured, not asserted here).
    let at = j
        .find("\"case\": \"skin_64_sensors\"")
        .unwrap_or_else(|| panic!("skin_64_sensors missing: {j}"));
    let skin = &j[at..];
    assert!(skin.contains("\"sensors\": 64"), "{skin}");
    for role in ["publisher", "estimator", "calibrator"] {
        let r = skin
            .find(&format!("{{\"role\": \"{role}\", \"processes\": 1, "))
            .unwrap_or_else(|| panic!("{role} missing: {skin}"));
        assert!(skin[r..].contains("\"rss_mb\": "), "{skin}");
    }
    for heavy in [
        "skin_64_sensors_per_process",
        "skin_max_sensors",
        "skin_64_sensors_realtime",
    ] {
        assert!(
            !j.contains(&format!("\"case\": \"{heavy}\"")),
            "{heavy} ran"
        );
    }
    for f in ["bench.md", "bench.json", "latency.svg", "latency.png"] {
        assert!(p.path(f).exists(), "{f}");
    }
}

#[test]
fn bench_writes_into_a_fresh_temp_dir_unless_told_and_never_into_the_current_one() {
    let p = pipeline!("bo");
    let cwd = p.path("cwd");
    std::fs::create_dir(&cwd).expect("cwd");
    let out = p
        .command(&[
            "bench",
            "--json",
            "--cases",
            "timer_wake_overshoot",
            "--seconds",
            "0.2",
        ])
        .current_dir(&cwd)
        .stdin(std::process::Stdio::null())
        .output()
        .expect("run taxel bench");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert_eq!(
        std::fs::read_dir(&cwd).expect("cwd").count(),
        0,
        "taxel bench wrote into the current directory"
    );
    // It says where it writes, on stderr (stdout stays one JSON object).
    let dir = err
        .lines()
        .find_map(|l| l.strip_prefix("taxel bench: writing to "))
        .and_then(|l| l.split(" (--out").next())
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| panic!("no output directory named:\n{err}"));
    assert!(dir.starts_with(std::env::temp_dir()), "{}", dir.display());
    let written = dir.join("bench.json").exists();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(written, "bench.json not in {}", dir.display());
    assert_eq!(String::from_utf8_lossy(&out.stdout).lines().count(), 1);

    // An unknown case is bad input: exit 2, one line naming it.
    let (code, _, err) = p.run(&["bench", "--cases", "nosuch", "--out", &p.arg("b")]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--cases: unknown case \"nosuch\""), "{err}");
}
