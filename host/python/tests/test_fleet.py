"""Fleet screening (``python -m dynacal.fleet``): the out-of-family rule on its own, and a
seeded lot of 200 units with three built out of family, screened on a local Dask cluster of two
workers, its numbers checked against the command line's fit of the same file.
"""

import json
import math
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from dynacal import fleet
from fleet_lot import simulate_lot, write_lot
from helpers import cli, relative_difference

#: One unit of 3x white noise, one of 5x bias instability, one of 10x random walk (the factors
#: are on the noise; the variances are their squares), each on its x axis.
PLANTED = {17: ("wn_sigma2", 9.0), 101: ("gm_sigma2", 25.0), 150: ("rw_sigma2", 100.0)}
PLANTED_FILES = {f"unit{u:03d}.parquet" for u in PLANTED}

#: The two-sided 95% normal quantile.
_Z95 = 1.959963984540054


def test_the_rule_flags_a_unit_out_of_the_lots_spread_and_no_unit_it_cannot_judge():
    rng = np.random.default_rng(3)
    y = rng.normal(-10.0, 0.2, 60)
    tests = [fleet.Test(row=i, key=("gx", "WN", "sigma2"), y=v, se=0.05) for i, v in enumerate(y)]
    tests[7] = fleet.Test(row=7, key=("gx", "WN", "sigma2"), y=-10.0 + 2.0, se=0.05)  # e^2 = 7.4x
    # A parameter the unit's data cannot pin down is never flagged, however far it lies.
    tests[9] = fleet.Test(row=9, key=("gx", "WN", "sigma2"), y=-30.0, se=math.inf)
    # A group of fewer than MIN_UNITS units has no spread to judge by: not tested.
    tests += [fleet.Test(row=70 + i, key=("gy", "RW", "sigma2"), y=float(i * 10), se=0.1)
              for i in range(fleet.MIN_UNITS - 1)]
    verdicts, summary = fleet.screen(tests, alpha=0.01)
    assert [i for i, v in enumerate(verdicts) if v.flagged] == [7]
    assert summary.n_tests == 59 and summary.p_threshold == pytest.approx(0.01 / 59)
    assert list(summary.groups) == [("gx", "WN", "sigma2")]
    group = summary.groups[("gx", "WN", "sigma2")]
    # The lot's own spread: the MAD's, less the units' estimation error.
    assert group.tau == pytest.approx(0.2, rel=0.3) and group.n == 59
    # k is the two-sided Student-t quantile of the per-test threshold.
    from scipy.stats import t as student_t

    assert 2 * student_t.sf(group.k, group.dof) == pytest.approx(summary.p_threshold, rel=1e-6)
    assert all(math.isnan(v.z) for v in verdicts[60:])
    # The smaller the lot, the wider its threshold.
    small = fleet.screen(tests[:20], alpha=0.01)[1].groups[("gx", "WN", "sigma2")]
    assert small.k > group.k + 1.0
    # The unit's own estimation error widens its band: the same distance with a wide interval
    # is not out of family.
    tests[7] = fleet.Test(row=7, key=("gx", "WN", "sigma2"), y=-8.0, se=1.0)
    assert not fleet.screen(tests, alpha=0.01)[0][7].flagged


def test_log_scale_errors_come_from_the_fits_interval():
    assert fleet.log_scale_se(1.0, (math.exp(-_Z95), math.exp(_Z95))) == pytest.approx(1.0)
    assert fleet.log_scale_se(1.0, (0.0, 2.0)) == math.inf
    assert fleet.log_scale_se(1.0, None) == math.inf
    assert fleet.log_scale_se(1.0, (None, 2.0)) == math.inf


