#!/usr/bin/env python3
"""Fleet screening benchmark: the out-of-family rule's error rates, and throughput.

``--lots N``: N seeded lots (host/python/tests/fleet_lot.py: 200 three-axis gyros, 30 min at
10 Hz, numpy-simulated, each lot with one unit of 3x white noise, one of 5x bias instability
and one of 10x random walk on its x axis) fitted and screened in memory; prints how many lots
raised a false flag (a unit other than the three), with a 95% Clopper-Pearson interval, and
how often each planted unit was flagged.

``--throughput``: lots written as Parquet files (200 units of 30 min at 10 Hz, and 40 units
of 10 h at 10 Hz), each screened by ``python -m dynacal.fleet``
on a local Dask cluster of 2 workers and on a 2-process pool, against a plain shell-style
loop over ``dynacal fit FILE --model WN+GM+RW --json M`` (one process per unit, one at a time, as a
user would script the CLI); units per second for each.

Run from the repository root with the package installed (scripts/setup) and the CLI built in
release (cargo build --release -p dynacal):
    .venv/bin/python bench/fleet_bench.py --lots 40 --throughput
"""
import argparse
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / "host" / "python" / "tests"))

import numpy as np  # noqa: E402
import dynacal  # noqa: E402
from dynacal import fleet  # noqa: E402
from fleet_lot import CHANNEL_COLUMNS, RATE_HZ, simulate_lot, write_lot  # noqa: E402

MODEL = "WN+GM+RW"
N_UNITS = 200
SECONDS = 1800.0
PLANTED = {17: ("wn_sigma2", 9.0), 101: ("gm_sigma2", 25.0), 150: ("rw_sigma2", 100.0)}


def binomial_tail(k, n, p, upper):
    """P(X >= k) if upper else P(X <= k) for X ~ Binomial(n, p)."""
    terms = range(k, n + 1) if upper else range(0, k + 1)
    return sum(math.comb(n, i) * p**i * (1 - p) ** (n - i) for i in terms)


def clopper_pearson(k, n):
    """Exact 95% interval of a binomial proportion, by bisection on the tails."""
    def solve(f):
        lo, hi = 0.0, 1.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if f(mid) else (lo, mid)
        return 0.5 * (lo + hi)

    low = 0.0 if k == 0 else solve(lambda p: binomial_tail(k, n, p, True) < 0.025)
    high = 1.0 if k == n else solve(lambda p: binomial_tail(k, n, p, False) > 0.025)
    return low, high


def screen_in_memory(lot):
    rows = []
    n = lot.series.shape[0]
    t_s = np.arange(n, dtype=np.float64) / RATE_HZ
    for unit in range(lot.series.shape[1]):
        columns = {"t_s": t_s}
        columns.update({c: lot.series[:, unit, i] for i, c in enumerate(CHANNEL_COLUMNS)})
        rec = dynacal.Recording(name=f"unit{unit:03d}", columns=columns, sample_rate_hz=RATE_HZ)
        for channel in rec.channels():
            rows.append(fleet.fit_channel(f"unit{unit:03d}", rec, channel, MODEL))
    table, summary = fleet.fleet_table(rows, alpha=0.01)
    return set(table.loc[table["out_of_family"], "file"]), summary, plain_rule_flags(rows, summary)


def plain_rule_flags(rows, summary):
    """The units the plain robust rule would flag: |y - median| / (1.4826 MAD) beyond the
    normal quantile of the same per-test threshold, ignoring each unit's own estimation error
    (for comparison only)."""
    from scipy.stats import norm

    k = norm.isf(summary.p_threshold / 2.0)
    groups = {}
    for t in fleet.lot_tests(rows):
        if math.isfinite(t.y):
            groups.setdefault(t.key, []).append(t)
    flagged = set()
    for tests in groups.values():
        y = np.array([t.y for t in tests])
        mu = np.median(y)
        spread = 1.4826 * np.median(np.abs(y - mu))
        for t in tests:
            if abs(t.y - mu) > k * spread:
                flagged.add(rows[t.row]["file"])
    return flagged


def screen_lot(seed):
    """The units flagged in the seeded lot, and the rule's summary."""
    return screen_in_memory(simulate_lot(N_UNITS, SECONDS, PLANTED, seed=1000 + seed))


