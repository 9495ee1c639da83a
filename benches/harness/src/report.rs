//! The report of a bench run: `bench.md` (a table per case), `bench.json` (the same numbers,
//! one object) and the percentile plot `latency.{svg,png}`.

use std::path::Path;

use taxel_plot::{Chart, Mark, Series};
use taxel_runtime::process::{Failure, ResultExt};

use crate::CaseResult;

/// Writes the report of `cases` into `out`; returns the Markdown table and the JSON object.
pub(crate) fn write(
    out: &Path,
    rate: f64,
    secs: f64,
    cases: &[CaseResult],
) -> Result<(String, String), Failure> {
    let m = machine();
    let mut md = format!(
        "# taxel bench\n\n{m}; {rate} Hz, RawFrame payload ({} bytes), {secs} s per case, separate processes. Age = receive time - capture time (CLOCK_MONOTONIC); force paths are two hops.\n\n| case | rate (Hz) | received | dropped | p50 (us) | p90 (us) | p99 (us) | p99.9 (us) | max (us) | CPU of waiting processes (% core) | busiest process (% core) |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        crate::peers::MSG
    );
    for c in cases {
        md.push_str(&format!(
            "| {} | {} | {} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} |\n",
            c.case,
            c.rate_hz,
            c.received,
            c.dropped,
            c.p50,
            c.p90,
            c.p99,
            c.p999,
            c.max,
            c.cpu_pct,
            c.cpu_pct_max_process
        ));
    }
    md.push_str(&roles_table(cases));
    md.push_str(&platform_lines(cases));
    let cases_json: Vec<String> = cases
        .iter()
        .map(|c| {
            let num = |v: f64| if v.is_finite() { format!("{v:.1}") } else { "null".into() };
            format!(
                "{{\"case\": \"{}\", \"rate_hz\": {}, \"received\": {}, \"p50_us\": {}, \"p90_us\": {}, \"p99_us\": {}, \"p999_us\": {}, \"max_us\": {}, \"dropped\": {}, \"cpu_pct\": {}, \"cpu_pct_max_process\": {}",
                c.case,
                c.rate_hz,
                num(c.received),
                num(c.p50),
                num(c.p90),
                num(c.p99),
                num(c.p999),
                num(c.max),
                num(c.dropped),
                num(c.cpu_pct),
                num(c.cpu_pct_max_process)
            ) + &skin_json(c)
        })
        .collect();
    let json = format!(
        "{{\"machine\": \"{}\", \"rate_hz\": {rate}, \"seconds_per_case\": {secs}, \"cases\": [{}]}}",
        m.replace('"', "'"),
        cases_json.join(", ")
    );
    for (name, text) in [("bench.md", &md), ("bench.json", &json)] {
        let p = out.join(name);
        std::fs::write(&p, text)
            .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
            .runtime_err()?;
    }
    let series: Vec<Series> = cases
        .iter()
        .map(|c| Series {
            name: c.case.clone(),
            points: vec![(50.0, c.p50), (90.0, c.p90), (99.0, c.p99), (99.9, c.p999)],
            mark: Mark::LinePoints,
        })
        .collect();
    for ext in ["svg", "png"] {
        taxel_plot::write(
            &out.join(format!("latency.{ext}")),
            &Chart {
                title: format!("one-way latency percentiles at {rate} Hz"),
                x_label: "percentile".into(),
                y_label: "latency (us)".into(),
                series: series.clone(),
                x_range: Some((45.0, 100.5)),
                y_range: None,
            },
        )
        .runtime_err()?;
    }
    Ok((md, json))
}

