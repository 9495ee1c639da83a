//! The live streams from Python: `subscribe` opens a stream of one sensor and yields its
//! samples as light objects (NumPy arrays made on access), waiting with the GIL released in
//! the consumer's wake-up mode (event, busy, or the adaptive waiter of taxel-runtime) in
//! slices of at most 100 ms, between which Ctrl-C (a pending KeyboardInterrupt) ends the wait;
//! `Publisher` sends raw frames from a Python-side source.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use numpy::{PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use taxel_msgs::{
    raw_flags, sensor_id_bytes, source, CurvatureEstimate, ForceSample, RawFrame, Reference, Stream,
};
use taxel_runtime::ipc::{Ipc, IpcError, StreamPublisher, StreamSubscriber, TICK};
use taxel_runtime::now_ns;
use taxel_runtime::wake::{Adaptive, Newest, WakeMode};

use crate::samples::{Curvature, Flags, Force, Item, Raw, ReferenceValue};
use crate::thread_bound::ThreadBound;
use crate::{bad, shape_str, taxel_err};

/// A value handed to `Python::detach`, which runs its closure on the calling thread: the value
/// never reaches another thread, it is only used while this thread does not hold the GIL.
struct OnThisThread<T>(T);
// SAFETY: `Python::detach` runs the closure on the current thread and returns only after it
// ended, so the wrapped value (iceoryx2 ports, which are not `Send`) is used on the thread that
// owns it, exactly as without the wrapper.
unsafe impl<T> Send for OnThisThread<T> {}
impl<T> OnThisThread<T> {
    fn get(self) -> T {
        self.0
    }
}

/// The default service prefix: `TAXEL_PREFIX`, else `taxel_` (as the command-line tools).
fn prefix_or_default(prefix: Option<String>) -> String {
    prefix
        .or_else(|| std::env::var("TAXEL_PREFIX").ok())
        .unwrap_or_else(|| "taxel_".into())
}

/// A payload a subscription can carry.
trait Payload: std::fmt::Debug + iceoryx2::prelude::ZeroCopySend + Copy + 'static {
    fn item(&self, t: u64) -> Item;
    fn stamp(&self) -> (u64, u64);
}
impl Payload for ForceSample {
    fn item(&self, t: u64) -> Item {
        Item::Force(*self, t)
    }
    fn stamp(&self) -> (u64, u64) {
        (self.seq, self.t_capture_ns)
    }
}
impl Payload for RawFrame {
    fn item(&self, t: u64) -> Item {
        Item::Raw(Box::new(*self), t)
    }
    fn stamp(&self) -> (u64, u64) {
        (self.seq, self.t_capture_ns)
    }
}
impl Payload for CurvatureEstimate {
    fn item(&self, t: u64) -> Item {
        Item::Curvature(Box::new(*self), t)
    }
    fn stamp(&self) -> (u64, u64) {
        (self.seq, self.t_capture_ns)
    }
}
impl Payload for Reference {
    fn item(&self, t: u64) -> Item {
        Item::Reference(*self, t)
    }
    fn stamp(&self) -> (u64, u64) {
        (self.seq, self.t_capture_ns)
    }
}

/// Waits in `mode` until samples arrived (queued into `out`) or `until` passed.
fn wait<T: Payload>(
    sub: &StreamSubscriber<T>,
    mode: WakeMode,
    adaptive: &mut Adaptive,
    until: Instant,
    out: &mut VecDeque<Item>,
) -> Result<(), IpcError> {
    let left = || until.saturating_duration_since(Instant::now());
    if left().is_zero() {
        // No time to wait: only what is there now.
        let t = now_ns();
        sub.poll_each(|v| {
            out.push_back(v.item(t));
            Ok(())
        })?;
        return Ok(());
    }
    match mode {
        WakeMode::Event => {
            let t = now_ns();
            if sub.drain(|v| out.push_back(v.item(t)))? > 0 {
                return Ok(());
            }
            sub.wait_wakeup(left())?;
            let t = now_ns();
            sub.drain(|v| out.push_back(v.item(t)))?;
        }
        WakeMode::Busy => {
            let mut polls = 0u32;
            loop {
                let t = now_ns();
                let n = sub.poll_each(|v| {
                    out.push_back(v.item(t));
                    Ok(())
                })?;
                if n > 0 {
                    return Ok(());
                }
                // As the Rust consumers: yield so a sender sharing this core gets it back.
                std::thread::yield_now();
                polls += 1;
                if polls >= 256 {
                    polls = 0;
                    if left().is_zero() {
                        return sub.clear_wakeups();
                    }
                }
            }
        }
        WakeMode::Adaptive => {
            let got = std::cell::Cell::new(false);
            let mut poll = |newest: &mut Newest| {
                let t = now_ns();
                sub.poll_each(|v| {
                    *newest = Some((v.stamp(), t));
                    out.push_back(v.item(t));
                    got.set(true);
                    Ok(())
                })
                .map(|_| ())
            };
            loop {
                let tick = left().max(Duration::from_millis(1));
                adaptive.step(sub, &mut poll, &|| Instant::now() >= until, tick)?;
                if got.get() || Instant::now() >= until {
                    break;
                }
            }
        }
    }
    Ok(())
}

