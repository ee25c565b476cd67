"""Type stubs of the native module ``dynacal._dynacal`` (host/python/src/lib.rs).

Sample arrays are 1-D float64 in SI units; structured results are JSON text of the dynacal
library's types, which ``dynacal/__init__.py`` turns into dataclasses.
"""

from typing import Dict, List, Optional, Tuple

import numpy as np
import numpy.typing as npt

#: ``(name, interchange columns by name, stated sample rate in Hz)``
RawRecording = Tuple[str, Dict[str, npt.NDArray[np.float64]], Optional[float]]

class DynacalError(Exception):
    """An error of the dynacal library, with its message as the command line prints it."""

def wavelet_variance(
    x: npt.NDArray[np.float64],
    dt_s: float,
    robust: bool = False,
    efficiency: float = 0.6,
    max_level: Optional[int] = None,
) -> str:
    """Haar wavelet variance of ``x`` sampled every ``dt_s`` s: JSON of ``WaveletVariance``
    (variances in the square of x's unit, scales in s)."""

def fit_wavelet_variance(
    wv_json: str,
    model: str = "auto",
    channel: str = "x",
    unit: Optional[str] = None,
    bootstrap: int = 0,
    seed: int = 1,
) -> str:
    """GMWM fit of one wavelet variance: JSON ``{"fit": ..., "model": ..., "notes": [...]}``."""

def read(path: str) -> Tuple[List[RawRecording], List[str]]:
    """Every sensor of a file dynacal reads (datasets, interchange, flight logs, board logs),
    and the importer's notes on the file."""

def redundancy(
    units: List[Tuple[str, List[Tuple[str, npt.NDArray[np.float64]]], Optional[float]]],
) -> str:
    """The units' own errors from their differences: JSON of ``RedundancyReport``."""

def simulate(
    model_json: str, seconds: float, seed: int = 1, scenario: str = "car"
) -> Tuple[RawRecording, List[RawRecording], str]:
    """A simulated run: ``(reference, imus, truth JSON)``."""
