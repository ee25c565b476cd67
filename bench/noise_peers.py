"""Python peers of `dynacal noise` (BENCHMARKS.md, "Against the peers"): Kalibr's four
numbers per axis from a static recording, by
- `allan_variance_analyzer` (PyPI, 1.0.4): its own Allan deviations over periods 0.1 s ..
  min(1000 s, a third of the record) in steps of 0.1 s, then its white-noise line (slope
  -1/2 through tau <= 10 s, read at tau = 1 s) and rate-random-walk line (slope +1/2,
  read at tau = 3 s), per axis;
- `allantools` with the same two lines, as `allan_variance_ros`'s analysis draws them: the
  overlapping Allan deviation at octave averaging times, N the -1/2 line through the taus up
  to 10 s (read at 1 s), K the +1/2 line through the taus from 100 s on (read at 3 s).

Usage: noise_peers.py RATE_HZ OUT.json FILE.f64 [...]; each FILE holds little-endian f64 rows
[ax ay az gx gy gz] (m/s^2, rad/s). Prints nothing; writes {file: {peer: {"N": [6], "K": [6],
"seconds": s}}}.
Install: pip install -r bench/requirements.txt allan-variance-analyzer==1.0.4
"""
import json
import sys
import time

import allantools
import numpy as np
from allan_variance_analyzer.analysis import compute_rate_random_walk, compute_white_noise_params
from allan_variance_analyzer.statistics import compute_allan_variances


def ava(data, rate):
    """allan_variance_analyzer's own steps (its `run` without the plots and the yaml)."""
    t0 = time.perf_counter()
    x = data.copy()
    x[:, 3:6] = np.rad2deg(x[:, 3:6])
    top = min(1000.0, len(x) / rate / 3.0)
    periods = np.round(np.arange(0.1, top, 0.1), 10)
    adev = np.sqrt(compute_allan_variances(x, periods, rate, 0))
    brk = int(np.where(periods == 10.0)[0][0])
    n = np.concatenate([compute_white_noise_params(periods, adev[:, :3], brk)[0],
                        np.deg2rad(compute_white_noise_params(periods, adev[:, 3:], brk)[0])])
    k = np.concatenate([compute_rate_random_walk(periods, adev[:, :3])[0],
                        np.deg2rad(compute_rate_random_walk(periods, adev[:, 3:])[0])])
    return {"N": n.tolist(), "K": k.tolist(), "seconds": time.perf_counter() - t0}


def line_value(taus, adev, slope, keep, at):
    """The log-log line of the given slope fitted to adev over taus where keep, read at `at`."""
    b = np.mean(np.log10(adev[keep]) - slope * np.log10(taus[keep]))
    return 10 ** (b + slope * np.log10(at))


def slope_lines(data, rate):
    t0 = time.perf_counter()
    n, k = [], []
    for axis in range(6):
        taus, adev, _, _ = allantools.oadev(data[:, axis], rate=rate, data_type="freq", taus="octave")
        n.append(line_value(taus, adev, -0.5, taus <= 10.0, 1.0))
        k.append(line_value(taus, adev, 0.5, taus >= 100.0, 3.0))
    return {"N": n, "K": k, "seconds": time.perf_counter() - t0}


def main():
    rate = float(sys.argv[1])
    out = {}
    for path in sys.argv[3:]:
        data = np.fromfile(path, dtype="<f8").reshape(-1, 6)
        out[path] = {"allan_variance_analyzer": ava(data, rate), "allantools_slope_lines": slope_lines(data, rate)}
    with open(sys.argv[2], "w") as f:
        json.dump(out, f)


if __name__ == "__main__":
    main()
