//! The samples a subscription yields, as light Python objects: each keeps its message (a
//! `Copy` payload of taxel-msgs) and makes NumPy arrays only when one is read; flags are named
//! booleans (`Flags`).

use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use taxel_msgs::{
    curvature_flags, force_flags, raw_flags, sensor_id_str, CurvatureEstimate, ForceSample,
    RawFrame, Reference, MAX_NODES,
};

/// Names of flag bits, per stream.
const FORCE_FLAGS: &[(&str, u32)] = &[
    ("saturated", force_flags::SATURATED),
    ("out_of_range", force_flags::OUT_OF_RANGE),
    ("curvature_stale", force_flags::CURVATURE_STALE),
    ("curvature_defaulted", force_flags::CURVATURE_DEFAULTED),
    ("no_baseline", force_flags::NO_BASELINE),
    ("gap_before", force_flags::GAP_BEFORE),
    (
        "baseline_from_calibration",
        force_flags::BASELINE_FROM_CALIBRATION,
    ),
    ("dynamics_warming", force_flags::DYNAMICS_WARMING),
];
const RAW_FLAGS: &[(&str, u32)] = &[
    ("gap_before", raw_flags::GAP_BEFORE),
    ("rail", raw_flags::RAIL),
];
const CURVATURE_FLAGS: &[(&str, u32)] = &[
    ("configured", curvature_flags::CONFIGURED),
    ("estimated", curvature_flags::ESTIMATED),
    ("out_of_range", curvature_flags::OUT_OF_RANGE),
    ("held", curvature_flags::HELD),
];

/// A sample's flags as named booleans (`flags.saturated`); `bits` is the raw value.
#[pyclass(frozen, module = "taxel._taxel")]
pub struct Flags {
    #[pyo3(get)]
    bits: u32,
    names: &'static [(&'static str, u32)],
}

#[pymethods]
impl Flags {
    fn __getattr__(&self, name: &str) -> PyResult<bool> {
        match self.names.iter().find(|(n, _)| *n == name) {
            Some((_, bit)) => Ok(self.bits & bit != 0),
            None => Err(pyo3::exceptions::PyAttributeError::new_err(format!(
                "no flag {name:?}; flags: {}",
                self.names
                    .iter()
                    .map(|(n, _)| *n)
                    .collect::<Vec<_>>()
                    .join(", ")
            ))),
        }
    }
    /// The names of the flags that are set.
    fn set(&self) -> Vec<&'static str> {
        self.names
            .iter()
            .filter(|(_, b)| self.bits & b != 0)
            .map(|(n, _)| *n)
            .collect()
    }
    /// Every flag name and whether it is set.
    fn as_dict(&self) -> Vec<(&'static str, bool)> {
        self.names
            .iter()
            .map(|(n, b)| (*n, self.bits & b != 0))
            .collect()
    }
    fn __dir__(&self) -> Vec<&'static str> {
        self.names.iter().map(|(n, _)| *n).collect()
    }
    fn __bool__(&self) -> bool {
        self.bits != 0
    }
    fn __repr__(&self) -> String {
        format!("Flags({})", self.set().join(", "))
    }
}

pub(crate) fn flags(
    py: Python<'_>,
    bits: u32,
    names: &'static [(&'static str, u32)],
) -> PyResult<Py<Flags>> {
    Py::new(py, Flags { bits, names })
}

fn nodes_array<'py>(
    py: Python<'py>,
    v: &[f32],
    rows: u16,
    cols: u16,
) -> PyResult<Bound<'py, PyAny>> {
    let (r, c) = (rows as usize, cols as usize);
    let n = (r * c).min(MAX_NODES).min(v.len());
    let a = PyArray1::from_slice(py, &v[..n]);
    if r * c == n {
        Ok(a.reshape([r, c])?.into_any())
    } else {
        Ok(a.into_any())
    }
}

/// A calibrated force sample (`taxel/<sensor>/force`).
#[pyclass(frozen, module = "taxel._taxel")]
pub struct Force {
    s: ForceSample,
    /// When this process took it from shared memory (CLOCK_MONOTONIC ns).
    #[pyo3(get)]
    t_received_ns: u64,
}

