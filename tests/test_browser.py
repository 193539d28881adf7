"""The browser viewer (web/) in real headless Chromium, against a real server.

Chromium is Debian's (`/usr/bin/chromium`, or GAZEHDR_CHROMIUM), driven by Playwright's sync
API; WebGL2 runs on SwiftShader, so no GPU is needed. Without Chromium or Playwright the tests
skip, except on CI (CI set), where that is a failure (tests/conftest.py).

Frames are kept small (320×176 or the fixture's 160×96): CI has two cores and runs the
kernels on the CPU, so a frame takes 50-200 ms there. Nothing here assumes a frame rate:
every wait is on a condition (a frame number, a gaze sequence number, a simulation time).
The browser, the viewer pages and the checks several test modules share are tests/browser.py's.
"""

# ruff: noqa: F811  (the browser fixtures are imported from tests/browser.py, used as arguments)
from __future__ import annotations

import base64
import contextlib
import json
import math
import socket
import threading
import urllib.request
from typing import Any

import numpy as np
import pytest

from tests.browser import (  # noqa: F401  (the fixtures, used as arguments)
    afterimage_centroid,
    browser,
    check_dither,
    dither_levels,
    open_viewer,
    web_page,
)
from tests.waiting import wait_until


def _png(data: bytes) -> np.ndarray:
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"), dtype=np.float64)


# --- 1. connect, frames, canvas, HUD ----------------------------------------------------------


def test_viewer_connects_shows_frames_and_hud(live_server, open_viewer) -> None:
    W, H = 320, 176  # the viewport has the frame's aspect, so the frame fills the canvas
    srv = live_server(scene="flash", size=(W, H))
    viewer = open_viewer(srv.url, W, H)

    state = viewer.js("() => window.gazehdr.state")
    assert state["scene"] == "flash" and "flash" in state["scenes"]
    assert state["gaze_source"] == "mouse" and "mouse" in state["gaze_sources"]
    assert state["params"] and state["defaults"] and state["sections"]

    first = viewer.header()
    later = viewer.next_frame(first["frame"] + 2)  # frame numbers increase
    assert later["frame"] > first["frame"] + 2 and later["time"] > first["time"]
    assert (later["width"], later["height"], later["encoding"]) == (W, H, 1)

    # The page's header decoder agrees with docs/protocol.md field by field.
    mine, theirs, v = viewer.payload()
    assert mine["version"] == 1 and mine["header_bytes"] == 56 and mine["reserved"] == 0
    for name in ("frame", "gaze_seq", "width", "height", "encoding", "flags", "dropped"):
        assert theirs[name] == mine[name], name
    for name in ("time", "gaze_x", "gaze_y", "adaptation", "rho", "server_ms"):
        assert theirs[name] == pytest.approx(mine[name], rel=1e-6, abs=1e-9), name
    assert theirs["eyes_open"] == bool(mine["flags"] & 1)
    assert 0.0 <= v.min() and v.max() <= 1.0 and v.std() > 0.01  # a picture, not a blank

    # The canvas shows exactly that frame, top row at the top, each value dithered to one of
    # its two neighbouring 8-bit levels: upload it and draw in one task, then read back.
    got = viewer.js(
        """async () => {
          const { decodeFrame } = await import('/protocol.js');
          const g = window.gazehdr, r = g.renderer, buf = g.lastPayload;
          const { header: h, pixels } = decodeFrame(buf);
          r.upload(h.width, h.height, h.encoding, pixels);
          r.draw();
          const px = r.readPixels();
          return [window.__b64(buf), window.__b64(px.buffer),
                  r.gl.drawingBufferWidth, r.gl.drawingBufferHeight];
        }"""
    )
    data = base64.b64decode(got[0])
    v = np.frombuffer(data, "<f2", count=W * H * 3, offset=56).reshape(H, W, 3).astype(np.float64)
    assert (got[2], got[3]) == (W, H)
    shown = np.frombuffer(base64.b64decode(got[1]), np.uint8).reshape(H, W, 4)[::-1, :, :3]
    lo, hi = dither_levels(v)
    bad = (shown < lo) | (shown > hi)
    assert not bad.any(), f"{bad.sum()} values off their two levels, first at {np.argwhere(bad)[0]}"

    # HUD: visible by default and showing live values; H hides it, H shows it again.
    viewer.wait(
        "() => /frames (?!0\\.0 )\\d+\\.\\d fps/.test(document.getElementById('hud').textContent)"
    )
    h = viewer.header()
    text = viewer.wait(
        "(n) => window.gazehdr.lastHeader.frame >= n && document.getElementById('hud').textContent",
        h["frame"],
    )
    for needle in ("open", f"{W}×{H} f16", "A = ", "cd/m²", "ρ = ", "server ", "dropped "):
        assert needle in text, (needle, text)
    assert viewer.js("() => !document.getElementById('hud').hidden")
    viewer.page.keyboard.press("h")
    assert viewer.js("() => document.getElementById('hud').hidden")

    # The live draw loop (HUD hidden, it covers the picture): two moments differ (new noise
    # every draw, new frames), both show the frame's brightness (mean within 3 levels of
    # 255·v: the dither noise averages out over 56k pixels).
    clip = {"x": 0, "y": 0, "width": W, "height": H}
    shot1 = _png(viewer.page.screenshot(clip=clip))
    viewer.next_frame()
    shot2 = _png(viewer.page.screenshot(clip=clip))
    assert (shot1 != shot2).mean() > 0.05
    _, _, v_now = viewer.payload()
    for shot in (shot1, shot2):
        assert abs(shot.mean() - 255 * v_now.mean()) < 3.0

    viewer.page.keyboard.press("h")
    assert viewer.js("() => !document.getElementById('hud').hidden")


