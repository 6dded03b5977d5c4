"""Flexure hinges (``cellinject hinge``)."""

from ._cellinject import flexure_hinge as hinge

__all__ = ["hinge"]
