"""Real headless Chromium for the browser tests (test_browser*.py, test_experiment_browser.py):
the fixtures (`browser`: one Chromium per module; `open_viewer`: viewer pages for a test, their
errors checked at its end), pages on web/ served from disk, and the checks that several of the
tests share (the dither statistics, an afterimage's centroid).

Chromium is Debian's (`/usr/bin/chromium`, or GAZEHDR_CHROMIUM), driven by Playwright's sync
API; WebGL2 runs on SwiftShader, so no GPU is needed. Without Chromium or Playwright the tests
skip, except on CI (CI set), where that is a failure (tests/conftest.py). A test module takes
the fixtures by importing them: `from tests.browser import browser, open_viewer`.
"""

from __future__ import annotations

import base64
import contextlib
import math
import os
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gazehdr.bench.live import CHROMIUM, CHROMIUM_ARGS, serve_web

WEB_DIR = Path(__file__).resolve().parent.parent / "web"
#: The frame header of docs/protocol.md, written out again here so that the test checks the
#: browser's decoder against the document, not against the server's own code.
HEADER = struct.Struct("<4sHHIIdffffHHBBHfI")
HEADER_FIELDS = (
    "magic", "version", "header_bytes", "frame", "gaze_seq", "time", "gaze_x", "gaze_y",
    "adaptation", "rho", "width", "height", "encoding", "flags", "reserved", "server_ms",
    "dropped",
)  # fmt: skip
WAIT_MS = 30_000  # generous: a loaded 2-core CI machine

#: Base64 of an ArrayBuffer, in chunks (String.fromCharCode has an argument limit).
B64_JS = """
window.__b64 = (buffer) => {
  const u8 = new Uint8Array(buffer);
  let s = '';
  for (let i = 0; i < u8.length; i += 0x8000) {
    s += String.fromCharCode.apply(null, u8.subarray(i, i + 0x8000));
  }
  return btoa(s);
};
// frames × width × height × 3 bytes: the renderer `r` drawing its frame with dither counters
// 0..frames-1, each drawing read back (RGB, bottom row first).
window.__drawFrames = (r, frames) => {
  const n = r.gl.drawingBufferWidth * r.gl.drawingBufferHeight;
  const out = new Uint8Array(frames * n * 3);
  for (let k = 0; k < frames; k++) {
    r.draw(k);
    const px = r.readPixels();
    for (let i = 0; i < n; i++) {
      for (let c = 0; c < 3; c++) out[(k * n + i) * 3 + c] = px[i * 4 + c];
    }
  }
  return out;
};
"""


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("the playwright package is not installed")
    if not os.access(CHROMIUM, os.X_OK):
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install chromium)")
    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = chromium.new_page()
            page.set_content("<canvas></canvas>")
            if not page.evaluate("() => !!document.querySelector('canvas').getContext('webgl2')"):
                pytest.skip("Chromium gives no WebGL2 context (SwiftShader missing?)")
            page.close()
            yield chromium
        finally:
            chromium.close()


class Viewer:
    """A page showing the viewer, with its errors collected and small helpers."""

    def __init__(self, browser: Any, url: str, width: int, height: int) -> None:
        self.page = browser.new_page(viewport={"width": width, "height": height})
        self.errors: list[str] = []
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.add_init_script(B64_JS)
        self.page.goto(url)
        self.wait("() => window.gazehdr?.state?.session && window.gazehdr.lastHeader")

    def wait(self, predicate: str, arg: Any = None, timeout: float = WAIT_MS) -> Any:
        return self.page.wait_for_function(predicate, arg=arg, timeout=timeout).json_value()

    def js(self, expression: str, arg: Any = None) -> Any:
        return self.page.evaluate(expression, arg)

    def header(self) -> dict[str, Any]:
        return self.js("() => window.gazehdr.lastHeader")

    def next_frame(self, after: int | None = None) -> dict[str, Any]:
        """The header of a frame newer than `after` (default: the current one)."""
        if after is None:
            after = self.header()["frame"]
        return self.wait(
            "(n) => window.gazehdr.lastHeader.frame > n && window.gazehdr.lastHeader", after
        )

    def payload(self) -> tuple[dict[str, Any], dict[str, Any], np.ndarray]:
        """The last frame message as (header decoded here, header decoded by the page, v)."""
        got = self.js("() => [window.__b64(window.gazehdr.lastPayload), window.gazehdr.lastHeader]")
        data = base64.b64decode(got[0])
        mine = dict(zip(HEADER_FIELDS, HEADER.unpack_from(data), strict=True))
        w, h, start = mine["width"], mine["height"], mine["header_bytes"]
        assert mine["magic"] == b"GZHF" and mine["encoding"] == 1  # f16: the server default
        v = np.frombuffer(data, "<f2", count=w * h * 3, offset=start).reshape(h, w, 3)
        return mine, got[1], v.astype(np.float64)

    def move_gaze(self, x: float, y: float) -> dict[str, Any]:
        """Move the pointer (CSS px) and wait for a frame that used that gaze."""
        sent = self.js("() => window.gazehdr.stats.gazeSent")
        self.page.mouse.move(x, y)
        seq = self.wait(
            "(s) => window.gazehdr.stats.gazeSent > s && window.gazehdr.stats.gazeSent", sent
        )
        return self.wait(
            "(s) => window.gazehdr.lastHeader.gaze_seq >= s && window.gazehdr.lastHeader", seq
        )

    def close(self) -> None:
        self.page.close()
        assert not self.errors, f"errors on the page: {self.errors}"


