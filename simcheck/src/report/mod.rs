//! What the diagnosis writes: report.json (for programs), report.md (findings first, then the
//! evidence and plots), SIM.toml (the start model extended with the fitted base and effects,
//! loadable by taxel-sim and the publisher's sim source), and the figures (PNG and SVG): the
//! recording against the simulation before and after, and the residual against the variable
//! that located each effect, before and after.

mod figures;
mod markdown;
mod simtoml;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context as _;
use serde_json::json;
use taxel_sim::SensorModel;

use crate::data::Dataset;
use crate::diagnose::Diagnosis;
use crate::effects::Config;
use crate::law::Law;
pub use simtoml::{extended_model, resimulate};

/// Writes every output into `dir`; returns the list of files.
pub fn write_all(
    dir: &Path,
    ds: &Dataset,
    start: &SensorModel,
    d: &Diagnosis,
    notes_in: &[String],
) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut files = Vec::new();
    let (model, mut notes) = extended_model(start, ds, d);
    notes.extend(notes_in.iter().cloned());
    if d.virgin_rest_shared {
        notes.push(
            "held out on folds that share the rest before the first press (a model that \
             remembers the sensor's state before the recording joined: the largest load so \
             far, or a loop's start state): the base's held-out error too"
                .into(),
        );
    }
    if d.unexplained_on_peak_folds {
        notes.push(
            "the selection's folds left one under 90 % of the peak load: each node named \
             `unexplained` was checked on folds that share the peak too, and kept only if \
             they show it"
                .into(),
        );
    }
    files.push(write_sim_toml(dir, ds, d, &model)?);
    // The latent temperature, when thermal drift was inferred without a column.
    let latent_temp: Option<Vec<f64>> = d
        .latent_m
        .as_ref()
        .map(|m| m.iter().map(|f| 25.0 + (f - 1.0) / -0.003).collect());
    if let Some(lt) = &latent_temp {
        let p = dir.join("latent_temperature.csv");
        let mut s = String::from("t_s,temp_c\n");
        for (t, v) in ds.t.iter().zip(lt) {
            let _ = writeln!(s, "{t},{v:.4}");
        }
        std::fs::write(&p, s).with_context(|| format!("cannot write {}", p.display()))?;
        files.push(p);
    }
    // The check that SIM.toml reproduces the fit when taxel-sim runs it.
    let (resim_rmse, resim_pred) = resimulate(&model, ds, latent_temp.as_deref());
    let figures = figures::figures(dir, ds, d, &resim_pred)?;
    for f in &figures {
        files.push(dir.join(f));
    }
    let j = report_json(ds, d, &notes, &figures, resim_rmse);
    let jp = dir.join("report.json");
    std::fs::write(&jp, serde_json::to_string_pretty(&j)? + "\n")
        .with_context(|| format!("cannot write {}", jp.display()))?;
    files.push(jp);
    let mp = dir.join("report.md");
    std::fs::write(&mp, markdown::markdown(ds, d, &notes, &figures, resim_rmse))
        .with_context(|| format!("cannot write {}", mp.display()))?;
    files.push(mp);
    Ok(files)
}

/// SIM.toml, with a header naming the recording, the verdict and the effects.
fn write_sim_toml(
    dir: &Path,
    ds: &Dataset,
    d: &Diagnosis,
    model: &SensorModel,
) -> anyhow::Result<PathBuf> {
    let sim_path = dir.join("SIM.toml");
    let header = format!(
        "# Written by taxel-simcheck diagnose from {}\n# verdict: {}; effects: {}\n",
        ds.path,
        d.verdict,
        if d.effects.is_empty() {
            "none".to_string()
        } else {
            d.effects
                .iter()
                .map(|e| e.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        }
    );
    std::fs::write(&sim_path, header + &model.to_toml_string())
        .with_context(|| format!("cannot write {}", sim_path.display()))?;
    Ok(sim_path)
}

/// report.json's content.
fn report_json(
    ds: &Dataset,
    d: &Diagnosis,
    notes: &[String],
    figures: &[String],
    resim_rmse: f64,
) -> serde_json::Value {
    let n = ds.n;
    let unit = ds.map.dom_unit();
    json!({
        "verdict": d.verdict,
        "effects": d.effects,
        "unexplained": d.unexplained,
        "rmse_base": d.rmse_base,
        "rmse_final": d.rmse_final,
        "rmse_start_law": d.rmse_start_law,
        "noise": d.noise,
        "recording": ds.path,
        "samples": ds.len(),
        "nodes": n,
        "readout": format!("{:?}", ds.map.kind()).to_lowercase(),
        "residual_unit": unit,
        "base": base_json(&d.base),
        "final": base_json(&d.final_cfg),
        "sim_law": base_json(&d.sim_cfg),
        "candidates": d.trials,
        "backward": d.backward,
        "skipped": d.skipped.iter().map(|(e, w)| json!({"effect": e, "why": w})).collect::<Vec<_>>(),
        "findings_base": d.base_findings,
        "findings_final": d.final_findings,
        "resim_rmse_taxel_sim": resim_rmse,
        "notes": notes,
        "virgin_rest_in_both_folds": d.virgin_rest_shared,
        "unexplained_on_peak_folds": d.unexplained_on_peak_folds,
        "figures": figures,
        "seconds": d.seconds,
    })
}

/// A model's static law: `exponent` and `r_floor_ohm` as before, and `law` (`power`,
/// `monotone_spline` with `spline_basis_per_node`, or `monotone_shared_shape` with
/// `shape_weights_ln`, the shape's `w_j`); with either the exponent is the start model's and
/// unused (`sim_law` has the power law written to SIM.toml).
fn base_json(c: &Config) -> serde_json::Value {
    let mut j = json!({
        "exponent": c.exponent,
        "r_floor_ohm": if c.sat_in_base || c.saturation { c.r_floor_ohm } else { 0.0 },
    });
    match c.law {
        Law::Power => match &c.law_shape {
            Some(w) => {
                j["law"] = json!("monotone_shared_shape");
                j["shape_weights_ln"] = json!(w);
            }
            None => j["law"] = json!("power"),
        },
        Law::Spline(m) => {
            j["law"] = json!("monotone_spline");
            j["spline_basis_per_node"] = json!(m);
        }
    }
    j
}
