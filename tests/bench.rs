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
    for f in ["bench.md", "bench.json", "latency.svg", "latency.png"] {
        assert!(p.path(f).exists(), "{f}");
    }
}
