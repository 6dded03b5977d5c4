import os
from typing import Any, Dict, Optional, Union

PathLike = Union[str, "os.PathLike[str]"]

class Bench:
    """A bench opened from a rig file, kept open from run to run."""

    @property
    def backend(self) -> str:
        """The bench as the run records name it: ``twin`` or the controller's address."""
    def run(
        self,
        plate: Optional[PathLike] = None,
        db: PathLike = "runs.sqlite",
    ) -> Dict[str, Any]:
        """`cellinject run --rig ... --format json`: the workflow on this bench, recorded in db."""

def open(
    path: Optional[PathLike] = None,
    seed: Optional[int] = None,
    config: Optional[PathLike] = None,
) -> Bench:
    """Opens the bench a rig file names (None: the twin)."""

def check(
    path: Optional[PathLike] = None,
    config: Optional[PathLike] = None,
) -> Dict[str, Any]:
    """`cellinject rig check --format json`: whether each device of the rig answers."""
