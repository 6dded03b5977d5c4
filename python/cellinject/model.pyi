import os
from typing import Any, Dict, Optional, Union

PathLike = Union[str, "os.PathLike[str]"]

def tension(approach: int, config: Optional[PathLike] = None) -> Dict[str, Any]:
    """`cellinject tension --approach N --format json` (SI units)."""

def model(config: Optional[PathLike] = None) -> Dict[str, Any]:
    """`cellinject model --format json`: J, L, W, B_l, linearisation."""

def reproduce(config: Optional[PathLike] = None) -> Dict[str, Any]:
    """`cellinject reproduce --format json`: the paper's figures recomputed."""
