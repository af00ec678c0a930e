"""Progress bars on stderr that write no escape codes where stderr is not a terminal: the one bar factory.

tqdm redraws its bar with ``\\r`` (and ANSI cursor moves for nested bars) whatever the stream is, so a
log file or a CI job's output fills with carriage returns and hundreds of half-lines. Every bar of
bop-cender comes from :func:`progress_bar`: a tqdm bar on a terminal, else a :class:`LineProgress`
that prints a plain line now and then (each tenth of the way, at most one per ``interval`` seconds)
and, for a bar that stays (``leave``), one last line when it closes.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import IO, Any

#: Seconds between two lines of a :class:`LineProgress` (the last line is always written).
LINE_INTERVAL_S = 5.0


def progress_bar(
    iterable: Iterable | None = None,
    *,
    total: int | None = None,
    desc: str = "",
    unit: str = "it",
    disable: bool | None = False,
    leave: bool = True,
    initial: int = 0,
    file: IO[str] | None = None,
    interval: float = LINE_INTERVAL_S,
) -> Any:
    """A progress bar with tqdm's interface (``update``, ``close``, ``n``, ``set_postfix``, iteration, ``with``).

    Args:
        disable: True: no output at all; None: as tqdm, no output where ``file`` is not a terminal.
        file: the stream (default: ``sys.stderr`` at the time of the call).
        interval: least seconds between two plain lines (where ``file`` is not a terminal).
    """
    stream = sys.stderr if file is None else file
    tty = _is_tty(stream)
    if disable or (disable is None and not tty):
        from tqdm import tqdm

        return tqdm(iterable, total=total, disable=True)
    if tty:
        from tqdm import tqdm

        return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave, initial=initial, file=stream)
    return LineProgress(iterable, total=total, desc=desc, unit=unit, leave=leave, initial=initial, file=stream,
                        interval=interval)  # fmt: skip


def _is_tty(stream: IO[str]) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


class LineProgress:
    """Plain-line progress for a stream that is not a terminal: ``desc: 3/15 scenes (20%), 4.1 s``, no ``\\r``."""

    def __init__(
        self,
        iterable: Iterable | None = None,
        *,
        total: int | None = None,
        desc: str = "",
        unit: str = "it",
        leave: bool = True,
        initial: int = 0,
        file: IO[str],
        interval: float = LINE_INTERVAL_S,
    ) -> None:
        self.iterable = iterable
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)  # type: ignore[arg-type]
        self.total = total
        self.desc, self.unit, self.leave, self.file, self.interval = desc, unit, leave, file, interval
        self.n = initial
        self.postfix = ""
        self._start = time.monotonic()
        self._last_line = self._start
        self._last_tenth = self._tenth()
        self._closed = False

    def __iter__(self) -> Iterator:
        assert self.iterable is not None, "LineProgress(iterable) to iterate"
        try:
            for item in self.iterable:
                yield item
                self.update()
        finally:
            self.close()

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __len__(self) -> int:
        return self.total or 0

    def _tenth(self) -> int:
        return 10 * self.n // self.total if self.total else 0

    def update(self, n: int = 1) -> None:
        """Count ``n`` more; write a line when a new tenth is reached (or, without a total, ``interval`` passed)
        and ``interval`` seconds passed since the last one."""
        self.n += n
        if self.leave and self.total is not None and self.n >= self.total:
            return  # the last line is close()'s
        now = time.monotonic()
        if now - self._last_line < self.interval:
            return
        tenth = self._tenth()
        if self.total and tenth == self._last_tenth:
            return
        self._last_tenth, self._last_line = tenth, now
        self._write(now)

    def set_postfix(self, ordered_dict: dict | None = None, refresh: bool = True, **kwargs: Any) -> None:
        """As tqdm's: ``key=value`` pairs written after the count on the next line."""
        items = {**(ordered_dict or {}), **kwargs}
        self.postfix = ", ".join(f"{k}={v}" for k, v in items.items())

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        """As tqdm's: a text written after the count on the next line."""
        self.postfix = s

    def close(self) -> None:
        """Write the last line (a bar that stays, ``leave``), once."""
        if self._closed:
            return
        self._closed = True
        if self.leave:
            self._write(time.monotonic(), last=True)

    def _write(self, now: float, last: bool = False) -> None:
        count = f"{self.n}/{self.total}" if self.total is not None else f"{self.n}"
        pct = f" ({100 * self.n // self.total}%)" if self.total else ""
        head = f"{self.desc}: " if self.desc else ""
        tail = f", {self.postfix}" if self.postfix else ""
        done = " done" if last else ""
        self.file.write(f"{head}{count} {self.unit}{pct}{done}, {now - self._start:.1f} s{tail}\n")
        self.file.flush()
