"""A simulated production lot for the fleet screening's tests and benchmark, made with numpy
alone (not dynacal's simulator, so the screening is not checked against its own generator).

Each unit is a three-axis gyro (rad/s, body axes) with white noise, a first-order Gauss-Markov
bias (the bias instability) and a rate random walk, its parameters spread log-normally around
the lot's nominal values; chosen units are built out of family by a factor on one parameter.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Tuple

import numpy as np

#: The lot's nominal gyro: white noise variance (rad/s)^2 per sample, GM stationary variance
#: (rad/s)^2 and rate (1/s), random-walk increment variance (rad/s)^2 per sample, at RATE_HZ.
NOMINAL = {"wn_sigma2": 1e-6, "gm_sigma2": 1e-7, "gm_beta_per_s": 0.5, "rw_sigma2": 1e-11}
RATE_HZ = 10.0
CHANNEL_COLUMNS = ("gx_rad_s", "gy_rad_s", "gz_rad_s")


@dataclass(frozen=True)
class Lot:
    """The units' series ``(n_samples, n_units, 3)`` and their true parameters
    ``(n_units, 3)`` by name."""

    series: np.ndarray
    parameters: Dict[str, np.ndarray]


def simulate_lot(n_units: int, seconds: float, planted: Dict[int, Tuple[str, float]],
                 seed: int, spread: float = 0.15) -> Lot:
    """``n_units`` units of ``seconds`` at RATE_HZ; ``planted[u] = (parameter, factor)``
    multiplies unit u's parameter on its x axis by ``factor`` (a variance: 9 is 3x the noise).
    ``spread``: the lot's unit-to-unit standard deviation of each ln(parameter)."""
    rng = np.random.default_rng(seed)
    n = int(round(seconds * RATE_HZ))
    dt_s = 1.0 / RATE_HZ
    shape = (n_units, 3)
    p = {k: v * np.exp(rng.normal(0.0, spread, shape)) for k, v in NOMINAL.items()}
    for unit, (name, factor) in planted.items():
        p[name][unit, 0] *= factor
    x = rng.normal(0.0, 1.0, (n,) + shape) * np.sqrt(p["wn_sigma2"])
    x += np.cumsum(rng.normal(0.0, 1.0, (n,) + shape), axis=0) * np.sqrt(p["rw_sigma2"])
    phi = np.exp(-p["gm_beta_per_s"] * dt_s)
    drive = rng.normal(0.0, 1.0, (n,) + shape) * np.sqrt(p["gm_sigma2"] * (1.0 - phi**2))
    gm = rng.normal(0.0, 1.0, shape) * np.sqrt(p["gm_sigma2"])
    for k in range(n):
        gm = phi * gm + drive[k]
        x[k] += gm
    return Lot(series=x, parameters=p)


def write_lot(lot: Lot, folder: Path, name: str = "unit{:03d}.parquet") -> None:
    """One interchange Parquet file per unit (``t_s`` and the gyro triad, the rate in the
    metadata), as a test bench's pyarrow script would write them."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    folder.mkdir(parents=True, exist_ok=True)
    n = lot.series.shape[0]
    t_s = np.arange(n, dtype=np.float64) / RATE_HZ
    for unit in range(lot.series.shape[1]):
        columns = {"t_s": t_s}
        columns.update({c: lot.series[:, unit, i] for i, c in enumerate(CHANNEL_COLUMNS)})
        table = pa.table(columns).replace_schema_metadata({"sample_rate_hz": f"{RATE_HZ:g}"})
        pq.write_table(table, folder / name.format(unit), compression="zstd")
