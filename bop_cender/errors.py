"""Error and warning types that name the file, the field and what was expected.

Every user-facing failure in bop-cender is one of these, so the CLI can print it as one line
(``file: field: message``) instead of a traceback.
"""

from __future__ import annotations

from pathlib import Path


class BopCenderError(Exception):
    """Base error: carries the file, the field and the expectation that failed.

    Args:
        message: what went wrong and what was expected.
        file: the file (or folder) the problem is in, if any.
        field: the key, column or line inside that file, if any.
    """

    def __init__(self, message: str, *, file: str | Path | None = None, field: str | None = None):
        self.message = message
        self.file = None if file is None else str(file)
        self.field = field
        super().__init__(self.format())

    def format(self) -> str:
        """One line: ``FILE: FIELD: MESSAGE`` with the absent parts left out."""
        parts = [p for p in (self.file, self.field) if p]
        return ": ".join([*parts, self.message])


class DatasetError(BopCenderError):
    """A dataset on disk is missing a file, malformed or inconsistent."""


class ResultsError(BopCenderError):
    """A results CSV (or a sidecar) is malformed; may carry many problems, one per bad line.

    Args:
        message: summary line.
        problems: every problem found, each already formatted with its line number.
    """

    def __init__(
        self,
        message: str,
        *,
        file: str | Path | None = None,
        field: str | None = None,
        problems: list[str] | None = None,
    ):
        self.problems = list(problems or [])
        super().__init__(message, file=file, field=field)

    #: Problems shown by :meth:`format` (a file with a wrong column order has one per line: the first few tell).
    SHOWN_PROBLEMS = 20

    def format(self) -> str:
        head = super().format()
        if not self.problems:
            return head
        shown = self.problems[: self.SHOWN_PROBLEMS]
        more = len(self.problems) - len(shown)
        tail = [f"  ... and {more} more of the {len(self.problems)}"] if more > 0 else []
        return "\n".join([head, *(f"  {p}" for p in shown), *tail])


class ConfigError(BopCenderError):
    """A command-line option or configuration value is invalid."""


class RunError(ResultsError):
    """A run produced nothing usable (every scene failed); carries one problem per failed scene."""


class DatasetWarning(UserWarning):
    """Something in a dataset is suspicious but usable (rounded poses, say)."""


class ResultsWarning(UserWarning):
    """Something in a results file is suspicious but usable (a slightly non-orthonormal R)."""
