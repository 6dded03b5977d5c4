from typing import Any, Dict, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

Image = npt.NDArray[Union[np.uint8, np.uint16, np.float32, np.float64]]
Points = Union[Sequence[Tuple[float, float]], npt.ArrayLike]

def points(
    reference: Image,
    current: Image,
    at: Points,
    subset: int = 31,
    shape: str = "affine",
    search: int = 64,
    prefilter: float = 0.0,
    min_zncc: float = 0.8,
    max_sigma: float = ...,
) -> Dict[str, Any]:
    """Correlates points of `reference` into `current`: arrays x, y, u, v (px; NaN
    without a match), gradients, zncc, sigma_u, sigma_v, iterations, subset,
    converged (bool), error (list)."""

def field(
    reference: Image,
    current: Image,
    step: int = 5,
    subset: int = 31,
    shape: str = "affine",
    prefilter: float = 0.0,
    min_zncc: float = 0.8,
    max_sigma: float = ...,
) -> Dict[str, Any]:
    """The full field on a grid: arrays over nx * ny points and the CLI's summary."""

def track(
    frames: Union[Sequence[Image], npt.NDArray[Any]],
    roi: Tuple[int, int, int, int],
    shape: str = "rigid",
    min_zncc: float = 0.8,
) -> Dict[str, Any]:
    """A region followed through frames: arrays u, v, zncc, ... and a status list."""

def synth(
    size: Tuple[int, int] = (512, 512),
    shift: Tuple[float, float] = (0.0, 0.0),
    rotation: float = 0.0,
    noise: float = 2.0,
    seed: int = 1,
) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """An exact speckle pair (reference, current), float64 grey levels."""
