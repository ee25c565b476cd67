"""The Python package against the command line on the same files, and on its own.

The command line is the binary of this checkout and the measured recordings the shared data
(``helpers``). Every random series is seeded.
"""

import json
import os
import pathlib
import subprocess
import threading
import time

import numpy as np
import pytest

import dynacal

from helpers import BIN, DATA, ROOT, cli, relative_difference


def write_interchange(path, t_s, columns, rate_hz):
    """An interchange CSV: the rate line, a header, values in round-trip form."""
    names = list(columns)
    with open(path, "w") as f:
        f.write(f"# sample_rate_hz: {rate_hz}\n")
        f.write(",".join(["t_s", *names]) + "\n")
        for i, t in enumerate(t_s):
            f.write(",".join(repr(float(v)) for v in [t, *(columns[n][i] for n in names)]) + "\n")


def gyro_with_random_walk(n, dt_s, seed):
    """White noise (1e-3 rad/s a sample) on a random walk (2e-6 rad/s a sample) on 0.01 rad/s."""
    rng = np.random.default_rng(seed)
    return 0.01 + 1e-3 * rng.standard_normal(n) + np.cumsum(2e-6 * rng.standard_normal(n))


@pytest.fixture(scope="module")
def gyro_file(tmp_path_factory):
    """A seeded 100 Hz gyro-x interchange file (2^16 samples)."""
    dt_s = 0.01
    n = 1 << 16
    gx = gyro_with_random_walk(n, dt_s, seed=7)
    path = tmp_path_factory.mktemp("gyro") / "unit.csv"
    write_interchange(path, np.arange(n) * dt_s, {"gx_rad_s": gx}, 100)
    return path


def test_wavelet_variance_equals_the_command_lines(gyro_file, tmp_path):
    out = tmp_path / "wv.json"
    cli("wv", gyro_file, "--json", out)
    want = json.loads(out.read_text())["channels"]["gx"]
    [rec] = dynacal.read(gyro_file)
    got = dynacal.wv(rec.channel("gx"), rec.dt_s)
    assert got.n == want["n"] == 1 << 16
    assert list(got.levels) == want["levels"]
    for key in ("variance", "ci_low", "ci_high", "allan_variance", "scales_s"):
        assert relative_difference(getattr(got, key), want[key]) <= 1e-12, key


def test_fit_equals_the_command_lines(gyro_file, tmp_path):
    out = tmp_path / "model.json"
    cli("fit", gyro_file, "--model", "auto", "--json", out)
    want = json.loads(out.read_text())["fit"]["channels"][0]
    [rec] = dynacal.read(gyro_file)
    got = dynacal.fit(rec.channel("gx"), rec.dt_s, model="auto", channel="gx")
    assert got.model == want["model"]
    assert got.unit == want["unit"] == "rad/s"
    assert len(got.parameters) == len(want["parameters"])
    for p, q in zip(got.parameters, want["parameters"]):
        assert (p.process, p.name, p.unit) == (q["process"], q["name"], q["unit"])
        assert relative_difference(p.value, q["value"]) <= 1e-9, p
        assert relative_difference(p.ci95, q["ci95"]) <= 1e-9, p
    # The model file is the command line's but for the IMU's name (the command line names
    # it after the file).
    [imu] = json.loads(got.model_json)["imus"]
    [cli_imu] = json.loads(out.read_text())["imus"]
    assert imu["channels"] == cli_imu["channels"]
    assert imu["rate_hz"] == cli_imu["rate_hz"]


def test_fit_recovers_the_noise_it_was_given():
    dt_s = 0.01
    x = gyro_with_random_walk(1 << 17, dt_s, seed=11)
    f = dynacal.fit(x, dt_s, model="WN+RW", channel="gx")
    # White noise of 1e-3 rad/s a sample at 100 Hz is 1e-4 rad/s/sqrt(Hz) as a density;
    # the random walk's 2e-6 rad/s a sample is 2e-5 rad/s/sqrt(s).
    wn = f.parameter("WN")
    rw = f.parameter("RW")
    assert wn.ci95[0] <= 1e-3**2 <= wn.ci95[1] or abs(wn.value / 1e-6 - 1) < 0.05, wn
    assert 0.7 < rw.value / (2e-6) ** 2 < 1.4, rw


