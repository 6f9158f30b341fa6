"""Headless Chromium driven over the DevTools protocol, for the tests that open the workflow's HTML
pages (tests/test_report_browser.py) and for the screenshots in docs/images/.

Why the DevTools protocol and not ``chromium --dump-dom``: the Snakemake report is a React app that
shows a result only after clicks, inside an iframe, and a page's console errors come as events.
The protocol gives both; websocket-client (test extras) carries it.

    python tests/chromium.py REPORT.html STUDY_DIR OUT_DIR   # the screenshots of docs/results.md
"""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import websocket

CONSOLE_ERROR_TYPES = ("error", "assert")


class BrowserUnavailable(RuntimeError):
    """Chromium is not installed, or does not start."""


INSTALL_COMMAND = "apt-get install chromium"  # Debian's package; .ci/run installs it


def chromium_binary() -> str:
    """The Chromium executable. Never installs it: raises BrowserUnavailable naming the command that does."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if not found:
        raise BrowserUnavailable(f"chromium is not installed: `{INSTALL_COMMAND}` installs it (.ci/run does)")
    return found


class Page:
    """One Chromium tab: navigate, evaluate JavaScript (in the page or in one of its frames), click,
    and the console errors, uncaught exceptions and error log entries of every frame so far."""

    def __init__(self, binary: str, width: int = 1280, height: int = 800, timeout: float = 30.0):
        self.timeout = timeout
        self.profile = Path(tempfile.mkdtemp(prefix="chromium-profile-"))
        # --no-sandbox: Chromium refuses to start as root with its sandbox (CI containers run as
        # root); the pages opened are the workflow's own local files.
        self.process = subprocess.Popen(
            [binary, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--remote-debugging-port=0",
             f"--user-data-dir={self.profile}", f"--window-size={width},{height}", "--hide-scrollbars", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )
        try:
            self.socket = websocket.create_connection(self._page_socket_url(), timeout=timeout, suppress_origin=True)
        except BaseException:
            self.close()
            raise
        self._next_id = 0
        self.events: list[dict] = []
        for domain in ("Runtime", "Page", "Log"):
            self.send(f"{domain}.enable")

    def _page_socket_url(self) -> str:
        """The tab's DevTools address: Chromium writes its port to DevToolsActivePort in the profile."""
        port_file = self.profile / "DevToolsActivePort"
        deadline = time.monotonic() + self.timeout
        while not (port_file.is_file() and port_file.read_text().strip()):
            if self.process.poll() is not None:
                raise BrowserUnavailable(f"chromium exited with code {self.process.returncode} at start:\n{self.process.stderr.read()[-3000:]}")
            if time.monotonic() > deadline:
                raise BrowserUnavailable(f"chromium wrote no DevToolsActivePort in {self.timeout:.0f} s")
            time.sleep(0.05)
        port = port_file.read_text().split()[0]
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=self.timeout) as response:
            targets = json.load(response)
        return next(target["webSocketDebuggerUrl"] for target in targets if target["type"] == "page")

    def close(self) -> None:
        if getattr(self, "socket", None) is not None:
            self.socket.close()
        self.process.terminate()
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self) -> Page:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ protocol

    def send(self, method: str, **params) -> dict:
        """Call a protocol method and return its result; events arriving meanwhile are kept."""
        self._next_id += 1
        self.socket.send(json.dumps({"id": self._next_id, "method": method, "params": params}))
        while True:
            message = json.loads(self.socket.recv())
            if message.get("id") == self._next_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message["result"]
            self.events.append(message)

    def _wait_event(self, method: str, after: int) -> dict:
        deadline = time.monotonic() + self.timeout
        while True:
            for event in self.events[after:]:
                if event.get("method") == method:
                    return event
            if time.monotonic() > deadline:
                raise TimeoutError(f"no {method} within {self.timeout:.0f} s")
            self.events.append(json.loads(self.socket.recv()))

    def open(self, path: Path) -> None:
        """Load a local file and wait for its load event."""
        seen = len(self.events)
        self.send("Page.navigate", url=Path(path).resolve().as_uri())
        self._wait_event("Page.loadEventFired", seen)

    def evaluate(self, expression: str, frame: str | None = None):
        """The value of a JavaScript expression (promises awaited), in the page or in the frame with id ``frame``."""
        context = {} if frame is None else {"contextId": self.send("Page.createIsolatedWorld", frameId=frame)["executionContextId"]}
        result = self.send("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True, **context)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression[:200]}: {result['exceptionDetails'].get('exception', result['exceptionDetails'])}")
        return result["result"].get("value")

    def wait_for(self, expression: str, frame: str | None = None, what: str | None = None):
        """Poll ``expression`` until it is truthy; returns its value."""
        deadline = time.monotonic() + self.timeout
        while True:
            value = self.evaluate(expression, frame)
            if value:
                return value
            if time.monotonic() > deadline:
                raise TimeoutError(f"{what or expression[:200]}: not true within {self.timeout:.0f} s")
            time.sleep(0.1)

    def click_text(self, text: str) -> None:
        """Click the innermost element of the page whose whole text is ``text`` (React menu entries),
        waiting for it to appear (the previous click's view may still be rendering)."""
        self.wait_for(
            f"(() => {{ const hits = [...document.querySelectorAll('body *')].filter(el => el.textContent.trim() === {json.dumps(text)});"
            " if (!hits.length) return false; hits[hits.length - 1].click(); return true; })()",
            what=f"an element with the text {text!r}",
        )

    def frames(self) -> list[dict]:
        """The page's child frames (id, url), depth first."""
        found = []

        def walk(node: dict) -> None:
            for child in node.get("childFrames", []):
                found.append(child["frame"])
                walk(child)

        walk(self.send("Page.getFrameTree")["frameTree"])
        return found

    def errors(self) -> list[str]:
        """Console errors and failed assertions, uncaught exceptions and error log entries, of every frame."""
        self.send("Runtime.evaluate", expression="0")  # a round trip: the events Chromium sent before it are read
        found = []
        for event in self.events:
            method, params = event.get("method"), event.get("params", {})
            if method == "Runtime.consoleAPICalled" and params.get("type") in CONSOLE_ERROR_TYPES:
                found.append("console." + params["type"] + ": " + " ".join(str(arg.get("value", arg.get("description", ""))) for arg in params.get("args", [])))
            elif method == "Runtime.exceptionThrown":
                details = params.get("exceptionDetails", {})
                found.append("exception: " + str(details.get("exception", {}).get("description", details.get("text"))))
            elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
                entry = params["entry"]
                found.append(f"log ({entry.get('source')}): {entry.get('text')} {entry.get('url', '')}".strip())
        return found

    def screenshot(self, out: Path) -> Path:
        data = self.send("Page.captureScreenshot", format="png")["data"]
        Path(out).write_bytes(base64.b64decode(data))
        return Path(out)


