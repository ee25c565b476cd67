#!/usr/bin/env python3
"""Wavelet variance benchmark: dynacal vs allantools.oadev vs a numpy prefix-sum Haar WV.

One run generates one seeded series (integer counts stored as little-endian f64: a large
offset, white noise and a random-walk bias, like an accelerometer axis), writes it once to
bench/.data/series.f64, and every tool reads that same file. Each tool runs in its own process
so its peak memory (VmHWM) is its own; times are the minimum over REPEATS runs. The script
checks that the tools agree numerically and prints ratios.

Setup and run (from the repository root):
    python3 -m venv bench/.venv && bench/.venv/bin/pip install -r bench/requirements.txt
    bench/.venv/bin/python bench/wv_bench.py            # sizes 1e6 and 1e7
The dynacal-python worker runs in the repository's .venv (scripts/setup installs the package
there; DYNACAL_PYTHON overrides it).
"""
import argparse
import json
import os
import platform
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATA = os.path.join(HERE, ".data")
SERIES = os.path.join(DATA, "series.f64")
RATE_HZ = 100.0
DYNACAL_PYTHON = os.environ.get("DYNACAL_PYTHON", os.path.join(ROOT, ".venv", "bin", "python"))


def rss_mib(field):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def default_max_level(n):
    return max(int(np.floor(np.log2(n))) - 1, 1)


def numpy_haar_wv(x):
    """Haar MODWT WV from a plain numpy cumulative sum (the usual vectorised recipe)."""
    n = len(x)
    s = np.concatenate(([0.0], np.cumsum(x)))
    out = []
    for j in range(1, default_max_level(n) + 1):
        h = 1 << (j - 1)
        d = s[2 * h:] - 2.0 * s[h:n + 1 - h] + s[:n + 1 - 2 * h]
        out.append(float(np.dot(d, d)) / (4.0 ** j) / (n + 1 - 2 * h))
    return out


def allantools_wv(x):
    """Overlapping Allan deviation at all octave taus; WV_j = oadev(2^{j-1})^2 / 2."""
    import allantools

    taus, adev, _, _ = allantools.oadev(x, rate=RATE_HZ, data_type="freq", taus="octave")
    m = np.rint(np.asarray(taus) * RATE_HZ).astype(np.int64)
    return {int(mm): float(a) ** 2 / 2.0 for mm, a in zip(m, adev)}


def dynacal_python_wv(x):
    """The Python package (host/python): numpy array in, the library's WV out."""
    import dynacal

    return dynacal.wv(x, 1.0 / RATE_HZ).variance.tolist()


