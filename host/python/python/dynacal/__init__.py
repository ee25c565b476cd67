"""dynacal from Python: how MEMS inertial sensors err, measured and modelled.

The functions take and return numpy arrays (float64, SI units: rad/s, m/s^2, s) and plain
dataclasses whose field names carry their units. They run the dynacal library (Rust) with
the GIL released, and compute exactly what the ``dynacal`` command line computes on the same
data: ``wv`` is ``dynacal wv``, ``fit`` is ``dynacal fit``, ``read`` is what ``dynacal
import`` and ``dynacal decode`` read, ``simulate`` is ``dynacal simulate``, ``redundancy`` is
``dynacal redundancy``. Errors raise :class:`DynacalError` with the library's message (the
file, line, field or sample at fault).
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _dynacal
from ._dynacal import DynacalError

try:
    from importlib.metadata import version as _version

    __version__ = _version("dynacal")
except Exception:  # noqa: BLE001 - not installed as a distribution (a bare build tree)
    __version__ = "unknown"

__all__ = [
    "AllanVariance",
    "DynacalError",
    "DynacalWarning",
    "Fit",
    "Parameter",
    "Recording",
    "Redundancy",
    "Simulation",
    "UnitNoise",
    "WaveletVariance",
    "avar",
    "fit",
    "read",
    "redundancy",
    "simulate",
    "wv",
]

#: Interchange channel names in file order: gyros (rad/s), then accelerometers (m/s^2).
CHANNELS = ("gx", "gy", "gz", "ax", "ay", "az")
_CHANNEL_COLUMNS = ("gx_rad_s", "gy_rad_s", "gz_rad_s", "ax_m_s2", "ay_m_s2", "az_m_s2")


def _series(x: Any, what: str = "x") -> np.ndarray:
    """A 1-D contiguous float64 copy-free view of ``x`` where it already is one."""
    a = np.ascontiguousarray(x, dtype=np.float64)
    if a.ndim != 1:
        raise DynacalError(f"{what}: a 1-D series is needed, got shape {a.shape}")
    return a


@dataclass(frozen=True)
class WaveletVariance:
    """Haar wavelet variance of one series, level by level, with 95% intervals.

    ``variance``, ``ci_low``, ``ci_high`` and ``allan_variance`` are in the square of the
    series' unit; ``scales_s`` (the Haar filter width 2^j dt) and ``dt_s`` in seconds.
    """

    scales_s: np.ndarray
    levels: np.ndarray
    variance: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    allan_variance: np.ndarray
    n_coefficients: np.ndarray
    n: int
    robust: bool
    dt_s: float
    _json: str = field(repr=False, compare=False, default="")

    @classmethod
    def from_json(cls, text: str) -> "WaveletVariance":
        """From the JSON of one channel of ``dynacal wv --json`` (or of this package)."""
        d = json.loads(text)
        return cls(
            scales_s=np.array(d["scales_s"], dtype=np.float64),
            levels=np.array(d["levels"], dtype=np.int64),
            variance=np.array(d["variance"], dtype=np.float64),
            ci_low=np.array(d["ci_low"], dtype=np.float64),
            ci_high=np.array(d["ci_high"], dtype=np.float64),
            allan_variance=np.array(d["allan_variance"], dtype=np.float64),
            n_coefficients=np.array(d["n_coefficients"], dtype=np.int64),
            n=int(d["n"]),
            robust=bool(d["robust"]),
            dt_s=float(d["dt_s"]),
            _json=text,
        )

    @property
    def allan_tau_s(self) -> np.ndarray:
        """Averaging time of each ``allan_variance`` value, s: half the Haar scale."""
        return self.scales_s / 2.0


@dataclass(frozen=True)
class AllanVariance:
    """Overlapping Allan variance at octave averaging times tau = 2^(j-1) dt.

    It is exactly twice the Haar wavelet variance of level j, so its 95% interval is twice
    the wavelet variance's. Variances in the square of the series' unit, times in seconds.
    """

    tau_s: np.ndarray
    allan_variance: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    n: int
    dt_s: float

    @property
    def allan_deviation(self) -> np.ndarray:
        """Allan deviation, in the series' unit."""
        return np.sqrt(self.allan_variance)


@dataclass(frozen=True)
class Parameter:
    """One fitted parameter: ``value`` in ``unit``, 95% interval ``ci95`` (None when the
    model is not identifiable at the fit)."""

    process: str
    name: str
    unit: str
    value: float
    ci95: Optional[Tuple[float, float]]


