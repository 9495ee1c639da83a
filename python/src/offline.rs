//! Calibrations and curvature models applied to arrays: `Calibration.apply` runs the live
//! calibrator's per-frame computation (`taxel_calibrator::run::Calibrator`) over every frame
//! of an array, `CurvatureModel.predict` the estimator's predictor over every baseline. Both
//! check the array's shape against the file's geometry and run without the GIL.

use std::path::PathBuf;

use numpy::{IntoPyArray, PyArray1, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use taxel_calibrator::calibration::Calibration as Cal;
use taxel_calibrator::run::Calibrator;
use taxel_estimator::model::CurvatureModel as Model;
use taxel_msgs::{CurvatureEstimate, ForceSample, RawFrame, MAX_BLOCKS, MAX_NODES};

use crate::{bad, shape_str, taxel_err};

/// How many frames of `n_nodes` readings an array of `shape` holds: `(rows, cols)` or
/// `(n_nodes,)` is one; `(n, rows, cols)` or `(n, n_nodes)` is `n`. `what` names the array in
/// messages.
fn frames_of(
    shape: &[usize],
    rows: usize,
    cols: usize,
    what: &str,
    of: &str,
) -> Result<usize, String> {
    let n_nodes = rows * cols;
    let fits = match shape {
        [k] if *k == n_nodes => Some(1),
        [r, c] if (*r, *c) == (rows, cols) => Some(1),
        [n, k] if *k == n_nodes => Some(*n),
        [n, r, c] if (*r, *c) == (rows, cols) => Some(*n),
        _ => None,
    };
    fits.ok_or_else(|| {
        format!(
            "{what} of shape {} do not fit {of} ({rows} x {cols} = {n_nodes} nodes): give ({rows}, {cols}), (n, {rows}, {cols}) or (n, {n_nodes})",
            shape_str(shape)
        )
    })
}

/// A per-frame value: one for every frame, or one per frame.
fn per_frame(v: &Option<PyReadonlyArrayDyn<'_, f64>>, n: usize, what: &str) -> PyResult<Vec<f64>> {
    match v {
        None => Ok(Vec::new()),
        Some(a) => {
            let s = a.as_slice().map_err(|e| bad(format!("{what}: {e}")))?;
            match s.len() {
                1 => Ok(vec![s[0]; n]),
                k if k == n => Ok(s.to_vec()),
                k => Err(bad(format!(
                    "{what} has {k} values for {n} frames: give one, or one per frame"
                ))),
            }
        }
    }
}

/// A validated calibration file.
#[pyclass(frozen, module = "taxel._taxel")]
struct Calibration {
    cal: Cal,
    path: String,
}

#[pymethods]
impl Calibration {
    /// Reads, parses and validates a calibration file (as the calibrator does).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Calibration> {
        let cal = py.detach(|| Cal::load(&path)).map_err(taxel_err)?;
        Ok(Calibration {
            cal,
            path: path.display().to_string(),
        })
    }

    #[getter]
    fn id(&self) -> &str {
        &self.cal.id
    }
    #[getter]
    fn version(&self) -> u32 {
        self.cal.version
    }
    #[getter]
    fn rows(&self) -> usize {
        self.cal.rows
    }
    #[getter]
    fn cols(&self) -> usize {
        self.cal.cols
    }
    #[getter]
    fn default_curvature_m1(&self) -> f64 {
        self.cal.default_curvature_m1
    }
    /// The names of the blocks, in the order of `block_force_n`'s columns.
    #[getter]
    fn block_names(&self) -> Vec<String> {
        self.cal
            .blocks
            .iter()
            .take(MAX_BLOCKS)
            .map(|b| b.name.clone())
            .collect()
    }
    #[getter]
    fn readout(&self) -> &'static str {
        self.cal.readout.kind.name()
    }

    fn __repr__(&self) -> String {
        format!(
            "Calibration(id={:?}, version={}, {} x {}, {} blocks, path={:?})",
            self.cal.id,
            self.cal.version,
            self.cal.rows,
            self.cal.cols,
            self.cal.blocks.len(),
            self.path
        )
    }

    /// Forces for every frame of `counts` (float32, shape checked against the calibration):
    /// a dict of `total_force_n`, `total_reading` (n,), `block_force_n`, `block_reading`
    /// (n, blocks), `flags` (n,) uint32, `curvature_m1` (n,).
    #[pyo3(signature = (counts, curvature_m1=None, baseline=None, t_capture_ns=None, dynamics=true))]
    fn apply<'py>(
        &self,
        py: Python<'py>,
        counts: PyReadonlyArrayDyn<'py, f32>,
        curvature_m1: Option<PyReadonlyArrayDyn<'py, f64>>,
        baseline: Option<PyReadonlyArrayDyn<'py, f32>>,
        t_capture_ns: Option<PyReadonlyArrayDyn<'py, u64>>,
        dynamics: bool,
    ) -> PyResult<Bound<'py, PyDict>> {
        let cal = &self.cal;
        let of = format!("calibration {}", self.path);
        let n = frames_of(counts.shape(), cal.rows, cal.cols, "counts", &of).map_err(bad)?;
        let n_nodes = cal.rows * cal.cols;
        let counts = counts.as_slice().map_err(|e| bad(format!("counts: {e}")))?;
        let curv = per_frame(&curvature_m1, n, "curvature_m1")?;
        let base = match &baseline {
            None => None,
            Some(b) => {
                let k = frames_of(b.shape(), cal.rows, cal.cols, "baseline", &of).map_err(bad)?;
                if k != 1 {
                    return Err(bad(format!(
                        "baseline of shape {}: give one no-load frame",
                        shape_str(b.shape())
                    )));
                }
                Some(b.as_slice().map_err(|e| bad(format!("baseline: {e}")))?)
            }
        };
        let times: Vec<u64> = match &t_capture_ns {
            None => Vec::new(),
            Some(t) => {
                let s = t
                    .as_slice()
                    .map_err(|e| bad(format!("t_capture_ns: {e}")))?;
                if s.len() != n {
                    return Err(bad(format!(
                        "t_capture_ns has {} values for {n} frames",
                        s.len()
                    )));
                }
                s.to_vec()
            }
        };
        let nb = cal.blocks.len().min(MAX_BLOCKS);
        let out = py.detach(|| {
            let mut c = Calibrator::for_calibration(cal.clone(), f64::INFINITY);
            // Without capture times there is no time step for the dynamic terms.
            c.set_dynamics(dynamics && !times.is_empty());
            if let Some(b) = base {
                let mut est = CurvatureEstimate::ZERO;
                est.rows = cal.rows as u16;
                est.cols = cal.cols as u16;
                est.curvature_m1 = curv.first().map_or(cal.default_curvature_m1, |c| *c) as f32;
                est.t_capture_ns = times.first().copied().unwrap_or(0);
                est.baseline[..n_nodes].copy_from_slice(b);
                c.set_curvature(&est);
            }
            let mut frame = RawFrame::ZERO;
            frame.rows = cal.rows as u16;
            frame.cols = cal.cols as u16;
            let mut f = ForceSample::ZERO;
            let mut total = Vec::with_capacity(n);
            let mut total_s = Vec::with_capacity(n);
            let mut flags = Vec::with_capacity(n);
            let mut used_c = Vec::with_capacity(n);
            let mut blocks = Vec::with_capacity(n * nb);
            let mut blocks_s = Vec::with_capacity(n * nb);
            for i in 0..n {
                frame.seq = i as u64;
                frame.t_capture_ns = times.get(i).copied().unwrap_or(0);
                frame.counts[..n_nodes].copy_from_slice(&counts[i * n_nodes..(i + 1) * n_nodes]);
                if let Some(cv) = curv.get(i) {
                    c.set_known_curvature(*cv);
                }
                c.apply(&frame, frame.t_capture_ns, &mut f);
                total.push(f.total_force_n);
                total_s.push(f.total_reading);
                flags.push(f.flags);
                used_c.push(f.curvature_m1);
                blocks.extend_from_slice(&f.block_force_n[..nb]);
                blocks_s.extend_from_slice(&f.block_reading[..nb]);
            }
            (total, total_s, flags, used_c, blocks, blocks_s)
        });
        let (total, total_s, flags, used_c, blocks, blocks_s) = out;
        let d = PyDict::new(py);
        d.set_item("total_force_n", total.into_pyarray(py))?;
        d.set_item("total_reading", total_s.into_pyarray(py))?;
        d.set_item(
            "block_force_n",
            PyArray1::from_vec(py, blocks).reshape([n, nb])?,
        )?;
        d.set_item(
            "block_reading",
            PyArray1::from_vec(py, blocks_s).reshape([n, nb])?,
        )?;
        d.set_item("flags", flags.into_pyarray(py))?;
        d.set_item("curvature_m1", used_c.into_pyarray(py))?;
        Ok(d)
    }
}

