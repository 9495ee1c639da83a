//! The shared layout of a pipeline (`layout = "shared"`): one calibrator and one estimator for
//! every sensor, one publisher for every simulated sensor and one per group of replays with the
//! same options; serial boards keep a publisher each (a board is a port of its own). Each
//! shared process gets its sensors' own settings as per-sensor lists (`--calibration
//! a.toml,b.toml`, `--seed 1,2`; an empty entry: not given for that sensor), built so that
//! every sensor runs exactly as it would in a process of its own: same services, same seeds,
//! same frames, same forces.

use std::path::{Path, PathBuf};

use crate::pipeline::{
    publisher_args, s, scenario_seed, Pipeline, Sensor, Source, STAGE_CALIBRATOR, STAGE_ESTIMATOR,
    STAGE_SOURCE,
};
use crate::supervise::ProcSpec;

/// A path as one entry of a per-sensor list (a comma would split it).
fn entry(p: &Path) -> anyhow::Result<String> {
    let t = p.display().to_string();
    anyhow::ensure!(
        !t.contains(','),
        "layout \"shared\": path {t:?} contains a comma, which a per-sensor list cannot hold"
    );
    Ok(t)
}

/// `--flag v` when every sensor has the same value, `--flag a,,c` otherwise (an empty entry:
/// not given for that sensor); nothing when no sensor has one.
fn per_sensor(args: &mut Vec<String>, flag: &str, values: &[Option<String>]) {
    if values.iter().all(Option::is_none) {
        return;
    }
    let first = &values[0];
    let text = if first.is_some() && values.iter().all(|v| v == first) {
        first.clone().unwrap_or_default()
    } else {
        values
            .iter()
            .map(|v| v.clone().unwrap_or_default())
            .collect::<Vec<_>>()
            .join(",")
    };
    args.extend([s(flag), text]);
}

/// `--flag a,b,c` with every sensor's own value (seeds: one value alone would mean "+ i").
fn each(args: &mut Vec<String>, flag: &str, values: &[Option<String>]) {
    if values.iter().all(Option::is_none) {
        return;
    }
    if let [one] = values {
        per_sensor(args, flag, std::slice::from_ref(one));
        return;
    }
    let text: Vec<String> = values
        .iter()
        .map(|v| v.clone().unwrap_or_default())
        .collect();
    args.extend([s(flag), text.join(",")]);
}

fn ids(sensors: &[&Sensor]) -> String {
    sensors
        .iter()
        .map(|x| x.id.as_str())
        .collect::<Vec<_>>()
        .join(",")
}

/// The wake-up group of a shared layout (one per prefix, as its pipeline).
pub const WAKE_GROUP: &str = "shared";

/// `--wake-group` for every process of a shared layout whose sources all notify it (sim and
/// replay publishers; a serial board's publisher serves one sensor and does not), else nothing:
/// the estimator and calibrator then listen to each sensor.
fn wake_group(all: &[&Sensor]) -> Vec<String> {
    if all.len() > 1
        && all
            .iter()
            .all(|x| matches!(x.source, Source::Sim { .. } | Source::Replay { .. }))
    {
        vec![s("--wake-group"), s(WAKE_GROUP)]
    } else {
        Vec::new()
    }
}

/// The calibrator, estimator and publishers of a shared pipeline (after the consumers).
pub fn shared_processes(p: &Pipeline) -> anyhow::Result<Vec<ProcSpec>> {
    let all: Vec<&Sensor> = p.sensors.iter().collect();
    let group = wake_group(&all);
    let mut cal = vec![s("calibrator"), s("run"), s("--sensor"), ids(&all)];
    cal.extend(group.iter().cloned());
    let files = all
        .iter()
        .map(|x| entry(&x.calibration).map(Some))
        .collect::<anyhow::Result<Vec<_>>>()?;
    per_sensor(&mut cal, "--calibration", &files);
    let mut est = vec![s("estimator"), s("run"), s("--sensor"), ids(&all)];
    est.extend(group.iter().cloned());
    let models = all
        .iter()
        .map(|x| x.model.as_deref().map(entry).transpose())
        .collect::<anyhow::Result<Vec<_>>>()?;
    per_sensor(&mut est, "--model", &models);
    let curv: Vec<Option<String>> = all.iter().map(|x| x.curvature_m1.map(s)).collect();
    per_sensor(&mut est, "--curvature-m1", &curv);
    let mut out = vec![
        ProcSpec::new("calibrator", STAGE_CALIBRATOR, cal),
        ProcSpec::new("estimator", STAGE_ESTIMATOR, est),
    ];
    let sims: Vec<&Sensor> = all
        .iter()
        .copied()
        .filter(|x| matches!(x.source, Source::Sim { .. }))
        .collect();
    if !sims.is_empty() {
        out.push(ProcSpec::new(
            "publisher-sim",
            STAGE_SOURCE,
            with_group(sim_args(&sims)?, &group),
        ));
    }
    let groups = replay_groups(&all);
    for (k, g) in groups.iter().enumerate() {
        let name = if groups.len() == 1 {
            s("publisher-replay")
        } else {
            format!("publisher-replay-{k}")
        };
        out.push(ProcSpec::new(
            &name,
            STAGE_SOURCE,
            with_group(replay_args(g)?, &group),
        ));
    }
    for x in all
        .iter()
        .filter(|x| matches!(x.source, Source::Serial { .. }))
    {
        out.push(ProcSpec::new(
            &format!("publisher-{}", x.id),
            STAGE_SOURCE,
            publisher_args(&x.id, &x.source),
        ));
    }
    Ok(out)
}

