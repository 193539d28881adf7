"""The viewer's HDR inspection and panel in real headless Chromium (see tests/browser.py for
the browser set-up): images made by OpenCV (not by gazehdr) upload, show and read out in
cd/m²; false colour and histogram follow the scene's scale; keys work whatever has focus; the
inspector's view (exposure, false-colour range, zoom), its readout of the file's pixel and
its labels."""

# ruff: noqa: F811  (the browser fixtures are imported from tests/browser.py, used as arguments)

from __future__ import annotations

import base64
import json
import re
import time
import urllib.request
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from tests.browser import browser, dither_levels, open_viewer  # noqa: F401

W, H = 160, 96  # the frame; the images are this size, so the scene map is the image itself


def _image() -> np.ndarray:
    """RGB with a different value in every pixel and channel, over four decades."""
    yy, xx = np.mgrid[:H, :W].astype(np.float32)
    base = 10.0 ** (4.0 * xx / W - 2.0 + yy / H)
    return np.stack([base, base * 0.5 + 0.01, base * (1 + yy / H)], axis=-1).astype(np.float32)


def _http(method: str, url: str, body: Any = None, token: str | None = None) -> tuple[int, Any]:
    data = json.dumps(body).encode() if isinstance(body, dict) else body
    request = urllib.request.Request(url, data=data, method=method)
    if token is not None:  # writes need the server's credential (gazehdr.security)
        request.add_header("Authorization", f"Bearer {token}")
    if isinstance(body, dict):
        request.add_header("Content-Type", "application/json")
    try:
        with urllib.request.urlopen(request, timeout=30) as answer:
            return answer.status, json.load(answer)
    except urllib.error.HTTPError as e:
        return e.code, json.load(e)


def _maps_seen(viewer: Any) -> int:
    return viewer.js("() => window.gazehdr.sceneMaps")


def _readout(viewer: Any, x: int, y: int) -> dict[str, Any]:
    """The inspector's readout with the pointer on frame pixel (x, y)."""
    viewer.page.mouse.move(x + 0.5, y + 0.5)
    return viewer.wait(
        """([x, y]) => { const r = window.gazehdr.inspector.last;
          return r && r.x === x && r.y === y && r; }""",
        [x, y],
    )


@pytest.mark.parametrize("suffix", [".hdr", ".pfm"])
def test_opencv_image_uploads_shows_and_reads_out_in_cd_per_m2(
    live_server, open_viewer, tmp_path: Path, suffix: str
) -> None:
    rgb = _image()
    path = tmp_path / f"made-by-opencv{suffix}"
    assert cv2.imwrite(str(path), rgb[..., ::-1])  # OpenCV writes BGR
    stored = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1]  # what the file holds
    # RGBE shares one exponent: each channel keeps 8 bits of the brightest one's scale.
    np.testing.assert_allclose(stored, rgb, atol=0, rtol=0.05)
    srv = live_server(size=(W, H))
    viewer = open_viewer(srv.url, W, H)
    page = viewer.page

    # Upload through the panel; the session switches to it.
    page.keyboard.press("p")
    page.set_input_files("#panel input[type=file]", str(path))
    page.fill("#panel input[type=text]", "opencv")
    page.click("#upload-button")
    viewer.wait("() => window.gazehdr.state.scene === 'opencv'")
    info = viewer.js("() => window.gazehdr.state.scene_info")
    assert info["format"] == suffix[1:] and (info["width"], info["height"]) == (W, H)
    assert info["scale_source"] == "estimate" and "EV 15" in info["scale_note"]

    # A scale given in the panel: applied at once, the file not read again.
    seen = _maps_seen(viewer)
    page.fill("#scale-input", "250")
    page.press("#scale-input", "Enter")
    viewer.wait("() => window.gazehdr.state.scene_info.scale === 250")
    viewer.wait("(n) => window.gazehdr.sceneMaps > n", seen)
    status, described = _http("GET", f"{srv.url}/api/scenes/opencv")
    assert status == 200 and described["scale_source"] == "user"

    # The picture shows (the image's gradient, not a blank), and the readout under the
    # pointer is the file's radiance times the scale, within float16 precision.
    page.keyboard.press("Escape")
    page.keyboard.press("i")
    _, _, v = viewer.payload()
    assert v.std() > 0.02
    for x, y in [(10, 20), (80, 48), (150, 90)]:
        r = _readout(viewer, x, y)
        want = stored[y, x].astype(np.float64) * 250.0
        np.testing.assert_allclose(r["rgb"], want, rtol=2**-10)
        weights = np.array([0.2126, 0.7152, 0.0722])
        assert r["Y"] == pytest.approx(float(want @ weights), rel=2**-10)
        assert r["log10Y"] == pytest.approx(np.log10(want @ weights), abs=1e-3)
        assert 0.0 <= min(r["display"]) and max(r["display"]) <= 1.0
        assert r["adaptation"] >= 2.0 and np.isfinite(r["rho"])
    text = viewer.js("() => document.querySelector('#inspector .readout').textContent")
    assert "cd/m²" in text and "250 cd/m² per unit (user)" in text