fn machine() -> String {
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| {
            c.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let kernel = std::fs::read_to_string("/proc/sys/kernel/osrelease")
        .map(|k| k.trim().to_string())
        .unwrap_or_default();
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    format!("{model}, {cores} cores, Linux {kernel}")
}

/// The many-sensor fields of a case's JSON object (`sensors`, `expected`, `roles`, `trials`)
/// and its closing brace.
fn skin_json(c: &CaseResult) -> String {
    let num = |v: f64| {
        if v.is_finite() {
            format!("{v:.1}")
        } else {
            "null".into()
        }
    };
    if c.roles.is_empty() && c.sensors == 0 {
        return "}".into();
    }
    let roles: Vec<String> = c
        .roles
        .iter()
        .map(|r| {
            format!(
                "{{\"role\": \"{}\", \"processes\": {}, \"cpu_pct\": {}, \"cpu_pct_max_process\": {}, \"rss_mb\": {}, \"rss_mb_max_process\": {}, \"rss_warm_mb\": {}, \"private_warm_mb\": {}, \"private_mb\": {}}}",
                r.role,
                r.processes,
                num(r.cpu_pct),
                num(r.cpu_pct_max_process),
                num(r.rss_mb),
                num(r.rss_mb_max_process),
                num(r.rss_warm_mb),
                num(r.private_warm_mb),
                num(r.private_mb)
            )
        })
        .collect();
    let trials: Vec<String> = c
        .trials
        .iter()
        .map(|(n, ok, what)| {
            format!(
                "{{\"sensors\": {n}, \"zero_loss\": {ok}, \"seen\": \"{}\"}}",
                what.replace(['"', '\\'], "'")
            )
        })
        .collect();
    let platform = match &c.platform {
        Some(l) => format!(
            ", \"platform_wakeup\": {{\"priority\": {}, \"wakeups\": {}, \"p50_us\": {}, \"p99_us\": {}, \"p999_us\": {}, \"max_us\": {}, \"over_1ms\": {}}}",
            l.priority,
            l.wakeups,
            num(l.p50_us),
            num(l.p99_us),
            num(l.p999_us),
            num(l.max_us),
            l.over_1ms
        ),
        None => String::new(),
    };
    format!(
        ", \"sensors\": {}, \"expected\": {}, \"roles\": [{}], \"trials\": [{}]{platform}}}",
        c.sensors,
        num(c.expected),
        roles.join(", "),
        trials.join(", ")
    )
}

/// The per-role table of the skin cases (empty when no case has roles).
fn roles_table(cases: &[CaseResult]) -> String {
    let mut md = String::new();
    for c in cases.iter().filter(|c| !c.roles.is_empty()) {
        if md.is_empty() {
            md.push_str("\nPer role (CPU over the probe's window; resident memory, VmRSS, and private memory, RssAnon, after a fifth of the window and at its end):\n\n| case | sensors | role | processes | CPU, all (% core) | CPU, busiest process (% core) | RSS after warm-up, all (MB) | RSS at end, all (MB) | RSS, largest process (MB) | private after warm-up, all (MB) | private at end, all (MB) |\n|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|\n");
        }
        for r in &c.roles {
            md.push_str(&format!(
                "| {} | {} | {} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} |\n",
                c.case,
                c.sensors,
                r.role,
                r.processes,
                r.cpu_pct,
                r.cpu_pct_max_process,
                r.rss_warm_mb,
                r.rss_mb,
                r.rss_mb_max_process,
                r.private_warm_mb,
                r.private_mb
            ));
        }
    }
    for c in cases.iter().filter(|c| !c.trials.is_empty()) {
        md.push_str(&format!("\n{} runs:\n\n", c.case));
        for (n, ok, what) in &c.trials {
            md.push_str(&format!(
                "- {n} sensors: {}: {what}\n",
                if *ok { "no loss" } else { "loss" }
            ));
        }
    }
    md
}

/// The platform's wake-up lateness beside each real-time case, a line each (empty when none).
fn platform_lines(cases: &[CaseResult]) -> String {
    let mut md = String::new();
    for c in cases {
        if let Some(l) = &c.platform {
            md.push_str(&format!(
                "\n{}: the platform beside it (a thread waking every {} ms on absolute deadlines at {}): {} wake-ups, lateness p50 {:.0} us, p99 {:.0} us, p99.9 {:.0} us, max {:.0} us; {} ({:.2} %) more than 1 ms late. A frame's age spans four wake-ups (publisher, estimator, calibrator, probe).\n",
                c.case,
                crate::platform::PERIOD_NS / 1_000_000,
                if l.priority > 0 {
                    format!("SCHED_FIFO {}", l.priority)
                } else {
                    "normal priority: real-time refused".to_string()
                },
                l.wakeups,
                l.p50_us,
                l.p99_us,
                l.p999_us,
                l.max_us,
                l.over_1ms,
                l.over_1ms_pct()
            ));
        }
    }
    md
}
