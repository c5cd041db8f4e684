"""Headless Chromium screenshots of a page (the viewer's, for ``ges view --screenshot`` and the tests).

Chromium is a system program (Debian: ``apt-get install chromium``), not a Python package; nothing is downloaded.
WebGL runs on the CPU through SwiftShader (``--use-angle=swiftshader --enable-unsafe-swiftshader``): headless
Chromium on a machine without a GPU otherwise draws no 3D canvas at all.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from ges_core.errors import BackendUnavailable

__all__ = ["CHROMIUM_NAMES", "HeadlessPage", "chromium_command", "find_chromium", "screenshot"]

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
"""Program names looked up on PATH, in order ($GES_CHROMIUM overrides them)."""

_FLAGS = (
    "--headless",
    "--no-sandbox",  # Chromium refuses to run as root with its sandbox; the page is our own local one
    "--use-angle=swiftshader",  # software WebGL: no GPU needed
    "--enable-unsafe-swiftshader",  # Chromium >= 137 turns SwiftShader WebGL off without this flag
    "--hide-scrollbars",
    "--mute-audio",
    "--no-first-run",
    "--disable-extensions",
    "--disable-background-networking",
)


def find_chromium() -> str | None:
    """Path of a Chromium executable ($GES_CHROMIUM, else the first of :data:`CHROMIUM_NAMES` on PATH) or None."""
    named = os.environ.get("GES_CHROMIUM")
    if named:
        return shutil.which(named) or (named if Path(named).is_file() else None)
    return next((found for n in CHROMIUM_NAMES if (found := shutil.which(n))), None)


def chromium_command(profile: Path, size: tuple[int, int], *extra: str) -> list[str]:
    """The headless command line (without the URL); ``profile``: a fresh user-data folder (two runs never share)."""
    exe = find_chromium()
    if exe is None:
        raise BackendUnavailable(
            "no Chromium found (looked for $GES_CHROMIUM, then " + ", ".join(CHROMIUM_NAMES) + " on PATH); "
            "install it, e.g. 'apt-get install chromium' on Debian"
        )
    return [exe, *_FLAGS, f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}", *extra]


def screenshot(
    url: str, path: str | Path, *, size: tuple[int, int] = (1280, 800), wait_ms: int = 8000, timeout: float = 90.0
) -> Path:
    """Load ``url`` in headless Chromium, let it run ``wait_ms`` of virtual time, write a PNG of the window.

    size: (width, height) pixels. BackendUnavailable without Chromium or when it writes no picture (its output
    ends the message).
    """
    path = Path(path).resolve()
    profile = Path(tempfile.mkdtemp(prefix="ges-chromium-"))
    try:
        cmd = chromium_command(profile, size, f"--virtual-time-budget={wait_ms}", f"--screenshot={path}", url)
        try:
            run = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
        except subprocess.TimeoutExpired as exc:
            raise BackendUnavailable(f"Chromium took over {timeout:.0f} s to screenshot {url}") from exc
    finally:
        remove_profile(profile)
    if not path.is_file():
        tail = (run.stderr or run.stdout).strip().splitlines()[-3:]
        raise BackendUnavailable(
            f"Chromium wrote no screenshot of {url} (exit {run.returncode}): {' | '.join(tail) or 'no output'}"
        )
    return path


PROFILE_REMOVAL_TRIES = 20
"""Tries, 0.1 s apart, at removing a Chromium profile folder: its helper processes may still write into it for a
moment after the browser exited (a test saw ``Directory not empty: 'Default'``)."""


def remove_profile(profile: Path) -> None:
    """Remove a Chromium profile folder, trying again while files still appear in it; what is left after
    :data:`PROFILE_REMOVAL_TRIES` tries stays in the temporary folder (a leftover there is not worth an error)."""
    for _ in range(PROFILE_REMOVAL_TRIES):
        try:
            shutil.rmtree(profile)
            return
        except FileNotFoundError:
            return
        except OSError:
            time.sleep(0.1)
    shutil.rmtree(profile, ignore_errors=True)


class HeadlessPage:
    """One headless Chromium tab driven over the DevTools protocol (for timing a page and polling its pixels).

    >>> with HeadlessPage(size=(1280, 800)) as page:
    ...     page.navigate("http://127.0.0.1:8080")
    ...     rgb = page.screenshot()          # (H, W, 3) uint8 of the window now

    Uses ``websockets`` (a dependency of viser) and Pillow. BackendUnavailable without Chromium or when it does
    not start within ``timeout`` seconds.
    """

    def __init__(self, size: tuple[int, int] = (1280, 800), *, timeout: float = 60.0) -> None:
        self.size, self.timeout = size, timeout
        self._profile = Path(tempfile.mkdtemp(prefix="ges-chromium-"))
        try:
            cmd = chromium_command(self._profile, size, "--remote-debugging-port=0", "about:blank")
            # a session of its own: close() ends the browser's helper processes with it
            self._proc = subprocess.Popen(
                cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
            )
        except BaseException:  # no browser to start: nothing will remove the profile later
            remove_profile(self._profile)
            raise
        self._next_id = 0
        try:
            self._ws = self._connect()
            self.call("Page.enable")
        except BaseException:
            self.close()
            raise

    def _connect(self):
        import json
        import urllib.request

        from websockets.sync.client import connect

        port_file, deadline = self._profile / "DevToolsActivePort", time.monotonic() + self.timeout
        while not port_file.is_file() or not port_file.read_text().strip():
            if self._proc.poll() is not None or time.monotonic() > deadline:
                raise BackendUnavailable(f"Chromium did not open its DevTools port (exit {self._proc.poll()})")
            time.sleep(0.05)
        port = int(port_file.read_text().split()[0])
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=self.timeout) as reply:
            targets = json.loads(reply.read())
        page = next(t for t in targets if t.get("type") == "page")
        return connect(page["webSocketDebuggerUrl"], max_size=None, open_timeout=self.timeout)

    def call(self, method: str, **params) -> dict:
        """Send one DevTools command and return its result (events that arrive meanwhile are dropped)."""
        import json

        self._next_id += 1
        self._ws.send(json.dumps({"id": self._next_id, "method": method, "params": params}))
        while True:
            message = json.loads(self._ws.recv(timeout=self.timeout))
            if message.get("id") == self._next_id:
                if "error" in message:
                    raise BackendUnavailable(f"Chromium: {method} failed: {message['error']}")
                return message.get("result", {})

    def navigate(self, url: str) -> None:
        """Start loading ``url`` (returns once the request is sent, not when the page is drawn)."""
        self.call("Page.navigate", url=url)

    def screenshot(self):
        """(H, W, 3) uint8 RGB of the window as it is now."""
        import base64
        import io

        import numpy as np
        from PIL import Image

        data = base64.b64decode(self._capture()["data"])
        with Image.open(io.BytesIO(data)) as image:
            return np.asarray(image.convert("RGB"))

    def _capture(self) -> dict:
        """Page.captureScreenshot, retried while a navigation swaps the page ("Not attached to an active page")."""
        deadline = time.monotonic() + self.timeout
        while True:
            try:
                return self.call("Page.captureScreenshot", format="png")
            except BackendUnavailable:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)

    def close(self) -> None:
        """Close the browser and remove its profile; calling twice is harmless."""
        ws = getattr(self, "_ws", None)
        if ws is not None:
            ws.close()
            self._ws = None
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        with contextlib.suppress(ProcessLookupError, PermissionError):  # helpers left in the browser's session
            os.killpg(self._proc.pid, signal.SIGKILL)
        remove_profile(self._profile)

    def __enter__(self) -> HeadlessPage:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


VIEWER_PANEL_PX = 340
"""Width of viser's side panel (320 px and its 20 px margin) on the right of the page: not 3D canvas."""


def canvas_pixels(rgb) -> dict[str, int]:
    """Pixel counts of a viewer page's 3D canvas, from an (H, W, 3) uint8 screenshot.

    Counted away from the side panel (right :data:`VIEWER_PANEL_PX`), viser's software-WebGL notice (top left,
    330 x 170 px) and its axes gizmo (bottom left, 70 x 70 px): ``scene`` pixels that are not the white background
    (any channel below 243), ``object`` pixels of the object's orange (red over blue by > 50, r >= g >= b) and
    ``hand`` pixels of the hand's blue-grey (blue over red by > 15). The thresholds separate the lit colours of
    :mod:`ges_core.render.base` from white and from the grey table in viewer screenshots.
    """
    import numpy as np

    h, w = rgb.shape[:2]
    mask = np.ones((h, w), dtype=bool)
    mask[:, w - VIEWER_PANEL_PX :], mask[:170, :330], mask[h - 70 :, :70] = False, False, False
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return {
        "scene": int(((rgb.min(axis=2) < 243) & mask).sum()),
        "object": int(((r - b > 50) & (r >= g) & (g >= b) & mask).sum()),
        "hand": int(((b - r > 15) & mask).sum()),
    }
