//! taxel-python owns the Python bindings of taxel: the extension module `taxel._taxel` that
//! the Python package `taxel` (python/taxel/) wraps. It reads recordings (`recording`: the
//! record file, the recording CSV and MCAP, each stream's fields as NumPy columns), applies
//! calibrations and curvature models to arrays of frames with the same Rust code the live
//! processes run (`offline`), and subscribes to and publishes on the live iceoryx2 streams
//! (`live`), waiting with the GIL released. Every failure is a `taxel.TaxelError` (a
//! `ValueError`) whose message is the one line the command-line tools print; nothing here
//! panics on bad input. Built by maturin (python/pyproject.toml); tested by the Python tests in
//! python/tests, which tests/python.rs runs from `cargo test`.

mod live;
mod offline;
mod recording;
mod samples;
mod thread_bound;

use pyo3::prelude::*;

pyo3::create_exception!(
    _taxel,
    TaxelError,
    pyo3::exceptions::PyValueError,
    "A taxel error: bad input (a file, an array's shape, a sensor id) or a failed operation; the message is the line the command-line tools print."
);

/// The one-line message of an error, as the command-line tools print it after `error: `.
pub(crate) fn one_line(e: &anyhow::Error) -> String {
    format!("{e:#}").replace('\n', " ")
}

/// A [`TaxelError`] carrying `e`'s one-line message.
pub(crate) fn taxel_err(e: impl Into<anyhow::Error>) -> PyErr {
    TaxelError::new_err(one_line(&e.into()))
}

/// A [`TaxelError`] with a message.
pub(crate) fn bad(msg: impl Into<String>) -> PyErr {
    TaxelError::new_err(msg.into())
}

/// An array's shape as Python prints it: `(4, 5)`, `(7,)`.
pub(crate) fn shape_str(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        s => format!(
            "({})",
            s.iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// CLOCK_MONOTONIC in nanoseconds: the clock of every `t_capture_ns` (the same clock as
/// Python's `time.monotonic_ns()` on Linux).
#[pyfunction]
fn now_ns() -> u64 {
    taxel_runtime::now_ns()
}

#[pymodule]
fn _taxel(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("TaxelError", m.py().get_type::<TaxelError>())?;
    m.add("MAX_NODES", taxel_msgs::MAX_NODES)?;
    m.add("MAX_BLOCKS", taxel_msgs::MAX_BLOCKS)?;
    m.add_function(wrap_pyfunction!(now_ns, m)?)?;
    recording::register(m)?;
    offline::register(m)?;
    live::register(m)?;
    Ok(())
}