def test_side_panel_sends_controls(live_server, open_viewer) -> None:
    srv = live_server()
    viewer = open_viewer(srv.url, 800, 600)
    page = viewer.page
    assert viewer.js("() => document.getElementById('panel').hidden")  # hidden by default
    page.keyboard.press("p")
    assert viewer.js("() => !document.getElementById('panel').hidden")
    scenes = viewer.js(
        "() => [...document.querySelectorAll('#scene-select option')].map(o => o.value)"
    )
    assert scenes == viewer.js("() => window.gazehdr.state.scenes") and "flash" in scenes

    # A parameter edited in the panel goes to the server, which answers with a new state.
    a1 = page.locator("#panel .param", has=page.locator(".name", has_text="a1")).locator("input")
    a1.fill("0.5")
    a1.press("Enter")
    viewer.wait("() => window.gazehdr.state.params.a1 === 0.5")
    # The panel and the HUD name the live preset and what was changed over it.
    viewer.wait("() => document.getElementById('preset-live').textContent === 'paper + a1'")
    viewer.wait("() => /preset paper \\+ a1/.test(document.getElementById('hud').textContent)")
    # A preset sets every parameter: ours, then the paper's (a1 back to its default).
    page.select_option("#preset-select", "visible")
    viewer.wait("() => window.gazehdr.state.params.bleach_display_gain === 32")
    viewer.wait("() => /preset visible\\n/.test(document.getElementById('hud').textContent)")
    page.select_option("#preset-select", "paper")
    viewer.wait("() => window.gazehdr.state.params.a1 === window.gazehdr.state.defaults.a1")
    viewer.wait("() => window.gazehdr.state.preset === 'paper'")
    # A refused value: the server says why, the page shows it, nothing changes.
    a1.fill("-1")
    a1.press("Enter")
    viewer.wait("() => /a1/.test(document.getElementById('toasts').textContent)")
    assert viewer.js("() => window.gazehdr.state.params.a1 === window.gazehdr.state.defaults.a1")
    # Matrices are shown, not edited.
    assert viewer.js("() => document.querySelectorAll('#panel code.readonly').length") >= 1


