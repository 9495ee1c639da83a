"""The live streams from Python, against the real processes that tests/python.rs started under
a unique prefix: a simulated sensor through estimator and calibrator (sensor ``s0``), and a
calibrator alone that the tests feed with ``taxel.Publisher`` (sensor ``py0``)."""

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
import unittest

import numpy as np

import taxel
from _env import PREFIX, SIM_CAL, cli_error


def needs_pipeline():
    if PREFIX is None:
        raise unittest.SkipTest("TAXEL_TEST_PREFIX is not set (tests/python.rs sets it)")


class Streams(unittest.TestCase):
    def setUp(self):
        needs_pipeline()

    def take(self, n, **kw):
        out = []
        with taxel.subscribe("s0", prefix=PREFIX, timeout=5.0, **kw) as sub:
            for s in sub:
                out.append(s)
                if len(out) == n:
                    break
        self.assertEqual(len(out), n, f"{len(out)} of {n} samples within 5 s")
        return out

    def test_force_samples_in_every_wake_mode(self):
        for wake in ("event", "busy", "adaptive"):
            got = self.take(40, wake=wake)
            seqs = [s.seq for s in got]
            self.assertEqual(seqs, sorted(seqs), wake)
            s = got[-1]
            self.assertIsInstance(s, taxel.Force)
            self.assertEqual(s.sensor, "s0")
            self.assertEqual(s.cal_version, 1)
            self.assertEqual(s.block_force_n.dtype, np.float32)
            self.assertIn(s.flags.saturated, (True, False))
            self.assertIsInstance(s.flags.no_baseline, bool)
            self.assertGreater(s.t_capture_ns, 0)
            # Live samples, not a backlog from the pipeline's start (seconds old): a check, not
            # a latency measurement (`taxel bench` measures that). The bound leaves room for a
            # loaded machine: under a CI build the adaptive mode's median was 86 ms once.
            ages = [x.age_ns for x in got[5:]]
            self.assertLess(np.median(ages), 500_000_000, wake)

    def test_raw_and_curvature(self):
        raw = self.take(5, stream="raw")
        self.assertEqual(raw[0].counts.shape, (raw[0].rows, raw[0].cols))
        self.assertEqual(raw[0].counts.dtype, np.float32)
        self.assertEqual(raw[0].source, 1)
        # Curvature has history 1: a late subscriber gets the latest estimate.
        [c] = self.take(1, stream="curvature")
        self.assertIsInstance(c, taxel.Curvature)
        self.assertEqual(c.baseline.shape, (raw[0].rows, raw[0].cols))
        self.assertTrue(c.flags.configured or c.flags.estimated)

    def test_timeout_ends_iteration(self):
        t0 = time.monotonic()
        with taxel.subscribe("nobody", prefix=PREFIX, timeout=0.3) as sub:
            self.assertEqual(list(sub), [])
            self.assertIsNone(sub.next(timeout=0.05))
            self.assertEqual(sub.poll(), [])
        self.assertLess(time.monotonic() - t0, 3.0)

    def test_the_gil_is_released_while_waiting(self):
        count = [0]
        stop = threading.Event()

        def spin():
            while not stop.is_set():
                count[0] += 1

        th = threading.Thread(target=spin)
        th.start()
        try:
            with taxel.subscribe("nobody", prefix=PREFIX) as sub:
                before = count[0]
                self.assertIsNone(sub.next(timeout=0.5))
                during = count[0] - before
        finally:
            stop.set()
            th.join()
        self.assertGreater(during, 1000)

    def test_another_thread_gets_a_taxel_error(self):
        errors = []

        def use(obj, *calls):
            for call in calls:
                try:
                    call(obj)
                    errors.append(None)
                except taxel.TaxelError as e:
                    errors.append(str(e))

        sub = taxel.subscribe("nobody", prefix=PREFIX)
        pub = taxel.Publisher("nobody", prefix=PREFIX, rows=2, cols=2)
        th = threading.Thread(target=lambda: (
            use(sub, lambda s: s.next(timeout=0.01), lambda s: s.poll(), lambda s: s.close()),
            use(pub, lambda p: p.publish(np.zeros((2, 2), np.float32)), lambda p: p.close())))
        th.start()
        th.join()
        self.assertEqual(len(errors), 5)
        for e in errors:
            self.assertIsNotNone(e)
            self.assertIn("used from a thread other than the one that made it", e)
        self.assertIn("the subscription to taxel/nobody/force", errors[0])
        self.assertIn("the publisher of nobody", errors[3])
        # Still usable on the thread that made them.
        self.assertIsNone(sub.next(timeout=0.01))
        self.assertEqual(pub.publish(np.zeros((2, 2), np.float32)), 0)
        sub.close()
        pub.close()

    def test_bad_arguments_raise_the_cli_message(self):
        with self.assertRaises(taxel.TaxelError) as e:
            taxel.subscribe("bad id!", prefix=PREFIX)
        self.assertEqual(str(e.exception), cli_error("control", "--sensor", "bad id!", "--seconds", "1"))
        with self.assertRaises(taxel.TaxelError) as e:
            taxel.subscribe("s0", stream="torque", prefix=PREFIX)
        self.assertIn("unknown stream \"torque\"", str(e.exception))
        with self.assertRaises(taxel.TaxelError):
            taxel.subscribe("s0", wake="sometimes", prefix=PREFIX)
        with self.assertRaises(ValueError):
            taxel.subscribe("s0", prefix=PREFIX, timeout=-1)