def test_false_colour_and_histogram_follow_the_scale(live_server, open_viewer, tmp_path) -> None:
    path = tmp_path / "scene.pfm"
    cv2.imwrite(str(path), _image()[..., ::-1])
    srv = live_server(size=(W, H))
    with open(path, "rb") as f:
        assert _http("PUT", f"{srv.url}/api/scenes/scene", f.read(), srv.token)[0] == 201
    assert _http("PATCH", f"{srv.url}/api/scenes/scene", {"scale": 1.0}, srv.token)[0] == 200
    viewer = open_viewer(srv.url, W, H)
    page = viewer.page
    viewer.js("() => window.gazehdr.connection.send({type: 'scene', name: 'scene'})")
    viewer.wait("() => window.gazehdr.state.scene === 'scene'")
    viewer.wait("() => window.gazehdr.inspector.map?.width === 160")
    page.keyboard.press("c")
    page.keyboard.press("i")
    assert viewer.js("() => !document.getElementById('falsecolour').hidden")

    def look() -> tuple[list[int], list[int]]:
        pixels = viewer.js(
            """() => { const c = document.getElementById('falsecolour'), x = c.width / 2;
              return [...c.getContext('2d').getImageData(x, c.height / 2, 1, 1).data]; }"""
        )
        return pixels, viewer.js("() => [...window.gazehdr.inspector.counts]")

    viewer.wait("() => document.getElementById('falsecolour').width === 160")
    before_colour, before_counts = look()
    seen = _maps_seen(viewer)
    assert _http("PATCH", f"{srv.url}/api/scenes/scene", {"scale": 1000.0}, srv.token)[0] == 200
    viewer.wait("(n) => window.gazehdr.sceneMaps > n", seen)
    viewer.wait("() => window.gazehdr.state.scene_info.scale === 1000")
    after_colour, after_counts = viewer.wait(
        "(c) => { const o = document.getElementById('falsecolour');"
        " const p = [...o.getContext('2d').getImageData(o.width / 2, o.height / 2, 1, 1).data];"
        " return p.join() !== c.join() && [p, [...window.gazehdr.inspector.counts]]; }",
        before_colour,
    )
    assert after_colour != before_colour
    # Three decades brighter: the histogram moves 30 of its 100 bins (0.1 decade each) up.
    mean = lambda c: float(np.average(np.arange(100), weights=c))  # noqa: E731
    assert mean(after_counts) - mean(before_counts) == pytest.approx(30.0, abs=1.0)
    legend = viewer.js("() => document.querySelector('#inspector .legend').textContent")
    assert "cd/m²" in legend


def test_keys_work_whatever_has_focus_and_escape_closes(live_server, open_viewer) -> None:
    srv = live_server(size=(W, H))
    viewer = open_viewer(srv.url, 800, 600)
    page = viewer.page
    hud_hidden = "() => document.getElementById('hud').hidden"
    panel_hidden = "() => document.getElementById('panel').hidden"
    page.keyboard.press("p")
    assert not viewer.js(panel_hidden)

    page.click("#falsecolour-toggle")  # a checkbox takes the focus ...
    assert viewer.js("() => document.activeElement.id") == "falsecolour-toggle"
    page.keyboard.press("h")  # ... and keys still work
    assert viewer.js(hud_hidden)
    page.keyboard.press("h")
    assert not viewer.js(hud_hidden)
    page.select_option("#scene-select", "lamp")  # a select takes it
    viewer.wait("() => window.gazehdr.state.scene === 'lamp'")
    page.focus("#scene-select")
    page.keyboard.press("i")
    assert viewer.js("() => !document.getElementById('inspector').hidden")
    assert viewer.js("() => document.getElementById('scene-select').value") == "lamp"
    page.keyboard.press("Space")  # a focused checkbox is not toggled by Space
    page.focus("#falsecolour-toggle")
    checked = viewer.js("() => document.getElementById('falsecolour-toggle').checked")
    page.keyboard.press("Space")
    assert viewer.js("() => document.getElementById('falsecolour-toggle').checked") == checked

    page.fill("#panel input[type=text]", "hph")  # typing in a text field is typing
    assert not viewer.js(hud_hidden) and not viewer.js(panel_hidden)

    page.keyboard.press("Escape")
    assert viewer.js(panel_hidden)
    page.keyboard.press("p")
    assert not viewer.js(panel_hidden)
    page.click("#panel-close")
    assert viewer.js(panel_hidden)

    # Every parameter shows its symbol, unit and meaning; long names are not cut off.
    page.keyboard.press("p")
    rows = viewer.js(
        """() => [...document.querySelectorAll('#panel .param')].map(r => [
          r.querySelector('.symbol').textContent, r.querySelector('.meaning').textContent,
          r.querySelector('.name').scrollWidth <= r.querySelector('.name').clientWidth + 1])"""
    )
    assert len(rows) == len(viewer.js("() => Object.keys(window.gazehdr.state.params)"))
    assert all(symbol and meaning and fits for symbol, meaning, fits in rows)


