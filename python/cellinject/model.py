"""The mechanism model (``cellinject tension``, ``model``, ``reproduce``)."""

from ._cellinject import model_model as model
from ._cellinject import model_reproduce as reproduce
from ._cellinject import model_tension as tension

__all__ = ["tension", "model", "reproduce"]
