"""The exceptions of cellinject (raised by the extension module too)."""


class Error(Exception):
    """Every error cellinject raises."""


class InputError(Error, ValueError):
    """A bad argument: its message names the argument (as the CLI names its option)."""


class NotConverged(Error, RuntimeError):
    """The computation ran but gave nothing usable (no DIC match, a solver that did
    not converge)."""
