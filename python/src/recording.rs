//! Recordings as NumPy columns: the logger's record file (`.taxrec`) and MCAP files give every
//! field of every stream (walked with the field tables of taxel-msgs, so every payload field
//! arrives, under its name); a recording CSV gives its `raw` readings and its `reference`
//! columns. Arrays of nodes come as `(n, rows, cols)` when every record of the stream has the
//! same geometry, else `(n, MAX_NODES)` padded with NaN; per-block arrays as `(n, blocks)`.

use std::path::{Path, PathBuf};

use numpy::{IntoPyArray, PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use taxel_formats::records::Record;
use taxel_formats::{RecordFileReader, Recording};
use taxel_msgs::{sensor_id_str, Field, SensorIdBytes, Visitor};

use crate::{bad, taxel_err};

/// One column of a stream.
enum Col {
    /// Sensor ids as indices into the names seen, in order of first appearance.
    Sensor {
        codes: Vec<u16>,
        names: Vec<String>,
    },
    U64(Vec<u64>),
    U32(Vec<u32>),
    U16(Vec<u16>),
    I32(Vec<i32>),
    F32(Vec<f32>),
    F64(Vec<f64>),
    /// An array per record: the values back to back, and each record's length.
    Arr {
        values: Vec<f32>,
        lens: Vec<u32>,
    },
}

/// The columns of one stream, in its field table's order.
#[derive(Default)]
struct Columns {
    names: Vec<&'static str>,
    cols: Vec<Col>,
    /// The field being visited.
    at: usize,
    rows: usize,
}

impl Columns {
    /// The column of the field being visited, created with the first record.
    fn col(&mut self, f: &Field, make: impl FnOnce() -> Col) -> &mut Col {
        let i = self.at;
        self.at += 1;
        if i == self.cols.len() {
            self.names.push(f.name);
            self.cols.push(make());
        }
        &mut self.cols[i]
    }

    fn add(&mut self, rec: &mut Record) {
        self.at = 0;
        rec.visit(self);
        self.rows += 1;
    }
}

macro_rules! scalar {
    ($fn:ident, $t:ty, $variant:ident) => {
        fn $fn(&mut self, f: &Field, v: &mut $t) {
            if let Col::$variant(c) = self.col(f, || Col::$variant(Vec::new())) {
                c.push(*v);
            }
        }
    };
}

impl Visitor for Columns {
    fn sensor(&mut self, f: &Field, v: &mut SensorIdBytes) {
        let make = || Col::Sensor {
            codes: Vec::new(),
            names: Vec::new(),
        };
        if let Col::Sensor { codes, names } = self.col(f, make) {
            let id = sensor_id_str(v);
            // Files hold one sensor or a few: the last one seen is the usual match.
            let code = match codes.last() {
                Some(&c) if names[c as usize] == id => c as usize,
                _ => names.iter().position(|n| n == id).unwrap_or_else(|| {
                    names.push(id.to_string());
                    names.len() - 1
                }),
            };
            codes.push(code as u16);
        }
    }
    scalar!(u64, u64, U64);
    scalar!(u32, u32, U32);
    scalar!(u16, u16, U16);
    scalar!(i32, i32, I32);
    scalar!(f32, f32, F32);
    scalar!(f64, f64, F64);
    fn f32s(&mut self, f: &Field, v: &mut [f32], len: &mut usize) {
        if let Col::Arr { values, lens } = self.col(f, || Col::Arr {
            values: Vec::new(),
            lens: Vec::new(),
        }) {
            let n = (*len).min(v.len());
            values.extend_from_slice(&v[..n]);
            lens.push(n as u32);
        }
    }
}

/// The streams of a record or MCAP file, in the order they first appear.
#[derive(Default)]
struct Streams {
    order: Vec<&'static str>,
    by_name: Vec<Columns>,
}

impl Streams {
    fn add(&mut self, rec: &mut Record, sensor: Option<&str>) {
        if sensor.is_some_and(|s| s != rec.sensor()) {
            return;
        }
        let name = rec.stream().suffix();
        let i = match self.order.iter().position(|s| *s == name) {
            Some(i) => i,
            None => {
                self.order.push(name);
                self.by_name.push(Columns::default());
                self.order.len() - 1
            }
        };
        self.by_name[i].add(rec);
    }
}

impl Streams {
    /// Appends the streams of the next part of the file; false if a stream's columns differ
    /// (they cannot: a stream's columns come from its one field table).
    fn append(&mut self, next: Streams) -> bool {
        let mut same = true;
        for (name, cols) in next.order.into_iter().zip(next.by_name) {
            match self.order.iter().position(|s| *s == name) {
                Some(i) => same &= self.by_name[i].append(cols),
                None => {
                    self.order.push(name);
                    self.by_name.push(cols);
                }
            }
        }
        same
    }
}

impl Columns {
    /// Appends the rows of the same stream from the next part of the file (the same field
    /// table, so the same columns in the same order).
    fn append(&mut self, next: Columns) -> bool {
        self.rows += next.rows;
        self.cols.len() == next.cols.len()
            && self
                .cols
                .iter_mut()
                .zip(next.cols)
                .fold(true, |same, (mine, theirs)| same & mine.append(theirs))
    }
}

impl Col {
    fn append(&mut self, next: Col) -> bool {
        match (self, next) {
            (
                Col::Sensor { codes, names },
                Col::Sensor {
                    codes: more,
                    names: more_names,
                },
            ) => {
                // The next part numbered its sensors in its own order of appearance.
                let map: Vec<u16> = more_names
                    .into_iter()
                    .map(|n| match names.iter().position(|m| *m == n) {
                        Some(i) => i as u16,
                        None => {
                            names.push(n);
                            (names.len() - 1) as u16
                        }
                    })
                    .collect();
                codes.extend(more.into_iter().map(|c| map[c as usize]));
            }
            (Col::U64(a), Col::U64(b)) => a.extend(b),
            (Col::U32(a), Col::U32(b)) => a.extend(b),
            (Col::U16(a), Col::U16(b)) => a.extend(b),
            (Col::I32(a), Col::I32(b)) => a.extend(b),
            (Col::F32(a), Col::F32(b)) => a.extend(b),
            (Col::F64(a), Col::F64(b)) => a.extend(b),
            (Col::Arr { values, lens }, Col::Arr { values: v, lens: l }) => {
                values.extend(v);
                lens.extend(l);
            }
            _ => return false,
        }
        true
    }
}

/// What kind of file `path` is: by its first bytes, else (a missing file) by its name.
fn kind(path: &Path) -> &'static str {
    let mut head = [0u8; 8];
    let got = std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read(&mut f, &mut head))
        .unwrap_or(0);
    let name = path.to_string_lossy().to_ascii_lowercase();
    if got == 8 && &head == taxel_formats::records::MAGIC {
        "taxrec"
    } else if taxel_formats::mcap::is_mcap(path) {
        "mcap"
    } else if got > 0 || name.ends_with(".csv") || name.ends_with(".csv.gz") {
        "csv"
    } else if name.ends_with(".mcap") {
        "mcap"
    } else {
        "taxrec"
    }
}