@dataclass(frozen=True)
class Fit:
    """A GMWM fit of one series, as ``dynacal fit`` reports a channel.

    ``model`` is the structure (e.g. ``"WN+RW+GM"``), ``model_json`` the model file
    ``dynacal fit --json`` writes (it loads in :func:`simulate` and ``dynacal simulate``),
    ``j_test_p_value`` the J-test's p-value, ``candidates`` the ranked structures when the
    model was chosen automatically, ``details`` the whole record.
    """

    channel: str
    unit: str
    model: str
    parameters: List[Parameter]
    objective: float
    converged: bool
    j_test_p_value: Optional[float]
    interval_method: str
    warnings: List[str]
    candidates: Optional[List[Dict[str, Any]]]
    scales_s: np.ndarray
    wv: np.ndarray
    model_wv: np.ndarray
    model_json: str
    notes: List[str]
    details: Dict[str, Any] = field(repr=False, compare=False)

    def parameter(self, process: str, name: Optional[str] = None) -> Parameter:
        """The parameter of ``process`` (``"WN"``, ``"RW"``, ``"GM1"``...), by ``name``
        where the process has several."""
        for p in self.parameters:
            if p.process == process and (name is None or p.name == name):
                return p
        raise KeyError(f"no parameter {process}{'/' + name if name else ''} in {self.model}")


@dataclass(frozen=True)
class Recording:
    """One sensor's recording: interchange columns (``t_s``, ``gx_rad_s`` .. ``az_m_s2``,
    ``roll_rad``.., ``lat_rad``.., ``vn_m_s``..) as 1-D arrays, SI units, body frame
    forward-right-down, navigation frame NED."""

    name: str
    columns: Dict[str, np.ndarray]
    sample_rate_hz: Optional[float] = None

    @property
    def t_s(self) -> np.ndarray:
        return self.columns["t_s"]

    @property
    def dt_s(self) -> float:
        """The sample interval, s: the stated rate's, else the median step."""
        if self.sample_rate_hz:
            return 1.0 / self.sample_rate_hz
        return float(np.median(np.diff(self.t_s)))

    def _triad(self, names: Sequence[str]) -> Optional[np.ndarray]:
        if not all(n in self.columns for n in names):
            return None
        return np.column_stack([self.columns[n] for n in names])

    @property
    def gyro_rad_s(self) -> Optional[np.ndarray]:
        """Angular rate, (N, 3), rad/s."""
        return self._triad(_CHANNEL_COLUMNS[:3])

    @property
    def accel_m_s2(self) -> Optional[np.ndarray]:
        """Specific force, (N, 3), m/s^2."""
        return self._triad(_CHANNEL_COLUMNS[3:])

    @property
    def attitude_rad(self) -> Optional[np.ndarray]:
        """Roll, pitch, yaw w.r.t. NED, (N, 3), rad."""
        return self._triad(("roll_rad", "pitch_rad", "yaw_rad"))

    @property
    def velocity_ned_m_s(self) -> Optional[np.ndarray]:
        """Velocity w.r.t. Earth in NED, (N, 3), m/s."""
        return self._triad(("vn_m_s", "ve_m_s", "vd_m_s"))

    def channel(self, name: str) -> np.ndarray:
        """A sensor channel by its short name, ``"gx"`` .. ``"az"``."""
        column = _CHANNEL_COLUMNS[CHANNELS.index(name)] if name in CHANNELS else name
        try:
            return self.columns[column]
        except KeyError:
            have = [c for c, col in zip(CHANNELS, _CHANNEL_COLUMNS) if col in self.columns]
            raise KeyError(f"{self.name}: no channel {name} (has {', '.join(have)})") from None

    def channels(self) -> List[str]:
        """The sensor channels this recording has, ``"gx"`` .. ``"az"``."""
        return [c for c, col in zip(CHANNELS, _CHANNEL_COLUMNS) if col in self.columns]


def _recording(raw: Tuple[str, Dict[str, np.ndarray], Optional[float]]) -> Recording:
    name, columns, rate = raw
    return Recording(name=name, columns=dict(columns), sample_rate_hz=rate)


def wv(
    x: Any,
    dt_s: float,
    robust: bool = False,
    efficiency: float = 0.6,
    max_level: Optional[int] = None,
) -> WaveletVariance:
    """Haar wavelet variance of the series ``x`` sampled every ``dt_s`` seconds.

    Levels 1..J (default J = floor(log2 N) - 1), scales 2^j dt, 95% chi-square intervals.
    Integer-valued series are taken as counts and summed exactly, as ``dynacal wv`` does.
    ``robust``: Tukey biweight M-scale estimate of asymptotic efficiency ``efficiency``.
    """
    text = _dynacal.wavelet_variance(_series(x), float(dt_s), robust, efficiency, max_level)
    return WaveletVariance.from_json(text)


