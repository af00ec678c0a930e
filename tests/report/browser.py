"""A small Chrome DevTools Protocol client over ``--remote-debugging-pipe`` (stdlib only), for the report page's test.

Chromium reads commands on fd 3 and writes replies and events on fd 4, each one JSON message ended by a NUL byte. The
client opens one page target, enables the Page, Runtime and Log domains, navigates to a ``file://`` URL, waits for
the load event, evaluates a script and takes a screenshot, collecting every error the page reports on the way:
console errors, uncaught exceptions and log entries of level error (failed resource loads among them).
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: The Debian package's binary names, first found wins.
BINARIES = ("chromium", "chromium-browser", "google-chrome")


def find_chromium() -> str | None:
    """The path of a Chromium binary on PATH, None where none is installed."""
    return next((p for p in map(shutil.which, BINARIES) if p), None)


@dataclass
class PageVisit:
    """What a visit found: the evaluated value, the screenshot (PNG bytes) and every error reported."""

    value: Any
    screenshot: bytes
    errors: list[str] = field(default_factory=list)


class Browser:
    """A headless Chromium speaking CDP over a pipe; use as a context manager (the process is ended on exit)."""

    def __init__(self, binary: str, timeout: float = 30.0, size: tuple[int, int] = (1200, 900)):
        self.timeout = timeout
        self.profile = tempfile.mkdtemp(prefix="bop-cender-chromium-")
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()
        # the child's ends moved above fd 9, so that putting them on 3 and 4 in the child cannot clobber each other
        to_browser_r, from_browser_w = (_above(fd, 10) for fd in (to_browser_r, from_browser_w))
        # the child's fds 3 and 4 must be these ends: dup them there before exec
        self.process = subprocess.Popen(
            [binary, "--headless=new", "--remote-debugging-pipe", "--no-sandbox", "--disable-gpu",
             "--no-first-run", "--no-default-browser-check", "--disable-extensions", "--hide-scrollbars",
             f"--window-size={size[0]},{size[1]}", f"--user-data-dir={self.profile}", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            pass_fds=(3, 4), preexec_fn=lambda: (os.dup2(to_browser_r, 3), os.dup2(from_browser_w, 4)),
        )  # fmt: skip
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._buffer = b""
        self._next_id = 0
        self.events: list[dict] = []

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """End the browser (politely, then by force) and remove its profile."""
        with contextlib.suppress(OSError, TimeoutError, RuntimeError):
            self.send("Browser.close", timeout=5)
        try:
            self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        for fd in (self._to_browser, self._from_browser):
            with contextlib.suppress(OSError):
                os.close(fd)
        shutil.rmtree(self.profile, ignore_errors=True)

    def _read_message(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("no reply from chromium in time")
            ready, _, _ = select.select([self._from_browser], [], [], left)
            if ready:
                chunk = os.read(self._from_browser, 1 << 20)
                if not chunk:
                    raise RuntimeError("chromium closed its pipe")
                self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def send(
        self, method: str, params: dict | None = None, session: str | None = None, timeout: float | None = None
    ) -> dict:
        """Send one command and return its result (events that arrive meanwhile are kept in :attr:`events`)."""
        self._next_id += 1
        message: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
        if session is not None:
            message["sessionId"] = session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + (timeout or self.timeout)
        while True:
            reply = self._read_message(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def wait_for(self, method: str, session: str | None = None) -> dict:
        """The first event ``method`` (of ``session``), already received or still to come."""
        deadline = time.monotonic() + self.timeout
        seen = 0
        while True:
            for event in self.events[seen:]:
                if event.get("method") == method and (session is None or event.get("sessionId") == session):
                    return event
            seen = len(self.events)
            self.events.append(self._read_message(deadline))

    def visit(self, url: str, script: str) -> PageVisit:
        """Open ``url`` in a new page, wait for its load event, evaluate ``script`` and screenshot the whole page."""
        target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            self.send(f"{domain}.enable", session=session)
        self.send("Page.navigate", {"url": url}, session=session)
        self.wait_for("Page.loadEventFired", session)
        value = self.send("Runtime.evaluate", {"expression": script, "returnByValue": True, "awaitPromise": True},
                          session=session)["result"].get("value")  # fmt: skip
        metrics = self.send("Page.getLayoutMetrics", session=session)["cssContentSize"]
        shot = self.send(
            "Page.captureScreenshot",
            {"format": "png", "captureBeyondViewport": True,
             "clip": {"x": 0, "y": 0, "width": min(metrics["width"], 1200), "height": min(metrics["height"], 4000),
                      "scale": 1}},
            session=session,
        )  # fmt: skip
        return PageVisit(value, base64.b64decode(shot["data"]), page_errors(self.events, session))


def _above(fd: int, lowest: int) -> int:
    """``fd`` duplicated onto the lowest free descriptor >= ``lowest`` (the original closed)."""
    import fcntl

    high = fcntl.fcntl(fd, fcntl.F_DUPFD, lowest)
    os.close(fd)
    return high


def page_errors(events: list[dict], session: str) -> list[str]:
    """The errors among a page's events: console errors, uncaught exceptions, log entries of level error."""
    errors = []
    for event in events:
        if event.get("sessionId") != session:
            continue
        method, params = event.get("method"), event.get("params", {})
        if method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
            errors.append("console: " + " ".join(str(a.get("value", a.get("description"))) for a in params["args"]))
        elif method == "Runtime.exceptionThrown":
            errors.append("exception: " + str(params["exceptionDetails"].get("text")))
        elif method == "Log.entryAdded" and params["entry"].get("level") == "error":
            entry = params["entry"]
            errors.append(f"log: {entry.get('text')} {entry.get('url', '')}".strip())
    return errors


def file_url(path: Path) -> str:
    """The ``file://`` URL of a local file."""
    return Path(path).resolve().as_uri()
