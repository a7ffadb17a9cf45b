"""Domain exceptions shared by every vertebra package (the kernel layer: no other import).

Libraries raise them; only ``cli`` turns them into exit codes.

Errors by meaning:

* :class:`InputError` — something a user wrote is invalid. It names the *source* (a file,
  ``<dict>``, ``--option``), the *field* inside it and the *reason*. Its kinds:
  :class:`SceneError` (scene files), :class:`SpecError` (sweep specifications),
  :class:`TrajectoryError` (trajectory CSV files), :class:`OptionError` (command-line and
  API options).
* :class:`CatalogueError` — a catalogue file is missing, corrupted, foreign or inconsistent,
  or the disk refused a write.
* :class:`GeometryError` — design parameters describe an impossible or implausible geometry.
* :class:`ConvergenceError` — a numerical stage failed; carries the partial result.
"""

from __future__ import annotations


class VertebraError(Exception):
    """Base class of every error vertebra raises on purpose."""


class InputError(VertebraError):
    """Invalid user input: names the source, the field and the reason.

    ``file`` is the source (a path, ``<dict>``, or the option's name on a command line)."""

    def __init__(self, reason: str, *, file: str | None = None, field: str | None = None):
        self.file = file
        self.field = field
        self.reason = reason
        where = ": ".join(str(part) for part in (file, field) if part)
        super().__init__(f"{where}: {reason}" if where else reason)

    @property
    def source(self) -> str | None:
        return self.file


class SceneError(InputError):
    """A scene file or scene dictionary is invalid (names file, field and reason)."""


class SpecError(InputError):
    """A sweep specification is invalid (names file, field and reason)."""


class TrajectoryError(InputError):
    """A trajectory file is invalid (names file, row or column, and reason)."""


class OptionError(InputError):
    """A command-line or API option is invalid (names the option and the reason)."""


class CatalogueError(VertebraError):
    """A catalogue file is missing, corrupted, foreign or inconsistent."""


class GeometryError(VertebraError):
    """Design parameters describe an impossible geometry (names the parameter)."""


class ConvergenceError(VertebraError):
    """A nonlinear solve did not converge; carries the partial result if any."""

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result


class PlausibilityWarning(UserWarning):
    """An input that is valid but implausible, most likely a unit slip (a pressure of 1.5 Pa, a
    Young's modulus of 5 Pa, a mesh size larger than the part): the message names the field,
    the value and the likely intended unit. The command line prints it as one line."""