def avar(x: Any, dt_s: float) -> AllanVariance:
    """Overlapping Allan variance of ``x`` (sampled every ``dt_s`` s) at octave averaging
    times 2^(j-1) dt, with 95% intervals."""
    w = wv(x, dt_s)
    return AllanVariance(
        tau_s=w.allan_tau_s,
        allan_variance=w.allan_variance,
        ci_low=2.0 * w.ci_low,
        ci_high=2.0 * w.ci_high,
        n=w.n,
        dt_s=w.dt_s,
    )


def fit(
    x_or_wv: Any,
    dt_s: Optional[float] = None,
    model: str = "auto",
    channel: str = "x",
    unit: Optional[str] = None,
    bootstrap: int = 0,
    seed: int = 1,
) -> Fit:
    """GMWM fit of a series (with ``dt_s``) or of its :class:`WaveletVariance`.

    ``model``: ``"auto"`` (chosen by WIC among WN, QN, RW, DR and up to 3 GM) or a structure
    such as ``"WN+RW+GM"``. ``channel`` names the series (``"gx"`` .. ``"az"`` place the
    fitted model on that IMU channel in ``model_json`` and set the unit to rad/s or m/s^2);
    ``unit`` overrides the unit of the reported parameters. ``bootstrap`` > 0: percentile
    intervals from that many parametric bootstrap replicates (seeded by ``seed``), else the
    delta method's.
    """
    if isinstance(x_or_wv, WaveletVariance):
        w = x_or_wv
    else:
        if dt_s is None:
            raise DynacalError("fit: a series needs its sample interval dt_s (s)")
        w = wv(x_or_wv, dt_s)
    wv_json = w._json or _wv_json(w)
    out = json.loads(
        _dynacal.fit_wavelet_variance(wv_json, model, channel, unit, int(bootstrap), int(seed))
    )
    f = out["fit"]
    j_test = f.get("j_test")
    return Fit(
        channel=f["channel"],
        unit=f["unit"],
        model=f["model"],
        parameters=[
            Parameter(
                process=p["process"],
                name=p["name"],
                unit=p["unit"],
                value=float(p["value"]),
                ci95=tuple(p["ci95"]) if p.get("ci95") else None,
            )
            for p in f["parameters"]
        ],
        objective=float(f["objective"]),
        converged=bool(f["converged"]),
        j_test_p_value=float(j_test["p_value"]) if j_test else None,
        interval_method=f["interval_method"],
        warnings=list(f["warnings"]),
        candidates=f.get("candidates"),
        scales_s=np.array(f["scales_s"], dtype=np.float64),
        wv=np.array(f["wv"], dtype=np.float64),
        model_wv=np.array(f["model_wv"], dtype=np.float64),
        model_json=json.dumps(out["model"]),
        notes=list(out["notes"]),
        details=f,
    )


def _wv_json(w: WaveletVariance) -> str:
    """A WaveletVariance built in Python (not from the library), as the library reads it."""
    return json.dumps(
        {
            "scales_s": w.scales_s.tolist(),
            "levels": [int(v) for v in w.levels],
            "variance": w.variance.tolist(),
            "ci_low": w.ci_low.tolist(),
            "ci_high": w.ci_high.tolist(),
            "allan_variance": w.allan_variance.tolist(),
            "n": int(w.n),
            "n_coefficients": [int(v) for v in w.n_coefficients],
            "robust": bool(w.robust),
            "dt_s": float(w.dt_s),
        }
    )


class DynacalWarning(UserWarning):
    """What dynacal found worth telling about an input it read (a ROS bag's topics left out
    and why), as the command line prints it."""


def read(path: Union[str, os.PathLike]) -> List[Recording]:
    """Every sensor of a file dynacal reads: an interchange recording (CSV, CSV.gz,
    Parquet), a ROS bag's Imu topics, a PX4 ULog, an ArduPilot DataFlash log, an Xsens DOT
    export, a shared dataset, or a dynacal board log; one :class:`Recording` each. The
    importer's notes on the file are raised as :class:`DynacalWarning`."""
    raws, notes = _dynacal.read(os.fspath(path))
    for note in notes:
        warnings.warn(f"{os.fspath(path)}: {note}", DynacalWarning, stacklevel=2)
    return [_recording(r) for r in raws]


