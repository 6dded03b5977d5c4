import os
from typing import Any, Dict, List, Optional, Union

PathLike = Union[str, "os.PathLike[str]"]

def list(db: PathLike) -> List[Dict[str, Any]]:
    """`cellinject runs list --format json`."""

def show(db: PathLike, run: Optional[int] = None) -> Dict[str, Any]:
    """`cellinject runs show`: run, attempts, events."""

def attempts(db: PathLike, run: Optional[int] = None) -> List[Dict[str, Any]]:
    """`cellinject runs export --format json`."""

def dataframe(db: PathLike, run: Optional[int] = None) -> Any:
    """The attempts as a pandas DataFrame (pandas needed)."""
