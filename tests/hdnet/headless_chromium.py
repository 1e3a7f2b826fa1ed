"""A headless Chromium for the browser tests of ``hd view``, driven through chromedriver's W3C
WebDriver protocol with the standard library (no Selenium): open a page, run a script in it, click
an element as a user would (chromedriver refuses a click that another element would catch), send
pointer and wheel input, and read the browser's console.

Chromium and chromedriver are system packages (Debian: ``apt-get install chromium chromium-driver``);
:func:`browser_or_skip` skips a test, saying what is missing, where either is absent.
"""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import time
import urllib.error
import urllib.request
from typing import Any

import pytest

ELEMENT = "element-6066-11e4-a52e-4f735466cecf"  # the W3C key of an element reference
WINDOW = (1400, 1000)  # CSS pixels, the window of issue 48's screenshots


class WebDriverError(Exception):
    """An error chromedriver answered, with its W3C error code (``element click intercepted``, ...)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(f"{code}: {message.splitlines()[0] if message else ''}")
        self.code = code


class Browser:
    """One chromedriver process and one headless Chromium session whose viewport is ``window`` (CSS pixels)."""

    def __init__(self, binary: str, driver: str, window: tuple[int, int] = WINDOW) -> None:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        self.base = f"http://127.0.0.1:{port}"
        self.process = subprocess.Popen(
            [driver, f"--port={port}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        self.session = ""
        try:
            self._wait_ready()
            options = {
                "binary": binary,
                "args": [
                    "--headless=new",
                    "--no-sandbox",
                    "--disable-gpu",
                    "--disable-dev-shm-usage",
                    f"--window-size={window[0]},{window[1]}",
                ],
            }
            caps = {"browserName": "chrome", "goog:chromeOptions": options, "goog:loggingPrefs": {"browser": "ALL"}}
            self.session = self._call("POST", "/session", {"capabilities": {"alwaysMatch": caps}})["sessionId"]
            # The viewport itself WINDOW (a headless window's size includes room for a toolbar).
            metrics = {"width": window[0], "height": window[1], "deviceScaleFactor": 1, "mobile": False}
            self._session("POST", "/goog/cdp/execute", {"cmd": "Emulation.setDeviceMetricsOverride", "params": metrics})
        except BaseException:
            self.close()
            raise

    def _wait_ready(self, timeout_s: float = 30.0) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                if self._call("GET", "/status").get("ready"):
                    return
            except (OSError, WebDriverError):
                pass
            if time.monotonic() > deadline or self.process.poll() is not None:
                raise RuntimeError("chromedriver did not start")
            time.sleep(0.1)

    def _call(self, method: str, path: str, body: object = None) -> Any:
        data = None if body is None else json.dumps(body).encode("utf-8")
        request = urllib.request.Request(
            self.base + path, data=data, method=method, headers={"Content-Type": "application/json"}
        )
        try:
            with urllib.request.urlopen(request, timeout=60) as response:
                return json.loads(response.read() or b"null").get("value")
        except urllib.error.HTTPError as exc:
            value = json.loads(exc.read() or b"{}").get("value", {})
            raise WebDriverError(str(value.get("error", exc.code)), str(value.get("message", ""))) from None

    def _session(self, method: str, path: str, body: object = None) -> Any:
        return self._call(method, f"/session/{self.session}{path}", body)

    def get(self, url: str) -> None:
        """Open ``url`` and wait for it to load."""
        self._session("POST", "/url", {"url": url})

    def run(self, script: str, *args: Any) -> Any:
        """The value of ``script`` (a function body: ``arguments`` are ``args``) run in the page."""
        return self._session("POST", "/execute/sync", {"script": script, "args": list(args)})

    def find(self, css: str) -> dict[str, str]:
        """The element that the CSS selector ``css`` finds first (a reference for :meth:`run`'s ``args``)."""
        found = self._session("POST", "/element", {"using": "css selector", "value": css})
        return {ELEMENT: found[ELEMENT]}

    def click(self, css: str) -> None:
        """Click the element ``css`` finds, at its centre, as a user would.

        Raises:
            WebDriverError: ``element click intercepted`` where another element would take the click.
        """
        self._session("POST", f"/element/{self.find(css)[ELEMENT]}/click", {})

    def pointer(self, *steps: dict[str, Any]) -> None:
        """Mouse input (W3C pointer actions: ``pointerMove`` with ``x``, ``y`` in the viewport,
        ``pointerDown``, ``pointerUp``)."""
        source = {"type": "pointer", "id": "mouse", "parameters": {"pointerType": "mouse"}, "actions": list(steps)}
        self._session("POST", "/actions", {"actions": [source]})
        self._session("DELETE", "/actions")

    def wheel(self, x: int, y: int, delta_y: int) -> None:
        """One turn of the wheel at (``x``, ``y``) in the viewport (``delta_y`` < 0: away from the user)."""
        step = {"type": "scroll", "x": x, "y": y, "deltaX": 0, "deltaY": delta_y, "origin": "viewport"}
        source = {"type": "wheel", "id": "wheel", "actions": [step]}
        self._session("POST", "/actions", {"actions": [source]})

    def console(self) -> list[dict[str, Any]]:
        """The browser console's entries since the last call (``level``, ``message``)."""
        return list(self._session("POST", "/se/log", {"type": "browser"}))

    def screenshot(self) -> bytes:
        """A PNG of the viewport."""
        import base64

        return base64.b64decode(self._session("GET", "/screenshot"))

    def close(self) -> None:
        """End the session and chromedriver."""
        try:
            if self.session:
                self._session("DELETE", "")
        except (OSError, WebDriverError):
            pass
        finally:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


def browser_or_skip() -> Browser:
    """A :class:`Browser`, or a skip of the test saying what is missing."""
    binary = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    driver = shutil.which("chromedriver")
    if binary is None or driver is None:
        pytest.skip("Chromium or chromedriver is missing (Debian: apt-get install chromium chromium-driver)")
    return Browser(binary, driver)
