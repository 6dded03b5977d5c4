import os
from typing import Any, Dict, Optional, Sequence, Union

import numpy.typing as npt

PathLike = Union[str, "os.PathLike[str]"]

def run(
    approach: int,
    forces: Union[Sequence[float], npt.ArrayLike],
    level: int = 1,
    preload: str = "deflection",
    config: Optional[PathLike] = None,
    cache: bool = True,
) -> Dict[str, Any]:
    """`cellinject fea --approach N --forces F11,F12 --format json` (m, N, Pa)."""

def tables(
    level: int = 1,
    preload: str = "deflection",
    config: Optional[PathLike] = None,
    cache: bool = True,
) -> Dict[str, Any]:
    """`cellinject fea tables --format json`."""

def modes(
    approach: Optional[int] = None,
    count: int = 8,
    level: int = 1,
    preload: str = "deflection",
    config: Optional[PathLike] = None,
    cache: bool = True,
) -> Dict[str, Any]:
    """`cellinject fea modes --format json` (Hz, m)."""