/// `publisher --sensor LIST` + `group` + the rest (the group is an option of the publisher,
/// before its source's subcommand).
fn with_group(mut args: Vec<String>, group: &[String]) -> Vec<String> {
    let at = args.len().min(3);
    args.splice(at..at, group.iter().cloned());
    args
}

/// One value per simulated sensor of one of its options.
fn sim_option(sims: &[&Sensor], f: impl Fn(&Source) -> Option<String>) -> Vec<Option<String>> {
    sims.iter().map(|x| f(&x.source)).collect()
}

/// `publisher --sensor a,b,.. sim ...` with each sensor's options.
fn sim_args(sims: &[&Sensor]) -> anyhow::Result<Vec<String>> {
    let mut a = vec![s("publisher"), s("--sensor"), ids(sims), s("sim")];
    let mut scenarios = Vec::new();
    let mut seeds = Vec::new();
    for x in sims {
        if let Source::Sim { scenario, seed, .. } = &x.source {
            scenarios.push(scenario.as_deref().map(entry).transpose()?);
            // The seed is always given per sensor: alone, a sensor uses the scenario's.
            let seed = match seed {
                Some(v) => *v,
                None => scenario_seed(scenario.as_deref())
                    .map_err(|e| anyhow::anyhow!("sensor {:?}: {e}", x.id))?,
            };
            seeds.push(Some(seed.to_string()));
        }
    }
    per_sensor(&mut a, "--scenario", &scenarios);
    let preset = sim_option(sims, |src| match src {
        Source::Sim { preset, .. } => preset.clone(),
        _ => None,
    });
    per_sensor(&mut a, "--preset", &preset);
    let build = sim_option(sims, |src| match src {
        Source::Sim { build_seed, .. } => build_seed.map(s),
        _ => None,
    });
    each(&mut a, "--build-seed", &build);
    each(&mut a, "--seed", &seeds);
    let rate = sim_option(sims, |src| match src {
        Source::Sim { rate_hz, .. } => rate_hz.map(s),
        _ => None,
    });
    per_sensor(&mut a, "--rate-hz", &rate);
    let curv = sim_option(sims, |src| match src {
        Source::Sim { curvature_m1, .. } => curvature_m1.map(s),
        _ => None,
    });
    per_sensor(&mut a, "--curvature-m1", &curv);
    Ok(a)
}

/// What replays must share to be served by one publisher: speed, loop, rows, cols.
type ReplayKey = (Option<u64>, bool, Option<usize>, Option<usize>);

fn replay_key(src: &Source) -> Option<ReplayKey> {
    match src {
        Source::Replay {
            speed,
            repeat,
            rows,
            cols,
            ..
        } => Some((speed.map(f64::to_bits), *repeat, *rows, *cols)),
        _ => None,
    }
}

/// Replay sensors grouped by their shared options, in file order.
fn replay_groups<'a>(all: &[&'a Sensor]) -> Vec<Vec<&'a Sensor>> {
    let mut groups: Vec<(ReplayKey, Vec<&Sensor>)> = Vec::new();
    for x in all {
        let Some(k) = replay_key(&x.source) else {
            continue;
        };
        match groups.iter_mut().find(|(g, _)| *g == k) {
            Some((_, v)) => v.push(x),
            None => groups.push((k, vec![x])),
        }
    }
    groups.into_iter().map(|(_, v)| v).collect()
}