enum Sub {
    Force(StreamSubscriber<ForceSample>),
    Raw(StreamSubscriber<RawFrame>),
    Curvature(StreamSubscriber<CurvatureEstimate>),
    Reference(StreamSubscriber<Reference>),
}

/// What a subscription waits with; used without the GIL.
struct Waiter {
    sub: Sub,
    mode: WakeMode,
    adaptive: Adaptive,
    queue: VecDeque<Item>,
}

impl Waiter {
    fn wait(&mut self, until: Instant) -> Result<(), IpcError> {
        let (mode, a, q) = (self.mode, &mut self.adaptive, &mut self.queue);
        match &self.sub {
            Sub::Force(s) => wait(s, mode, a, until, q),
            Sub::Raw(s) => wait(s, mode, a, until, q),
            Sub::Curvature(s) => wait(s, mode, a, until, q),
            Sub::Reference(s) => wait(s, mode, a, until, q),
        }
    }
}

/// An open subscription: an iterator of samples. Iteration ends after `timeout` seconds
/// without a sample (never, without a timeout); `next(timeout)` returns None instead.
#[pyclass(module = "taxel._taxel")]
pub struct Subscription {
    ports: ThreadBound<SubscriptionPorts>,
    timeout: Option<f64>,
    #[pyo3(get)]
    sensor: String,
    #[pyo3(get)]
    stream: &'static str,
    #[pyo3(get)]
    prefix: String,
    #[pyo3(get)]
    wake: &'static str,
}

/// What a subscription holds on the thread that made it.
struct SubscriptionPorts {
    waiter: Option<Waiter>,
    /// Declared after the waiter: the node outlives its ports.
    ipc: Option<Ipc>,
}

impl Subscription {
    fn next_item(&mut self, py: Python<'_>, timeout: Option<f64>) -> PyResult<Option<Py<PyAny>>> {
        let deadline = match timeout {
            Some(t) if !(t.is_finite() && t >= 0.0) => {
                return Err(bad(format!(
                    "timeout must be a finite number >= 0, got {t}"
                )))
            }
            Some(t) => Some(Instant::now() + Duration::from_secs_f64(t)),
            None => None,
        };
        let what = || format!("the subscription to taxel/{}/{}", self.sensor, self.stream);
        let ports = self.ports.get(what)?;
        // A deadline already passed (a timeout of 0, `poll`) still takes what is waiting.
        let mut looked = false;
        loop {
            let Some(w) = ports.waiter.as_mut() else {
                return Err(bad(format!(
                    "the subscription to taxel/{}/{} is closed",
                    self.sensor, self.stream
                )));
            };
            if let Some(item) = w.queue.pop_front() {
                return item.into_py(py).map(Some);
            }
            let now = Instant::now();
            if looked && deadline.is_some_and(|d| now >= d) {
                return Ok(None);
            }
            looked = true;
            let slice = now + TICK;
            let until = deadline.map_or(slice, |d| d.min(slice));
            let w = OnThisThread(w);
            py.detach(move || w.get().wait(until)).map_err(taxel_err)?;
            // Ctrl-C while waiting: raise KeyboardInterrupt here.
            py.check_signals()?;
        }
    }
}

#[pymethods]
impl Subscription {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&mut self, py: Python<'_>) -> PyResult<Option<Py<PyAny>>> {
        let t = self.timeout;
        self.next_item(py, t)
    }

    /// The next sample, or None after `timeout` seconds (the subscription's timeout when not
    /// given; wait for ever when neither is).
    #[pyo3(signature = (timeout=None))]
    fn next(&mut self, py: Python<'_>, timeout: Option<f64>) -> PyResult<Option<Py<PyAny>>> {
        let t = timeout.or(self.timeout);
        self.next_item(py, t)
    }

    /// Samples waiting now, without blocking (at most `limit`).
    #[pyo3(signature = (limit=None))]
    fn poll(&mut self, py: Python<'_>, limit: Option<usize>) -> PyResult<Vec<Py<PyAny>>> {
        let mut out = Vec::new();
        while limit.is_none_or(|l| out.len() < l) {
            match self.next_item(py, Some(0.0))? {
                Some(x) => out.push(x),
                None => break,
            }
        }
        Ok(out)
    }

    /// Closes the subscription (its iceoryx2 node is removed); also on garbage collection.
    fn close(&mut self) -> PyResult<()> {
        let what = || format!("the subscription to taxel/{}/{}", self.sensor, self.stream);
        let ports = self.ports.get(what)?;
        ports.waiter = None;
        ports.ipc = None;
        Ok(())
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __exit__(
        &mut self,
        _t: Option<Bound<'_, PyAny>>,
        _v: Option<Bound<'_, PyAny>>,
        _tb: Option<Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        self.close()
    }

    fn __repr__(&self) -> String {
        format!(
            "Subscription(taxel/{}/{}, prefix={:?}, wake={:?})",
            self.sensor, self.stream, self.prefix, self.wake
        )
    }
}