#[pymethods]
impl Force {
    #[getter]
    fn seq(&self) -> u64 {
        self.s.seq
    }
    #[getter]
    fn t_capture_ns(&self) -> u64 {
        self.s.t_capture_ns
    }
    #[getter]
    fn t_publish_ns(&self) -> u64 {
        self.s.t_publish_ns
    }
    #[getter]
    fn sensor(&self) -> &str {
        sensor_id_str(&self.s.sensor)
    }
    #[getter]
    fn total_force_n(&self) -> f32 {
        self.s.total_force_n
    }
    #[getter]
    fn total_reading(&self) -> f32 {
        self.s.total_reading
    }
    #[getter]
    fn curvature_m1(&self) -> f32 {
        self.s.curvature_m1
    }
    #[getter]
    fn cal_version(&self) -> u32 {
        self.s.cal_version
    }
    #[getter]
    fn cal_generation(&self) -> u32 {
        self.s.cal_generation
    }
    #[getter]
    fn curvature_model_version(&self) -> u32 {
        self.s.curvature_model_version
    }
    #[getter]
    fn zero_age_s(&self) -> f32 {
        self.s.zero_age_s
    }
    /// Force per calibration block (N), in the calibration file's order.
    #[getter]
    fn block_force_n<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f32>> {
        PyArray1::from_slice(py, self.s.blocks())
    }
    #[getter]
    fn block_reading<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f32>> {
        let n = self.s.blocks().len();
        PyArray1::from_slice(py, &self.s.block_reading[..n])
    }
    #[getter]
    fn flags(&self, py: Python<'_>) -> PyResult<Py<Flags>> {
        flags(py, self.s.flags, FORCE_FLAGS)
    }
    /// Age at receipt (ns): `t_received_ns - t_capture_ns`.
    #[getter]
    fn age_ns(&self) -> u64 {
        self.t_received_ns.saturating_sub(self.s.t_capture_ns)
    }
    fn __repr__(&self) -> String {
        format!(
            "Force(sensor={:?}, seq={}, total_force_n={:.3}, blocks={:?}, cal_version={}, flags=[{}])",
            self.sensor(),
            self.s.seq,
            self.s.total_force_n,
            self.s.blocks(),
            self.s.cal_version,
            Flags { bits: self.s.flags, names: FORCE_FLAGS }.set().join(", ")
        )
    }
}

/// A raw frame (`taxel/<sensor>/raw`).
#[pyclass(frozen, module = "taxel._taxel")]
pub struct Raw {
    f: Box<RawFrame>,
    #[pyo3(get)]
    t_received_ns: u64,
}

#[pymethods]
impl Raw {
    #[getter]
    fn seq(&self) -> u64 {
        self.f.seq
    }
    #[getter]
    fn t_capture_ns(&self) -> u64 {
        self.f.t_capture_ns
    }
    #[getter]
    fn sensor(&self) -> &str {
        sensor_id_str(&self.f.sensor)
    }
    #[getter]
    fn rows(&self) -> u16 {
        self.f.rows
    }
    #[getter]
    fn cols(&self) -> u16 {
        self.f.cols
    }
    #[getter]
    fn full_scale(&self) -> f32 {
        self.f.full_scale
    }
    /// Source kind: 1 sim, 2 serial, 3 replay, 4 external (a Python publisher).
    #[getter]
    fn source(&self) -> u32 {
        self.f.source
    }
    /// The readout the source declares (0: not declared).
    #[getter]
    fn readout_code(&self) -> u32 {
        raw_flags::readout_code(self.f.flags)
    }
    /// The readings as a rows x cols float32 array.
    #[getter]
    fn counts<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        nodes_array(py, &self.f.counts, self.f.rows, self.f.cols)
    }
    #[getter]
    fn flags(&self, py: Python<'_>) -> PyResult<Py<Flags>> {
        flags(py, self.f.flags & !raw_flags::READOUT_MASK, RAW_FLAGS)
    }
    #[getter]
    fn age_ns(&self) -> u64 {
        self.t_received_ns.saturating_sub(self.f.t_capture_ns)
    }
    fn __repr__(&self) -> String {
        format!(
            "Raw(sensor={:?}, seq={}, {} x {})",
            self.sensor(),
            self.f.seq,
            self.f.rows,
            self.f.cols
        )
    }
}