/// `publisher --sensor a,b replay FILE... [options]` for one group.
fn replay_args(group: &[&Sensor]) -> anyhow::Result<Vec<String>> {
    let mut files: Vec<PathBuf> = Vec::new();
    for x in group {
        if let Source::Replay { file, .. } = &x.source {
            entry(file)?;
            files.push(file.clone());
        }
    }
    // One file for all when they are the same.
    if files.iter().all(|f| *f == files[0]) {
        files.truncate(1);
    }
    let mut a = vec![s("publisher"), s("--sensor"), ids(group), s("replay")];
    a.extend(files.iter().map(|f| f.display().to_string()));
    if let Some(Source::Replay {
        speed,
        repeat,
        rows,
        cols,
        ..
    }) = group.first().map(|x| &x.source)
    {
        if let Some(v) = speed {
            a.extend([s("--speed"), v.to_string()]);
        }
        if let Some(v) = rows {
            a.extend([s("--rows"), v.to_string()]);
        }
        if let Some(v) = cols {
            a.extend([s("--cols"), v.to_string()]);
        }
        if *repeat {
            a.push(s("--loop"));
        }
    }
    Ok(a)
}

#[cfg(test)]
mod tests {
    use crate::pipeline::Pipeline;

    const CAL: &str = include_str!("../../calibrations/sim-default.toml");

    fn load(dir: &std::path::Path, body: &str) -> anyhow::Result<Pipeline> {
        std::fs::write(dir.join("cal.toml"), CAL).expect("cal");
        std::fs::write(dir.join("cal2.toml"), CAL).expect("cal2");
        std::fs::write(dir.join("rec.csv"), "t_s,n0\n0,1\n0.01,2\n").expect("csv");
        let p = dir.join("p.toml");
        std::fs::write(&p, body).expect("pipeline");
        Pipeline::load(&p)
    }

