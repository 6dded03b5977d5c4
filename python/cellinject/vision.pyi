from typing import Any, Dict, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

Image = npt.NDArray[Union[np.uint8, np.uint16, np.float32, np.float64]]

def cells(
    image: Image,
    pixel_size: Optional[float] = None,
    diameter: Optional[Tuple[float, float]] = None,
    contrast: str = "auto",
) -> Dict[str, Any]:
    """The cells and debris in `image`: `cells` and `debris`, each a list of dicts
    with x_px, y_px, diameter_px, diameter_m (None without pixel_size), confidence
    and contrast; `pixel_size_m`."""