# ---------------------------------------------------------------------- the Snakemake report


def show_report_result(page: Page, *menu: str) -> None:
    """Open a result of the Snakemake report: click through the menu entries (category, then
    subcategory if any), then the first result's view button."""
    for entry in menu:
        page.click_text(entry)
    page.wait_for("document.querySelector('a[iconname=eye]') !== null", what=f"a view button under {' > '.join(menu)}")
    page.evaluate("document.querySelector('a[iconname=eye]').click()")


def report_frame(page: Page, filename: str) -> str:
    """The id of the report's content frame that shows ``filename`` (an HTML result), once loaded."""
    marker = f"filename={filename};"

    def frame_id():
        return next((frame["id"] for frame in page.frames() if marker in frame.get("url", "")), None)

    deadline = time.monotonic() + page.timeout
    while (found := frame_id()) is None:
        if time.monotonic() > deadline:
            raise TimeoutError(f"the report shows no frame with {filename}")
        time.sleep(0.1)
    page.wait_for("document.readyState === 'complete'", frame=found, what=f"{filename} loaded")
    return found


def take_screenshots(report: Path, study: Path, out_dir: Path) -> list[Path]:
    """docs/images: the report showing table 1 and a novel-view clip, and the study page."""
    out_dir.mkdir(parents=True, exist_ok=True)
    binary = chromium_binary()
    written = []
    all_images_loaded = "[...document.images].every(image => image.complete && image.naturalWidth > 0)"
    with Page(binary, 1280, 760) as page:
        page.open(report)
        page.wait_for("document.body.innerText.includes('1. Tables')")
        show_report_result(page, "1. Tables", "Table 1: method comparison")
        report_frame(page, "table1.html")
        written.append(page.screenshot(out_dir / "report.png"))
        clip = page.evaluate("Object.keys(results).find(path => path.includes('/clips/')).split('/').pop()")
        page.click_text("Results")
        show_report_result(page, "2. Figures", "Novel-view clips")
        page.wait_for("(() => { const video = document.querySelector('video'); return video && video.readyState >= 2; })()",
                      frame=report_frame(page, clip), what="the clip's video decoded")
        written.append(page.screenshot(out_dir / "report-clip.png"))
    with Page(binary, 1000, 900) as page:
        page.open(study / "index.html")
        page.wait_for(all_images_loaded)
        written.append(page.screenshot(out_dir / "study-page.png"))
    return written


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    for path in take_screenshots(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])):
        print(path)
