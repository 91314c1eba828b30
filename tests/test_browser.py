"""The live viewer in a real browser: ``qchain run --serve`` serves the Rerun web viewer on loopback,
headless Chromium opens it (driven over the DevTools protocol); the whole arm must be drawn inside
the 3D view, and the page must ask no host but 127.0.0.1 for anything.

Needs Debian's ``chromium`` (``apt-get install chromium``) and the ``websocket-client``
package; without them the test fails with a message saying so (it is not skipped). The
screenshots are kept in ``test-artifacts/`` at the repository root.
"""

from __future__ import annotations

import base64
import io
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from qchain.logging import SEGMENT_COLORS

pytestmark = pytest.mark.slow  # see tests/README.md

ROOT = Path(__file__).resolve().parent.parent
ARTIFACTS = ROOT / "test-artifacts"
WIDTH, HEIGHT = 1024, 700
TIME_LIMIT = 50.0  # s, for the whole test
MIN_ARM_PIXELS = 1500  # the arm covers ~8000-15000 pixels of the 3D view when drawn

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",  # WebGL on the CPU: the viewer renders with it
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--disable-default-apps",
    "--disable-breakpad",
    "--disable-crash-reporter",
    f"--window-size={WIDTH},{HEIGHT}",
    "--remote-debugging-address=127.0.0.1",
    "--remote-debugging-port=0",
]


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    raise AssertionError("no Chromium found: install Debian's package (apt-get install -y chromium)")


class DevTools:
    """A minimal Chrome DevTools Protocol client for one page target."""

    def __init__(self, ws_url: str):
        import websocket  # websocket-client

        self.ws = websocket.create_connection(ws_url, timeout=30, suppress_origin=True)
        self._id = 0
        self.events: list[dict] = []  # what the page did meanwhile (Network.* events)

    def call(self, method: str, **params):
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv())
            if "method" in msg:
                self.events.append(msg)
            if msg.get("id") == self._id:
                if "error" in msg:
                    raise AssertionError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    def close(self):
        self.ws.close()


def _start_chromium(profile: Path) -> tuple[subprocess.Popen, DevTools]:
    proc = subprocess.Popen(
        [_chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "about:blank"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # its own process group, ended as a whole at the end
    )
    port_file = profile / "DevToolsActivePort"
    deadline = time.monotonic() + 20
    while not (port_file.exists() and port_file.read_text().strip()):
        assert proc.poll() is None, "chromium exited at start"
        assert time.monotonic() < deadline, "chromium did not open its DevTools port"
        time.sleep(0.1)
    port = int(port_file.read_text().split()[0])
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=10) as resp:
        targets = json.load(resp)
    page = next(t for t in targets if t["type"] == "page")
    return proc, DevTools(page["webSocketDebuggerUrl"])


#: The 3D view in the viewer's window (fractions of its width and height): left of the plots
#: (3 : 2 columns), below the top bar and the view's title, above the time panel.
VIEW = (0.0, 0.595, 0.075, 0.94)


def _arm_mask(png: bytes) -> np.ndarray:
    """Pixels of the arm's colours in the whole window (bool, H x W)."""
    from PIL import Image  # Pillow comes with matplotlib

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)
    near = np.zeros(img.shape[:2], dtype=bool)
    for c in SEGMENT_COLORS:
        near |= np.abs(img - np.array(c, dtype=np.int16)).max(axis=2) <= 24
    return near


def _view_box(mask: np.ndarray) -> tuple[int, int, int, int]:
    h, w = mask.shape
    return int(VIEW[0] * w), int(VIEW[1] * w), int(VIEW[2] * h), int(VIEW[3] * h)


def _arm_pixels(png: bytes) -> int:
    """Pixels of the arm's colours in the 3D view."""
    mask = _arm_mask(png)
    x0, x1, y0, y1 = _view_box(mask)
    return int(mask[y0:y1, x0:x1].sum())


def _framing(png: bytes) -> dict:
    """Where the arm is in the 3D view: its bounding box's margins to the view's edges
    (px) and its centre as fractions of the view's size."""
    mask = _arm_mask(png)
    x0, x1, y0, y1 = _view_box(mask)
    ys, xs = np.nonzero(mask[y0:y1, x0:x1])
    return {"left": int(xs.min()), "right": int(x1 - x0 - 1 - xs.max()), "top": int(ys.min()),
            "bottom": int(y1 - y0 - 1 - ys.max()), "cx": float(xs.mean() / (x1 - x0)),
            "cy": float(ys.mean() / (y1 - y0)), "outside": int(mask.sum() - mask[y0:y1, x0:x1].sum())}


