"""Cells in a lab's own micrographs (``cellinject vision cells``, docs/vision.md): a
NumPy image of grey levels in, the command's JSON as a dict out; phase contrast or
bright field, either polarity; x along the columns, y along the rows, in pixels."""

from ._cellinject import vision_cells as cells

__all__ = ["cells"]