def test_split_view_from_the_panel(live_server, open_viewer) -> None:
    """The panel's split toggle and model choosers: split frames arrive, a divider and a label
    per pane appear, the HUD names both models, and the pointer over the right pane looks at
    the same spot as over the left one (the server maps it; docs/protocol.md)."""
    W, H = 320, 176
    srv = live_server(scene="lamp", size=(W, H))
    viewer = open_viewer(srv.url, W, H)
    page = viewer.page
    afterimages = viewer.js("() => window.gazehdr.state.models.afterimage")
    assert viewer.js("() => document.getElementById('split-overlay').hidden")
    page.keyboard.press("p")
    options = "(id) => [...document.querySelectorAll(`#${id} option`)].map(o => o.value)"
    assert viewer.js(options, "afterimage-select") == afterimages
    assert viewer.js(options, "split-acuity-select") == viewer.js(
        "() => window.gazehdr.state.models.acuity"
    )
    page.select_option("#split-afterimage-select", "ritschel")
    assert viewer.js("() => window.gazehdr.state.split") is None  # chosen, not yet shown
    page.check("#split-toggle")
    viewer.wait("() => window.gazehdr.state.split?.afterimage === 'ritschel'")
    split = viewer.wait("() => window.gazehdr.lastHeader.split && window.gazehdr.lastHeader")
    assert (split["width"], split["height"]) == (W, H)
    viewer.next_frame(split["frame"])  # frames keep coming

    overlay = viewer.js(
        """() => { const o = document.getElementById('split-overlay');
          const d = o.querySelector('.divider').getBoundingClientRect();
          return { hidden: o.hidden, x: d.left, top: d.top, height: d.height,
                   labels: [...o.querySelectorAll('.pane-label')].map(l => [
                     l.textContent, l.getBoundingClientRect().left]) }; }"""
    )
    assert not overlay["hidden"]
    assert overlay["x"] == pytest.approx(W / 2, abs=1) and overlay["height"] == pytest.approx(H)
    assert [text for text, _ in overlay["labels"]] == [
        "jacobs + stochastic",
        "ritschel + stochastic",
    ]
    assert overlay["labels"][0][1] < W / 2 < overlay["labels"][1][1]
    viewer.wait(
        "() => /left jacobs \\+ stochastic \\| right ritschel \\+ stochastic/"
        ".test(document.getElementById('hud').textContent)"
    )

    # Close the panel (it covers the frame), then point at the right pane: the header's gaze is
    # the same spot in the left pane, and a ring marks it in each pane.
    page.evaluate("() => document.activeElement.blur()")
    page.keyboard.press("p")
    h = viewer.move_gaze(240.0, 60.0)
    assert h["split"] and h["gaze_x"] * W == pytest.approx(240.0 - W / 2, abs=1.0)
    assert h["gaze_y"] * H == pytest.approx(60.0, abs=1.0)
    rings = viewer.js(
        """() => ['marker', 'marker-right'].map(id => {
          const r = document.getElementById(id).getBoundingClientRect();
          return [r.left + r.width / 2, r.top + r.height / 2]; })"""
    )
    np.testing.assert_allclose(rings, [[80.0, 60.0], [240.0, 60.0]], atol=1.5)
    h = viewer.move_gaze(70.0, 60.0)
    assert h["gaze_x"] * W == pytest.approx(70.0, abs=1.0)

    # Split off from the panel: whole frames again, the overlay and second ring go.
    page.keyboard.press("p")
    page.uncheck("#split-toggle")
    viewer.wait("() => window.gazehdr.state.split === null")
    viewer.wait("() => !window.gazehdr.lastHeader.split")
    viewer.wait("() => document.getElementById('split-overlay').hidden")
    assert viewer.js("() => document.getElementById('marker-right').hidden")


