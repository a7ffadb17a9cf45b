"""Domain exceptions shared by every vertebra package.

They live in ``store`` because it is the lowest layer (``designer`` and ``solver``
both depend on it); libraries raise them, only ``cli`` turns them into exit codes.
"""

from __future__ import annotations


class VertebraError(Exception):
    """Base class of every error vertebra raises on purpose."""


class SceneError(VertebraError):
    """A scene file or scene dictionary is invalid (names file, field and reason)."""

    def __init__(self, reason: str, *, file: str | None = None, field: str | None = None):
        self.file = file
        self.field = field
        self.reason = reason
        where = ": ".join(part for part in (file, field) if part)
        super().__init__(f"{where}: {reason}" if where else reason)


class CatalogueError(VertebraError):
    """A catalogue file is missing, corrupted, foreign or inconsistent."""


class GeometryError(VertebraError):
    """Design parameters describe an impossible geometry (names the parameter)."""


class ConvergenceError(VertebraError):
    """A nonlinear solve did not converge; carries the partial result if any."""

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result