def test_upload_asks_before_replacing(live_server, open_viewer, tmp_path: Path) -> None:
    small, large = tmp_path / "a.pfm", tmp_path / "b.pfm"
    cv2.imwrite(str(small), _image()[:48, :80, ::-1])
    cv2.imwrite(str(large), _image()[..., ::-1])
    srv = live_server(size=(W, H))
    viewer = open_viewer(srv.url, W, H)
    page = viewer.page
    page.keyboard.press("p")

    def upload(path: Path) -> None:
        page.set_input_files("#panel input[type=file]", str(path))
        page.fill("#panel input[type=text]", "pic")
        page.click("#upload-button")

    upload(small)
    viewer.wait("() => window.gazehdr.state.scene === 'pic'")
    answers: list[str] = []
    page.once("dialog", lambda d: (answers.append(d.message), d.dismiss()))
    upload(large)
    viewer.wait("() => /kept/.test(document.getElementById('toasts').textContent)")
    assert "exists" in answers[0] and _http("GET", f"{srv.url}/api/scenes/pic")[1]["width"] == 80
    page.once("dialog", lambda d: d.accept())
    upload(large)
    viewer.wait("() => window.gazehdr.state.scene_info.width === 160")
    assert _http("GET", f"{srv.url}/api/scenes/pic")[1]["width"] == 160


def test_a_file_dropped_anywhere_on_the_page_uploads(live_server, open_viewer, tmp_path) -> None:
    """Drag and drop: the page shows its hint while a file is dragged over it, and a drop
    uploads the file under its own name, which the session then shows."""
    import base64

    path = tmp_path / "dropped.pfm"
    assert cv2.imwrite(str(path), _image()[..., ::-1])
    srv = live_server(size=(W, H))
    viewer = open_viewer(srv.url, W, H)
    drop = """async (b64) => {
      const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
      const data = new DataTransfer();
      data.items.add(new File([bytes], 'dropped.pfm'));
      window.dispatchEvent(new DragEvent('dragover', { dataTransfer: data, cancelable: true }));
      const hinted = !document.getElementById('drop').hidden;
      window.dispatchEvent(new DragEvent('drop', { dataTransfer: data, cancelable: true }));
      return [hinted, document.getElementById('drop').hidden];
    }"""
    hinted, hidden_after = viewer.js(drop, base64.b64encode(path.read_bytes()).decode())
    assert hinted and hidden_after
    viewer.wait("() => window.gazehdr.state.scenes.includes('dropped')")
    status, listed = _http("GET", srv.url + "/api/scenes")
    assert status == 200 and "dropped" in listed["scenes"]


def test_the_hud_plots_adaptation_and_rho_from_the_frames(live_server, open_viewer) -> None:
    """The HUD's plot holds A and rho of the frames it was given, over the last 10 s of
    simulation time, and draws them (red A, blue rho). The test waits until a drawn plot
    spans 2 s of simulation time (a fifth of the 240 px canvas: ~48 px of each line, however
    few frames a loaded machine made in that time); the wait's timeout is only a safety net."""
    srv = live_server(size=(W, H))
    viewer = open_viewer(srv.url, W, H)
    viewer.wait("() => window.gazehdr.hud.plot.drawnSpan >= 2.0", timeout=60_000)
    plotted = viewer.js(
        """() => { const c = document.querySelector('#hud canvas.plot');
          const px = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
          let red = 0, blue = 0;
          for (let i = 0; i < px.length; i += 4) {
            if (px[i] > 200 && px[i + 2] < 150) red++;
            if (px[i + 2] > 200 && px[i] < 150) blue++;
          }
          return [red, blue]; }"""
    )
    assert plotted[0] > 10 and plotted[1] > 10, plotted


def test_a_status_line_says_what_the_page_waits_for_until_the_first_frame(
    live_server, browser
) -> None:
    """While no frame has come (the server builds its kernels on first use), the page says
    so with the seconds it has waited; the line goes once frames arrive. Frames are held back
    by routing the page's /ws/view through the test."""
    srv = live_server(size=(W, H))
    held: list[Any] = []
    release = {"now": False}

    def route(ws: Any) -> None:
        server = ws.connect_to_server()

        def from_server(message: Any) -> None:
            if isinstance(message, bytes) and not release["now"]:
                held.append(message)
                return
            ws.send(message)

        server.on_message(from_server)
        ws.on_message(lambda message: server.send(message))

    page = browser.new_page(viewport={"width": W, "height": H})
    try:
        page.route_web_socket("**/ws/view*", route)
        page.goto(srv.url)
        waiting = """() => { const t = document.getElementById('status').textContent;
              return /waiting for the first frame… \\d+\\.\\d s/.test(t) && t; }"""
        page.wait_for_function(waiting, timeout=30_000)
        deadline = time.monotonic() + 30  # a safety net: the server makes frames within it
        while not held and time.monotonic() < deadline:
            page.wait_for_timeout(50)  # lets playwright deliver the routed messages
        assert held, "the server sent no frame"
        text = page.evaluate(f"({waiting})()")  # frames came and were held back: still waiting
        assert text and "first frame" in text
        release["now"] = True
        shown = "() => window.gazehdr.lastHeader && !document.getElementById('status').textContent"
        page.wait_for_function(shown, timeout=30_000)
    finally:
        page.close()