/// Reads every record of a record file; a tail cut short (a crash of the writer) is a warning,
/// damage inside the file an error, as for `taxel logger export`.
fn read_taxrec(py: Python<'_>, path: &Path, sensor: Option<&str>) -> PyResult<Streams> {
    let (streams, stop) = py
        .detach(|| {
            let mut reader = RecordFileReader::open(path).map_err(|e| e.to_string())?;
            let mut streams = Streams::default();
            while let Some(rec) = reader.next_view() {
                streams.add(rec, sensor);
            }
            let stop = reader
                .stop_position()
                .map(|at| (at, reader.damaged(), path.display().to_string()));
            Ok::<_, String>((streams, stop))
        })
        .map_err(bad)?;
    match stop {
        Some((at, true, p)) => Err(bad(format!(
            "{p}: damaged at {at}; the rest of the file was not read"
        ))),
        Some((at, false, p)) => {
            let msg = std::ffi::CString::new(format!(
                "{p}: cut short at {at}; everything before it was read"
            ))
            .unwrap_or_default();
            PyErr::warn(
                py,
                &py.get_type::<pyo3::exceptions::PyUserWarning>(),
                &msg,
                1,
            )?;
            Ok(streams)
        }
        None => Ok(streams),
    }
}

/// Reads an MCAP file on up to two threads (a 2-core machine is what the target is set on;
/// parts decode into their own columns, joined in file order).
fn read_mcap(py: Python<'_>, path: &Path, sensor: Option<&str>) -> PyResult<Streams> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get().min(2));
    py.detach(|| {
        let parts = taxel_formats::mcap::for_each_view_parts(
            path,
            threads,
            Streams::default,
            |streams, m| streams.add(m.record, sensor),
        )
        .map_err(anyhow::Error::from)?;
        let mut parts = parts.into_iter();
        let mut streams = parts.next().unwrap_or_default();
        for part in parts {
            if !streams.append(part) {
                return Err(anyhow::anyhow!(
                    "{}: the parts of the file read on two threads do not match",
                    path.display()
                ));
            }
        }
        Ok(streams)
    })
    .map_err(taxel_err)
}

