"""The late gaze warp in real headless Chromium (web/warp.js; fixtures of tests/browser.py).

The shader, run by the viewer's own Renderer, composes a warp frame as the server does; and
with the warp on the afterimage on the canvas follows a pointer move at the next display
refresh while no new frame comes (the page holds its frame, as a stalled server would make it),
where with the warp off it stays put; and likewise with a gaze daemon's tracker as the gaze,
at the tracker's gaze the server forwards (tests/test_gaze_forward.py).
"""

# ruff: noqa: F811  (the browser fixtures are imported from tests/browser.py, used as arguments)
from __future__ import annotations

import base64
import json
from typing import Any

import numpy as np
from websockets.sync.client import connect

from gazehdr import warp
from gazehdr.protocol import HEADER_BYTES, Encoding, FrameHeader, Gaze, decode_frame, parse_control
from gazehdr.session import SessionSettings
from gazehdr.sim import Simulator
from gazehdr.sim.presets import preset
from tests.browser import afterimage_centroid, browser, open_viewer, web_page  # noqa: F401
from tests.sessions import new_session
from tests.test_sim_backends import mixed_scene

DRAWS = 512  # dithered draws averaged per pixel: the mean's std is <= 0.09 codes of 1023

MEAN_JS = """
async ([b64, draws, gaze]) => {
  const { Renderer } = await import('/renderer.js');
  const { decodeFrame } = await import('/protocol.js');
  const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
  const { header, pixels } = decodeFrame(bytes.buffer);
  const canvas = document.createElement('canvas');
  canvas.width = header.width;
  canvas.height = header.height;
  const r = new Renderer(canvas);
  r.upload(header.width, header.height, header.encoding, pixels);
  const n = header.width * header.height;
  const sum = new Float64Array(n * 3);
  for (let k = 0; k < draws; k++) {
    r.draw(k, gaze);
    const px = r.readPixels();
    for (let i = 0; i < n; i++) for (let c = 0; c < 3; c++) sum[i * 3 + c] += px[i * 4 + c];
  }
  const mean = new Float32Array(sum.map((s) => s / (255 * draws)));
  return window.__b64(mean.buffer);
}
"""


def _shader_mean(page: Any, message: bytes, w: int, h: int, gaze: Any = None) -> np.ndarray:
    """The mean over DRAWS dithered canvas read-backs (an unbiased dither: the mean is v)."""
    b64 = base64.b64encode(message).decode()
    data = base64.b64decode(page.evaluate(MEAN_JS, [b64, DRAWS, gaze]))
    return np.frombuffer(data, np.float32).reshape(h, w, 3)[::-1].astype(np.float64)


def test_warp_shader_composes_as_the_server(browser) -> None:
    """At the frame's own gaze the canvas shows the server's frame within 2 codes of 1023 (the
    half floats' rounding, test_warp.py) and the oracle within 0.75 (float32 in the shader and
    the mean's noise); at another gaze, the oracle there."""
    w, h = 48, 32
    sim = Simulator(w, h, backend="opencl", seed=2)
    sim.load_scene(mixed_scene(1)[::2, ::2])
    sim.step(0.1, gaze=(16, 16))
    sim.step(0.05, gaze=(24, 10))
    v = sim.step(0.05, gaze=(26, 11))
    layers = sim.warp_layers()
    header = FrameHeader(0, 0, sim.time, 26 / w, 11 / h, sim.adaptation, 0.0, w, h, Encoding.warp)
    message = header.pack() + warp.pack([layers], w, sim.params)
    frame = warp.unpack(message[HEADER_BYTES:], w, h)
    with web_page(browser) as page:
        shown = _shader_mean(page, message, w, h)
        assert np.abs(shown - v).max() * 1023 <= 2.0
        assert np.abs(shown - warp.compose(frame)).max() * 1023 <= 0.75
        moved = _shader_mean(page, message, w, h, {"x": 10.5 / w, "y": 20.5 / h})
        oracle = warp.compose(frame, (10.5, 20.5))
        assert np.abs(oracle - v).max() * 1023 > 50  # the afterimages moved
        assert np.abs(moved - oracle).max() * 1023 <= 0.75


