//! The paper's Table I, reproduced on the simulator: one sensor build is calibrated on
//! cylindrical fixtures the way the paper collected its data (0-80 1/m in ten steps plus
//! 100 1/m, robot presses 1-20 N on the central block), then held on five everyday objects
//! (gum box 0, tuna can 12.03, energy drink 17.54, rubbing alcohol 25, ping-pong ball 50 1/m)
//! by a human hand with tremor at 2, 4, 6 and 8 N plus natural holding. Each object recording
//! is a held-out session (its own noise and mounting). The flat and curvature-aware
//! calibrations are fitted with the same code as `taxel calibrator fit`, and every recording
//! goes through `taxel calibrator eval`'s protocol.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use taxel_estimator::model::CurvatureModel;
use taxel_formats::csv::{Columns, Row};
use taxel_formats::{Recording, RecordingWriter};
use taxel_plot::{Chart, Mark, Series};
use taxel_sim::{Mounting, Scenario, SensorModel, Simulator, Step, Tremor};

use crate::protocol::{evaluate, Headline, LevelResult, Report};
use taxel_calibrator::fit::{fit_calibration, FitOptions};

/// The paper's objects and their curvature (1/m).
pub const OBJECTS: [(&str, f64); 5] = [
    ("gum box", 0.0),
    ("tuna can", 12.03),
    ("energy drink", 17.54),
    ("rubbing alcohol", 25.0),
    ("ping-pong ball", 50.0),
];
/// The paper's force levels (N).
pub const LEVELS: [f64; 4] = [2.0, 4.0, 6.0, 8.0];
/// The paper's Table I averages (N): flat, curvature-aware.
pub const PAPER_AVERAGES_N: (f64, f64) = (2.79, 0.80);

/// Fixture calibration scenario: fixtures 0-80 1/m (ten) and 100 1/m, presses 1-20 N.
pub fn fixture_scenario(seed: u64) -> Scenario {
    let mut fixtures: Vec<f64> = (0..10).map(|i| 80.0 * i as f64 / 9.0).collect();
    fixtures.push(100.0);
    let mut steps = vec![Step::Rest { duration_s: 1.0 }];
    for (i, &c) in fixtures.iter().enumerate() {
        if i > 0 {
            steps.push(Step::Mount {
                curvature_m1: c,
                rotation_deg: 0,
                flipped: false,
                rest_s: 1.0,
            });
        }
        for f in [1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 12.0, 15.0, 18.0, 20.0] {
            steps.push(Step::Press {
                force_n: f,
                ramp_s: 0.5,
                hold_s: 1.0,
                release_s: 0.3,
                rest_s: 0.5,
            });
        }
    }
    Scenario {
        name: "fixture-calibration".into(),
        rate_hz: 100.0,
        seed,
        mounting: Mounting {
            curvature_m1: fixtures[0],
            ..Mounting::default()
        },
        steps,
        ..Scenario::default()
    }
}

/// A hand holding the sensor against an object: a no-load start, the four levels held for
/// 4 s each with tremor, then natural holding (slowly varying force).
pub fn object_scenario(curvature_m1: f64, seed: u64) -> Scenario {
    let mut steps = vec![Step::Rest { duration_s: 2.0 }];
    for f in LEVELS {
        steps.push(Step::Press {
            force_n: f,
            ramp_s: 0.8,
            hold_s: 4.0,
            release_s: 0.5,
            rest_s: 1.5,
        });
    }
    for (f, d) in [(5.0, 2.0), (3.0, 1.5), (6.5, 2.0), (4.0, 1.5), (0.0, 1.0)] {
        steps.push(Step::Ramp {
            force_n: f,
            duration_s: d,
        });
    }
    steps.push(Step::Rest { duration_s: 1.0 });
    Scenario {
        name: "object-hold".into(),
        rate_hz: 100.0,
        seed,
        mounting: Mounting {
            curvature_m1,
            rotation_deg: 90 * (seed % 4) as u32,
            flipped: seed % 2 == 1,
        },
        tremor: Some(Tremor {
            amplitude_n: 0.08,
            freq_hz: 9.0,
        }),
        steps,
        ..Scenario::default()
    }
}