def worker(tool, n, repeats):
    x = np.fromfile(SERIES, dtype="<f8", count=n)
    baseline = rss_mib("VmRSS:")
    fn = {"numpy": numpy_haar_wv, "allantools": allantools_wv, "dynacal-python": dynacal_python_wv}[tool]
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn(x)
        times.append(time.perf_counter() - t0)
    print(json.dumps({"tool": tool, "n": n, "time_min_s": min(times),
                      "time_median_s": sorted(times)[len(times) // 2],
                      "baseline_rss_mib": baseline, "peak_rss_mib": rss_mib("VmHWM:"),
                      "result": result}))


def run_json(cmd, env=None):
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


def max_rel(a, b):
    return max(abs(x - y) / abs(y) for x, y in zip(a, b))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="1000000,10000000")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=20151015)
    ap.add_argument("--worker", nargs=2, metavar=("TOOL", "N"))
    args = ap.parse_args()
    if args.worker:
        worker(args.worker[0], int(args.worker[1]), args.repeats)
        return

    sizes = [int(float(s)) for s in args.sizes.split(",")]
    os.makedirs(DATA, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    n_max = max(sizes)
    walk = np.cumsum(rng.normal(0.0, 0.05, n_max))
    counts = np.rint(100_000.0 + walk + rng.normal(0.0, 20.0, n_max))
    counts.astype("<f8").tofile(SERIES)
    del walk, counts
    print(f"series: {n_max} samples (seed {args.seed}) -> {SERIES}")

    subprocess.run(["cargo", "build", "--release", "--quiet", "--example", "bench_wv"],
                   cwd=ROOT, check=True)
    exe = os.path.join(ROOT, "target", "release", "examples", "bench_wv")
    cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo")
                if l.startswith("model name")), platform.processor())
    print(f"machine: {cpu}, {os.cpu_count()} logical CPUs, {platform.platform()}")
    print(f"python {platform.python_version()}, numpy {np.__version__}, "
          f"allantools {__import__('allantools').__version__}")

    results = []
    for n in sizes:
        rust = {}
        for threads in (os.cpu_count(), 1):
            env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
            rust[threads] = run_json([exe, SERIES, str(n), str(args.repeats)], env=env)
        npy = run_json([sys.executable, __file__, "--worker", "numpy", str(n),
                        "--repeats", str(args.repeats)])
        alt = run_json([sys.executable, __file__, "--worker", "allantools", str(n),
                        "--repeats", str(args.repeats)])
        # The package lives in the repository's .venv (scripts/setup), not bench/.venv.
        pkg = run_json([DYNACAL_PYTHON, __file__, "--worker", "dynacal-python", str(n),
                        "--repeats", str(args.repeats)])
        r = rust[os.cpu_count()]
        exact = r["exact_variance"]
        levels = r["levels"]
        alt_wv = [alt["result"][str(1 << (j - 1))] if str(1 << (j - 1)) in alt["result"]
                  else alt["result"].get(1 << (j - 1)) for j in range(1, levels + 1)]
        agree = {
            "dynacal_f64_vs_exact": r["f64_vs_exact_max_rel"],
            "naive_f64_cumsum_vs_exact": r["naive_prefix_vs_exact_max_rel"],
            "numpy_cumsum_vs_exact": max_rel(npy["result"], exact),
            "allantools_vs_exact": max_rel(alt_wv, exact),
            "dynacal_python_vs_exact": max_rel(pkg["result"], exact),
        }
        row = {"n": n, "levels": levels, "rust": rust, "numpy": {k: v for k, v in npy.items() if k != "result"},
               "allantools": {k: v for k, v in alt.items() if k != "result"},
               "dynacal_python": {k: v for k, v in pkg.items() if k != "result"}, "max_rel_diff": agree}
        results.append(row)
        t_rs, t_rs1 = r["f64_time_min_s"], rust[1]["f64_time_min_s"]
        print(f"\nN = {n:.0e} ({levels} levels), min of {args.repeats} runs")
        print(f"  dynacal haar_wv        {t_rs:8.4f} s  ({r['threads']} threads)  peak RSS {r['peak_rss_f64_mib']:.0f} MiB (data alone {r['baseline_rss_mib']:.0f})")
        print(f"  dynacal haar_wv        {t_rs1:8.4f} s  (1 thread)")
        print(f"  dynacal haar_wv_counts {r['counts_time_min_s']:8.4f} s  ({r['threads']} threads)")
        overhead = pkg["time_min_s"] / r["input_path_time_min_s"] - 1.0
        print(f"  dynacal from Python    {pkg['time_min_s']:8.4f} s  peak RSS {pkg['peak_rss_mib']:.0f} MiB (data alone {pkg['baseline_rss_mib']:.0f}); "
              f"the same call in Rust {r['input_path_time_min_s']:.4f} s: the bindings add {100 * overhead:.1f}%")
        print(f"  numpy prefix-sum WV    {npy['time_min_s']:8.4f} s  peak RSS {npy['peak_rss_mib']:.0f} MiB (data alone {npy['baseline_rss_mib']:.0f})")
        print(f"  allantools.oadev       {alt['time_min_s']:8.4f} s  peak RSS {alt['peak_rss_mib']:.0f} MiB (data alone {alt['baseline_rss_mib']:.0f})")
        print(f"  speed-up vs numpy: {npy['time_min_s'] / t_rs:.1f}x ({npy['time_min_s'] / t_rs1:.1f}x on 1 thread); "
              f"vs allantools: {alt['time_min_s'] / t_rs:.1f}x ({alt['time_min_s'] / t_rs1:.1f}x on 1 thread)")
        print("  max relative difference from the exact (integer) WV: "
              + ", ".join(f"{k} {v:.1e}" for k, v in agree.items()))
        assert agree["dynacal_f64_vs_exact"] < 1e-9, "dynacal disagrees with exact"
        assert agree["dynacal_python_vs_exact"] == 0.0, "the package's counts path is not exact"
        assert agree["numpy_cumsum_vs_exact"] < 1e-2 and agree["allantools_vs_exact"] < 1e-2, \
            "tools disagree: not computing the same quantity"
    with open(os.path.join(DATA, "results.json"), "w") as f:
        json.dump({"machine": cpu, "cpus": os.cpu_count(), "results": results}, f, indent=1)
    print(f"\nresults: {os.path.join(DATA, 'results.json')}")


if __name__ == "__main__":
    main()
