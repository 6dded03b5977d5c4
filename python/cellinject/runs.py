"""The run database read back (``cellinject runs``)."""

from ._cellinject import runs_attempts as attempts
from ._cellinject import runs_list as list
from ._cellinject import runs_show as show


def dataframe(db, run=None):
    """A run's attempts (:func:`attempts`) as a pandas DataFrame, one row per attempt.

    Raises:
        ImportError: pandas is not installed (``pip install pandas``).
    """
    import pandas

    return pandas.DataFrame(attempts(db, run))


__all__ = ["list", "show", "attempts", "dataframe"]