@pytest.fixture
def open_viewer(browser: Any) -> Iterator[Any]:
    pages: list[Viewer] = []

    def open_(url: str, width: int, height: int) -> Viewer:
        viewer = Viewer(browser, url, width, height)
        pages.append(viewer)
        return viewer

    yield open_
    for viewer in pages:
        viewer.close()


def serve_checkout_web(page: Any, origin: str = "http://viewer.test") -> str:
    """web/ of this checkout, served from disk (`gazehdr.bench.live.serve_web`)."""
    return serve_web(page, origin, WEB_DIR)


@contextlib.contextmanager
def web_page(browser: Any) -> Iterator[Any]:
    """A page on web/ served from disk (`serve_checkout_web`), closed after, with no errors on
    it."""
    page = browser.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.add_init_script(B64_JS)
    try:
        serve_checkout_web(page)
        yield page
    finally:
        page.close()
    assert not errors, errors


def dither_levels(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two 8-bit levels `floor(255 v + u)` can give, u in [0, 1). A hair of slack where
    255·v is within float32 rounding of an integer (the GPU computes in float32)."""
    x = 255.0 * np.clip(v, 0.0, 1.0)
    return np.floor(x - 1e-4), np.minimum(np.floor(x + 1e-4) + 1, 255)


def check_dither(out: np.ndarray, v: np.ndarray, correlations: bool = True) -> None:
    frames, h, w, _ = out.shape
    x = 255.0 * v
    lo = np.floor(x)
    p = x - lo  # probability of the upper level
    # Every value is one of the two levels around 255·v.
    assert ((out == lo) | (out == lo + 1)).all(), np.unique(out.reshape(-1, 3), axis=0)
    d = (out - lo).astype(np.float64)  # the dither decisions, 0 or 1

    # Mean over frames and pixels: an unbiased dither gives p. Each decision is Bernoulli(p);
    # with independent decisions the mean's standard deviation is sqrt(p(1-p)/N): allow 5 of
    # them (N = 262144 for 256 frames of 32×32: about 0.0045 levels at p = 0.3).
    n = frames * h * w
    sigma = np.sqrt(p * (1 - p) / n)
    mean = d.mean(axis=(0, 1, 2))
    assert (np.abs(mean - p) < 5 * sigma).all(), (mean, p, sigma)

    # Per pixel over frames, looser: sqrt(p(1-p)/frames) each, 6 sigma over 3072 pixel
    # channels (a chance of ~1e-5 that one exceeds it with a perfect hash; the hash is
    # deterministic, so this either always passes or always fails).
    sigma_px = np.sqrt(p * (1 - p) / frames)
    per_pixel = d.mean(axis=0)
    worst = np.abs(per_pixel - p) / sigma_px
    assert (worst < 6).all(), worst.max(axis=(0, 1))

    if not correlations:
        return
    # Independence: neighbours in x, y and time (per channel: the channels' means differ, so
    # pooling them would correlate by itself) and the three channels must not be locked
    # together. With ~250k pairs a correlation coefficient has std 1/sqrt(N) ≈ 0.002, so
    # |r| < 0.02 is 10 sigma from a perfect hash, yet far below what shared or row-wise noise
    # gives (r = 1) or a weak hash typically does.
    pairs = {"R and G": (d[..., 0], d[..., 1]), "R and B": (d[..., 0], d[..., 2])}
    pairs["G and B"] = (d[..., 1], d[..., 2])
    for c in range(3):
        e = d[..., c]
        pairs[f"x neighbours, channel {c}"] = (e[:, :, 1:], e[:, :, :-1])
        pairs[f"y neighbours, channel {c}"] = (e[:, 1:], e[:, :-1])
        pairs[f"diagonal neighbours, channel {c}"] = (e[:, 1:, 1:], e[:, :-1, :-1])
        pairs[f"next frame, channel {c}"] = (e[1:], e[:-1])
    for name, (a, b) in pairs.items():
        r = correlation(a, b)
        assert abs(r) < 0.02, f"dither decisions correlated across {name}: r = {r:.4f}"


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a.ravel() - a.mean(), b.ravel() - b.mean()
    return float((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum()))


def afterimage_centroid(v: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Centroid (x, y; pixel centres at +0.5) of the pixels above half the peak, the peak, and
    how far the farthest of those pixels is from the centroid, for a frame seen with the eyes
    closed: dark but for the afterimage (and a faint trace of the whole wall)."""
    s = v.sum(axis=2)
    peak = float(s.max())
    w = np.where(s > 0.5 * peak, s, 0.0)
    yy, xx = np.mgrid[: s.shape[0], : s.shape[1]]
    c = np.array([(w * xx).sum(), (w * yy).sum()]) / w.sum()
    radius = float(np.hypot(xx - c[0], yy - c[1])[w > 0].max())
    return c + 0.5, peak, radius
