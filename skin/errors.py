"""One exception root for the whole project.

Each subclass also inherits the built-in a caller would naturally catch, so
``except ValueError`` keeps working for code that does not know canskin.
"""

from __future__ import annotations


class SkinError(Exception):
    """Root of every error canskin raises on purpose."""


class ConfigError(SkinError, ValueError):
    """A scene, config or command-line value is wrong; the message names the field, and
    the file it is in when there is one (``scene.toml: loads[0].kind: ...``)."""

    def __init__(self, field: str, problem: str, *, source: str | None = None) -> None:
        self.field = field
        self.problem = problem
        self.source = source
        where = ": ".join(part for part in (source, field) if part)
        super().__init__(f"{where}: {problem}" if where else problem)

    def in_file(self, source: str) -> ConfigError:
        """The same error naming the file it came from (kept if it names one already)."""
        if self.source is not None:
            return self
        return ConfigError(self.field, self.problem, source=source)


class StrainLimitError(SkinError, ValueError):
    """A force would strain a pillar past the model's validity limit."""


class ConvergenceError(SkinError, ArithmeticError):
    """An iterative solve of the sensor model did not converge."""


class DecodeError(SkinError, ValueError):
    """Resistances could not be turned into forces."""


class NotFittedError(SkinError, ValueError):
    """A decoder was used before it was fitted."""


class ModelFileError(SkinError, ValueError):
    """A model file is corrupt, truncated, of another schema, or hostile."""


class DatasetError(SkinError, ValueError):
    """A dataset file is missing keys, has wrong shapes, or is unreadable."""


class OutputError(SkinError, OSError):
    """A result cannot be written where the user asked: names the user's path, never a
    temporary file's."""


class BusError(SkinError, RuntimeError):
    """Something on the CAN bus went wrong."""


class SourceError(SkinError, RuntimeError):
    """What feeds the patches their resistances (the simulator, a replay) failed."""


class RecordingError(SkinError, ValueError):
    """A recording is truncated, corrupt or of an unsupported kind; names the frame."""

    def __init__(self, source: str, frame: int | None, problem: str) -> None:
        self.source = source
        self.frame = frame
        self.problem = problem
        where = f"{source}: frame {frame}" if frame is not None else source
        super().__init__(f"{where}: {problem}")


class ReferenceFileError(SkinError, ValueError):
    """A reference-force file (CSV or .npz) is malformed; names the file and the row."""

    def __init__(self, source: str, row: int | None, problem: str) -> None:
        self.source = source
        self.row = row
        self.problem = problem
        where = f"{source}: row {row}" if row is not None else source
        super().__init__(f"{where}: {problem}")


def printable_line(text: str) -> str:
    """``text`` as one printable line: whitespace runs (line breaks of every kind
    included) become one space, other control characters their ``\\xNN`` escape, so text
    read from a broken file can neither split an error line nor drive the terminal."""
    flat = " ".join(text.split())
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii")
                   for c in flat)