/// Simulates `scenario` on `model` into a recording CSV with the reference columns.
pub fn simulate(
    model: &SensorModel,
    scenario: &Scenario,
    path: &Path,
) -> anyhow::Result<Recording> {
    let mut sim = Simulator::new(model, scenario)?;
    let n = model.rows * model.cols;
    let cols = Columns {
        force_n: true,
        curvature_m1: true,
        trial: true,
        ..Columns::default()
    };
    let mut w = RecordingWriter::create(path, n, cols)?;
    let frames = sim
        .frames_in_scenario()
        .ok_or_else(|| anyhow::anyhow!("scenario repeats"))?;
    let mut out = vec![0f32; n];
    let mut nodes = vec![0f64; n];
    for _ in 0..frames {
        let t = sim.step(&mut out);
        for (d, v) in nodes.iter_mut().zip(&out) {
            *d = *v as f64;
        }
        w.write_row(&Row {
            t_s: t.t_s,
            nodes: &nodes,
            force_n: t.force_n,
            curvature_m1: t.curvature_m1,
            trial: t.trial as i64,
            ..Row::default()
        })?;
    }
    w.finish()?;
    Ok(Recording::read(path)?)
}

/// Everything the reproduction produced.
pub struct Table1 {
    pub reports: Vec<(String, f64, Report)>,
    pub markdown: String,
    pub files: Vec<PathBuf>,
}

/// Runs the whole reproduction into `out`: data, calibrations, evaluations, table and plots.
pub fn run(
    out: &Path,
    model: &CurvatureModel,
    sensor: &SensorModel,
    seed: u64,
    mut progress: impl FnMut(&str),
) -> anyhow::Result<Table1> {
    std::fs::create_dir_all(out)?;
    let mut files = Vec::new();
    progress("fixture calibration data");
    let fixtures_path = out.join("fixtures.csv.gz");
    let fixtures = simulate(sensor, &fixture_scenario(seed), &fixtures_path)?;
    files.push(fixtures_path);
    let opts = |flat: bool, id: &str| FitOptions {
        rows: Some(sensor.rows),
        cols: Some(sensor.cols),
        ..FitOptions::new(id, flat)
    };
    progress("fitting the calibrations");
    let (curve_text, curve, curve_report) = fit_calibration(
        std::slice::from_ref(&fixtures),
        &opts(false, "table1-curvature"),
    )?;
    let (flat_text, flat, flat_report) =
        fit_calibration(std::slice::from_ref(&fixtures), &opts(true, "table1-flat"))?;
    for (name, text) in [("curvature.toml", &curve_text), ("flat.toml", &flat_text)] {
        let p = out.join(name);
        std::fs::write(&p, text)?;
        files.push(p);
    }
    let mut reports = Vec::new();
    for (i, (name, c)) in OBJECTS.iter().enumerate() {
        progress(name);
        let p = out.join(format!("object-{}.csv.gz", name.replace(' ', "-")));
        let rec = simulate(sensor, &object_scenario(*c, seed * 100 + 10 + i as u64), &p)?;
        files.push(p);
        let g = rec.geometry(Some(sensor.rows), Some(sensor.cols))?;
        let r = evaluate(&rec, g, model, &curve, &flat, &LEVELS)?;
        reports.push((name.to_string(), *c, r));
    }
    let markdown = markdown(&reports, &curve_report, &flat_report);
    let md = out.join("table1.md");
    std::fs::write(&md, &markdown)?;
    files.push(md);
    for ext in ["svg", "png"] {
        let p = out.join(format!("error-vs-curvature.{ext}"));
        error_plot(&p, &reports)?;
        files.push(p);
        let p = out.join(format!("calibration-surface.{ext}"));
        taxel_calibrator::plots::surface(&p, &curve)?;
        files.push(p);
    }
    Ok(Table1 {
        reports,
        markdown,
        files,
    })
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |a, x| (a.0 + x, a.1 + 1));
    s / n.max(1) as f64
}

/// Means over every scored (object, level) cell of the headline (the whole array): flat,
/// curvature-aware, and the worst curvature-aware cell (N).
pub fn averages(reports: &[(String, f64, Report)]) -> (f64, f64, f64) {
    cell_averages(reports.iter().map(|(_, _, r)| r.levels.as_slice()))
}

/// [`averages`] of one block's scores (the whole array or the central block).
pub fn block_averages(reports: &[(String, f64, Report)], block: Headline) -> (f64, f64, f64) {
    cell_averages(reports.iter().filter_map(move |(_, _, r)| {
        r.blocks
            .iter()
            .find(|b| b.block == block)
            .map(|b| b.levels.as_slice())
    }))
}