def test_fit_of_a_wavelet_variance_is_the_fit_of_its_series():
    dt_s = 0.005
    x = gyro_with_random_walk(1 << 15, dt_s, seed=3)
    w = dynacal.wv(x, dt_s)
    a = dynacal.fit(w, model="WN+RW", channel="gy")
    b = dynacal.fit(x, dt_s, model="WN+RW", channel="gy")
    assert [p.value for p in a.parameters] == [p.value for p in b.parameters]


def test_allan_variance_is_twice_the_wavelet_variance_at_half_its_scale():
    x = np.random.default_rng(5).standard_normal(4096)
    a = dynacal.avar(x, 0.1)
    w = dynacal.wv(x, 0.1)
    np.testing.assert_array_equal(a.allan_variance, 2 * w.variance)
    np.testing.assert_array_equal(a.tau_s, w.scales_s / 2)
    # Overlapping Allan variance by its definition at tau = m dt.
    for m in (1, 2, 8):
        cs = np.concatenate([[0.0], np.cumsum(x)])
        means = (cs[m:] - cs[:-m]) / m
        oavar = 0.5 * np.mean((means[m:] - means[:-m]) ** 2)
        k = int(np.log2(m))
        assert abs(a.allan_variance[k] / oavar - 1) < 1e-10


def test_counts_are_summed_exactly_as_the_command_line_does(tmp_path):
    rng = np.random.default_rng(9)
    counts = rng.integers(-30000, 30000, size=5000).astype(np.float64)
    path = tmp_path / "counts.csv"
    write_interchange(path, np.arange(5000) * 0.01, {"gx_rad_s": counts}, 100)
    out = tmp_path / "wv.json"
    cli("wv", path, "--json", out)
    want = json.loads(out.read_text())["channels"]["gx"]["variance"]
    got = dynacal.wv(counts, 0.01).variance
    assert relative_difference(got, want) <= 1e-12


def test_read_gives_what_import_writes():
    ulog = DATA / "px4-ulog" / "sample_log_small.ulg"
    recordings = dynacal.read(ulog)
    names = [r.name for r in recordings]
    assert any(n.startswith("px4-sample_log_small") for n in names), names
    imu = next(r for r in recordings if r.gyro_rad_s is not None)
    assert imu.gyro_rad_s.shape[1] == 3
    assert np.all(np.diff(imu.t_s) > 0)
    # At rest or flying, gravity is about 9.8 m/s^2 on average in the specific force.
    norm = np.linalg.norm(imu.accel_m_s2, axis=1)
    assert 8.0 < float(np.median(norm)) < 11.5


def test_read_of_the_four_unit_rig_and_their_own_noise():
    rig = DATA / "mpu9250x4-tetra-static" / "static.csv.gz"
    units = dynacal.read(rig)
    assert len(units) == 4
    r = dynacal.redundancy(units[:3])
    assert [u.name for u in r.units] == [u.name for u in units[:3]]
    for u in r.units:
        for c in ("gx", "gy", "gz"):
            # An MPU9250's gyro noise is about 0.01 deg/s/sqrt(Hz): a white-noise sigma
            # per sample of 1e-4..1e-2 rad/s at these rates.
            sigma = np.sqrt(u.white_noise_sigma2[c])
            assert 1e-4 < sigma < 1e-2, (u.name, c, sigma)


def test_redundancy_finds_each_units_own_noise():
    rng = np.random.default_rng(21)
    n, dt_s = 1 << 15, 0.01
    motion = np.cumsum(rng.standard_normal((n, 6)) * 1e-3, axis=0)
    sigmas = [1e-3, 2e-3, 4e-3]
    units = [motion + s * rng.standard_normal((n, 6)) for s in sigmas]
    for u in units:
        u[:, 5] += 9.81
    r = dynacal.redundancy(units, dt_s)
    for unit, s in zip(r.units, sigmas):
        got = np.sqrt(unit.white_noise_sigma2["gx"])
        assert abs(got / s - 1) < 0.05, (unit.name, got, s)


def test_a_fitted_model_simulates_and_fits_back():
    dt_s = 0.01
    x = gyro_with_random_walk(1 << 16, dt_s, seed=13)
    f = dynacal.fit(x, dt_s, model="WN+RW", channel="gz")
    sim = dynacal.simulate(f, seconds=600, seed=4, scenario="static")
    [unit] = sim.imus.values()
    g = dynacal.fit(unit.channel("gz"), unit.dt_s, model="WN+RW", channel="gz")
    lo, hi = g.parameter("WN").ci95
    assert lo <= f.parameter("WN").value <= hi
    assert sim.truth["seed"] == 4 and sim.truth["scenario"] == "static"