@pytest.fixture(scope="module")
def lot_dir(tmp_path_factory):
    """200 seeded gyro units (30 min at 10 Hz, Parquet) with the three planted, and two
    files dynacal cannot read (a Parquet file cut short, a CSV with a bad field)."""
    folder = tmp_path_factory.mktemp("lot")
    write_lot(simulate_lot(200, 1800.0, PLANTED, seed=2027), folder)
    whole = (folder / "unit000.parquet").read_bytes()
    (folder / "cut-short.parquet").write_bytes(whole[: len(whole) // 2])
    (folder / "bad-field.csv").write_text("t_s,gx_rad_s\n0,0.1\n0.1,abc\n0.2,0.1\n")
    (folder / "README.md").write_text("the lot's notes: not a recording\n")
    return folder


def run_fleet(lot, out, *args):
    return subprocess.run(
        [sys.executable, "-m", "dynacal.fleet", str(lot), "--out", str(out), *args],
        capture_output=True, text=True,
    )


def test_a_lot_on_a_dask_cluster_flags_the_planted_units_and_lists_the_failed(lot_dir, tmp_path):
    import pandas as pd

    out = tmp_path / "out"
    done = run_fleet(lot_dir, out, "--engine", "dask", "--workers", "2")
    # Two units failed: the run completes, says which and why, and exits non-zero.
    assert done.returncode == 1, done.stderr
    assert "2 of 202 units failed" in done.stderr
    assert "cut-short.parquet" in done.stderr and "bad-field.csv" in done.stderr
    assert "local Dask cluster of 2 worker processes" in done.stdout
    failed = pd.read_csv(out / "failed.csv")
    assert sorted(failed["file"]) == ["bad-field.csv", "cut-short.parquet"]
    errors = failed.set_index("file")["error"]
    assert "line 3" in errors["bad-field.csv"] and "gx_rad_s" in errors["bad-field.csv"]
    assert "cut short" in errors["cut-short.parquet"]

    table = pd.read_parquet(out / "fleet.parquet")
    assert len(table) == 200 * 3 and set(table["channel"]) == {"gx", "gy", "gz"}
    flagged = set(table.loc[table["out_of_family"], "file"])
    assert PLANTED_FILES <= flagged, flagged
    assert len(flagged - PLANTED_FILES) <= 1, flagged
    # Each planted unit is named by the parameter it was built with, on its x axis.
    by = table[table["out_of_family"]].set_index("file")
    for unit, (name, _) in PLANTED.items():
        row = by.loc[f"unit{unit:03d}.parquet"]
        assert row["channel"] == "gx"
        assert {"wn_sigma2": "wn_sigma2", "gm_sigma2": "gm1_sigma2", "rw_sigma2": "rw_sigma2"}[name] in row["flagged_by"]
        assert row["p_value_lot"] < 0.01
    # Intervals and diagnostics travel with every parameter.
    for col in ("wn_sigma2_ci_low", "gm1_beta_per_s_ci_high", "rw_sigma2_z", "j_test_p_value", "converged"):
        assert col in table.columns

    # The same numbers as the command line's fit of the same file.
    unit = lot_dir / "unit042.parquet"
    cli("fit", unit, "--model", "WN+GM+RW", "--json", tmp_path / "m.json")
    stored = json.loads((tmp_path / "m.json").read_text())["fit"]["channels"]
    mine = table[table["file"] == "unit042.parquet"].set_index("channel")
    for ch in stored:
        name = ch["channel"].replace("_rad_s", "")
        for p in ch["parameters"]:
            col = fleet.parameter_column(p["process"], p["name"])
            assert relative_difference(mine.loc[name, col], p["value"]) < 1e-9, (name, col)

    # The report names the planted units among those out of family, and the failed ones.
    page = (out / "report.html").read_text()
    section = page.split("id='out-of-family'")[1].split("id='failed'")[0]
    for f in PLANTED_FILES:
        assert f in section
    assert "cut-short.parquet" in page.split("id='failed'")[1]
    assert page.count("data:image/png;base64,") == 2

    # A rerun fits only what is new (and retries what failed), and gives the same verdicts.
    (lot_dir / "extra").mkdir()
    (lot_dir / "extra" / "unit200.parquet").write_bytes((lot_dir / "unit000.parquet").read_bytes())
    again = run_fleet(lot_dir, out, "--engine", "local", "--workers", "2")
    assert again.returncode == 1
    assert "(3 fitted on 2 local processes, 200 from an earlier run)" in again.stdout, again.stdout
    table2 = pd.read_parquet(out / "fleet.parquet")
    assert len(table2) == 201 * 3
    assert set(table2.loc[table2["out_of_family"], "file"]) >= PLANTED_FILES


def test_the_fleet_refuses_what_it_cannot_do(tmp_path):
    done = run_fleet(tmp_path / "nowhere", tmp_path / "out")
    assert done.returncode == 2 and "nowhere: not a folder" in done.stderr
    (tmp_path / "empty").mkdir()
    done = run_fleet(tmp_path / "empty", tmp_path / "out", "--engine", "local")
    assert done.returncode != 0 and "no recording under" in done.stderr
    done = run_fleet(tmp_path / "empty", tmp_path / "out", "--false-flag-rate", "2")
    assert done.returncode == 2 and "--false-flag-rate 2.0" in done.stderr
    assert not (tmp_path / "out" / "fleet.parquet").exists()


def free_port():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_same_command_runs_on_a_running_cluster_by_its_address(tmp_path):
    """A scheduler and a worker started as their own processes (as on a remote cluster):
    the fleet reaches them by address and gets the same verdicts as a local run."""
    import pandas as pd

    lot = tmp_path / "lot"
    write_lot(simulate_lot(12, 1800.0, {3: ("wn_sigma2", 9.0)}, seed=5), lot)
    address = f"tcp://127.0.0.1:{free_port()}"
    bin_dir = pathlib.Path(sys.executable).parent
    scheduler = subprocess.Popen(
        [str(bin_dir / "dask"), "scheduler", "--host", "127.0.0.1", "--port", address.rsplit(":", 1)[1],
         "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    worker = subprocess.Popen(
        [str(bin_dir / "dask"), "worker", address, "--nworkers", "1", "--nthreads", "1",
         "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        from dask.distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(1, timeout=60)
        remote = run_fleet(lot, tmp_path / "remote", "--scheduler", address)
        assert remote.returncode == 0, remote.stderr
        assert f"Dask cluster at {address}" in remote.stdout
    finally:
        worker.terminate()
        scheduler.terminate()
        worker.wait(30)
        scheduler.wait(30)
    local = run_fleet(lot, tmp_path / "local", "--engine", "local", "--workers", "1")
    assert local.returncode == 0, local.stderr
    a = pd.read_parquet(tmp_path / "remote" / "fleet.parquet")
    b = pd.read_parquet(tmp_path / "local" / "fleet.parquet")
    pd.testing.assert_frame_equal(a, b)
    # Twelve units know their spread too poorly to flag even a 3x white noise at a 1% lot
    # rate (Student t of 4 degrees of freedom), but it stands out as the largest z.
    gx = a[a["channel"] == "gx"].set_index("file")
    assert gx["wn_sigma2_z"].idxmax() == "unit003.parquet" and gx["wn_sigma2_z"].max() > 5