fn cell_averages<'a>(levels: impl Iterator<Item = &'a [LevelResult]> + Clone) -> (f64, f64, f64) {
    let scored = |flat: bool| {
        levels
            .clone()
            .flat_map(|l| l.iter().filter(|l| l.n > 0))
            .map(move |l| if flat { l.flat_mae_n } else { l.curve_mae_n })
    };
    (
        mean(scored(true)),
        mean(scored(false)),
        scored(false).fold(0.0, f64::max),
    )
}

/// The table in the paper's layout (objects x levels, flat vs curvature-aware MAE +- SD).
pub fn markdown(
    reports: &[(String, f64, Report)],
    curve_fit: &[String],
    flat_fit: &[String],
) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Table I, reproduced on the simulator\n");
    let _ = writeln!(
        s,
        "Mean absolute force error +- SD (N) within the windows where the reference force stays within +-0.2 N of each level for at least 1 s. Curvature is predicted from each recording's no-load start.\n"
    );
    let _ = writeln!(s, "| object | curvature (1/m) | predicted (1/m) | calibration | 2 N | 4 N | 6 N | 8 N | mean |");
    let _ = writeln!(s, "|---|---:|---:|---|---:|---:|---:|---:|---:|");
    let cell = |m: f64, sd: f64, n: usize| {
        if n == 0 {
            "n/a".to_string()
        } else {
            format!("{m:.2} +- {sd:.2}")
        }
    };
    for (name, c, r) in reports {
        for (label, flat) in [("flat", true), ("curvature-aware", false)] {
            let cells: Vec<String> = r
                .levels
                .iter()
                .map(|l| {
                    if flat {
                        cell(l.flat_mae_n, l.flat_sd_n, l.n)
                    } else {
                        cell(l.curve_mae_n, l.curve_sd_n, l.n)
                    }
                })
                .collect();
            let m = mean(r.levels.iter().filter(|l| l.n > 0).map(|l| {
                if flat {
                    l.flat_mae_n
                } else {
                    l.curve_mae_n
                }
            }));
            let _ = writeln!(
                s,
                "| {name} | {c:.2} | {:.1} | {label} | {} | {m:.2} |",
                r.curvature_pred_m1,
                cells.join(" | ")
            );
        }
    }
    let (flat_avg, curve_avg, worst) = averages(reports);
    let _ = writeln!(
        s,
        "\n| average over the 20 cells | flat | curvature-aware | worst curvature-aware cell |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|");
    let _ = writeln!(
        s,
        "| taxel (this run) | {flat_avg:.2} N | {curve_avg:.2} N | {worst:.2} N |"
    );
    let _ = writeln!(
        s,
        "| paper (Zhong et al. 2025, Table I) | {:.2} N | {:.2} N | |",
        PAPER_AVERAGES_N.0, PAPER_AVERAGES_N.1
    );
    let _ = writeln!(s, "\nCurvature-aware calibration fit:\n");
    for l in curve_fit {
        let _ = writeln!(s, "- {l}");
    }
    let _ = writeln!(s, "\nFlat calibration fit:\n");
    for l in flat_fit {
        let _ = writeln!(s, "- {l}");
    }
    s
}

fn error_plot(path: &Path, reports: &[(String, f64, Report)]) -> anyhow::Result<()> {
    let series = |flat: bool, name: &str| Series {
        name: name.into(),
        points: reports
            .iter()
            .map(|(_, c, r)| {
                (
                    *c,
                    mean(r.levels.iter().filter(|l| l.n > 0).map(|l| {
                        if flat {
                            l.flat_mae_n
                        } else {
                            l.curve_mae_n
                        }
                    })),
                )
            })
            .collect(),
        mark: Mark::LinePoints,
    };
    taxel_plot::write(
        path,
        &Chart {
            title: "force error vs object curvature (mean over 2, 4, 6, 8 N)".into(),
            x_label: "object curvature (1/m)".into(),
            y_label: "mean absolute force error (N)".into(),
            series: vec![
                series(true, "flat calibration"),
                series(false, "curvature-aware calibration"),
            ],
            x_range: None,
            y_range: None,
        },
    )
}