def error_rates(n_lots):
    from concurrent.futures import ProcessPoolExecutor

    planted_files = {f"unit{u:03d}": name for u, (name, _) in PLANTED.items()}
    lots_with_false_flag = 0
    false_flags = 0
    plain_lots, plain_false, plain_detected = 0, 0, 0
    detected = {name: 0 for name in planted_files.values()}
    with ProcessPoolExecutor() as pool:
        for seed, (flagged, summary, plain) in enumerate(pool.map(screen_lot, range(1, n_lots + 1)), 1):
            plain_others = plain - set(planted_files)
            plain_lots += bool(plain_others)
            plain_false += len(plain_others)
            plain_detected += len(plain & set(planted_files))
            others = flagged - set(planted_files)
            lots_with_false_flag += bool(others)
            false_flags += len(others)
            for f, name in planted_files.items():
                detected[name] += f in flagged
            k_low, k_high = summary.k_range()
            print(f"lot {seed}: flagged {sorted(flagged)} (k = {k_low:.2f} to {k_high:.2f}, "
                  f"{summary.n_tests} tests)", flush=True)
    low, high = clopper_pearson(lots_with_false_flag, n_lots)
    print(f"\nlots with a false flag: {lots_with_false_flag}/{n_lots} "
          f"(95% interval {low:.3f}..{high:.3f}; nominal 0.01); false flags in all: {false_flags}")
    for name, k in detected.items():
        print(f"planted {name} x{dict(PLANTED.values())[name]:g} (variance): flagged in {k}/{n_lots} lots")
    low, high = clopper_pearson(plain_lots, n_lots)
    print(f"the plain robust rule (no estimation error, normal tails): lots with a false flag "
          f"{plain_lots}/{n_lots} (95% interval {low:.3f}..{high:.3f}), false flags in all "
          f"{plain_false}, planted units flagged {plain_detected}/{3 * n_lots}")


def timed(cmd, **kw):
    start = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, **kw)
    return time.perf_counter() - start


def fleet_times(lot_dir, out, engine):
    """(first run, rerun) seconds of python -m dynacal.fleet: the rerun finds every unit done,
    so it is the fixed cost (start-up, the engine, the lot's table and report)."""
    cmd = [sys.executable, "-m", "dynacal.fleet", str(lot_dir), "--out", str(out),
           "--engine", engine, "--workers", "2"]
    return timed(cmd, stderr=subprocess.DEVNULL), timed(cmd, stderr=subprocess.DEVNULL)


def throughput(n_units, seconds):
    cli = ROOT / "target" / "release" / "dynacal"
    if not cli.exists():
        sys.exit(f"{cli}: build it first (cargo build --release -p dynacal)")
    work = Path(tempfile.mkdtemp(prefix="fleet-bench-"))
    try:
        lot_dir = work / "lot"
        write_lot(simulate_lot(n_units, seconds, {}, seed=7), lot_dir)
        files = sorted(lot_dir.iterdir())
        dask_first, dask_fixed = fleet_times(lot_dir, work / "o1", "dask")
        pool_first, pool_fixed = fleet_times(lot_dir, work / "o2", "local")
        start = time.perf_counter()
        (work / "cli").mkdir()
        for f in files:
            subprocess.run([str(cli), "fit", str(f), "--model", MODEL,
                            "--json", str(work / "cli" / (f.stem + ".json"))], check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        t_cli = time.perf_counter() - start
        n = len(files)
        print(f"\n{n} units of {seconds:g} s at {RATE_HZ:g} Hz ({int(seconds * RATE_HZ)} samples), "
              f"3 channels, model {MODEL}:")
        print(f"  loop over `dynacal fit` (one process at a time): {t_cli:.1f} s, {n / t_cli:.2f} units/s")
        for name, first, fixed in (("Dask LocalCluster of 2 workers", dask_first, dask_fixed),
                                   ("local pool of 2 processes", pool_first, pool_fixed)):
            per_unit = n / max(first - fixed, 1e-9)
            print(f"  dynacal.fleet, {name}: {first:.1f} s in all, {n / first:.2f} units/s "
                  f"({t_cli / first:.2f}x the CLI loop); fixed cost (a rerun) {fixed:.1f} s; "
                  f"beyond it {per_unit:.2f} units/s ({per_unit * t_cli / n:.2f}x the CLI loop)")
    finally:
        shutil.rmtree(work, ignore_errors=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lots", type=int, default=0)
    parser.add_argument("--throughput", action="store_true")
    args = parser.parse_args()
    print(f"dynacal {getattr(dynacal, '__version__', '?')}, python {sys.version.split()[0]}, "
          f"{os.cpu_count()} CPUs")
    if args.lots:
        error_rates(args.lots)
    if args.throughput:
        throughput(N_UNITS, SECONDS)
        throughput(40, 36000.0)


if __name__ == "__main__":
    main()
