"""The digital twin of the bench, driven through its safety envelope, and the
injection workflow on it (``cellinject run``)."""

from ._cellinject import Twin
from ._cellinject import twin_run as run

__all__ = ["Twin", "run"]
