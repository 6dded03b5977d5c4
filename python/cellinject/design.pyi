import os
from typing import Any, Callable, Dict, List, Optional, Union

PathLike = Union[str, "os.PathLike[str]"]

def evaluate(
    variables: Optional[Dict[str, float]] = None,
    config: Optional[PathLike] = None,
    approach: Optional[int] = None,
    fidelity: str = "beam",
    level: int = 1,
) -> Dict[str, Any]:
    """`cellinject design evaluate --format json` (SI units)."""

def evaluate_point(task: str, x: List[float]) -> Dict[str, Any]:
    """One point of a study's task: {"variables", "figures"} or {"variables", "error"}."""

class Study:
    """A design study: a space on a description and its seeded NSGA-II search."""

    def __init__(
        self,
        space: str,
        config: Optional[PathLike] = None,
        approach: Optional[int] = None,
        population: int = 40,
        generations: int = 30,
        seed: int = 1,
        fidelity: str = "beam",
        level: int = 1,
    ) -> None: ...
    @property
    def done(self) -> bool: ...
    @property
    def generation(self) -> int: ...
    @property
    def evaluations(self) -> int: ...
    def ask(self) -> List[List[float]]: ...
    def tell(self, points: List[List[float]], records: List[Dict[str, Any]]) -> None: ...
    def task(self, final_step: bool = False) -> str: ...
    def screened_front(self) -> List[Any]: ...
    def front(self, points: List[List[float]], records: List[Dict[str, Any]]) -> List[Dict[str, Any]]: ...

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
    """A multi-objective search like `cellinject design optimise`; `map=client.map` runs it on Dask."""