def test_errors_name_what_is_wrong(tmp_path):
    with pytest.raises(dynacal.DynacalError, match="at least 4 samples, got 3"):
        dynacal.wv([1.0, 2.0, 3.0], 0.01)
    with pytest.raises(dynacal.DynacalError, match="sample 2 is not a finite number"):
        dynacal.wv([1.0, 2.0, np.nan, 4.0, 5.0], 0.01)
    with pytest.raises(dynacal.DynacalError, match="sampling interval"):
        dynacal.wv(np.zeros(16), -1.0)
    missing = tmp_path / "nothing.csv"
    with pytest.raises(dynacal.DynacalError, match="nothing.csv"):
        dynacal.read(missing)
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,gx_rad_s\n0.0,0.1\n0.01,oops\n")
    with pytest.raises(dynacal.DynacalError, match=r"bad\.csv.*line 3"):
        dynacal.read(bad)
    with pytest.raises(dynacal.DynacalError, match="WN\\+XX"):
        dynacal.fit(np.zeros(64) + np.arange(64), 0.1, model="WN+XX")
    with pytest.raises(dynacal.DynacalError, match="scenario"):
        dynacal.simulate({}, 10, scenario="boat")
    with pytest.raises(dynacal.DynacalError, match="shape"):
        dynacal.redundancy([np.zeros((100, 3))] * 3, 0.01)


def test_the_gil_is_released_while_the_library_works():
    x = np.random.default_rng(1).standard_normal(1 << 22)
    span = []

    def work():
        t0 = time.perf_counter()
        dynacal._dynacal.wavelet_variance(x, 0.001)
        span.extend([t0, time.perf_counter()])

    worker = threading.Thread(target=work)
    ticks = []
    worker.start()
    while worker.is_alive():
        ticks.append(time.perf_counter())
    worker.join()
    # The main thread ran Python while the worker was inside the library (about 0.1 s for
    # 4e6 samples): were the GIL held there, no tick could fall inside the call.
    t0, t1 = span
    inside = sum(t0 < t < t1 for t in ticks)
    assert inside > 1000, (inside, t1 - t0)


def python_blocks(markdown):
    """The ```python blocks of a markdown page, joined."""
    blocks, inside = [], None
    for line in markdown.splitlines():
        if inside is None and line.strip() == "```python":
            inside = []
        elif inside is not None and line.strip() == "```":
            blocks.append("\n".join(inside))
            inside = None
        elif inside is not None:
            inside.append(line)
    return "\n\n".join(blocks)


@pytest.mark.skipif(
    not list((ROOT / "target" / "wheels").glob("dynacal-*-abi3-*.whl")),
    reason="no wheel built (scripts/setup builds it)",
)
def test_the_documented_example_runs_in_a_fresh_environment(tmp_path):
    """docs/python.md's example, with only the wheel, numpy and matplotlib installed."""
    [wheel] = (ROOT / "target" / "wheels").glob("dynacal-*-abi3-*.whl")
    venv = tmp_path / "venv"
    subprocess.run(["python3", "-m", "venv", str(venv)], check=True)
    pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--disable-pip-version-check"]
    subprocess.run([*pip, str(wheel), "matplotlib"], check=True)
    script = tmp_path / "example.py"
    script.write_text(python_blocks((ROOT / "docs" / "python.md").read_text()))
    done = subprocess.run(
        [str(venv / "bin" / "python"), str(script)], cwd=tmp_path, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert "chosen model: WN+RW" in done.stdout, done.stdout
    png = (tmp_path / "allan.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10000
    model = json.loads((tmp_path / "gyro-model.json").read_text())
    assert model["imus"][0]["channels"]["gx"]["stochastic"]["model"] == "WN+RW"


def test_read_of_a_bag_warns_what_the_command_line_prints():
    bag = ROOT / "tests" / "ros" / "ros1-plain.bag"
    with pytest.warns(dynacal.DynacalWarning) as caught:
        recordings = dynacal.read(bag)
    notes = [str(w.message) for w in caught]
    assert all(n.startswith(str(bag)) and not n.startswith(f"{bag}: {bag}") for n in notes)
    assert any("/odom_imu/imu: skipped, not a sensor" in n for n in notes)
    assert any("/imu/messy: 2 messages whose stamp is not after every earlier one" in n for n in notes)
    assert {"imu-data", "imu-messy"} <= {r.name for r in recordings}
