"""cellinject: a piezo-actuated compliant micromanipulator for cell injection.

The modules (each a thin layer over the Rust library crates, all imported here):

- ``cellinject.design``: design studies: one design's figures, a multi-objective search on any ``map`` (Dask);
- ``cellinject.dic``: digital image correlation on NumPy images;
- ``cellinject.model``: pre-tension, Jacobians, the paper's figures;
- ``cellinject.flexure``: one flexure hinge;
- ``cellinject.fea``: the whole manipulator on FEM joints;
- ``cellinject.hysteresis``: hysteresis models, fitted, applied and inverted;
- ``cellinject.twin``: the digital twin of the bench, and the injection workflow;
- ``cellinject.rig``: a bench opened from a rig file, its devices checked, runs on it;
- ``cellinject.vision``: the cells in a lab's own micrograph (NumPy in, dict out);
- ``cellinject.runs``: the run database read back.

Results are dicts with the CLI's JSON field names and SI units (docs/json.md).
Errors: ``cellinject.Error``; ``InputError`` (also ``ValueError``) for a bad argument,
named; ``NotConverged`` (also ``RuntimeError``) when nothing usable came out.
"""

from ._errors import Error, InputError, NotConverged
from ._cellinject import __version__
from . import design, dic, fea, flexure, hysteresis, model, rig, runs, twin, vision

__all__ = [
    "Error",
    "InputError",
    "NotConverged",
    "__version__",
    "design",
    "dic",
    "fea",
    "flexure",
    "hysteresis",
    "model",
    "rig",
    "runs",
    "twin",
    "vision",
]
