"""Cells and the pipette's tip in a lab's own micrographs (``cellinject vision cells``
and ``cellinject vision tip``, docs/vision.md): a NumPy image of grey levels in, the
command's JSON as a dict out; cells in phase contrast or bright field, either
polarity; the pipette entering from any edge; x along the columns, y along the rows,
in pixels."""

from ._cellinject import vision_cells as cells
from ._cellinject import vision_tip as tip

__all__ = ["cells", "tip"]
