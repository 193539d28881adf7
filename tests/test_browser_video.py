"""The stream encodings (`h264`, `av1`) in real headless Chromium: WebCodecs decodes the server's
packets (FFmpeg's h264 and dav1d, in software), the page copies the 10-bit planes out and the
dither shader draws them.

The browser, the pages and the dither statistics are tests/browser.py's (its fixtures and
helpers, imported). WebCodecs exists only in a secure context: the server's pages are on
http://127.0.0.1, which is one; the shader-only page is served as http://localhost.
"""
# ruff: noqa: F811  (the browser fixtures are imported from tests/browser.py, used as arguments)

from __future__ import annotations

import base64

import numpy as np
import pytest

from gazehdr.protocol import Encoding
from gazehdr.video import CODECS, Decoder, Encoder
from gazehdr.yuv import to_rgb
from tests.browser import (  # noqa: F401
    B64_JS,
    browser,
    check_dither,
    dither_levels,
    open_viewer,
    serve_checkout_web,
)

#: Decode packets with the page's VideoStream, then draw the newest picture `frames` times
#: (dither counters 0..frames-1) and read each back; also returns the decoded planes.
DECODE_AND_DRAW_JS = """
async ([packets, width, height, frames, encoding]) => {
  const { VideoStream } = await import('/video.js');
  const { Renderer } = await import('/renderer.js');
  const canvas = document.createElement('canvas');
  canvas.width = width;
  canvas.height = height;
  const r = new Renderer(canvas);
  let planes = null;
  const lost = [];
  const stream = new VideoStream((p) => (planes = p), (why) => lost.push(why));
  packets.forEach(([b64, key], frame) => {
    const packet = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    stream.decode({ frame, width, height, keyframe: key, encoding }, packet);
  });
  await stream.decoder.flush();
  for (let i = 0; i < 100 && stream.stats.decoded < packets.length; i++) {
    await new Promise((ok) => setTimeout(ok, 10));  // the last copyTo
  }
  r.uploadYuv(planes);
  const out = window.__drawFrames(r, frames);
  return [window.__b64(out.buffer), window.__b64(planes.data.buffer), planes.layout,
          stream.stats.decoded, lost];
}
"""


