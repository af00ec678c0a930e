"""Progress bars: tqdm on a terminal; plain lines, without ``\\r`` or escape codes, on anything else."""

from __future__ import annotations

import io

from bop_cender.progress import LineProgress, progress_bar


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_not_a_terminal_gets_a_line_per_tenth_and_a_last_line() -> None:
    out = io.StringIO()
    with progress_bar(total=20, desc="work", unit="scene", file=out, interval=0) as bar:
        assert isinstance(bar, LineProgress)
        for _ in range(20):
            bar.update()
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue() and "\x1b" not in out.getvalue()
    assert [line.split(",")[0] for line in lines] == [f"work: {2 * k}/20 scene ({10 * k}%)" for k in range(1, 10)] + [
        "work: 20/20 scene (100%) done"
    ]


def test_lines_are_rate_limited_and_a_bar_that_does_not_stay_writes_no_last_line() -> None:
    out = io.StringIO()
    bar = progress_bar(range(50), desc="inner", file=out, interval=3600, leave=False)
    assert sum(1 for _ in bar) == 50
    assert out.getvalue() == ""
    out = io.StringIO()
    bar = progress_bar(total=None, desc="open-ended", unit="pair", file=out, interval=0)
    bar.update(7)
    bar.set_postfix_str("last 000001")
    bar.close()
    bar.close()  # once
    assert out.getvalue().splitlines()[-1].startswith("open-ended: 7 pair done, ")
    assert out.getvalue().splitlines()[-1].endswith(", last 000001") and len(out.getvalue().splitlines()) == 2


def test_disabled_writes_nothing_and_a_terminal_gets_tqdm() -> None:
    out = io.StringIO()
    for disable in (True, None):  # None: as tqdm, nothing where the stream is not a terminal
        bar = progress_bar(total=3, desc="x", file=out, disable=disable)
        bar.update(3)
        bar.close()
    assert out.getvalue() == ""
    tty = Terminal()
    bar = progress_bar(total=3, desc="x", file=tty)
    bar.update(3)
    bar.close()
    assert not isinstance(bar, LineProgress) and "\r" in tty.getvalue()