/// `subscribe(sensor, stream="force", prefix=None, wake="event", timeout=None)`.
#[pyfunction]
#[pyo3(signature = (sensor, stream="force", prefix=None, wake="event", timeout=None))]
fn subscribe(
    sensor: &str,
    stream: &str,
    prefix: Option<String>,
    wake: &str,
    timeout: Option<f64>,
) -> PyResult<Subscription> {
    sensor_id_bytes(sensor).map_err(taxel_err)?;
    let prefix = prefix_or_default(prefix);
    let (mode, wake) = match wake {
        "event" => (WakeMode::Event, "event"),
        "busy" => (WakeMode::Busy, "busy"),
        "adaptive" => (WakeMode::Adaptive, "adaptive"),
        w => {
            return Err(bad(format!(
                "unknown wake mode {w:?}: use event, busy or adaptive"
            )))
        }
    };
    if let Some(t) = timeout {
        if !(t.is_finite() && t >= 0.0) {
            return Err(bad(format!(
                "timeout must be a finite number >= 0, got {t}"
            )));
        }
    }
    let s = Stream::ALL
        .into_iter()
        .find(|s| s.suffix() == stream)
        .ok_or_else(|| {
            bad(format!(
                "unknown stream {stream:?}: use force, raw, curvature or reference"
            ))
        })?;
    let ipc = Ipc::open(&prefix, &format!("py-{}-{sensor}", s.suffix())).map_err(taxel_err)?;
    let sub = match s {
        Stream::Force => Sub::Force(ipc.subscriber(sensor, s).map_err(taxel_err)?),
        Stream::Raw => Sub::Raw(ipc.subscriber(sensor, s).map_err(taxel_err)?),
        Stream::Curvature => Sub::Curvature(ipc.subscriber(sensor, s).map_err(taxel_err)?),
        Stream::Reference => Sub::Reference(ipc.subscriber(sensor, s).map_err(taxel_err)?),
    };
    if mode == WakeMode::Adaptive {
        taxel_runtime::clock::fine_timer_slack();
    }
    Ok(Subscription {
        ports: ThreadBound::new(SubscriptionPorts {
            waiter: Some(Waiter {
                sub,
                mode,
                adaptive: Adaptive::new(),
                queue: VecDeque::new(),
            }),
            ipc: Some(ipc),
        }),
        timeout,
        sensor: sensor.to_string(),
        stream: s.suffix(),
        prefix,
        wake,
    })
}

/// Sends raw frames on `taxel/<sensor>/raw` from a Python-side source (a lab's own reader).
#[pyclass(module = "taxel._taxel")]
pub struct Publisher {
    ports: ThreadBound<PublisherPorts>,
    frame: Box<RawFrame>,
    #[pyo3(get)]
    sensor: String,
    #[pyo3(get)]
    prefix: String,
    /// Frames sent so far (the next frame's `seq`).
    #[pyo3(get)]
    sent: u64,
}

/// What a publisher holds on the thread that made it.
struct PublisherPorts {
    publisher: Option<StreamPublisher<RawFrame>>,
    /// Declared after the port: the node outlives it.
    ipc: Option<Ipc>,
}

fn readout_code(name: &str) -> Option<u32> {
    Some(match name {
        "amplifier" => 1,
        "divider" => 2,
        "divider-falling" => 3,
        "resistance" => 4,
        "inverted" => 5,
        _ => return None,
    })
}