    fn value<'a>(args: &'a [String], flag: &str) -> &'a str {
        let i = args.iter().position(|a| a == flag).expect(flag);
        &args[i + 1]
    }

    #[test]
    fn a_shared_pipeline_is_one_process_per_role_with_each_sensors_settings() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = load(
            dir.path(),
            r#"
layout = "shared"
[[sensor]]
id = "p"
count = 3
calibration = "cal.toml"
curvature_m1 = 40
source = { kind = "sim", seed = 5, build_seed = 100, rate_hz = 500 }
[[sensor]]
id = "x"
calibration = "cal2.toml"
curvature_m1 = 10
source = { kind = "sim" }
[[sensor]]
id = "r"
calibration = "cal.toml"
curvature_m1 = 0
source = { kind = "replay", file = "rec.csv", loop = true }
[[sensor]]
id = "q"
calibration = "cal.toml"
curvature_m1 = 0
source = { kind = "serial", port = "/dev/ttyX" }
"#,
        )
        .expect("load");
        let procs = p.processes().expect("processes");
        let names: Vec<&str> = procs.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "calibrator",
                "estimator",
                "publisher-sim",
                "publisher-replay",
                "publisher-q"
            ]
        );
        let cal = &procs[0].args;
        assert_eq!(value(cal, "--sensor"), "p0,p1,p2,x,r,q");
        let c = dir.path().join("cal.toml").display().to_string();
        let c2 = dir.path().join("cal2.toml").display().to_string();
        assert_eq!(
            value(cal, "--calibration"),
            [&c, &c, &c, &c2, &c, &c].map(|x| x.as_str()).join(",")
        );
        assert_eq!(value(&procs[1].args, "--curvature-m1"), "40,40,40,10,0,0");
        let sim = &procs[2].args;
        assert_eq!(value(sim, "--sensor"), "p0,p1,p2,x");
        // Explicit per sensor: the count's seeds + k, x alone would use the demo scenario's (1).
        assert_eq!(value(sim, "--seed"), "5,6,7,1");
        assert_eq!(value(sim, "--build-seed"), "100,101,102,");
        assert_eq!(value(sim, "--rate-hz"), "500,500,500,");
        let replay = &procs[3].args;
        assert_eq!(value(replay, "--sensor"), "r");
        assert!(replay.contains(&"--loop".to_string()), "{replay:?}");
        assert_eq!(value(&procs[4].args, "--sensor"), "q");
    }

    #[test]
    fn a_shared_layout_of_sim_and_replay_sources_wakes_by_group_and_one_with_a_board_does_not() {
        let dir = tempfile::tempdir().expect("tempdir");
        let body = |extra: &str| {
            format!(
                r#"
layout = "shared"
[[sensor]]
id = "p"
count = 3
calibration = "cal.toml"
curvature_m1 = 40
source = {{ kind = "sim" }}
[[sensor]]
id = "r"
calibration = "cal.toml"
curvature_m1 = 0
source = {{ kind = "replay", file = "rec.csv" }}
{extra}
"#
            )
        };
        let p = load(dir.path(), &body("")).expect("pipeline");
        let procs = super::shared_processes(&p).expect("processes");
        for proc in &procs {
            assert_eq!(
                value(&proc.args, "--wake-group"),
                super::WAKE_GROUP,
                "{proc:?}"
            );
        }
        // The group is the publisher's option, before its source's subcommand.
        let sim = &procs[2].args;
        let at = |f: &str| sim.iter().position(|a| a == f).expect(f);
        assert!(at("--wake-group") < at("sim"), "{sim:?}");
        let board = r#"
[[sensor]]
id = "q"
calibration = "cal.toml"
curvature_m1 = 0
source = { kind = "serial", port = "/dev/null" }
"#;
        let p = load(dir.path(), &body(board)).expect("pipeline");
        let procs = super::shared_processes(&p).expect("processes");
        for proc in &procs {
            assert!(!proc.args.contains(&"--wake-group".to_string()), "{proc:?}");
        }
    }

    #[test]
    fn counts_and_layouts_are_checked() {
        let dir = tempfile::tempdir().expect("tempdir");
        for (body, needle) in [
            ("layout = \"skin\"\n[[sensor]]\nid = \"a\"\ncalibration = \"cal.toml\"\ncurvature_m1 = 1\nsource = { kind = \"sim\" }\n", "skin"),
            ("[[sensor]]\nid = \"a\"\ncount = 0\ncalibration = \"cal.toml\"\ncurvature_m1 = 1\nsource = { kind = \"sim\" }\n", "count must be 1..="),
            ("[[sensor]]\nid = \"a\"\ncount = 2\ncalibration = \"cal.toml\"\ncurvature_m1 = 1\nsource = { kind = \"serial\", port = \"/dev/x\" }\n", "a serial board is one sensor"),
            ("[[sensor]]\nid = \"a\"\ncount = 2\ncalibration = \"cal.toml\"\ncurvature_m1 = 1\nsource = { kind = \"sim\" }\n[[sensor]]\nid = \"a1\"\ncalibration = \"cal.toml\"\ncurvature_m1 = 1\nsource = { kind = \"sim\" }\n", "duplicate id"),
        ] {
            let e = format!("{:#}", load(dir.path(), body).expect_err(body));
            assert!(e.contains(needle), "{needle:?} not in {e}");
            assert!(!e.contains('\n'), "{e}");
        }
        // The same file in the per-sensor layout: three publishers with seeds 5, 6, 7.
        let p = load(
            dir.path(),
            "[[sensor]]\nid = \"p\"\ncount = 3\ncalibration = \"cal.toml\"\ncurvature_m1 = 1\nsource = { kind = \"sim\", seed = 5 }\n",
        )
        .expect("load");
        let procs = p.processes().expect("processes");
        let seeds: Vec<&str> = procs
            .iter()
            .filter(|p| p.name.starts_with("publisher-"))
            .map(|p| value(&p.args, "--seed"))
            .collect();
        assert_eq!(seeds, ["5", "6", "7"]);
    }

    #[test]
    fn realtime_goes_to_every_hot_process_as_its_own_option() {
        let dir = tempfile::tempdir().expect("tempdir");
        let body = |layout: &str, realtime: &str| {
            format!(
                "layout = \"{layout}\"\n{realtime}\n[[latency]]\n[[control]]\nsensor = \"p0\"\n\
                 [[sensor]]\nid = \"p\"\ncount = 2\ncalibration = \"cal.toml\"\n\
                 curvature_m1 = 40\nsource = {{ kind = \"sim\" }}\n"
            )
        };
        for layout in ["shared", "per-sensor"] {
            let p = load(dir.path(), &body(layout, "realtime = 20")).expect(layout);
            let procs = p.processes().expect("processes");
            assert!(procs.len() >= 5, "{procs:?}");
            for proc in &procs {
                assert_eq!(value(&proc.args, "--realtime"), "20", "{proc:?}");
                let at = proc.args.iter().position(|a| a == "--realtime");
                let sub = proc.args.iter().position(|a| a == "sim" || a == "run");
                match (proc.args[0].as_str(), sub) {
                    ("publisher", Some(sub)) => assert!(at < Some(sub), "{proc:?}"),
                    (_, Some(run)) => assert!(at > Some(run), "{proc:?}"),
                    _ => {}
                }
            }
            let p = load(dir.path(), &body(layout, "")).expect(layout);
            let procs = p.processes().expect("processes");
            assert!(procs
                .iter()
                .all(|p| !p.args.contains(&"--realtime".to_string())));
            let e = format!(
                "{:#}",
                load(dir.path(), &body(layout, "realtime = 0")).expect_err("0")
            );
            assert!(e.contains("realtime = 0: must be 1 to 99"), "{e}");
        }
    }
}
