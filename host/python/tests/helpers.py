"""What the Python tests share: the command line of this checkout and the shared data.

The command line is ``DYNACAL_BIN`` (by default ``target/debug/dynacal``, which
``scripts/test`` builds before running the tests); the measured recordings come from
``DYNACAL_DATA`` (default ``../shared/data``).
"""

import os
import pathlib
import subprocess

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[3]
BIN = pathlib.Path(os.environ.get("DYNACAL_BIN", ROOT / "target" / "debug" / "dynacal"))
DATA = pathlib.Path(os.environ.get("DYNACAL_DATA", ROOT.parent / "shared" / "data"))


def cli(*args):
    """Runs the command line; its stdout, or the test fails with its stderr."""
    done = subprocess.run([str(BIN), *map(str, args)], capture_output=True, text=True)
    assert done.returncode == 0, f"dynacal {' '.join(map(str, args))}: {done.stderr}"
    return done.stdout


def relative_difference(a, b):
    """The largest |a - b| / |b| over the elements."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-300)))
