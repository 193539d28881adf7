"""What the late gaze warp costs: bytes per frame and server ms per step, plain frames against
warp layers, side by side in one run (`python -m gazehdr.bench.warp --size 1280x720`); with
`--browser`, the viewer's upload and draw in headless Chromium too (SwiftShader: a CPU's
figures, not a GPU's).

Each round steps one session three ways in turn (plain only, warp only, both), so drift and
other load on the machine fall on all three alike; medians are reported.
"""

from __future__ import annotations

import argparse
import base64
import os
import statistics
import time
from typing import Any

from gazehdr.drivers.cli_args import screen_size_arg
from gazehdr.protocol import Encoding, Gaze
from gazehdr.scenes.library import SceneLibrary
from gazehdr.session import Frame, Session, SessionSettings

MODES = {"plain": (True, False), "warp": (False, True), "both": (True, True)}


def measure_server(size: tuple[int, int], encoding: Encoding, rounds: int) -> dict[str, Any]:
    """Median ms per step (simulation + encoding, as the frame header's server_ms), the CPU
    time of this process's threads in it (PoCL's included: less sensitive to other load on the
    machine than the wall clock) and bytes per frame message, per mode; the flash scene with
    the gaze moving, so afterimages show."""
    settings = SessionSettings(
        width=size[0], height=size[1], scene="flash", encoding=encoding, fit_viewport=False
    )
    session = Session("bench", settings, SceneLibrary(), clock=time.perf_counter)
    ms: dict[str, list[float]] = {m: [] for m in MODES}
    cpu: dict[str, list[float]] = {m: [] for m in MODES}
    sizes: dict[str, int] = {}
    for k in range(rounds + 1):
        for i, (mode, (plain, warp)) in enumerate(MODES.items()):
            session.pointer.take(Gaze(0.3 + 0.04 * (k % 10), 0.45, 3 * k + i + 1), 0.0)
            started = time.process_time()
            frame, _ = session.tick(1 / 60, [], plain=plain, warp=warp)
            if k:  # the first round builds kernels and buffers
                ms[mode].append(frame.header.server_ms)
                cpu[mode].append((time.process_time() - started) * 1e3)
            sizes[mode] = _bytes(frame, plain, warp)
    return {
        m: {"ms": statistics.median(ms[m]), "cpu_ms": statistics.median(cpu[m]), "bytes": n}
        for m, n in sizes.items()
    }


def _bytes(frame: Frame, plain: bool, warp: bool) -> int:
    messages = ([frame.message(0)] if plain else []) + ([frame.message(0, True)] if warp else [])
    return sum(len(m) for m in messages if m is not None)


BROWSER_JS = """
async ([plainB64, warpB64, draws]) => {
  const { Renderer } = await import('/renderer.js');
  const { decodeFrame } = await import('/protocol.js');
  const out = {};
  for (const [name, b64] of [['plain', plainB64], ['warp', warpB64]]) {
    const buffer = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0)).buffer;
    const canvas = document.createElement('canvas');
    const { header } = decodeFrame(buffer);
    [canvas.width, canvas.height] = [header.width, header.height];
    const r = new Renderer(canvas);
    const gl = r.gl;
    const up = [], draw = [];
    const px = new Uint8Array(4);
    const sync = () => gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px); // waits for all
    for (let k = 0; k < draws; k++) {
      sync();
      let t = performance.now();
      const { header: h, pixels } = decodeFrame(buffer);
      r.upload(h.width, h.height, h.encoding, pixels);
      sync();
      up.push(performance.now() - t);
      t = performance.now();
      r.draw(k, { x: 0.3 + 0.01 * k, y: 0.5 });
      sync();
      draw.push(performance.now() - t);
    }
    const med = (a) => a.sort((x, y) => x - y)[a.length >> 1];
    out[name] = { upload_ms: med(up), draw_ms: med(draw) };
  }
  return out;
}
"""


def measure_browser(size: tuple[int, int], encoding: Encoding, draws: int) -> dict[str, Any]:
    """Median ms to decode + upload a frame and to draw it (a 1-pixel read-back after each
    waits for the GL work: gl.finish need not) in headless
    Chromium, plain against warp; Chromium as tests/browser.py starts it."""
    from playwright.sync_api import sync_playwright

    from gazehdr.bench.live import CHROMIUM, CHROMIUM_ARGS, serve_web

    settings = SessionSettings(
        width=size[0], height=size[1], scene="flash", encoding=encoding, fit_viewport=False
    )
    session = Session("bench", settings, SceneLibrary(), clock=time.perf_counter)
    session.tick(0.1, [])
    frame, _ = session.tick(1 / 60, [], plain=True, warp=True)
    plain, warp = frame.message(0), frame.message(0, True)
    assert plain is not None and warp is not None
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page()
            serve_web(page)
            b64 = [base64.b64encode(m).decode() for m in (plain, warp)]
            return page.evaluate(BROWSER_JS, [*b64, draws])
        finally:
            browser.close()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m gazehdr.bench.warp", description=__doc__)
    parser.add_argument("--size", type=screen_size_arg, default="1280x720")
    parser.add_argument("--encoding", default="rgb10a2", choices=("f16", "rgb10a2"))
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--browser", action="store_true", help="also the viewer's cost")
    args = parser.parse_args(argv)
    size = args.size
    encoding = Encoding[args.encoding]
    print(f"{size[0]}x{size[1]}, plain frames {args.encoding}, {os.cpu_count()} CPUs")
    for mode, r in measure_server(size, encoding, args.rounds).items():  # type: ignore[arg-type]
        ms, cpu, mb = r["ms"], r["cpu_ms"], r["bytes"] / 1e6
        print(f"server {mode:5s}: {ms:6.1f} ms/step ({cpu:6.1f} ms CPU)  {mb:6.2f} MB/frame")
    if args.browser:
        for name, r in measure_browser(size, encoding, 10).items():  # type: ignore[arg-type]
            up, draw = r["upload_ms"], r["draw_ms"]
            print(f"browser {name:5s}: upload {up:6.1f} ms  draw {draw:6.1f} ms")


if __name__ == "__main__":
    main()