def test_plain_compare_puts_the_plain_tone_curve_in_the_right_pane(
    live_server, open_viewer
) -> None:
    """The panel's "Compare: plain tone curve" button: split view, the left pane keeping the
    model chosen, the right pane with neither afterimages nor acuity loss."""
    srv = live_server(size=(W, H))
    viewer = open_viewer(srv.url, 320, 192)
    page = viewer.page
    page.keyboard.press("p")
    page.select_option("#afterimage-select", "mikamo")
    viewer.wait("() => window.gazehdr.state.model.afterimage === 'mikamo'")
    assert viewer.js("() => window.gazehdr.state.split") is None
    page.click("#plain-compare")
    split = viewer.wait("() => window.gazehdr.state.split")
    assert split == {"afterimage": "none", "acuity": "none"}
    model = viewer.js("() => window.gazehdr.state.model")
    assert model["afterimage"] == "mikamo"  # the left pane keeps the chosen model
    viewer.wait("() => window.gazehdr.lastHeader.split")  # split frames come
    labels = viewer.wait(
        """() => { const l = [...document.querySelectorAll('#split-overlay .pane-label')]
            .map((e) => e.textContent);
          return l.length === 2 && l.every(Boolean) && l; }"""
    )
    assert "mikamo" in labels[0] and "none + none" in labels[1], labels


def test_histogram_marks_the_adaptation_and_the_floor(live_server, open_viewer, tmp_path) -> None:
    """The histogram (300 px for log10 cd/m² -3…7: 30 px a decade) has a red line at the
    eye's adaptation A and a dashed grey one at the floor A_min, which follows the parameter.
    The scene is uniform at 1e5 cd/m², so A (about 5, x = 240) is far from the floor (x = 150)."""
    path = tmp_path / "bright.pfm"
    cv2.imwrite(str(path), np.ones((H, W, 3), np.float32))
    srv = live_server(size=(W, H))
    with open(path, "rb") as f:
        assert _http("PUT", f"{srv.url}/api/scenes/bright", f.read(), srv.token)[0] == 201
    assert _http("PATCH", f"{srv.url}/api/scenes/bright", {"scale": 1e5}, srv.token)[0] == 200
    viewer = open_viewer(srv.url, W, H)
    viewer.js("() => window.gazehdr.connection.send({type: 'scene', name: 'bright'})")
    viewer.wait("() => window.gazehdr.state.scene === 'bright'")
    viewer.page.keyboard.press("i")
    columns = """() => { const c = document.querySelector('#inspector canvas.histogram');
      const px = c.getContext('2d').getImageData(0, 0, c.width, c.height - 14).data;
      const red = new Array(c.width).fill(0), grey = new Array(c.width).fill(0);
      for (let i = 0; i < px.length; i += 4) {
        const x = (i / 4) % c.width, [r, g, b, a] = px.slice(i, i + 4);
        if (a > 60 && r > 200 && g < 140 && b < 140) red[x]++;
        if (a > 60 && r > 120 && Math.abs(r - g) < 12 && Math.abs(g - b) < 12) grey[x]++;
      }
      return [red, grey, window.gazehdr.lastHeader.adaptation]; }"""

    def lines(floor: float) -> tuple[float, float, float]:
        """Where the red and the grey lines are (mean x of their pixels), and A: waited for
        until the grey line is near `floor`'s place and a red line is drawn."""
        red, grey, a = viewer.wait(
            f"""() => {{ const [red, grey, a] = ({columns})();
              const at = grey.findIndex((n) => n > 10);
              return Math.abs(at - {(floor + 3) * 30}) < 3 && red.some((n) => n > 20)
                && [red, grey, a]; }}"""
        )
        mean = lambda n: float(np.average(np.arange(len(n)), weights=n))  # noqa: E731
        assert sum(red) > 30 and sum(grey) > 10  # a line each, the grey one dashed
        return mean(red), mean(grey), a

    red_x, grey_x, a = lines(2.0)
    assert 4.0 < a < 6.0 and red_x == pytest.approx((a + 3) * 30, abs=3.0)
    assert grey_x == pytest.approx(150, abs=1.0)
    viewer.js("() => window.gazehdr.connection.send({type: 'params', values: {A_min: 3.0}})")
    viewer.wait("() => window.gazehdr.state.params.A_min === 3")
    red_x, grey_x, a = lines(3.0)
    assert grey_x == pytest.approx(180, abs=1.0) and red_x == pytest.approx((a + 3) * 30, abs=3.0)