@dataclass(frozen=True)
class Simulation:
    """A simulated run: the navigation-grade ``reference`` (its truth columns), the MEMS
    ``imus`` by name, and the ``truth`` file (options, trajectory, every effect)."""

    reference: Recording
    imus: Dict[str, Recording]
    truth: Dict[str, Any] = field(repr=False)


def _model_text(model: Any) -> str:
    if isinstance(model, Fit):
        return model.model_json
    if isinstance(model, Mapping):
        return json.dumps(model)
    if isinstance(model, os.PathLike) or (
        isinstance(model, str) and not model.lstrip().startswith("{")
    ):
        with open(model, encoding="utf-8") as f:
            return f.read()
    if isinstance(model, str):
        return model
    raise DynacalError(
        f"simulate: a model is a Fit, a dict, JSON text or a model file's path, not {type(model).__name__}"
    )


def simulate(model: Any, seconds: float, seed: int = 1, scenario: str = "car") -> Simulation:
    """Simulate ``seconds`` of a ``"car"`` drive or a ``"static"`` platform from a model: a
    :class:`Fit`, a model file's path, its JSON text or a dict (``docs/formats.md``,
    section 3), seeded by ``seed``, as ``dynacal simulate`` does."""
    reference, imus, truth = _dynacal.simulate(
        _model_text(model), float(seconds), int(seed), scenario
    )
    return Simulation(
        reference=_recording(reference),
        imus={r[0]: _recording(r) for r in imus},
        truth=json.loads(truth),
    )


@dataclass(frozen=True)
class UnitNoise:
    """What the set says of one unit: its own white-noise variance per channel (SI unit
    squared, at its sample rate) and its own wavelet variance per channel (``scales_s``,
    ``variance``, ``ci_low``, ``ci_high`` arrays), with its alignment to the first unit."""

    name: str
    white_noise_sigma2: Dict[str, float]
    wv: Dict[str, Dict[str, np.ndarray]]
    alignment: Dict[str, Any]


@dataclass(frozen=True)
class Redundancy:
    """Three or more units' own errors from their differences (``dynacal redundancy``)."""

    units: List[UnitNoise]
    faults: List[Dict[str, Any]]
    notes: List[str]
    details: Dict[str, Any] = field(repr=False, compare=False)


def _unit_columns(unit: Any, k: int, dt_s: Optional[float]) -> Tuple[str, Dict[str, np.ndarray], Optional[float]]:
    if isinstance(unit, Recording):
        return unit.name, unit.columns, unit.sample_rate_hz
    a = np.asarray(unit, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 6:
        raise DynacalError(
            f"redundancy: unit {k + 1} is an array of shape {a.shape}; each unit is a Recording "
            "or an (N, 6) array of gx, gy, gz (rad/s), ax, ay, az (m/s^2)"
        )
    if dt_s is None:
        raise DynacalError("redundancy: arrays need their sample interval dt_s (s)")
    columns = {"t_s": np.arange(a.shape[0], dtype=np.float64) * dt_s}
    columns.update({c: np.ascontiguousarray(a[:, i]) for i, c in enumerate(_CHANNEL_COLUMNS)})
    return f"imu{k + 1}", columns, 1.0 / dt_s


def redundancy(units: Sequence[Any], dt_s: Optional[float] = None) -> Redundancy:
    """Each unit's own noise from three or more IMUs sampled together, without a reference.

    ``units``: :class:`Recording` objects, or (N, 6) arrays (gx, gy, gz in rad/s, ax, ay, az
    in m/s^2) sampled together every ``dt_s`` seconds.
    """
    raw = []
    for k, unit in enumerate(units):
        name, columns, rate = _unit_columns(unit, k, dt_s)
        raw.append((name, [(c, _series(v, f"{name}/{c}")) for c, v in columns.items()], rate))
    d = json.loads(_dynacal.redundancy(raw))
    return Redundancy(
        units=[
            UnitNoise(
                name=u["name"],
                white_noise_sigma2=dict(u["white_noise_sigma2"]),
                wv={
                    c: {k: np.array(v, dtype=np.float64) for k, v in w.items() if k != "clamped"}
                    for c, w in u["wv"].items()
                },
                alignment=u["alignment"],
            )
            for u in d["imus"]
        ],
        faults=d["faults"],
        notes=d["notes"],
        details=d,
    )
