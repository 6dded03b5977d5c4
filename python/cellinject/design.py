"""Design studies (``cellinject design``): one design's figures, and a seeded
multi-objective search (NSGA-II) whose generations run on any ``map``: the builtin,
or a Dask client's (``client.map``) for a ``LocalCluster`` or a Slurm cluster.

The search itself (the space, the seeded NSGA-II, the front) is the Rust library's;
this module only hands each generation's points to ``map`` and the records back. The
same seed gives the same front whatever ``map`` evaluates the points.
"""

import builtins
import os
from typing import Any, Callable, Dict, List, Optional

from ._cellinject import Study
from ._cellinject import design_evaluate as evaluate
from ._cellinject import design_evaluate_point as evaluate_point

__all__ = ["evaluate", "evaluate_point", "optimise", "Study"]


def _gather(results: Any) -> List[Dict[str, Any]]:
    """The values of what ``map`` returned: plain results, or futures (Dask's
    ``client.map`` returns ``Future`` objects; their ``result()`` waits for each)."""
    out = []
    for r in results:
        res = getattr(r, "result", None)
        out.append(res() if callable(res) else r)
    return out


def optimise(
    space: str,
    config: Optional[str] = None,
    approach: Optional[int] = None,
    population: int = 40,
    generations: int = 30,
    seed: int = 1,
    fidelity: str = "beam",
    level: int = 1,
    map: Optional[Callable[..., Any]] = None,
) -> Dict[str, Any]:
    """A multi-objective search over the description keys a space names, like
    ``cellinject design optimise`` (without its files): every generation's points
    are evaluated through ``map(evaluate_point, tasks, points)``.

    Args:
        space: a space file's path, or its TOML text.
        config: a description file (TOML); None: the embedded prototype.
        approach: 1 or 2; None: the description's ``twin.approach``.
        population: designs per generation.
        generations: generations.
        seed: the search's seed: one seed, one front.
        fidelity: ``"beam"``, or ``"fea"`` (screen with the beam formulas, then
            evaluate the front again with the joints' FEM).
        level: the FEM mesh level of the ``"fea"`` step.
        map: how to evaluate a generation: None (the builtin ``map``, serial), or a
            Dask client's ``client.map`` (any ``map(f, *iterables)`` whose results,
            or their ``.result()``, are the values).

    Returns:
        dict: ``front`` (a list of ``{"variables", "figures"}``, as ``front.json``),
        ``generations``, ``evaluations``, ``fidelity``.

    Raises:
        InputError: a bad space (named key), description or argument.

    Example:
        >>> from cellinject import design
        >>> space = '[variables]\\n"geometry.b2" = [0.1, 0.3]\\n[objectives]\\nmaximise = ["range_min_m"]\\n[constraints]\\nfirst_mode_hz = 600\\n'
        >>> r = design.optimise(space, population=8, generations=4)
        >>> r["front"][0]["figures"]["first_mode_hz"] >= 600
        True
    """
    text = space
    if "\n" not in space and os.path.exists(space):
        with open(space, encoding="utf-8") as f:
            text = f.read()
    study = Study(
        text,
        config=config,
        approach=approach,
        population=population,
        generations=generations,
        seed=seed,
        fidelity=fidelity,
        level=level,
    )
    mapper = map if map is not None else builtins.map
    task = study.task(False)
    while not study.done:
        points = study.ask()
        records = _gather(mapper(evaluate_point, [task] * len(points), points))
        study.tell(points, records)
    screened = study.screened_front()
    points = [x for x, _ in screened]
    if fidelity == "fea" and points:
        final = study.task(True)
        records = _gather(mapper(evaluate_point, [final] * len(points), points))
    else:
        records = [r for _, r in screened]
    return {
        "front": study.front(points, records),
        "generations": study.generation,
        "evaluations": study.evaluations,
        "fidelity": fidelity,
    }
