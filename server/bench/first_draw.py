"""`python -m gazehdr.bench.first_draw`: how long a new tab takes to draw its first frame.

It starts a real server (uvicorn on loopback, kernels built first, as `serve` does), optionally
beside `--burn N` processes that each keep a core busy, and opens the viewer in new tabs of
headless Chromium (Debian's, driven by Playwright) one after another, each a new session. For
each tab it prints when, from the navigation, the page opened its WebSocket, heard the
session's hello, received the first frame and drew it (the page's own clock).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Marks the page's times (performance.now()): its WebSocket made and opened, the first text
#: message (the hello), the first binary one (a frame), and the first frame drawn.
MARKS = """
window.__marks = {};
const Real = window.WebSocket;
window.WebSocket = function (...args) {
  const ws = new Real(...args);
  window.__marks.socket ??= performance.now();
  ws.addEventListener('open', () => (window.__marks.open ??= performance.now()));
  ws.addEventListener('message', (e) => {
    const kind = typeof e.data === 'string' ? 'hello' : 'frame';
    window.__marks[kind] ??= performance.now();
  });
  return ws;
};
window.WebSocket.prototype = Real.prototype;
const drawn = () => {
  if (window.gazehdr?.shown) window.__marks.drawn = performance.now();
  else requestAnimationFrame(drawn);
};
requestAnimationFrame(drawn);
"""
STEPS = ("socket", "open", "hello", "frame", "drawn")


def measure(tabs: int, burn: int, size: tuple[int, int]) -> list[dict[str, float]]:
    """Each tab's marks, ms from its navigation."""
    from playwright.sync_api import sync_playwright

    from gazehdr.app import ServerConfig
    from gazehdr.bench.live import CHROMIUM, CHROMIUM_ARGS
    from gazehdr.serve import BackgroundServer, build_kernels
    from gazehdr.session import SessionSettings

    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(burn)]
    settings = SessionSettings(width=size[0], height=size[1])
    build_kernels(settings)
    config = ServerConfig(session=settings, data_dir=Path(tempfile.mkdtemp()), token="bench",
                          session_grace_s=0.0)  # fmt: skip
    server = BackgroundServer(config)
    rows = []
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            for _ in range(tabs):
                page = browser.new_page(viewport={"width": 960, "height": 540})
                page.add_init_script(MARKS)
                page.goto(server.url + "/")
                page.wait_for_function("() => window.__marks.drawn", timeout=60_000)
                rows.append(page.evaluate("() => window.__marks"))
                page.close()
                time.sleep(0.5)  # the session ends with its tab
            browser.close()
    finally:
        server.stop()
        for b in burners:
            b.kill()
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gazehdr.bench.first_draw", description=__doc__)
    parser.add_argument("--tabs", type=int, default=5, help="new tabs, one after another")
    parser.add_argument("--burn", type=int, default=1, help="CPU-burning processes beside")
    parser.add_argument("--size", default="640x360", help="the sessions' frame budget, WxH")
    args = parser.parse_args(argv)
    w, h = (int(x) for x in args.size.split("x"))
    rows = measure(args.tabs, args.burn, (w, h))
    print(f"{args.tabs} new tabs, {args.burn} CPU burner(s), {w}x{h}: ms from navigation")
    print("  ".join(f"{s:>7}" for s in STEPS))
    for row in rows:
        print("  ".join(f"{row.get(s, float('nan')):7.0f}" for s in STEPS))
    print(f"median first draw {statistics.median(r['drawn'] for r in rows):.0f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
