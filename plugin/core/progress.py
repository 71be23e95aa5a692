"""Progress reporting and cancellation for long engine work, independent of QGIS.

Engine functions take an optional ``progress`` (a :class:`Progress`) and call
``progress.step(fraction)`` in their loops; cancellation raises :class:`Canceled`
so that work stops promptly wherever it is. ``qgis_io`` adapts a QgsProcessingFeedback.
"""
from __future__ import annotations

import importlib
from typing import Callable, Optional


class InputError(ValueError):
    """Bad input the user can fix (empty layer, missing field, absurd parameter)."""


class MissingPackage(InputError):
    """A package the engine imports only where it needs it (OpenCV, onnxruntime) is not
    installed. ``distribution`` is its name on the package index: the QGIS glue turns this
    into the plugin's own advice (its dependency installer), not a pip command line."""

    def __init__(self, what: str, distribution: str):
        super().__init__(f"{what} is not installed (Python package {distribution})")
        self.distribution = distribution


def require(module: str, distribution: str, what: str = ""):
    """Import ``module`` where a method needs it; :class:`MissingPackage` when it is missing."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingPackage(what or distribution, distribution) from exc


class Canceled(RuntimeError):
    """The user canceled the operation."""


class Progress:
    """Maps engine-local fractions [0, 1] onto a sub-range of an outer progress bar.

    Parameters
    ----------
    report : callable(float percent) or None
    is_canceled : callable() -> bool or None
    log : callable(str) or None
        Informational messages (counts of repaired or skipped features ...).
    """

    def __init__(self, report: Optional[Callable[[float], None]] = None,
                 is_canceled: Optional[Callable[[], bool]] = None,
                 log: Optional[Callable[[str], None]] = None,
                 start: float = 0.0, end: float = 100.0):
        self._report = report
        self._is_canceled = is_canceled
        self._log = log
        self.start = start
        self.end = end

    def sub(self, a: float, b: float) -> "Progress":
        """A child progress covering fractions a..b of this one."""
        span = self.end - self.start
        return Progress(self._report, self._is_canceled, self._log,
                        self.start + a * span, self.start + b * span)

    def step(self, fraction: float) -> None:
        """Report progress and raise :class:`Canceled` if the user asked to stop."""
        self.check()
        if self._report is not None:
            f = min(max(fraction, 0.0), 1.0)
            self._report(self.start + f * (self.end - self.start))

    def check(self) -> None:
        """Raise :class:`Canceled` if the user asked to stop (no progress report): for
        loops whose share of the work is unknown, e.g. a backtracking search."""
        if self._is_canceled is not None and self._is_canceled():
            raise Canceled("Canceled by the user.")

    def info(self, message: str) -> None:
        if self._log is not None:
            self._log(message)


def ensure(progress: Optional[Progress]) -> Progress:
    return progress if progress is not None else Progress()
