from typing import Any, Dict, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

Vector = Union[Sequence[float], npt.ArrayLike]

class Model:
    """A fitted hysteresis model: input V, output m."""

    def apply(self, voltages: Vector) -> npt.NDArray[np.float64]:
        """The output (m) for `voltages` (V) applied from relaxed at 0 V."""
    def invert(self, displacements: Vector) -> Dict[str, Any]:
        """voltage, predicted (arrays) and samples, voltage_range, residual."""
    def to_json(self) -> str:
        """The CLI's model file."""
    @staticmethod
    def from_json(text: str) -> "Model":
        """A model from the CLI's model file."""
    @property
    def report(self) -> Optional[Dict[str, Any]]:
        """`hysteresis fit --format json`'s fields; None after from_json."""
    @property
    def kind(self) -> str:
        """"preisach" or "pi"."""

def fit(
    voltage: Vector,
    displacement: Vector,
    model: str = "preisach",
    size: int = 20,
    v_max: Optional[float] = None,
) -> Model:
    """`cellinject hysteresis fit`: a model fitted to (V, m) samples in time order."""
