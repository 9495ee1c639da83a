"""What tests/python.rs hands the Python tests: the taxel binary, a directory of recordings and
files made for them, and (for the live tests) the prefix of a running pipeline."""

import os
import subprocess
import unittest

TAXEL = os.environ.get("TAXEL_EXE")
DIR = os.environ.get("TAXEL_TEST_DIR")
PREFIX = os.environ.get("TAXEL_TEST_PREFIX")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SIM_CAL = os.path.join(ROOT, "calibrations", "sim-default.toml")
MODEL = os.path.join(ROOT, "models", "curvature-default.taxcrv")


def path(name):
    if DIR is None:
        raise unittest.SkipTest("TAXEL_TEST_DIR is not set (tests/python.rs sets it)")
    return os.path.join(DIR, name)


def cli_error(*args):
    """Runs ``taxel args...`` (which must fail) and returns its one-line message, without the
    ``program: error: `` in front."""
    if TAXEL is None:
        raise unittest.SkipTest("TAXEL_EXE is not set (tests/python.rs sets it)")
    env = dict(os.environ, TAXEL_PREFIX=PREFIX or "txpycli_")
    r = subprocess.run([TAXEL, *args], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode != 0, (args, r.stdout, r.stderr)
    lines = [l for l in r.stderr.splitlines() if ": error: " in l]
    assert lines, r.stderr
    return lines[-1].split(": error: ", 1)[1]