def test_panel_chooses_afterimage_and_acuity_models(live_server, open_viewer) -> None:
    """The panel's choosers switch the session's models on the server, OpenCL backend: the
    state the page gets, the HUD and /api/sessions name them, and frames keep coming."""
    from gazehdr.sim.reference import ReferenceBackend

    srv = live_server(scene="lamp", size=(160, 96))
    viewer = open_viewer(srv.url, 800, 600)
    page = viewer.page
    state = viewer.js("() => window.gazehdr.state")
    assert state["device"] != ReferenceBackend.device_name  # the kernels run, not NumPy
    assert state["model"] == {"afterimage": "jacobs", "acuity": "stochastic"}

    def on_server() -> dict[str, Any]:
        request = urllib.request.Request(f"{srv.url}/api/sessions", headers=srv.auth)
        with urllib.request.urlopen(request, timeout=10) as answer:
            sessions = json.load(answer)
        return next(s for s in sessions if s["id"] == state["session"])

    assert on_server()["model"] == "jacobs+stochastic"
    page.keyboard.press("p")
    page.select_option("#afterimage-select", "mikamo")
    viewer.wait("() => window.gazehdr.state.model.afterimage === 'mikamo'")
    page.select_option("#acuity-select", "thompson")
    viewer.wait("() => window.gazehdr.state.model.acuity === 'thompson'")
    assert viewer.js("() => window.gazehdr.state.split") is None  # one model, whole frames
    served = on_server()
    assert served["model"] == "mikamo+thompson" and served["split"] is None
    viewer.wait(
        "() => /model mikamo \\+ thompson/.test(document.getElementById('hud').textContent)"
    )

    # Frames keep arriving from the switched session, whole frames, its clock running on.
    first = viewer.header()
    later = viewer.next_frame(first["frame"] + 3)
    assert later["time"] > first["time"] and not later["split"]
    assert on_server()["frame"] > first["frame"]
    # The choosers show what the server runs (refreshed from its state).
    values = (
        "() => ['afterimage-select', 'acuity-select'].map(i => document.getElementById(i).value)"
    )
    assert viewer.js(values) == ["mikamo", "thompson"]


# --- 2. the pointer is the gaze; afterimages stay on the retina -------------------------------


def test_pointer_moves_the_gaze(live_server, open_viewer) -> None:
    W, H = 320, 176
    srv = live_server(scene="flash", size=(W, H))
    viewer = open_viewer(srv.url, W, H)

    seqs = []
    for x, y in [(80.0, 44.0), (250.5, 150.5), (3.0, 170.0)]:
        h = viewer.move_gaze(x, y)
        # The canvas is the frame, 1 CSS px = 1 frame px: the gaze is the pointer's fraction.
        # Tolerance: one pixel (pointer coordinates are whole CSS px in some Chromium builds).
        assert h["gaze_x"] * W == pytest.approx(x, abs=1.0)
        assert h["gaze_y"] * H == pytest.approx(y, abs=1.0)
        assert not h["tracker_gaze"]
        seqs.append(h["gaze_seq"])
    assert seqs == sorted(seqs) and len(set(seqs)) == 3

    # End-to-end latency: one sample per acknowledged gaze, shown in the HUD.
    lat = viewer.js("() => window.gazehdr.stats.latency.values")
    assert len(lat) >= 3 and all(0 < t < 10_000 for t in lat)
    viewer.wait("() => /latency p50 \\d+ ms/.test(document.getElementById('hud').textContent)")

    # A window of another aspect ratio: the frame takes it (within the server's rounding of
    # sizes to multiples of 8: 296×192 here), is drawn "contain" with 6 px bars left and right,
    # and the pointer over a bar gives a gaze outside [0, 1].
    VW, VH = 376, 236
    viewer.page.set_viewport_size({"width": VW, "height": VH})
    h = viewer.wait("(h) => window.gazehdr.lastHeader.height != h && window.gazehdr.lastHeader", H)
    fw, fh = h["width"], h["height"]
    s = min(VW / fw, VH / fh)
    dw, dh = round(fw * s), round(fh * s)
    x0, y0 = (VW - dw) // 2, (VH - dh) // 2
    assert y0 > 0 or x0 > 0, "no bars to test with"
    px, py = (VW / 2, 1.0) if y0 > 0 else (1.0, VH / 2)
    h = viewer.move_gaze(px, py)
    assert h["gaze_x"] == pytest.approx((px - x0) / dw, abs=1.0 / dw)
    assert h["gaze_y"] == pytest.approx((py - y0) / dh, abs=1.0 / dh)
    assert h["gaze_x"] < 0 or h["gaze_y"] < 0