/// The dict of one stream's columns.
fn stream_dict<'py>(py: Python<'py>, c: Columns) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    // Node arrays are shaped by the stream's rows and cols when they are constant.
    let geometry = {
        let get = |name: &str| {
            c.names
                .iter()
                .position(|n| *n == name)
                .and_then(|i| match &c.cols[i] {
                    Col::U16(v) => Some(v),
                    _ => None,
                })
        };
        match (get("rows"), get("cols")) {
            (Some(r), Some(k)) if !r.is_empty() => {
                let (r0, k0) = (r[0], k[0]);
                (r.iter().all(|x| *x == r0) && k.iter().all(|x| *x == k0))
                    .then_some((r0 as usize, k0 as usize))
            }
            _ => None,
        }
    };
    let n = c.rows;
    for (name, col) in c.names.into_iter().zip(c.cols) {
        let obj: Bound<'py, PyAny> = match col {
            // (codes, names): the Python layer makes the array of ids from them.
            Col::Sensor { codes, names } => (codes.into_pyarray(py), PyList::new(py, names)?)
                .into_pyobject(py)?
                .into_any(),
            Col::U64(v) => v.into_pyarray(py).into_any(),
            Col::U32(v) => v.into_pyarray(py).into_any(),
            Col::U16(v) => v.into_pyarray(py).into_any(),
            Col::I32(v) => v.into_pyarray(py).into_any(),
            Col::F32(v) => v.into_pyarray(py).into_any(),
            Col::F64(v) => v.into_pyarray(py).into_any(),
            Col::Arr { values, lens } => {
                let width = lens.iter().copied().max().unwrap_or(0) as usize;
                let full = lens.iter().all(|l| *l as usize == width);
                let flat: Vec<f32> = if full {
                    values
                } else {
                    let mut out = vec![f32::NAN; n * width];
                    let mut at = 0;
                    for (i, l) in lens.iter().enumerate() {
                        let l = *l as usize;
                        out[i * width..i * width + l].copy_from_slice(&values[at..at + l]);
                        at += l;
                    }
                    out
                };
                let arr = PyArray1::from_vec(py, flat);
                let shape: Vec<usize> = match geometry {
                    Some((r, k)) if full && r * k == width => vec![n, r, k],
                    _ => vec![n, width],
                };
                arr.reshape(shape)?.into_any()
            }
        };
        d.set_item(name, obj)?;
    }
    Ok(d)
}

/// A recording CSV as two streams: `raw` (`t_s`, `counts` as (n, rows, cols) for a square
/// array, else (n, nodes)) and `reference` (`t_s` and the reference columns it has).
fn csv_dict<'py>(py: Python<'py>, path: &Path) -> PyResult<Bound<'py, PyDict>> {
    let rec = py.detach(|| Recording::read(path)).map_err(taxel_err)?;
    let out = PyDict::new(py);
    let n = rec.len();
    let width = rec.n_nodes;
    let shape = match taxel_formats::Geometry::resolve(width, None, None) {
        Ok(g) => vec![n, g.rows, g.cols],
        Err(_) => vec![n, width],
    };
    let raw = PyDict::new(py);
    raw.set_item("t_s", rec.t_s.clone().into_pyarray(py))?;
    raw.set_item("counts", PyArray1::from_vec(py, rec.nodes).reshape(shape)?)?;
    out.set_item("raw", raw)?;
    let reference = PyDict::new(py);
    let mut any = false;
    for (name, col) in [
        ("force_n", rec.force_n),
        ("curvature_m1", rec.curvature_m1),
        ("temp_c", rec.temp_c),
    ] {
        if let Some(v) = col {
            reference.set_item(name, v.into_pyarray(py))?;
            any = true;
        }
    }
    if let Some(v) = rec.trial {
        reference.set_item("trial", v.into_pyarray(py))?;
        any = true;
    }
    if any {
        reference.set_item("t_s", rec.t_s.into_pyarray(py))?;
        out.set_item("reference", reference)?;
    }
    Ok(out)
}

/// `read_recording(path, sensor=None) -> (kind, {stream: {field: array}})`: every stream of a
/// record file, MCAP file or recording CSV (kind `"taxrec"`, `"mcap"` or `"csv"`). `sensor`
/// keeps one sensor's records (record and MCAP files).
#[pyfunction]
#[pyo3(signature = (path, sensor=None))]
fn read_recording<'py>(
    py: Python<'py>,
    path: PathBuf,
    sensor: Option<String>,
) -> PyResult<(&'static str, Bound<'py, PyDict>)> {
    let k = kind(&path);
    if k == "csv" {
        return Ok((k, csv_dict(py, &path)?));
    }
    let streams = if k == "mcap" {
        read_mcap(py, &path, sensor.as_deref())?
    } else {
        read_taxrec(py, &path, sensor.as_deref())?
    };
    if streams.order.is_empty() {
        return Err(bad(format!(
            "{}: no records{}",
            path.display(),
            sensor.map_or(String::new(), |s| format!(" for sensor {s}"))
        )));
    }
    let out = PyDict::new(py);
    for (name, cols) in streams.order.into_iter().zip(streams.by_name) {
        out.set_item(name, stream_dict(py, cols)?)?;
    }
    Ok((k, out))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_recording, m)?)
}
