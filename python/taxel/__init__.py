"""taxel from Python: the live streams of the taxel middleware, its recordings, calibrations and
curvature models, running the same Rust code as the taxel processes (docs/python.md).

Live::

    import taxel
    for s in taxel.subscribe("s0", stream="force", timeout=1.0):
        print(s.seq, s.total_force_n, s.block_force_n, s.flags.saturated)

Offline::

    rec = taxel.read_recording("run.taxrec")          # .taxrec, .csv/.csv.gz or .mcap
    cal = taxel.Calibration.load("cal.toml")
    forces = cal.apply(rec["raw"]["counts"], curvature_m1=30.0)

Every failure raises ``taxel.TaxelError`` (a ``ValueError``) with the one-line message the
command-line tools print.
"""

import numpy as np

from . import _taxel
from ._taxel import (
    MAX_BLOCKS,
    MAX_NODES,
    Curvature,
    Flags,
    Force,
    Raw,
    ReferenceValue,
    Subscription,
    TaxelError,
    now_ns,
    subscribe,
)

__all__ = [
    "Calibration",
    "CurvatureModel",
    "Curvature",
    "Flags",
    "Force",
    "MAX_BLOCKS",
    "MAX_NODES",
    "Publisher",
    "Raw",
    "Recording",
    "ReferenceValue",
    "Subscription",
    "TaxelError",
    "now_ns",
    "read_recording",
    "subscribe",
]


def _f32(a):
    return np.ascontiguousarray(a, dtype=np.float32)


def _f64(a):
    return np.ascontiguousarray(a, dtype=np.float64)


def _column(v):
    # Sensor ids come as (codes, names): an object array of the ids.
    if isinstance(v, tuple):
        codes, names = v
        return np.array(names, dtype=object)[codes]
    return v


class Recording:
    """A recording's streams: ``rec["force"]`` is a dict of NumPy columns, one per field of the
    stream's message (docs/messages.md); node arrays are (n, rows, cols). ``kind`` is
    ``"taxrec"``, ``"mcap"`` or ``"csv"`` (a CSV gives ``raw`` and ``reference``)."""

    def __init__(self, path, kind, streams):
        self.path = str(path)
        self.kind = kind
        self.streams = {}
        for name, cols in streams.items():
            self.streams[name] = {k: _column(v) for k, v in cols.items()}

    def __getitem__(self, stream):
        try:
            return self.streams[stream]
        except KeyError:
            raise KeyError(
                f"{self.path} has no {stream!r} stream (it has {', '.join(self.streams)})"
            ) from None

    def __contains__(self, stream):
        return stream in self.streams

    def __iter__(self):
        return iter(self.streams)

    def keys(self):
        return self.streams.keys()

    def __len__(self):
        return len(self.streams)

    def __repr__(self):
        parts = []
        for name, cols in self.streams.items():
            n = len(next(iter(cols.values()))) if cols else 0
            parts.append(f"{name}: {n}")
        return f"Recording({self.path!r}, {self.kind}, {', '.join(parts)})"

    def dataframe(self, stream):
        """The stream as a pandas DataFrame (needs pandas): one column per scalar field, and
        one per entry of an array field (``counts`` -> ``counts0`` .. ``counts15``)."""
        import pandas as pd

        data = {}
        for k, v in self[stream].items():
            if v.ndim == 1:
                data[k] = v
            else:
                flat = v.reshape(v.shape[0], -1)
                for j in range(flat.shape[1]):
                    data[f"{k}{j}"] = flat[:, j]
        return pd.DataFrame(data)

    def dataframes(self):
        """Every stream as a pandas DataFrame, by stream name (needs pandas)."""
        return {name: self.dataframe(name) for name in self.streams}


def read_recording(path, sensor=None):
    """Reads a record file (``.taxrec``), an MCAP file or a recording CSV (``.csv``,
    ``.csv.gz``) into a :class:`Recording`. ``sensor`` keeps one sensor's records."""
    kind, streams = _taxel.read_recording(str(path), sensor)
    return Recording(path, kind, streams)


class Calibration:
    """A validated calibration file; ``apply`` runs the calibrator's computation."""

    def __init__(self, inner):
        self._inner = inner

    @classmethod
    def load(cls, path):
        """Reads, parses and validates a calibration file, as the calibrator does."""
        return cls(_taxel.Calibration.load(str(path)))

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def __repr__(self):
        return repr(self._inner)

    def apply(self, counts, curvature_m1=None, baseline=None, t_s=None, t_capture_ns=None,
              dynamics=True):
        """Forces for every frame of ``counts`` ((rows, cols), (n, rows, cols) or (n, nodes)).

        ``curvature_m1``: one value or one per frame (default: the file's default curvature,
        flagged ``curvature_defaulted``). ``baseline``: the no-load frame to zero on (default:
        the file's ``no_load_reading``). ``t_s`` or ``t_capture_ns``: the frames' times, which
        the dynamic terms need (without them only the static model runs).

        Returns a dict of ``total_force_n``, ``total_reading``, ``curvature_m1``, ``flags``
        (n,) and ``block_force_n``, ``block_reading`` (n, blocks)."""
        if t_s is not None and t_capture_ns is None:
            t = _f64(t_s)
            t_capture_ns = np.round((t - t.min()) * 1e9).astype(np.uint64) if t.size else t
        return self._inner.apply(
            _f32(counts),
            None if curvature_m1 is None else _f64(np.atleast_1d(curvature_m1)),
            None if baseline is None else _f32(baseline),
            None if t_capture_ns is None else np.ascontiguousarray(t_capture_ns, dtype=np.uint64),
            bool(dynamics),
        )


class CurvatureModel:
    """A curvature model file (``.taxcrv``); ``predict`` runs the estimator's predictor."""

    def __init__(self, inner):
        self._inner = inner

    @classmethod
    def load(cls, path):
        """Reads and checks a curvature model file, as the estimator does."""
        return cls(_taxel.CurvatureModel.load(str(path)))

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def __repr__(self):
        return repr(self._inner)

    def predict(self, baseline):
        """Curvature (1/m) of one no-load baseline ((nodes,) or (rows, cols)) or of many
        ((n, nodes) or (n, rows, cols)): a dict of ``curvature_m1``, ``sd_m1`` and
        ``out_of_range`` arrays (n,)."""
        return self._inner.predict(_f64(baseline))


class Publisher:
    """Sends raw frames on ``taxel/<sensor>/raw``, as a taxel publisher would, so a lab's own
    reader script can feed the estimator and calibrator. ``publish(counts, t_capture_ns=None)``
    returns the frame's ``seq``."""

    def __init__(self, sensor, prefix=None, rows=None, cols=None, full_scale=0.0, readout=None):
        self._inner = _taxel.Publisher(sensor, prefix, rows, cols, float(full_scale), readout)

    def publish(self, counts, t_capture_ns=None):
        return self._inner.publish(_f32(counts), t_capture_ns)

    def close(self):
        self._inner.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def sensor(self):
        return self._inner.sensor

    @property
    def prefix(self):
        return self._inner.prefix

    @property
    def sent(self):
        return self._inner.sent
