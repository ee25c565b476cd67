#!/usr/bin/env python3
"""Ingest benchmark: `dynacal wv` end to end on interchange CSV and Parquet files against
pandas + numpy and pandas + allantools, side by side in one run on the same files (issue 22).

One run writes seeded one-channel recordings (`t_s,gx_rad_s` at 100 Hz, a 1e-3 rad/s white
noise on a random walk, `# sample_rate_hz: 100`) of each size into bench/.data/, plain and
gzip, and the same table as Parquet the way pandas writes it (`DataFrame.to_parquet`: pyarrow,
snappy, dictionary pages tried; the rate in the `sample_rate_hz` metadata), and times every tool in its own process, --repeats rounds (default 3) with every tool once a round, medians reported, under /usr/bin/time -v (wall time and peak RSS
of the whole process, interpreter start included): `dynacal wv FILE` as a user runs it
(the default `--stream auto`, which streams files over 256 MiB) and loaded whole
(`--stream never`); `pandas.read_csv` then the numpy prefix-sum Haar WV of wv_bench.py;
`pandas.read_csv` then `allantools.oadev`. The read alone is timed in-process too
(`bench_read` example for dynacal; `pandas.read_csv` / `read_parquet` for pandas), as MB/s
of the file's CSV text (so the two forms compare as rows per second). The script checks the wavelet variances agree and prints a markdown table.

Setup and run (from the repository root):
    python3 -m venv bench/.venv && bench/.venv/bin/pip install -r bench/requirements.txt
    bench/.venv/bin/python bench/ingest_bench.py            # sizes 4e6 and 3.6e7
"""
import argparse
import gzip
import json
import os
import shutil
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATA = os.path.join(HERE, ".data")
sys.path.insert(0, HERE)
from wv_bench import allantools_wv, numpy_haar_wv  # noqa: E402


def write_csv(path, n, seed):
    """Writes n rows in chunks (shortest round-trip text of the values, as dynacal writes)."""
    rng = np.random.default_rng(seed)
    walk = 0.0
    with open(path, "w") as f:
        f.write("# sample_rate_hz: 100\nt_s,gx_rad_s\n")
        chunk = 1_000_000
        for start in range(0, n, chunk):
            m = min(chunk, n - start)
            steps = np.cumsum(rng.normal(0.0, 1e-6, m)) + walk
            walk = float(steps[-1])
            gx = 0.5 + steps + rng.normal(0.0, 1e-3, m)
            t = np.arange(start, start + m) * 0.01
            f.write("".join(f"{ti!r},{gi!r}\n" for ti, gi in zip(t.tolist(), gx.tolist())))


def write_parquet(csv_path, path):
    """The CSV's table as pandas writes Parquet, with the rate in the file's metadata."""
    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pandas(pd.read_csv(csv_path, comment="#"), preserve_index=False)
    metadata = {**(table.schema.metadata or {}), b"sample_rate_hz": b"100"}
    pq.write_table(table.replace_schema_metadata(metadata), path)


def pandas_worker(tool, path):
    import pandas as pd

    t0 = time.perf_counter()
    if path.endswith(".parquet"):
        df = pd.read_parquet(path)
    else:
        df = pd.read_csv(path, comment="#")
    x = df["gx_rad_s"].to_numpy()
    t1 = time.perf_counter()
    if tool == "numpy":
        wv = numpy_haar_wv(x)
    else:
        res = allantools_wv(x)
        wv = [res[1 << j] for j in range(len(res)) if (1 << j) in res]
    t2 = time.perf_counter()
    print(json.dumps({"read_s": t1 - t0, "compute_s": t2 - t1, "wv": wv}))


