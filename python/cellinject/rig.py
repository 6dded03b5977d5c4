"""A bench opened from a rig file (docs/rig.md): each device through its driver, its
devices asked whether they answer (``cellinject rig check``), and the injection
workflow run on it (``cellinject run --rig``)."""

from ._cellinject import Bench
from ._cellinject import rig_check as check
from ._cellinject import rig_open as open

__all__ = ["Bench", "check", "open"]
