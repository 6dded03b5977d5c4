import os
from typing import Any, Dict, List, Optional, Union

PathLike = Union[str, "os.PathLike[str]"]

class Twin:
    """The digital twin of the bench behind its safety envelope."""

    def __init__(
        self,
        approach: Optional[int] = None,
        seed: Optional[int] = None,
        config: Optional[PathLike] = None,
    ) -> None: ...
    def set_voltages(self, a1: float, a2: float, a3: float) -> List[float]:
        """Commands A1, A2, A3, V, each through the safety envelope; a refused voltage raises InputError and moves nothing. Returns what was applied."""
    def voltages(self) -> List[float]:
        """The commanded voltages, V."""
    def sensors(self) -> List[float]:
        """The stacks' extensions from their sensors, m."""
    def advance(self, seconds: float) -> None:
        """Advances the simulated clock."""
    @property
    def time(self) -> float:
        """The simulated clock, s."""
    def grab(self, camera: str = "top") -> Dict[str, Any]:
        """A frame: image (uint16, rows x columns), bit_depth, timestamp, exposure,
        pixel_size (m), index."""
    def load_plate(self, plate: PathLike) -> None:
        """Puts a plate file's cells under the microscope."""
    def tip(self) -> Dict[str, float]:
        """The tip's true pose: x, z, depth (m)."""

def run(
    plate: Optional[PathLike] = None,
    seed: Optional[int] = None,
    db: PathLike = "runs.sqlite",
    config: Optional[PathLike] = None,
) -> Dict[str, Any]:
    """`cellinject run --format json`: the workflow on a fresh twin, recorded in db."""
