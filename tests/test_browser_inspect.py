"""The viewer's HDR inspection and panel in real headless Chromium (see tests/browser.py for
the browser set-up): images made by OpenCV (not by gazehdr) upload, show and read out in
cd/m²; false colour and histogram follow the scene's scale; keys work whatever has focus."""

# ruff: noqa: F811  (the browser fixtures are imported from tests/browser.py, used as arguments)

from __future__ import annotations

import json
import time
import urllib.request
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from tests.browser import browser, open_viewer  # noqa: F401

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
