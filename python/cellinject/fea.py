"""The whole manipulator on joints from the 3-D FEM (``cellinject fea``), with the
CLI's joint cache."""

from ._cellinject import fea_modes as modes
from ._cellinject import fea_run as run
from ._cellinject import fea_tables as tables

__all__ = ["run", "tables", "modes"]
