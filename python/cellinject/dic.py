"""Digital image correlation on NumPy images (``cellinject dic``): FFT-ZNCC search,
IC-GN with ZNSSD on cubic B-splines; x along columns, y along rows, in pixels."""

from ._cellinject import dic_field as field
from ._cellinject import dic_points as points
from ._cellinject import dic_synth as synth
from ._cellinject import dic_track as track

__all__ = ["points", "field", "track", "synth"]