/// A curvature model file (`.taxcrv`).
#[pyclass(frozen, module = "taxel._taxel")]
struct CurvatureModel {
    model: Model,
    path: String,
}

#[pymethods]
impl CurvatureModel {
    /// Reads and checks a curvature model file (as the estimator does).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<CurvatureModel> {
        let model = py.detach(|| Model::load(&path)).map_err(taxel_err)?;
        Ok(CurvatureModel {
            model,
            path: path.display().to_string(),
        })
    }

    #[getter]
    fn n_nodes(&self) -> usize {
        self.model.n_nodes
    }
    #[getter]
    fn kind(&self) -> &str {
        &self.model.kind
    }
    #[getter]
    fn model_version(&self) -> u32 {
        self.model.model_version
    }

    fn __repr__(&self) -> String {
        format!(
            "CurvatureModel(kind={:?}, n_nodes={}, model_version={:08x}, path={:?})",
            self.model.kind, self.model.n_nodes, self.model.model_version, self.path
        )
    }

    /// The curvature (1/m) of every no-load baseline: `baseline` is one baseline
    /// (`(n_nodes,)`, or `(rows, cols)`) or many (`(n, n_nodes)`, `(n, rows, cols)`). Returns a
    /// dict of `curvature_m1`, `sd_m1` (n,) float64 and `out_of_range` (n,) bool.
    fn predict<'py>(
        &self,
        py: Python<'py>,
        baseline: PyReadonlyArrayDyn<'py, f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let m = &self.model;
        let shape = baseline.shape();
        let per = match shape {
            [] => 1,
            [k] => *k,
            s => s[1..].iter().product(),
        };
        let per = if shape.len() == 2 && shape.iter().product::<usize>() == m.n_nodes {
            m.n_nodes
        } else {
            per
        };
        m.check_nodes(&self.path, per).map_err(taxel_err)?;
        if per == 0 || per > MAX_NODES {
            return Err(bad(format!(
                "baseline of shape {}: no nodes",
                shape_str(shape)
            )));
        }
        let v = baseline
            .as_slice()
            .map_err(|e| bad(format!("baseline: {e}")))?;
        let (c, sd, out) = py.detach(|| {
            let mut p = m.predictor();
            let n = v.len() / per;
            let (mut c, mut sd, mut out) = (
                Vec::with_capacity(n),
                Vec::with_capacity(n),
                Vec::with_capacity(n),
            );
            for b in v.chunks_exact(per) {
                let r = p.predict(b);
                c.push(r.curvature_m1);
                sd.push(r.sd_m1);
                out.push(r.out_of_range);
            }
            (c, sd, out)
        });
        let d = PyDict::new(py);
        d.set_item("curvature_m1", c.into_pyarray(py))?;
        d.set_item("sd_m1", sd.into_pyarray(py))?;
        d.set_item("out_of_range", out.into_pyarray(py))?;
        Ok(d)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Calibration>()?;
    m.add_class::<CurvatureModel>()
}
