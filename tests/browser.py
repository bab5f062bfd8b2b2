"""A headless Chromium driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``): no port, no client
library, no browser download; Debian's ``chromium`` package is enough.

The pipe is fd 3 (Chromium reads) and fd 4 (Chromium writes), each message JSON followed by a NUL byte. One page is
opened in a flattened session; console errors, uncaught exceptions and error log entries (a resource that fails to
load is one) are collected while it loads.
"""

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

#: Debian names the binary ``chromium``; other systems ``chromium-browser`` or ``google-chrome``
BINARIES = ("chromium", "chromium-browser", "google-chrome")
PAGE_PROBE = """JSON.stringify({
  images: Array.from(document.images).map(i => [i.getAttribute('src'), i.complete, i.naturalWidth]),
  headings: Array.from(document.querySelectorAll('h1, h2, h3')).map(h => h.textContent.trim()),
})"""


def find_chromium() -> str | None:
    return next((path for path in map(shutil.which, BINARIES) if path), None)


@dataclass
class PageVisit:
    """What one page load showed: errors, every ``<img>`` as (src, complete, naturalWidth), headings, screenshot."""

    errors: list[str] = field(default_factory=list)
    images: list[tuple[str, bool, int]] = field(default_factory=list)
    headings: list[str] = field(default_factory=list)
    screenshot: bytes = b""
    #: what each of ``visit``'s ``steps`` returned, in order
    results: list[Any] = field(default_factory=list)


class Chromium:
    """One headless browser process; use as a context manager."""

    def __init__(self, binary: str, timeout: float = 60.0) -> None:
        self.timeout = timeout
        self.profile = tempfile.mkdtemp(prefix="report-chromium-")
        to_browser, self._write = os.pipe()
        self._read, from_browser = os.pipe()

        def plumb() -> None:  # in the child: the protocol's fixed descriptors
            reading, writing = os.dup(to_browser), os.dup(from_browser)
            os.dup2(reading, 3)
            os.dup2(writing, 4)

        arguments = ["--headless", "--no-sandbox", "--disable-gpu", "--remote-debugging-pipe", "--no-first-run",
                     "--window-size=1280,1000", f"--user-data-dir={self.profile}", "about:blank"]  # fmt: skip
        self.process = subprocess.Popen(
            [binary, *arguments], preexec_fn=plumb, close_fds=False,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        os.close(to_browser)
        os.close(from_browser)
        self._buffer = b""
        self._next_id = 0
        self._events: list[dict[str, Any]] = []

    def __enter__(self) -> "Chromium":
        return self

    def __exit__(self, *exc: object) -> None:
        with contextlib.suppress(OSError):
            self._send("Browser.close")
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        os.close(self._write)
        os.close(self._read)
        shutil.rmtree(self.profile, ignore_errors=True)

    def _send(self, method: str, params: dict[str, Any] | None = None, session: str | None = None) -> int:
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._write, json.dumps(message).encode() + b"\0")
        return self._next_id

    def _receive(self, deadline: float) -> dict[str, Any]:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._read], [], [], left)[0]:
                raise TimeoutError("chromium did not answer in time")
            chunk = os.read(self._read, 1 << 20)
            if not chunk:
                raise ConnectionError("chromium closed the DevTools pipe")
            self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def call(self, method: str, params: dict[str, Any] | None = None, session: str | None = None) -> dict[str, Any]:
        """Send a command and wait for its answer; events that arrive meanwhile are kept."""
        wanted = self._send(method, params, session)
        deadline = time.monotonic() + self.timeout
        while True:
            message = self._receive(deadline)
            if message.get("id") == wanted:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message.get("result", {})
            self._events.append(message)

    def _wait_for(self, method: str, session: str) -> None:
        deadline = time.monotonic() + self.timeout
        while not any(e.get("method") == method and e.get("sessionId") == session for e in self._events):
            self._events.append(self._receive(deadline))

    def _evaluate(self, expression: str, session: str) -> Any:
        answer = self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True}, session)
        if "exceptionDetails" in answer:
            raise RuntimeError(f"{expression}: {answer['exceptionDetails'].get('text')}")
        return answer["result"].get("value")

    def visit(self, page: Path, steps: tuple[str, ...] = ()) -> PageVisit:
        """Open ``page`` from the file system, wait for its load event, run each JavaScript expression of ``steps``
        in turn (a click, a query; their JSON-able values are kept), probe it and take a full-page screenshot."""
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Runtime", "Log", "Page"):
            self.call(f"{domain}.enable", session=session)
        self._events.clear()
        self.call("Page.navigate", {"url": page.resolve().as_uri()}, session)
        self._wait_for("Page.loadEventFired", session)
        results = [self._evaluate(step, session) for step in steps]
        probe = self.call("Runtime.evaluate", {"expression": PAGE_PROBE, "returnByValue": True}, session)
        shot = self.call("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True}, session)
        visit = PageVisit(screenshot=base64.b64decode(shot["data"]), results=results)
        found = json.loads(probe["result"]["value"])
        visit.images = [tuple(image) for image in found["images"]]
        visit.headings = found["headings"]
        visit.errors = [_error(event) for event in self._events if _error(event)]
        self.call("Target.closeTarget", {"targetId": target})
        return visit


def _error(event: dict[str, Any]) -> str:
    """The text of an error event, empty for any other event."""
    method, params = event.get("method"), event.get("params", {})
    if method == "Runtime.consoleAPICalled" and params.get("type") == "error":
        return "console.error: " + " ".join(str(arg.get("value")) for arg in params.get("args", []))
    if method == "Runtime.exceptionThrown":
        return "exception: " + params.get("exceptionDetails", {}).get("text", "")
    if method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
        entry = params["entry"]
        return f"log: {entry.get('text')} {entry.get('url', '')}"
    return ""