def timed(cmd):
    """Wall time (s), peak RSS (MiB) and stdout of cmd under /usr/bin/time -v."""
    out = subprocess.run(["/usr/bin/time", "-v"] + cmd, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{out.stderr[-3000:]}")
    field = lambda name: next(l.split(name, 1)[1].strip() for l in out.stderr.splitlines()
                              if name in l)
    wall = 0.0
    for part in field("Elapsed (wall clock) time (h:mm:ss or m:ss):").split(":"):
        wall = wall * 60 + float(part)
    rss = int(field("Maximum resident set size (kbytes):")) / 1024
    return wall, rss, out.stdout


def dynacal_wv(exe, path, mode, json_path):
    wall, rss, _ = timed([exe, "wv", path, "--stream", mode, "--json", json_path])
    with open(json_path) as f:
        report = json.load(f)
    return wall, rss, report


def dynacal_fit(exe, path, json_path):
    wall, rss, _ = timed([exe, "fit", path, "--model", "auto", "--json", json_path])
    return wall, rss


def wv_values(report):
    """The gx channel's wavelet variance per level from `dynacal wv --json`."""
    return report["channels"]["gx"]["variance"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="4000000,36000000")
    ap.add_argument("--seed", type=int, default=22)
    ap.add_argument("--repeats", type=int, default=3,
                    help="rounds per file, every tool once a round (interleaved); medians reported")
    ap.add_argument("--worker", nargs=2, metavar=("TOOL", "PATH"))
    args = ap.parse_args()
    if args.worker:
        pandas_worker(*args.worker)
        return
    os.makedirs(DATA, exist_ok=True)
    subprocess.run(["cargo", "build", "--release", "--quiet", "-p", "dynacal", "--bin",
                    "dynacal", "--example", "bench_read"], cwd=ROOT, check=True)
    exe = os.path.join(ROOT, "target", "release", "dynacal")
    reader = os.path.join(ROOT, "target", "release", "examples", "bench_read")
    import pandas
    print(f"python {sys.version.split()[0]}, pandas {pandas.__version__}, numpy {np.__version__}, "
          f"allantools {__import__('allantools').__version__}; {os.cpu_count()} CPUs")
    rows = []
    for n in [int(float(s)) for s in args.sizes.split(",")]:
        plain = os.path.join(DATA, f"ingest-{n}.csv")
        if not os.path.exists(plain):
            write_csv(plain, n, args.seed + n)
        gz = plain + ".gz"
        if not os.path.exists(gz):
            subprocess.run(["sh", "-c", f"gzip -1 -c {plain} > {gz}"], check=True)
        parquet = os.path.join(DATA, f"ingest-{n}.parquet")
        if not os.path.exists(parquet):
            write_parquet(plain, parquet)
        mb = os.path.getsize(plain) / 1e6
        for path, kind in [(plain, "csv"), (gz, "csv.gz"), (parquet, "parquet")]:
            read = json.loads(subprocess.run([reader, path, "2"], capture_output=True,
                                             text=True, check=True).stdout)
            result = {"n": n, "kind": kind, "mb": mb, "disk_mb": os.path.getsize(path) / 1e6,
                      "dynacal_read_s": read["read_s"],
                      "csv_crate_read_s": read["csv_crate_s"] or float("nan")}
            runs = {}  # tool -> one (wall s, RSS MiB[, read s]) per round
            for _ in range(args.repeats):
                for mode in ["auto", "never"]:
                    wall, rss, rep = dynacal_wv(exe, path, mode, os.path.join(DATA, "wv.json"))
                    runs.setdefault(f"dynacal_{mode}", []).append((wall, rss))
                    result[f"wv_{mode}"] = wv_values(rep)
                # `fit --model auto` end to end, and its fit stage alone: the same fit from
                # the wavelet variances `wv` (auto) stored, so read + WV is the difference.
                _, _, _ = dynacal_wv(exe, path, "auto", os.path.join(DATA, "wv.json"))
                runs.setdefault("fit", []).append(
                    dynacal_fit(exe, path, os.path.join(DATA, "model.json")))
                runs.setdefault("fit_stage", []).append(
                    dynacal_fit(exe, os.path.join(DATA, "wv.json"),
                                os.path.join(DATA, "model-wv.json")))
                for tool in ["numpy", "allantools"]:
                    wall, rss, out = timed([sys.executable, __file__, "--worker", tool, path])
                    w = json.loads(out.strip().splitlines()[-1])
                    runs.setdefault(tool, []).append((wall, rss, w["read_s"]))
                    result[f"wv_{tool}"] = w["wv"]
            for tool, values in runs.items():
                result[tool] = tuple(float(np.median(column)) for column in zip(*values))
            # The speed-up round by round (each round's tools ran one after another).
            ratios = [n[0] / a[0] for n, a in zip(runs["numpy"], runs["dynacal_auto"])]
            result["speedup_range"] = (min(ratios), max(ratios))
            ref = result["wv_numpy"]
            for key in ["wv_auto", "wv_never", "wv_allantools"]:
                k = min(len(ref), len(result[key]), 18)
                rel = max(abs(a - b) / b for a, b in zip(result[key][:k], ref[:k]))
                assert rel < 1e-3, f"{key} disagrees with numpy by {rel:.2e}"
            rows.append(result)
            print(json.dumps({k: v for k, v in result.items() if not k.startswith("wv_")}))
    print(f"\nMedians of {args.repeats} rounds (every tool once a round, one after another).")
    print("\n| rows | file | MB (text) | MB on disk | dynacal wv (auto) s / MiB | dynacal wv (whole) s / MiB "
          "| dynacal read s (MB/s) | csv crate read s (MB/s) | pandas+numpy s / MiB (read s) "
          "| pandas+allantools s / MiB | speed-up vs pandas+numpy (rounds) | vs pandas+allantools |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        a, w, npy, alt = r["dynacal_auto"], r["dynacal_never"], r["numpy"], r["allantools"]
        print(f"| {r['n']:.1e} | {r['kind']} | {r['mb']:.0f} | {r['disk_mb']:.0f} "
              f"| {a[0]:.2f} / {a[1]:.0f} "
              f"| {w[0]:.2f} / {w[1]:.0f} | {r['dynacal_read_s']:.2f} ({r['mb'] / r['dynacal_read_s']:.0f}) "
              f"| {r['csv_crate_read_s']:.2f} ({r['mb'] / r['csv_crate_read_s']:.0f}) "
              f"| {npy[0]:.2f} / {npy[1]:.0f} ({npy[2]:.2f}) | {alt[0]:.2f} / {alt[1]:.0f} "
              f"| {npy[0] / a[0]:.1f}x ({r['speedup_range'][0]:.1f}-{r['speedup_range'][1]:.1f}) "
              f"| {alt[0] / a[0]:.1f}x |")

    print("\n| rows | file | `fit --model auto` s / MiB | read + WV s (share) | fit stage s (share) |")
    print("|---|---|---|---|---|")
    for r in rows:
        total, rss = r["fit"]
        stage = r["fit_stage"][0]
        print(f"| {r['n']:.1e} | {r['kind']} | {total:.2f} / {rss:.0f} "
              f"| {total - stage:.2f} ({(total - stage) / total:.0%}) "
              f"| {stage:.2f} ({stage / total:.0%}) |")


if __name__ == "__main__":
    main()
