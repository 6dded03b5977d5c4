"""Hysteresis models of piezo stacks (``cellinject hysteresis fit | invert``)."""

from ._cellinject import Model
from ._cellinject import hysteresis_fit as fit

__all__ = ["fit", "Model"]