def test_live_viewer_frames_the_arm_and_stays_on_loopback(tmp_path):
    """``qchain run SCENE --serve`` prints the viewer URL; Chromium opens it; the arm (hanging
    from its base) is drawn whole inside the 3D view, near its middle; every request of the
    page goes to 127.0.0.1."""
    import sys

    t_start = time.monotonic()
    ARTIFACTS.mkdir(exist_ok=True)
    shots = ARTIFACTS / "browser"
    shots.mkdir(exist_ok=True)
    for old in shots.glob("viewer-*.png"):
        old.unlink()

    run = subprocess.Popen(
        [sys.executable, "-m", "qchain", "run", str(ROOT / "examples" / "scenes" / "wave_arm.toml"), "--serve",
         "--duration", "2", "--no-progress", "--no-plots", "--out", str(tmp_path / "out"),
         "--mcap", str(tmp_path / "run.mcap")],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))},
    )
    browser = None
    devtools = None
    lines = []
    try:
        url = None
        while url is None and time.monotonic() - t_start < 30:
            line = run.stdout.readline()
            assert line or run.poll() is None, f"qchain run ended early: {''.join(lines)}"
            lines.append(line)
            if "live Rerun viewer at " in line:
                url = line.split("live Rerun viewer at ")[1].split()[0]
        assert url and url.startswith("http://127.0.0.1:"), "".join(lines)
        assert "url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A" in url  # the data server is on loopback too

        profile = Path(tempfile.mkdtemp(prefix="chromium-profile-", dir=tmp_path))
        browser, devtools = _start_chromium(profile)
        devtools.call("Page.enable")
        devtools.call("Network.enable")
        devtools.call("Emulation.setDeviceMetricsOverride", width=WIDTH, height=HEIGHT, deviceScaleFactor=1,
                      mobile=False)
        devtools.call("Page.navigate", url=url)

        counts = []
        best = None
        i = 0

        def screenshot() -> bytes | None:
            try:
                return base64.b64decode(devtools.call("Page.captureScreenshot", format="png")["data"])
            except AssertionError:  # e.g. "Not attached to an active page" while the page loads
                return None

        while time.monotonic() - t_start < TIME_LIMIT:
            time.sleep(1.0)
            png = screenshot()
            if png is None:
                continue
            (shots / f"viewer-{i:02d}.png").write_bytes(png)
            counts.append(_arm_pixels(png))
            i += 1
            if counts[-1] >= MIN_ARM_PIXELS:  # the arm is drawn; one more frame to let it settle
                time.sleep(1.0)
                png = screenshot() or png
                if _arm_pixels(png) >= MIN_ARM_PIXELS:
                    best = png
                    (ARTIFACTS / "viewer.png").write_bytes(png)
                    break
        assert best is not None, (
            f"the arm never appeared in the viewer within {TIME_LIMIT:.0f} s; arm-coloured pixels per "
            f"screenshot: {counts} (screenshots in {shots})"
        )
    finally:
        devtools_events = devtools.events if devtools is not None else []
        if devtools is not None:
            devtools.close()
        if browser is not None:
            try:
                os.killpg(browser.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                browser.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(browser.pid, signal.SIGKILL)
                browser.wait()
        if run.poll() is None:  # the run keeps serving the viewer until Ctrl-C
            run.send_signal(signal.SIGINT)
            try:
                run.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(run.pid, signal.SIGKILL)
                run.wait()
    assert run.returncode == 0, "".join(lines) + run.stdout.read()
    # the whole arm inside the 3D view, not cut at an edge, and about its middle
    f = _framing(best)
    assert min(f["left"], f["right"], f["top"], f["bottom"]) >= 8, f
    assert 0.3 <= f["cx"] <= 0.7 and 0.25 <= f["cy"] <= 0.75, f
    # nothing but loopback: every request the page made, web sockets included
    from urllib.parse import urlsplit

    urls = [e["params"]["request"]["url"] for e in devtools_events if e["method"] == "Network.requestWillBeSent"]
    urls += [e["params"]["url"] for e in devtools_events if e["method"] == "Network.webSocketCreated"]
    hosts = {urlsplit(u).hostname for u in urls if not u.startswith(("data:", "blob:", "about:"))}
    assert urls and hosts == {"127.0.0.1"}, sorted(hosts)
    assert (tmp_path / "run.mcap").stat().st_size > 1000
    assert time.monotonic() - t_start < 60.0