def _planes(data: bytes, layout: list[dict[str, int]], w: int, h: int) -> list[np.ndarray]:
    """Y', Cb, Cr as the page copied them out of its VideoFrame."""
    words = np.frombuffer(data, np.uint16)
    sizes = [(h, w), ((h + 1) // 2, (w + 1) // 2), ((h + 1) // 2, (w + 1) // 2)]
    out = []
    for (rows, cols), plane in zip(sizes, layout, strict=True):
        start, stride = plane["offset"] // 2, plane["stride"] // 2
        out.append(words[start : start + rows * stride].reshape(rows, stride)[:, :cols])
    return out


STREAMS = [Encoding.h264, Encoding.av1]


@pytest.mark.parametrize("encoding", STREAMS, ids=lambda e: e.name)
def test_dither_shader_is_unbiased_and_uncorrelated_on_a_decoded_stream(
    browser, encoding: Encoding
) -> None:
    """The dither statistics (tests/browser.py's check_dither), unchanged, on a picture that
    went through the encoder, the browser's decoder and the YUV shader: the mean of the shown
    levels is the decoded value, and the decisions are independent across pixels, channels
    and frames."""
    page = browser.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.add_init_script(B64_JS)
    try:
        serve_checkout_web(page, origin="http://localhost")
        size, frames = 32, 256
        colour = np.array([100.3, 40.7, 200.5]) / 255  # between two 8-bit levels each
        v = np.broadcast_to(colour.astype(np.float32), (size, size, 3))
        encoder = Encoder((size, size), 30, encoding.name)
        packets = [encoder.encode(v) for _ in range(3)]  # a keyframe and two deltas
        b64 = [[base64.b64encode(p.data).decode(), p.key] for p in packets]
        got = page.evaluate(DECODE_AND_DRAW_JS, [b64, size, size, frames, int(encoding)])
        out_b64, planes_b64, layout, decoded, lost = got
        assert decoded == 3 and not lost, (decoded, lost)
        # The browser decoded the same planes as FFmpeg's decoders in Python do, bit for bit ...
        planes = _planes(base64.b64decode(planes_b64), layout, size, size)
        decoder = Decoder(encoding.name)
        for p in packets:
            mine = decoder.planes(p.data, p.key)
        for theirs, ours in zip(planes, mine, strict=True):
            np.testing.assert_array_equal(theirs, ours[: theirs.shape[0], : theirs.shape[1]])
        # ... a flat colour stays flat (so one expected value per channel) ...
        assert all(len(np.unique(plane)) == 1 for plane in planes), [np.unique(p) for p in planes]
        decoded_v = to_rgb(*planes, (size, size))[0, 0].astype(np.float64)
        assert np.abs(decoded_v - colour).max() < 3 / 1023, decoded_v * 255
        # ... and the shader dithers around it as it does around raw frames.
        out = np.frombuffer(base64.b64decode(out_b64), np.uint8).reshape(frames, size, size, 3)
        check_dither(out, decoded_v)
    finally:
        page.close()
    assert not errors, errors


@pytest.mark.parametrize("encoding", STREAMS, ids=lambda e: e.name)
def test_viewer_shows_a_stream_and_recovers_from_a_corrupt_packet(
    live_server, open_viewer, encoding: Encoding
) -> None:
    W, H = 320, 176
    srv = live_server(scene="lamp", size=(W, H), encoding=Encoding.rgb10a2)
    viewer = open_viewer(srv.url + f"/?encoding={encoding.name}", W, H)
    viewer.wait(f"() => window.gazehdr.lastHeader.encoding === {int(encoding)}")
    assert viewer.js("() => window.gazehdr.encodingRefused") is None
    viewer.wait("() => window.gazehdr.video.stats.decoded >= 3")
    # A remote viewer gets no scene maps (20 MB at 1080p) until it shows the inspector.
    assert viewer.js("() => window.gazehdr.sceneMaps") == 0
    viewer.page.keyboard.press("i")
    viewer.wait("() => window.gazehdr.sceneMaps > 0")
    viewer.page.keyboard.press("i")

    # The canvas shows the decoded picture: each pixel one of the two 8-bit levels around its
    # decoded value (the planes and the drawing read back in one task).
    got = viewer.js(
        """async () => {
          const g = window.gazehdr, r = g.renderer;
          const planes = await new Promise((ok, no) => {
            const s = g.video, on = s.onPlanes;
            s.onPlanes = (p) => { s.onPlanes = on; on(p); ok(p); };
            setTimeout(() => no(new Error('no picture decoded in 30 s')), 30000);
          });
          r.uploadYuv(planes);
          r.draw();
          const px = r.readPixels();
          return [window.__b64(planes.data.buffer), planes.layout, window.__b64(px.buffer),
                  r.gl.drawingBufferWidth, r.gl.drawingBufferHeight];
        }"""
    )
    planes = _planes(base64.b64decode(got[0]), got[1], W, H)
    v = to_rgb(*planes, (W, H)).astype(np.float64)
    assert (got[3], got[4]) == (W, H)
    assert v.std() > 0.01  # a picture, not a blank
    shown = np.frombuffer(base64.b64decode(got[2]), np.uint8).reshape(H, W, 4)[::-1, :, :3]
    lo, hi = dither_levels(v)
    bad = (shown < lo) | (shown > hi)
    assert not bad.any(), f"{bad.sum()} values off their two levels, first at {np.argwhere(bad)[0]}"

    # A corrupt packet: the page's decoder fails, it asks for a keyframe, and the stream
    # goes on from there.
    before = viewer.js(
        "() => [window.gazehdr.stats.keyRequests, window.gazehdr.video.stats.decoded]"
    )
    viewer.js(
        """() => {
          const g = window.gazehdr, h = { ...g.lastHeader, keyframe: false, frame: 1e9 };
          const junk = new Uint8Array(600).map((_, i) => (i * 89 + 7) & 255);
          g.video.decode(h, junk);
        }"""
    )
    viewer.wait("(n) => window.gazehdr.stats.keyRequests > n", before[0])
    text = viewer.js("() => window.gazehdr.video.stats.lastError")
    assert "decoder error" in text or "bad packet" in text, text
    viewer.wait(
        "(n) => window.gazehdr.video.stats.decoded > n + 3 && window.gazehdr.video.keyed",
        before[1],
    )


def test_a_page_that_cannot_decode_says_why(browser) -> None:
    """Over plain http from another host there is no WebCodecs (not a secure context): the page
    is told why in words it can show, rather than failing on the first packet."""
    page = browser.new_page()
    try:
        serve_checkout_web(page)  # http://viewer.test: not a secure context
        why = page.evaluate("async () => (await import('/video.js')).unsupported('h264')")
        assert why is not None and "secure context" in why and "https" in why, why
        serve_checkout_web(page, origin="http://localhost")
        for name in ("h264", "av1"):
            supported = f"async () => (await import('/video.js')).unsupported('{name}')"
            assert page.evaluate(supported) is None, name
    finally:
        page.close()


def test_the_page_names_the_servers_encodings_and_codecs(browser) -> None:
    """web/protocol.js and web/video.js mirror gazehdr.protocol.Encoding and gazehdr.video's
    WebCodecs names: read from the modules the page loads."""
    page = browser.new_page()
    try:
        serve_checkout_web(page, origin="http://localhost")
        names, codecs = page.evaluate(
            """async () => [(await import('/protocol.js')).ENCODING_NAMES,
                            (await import('/video.js')).CODECS]"""
        )
        assert {int(k): v for k, v in names.items()} == {int(e): e.name for e in Encoding}
        assert {k: c["codec"] for k, c in codecs.items()} == {
            name: c.webcodecs for name, c in CODECS.items()
        }
    finally:
        page.close()