def test_panel_lists_the_connected_trackers_and_follows_the_one_chosen(
    live_server, open_viewer
) -> None:
    """A gaze daemon connects after the page opened: the panel offers its tracker, choosing it
    makes the session follow its fixations (the pointer no longer moves the gaze), and the HUD
    names it."""
    from websockets.sync.client import connect

    W, H = 320, 176
    srv = live_server(scene="lamp", size=(W, H), token="t")
    viewer = open_viewer(srv.url, W, H)
    viewer.page.keyboard.press("p")
    options = "() => [...document.querySelectorAll('#source-select option')].map(o => o.value)"
    assert "remote:bench rig" not in viewer.js(options)
    auth = {"Authorization": "Bearer t"}
    with connect(srv.ws_url + "/ws/gaze", additional_headers=auth) as daemon:
        daemon.send(json.dumps({"type": "hello", "protocol": 1, "tracker": "bench rig"}))
        assert json.loads(daemon.recv())["type"] == "welcome"
        fixation = {"type": "event", "kind": "fixation_start", "id": 1, "t": 1, "x": 0.7,
                    "y": 0.2}  # fmt: skip
        daemon.send(json.dumps(fixation))
        daemon.send(json.dumps({"type": "samples", "samples": [{"t": 2, "x": 0.7, "y": 0.2}]}))
        viewer.wait(f"() => ({options})().includes('remote:bench rig')")
        viewer.page.select_option("#source-select", "remote:bench rig")
        h = viewer.wait("() => window.gazehdr.lastHeader.tracker_gaze && window.gazehdr.lastHeader")
        assert (h["gaze_x"], h["gaze_y"]) == (pytest.approx(0.7), pytest.approx(0.2))
        # The pointer is not the gaze now: once the page sent the pointer's position, a frame
        # 0.5 s of simulation time later (the server has had it by then) still has the
        # tracker's gaze. A wait on a sent gaze and a clock, not on a count of frames. The
        # panel covers this narrow page, and a pointer over the panel is not sent: close it.
        viewer.page.keyboard.press("Escape")
        assert viewer.js("() => document.getElementById('panel').hidden")
        sent = viewer.js("() => window.gazehdr.stats.gazeSent")
        viewer.page.mouse.move(10, 10)
        viewer.wait("(s) => window.gazehdr.stats.gazeSent > s", sent)
        t = viewer.header()["time"]
        h = viewer.wait(
            "(t) => window.gazehdr.lastHeader.time > t + 0.5 && window.gazehdr.lastHeader", t
        )
        assert h["gaze_x"] == pytest.approx(0.7)
        viewer.wait("() => /tracker bench rig/.test(document.getElementById('hud').textContent)")
    viewer.wait(
        "() => /bench rig · not connected/.test(document.getElementById('hud').textContent)"
    )
    assert viewer.errors == []


def test_afterimage_moves_with_the_gaze(live_server, open_viewer) -> None:
    """The `flash` scene fires 1e7 cd/m² at frame position (0.5, 0.42) for 1/8 s every 4 s from
    t = 1 s. Fixate it through a flash, close the eyes (Space) so the frame is dark but for
    the afterimage, then move the gaze: the afterimage moves by the same offset, because it
    lives on the retina, not on the screen."""
    W, H = 320, 176
    srv = live_server(scene="flash", size=(W, H))
    viewer = open_viewer(srv.url, W, H)
    flash = np.array([0.5 * W, 0.42 * H])
    h = viewer.move_gaze(*flash)
    assert h["gaze_x"] * W == pytest.approx(flash[0], abs=1.0)

    # Fixate through the next flash: `h` ends the first step that had the gaze on it, so the
    # gaze is there from before the flash starts until past its end. However long the steps
    # are on a slow machine, the session splits them at the flash's edges, so the retina
    # integrates the flash for its 1/8 s at the gaze (test_session.py checks the split).
    t_flash = 1.0 + 4.0 * math.ceil(max(0.0, h["time"] - 1.0) / 4.0)
    viewer.wait("(t) => window.gazehdr.lastHeader.time > t", t_flash + 0.3, timeout=60_000)

    viewer.page.keyboard.down("Space")
    try:
        closed = viewer.wait(
            "() => !window.gazehdr.lastHeader.eyes_open && window.gazehdr.lastHeader"
        )
        viewer.next_frame(closed["frame"])
        before, peak0, radius0 = afterimage_centroid(viewer.payload()[2])
        shift = np.array([40.0, 30.0])
        h = viewer.move_gaze(*(flash + shift))
        assert not h["eyes_open"]
        after, peak1, radius1 = afterimage_centroid(viewer.payload()[2])
    finally:
        viewer.page.keyboard.up("Space")
    # A real afterimage, not noise: a bright (v summed over RGB > 0.1; ~0.35 seen), compact
    # blob (the flash head with its halo, blurred: ~11 px from centre to the half-peak edge).
    assert peak0 > 0.1 and peak1 > 0.05, (peak0, peak1)
    assert radius0 < 20 and radius1 < 20, ("not one blob", radius0, radius1)
    # Where the flash was on the retina: at the gaze, i.e. on the flash (within 1.5 px: the
    # flash head's edges are rounded to whole pixels and the retina's cells are ~1 px here).
    np.testing.assert_allclose(before, flash, atol=1.5)
    # And it moved with the eye, by the gaze shift (1 px: the retina is sampled bilinearly at
    # the gaze, so a shift moves the whole blob without changing its shape).
    np.testing.assert_allclose(after - before, shift, atol=1.0)
    viewer.wait("() => window.gazehdr.lastHeader.eyes_open")  # Space released: eyes open