/// A curvature estimate and the no-load baseline it came from (`taxel/<sensor>/curvature`).
#[pyclass(frozen, module = "taxel._taxel")]
pub struct Curvature {
    e: Box<CurvatureEstimate>,
    #[pyo3(get)]
    t_received_ns: u64,
}

#[pymethods]
impl Curvature {
    #[getter]
    fn seq(&self) -> u64 {
        self.e.seq
    }
    #[getter]
    fn t_capture_ns(&self) -> u64 {
        self.e.t_capture_ns
    }
    #[getter]
    fn t_window_start_ns(&self) -> u64 {
        self.e.t_window_start_ns
    }
    #[getter]
    fn sensor(&self) -> &str {
        sensor_id_str(&self.e.sensor)
    }
    #[getter]
    fn curvature_m1(&self) -> f32 {
        self.e.curvature_m1
    }
    #[getter]
    fn curvature_sd_m1(&self) -> f32 {
        self.e.curvature_sd_m1
    }
    #[getter]
    fn model_version(&self) -> u32 {
        self.e.model_version
    }
    #[getter]
    fn window_frames(&self) -> u32 {
        self.e.window_frames
    }
    #[getter]
    fn estimate_index(&self) -> u32 {
        self.e.estimate_index
    }
    /// The no-load baseline as a rows x cols float32 array.
    #[getter]
    fn baseline<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        nodes_array(py, &self.e.baseline, self.e.rows, self.e.cols)
    }
    #[getter]
    fn flags(&self, py: Python<'_>) -> PyResult<Py<Flags>> {
        flags(py, self.e.flags, CURVATURE_FLAGS)
    }
    fn __repr__(&self) -> String {
        format!(
            "Curvature(sensor={:?}, curvature_m1={:.2}, estimate_index={})",
            self.sensor(),
            self.e.curvature_m1,
            self.e.estimate_index
        )
    }
}

/// Reference values (`taxel/<sensor>/reference`): the simulator's truth or a recording's.
#[pyclass(frozen, module = "taxel._taxel")]
pub struct ReferenceValue {
    r: Reference,
    #[pyo3(get)]
    t_received_ns: u64,
}

#[pymethods]
impl ReferenceValue {
    #[getter]
    fn seq(&self) -> u64 {
        self.r.seq
    }
    #[getter]
    fn t_capture_ns(&self) -> u64 {
        self.r.t_capture_ns
    }
    #[getter]
    fn sensor(&self) -> &str {
        sensor_id_str(&self.r.sensor)
    }
    #[getter]
    fn t_source_s(&self) -> f64 {
        self.r.t_source_s
    }
    #[getter]
    fn force_n(&self) -> f32 {
        self.r.force_n
    }
    #[getter]
    fn curvature_m1(&self) -> f32 {
        self.r.curvature_m1
    }
    #[getter]
    fn temp_c(&self) -> f32 {
        self.r.temp_c
    }
    #[getter]
    fn trial(&self) -> i32 {
        self.r.trial
    }
}

/// A received sample and when it was taken.
pub(crate) enum Item {
    Force(ForceSample, u64),
    Raw(Box<RawFrame>, u64),
    Curvature(Box<CurvatureEstimate>, u64),
    Reference(Reference, u64),
}

impl Item {
    pub(crate) fn into_py(self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        Ok(match self {
            Item::Force(s, t) => Py::new(
                py,
                Force {
                    s,
                    t_received_ns: t,
                },
            )?
            .into_any(),
            Item::Raw(f, t) => Py::new(
                py,
                Raw {
                    f,
                    t_received_ns: t,
                },
            )?
            .into_any(),
            Item::Curvature(e, t) => Py::new(
                py,
                Curvature {
                    e,
                    t_received_ns: t,
                },
            )?
            .into_any(),
            Item::Reference(r, t) => Py::new(
                py,
                ReferenceValue {
                    r,
                    t_received_ns: t,
                },
            )?
            .into_any(),
        })
    }
}
