"""The one exception tree of chaintwin.

Every mistake a user can make (a bad file, a bad profile, an impossible
option) raises a subclass of :class:`ChaintwinError`. The command line turns
them into a one-line message and exit code 2; a traceback means a bug.

::

    ChaintwinError
    ├── DataError               bad input data
    │   ├── RecordingError      a drive recording cannot be used
    │   ├── ColumnMapError      a column map file is invalid
    │   ├── ProfileError        a conveyor profile is invalid
    │   └── CalibrationError    a calibration file is invalid
    ├── ModelError              a model cannot be built or simulated
    ├── EstimationError         an estimator cannot be fitted or used
    │   └── NotFittedError      an estimator used before ``fit``
    ├── MonitorError            monitoring cannot run as asked (settings, alarms)
    ├── StoreError              the results store or a state file cannot be used
    └── ConnectorError          a live data source cannot be used

Each message names the file and the place (line, column, field path) and
says what to do. The library names its own settings (``days``, ``url``), not
the command line's options: an error about one setting carries its name in
``field`` and mentions it, and the command line puts the option's name in
its place (``days`` → ``--days``).

Beside the tree, :class:`ConvergenceWarning` (a ``UserWarning``) tells that an
estimator's result is usable but poorly determined, as in scikit-learn.
"""

from __future__ import annotations

__all__ = [
    "CalibrationError",
    "ChaintwinError",
    "ColumnMapError",
    "ConnectorError",
    "ConvergenceWarning",
    "DataError",
    "EstimationError",
    "ModelError",
    "MonitorError",
    "NotFittedError",
    "ProfileError",
    "RecordingError",
    "StoreError",
]


class ChaintwinError(Exception):
    """Base of every error chaintwin raises for a user's mistake.

    Parameters
    ----------
    *args : object
        The message: what is wrong and what to do; when ``field`` is given it
        mentions the field by that name.
    field : str, optional
        The setting or argument the error is about, by its name in the
        library (a keyword argument, a profile or calibration key).
    """

    field: str | None = None

    def __init__(self, *args: object, field: str | None = None) -> None:
        super().__init__(*args)
        if field is not None:
            self.field = field


class DataError(ChaintwinError):
    """Input data cannot be used."""


class RecordingError(DataError):
    """A drive recording cannot be read or fails validation.

    Parameters
    ----------
    source : str
        The file as given (or ``"<text>"`` for in-memory text).
    message : str
        What is wrong and what to do.
    line : int, optional
        1-based line number in the file, when the problem sits on a line.
    column : str, optional
        The column header (as written), when the problem sits in a column.
    field : str, optional
        The reading setting the message names (see :class:`ChaintwinError`).
    """

    def __init__(
        self,
        source: str,
        message: str,
        *,
        line: int | None = None,
        column: str | None = None,
        field: str | None = None,
    ) -> None:
        if field is not None:
            self.field = field
        self.source = source
        self.line = line
        self.column = column
        self.reason = message
        where = source
        if line is not None:
            where += f", line {line}"
        if column is not None:
            where += f", column '{column}'"
        super().__init__(f"{where}: {message}")


class ColumnMapError(DataError):
    """A column map (vendor header → canonical name and unit) is invalid."""


class ProfileError(DataError):
    """A conveyor profile is invalid: the message names the field path."""


class CalibrationError(DataError):
    """A calibration file cannot be read, or does not belong to the data."""


class ModelError(ChaintwinError):
    """A physics model cannot be built or simulated with the given inputs."""


class EstimationError(ChaintwinError):
    """An estimator cannot be fitted with the given data."""


class NotFittedError(EstimationError, AttributeError):
    """An estimator was used before it was fitted (also an AttributeError, as in scikit-learn)."""


class MonitorError(ChaintwinError):
    """Monitoring cannot run as asked (settings, alarm rule, alarm ids)."""


class StoreError(ChaintwinError):
    """The results store cannot be opened, read or written."""


class ConnectorError(ChaintwinError):
    """A live data source (OPC UA, ...) cannot be used."""


class ConvergenceWarning(UserWarning):
    """An estimator did not converge, ended at a bound, or its starts disagree."""