# --- 3. the dither shader ---------------------------------------------------------------------


DITHER_JS = """
async ([size, frames, encoding, words]) => {
  const { Renderer } = await import('/renderer.js');
  const canvas = document.createElement('canvas');
  canvas.width = canvas.height = size;
  const r = new Renderer(canvas);
  const n = size * size;
  const pixels = encoding === 1 ? new Uint16Array(n * 3) : new Uint32Array(n);
  const per = encoding === 1 ? 3 : 1;
  for (let i = 0; i < pixels.length; i++) pixels[i] = words[i % per];
  r.upload(size, size, encoding, pixels);
  return window.__b64(window.__drawFrames(r, frames).buffer);
}
"""


def _dither(page: Any, encoding: int, words: list[int], size: int, frames: int) -> np.ndarray:
    """frames × size × size × 3 bytes read back from the real Renderer drawing a constant
    frame with frame counters 0..frames-1."""
    data = page.evaluate(DITHER_JS, [size, frames, encoding, words])
    return np.frombuffer(base64.b64decode(data), np.uint8).reshape(frames, size, size, 3)


def test_dither_shader_is_unbiased_and_uncorrelated(browser) -> None:
    with web_page(browser) as page:
        size, frames = 32, 256

        # f16: values between two 8-bit levels, rounded to half precision; the expected mean
        # is 255·v of the half actually sent, not of the decimal asked for.
        halves = np.array([100.3, 40.7, 200.5]) / 255
        halves = halves.astype(np.float16)
        v = halves.astype(np.float64)
        out = _dither(page, 1, [int(h) for h in halves.view(np.uint16)], size, frames)
        check_dither(out, v)

        # rgb10a2: v = q/1023.
        q = np.array([402, 163, 803])
        word = int(q[0] | (q[1] << 10) | (q[2] << 20))
        out = _dither(page, 2, [word], size, 64)
        check_dither(out, q / 1023.0, correlations=False)

        # The ends: 0 and 1 are shown exactly, never dithered off the range.
        ends = [int(x) for x in np.array([0.0, 1.0, 0.0], np.float16).view(np.uint16)]
        out = _dither(page, 1, ends, 8, 16)
        assert (out[..., 0] == 0).all() and (out[..., 1] == 255).all() and (out[..., 2] == 0).all()


# --- 4. reconnecting ----------------------------------------------------------------------------


