"""Fleet screening: every unit of a lot fitted on a distributed engine, and the units out of family.

``python -m dynacal.fleet DIR --out OUT [--engine local|dask] [--workers N] [--scheduler ADDR]``
fits the noise model of every recording under ``DIR`` (one unit each, any format :func:`dynacal.read`
takes) as one map task per unit, gathers one row per unit and channel in ``OUT/fleet.parquet``
and writes ``OUT/report.html``. A unit is out of family when a parameter of one of its
channels lies outside the lot's robust spread on the log scale (:func:`screen`; the rule and its
false-flag rate are in ``docs/python.md``). Units that fail are listed with their error in
``OUT/failed.csv`` and the report, never dropped; each unit's result is kept in ``OUT/units/``
so that a rerun fits only the units that are new or changed.

The engine is Dask distributed: a local cluster of worker processes by default, or a running
cluster by its scheduler's address (the workers need the ``dynacal`` wheel and the files at the
same paths). ``local`` runs the same tasks in a process pool, without Dask.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, Iterable, List, Optional, Sequence, Tuple

import numpy as np

import dynacal

#: Parameters the rule compares across the lot (one per degree of freedom of each process:
#: white noise, quantization, random walk and Gauss-Markov variance, GM rate, |drift|); the
#: others (``noise_density``, ``correlation_time_s``, ``bias_random_walk``) restate them.
TESTED_PARAMETERS = ("sigma2", "q2", "beta_per_s", "slope_per_s")

#: Files under DIR that are documents, not recordings.
NOT_RECORDINGS = {".md", ".txt", ".json", ".yaml", ".yml", ".html", ".png", ".pdf", ".py"}

#: Bumped when a unit's cached result changes meaning, so that reruns refit.
CACHE_VERSION = 1

_Z95 = 1.959963984540054


def discover(root: Path, out: Optional[Path] = None) -> List[Path]:
    """Every recording under ``root`` (recursively, sorted), skipping hidden files, documents
    and the output folder ``out``."""
    found = []
    out_resolved = out.resolve() if out else None
    for path in sorted(root.rglob("*")):
        if not path.is_file() or any(part.startswith(".") for part in path.relative_to(root).parts):
            continue
        if out_resolved and out_resolved in path.resolve().parents:
            continue
        if path.suffix.lower() in NOT_RECORDINGS:
            continue
        found.append(path)
    return found


def parameter_column(process: str, name: str) -> str:
    """The Parquet column of a fitted parameter, e.g. ``wn_sigma2``, ``gm1_beta_per_s``."""
    return f"{process}_{name}".lower()


def screen_unit(path: str, file: str, model: str) -> Dict[str, Any]:
    """One map task: read the unit's recording(s) at ``path`` and fit every channel.

    Returns ``{"file", "rows": [...]}`` (one row per sensor and channel: parameters with
    their 95% intervals and the fit's diagnostics) or ``{"file", "error"}``; never raises, so
    that one bad unit does not stop the lot.
    """
    try:
        rows = []
        for rec in dynacal.read(path):
            for channel in rec.channels():
                rows.append(fit_channel(file, rec, channel, model))
        if not rows:
            return {"file": file, "error": f"{path}: no gyro or accelerometer channel"}
        return {"file": file, "rows": rows}
    except Exception as e:  # noqa: BLE001 - every failure is reported with its unit
        return {"file": file, "error": str(e) or type(e).__name__}


def fit_channel(file: str, rec: "dynacal.Recording", channel: str, model: str) -> Dict[str, Any]:
    """One row of the lot: ``channel`` of the recording ``rec`` (from ``file``) fitted with
    ``model``; the parameters keep their 95% intervals."""
    x = rec.channel(channel)
    f = dynacal.fit(x, rec.dt_s, model=model, channel=channel)
    row: Dict[str, Any] = {
        "file": file,
        "sensor": rec.name,
        "channel": channel,
        "si_unit": f.unit,
        "n_samples": int(x.size),
        "dt_s": rec.dt_s,
        "model": f.model,
        "objective": f.objective,
        "converged": f.converged,
        "j_test_p_value": f.j_test_p_value,
        "warnings": "; ".join(f.warnings),
        "parameters": [
            {"process": p.process, "name": p.name, "unit": p.unit, "value": p.value,
             "ci95": list(p.ci95) if p.ci95 else None}
            for p in f.parameters
        ],
    }
    return row


# --- The out-of-family rule -------------------------------------------------------------------


@dataclass(frozen=True)
class Test:
    """One parameter of one unit's channel, on the log scale: ``y = ln(value)`` and the
    standard error ``se`` of ``y`` from the fit's 95% interval (inf when it has none)."""

    row: int
    key: Tuple[str, str, str]  # (channel, process, name)
    y: float
    se: float


@dataclass(frozen=True)
class Verdict:
    """The rule's verdict on one test: its z-score, two-sided p-value, and whether it is
    flagged at the lot's threshold."""

    z: float
    p_value: float
    flagged: bool


@dataclass(frozen=True)
class Group:
    """The lot's spread of one channel's parameter, ln scale: centre ``mu``, unit-to-unit
    standard deviation ``tau``, ``n`` units, the Student-t degrees of freedom ``dof`` of its
    z-scores and the threshold ``k`` (|z| > k flags)."""

    mu: float
    tau: float
    n: int
    dof: float
    k: float


@dataclass(frozen=True)
class RuleSummary:
    """What the rule used: the false-flag rate per lot ``alpha``, the number of tests ``n_tests``
    it is shared among, the per-test threshold ``p_threshold`` = alpha / n_tests, and each
    (channel, process, parameter) group's spread."""

    alpha: float
    n_tests: int
    p_threshold: float
    groups: Dict[Tuple[str, str, str], Group]

    def k_range(self) -> Tuple[float, float]:
        """The smallest and largest threshold over the groups (nan when none was tested)."""
        ks = [g.k for g in self.groups.values()]
        return (min(ks), max(ks)) if ks else (math.nan, math.nan)


#: Fewest units that pin a parameter down for the lot to be judged on it.
MIN_UNITS = 10

#: Asymptotic efficiency of the MAD as an estimate of a normal spread: the z-scores are
#: Student-t with about this fraction of n - 1 degrees of freedom.
MAD_EFFICIENCY = 0.3675


def log_scale_se(value: float, ci95: Optional[Sequence[Optional[float]]]) -> float:
    """Standard error of ln(value) from a 95% interval, inf when the interval is missing or
    reaches 0 or infinity (the parameter is not identified in that unit)."""
    if not ci95 or ci95[0] is None or ci95[1] is None:
        return math.inf
    low, high = float(ci95[0]), float(ci95[1])
    if not (0.0 < low <= high < math.inf) or value <= 0.0:
        return math.inf
    return math.log(high / low) / (2.0 * _Z95)


def screen(tests: Sequence[Test], alpha: float) -> Tuple[List[Verdict], RuleSummary]:
    """The out-of-family rule over a lot's tests (one per unit, channel and parameter).

    Per channel and parameter, the lot is modelled as ``y_i = mu + u_i + e_i``: a unit-to-unit
    spread ``u_i ~ N(0, tau^2)`` and the unit's own estimation error ``e_i ~ N(0, se_i^2)``.
    ``mu`` is the median of ``y``; the total spread is 1.4826 MAD (robust to the units out of
    family), ``tau^2`` = that squared minus the median ``se^2``. Each unit's
    ``z = (y - mu) / sqrt(tau^2 + se_i^2)`` is tested two-sided against a Student t of
    0.3675 (n - 1) degrees of freedom (the MAD's efficiency: a small lot knows its spread
    less well, so its threshold is wider); a test is flagged when its p-value is below
    ``alpha / n_tests`` (Bonferroni: the chance that a lot of in-family units raises any flag
    is at most ``alpha`` when the model holds). A parameter a unit's data cannot pin down (no
    finite interval) is neither tested nor counted in the lot's centre and spread; a
    parameter fewer than MIN_UNITS units pin down is not tested.
    """
    # scipy.special's Student-t tails: scipy.stats costs a second to import.
    from scipy.special import stdtr, stdtrit

    members_of: Dict[Tuple[str, str, str], List[int]] = {}
    for i, t in enumerate(tests):
        if math.isfinite(t.y) and math.isfinite(t.se):
            members_of.setdefault(t.key, []).append(i)
    members_of = {k: v for k, v in members_of.items() if len(v) >= MIN_UNITS}
    n_tests = sum(len(v) for v in members_of.values())
    p_threshold = alpha / max(n_tests, 1)
    verdicts = [Verdict(z=math.nan, p_value=math.nan, flagged=False)] * len(tests)
    groups = {}
    for key, members in members_of.items():
        y = np.array([tests[i].y for i in members])
        se = np.array([tests[i].se for i in members])
        mu = float(np.median(y))
        spread2 = (1.4826 * float(np.median(np.abs(y - mu)))) ** 2
        tau2 = max(0.0, spread2 - float(np.median(se**2)))
        dof = MAD_EFFICIENCY * (len(members) - 1)
        groups[key] = Group(mu=mu, tau=math.sqrt(tau2), n=len(members), dof=dof,
                            k=float(-stdtrit(dof, p_threshold / 2.0)))
        sd = np.sqrt(tau2 + se**2)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = (y - mu) / sd
        p = 2.0 * stdtr(dof, -np.abs(z))
        for i, zi, pi, si in zip(members, z, p, sd):
            if si > 0.0:
                verdicts[i] = Verdict(z=float(zi), p_value=float(pi), flagged=bool(pi < p_threshold))
    return verdicts, RuleSummary(alpha=alpha, n_tests=n_tests, p_threshold=p_threshold,
                                 groups=groups)


def lot_tests(rows: Sequence[Dict[str, Any]]) -> List[Test]:
    """The tests of a lot's rows: each tested parameter with a positive value."""
    tests = []
    for r, row in enumerate(rows):
        for p in row["parameters"]:
            if p["name"] not in TESTED_PARAMETERS:
                continue
            value = abs(float(p["value"]))
            y = math.log(value) if value > 0.0 else math.nan
            tests.append(Test(row=r, key=(row["channel"], p["process"], p["name"]), y=y,
                              se=log_scale_se(value, p["ci95"])))
    return tests


# --- The table ---------------------------------------------------------------------------------


def fleet_table(rows: Sequence[Dict[str, Any]], alpha: float):
    """The lot's rows with the rule applied, as a pandas DataFrame (one row per unit and
    channel), and the rule's summary."""
    import pandas as pd

    tests = lot_tests(rows)
    verdicts, summary = screen(tests, alpha)
    flat = []
    for row in rows:
        out = {k: v for k, v in row.items() if k != "parameters"}
        for p in row["parameters"]:
            col = parameter_column(p["process"], p["name"])
            ci = p["ci95"] or [None, None]
            out[col] = p["value"]
            out[col + "_ci_low"] = ci[0]
            out[col + "_ci_high"] = ci[1]
        out["out_of_family"] = False
        out["p_value"] = math.nan
        out["p_value_lot"] = math.nan
        out["flagged_by"] = ""
        flat.append(out)
    for t, v in zip(tests, verdicts):
        out = flat[t.row]
        col = parameter_column(t.key[1], t.key[2])
        out[col + "_z"] = v.z
        out[col + "_p_value"] = v.p_value
        if math.isfinite(v.p_value) and not (out["p_value"] <= v.p_value):
            out["p_value"] = v.p_value
            out["p_value_lot"] = min(1.0, v.p_value * summary.n_tests)
        if v.flagged:
            out["out_of_family"] = True
            out["flagged_by"] = ",".join(filter(None, [out["flagged_by"], col]))
    table = pd.DataFrame(flat)
    # Each parameter's value, interval, z and p-value side by side; the verdict last.
    verdict = ["out_of_family", "p_value", "p_value_lot", "flagged_by"]
    base = [c for c in table.columns if c not in verdict]
    ordered = sorted(base, key=lambda c: _column_rank(c, base))
    return table[ordered + verdict], summary


def _column_rank(column: str, columns: Sequence[str]) -> Tuple[int, int]:
    """Sort key keeping a parameter's suffixed columns (``_ci_low``, ``_z``...) after it."""
    for suffix in ("_ci_low", "_ci_high", "_z", "_p_value"):
        if column.endswith(suffix) and column[: -len(suffix)] in columns:
            return (columns.index(column[: -len(suffix)]), 1 + ("_ci_low", "_ci_high", "_z", "_p_value").index(suffix))
    return (columns.index(column), 0)


# --- Running the lot -----------------------------------------------------------------------------


def _cache_key(path: Path, model: str) -> str:
    st = path.stat()
    return json.dumps([CACHE_VERSION, str(path.resolve()), st.st_size, st.st_mtime_ns, model])


def _cache_file(out: Path, file: str) -> Path:
    return out / "units" / (hashlib.sha1(file.encode("utf-8")).hexdigest()[:16] + ".json")


def write_atomically(path: Path, write: Callable[[Path], None]) -> None:
    """Write ``path`` whole or not at all: into a temporary file beside it, then renamed."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix="." + path.name, suffix=".tmp")
    os.close(fd)
    try:
        write(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _cached(out: Path, file: str, key: str) -> Optional[Dict[str, Any]]:
    try:
        stored = json.loads(_cache_file(out, file).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return stored["result"] if stored.get("key") == key else None


def _store(out: Path, file: str, key: str, result: Dict[str, Any]) -> None:
    text = json.dumps({"key": key, "result": result})
    write_atomically(_cache_file(out, file), lambda p: p.write_text(text, encoding="utf-8"))


@dataclass
class Engine:
    """Where the map tasks run: ``submit(fn, *args)`` returns futures, ``as_completed``
    yields them as they finish."""

    submit: Callable[..., Any]
    as_completed: Callable[[Iterable[Any]], Iterable[Any]]
    close: Callable[[], None]
    description: str


def make_engine(kind: str, workers: Optional[int], scheduler: Optional[str]) -> Engine:
    """A Dask distributed client (a local cluster of ``workers`` processes, or the cluster at
    ``scheduler``), or a plain process pool for ``local``."""
    if kind == "dask" or scheduler:
        try:
            from dask.distributed import Client, LocalCluster
            from dask.distributed import as_completed as dask_as_completed
        except ImportError as e:
            raise SystemExit(
                f"dynacal.fleet: --engine dask needs Dask distributed ({e}); "
                "pip install 'dynacal[fleet]'"
            ) from None
        if scheduler:
            client = Client(scheduler)
            description = f"Dask cluster at {scheduler}"
            cluster = None
        else:
            n = workers or os.cpu_count() or 1
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   dashboard_address=None)
            client = Client(cluster)
            description = f"local Dask cluster of {n} worker processes"

        def close() -> None:
            client.close()
            if cluster is not None:
                cluster.close()

        return Engine(submit=lambda fn, *a: client.submit(fn, *a, pure=False),
                      as_completed=dask_as_completed, close=close, description=description)
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures import as_completed as futures_as_completed

    n = workers or os.cpu_count() or 1
    pool = ProcessPoolExecutor(max_workers=n)
    return Engine(submit=pool.submit, as_completed=futures_as_completed,
                  close=lambda: pool.shutdown(), description=f"{n} local processes")


@dataclass
class LotRun:
    """A screened lot: per-unit results (``rows`` or ``error``) in file order, and how many
    were fitted now rather than taken from an earlier run."""

    results: List[Dict[str, Any]]
    fitted_now: int
    reused: int


def run_lot(root: Path, out: Path, model: str, engine: Engine,
            progress: Callable[[str], None] = lambda s: None) -> LotRun:
    """Fit every unit under ``root`` not already done in ``out`` on ``engine``."""
    files = discover(root, out)
    if not files:
        raise SystemExit(f"dynacal.fleet: no recording under {root}")
    results: Dict[str, Dict[str, Any]] = {}
    pending = {}
    for path in files:
        file = path.relative_to(root).as_posix()
        key = _cache_key(path, model)
        done = _cached(out, file, key)
        if done is not None and "rows" in done:
            results[file] = done
        else:
            pending[engine.submit(screen_unit, str(path.resolve()), file, model)] = (file, key)
    reused = len(results)
    for k, future in enumerate(engine.as_completed(list(pending)), 1):
        file, key = pending[future]
        result = future.result()
        results[file] = result
        if "rows" in result:
            _store(out, file, key, result)
        progress(f"fitted {k}/{len(pending)}: {file}" + (" (failed)" if "error" in result else ""))
    ordered = [results[p.relative_to(root).as_posix()] for p in files]
    return LotRun(results=ordered, fitted_now=len(pending), reused=reused)


def write_outputs(out: Path, run: LotRun, alpha: float, model: str, engine: str) -> Tuple[Any, RuleSummary, List[Dict[str, str]]]:
    """``fleet.parquet``, ``failed.csv`` and ``report.html`` in ``out``, each written whole."""
    from . import fleet_report

    rows = [row for r in run.results for row in r.get("rows", [])]
    failed = [{"file": r["file"], "error": r["error"]} for r in run.results if "error" in r]
    table, summary = fleet_table(rows, alpha)
    write_atomically(out / "fleet.parquet", lambda p: table.to_parquet(p, index=False))
    import csv

    def write_failed(p: Path) -> None:
        with open(p, "w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=["file", "error"])
            w.writeheader()
            w.writerows(failed)

    write_atomically(out / "failed.csv", write_failed)
    html = fleet_report.render(table, summary, failed, model=model, engine=engine,
                               n_units=len(run.results))
    write_atomically(out / "report.html", lambda p: p.write_text(html, encoding="utf-8"))
    return table, summary, failed


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dynacal.fleet",
        description="Fit every unit's noise model under DIR on a distributed engine and flag "
        "the units out of family (OUT/fleet.parquet, OUT/report.html).",
    )
    parser.add_argument("dir", type=Path, help="folder of recordings, one unit each (searched recursively)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--engine", choices=("local", "dask"), default="dask",
                        help="dask: Dask distributed (default); local: a process pool")
    parser.add_argument("--workers", type=int, default=None,
                        help="worker processes of the local cluster or pool (default: the CPUs)")
    parser.add_argument("--scheduler", default=None,
                        help="address of a running Dask scheduler (tcp://host:8786) instead of a local cluster")
    parser.add_argument("--model", default="WN+GM+RW",
                        help="the GMWM structure fitted to every channel (default WN+GM+RW; "
                        "'auto' chooses per unit, and units are compared on the processes they share)")
    parser.add_argument("--false-flag-rate", type=float, default=0.01, dest="alpha",
                        help="chance that a lot with no unit out of family has any unit flagged (default 0.01)")
    args = parser.parse_args(argv)
    if not args.dir.is_dir():
        parser.error(f"{args.dir}: not a folder")
    if not 0.0 < args.alpha < 1.0:
        parser.error(f"--false-flag-rate {args.alpha}: a probability in (0, 1) is needed")
    if args.workers is not None and args.workers < 1:
        parser.error(f"--workers {args.workers}: at least 1")
    engine = make_engine(args.engine, args.workers, args.scheduler)
    try:
        run = run_lot(args.dir, args.out, args.model, engine,
                      progress=lambda s: print(s, file=sys.stderr, flush=True))
    finally:
        engine.close()
    table, summary, failed = write_outputs(args.out, run, args.alpha, args.model, engine.description)
    flagged = sorted(set(table.loc[table["out_of_family"], "file"])) if len(table) else []
    print(f"{len(run.results)} units ({run.fitted_now} fitted on {engine.description}, "
          f"{run.reused} from an earlier run), {len(table)} channels; "
          f"out of family (|z| > {summary.k_range()[0]:.2f} to {summary.k_range()[1]:.2f}, "
          f"false-flag rate {summary.alpha:g} per lot): "
          f"{len(flagged)}" + (": " + ", ".join(flagged) if flagged else ""))
    print(f"wrote {args.out / 'fleet.parquet'}, {args.out / 'report.html'}")
    if failed:
        print(f"dynacal.fleet: {len(failed)} of {len(run.results)} units failed "
              f"(listed in {args.out / 'failed.csv'}):", file=sys.stderr)
        for f in failed:
            print(f"  {f['file']}: {f['error']}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    # Run as dynacal.fleet, not __main__, so that the workers find screen_unit by its module.
    from dynacal.fleet import main as _main

    sys.exit(_main())
