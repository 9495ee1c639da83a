"""Recordings, calibrations and curvature models from Python, on a demo run recorded by the
logger and exported to MCAP and CSV by tests/python.rs; bad input raises TaxelError with the
command-line tools' message."""

import os
import time
import unittest

import numpy as np

import taxel
from _env import MODEL, SIM_CAL, cli_error, path


class Recordings(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.rec = taxel.read_recording(path("demo.taxrec"))

    def test_record_file_has_every_stream_and_field(self):
        rec = self.rec
        self.assertEqual(rec.kind, "taxrec")
        for s in ("raw", "force", "curvature", "reference"):
            self.assertIn(s, rec)
        raw = rec["raw"]
        n = len(raw["seq"])
        self.assertGreater(n, 100)
        rows, cols = int(raw["rows"][0]), int(raw["cols"][0])
        self.assertEqual(raw["counts"].shape, (n, rows, cols))
        self.assertEqual(raw["counts"].dtype, np.float32)
        self.assertTrue(np.all(np.diff(raw["seq"].astype(np.int64)) > 0))
        self.assertEqual(raw["t_capture_ns"].dtype, np.uint64)
        force = rec["force"]
        for field in ("seq", "t_capture_ns", "t_publish_ns", "sensor", "total_force_n",
                      "block_force_n", "block_reading", "cal_version", "cal_generation",
                      "curvature_model_version", "flags", "zero_age_s"):
            self.assertIn(field, force)
        self.assertEqual(force["block_force_n"].shape[0], len(force["seq"]))
        self.assertEqual(set(force["sensor"]), {"s0"})
        cur = rec["curvature"]
        self.assertEqual(cur["baseline"].shape[1:], (rows, cols))

    def test_mcap_and_csv_hold_the_same_frames(self):
        raw = self.rec["raw"]
        m = taxel.read_recording(path("demo.mcap"))
        self.assertEqual(m.kind, "mcap")
        np.testing.assert_array_equal(m["raw"]["counts"], raw["counts"])
        np.testing.assert_array_equal(m["force"]["total_force_n"], self.rec["force"]["total_force_n"])
        c = taxel.read_recording(path("demo.csv"))
        self.assertEqual(c.kind, "csv")
        self.assertEqual(c["raw"]["counts"].shape, raw["counts"].shape)
        np.testing.assert_allclose(c["raw"]["counts"], raw["counts"], rtol=1e-6)
        self.assertIn("force_n", c["reference"])

    def test_a_record_file_cut_short_reads_to_the_cut_with_a_warning(self):
        with open(path("demo.taxrec"), "rb") as f:
            data = f.read()
        # Cut inside a record (a cut on a record boundary is a clean end): walk the records
        # (a 12-byte file header, then per record its length and checksum, 4 bytes each, and
        # the payload) to the first that ends past two thirds of the file.
        at = 12
        while True:
            size = 8 + int.from_bytes(data[at:at + 4], "little")
            if at + size > len(data) * 2 // 3:
                break
            at += size
        cut = path("cut.taxrec")
        with open(cut, "wb") as f:
            f.write(data[: at + size // 2])
        with self.assertWarns(UserWarning) as w:
            rec = taxel.read_recording(cut)
        self.assertIn("cut short at record", str(w.warning))
        n = len(rec["raw"]["seq"])
        self.assertTrue(0 < n < len(self.rec["raw"]["seq"]))
        np.testing.assert_array_equal(rec["raw"]["counts"], self.rec["raw"]["counts"][:n])
        # Damage inside the file is an error naming where.
        bad = bytearray(data)
        at = len(bad) // 2
        bad[at:at + 64] = bytes(64)
        damaged = path("damaged.taxrec")
        with open(damaged, "wb") as f:
            f.write(bad)
        with self.assertRaises(taxel.TaxelError) as e:
            taxel.read_recording(damaged)
        self.assertIn("damaged.taxrec: damaged at record", str(e.exception))

    def test_sensor_filter_and_pandas(self):
        with self.assertRaises(taxel.TaxelError) as e:
            taxel.read_recording(path("demo.taxrec"), sensor="nobody")
        self.assertIn("no records for sensor nobody", str(e.exception))
        try:
            import pandas  # noqa: F401
        except ImportError:
            self.skipTest("pandas is not installed")
        df = self.rec.dataframe("force")
        self.assertEqual(len(df), len(self.rec["force"]["seq"]))
        self.assertIn("block_force_n0", df.columns)

    def test_bad_files_raise_the_cli_message(self):
        missing = path("missing.taxrec")
        with self.assertRaises(taxel.TaxelError) as e:
            taxel.read_recording(missing)
        self.assertIn("missing.taxrec", str(e.exception))
        self.assertEqual(str(e.exception), cli_error("logger", "export", missing, "--csv", path("x.csv")))
        garbage = path("garbage.csv")
        with open(garbage, "w") as f:
            f.write("t_s,n0\n0.0,1\nzero,2\n")
        with self.assertRaises(taxel.TaxelError) as e:
            taxel.read_recording(garbage)
        self.assertIn("garbage.csv:3", str(e.exception))
        self.assertTrue(isinstance(e.exception, ValueError))
        cut = path("cut.mcap")
        with open(path("demo.mcap"), "rb") as f:
            data = f.read()
        with open(cut, "wb") as f:
            f.write(data[: len(data) // 3])
        with self.assertRaises(taxel.TaxelError) as e:
            taxel.read_recording(cut)
        self.assertIn("cut.mcap", str(e.exception))


class Calibrations(unittest.TestCase):
    def test_apply_is_the_calibrators_computation(self):
        rec = taxel.read_recording(path("demo.taxrec"))
        cal = taxel.Calibration.load(path("calibration.toml"))
        self.assertEqual((cal.rows, cal.cols), rec["raw"]["counts"].shape[1:])
        cur, force, raw = rec["curvature"], rec["force"], rec["raw"]
        # Frames well after the last baseline arrived used it: the same forces offline.
        last = len(cur["seq"]) - 1
        t0 = int(cur["t_capture_ns"][last]) + 300_000_000
        keep_raw = raw["t_capture_ns"] > t0
        if keep_raw.sum() < 10:
            self.skipTest("too few frames after the last baseline")
        out = cal.apply(raw["counts"][keep_raw], curvature_m1=float(cur["curvature_m1"][last]),
                        baseline=cur["baseline"][last], dynamics=False)
        by_seq = dict(zip(force["seq"].tolist(), force["total_force_n"].tolist()))
        got = out["total_force_n"]
        want = np.array([by_seq.get(s, np.nan) for s in raw["seq"][keep_raw].tolist()], np.float32)
        ok = ~np.isnan(want)
        self.assertGreater(ok.sum(), 10)
        np.testing.assert_allclose(got[ok], want[ok], rtol=1e-5, atol=1e-4)

    def test_shapes_flags_and_bad_input(self):
        cal = taxel.Calibration.load(SIM_CAL)
        r, c = cal.rows, cal.cols
        frames = np.full((5, r, c), 300.0, np.float32)
        a = cal.apply(frames)
        b = cal.apply(frames.reshape(5, r * c))
        np.testing.assert_array_equal(a["total_force_n"], b["total_force_n"])
        self.assertEqual(a["block_force_n"].shape, (5, len(cal.block_names)))
        one = cal.apply(frames[0])
        self.assertEqual(one["total_force_n"].shape, (1,))
        # No curvature given: the file's default, flagged as the live calibrator does.
        self.assertTrue(np.all(a["flags"] & (1 << 3)))
        per = cal.apply(frames, curvature_m1=np.linspace(10, 50, 5))
        self.assertEqual(per["curvature_m1"].tolist(), np.linspace(10, 50, 5).astype(np.float32).tolist())
        with self.assertRaises(taxel.TaxelError) as e:
            cal.apply(np.zeros((5, r + 1, c)))
        self.assertIn(f"do not fit calibration {SIM_CAL}", str(e.exception))
        with self.assertRaises(taxel.TaxelError) as e:
            cal.apply(frames, curvature_m1=[1.0, 2.0])
        self.assertIn("curvature_m1 has 2 values for 5 frames", str(e.exception))

    def test_bad_calibration_files_raise_the_cli_message(self):
        with open(MODEL, "rb") as f:
            model = f.read()
        for name, text in (("missing.toml", None), ("broken.toml", "version = \"three\"\n\x01"),
                           ("model.toml", model)):
            p = path(name)
            if text is not None:
                with open(p, "wb") as f:
                    f.write(text if isinstance(text, bytes) else text.encode())
            with self.assertRaises(taxel.TaxelError) as e:
                taxel.Calibration.load(p)
            self.assertIn(name, str(e.exception))
            self.assertEqual(str(e.exception),
                             cli_error("calibrator", "run", "--sensor", "pyclierr", "--calibration", p))

    def test_a_ten_minute_recording_at_1khz_in_under_a_second(self):
        cal = taxel.Calibration.load(SIM_CAL)
        n = 600_000
        frames = np.random.default_rng(1).uniform(200, 600, (n, cal.rows, cal.cols)).astype(np.float32)
        t = np.arange(n, dtype=np.uint64) * 1_000_000
        t0 = time.perf_counter()
        out = cal.apply(frames, curvature_m1=30.0, t_capture_ns=t)
        took = time.perf_counter() - t0
        print(f"\nCalibration.apply: {n} frames of {cal.rows} x {cal.cols} in {took:.3f} s")
        self.assertEqual(out["total_force_n"].shape, (n,))
        # 1 s on an idle machine; the bound leaves room for a loaded CI host.
        self.assertLess(took, 5.0)


class CurvatureModels(unittest.TestCase):
    def test_predict_is_the_estimators_prediction(self):
        rec = taxel.read_recording(path("demo.taxrec"))
        cur = rec["curvature"]
        model = taxel.CurvatureModel.load(MODEL)
        first = int(np.argmin(cur["estimate_index"]))
        if not (cur["flags"][first] & 2):
            self.skipTest("the demo's first estimate is not a learned one")
        got = model.predict(cur["baseline"][first])
        self.assertEqual(got["curvature_m1"].shape, (1,))
        self.assertAlmostEqual(float(got["curvature_m1"][0]), float(cur["curvature_m1"][first]), places=3)
        many = model.predict(cur["baseline"])
        flat = model.predict(cur["baseline"].reshape(len(cur["seq"]), -1))
        np.testing.assert_array_equal(many["curvature_m1"], flat["curvature_m1"])
        self.assertEqual(many["out_of_range"].dtype, np.bool_)

    def test_bad_model_input(self):
        model = taxel.CurvatureModel.load(MODEL)
        with self.assertRaises(taxel.TaxelError) as e:
            model.predict(np.zeros(model.n_nodes + 1))
        self.assertIn(f"model expects {model.n_nodes} nodes per baseline, the data has {model.n_nodes + 1}",
                      str(e.exception))
        with self.assertRaises(taxel.TaxelError) as e:
            taxel.CurvatureModel.load(SIM_CAL)
        self.assertEqual(str(e.exception),
                         cli_error("estimator", "run", "--sensor", "pyclierr", "--model", SIM_CAL))


if __name__ == "__main__":
    unittest.main()