class Proxy:
    """A TCP forwarder in front of the server: `drop()` cuts every connection as a network
    failure or a dying server would, `refusing` closes new ones at once (a server that is
    down; `refused` counts them), and `backend` can point at another server (a restart on the
    same address)."""

    def __init__(self, backend_port: int) -> None:
        self.backend = backend_port
        self.refusing = False
        self.refused = 0
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}"
        self.sockets: set[socket.socket] = set()
        self.lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            if self.refusing:
                self.refused += 1
                client.close()
                continue
            try:
                upstream = socket.create_connection(("127.0.0.1", self.backend), timeout=5)
                upstream.settimeout(None)
            except OSError:
                client.close()
                continue
            with self.lock:
                self.sockets |= {client, upstream}
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                dst.sendall(data)
        except OSError:
            pass
        finally:
            self._kill(src, dst)

    def _kill(self, *socks: socket.socket) -> None:
        for s in socks:
            with self.lock:
                self.sockets.discard(s)
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)
            s.close()

    def drop(self) -> None:
        with self.lock:
            socks = list(self.sockets)
        self._kill(*socks)

    def close(self) -> None:
        self.listener.close()
        self.drop()


def test_viewer_reconnects(live_server, open_viewer) -> None:
    # Sessions outlive their viewer by 30 s here, so a reconnect can rejoin its session.
    first = live_server(session_grace_s=30.0)
    proxy = Proxy(first.port)
    try:
        viewer = open_viewer(proxy.url, 160, 96)
        session = viewer.js("() => window.gazehdr.state.session")
        before = viewer.next_frame(3)["frame"]
        assert viewer.js("() => window.gazehdr.stats.connects") == 1

        def joined(connects: int) -> tuple[str, int]:
            """Wait for the hello on socket number `connects`; its session and the count of
            frames received so far (every later frame comes from that session)."""
            return viewer.wait(
                """(n) => { const g = window.gazehdr;
                  return g.stats.connects === n && g.connection.helloSeen
                    && [g.state.session, g.stats.received]; }""",
                connects,
                timeout=40_000,
            )

        # A network blip: the page notices, reconnects after the first back-off step, and
        # rejoins its session (?session=ID), whose frame numbers went on meanwhile (a new
        # session would start again from 0).
        proxy.drop()
        viewer.wait("() => window.gazehdr.connection.status === 'reconnecting'")
        rejoined, received = joined(2)
        assert rejoined == session
        viewer.wait("(n) => window.gazehdr.stats.received > n", received)
        assert viewer.header()["frame"] > before

        # The server goes away and another starts on the same address a moment later: the
        # page retries with growing delays, says so, and gets a fresh session.
        proxy.refusing = True
        proxy.drop()
        first.stop()
        text = viewer.wait(
            "() => { const t = document.getElementById('hud').textContent;"
            " return /reconnecting in \\d/.test(t) && t; }"
        )
        assert "reconnecting" in text
        second = live_server()
        proxy.backend = second.port
        wait_until(lambda: proxy.refused > 0, "a reconnect attempt the proxy refused")
        proxy.refusing = False
        fresh, received = joined(3)
        assert fresh != session
        viewer.wait("(n) => window.gazehdr.stats.received > n + 2", received)
        assert viewer.js("() => window.gazehdr.connection.status") == "open"
    finally:
        proxy.close()


def test_a_page_without_the_credential_says_how_to_get_in_and_stops(
    live_server, open_viewer
) -> None:
    """A page whose credential is gone (its cookie cleared, as a browser on another machine
    that did not open the address with ?token= never had one) reconnects, is refused (4401),
    says how to get in and stops connecting: no retry can mend a 4401. Guards the refusal's
    end of the retries (the page retried forever, "preparing the simulation")."""
    srv = live_server(token="tok")
    viewer = open_viewer(srv.url, 640, 400)
    page = viewer.page
    page.context.clear_cookies()
    page.evaluate("() => window.gazehdr.connection.drop()")
    viewer.wait("() => window.gazehdr.connection.status === 'refused'")
    said = page.evaluate("() => document.getElementById('toasts').textContent")
    assert "not authorized (4401)" in said and "?token=" in said
    attempts = page.evaluate("() => window.gazehdr.connection.attempt")
    page.wait_for_timeout(2500)  # longer than the first back-offs
    assert page.evaluate("() => window.gazehdr.connection.attempt") == attempts
    assert page.evaluate("() => window.gazehdr.connection.ws") is None