class PythonPublisher(unittest.TestCase):
    def setUp(self):
        needs_pipeline()

    def test_frames_published_from_python_are_calibrated_as_offline(self):
        cal = taxel.Calibration.load(SIM_CAL)
        r, c = cal.rows, cal.cols
        rng = np.random.default_rng(7)
        frames = rng.uniform(250, 700, (60, r, c)).astype(np.float32)
        got = {}
        with taxel.subscribe("py0", prefix=PREFIX, timeout=5.0) as sub, \
                taxel.Publisher("py0", prefix=PREFIX, full_scale=1023) as pub:
            # The calibrator connects to the new publisher within a few ms; send until it did.
            deadline = time.monotonic() + 10
            first = None
            while first is None and time.monotonic() < deadline:
                pub.publish(frames[0])
                first = sub.next(timeout=0.1)
            self.assertIsNotNone(first, "the calibrator never answered")
            base = pub.sent
            for f in frames:
                pub.publish(f)
                time.sleep(0.002)
            while len(got) < len(frames):
                s = sub.next(timeout=5.0)
                if s is None:
                    break
                if s.seq >= base:
                    got[s.seq - base] = s
        self.assertEqual(len(got), len(frames))
        offline = cal.apply(frames)
        live = np.array([got[i].total_force_n for i in range(len(frames))], np.float32)
        np.testing.assert_array_equal(live, offline["total_force_n"])
        blocks = np.array([got[i].block_force_n for i in range(len(frames))], np.float32)
        np.testing.assert_array_equal(blocks, offline["block_force_n"])
        flags = np.array([got[i].flags.bits for i in range(len(frames))], np.uint32)
        np.testing.assert_array_equal(flags, offline["flags"])

    def test_poll_takes_what_waits_in_every_wake_mode(self):
        for i, wake in enumerate(("event", "busy", "adaptive")):
            sensor = f"pyq{i}"
            with taxel.subscribe(sensor, stream="raw", prefix=PREFIX, wake=wake) as sub, \
                    taxel.Publisher(sensor, prefix=PREFIX) as pub:
                self.assertEqual(sub.poll(), [])
                for k in range(3):
                    pub.publish(np.full((2, 3), k, np.float32), t_capture_ns=taxel.now_ns())
                got = sub.poll()
                self.assertEqual([s.seq for s in got], [0, 1, 2], wake)
                self.assertEqual(got[2].counts.tolist(), [[2.0] * 3] * 2)
                self.assertEqual(got[0].source, 4)
                self.assertEqual(sub.poll(limit=1), [])

    def test_bad_frames(self):
        with taxel.Publisher("py1", prefix=PREFIX) as pub:
            with self.assertRaises(taxel.TaxelError):
                pub.publish(np.zeros(7))
            pub.publish(np.zeros((4, 4)))
            with self.assertRaises(taxel.TaxelError) as e:
                pub.publish(np.zeros((4, 5)))
            self.assertIn("(4, 5)", str(e.exception))
            self.assertEqual(pub.sent, 1)
        with self.assertRaises(taxel.TaxelError):
            taxel.Publisher("py1", prefix=PREFIX, readout="thermistor")


class CtrlC(unittest.TestCase):
    def test_sigint_ends_a_waiting_iteration_cleanly(self):
        needs_pipeline()
        script = textwrap.dedent(f"""
            import signal, sys, taxel
            # As in a terminal, even when this test runs in the background (SIGINT ignored).
            signal.signal(signal.SIGINT, signal.default_int_handler)
            sub = taxel.subscribe("nobody", prefix={PREFIX!r}, wake=sys.argv[1])
            print("waiting", flush=True)
            try:
                for s in sub:
                    pass
            except KeyboardInterrupt:
                sub.close()
                print("interrupted", flush=True)
        """)
        for wake in ("event", "adaptive", "busy"):
            p = subprocess.Popen([sys.executable, "-c", script, wake], stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)
            self.assertEqual(p.stdout.readline().strip(), "waiting")
            time.sleep(0.3)
            t0 = time.monotonic()
            p.send_signal(signal.SIGINT)
            out, err = p.communicate(timeout=10)
            self.assertEqual(p.returncode, 0, err)
            self.assertIn("interrupted", out)
            self.assertLess(time.monotonic() - t0, 2.0, wake)


if __name__ == "__main__":
    unittest.main()
