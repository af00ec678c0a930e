"""Type and range checks of the method's settings (``TargetConfig``, ``CenterConfig``, ``PoseConfig``).

A setting comes from code, from ``run --set section.field=value`` or from the targets recorded in a weights
file. Each config checks its fields in ``__post_init__`` with :func:`check_settings`, so a bad value is one
error naming the field before any scene runs: never a traceback mid-run, and never a silent no-op such as a
search with zero candidates or a peak threshold no heatmap reaches.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass

from bop_cender.errors import ConfigError


@dataclass(frozen=True)
class Bound:
    """What one setting may be.

    Attributes:
        low, high: the range (None: unbounded on that side).
        low_open, high_open: the bound itself is excluded.
        integer: an int (bools refused); otherwise any finite real number.
        optional: None is allowed.
    """

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    integer: bool = False
    optional: bool = False

    def describe(self) -> str:
        kind = "an integer" if self.integer else "a number"
        if self.low is not None and self.high is not None:
            text = (
                f"{kind} in {'(' if self.low_open else '['}{self.low:g}, {self.high:g}{')' if self.high_open else ']'}"
            )
        elif self.low is not None:
            text = f"{kind} {'>' if self.low_open else '>='} {self.low:g}"
        elif self.high is not None:
            text = f"{kind} {'<' if self.high_open else '<='} {self.high:g}"
        else:
            text = kind
        return text + (" or none" if self.optional else "")

    def admits(self, value: object) -> bool:
        if value is None:
            return self.optional
        if isinstance(value, bool) or not isinstance(value, numbers.Integral if self.integer else numbers.Real):
            return False
        number = float(value)  # type: ignore[arg-type]
        if not math.isfinite(number):
            return False
        if self.low is not None and (number <= self.low if self.low_open else number < self.low):
            return False
        return not (self.high is not None and (number >= self.high if self.high_open else number > self.high))


#: Shorthands for the common bounds.
POSITIVE = Bound(0.0, low_open=True)
NON_NEGATIVE = Bound(0.0)
COUNT = Bound(1, integer=True)
COUNT_OR_ZERO = Bound(0, integer=True)
FRACTION_OPEN = Bound(0.0, 1.0, low_open=True, high_open=True)


def check_settings(section: str, config: object, bounds: Mapping[str, Bound], flags: tuple[str, ...] = ()) -> None:
    """Check the fields of ``config`` named in ``bounds`` (and that the fields in ``flags`` are bools).

    Raises:
        ConfigError: the first field outside its bound, as ``section.field: expected ..., got ...`` (field ``--set``).
    """
    for name, bound in bounds.items():
        value = getattr(config, name)
        if not bound.admits(value):
            raise ConfigError(f"{section}.{name}: expected {bound.describe()}, got {value!r}", field="--set")
    for name in flags:
        value = getattr(config, name)
        if not isinstance(value, bool):
            raise ConfigError(f"{section}.{name}: expected true or false, got {value!r}", field="--set")