def test_warp_shader_warps_each_pane_in_split_view(browser) -> None:
    """Split view: the right pane (no afterimages) and the left (jacobs) side by side, an odd
    last column black; the pointer over the right half warps both panes as the server maps it.
    Our `visible` preset, whose flash afterimage is strong enough to see move at 81x32."""
    w, h = 81, 32
    settings = SessionSettings(
        width=w, height=h, scene="flash", backend="opencl", params=preset("visible")
    )
    session = new_session(settings)
    session.apply(parse_control('{"type": "model", "split": {"afterimage": "none"}}'))
    session.pointer.take(Gaze(0.25, 0.42, 1), 0.0)
    for _ in range(30):  # through the flash at t = 1 s, gaze on it
        frame, _ = session.tick(0.05, [], plain=True, warp=True)
    session.pointer.take(Gaze(0.3, 0.5, 2), 0.0)
    frame, _ = session.tick(0.05, [], plain=True, warp=True)
    message = frame.message(0, warp=True)
    assert message is not None
    _, plain = decode_frame(frame.message(0))
    layers = warp.unpack(message[HEADER_BYTES:], w, h)
    with web_page(browser) as page:
        shown = _shader_mean(page, message, w, h)
        assert np.abs(shown - plain).max() * 1023 <= 2.0
        pointer = {"x": 60.5 / w, "y": 8.5 / h}  # over the right pane: pane x 60.5 - 40
        moved = _shader_mean(page, message, w, h, pointer)
    oracle = warp.compose(layers, (60.5 - w // 2, 8.5))
    assert np.abs(oracle - plain).max() * 1023 > 50  # the left pane's afterimage moved
    assert np.abs(moved - oracle).max() * 1023 <= 0.75
    assert (moved[:, -1] == 0).all()


# The live warp tests' session rate. A 320×176 warp frame carries the whole retina grid's maps
# (640×352 cells at this size): 3 MB, and Playwright's driver gets every WebSocket frame a page
# receives, base64 in JSON. At the live_server's 20 fps that is 80 MB/s through the driver, more
# than it keeps up with on 2 cores: its backlog grew until the page's answers to the test never
# came. At 5 fps it still does: nothing (such as a kernel compile for each new gaze) holds the
# warp frames back. The warp itself runs at the display's rate, whatever the session's. (At
# 2 fps a step ends exactly on the flash's start at 1 s, which Eye.step handles.)
WARP_FPS = 2.0


# Read back in the next refresh's callback, into a global that `Viewer.wait` polls: a promise
# that `page.evaluate` awaited would wait without a timeout if no refresh came.
READ_NEXT_REFRESH_JS = """
() => { window.__nextRefresh = null; requestAnimationFrame(() => {
  // Runs after the viewer's own draw of this refresh (its callback was queued first).
  const g = window.gazehdr;
  const c = g.renderer.canvas;
  window.__nextRefresh = [window.__b64(g.renderer.readPixels().buffer), c.width, c.height, g.shown];
}); }
"""


def _canvas_next_refresh(viewer: Any) -> tuple[np.ndarray, dict[str, Any]]:
    """The canvas as drawn at the next display refresh (RGB in [0, 1], top row first) and the
    header of the frame it shows."""
    viewer.js(READ_NEXT_REFRESH_JS)
    b64, w, h, shown = viewer.wait("() => window.__nextRefresh")
    px = np.frombuffer(base64.b64decode(b64), np.uint8).reshape(h, w, 4)[::-1, :, :3]
    return px.astype(np.float64) / 255.0, shown


def _hold_a_closed_eyes_frame(viewer: Any, encoding: int) -> dict[str, Any]:
    """Hold the viewer on a frame of `encoding` made with the eyes closed."""
    viewer.js("() => { window.gazehdr.hold = false; }")
    viewer.wait(
        "(e) => { const s = window.gazehdr.shown; if (s && s.encoding === e && !s.eyes_open) "
        "{ window.gazehdr.hold = true; return true; } return false; }",
        encoding,
    )
    return viewer.js("() => window.gazehdr.shown")


def test_afterimage_follows_the_pointer_between_frames(live_server, open_viewer) -> None:
    """The `flash` scene's afterimage (as in test_browser's test_afterimage_moves_with_the_gaze),
    eyes closed, the viewer holding one frame: with the warp on, the afterimage on the canvas
    moves with the pointer at the very next display refresh, by the pointer's shift; with the
    warp off (the panel's box) it stays where the held frame has it."""
    W, H = 320, 176
    srv = live_server(scene="flash", size=(W, H), fps=WARP_FPS)
    viewer = open_viewer(srv.url + "?warp=1", W, H)
    flash = np.array([0.5 * W, 0.42 * H])
    viewer.move_gaze(*flash)
    h = viewer.wait("() => window.gazehdr.shown?.encoding === 16 && window.gazehdr.shown")
    t_flash = 1.0 + 4.0 * np.ceil(max(0.0, h["time"] - 1.0) / 4.0)
    viewer.wait("(t) => window.gazehdr.lastHeader.time > t", t_flash + 0.3, timeout=60_000)
    shift = np.array([40.0, 30.0])
    viewer.page.keyboard.down("Space")
    try:
        held = _hold_a_closed_eyes_frame(viewer, 16)
        canvas, shown = _canvas_next_refresh(viewer)
        before, peak0, radius0 = afterimage_centroid(canvas)
        viewer.page.mouse.move(*(flash + shift))
        canvas, shown = _canvas_next_refresh(viewer)
        after, peak1, radius1 = afterimage_centroid(canvas)
        assert shown["frame"] == held["frame"], "a new frame was shown: not the warp's doing"

        # The warp off: a plain frame, held; the pointer moves back, the afterimage stays.
        assert viewer.js("() => document.getElementById('warp-toggle').checked")
        viewer.js("() => document.getElementById('warp-toggle').click()")  # the panel's box
        plain = _hold_a_closed_eyes_frame(viewer, 1)
        canvas, _ = _canvas_next_refresh(viewer)
        still0, _, _ = afterimage_centroid(canvas)
        viewer.page.mouse.move(*flash)
        canvas, shown = _canvas_next_refresh(viewer)
        still1, peak2, radius2 = afterimage_centroid(canvas)
        assert shown["frame"] == plain["frame"]
    finally:
        viewer.page.keyboard.up("Space")
    assert peak0 > 0.1 and peak1 > 0.1 and peak2 > 0.05, (peak0, peak1, peak2)
    assert max(radius0, radius1, radius2) < 20, ("not one blob", radius0, radius1, radius2)
    np.testing.assert_allclose(before, flash, atol=1.5)
    np.testing.assert_allclose(after - before, shift, atol=1.0)
    np.testing.assert_allclose(still1, still0, atol=0.5)


def _fixate(daemon: Any, i: int, at: np.ndarray | None, size: tuple[int, int]) -> None:
    """The daemon's i-th event: a fixation at frame px `at` (a blink, if `at` is None)."""
    if at is None:
        event = {"type": "event", "kind": "blink_start", "id": i, "t": i}
    else:
        x, y = at / np.array(size)
        event = {"type": "event", "kind": "fixation_start", "id": i, "t": i, "x": x, "y": y}
    daemon.send(json.dumps(event))


# A frame 0.3 to 2 s after the start of a flash (1/8 s long, every 4 s from t = 1 s) that began
# once the gaze was on it (at `t0` or later): its afterimage is fresh, the next flash far. (Not
# from `t0` alone: a page that starts slowly may see its first frames seconds late.)
AFTER_A_FLASH_JS = """(t0) => { const t = window.gazehdr.lastHeader.time, phase = (t - 1) % 4;
  return t - phase >= t0 - 1e-6 && phase > 0.3 && phase < 2; }"""


def _blink_after_a_flash(
    viewer: Any, daemon: Any, t0: float, flash: np.ndarray, size: tuple[int, int]
) -> dict[str, Any]:
    """Blink after a flash seen from `t0` on and hold the first frame shown with the eyes
    closed, if it comes while the afterimage is fresh (else open the eyes on the flash and try
    again at the next: a loaded machine may show it seconds late); its header."""
    for attempt in range(4):
        viewer.wait(AFTER_A_FLASH_JS, t0, timeout=60_000)
        _fixate(daemon, 100 + 2 * attempt, None, size)
        held = _hold_a_closed_eyes_frame(viewer, 16)
        if 0.3 < (held["time"] - 1.0) % 4.0 < 2.5:
            return held
        _fixate(daemon, 101 + 2 * attempt, flash, size)
        viewer.js("() => { window.gazehdr.hold = false; }")
        opened = "() => window.gazehdr.lastHeader.eyes_open && window.gazehdr.lastHeader"
        t0 = viewer.wait(opened)["time"]
    raise AssertionError("no frame with the eyes closed came while an afterimage was fresh")


NOTE_AT_JS = """([x, y, open]) => { const g = window.gazehdr.trackerGaze;
  return g && Math.abs(g.x - x) < 1e-9 && Math.abs(g.y - y) < 1e-9 && g.eyesOpen === open; }"""


def test_afterimage_follows_a_tracker_between_frames(live_server, open_viewer) -> None:
    """A gaze daemon's tracker as the gaze: the flash's afterimage, the viewer holding one
    frame made with the eyes closed (a blink), moves on the canvas with the tracker's next
    fixation at the very next display refresh after its forwarded `gaze` note arrives, by the
    fixation's shift; a blink then (the tracker's place held) leaves it there."""
    W, H = 320, 176
    srv = live_server(scene="flash", size=(W, H), gaze_source="remote:rig", fps=WARP_FPS)
    flash = np.array([0.5 * W, 0.42 * H])
    with connect(srv.ws_url + "/ws/gaze", additional_headers=srv.auth) as daemon:
        daemon.send(json.dumps({"type": "hello", "protocol": 1, "tracker": "rig"}))
        assert json.loads(daemon.recv(timeout=30))["type"] == "welcome"
        _fixate(daemon, 1, flash, (W, H))
        viewer = open_viewer(srv.url + "?warp=1", W, H)
        h = viewer.wait(
            "([x, y]) => { const s = window.gazehdr.shown; return s?.encoding === 16 && "
            "s.tracker_gaze && Math.abs(s.gaze_x - x) < 1e-3 && Math.abs(s.gaze_y - y) < 1e-3 "
            "&& s; }",
            [0.5, 0.42],
        )
        held = _blink_after_a_flash(viewer, daemon, h["time"], flash, (W, H))
        viewer.wait(NOTE_AT_JS, [0.5, 0.42, False])
        canvas, _ = _canvas_next_refresh(viewer)
        before, peak0, radius0 = afterimage_centroid(canvas)
        shift = np.array([40.0, 30.0])
        _fixate(daemon, 3, flash + shift, (W, H))
        viewer.wait(NOTE_AT_JS, [*((flash + shift) / [W, H]), True])
        canvas, shown = _canvas_next_refresh(viewer)
        after, peak1, radius1 = afterimage_centroid(canvas)
        assert shown["frame"] == held["frame"], "a new frame was shown: not the warp's doing"
        _fixate(daemon, 4, None, (W, H))  # a blink: the tracker's place is held
        viewer.wait(NOTE_AT_JS, [*((flash + shift) / [W, H]), False])
        canvas, shown = _canvas_next_refresh(viewer)
        blinked, _, _ = afterimage_centroid(canvas)
        assert shown["frame"] == held["frame"]
    seen = (peak0, peak1, radius0, radius1, h["time"], held["time"])
    assert peak0 > 0.1 and peak1 > 0.1, ("no afterimage", seen)
    assert max(radius0, radius1) < 20, ("not one blob", seen)
    np.testing.assert_allclose(before, flash, atol=1.5)
    np.testing.assert_allclose(after - before, shift, atol=1.0)
    np.testing.assert_allclose(blinked, after, atol=0.5)