#[pymethods]
impl Publisher {
    /// `Publisher(sensor, prefix=None, rows=None, cols=None, full_scale=0.0, readout=None)`:
    /// rows and cols default to the shape of the first frame published; `full_scale` (the top
    /// code, e.g. 1023; 0 unknown) flags rail clipping; `readout` declares what the board
    /// reads (amplifier, divider, divider-falling, resistance, inverted).
    #[new]
    #[pyo3(signature = (sensor, prefix=None, rows=None, cols=None, full_scale=0.0, readout=None))]
    fn new(
        sensor: &str,
        prefix: Option<String>,
        rows: Option<usize>,
        cols: Option<usize>,
        full_scale: f32,
        readout: Option<&str>,
    ) -> PyResult<Publisher> {
        let id = sensor_id_bytes(sensor).map_err(taxel_err)?;
        let prefix = prefix_or_default(prefix);
        if !(full_scale.is_finite() && full_scale >= 0.0) {
            return Err(bad(format!(
                "full_scale must be a finite number >= 0, got {full_scale}"
            )));
        }
        let code = match readout {
            None => 0,
            Some(r) => readout_code(r).ok_or_else(|| {
                bad(format!(
                    "unknown readout {r:?}: use amplifier, divider, divider-falling, resistance or inverted"
                ))
            })?,
        };
        let mut frame = Box::new(RawFrame::ZERO);
        frame.sensor = id;
        frame.source = source::EXTERNAL;
        frame.full_scale = full_scale;
        frame.flags = raw_flags::with_readout_code(0, code);
        match (rows, cols) {
            (Some(r), Some(c)) if r > 0 && c > 0 && r <= 32 && c <= 32 => {
                frame.rows = r as u16;
                frame.cols = c as u16;
            }
            (None, None) => {}
            (r, c) => {
                return Err(bad(format!(
                    "rows {r:?} x cols {c:?}: give both, each 1 to 32 (or neither: the first frame's shape)"
                )))
            }
        }
        let ipc = Ipc::open(&prefix, &format!("py-publisher-{sensor}")).map_err(taxel_err)?;
        let publisher = ipc
            .publisher::<RawFrame>(sensor, Stream::Raw)
            .map_err(taxel_err)?;
        Ok(Publisher {
            ports: ThreadBound::new(PublisherPorts {
                publisher: Some(publisher),
                ipc: Some(ipc),
            }),
            frame,
            sensor: sensor.to_string(),
            prefix,
            sent: 0,
        })
    }

    /// Sends one frame: `counts` as (rows, cols) or (rows * cols,) (float32), stamped with
    /// `t_capture_ns` (CLOCK_MONOTONIC ns, as `taxel.now_ns()`; now when not given). Returns
    /// the frame's `seq`.
    #[pyo3(signature = (counts, t_capture_ns=None))]
    fn publish(
        &mut self,
        counts: PyReadonlyArrayDyn<'_, f32>,
        t_capture_ns: Option<u64>,
    ) -> PyResult<u64> {
        let sensor = &self.sensor;
        let ports = self.ports.get(|| format!("the publisher of {sensor}"))?;
        let Some(publisher) = ports.publisher.as_ref() else {
            return Err(bad(format!("the publisher of {sensor} is closed")));
        };
        let f = &mut self.frame;
        let shape = counts.shape();
        if f.rows == 0 {
            match shape {
                [r, c] if *r > 0 && *c > 0 && *r <= 32 && *c <= 32 => {
                    f.rows = *r as u16;
                    f.cols = *c as u16;
                }
                _ => {
                    return Err(bad(format!(
                        "counts of shape {}: the first frame must be (rows, cols) with 1 to 32 each, or give rows and cols to Publisher",
                        shape_str(shape)
                    )))
                }
            }
        }
        let (r, c) = (f.rows as usize, f.cols as usize);
        let fits =
            matches!(shape, [a, b] if (*a, *b) == (r, c)) || matches!(shape, [k] if *k == r * c);
        if !fits {
            return Err(bad(format!(
                "counts of shape {} for sensor {}'s {r} x {c} array: give ({r}, {c}) or ({},)",
                shape_str(shape),
                self.sensor,
                r * c
            )));
        }
        let v = counts.as_slice().map_err(|e| bad(format!("counts: {e}")))?;
        f.counts[..r * c].copy_from_slice(v);
        let rail = f.full_scale > 0.0 && v.iter().any(|x| *x >= f.full_scale);
        f.flags = if rail {
            f.flags | raw_flags::RAIL
        } else {
            f.flags & !raw_flags::RAIL
        };
        f.seq = self.sent;
        f.t_capture_ns = t_capture_ns.unwrap_or_else(now_ns);
        publisher.send(f).map_err(taxel_err)?;
        self.sent += 1;
        Ok(f.seq)
    }

    /// Closes the publisher (its iceoryx2 node is removed); also on garbage collection.
    fn close(&mut self) -> PyResult<()> {
        let sensor = &self.sensor;
        let ports = self.ports.get(|| format!("the publisher of {sensor}"))?;
        ports.publisher = None;
        ports.ipc = None;
        Ok(())
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __exit__(
        &mut self,
        _t: Option<Bound<'_, PyAny>>,
        _v: Option<Bound<'_, PyAny>>,
        _tb: Option<Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        self.close()
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(subscribe, m)?)?;
    m.add_class::<Subscription>()?;
    m.add_class::<Publisher>()?;
    m.add_class::<Force>()?;
    m.add_class::<Raw>()?;
    m.add_class::<Curvature>()?;
    m.add_class::<ReferenceValue>()?;
    m.add_class::<Flags>()
}