# ---- the inspector's view: exposure, false-colour range, zoom, the file's pixel, labels ------

#: Viridis at the five stops web/inspect.js joins linearly, written out again here.
VIRIDIS = np.array(
    [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], np.float64
)
READOUT = "() => document.querySelector('#inspector .readout').textContent"
#: A number as the legend and the histogram write it: 10ⁿ or m·10ⁿ, "≤"/"≥" at the ends.
TEN_TO_THE = re.compile("^(≤|≥)?(\\d(\\.\\d+)?·)?10[⁻⁰¹²³⁴⁵⁶⁷⁸⁹]+$")


def _viridis(t: float) -> list[int]:
    x = min(max(t, 0.0), 1.0) * 4
    i = min(int(x), 3)
    return [int(np.floor(v + 0.5)) for v in VIRIDIS[i] + (VIRIDIS[i + 1] - VIRIDIS[i]) * (x - i)]


def _srgb_bytes(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    return 255.0 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def _scene(srv: Any, viewer: Any, name: str, rgb: np.ndarray, scale: float, tmp: Path) -> None:
    """Upload `rgb` (as a PFM) as scene `name` at `scale` cd/m² per unit, show it and wait for
    its scene map."""
    path = tmp / f"{name}.pfm"
    assert cv2.imwrite(str(path), rgb[..., ::-1].astype(np.float32))
    with open(path, "rb") as f:
        assert _http("PUT", f"{srv.url}/api/scenes/{name}", f.read(), srv.token)[0] == 201
    assert _http("PATCH", f"{srv.url}/api/scenes/{name}", {"scale": scale}, srv.token)[0] == 200
    seen = _maps_seen(viewer)
    viewer.js("(n) => window.gazehdr.connection.send({type: 'scene', name: n})", name)
    viewer.wait(
        "([n, s]) => { const g = window.gazehdr;"
        " return g.state.scene === n && g.state.scene_info.scale === s; }",
        [name, scale],
    )
    viewer.wait("(n) => window.gazehdr.sceneMaps > n", seen)


def _overlay(viewer: Any) -> np.ndarray:
    """The overlay canvas (scene view or false colour) as an H×W×3 byte array."""
    w, h, b64 = viewer.js(
        """() => { const c = document.getElementById('falsecolour');
          const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
          return [c.width, c.height, window.__b64(d.buffer)]; }"""
    )
    return np.frombuffer(base64.b64decode(b64), np.uint8).reshape(h, w, 4)[..., :3]


def _gaze_after(viewer: Any, sent: int) -> dict[str, Any]:
    """The header of a frame made with a gaze sent after gaze number `sent`."""
    seq = viewer.wait(
        "(s) => window.gazehdr.stats.gazeSent > s && window.gazehdr.stats.gazeSent", sent
    )
    return viewer.wait(
        "(s) => window.gazehdr.lastHeader.gaze_seq >= s && window.gazehdr.lastHeader", seq
    )


def test_exposure_scales_the_scene_view_by_two_to_the_stops(
    live_server, open_viewer, tmp_path
) -> None:
    """S shows the scene as tev shows its file: each channel's value in file units (radiance ÷
    scale) × 2^exposure, sRGB-encoded; ] and [ step the exposure by half a stop. The canvas's
    pixels are read back at 0, +1.5 and −1 stops and each compared with the formula, within a
    byte; the panel and the readout show the exposure; no message goes to the server. Guards
    the mutation: the gain drawn without 2^exposure (`2 ** this.exposure / this.scale` →
    `1 / this.scale` in sceneImage)."""
    srv = live_server(size=(W, H))
    viewer = open_viewer(srv.url, W, H)
    stored = _image() * 0.02  # 2·10⁻⁴ … 2.3 file units: most of it between black and white
    _scene(srv, viewer, "exposed", stored, 250.0, tmp_path)
    page = viewer.page
    page.keyboard.press("i")
    page.keyboard.press("s")
    viewer.wait("() => document.getElementById('falsecolour').width === 160")
    viewer.js(
        """() => { const c = window.gazehdr.connection, send = c.send.bind(c);
          window.__sent = []; c.send = (m) => { window.__sent.push(m); return send(m); }; }"""
    )
    for keys, stops, shown in [("", 0.0, "±0.0"), ("]]]", 1.5, "+1.5"), ("[[[[[", -1.0, "−1.0")]:
        for key in keys:
            page.keyboard.press(key)
        viewer.wait(
            "(e) => { const d = window.gazehdr.inspector.drawn;"
            " return d?.mode === 'scene' && d.exposure === e && d.scale === 250; }",
            stops,
        )
        diff = np.abs(_overlay(viewer) - _srgb_bytes(stored * 2.0**stops))
        assert diff.max() <= 1.01, (stops, diff.max())
        field = viewer.js("() => Number(document.getElementById('exposure-input').value)")
        assert field == stops
        line = f"scene view · exposure {shown} stops"
        viewer.wait(f"(l) => ({READOUT})().includes(l)", line)
    sent = viewer.js("() => window.__sent.filter((m) => !['gaze', 'ack'].includes(m.type))")
    assert sent == [], sent  # the exposure is this page's


def test_the_false_colour_range_maps_a_known_radiance_to_its_colour(
    live_server, open_viewer, tmp_path
) -> None:
    """A uniform 10 cd/m² scene (log10 Y = 1) in false colour: with the default range
    (10⁻³…10⁷) it is viridis at 0.4; with the range set in the panel to 0…2, viridis at 0.5;
    to 1…3, at 0 (the range's foot); to −1…1.5, at 0.8. The overlay's pixels are read back;
    the legend's ends follow the range; a minimum above the maximum is refused. Guards the
    mutation: the false colour drawn over LOG_RANGE whatever the range (`const [lo, hi] =
    this.range` → `= LOG_RANGE` in falseImage)."""
    srv = live_server(size=(W, H))
    viewer = open_viewer(srv.url, W, H)
    _scene(srv, viewer, "ten", np.ones((H, W, 3), np.float32), 10.0, tmp_path)
    page = viewer.page
    page.keyboard.press("c")
    log_y = np.log10(10.0 * sum(viewer.js("() => window.gazehdr.state.params.w_P")))

    def colour(lo: float, hi: float) -> list[int]:
        viewer.wait("(r) => window.gazehdr.inspector.drawn?.range.join() === r.join()", [lo, hi])
        return [int(v) for v in _overlay(viewer)[H // 2, W // 2]]

    assert colour(-3, 7) == _viridis((log_y + 3) / 10)
    page.keyboard.press("p")
    for lo, hi in [(0, 2), (1, 3), (-1, 1.5)]:
        page.fill("#falsecolour-min", str(lo))
        page.press("#falsecolour-min", "Enter")
        page.fill("#falsecolour-max", str(hi))
        page.press("#falsecolour-max", "Enter")
        assert colour(lo, hi) == _viridis((log_y - lo) / (hi - lo)), (lo, hi)
    labels = viewer.js(
        "() => [...document.querySelectorAll('#inspector .legend .labels span')]"
        ".map((s) => s.textContent)"
    )
    assert labels[0] == "≤10⁻¹" and labels[-1] == "≥3.2·10¹", labels
    page.fill("#falsecolour-min", "5")
    page.press("#falsecolour-min", "Enter")
    invalid = "() => document.getElementById('falsecolour-min').classList.contains('invalid')"
    assert viewer.js(invalid)
    assert viewer.js("() => window.gazehdr.inspector.range") == [-1, 1.5]


def test_zoom_draws_blocks_and_the_gaze_is_the_scene_point_under_the_pointer(
    live_server, open_viewer
) -> None:
    """Inspector open, + twice at P0: the 160×96 frame, fitted 3× into 480×288, is magnified 4×
    about P0, which stays put (the frame's rectangle: P0 − 4·P0, 1920×1152). (1) Blocks: a known
    frame drawn zoomed and read back has, at every canvas pixel, the dithered value of the
    frame pixel under it, nothing between. (2) The gaze sent for a pointer at P1 is the frame
    point under P1 in that rectangle, the readout's pixel is the one it falls in, and the
    overlay's block there has that scene pixel's colour. (3) The wheel zooms about the
    pointer. (4) 0 resets, and the gaze is sent anew for the unzoomed point. Guards the
    mutations: the zoomed frame sampled LINEAR (`this.view.scale === 1 &&` dropped in
    renderer.draw), and the pointer mapped through the unzoomed rectangle in frameFraction."""
    srv = live_server(size=(W, H))
    viewer = open_viewer(srv.url, 3 * W, 3 * H)
    assert (viewer.header()["width"], viewer.header()["height"]) == (W, H)
    page = viewer.page
    page.keyboard.press("i")
    page.keyboard.press("c")
    p0 = (241.0, 143.0)
    page.mouse.move(*p0)
    page.keyboard.press("+")
    page.keyboard.press("+")
    zoomed = "(z) => window.gazehdr.renderer.view.scale === z && window.gazehdr.renderer.cssRect()"
    rect = viewer.wait(zoomed, 4)
    assert rect == {"x": -3 * p0[0], "y": -3 * p0[1], "width": 1920, "height": 1152}

    # (1) A known frame (RGB10A2: q/1023, neighbours far apart) drawn zoomed, read back.
    yy, xx = np.mgrid[:H, :W]
    q = np.stack([(xx * 37 + yy * 11) % 32 * 33, (xx * 7) % 16 * 68, (yy * 5) % 16 * 68], -1)
    words = (q[..., 0] | q[..., 1] << 10 | q[..., 2] << 20).astype(np.uint32)
    got = viewer.js(
        """([b64, w, h]) => { const g = window.gazehdr; g.hold = true;
          const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
          g.renderer.upload(w, h, 2, new Uint32Array(bytes.buffer));
          g.renderer.draw(7);
          return window.__b64(g.renderer.readPixels().buffer); }""",
        [base64.b64encode(words.tobytes()).decode(), W, H],
    )
    px = np.frombuffer(base64.b64decode(got), np.uint8).reshape(3 * H, 3 * W, 4)[::-1, :, :3]
    cy, cx = np.mgrid[: 3 * H, : 3 * W] + 0.5  # canvas pixel centres, from the top
    fx = np.floor((cx - rect["x"]) / 12).astype(int)  # 12 canvas px a frame pixel
    fy = np.floor((cy - rect["y"]) / 12).astype(int)
    lo, hi = dither_levels(q[fy, fx] / 1023.0)
    assert ((px >= lo) & (px <= hi)).all(), "zoomed pixels are not the frame's pixels as blocks"
    viewer.js("() => { window.gazehdr.hold = false; }")

    # (2) The gaze for a pointer at P1 under the zoom.
    p1 = (100.3, 60.7)
    h = viewer.move_gaze(*p1)
    gaze = ((p1[0] - rect["x"]) / 1920, (p1[1] - rect["y"]) / 1152)
    assert h["gaze_x"] == pytest.approx(gaze[0], abs=1e-5)
    assert h["gaze_y"] == pytest.approx(gaze[1], abs=1e-5)
    x, y = int(gaze[0] * W), int(gaze[1] * H)
    assert (x, y) != (int(p1[0] / 3), int(p1[1] / 3))  # not where the unzoomed frame has it
    viewer.wait(
        "([x, y]) => { const r = window.gazehdr.inspector.last; return r?.x === x && r.y === y; }",
        [x, y],
    )
    block = viewer.js(
        """([px, py, x, y]) => {
          const o = document.getElementById('falsecolour').getContext('2d');
          const i = window.gazehdr.inspector.images.false.getContext('2d');
          return [[...o.getImageData(px, py, 1, 1).data], [...i.getImageData(x, y, 1, 1).data]];
        }""",
        [int(p1[0]), int(p1[1]), x, y],
    )
    assert block[0] == block[1]

    # (3) The wheel zooms about the pointer: the frame point under P1 stays under it.
    page.mouse.wheel(0, -200)
    rect = viewer.wait(zoomed, 8)
    assert rect["width"] == 8 * 3 * W
    assert (p1[0] - rect["x"]) / rect["width"] == pytest.approx(gaze[0], abs=1 / rect["width"])
    assert (p1[1] - rect["y"]) / rect["height"] == pytest.approx(gaze[1], abs=1 / rect["height"])

    # (4) 0: the whole frame again, and the gaze follows to the unzoomed point.
    sent = viewer.js("() => window.gazehdr.stats.gazeSent")
    page.keyboard.press("0")
    h = _gaze_after(viewer, sent)
    assert viewer.js("() => window.gazehdr.renderer.view.scale") == 1
    assert h["gaze_x"] == pytest.approx(p1[0] / 480, abs=1e-5)
    assert h["gaze_y"] == pytest.approx(p1[1] / 288, abs=1e-5)


def test_the_readout_gives_the_file_pixel_in_file_units_and_in_cd_per_m2(
    live_server, open_viewer, tmp_path
) -> None:
    """At 250 cd/m² per unit: a 160×96 file (the frame's size) reads out the file's own pixel,
    its value in file units and × 250 in cd/m²; a 320×192 one the mean of the 2×2 file pixels
    the frame pixel covers, said so; the bars around a 160×48 one read 0, black, with no file
    pixel, and its image the file's own pixels, 24 rows down. Guards the mutations: the file
    units shown without ÷ scale (`v / scale` → `v`), and the file's span taken as the frame's
    (`x0: u * sx` → `x0: u`)."""
    srv = live_server(size=(W, H))
    viewer = open_viewer(srv.url, W, H)
    viewer.page.keyboard.press("i")

    def shown(part: str) -> str:
        return viewer.wait(f"(p) => ({READOUT})().includes(p) && ({READOUT})()", part)

    own = _image()
    _scene(srv, viewer, "own", own, 250.0, tmp_path)
    r = _readout(viewer, 80, 48)
    assert r["file"] == {"kind": "own", "x": 80, "y": 48, "x0": 80, "x1": 81, "y0": 48, "y1": 49}
    np.testing.assert_allclose(r["units"], own[48, 80], rtol=2**-10)
    np.testing.assert_allclose(r["rgb"], own[48, 80] * 250.0, rtol=2**-10)
    text = shown("file  px 80, 48 of 160×96: its own pixel")
    assert f"RGB  {'  '.join(f'{v:.4g}' for v in r['units'])} file units" in text
    assert f"RGB  {'  '.join(f'{v:.4g}' for v in r['rgb'])} cd/m²" in text

    ramp = np.linspace(0.5, 1.5, 2 * W, dtype=np.float32)[None, :, None]
    big = np.kron(_image(), np.ones((2, 2, 1), np.float32)) * ramp
    _scene(srv, viewer, "big", big, 250.0, tmp_path)
    r = _readout(viewer, 40, 30)
    f = r["file"]
    assert f["kind"] == "mean" and (f["x0"], f["x1"], f["y0"], f["y1"]) == (80, 82, 60, 62)
    np.testing.assert_allclose(r["units"], big[60:62, 80:82].mean(axis=(0, 1)), rtol=0.01)
    shown("file  mean of px 80–81, 60–61 of 320×192")

    _scene(srv, viewer, "wide", _image()[:48], 250.0, tmp_path)
    r = _readout(viewer, 80, 10)  # above the image: a bar
    assert r["file"] == {"kind": "bar"} and r["Y"] == 0 and r["log10Y"] is None
    text = shown("file  – (the bars around its 160×48: 0)")
    assert "Y    0 cd/m² (black)" in text and "Infinity" not in text and "NaN" not in text
    r = _readout(viewer, 80, 30)  # in it: the file's own pixel
    assert r["file"]["kind"] == "own" and (r["file"]["x"], r["file"]["y"]) == (80, 6)


def test_labels_fit_their_boxes_read_no_infinity_and_share_one_format(
    live_server, open_viewer, tmp_path
) -> None:
    """With the false colour on, at the default range and at a fractional one (−2.5…3.7):
    every legend label lies inside the legend's bar (bounding boxes compared), every histogram
    axis label inside its canvas, both in the 10⁻³ style; the inspector inside the window, the
    panel's inspector controls inside the panel; black under the pointer reads 0, and nothing
    reads Infinity, NaN or 1e-3. Guards the mutations: the legend's end labels centred on the
    bar's ends (the `.start`/`.end` rules of style.css dropped), and black's log10 printed
    (`log10Y: Math.log10(Y)` and the readout's Y line always with it: "log10 -Infinity")."""
    srv = live_server(size=(W, H))
    viewer = open_viewer(srv.url, 880, 500)
    image = _image()
    image[:, :20] = 0
    _scene(srv, viewer, "labels", image, 250.0, tmp_path)
    page = viewer.page
    page.keyboard.press("i")
    page.keyboard.press("c")
    page.mouse.move(40, 250)  # over the black columns
    viewer.wait("() => window.gazehdr.inspector.last?.Y === 0")
    for lo, hi in [(-3, 7), (-2.5, 3.7)]:
        viewer.js("(r) => window.gazehdr.view.falseRange(r)", [lo, hi])
        boxes = viewer.js(
            """() => { const box = (e) => { const b = e.getBoundingClientRect();
                return [b.left, b.top, b.right, b.bottom]; };
              const legend = document.querySelector('#inspector .legend');
              const spans = [...legend.querySelectorAll('.labels span')];
              return {
                bar: box(legend.querySelector('canvas')),
                labels: spans.map((s) => [s.textContent, box(s)]),
                axis: window.gazehdr.inspector.axisLabels,
                histogram: document.querySelector('#inspector canvas.histogram').width,
                inspector: box(document.getElementById('inspector')),
                text: document.getElementById('inspector').textContent,
              }; }"""
        )
        bar = boxes["bar"]
        for text, (left, _, right, _) in boxes["labels"]:
            assert bar[0] - 0.5 <= left and right <= bar[2] + 0.5, (text, left, right, bar)
            assert TEN_TO_THE.match(text), text
        assert boxes["labels"][0][0].startswith("≤") and boxes["labels"][-1][0].startswith("≥")
        for label in boxes["axis"]:
            assert 0 <= label["x"] and label["x"] + label["width"] <= boxes["histogram"], label
            assert TEN_TO_THE.match(label["text"]), label
        left, top, right, bottom = boxes["inspector"]
        assert 0 <= left and 0 <= top and right <= 880 and bottom <= 500, boxes["inspector"]
        for bad in ("Infinity", "NaN", "e-", "e+"):
            assert bad not in boxes["text"], (bad, boxes["text"])
        assert "Y    0 cd/m² (black)" in boxes["text"]
    page.keyboard.press("p")
    inside = viewer.js(
        """() => { const panel = document.getElementById('panel').getBoundingClientRect();
          const group = document.getElementById('inspector-group');
          return [...group.querySelectorAll('input, button, span')].map((e) => {
            const b = e.getBoundingClientRect();
            return [e.id || e.textContent, b.left >= panel.left && b.right <= panel.right]; }); }"""
    )
    assert inside and all(ok for _, ok in inside), inside
