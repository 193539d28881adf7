"""`gazehdr bench-live`: the live path measured end to end, server and a real browser.

For each frame size and encoding it starts a real server (uvicorn on loopback), opens the viewer
in headless Chromium (Debian's, driven by Playwright), moves the mouse every 100 ms, and reports
over the same window: frames per second delivered to the page, bytes per frame, the server's time
per frame split into simulation, encoding and sending, and the latency from a pointer move to
the first frame that used it, as the page measured it (p50, p95). The same run with a plain
WebSocket client instead of the browser separates the browser's own cost (on a 2-core machine
Chromium's software WebGL competes with the simulation for the CPU); that client
(gazehdr.bench.frame_client: each message read once, into one buffer, as a browser's network
stack does) runs in this process (`socket`, sharing the server's interpreter) or in one of its
own (`process`, as a browser does).

The streams (`h264`, `av1`: gazehdr.video) are a viewer's choice: the session simulates
`rgb10a2`, the page opens with `?encoding=h264`, the socket client asks for it, acks each frame
as the page does and decodes every packet (FFmpeg's h264 and dav1d, as Chromium); frames per
second count decoded pictures. `--link-mbit` runs the whole benchmark over a capped link
(gazehdr.bench.netlink: a network namespace whose loopback `tc` shapes), so the raw encodings
and the streams are compared over the same link.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from gazehdr.bench import netlink
from gazehdr.bench.frame_client import FrameClient
from gazehdr.drivers.cli_args import size_list_arg
from gazehdr.protocol import RAW, Encoding, split_frame

CHROMIUM = os.environ.get("GAZEHDR_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless=new", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]  # fmt: skip


def serve_web(page: Any, origin: str = "http://viewer.test", web_dir: Path | None = None) -> str:
    """Serve the viewer's files (`web_dir`, default the installed viewer) to a Playwright
    `page` under a made-up origin, with no server (the shaders need none), and open a blank
    page there. WebCodecs needs a secure context: `http://localhost` is one."""
    from gazehdr.viewer import default_web_dir

    root = (web_dir or default_web_dir()).resolve()
    types = {".js": "text/javascript", ".html": "text/html", ".css": "text/css"}

    def handle(route: Any) -> None:
        path = route.request.url[len(origin) :].split("?")[0].lstrip("/") or "blank.html"
        file = root / path
        if path == "blank.html":
            route.fulfill(body="<!doctype html><title>blank</title>", content_type="text/html")
        elif file.is_file() and root in file.resolve().parents:
            route.fulfill(body=file.read_bytes(), content_type=types.get(file.suffix, "text/plain"))
        else:
            route.fulfill(status=404, body="not found")

    page.route(f"{origin}/**", handle)
    page.goto(f"{origin}/blank.html")
    return origin


def _server_snapshot(metrics) -> dict[str, float]:
    return {
        "at": time.monotonic(),
        "frames": metrics.frames_sent.value,
        "bytes": metrics.bytes_sent.value,
        "sim_s": metrics.sim_seconds.total,
        "sim_n": metrics.sim_seconds.n,
        "enc_s": metrics.encode_seconds.total + metrics.stream_encode_seconds.total,
        "send_s": metrics.send_seconds.total,
        "send_n": metrics.send_seconds.n,
        "gaze_s": metrics.gaze_latency.total,
        "gaze_n": metrics.gaze_latency.n,
    }


def _server_figures(before: dict[str, float], after: dict[str, float]) -> dict[str, float]:
    d = {k: after[k] - before[k] for k in before}
    n, sent = max(d["sim_n"], 1), max(d["frames"], 1)
    return {
        "bytes_per_frame": d["bytes"] / sent,
        "sim_ms": 1e3 * d["sim_s"] / n,
        "encode_ms": 1e3 * d["enc_s"] / n,
        "send_ms": 1e3 * d["send_s"] / max(d["send_n"], 1),
        # Steps the session made a second in the same window: below the setting where steps ran
        # more than an interval late (`live.next_due`); a client's fps below this where its
        # mailbox replaced frames it had not taken.
        "steps_per_s": d["sim_n"] / max(d["at"], 1e-9),
        # From a gaze reaching the server to its first frame handed to the socket (a mean).
        "server_lat_ms": 1e3 * d["gaze_s"] / max(d["gaze_n"], 1),
    }


def _percentiles(values: list[float]) -> tuple[float, float]:
    if len(values) < 2:
        return (values[0], values[0]) if values else (float("nan"), float("nan"))
    q = statistics.quantiles(values, n=20, method="inclusive")
    return statistics.median(values), q[18]


def run_browser(
    live, size: tuple[int, int], seconds: float, warmup: float, encoding: Encoding
) -> dict[str, float]:
    from playwright.sync_api import sync_playwright

    w, h = size
    stream = encoding not in RAW
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": w, "height": h})
        page.goto(live.url + (f"/?encoding={encoding.name}" if stream else "/"))
        page.wait_for_function("window.gazehdr && window.gazehdr.stats.received > 2", timeout=180e3)
        if stream:
            page.wait_for_function("window.gazehdr.video.stats.decoded > 2", timeout=180e3)
        rng = random.Random(0)

        def wiggle(duration: float) -> None:
            end = time.monotonic() + duration
            while time.monotonic() < end:
                page.mouse.move(rng.uniform(0.1, 0.9) * w, rng.uniform(0.1, 0.9) * h)
                page.wait_for_timeout(100)

        wiggle(warmup)
        count = "window.gazehdr.video.stats.decoded" if stream else "s.received"
        read = f"(() => {{ const s = window.gazehdr.stats; return [{count}, s.latency.total] }})()"
        received0, lat0 = page.evaluate(read)
        before, t0 = _server_snapshot(live.metrics), time.monotonic()
        latencies: list[float] = []
        seen = lat0
        while time.monotonic() - t0 < seconds:
            wiggle(0.5)
            total, values = page.evaluate(
                "(() => { const l = window.gazehdr.stats.latency; return [l.total, l.values] })()"
            )
            fresh = min(total - seen, len(values))
            latencies += values[len(values) - fresh :] if fresh else []
            seen = total
        elapsed = time.monotonic() - t0
        received1, _ = page.evaluate(read)
        after = _server_snapshot(live.metrics)
        browser.close()
    p50, p95 = _percentiles(latencies)
    return {
        "fps": (received1 - received0) / elapsed,
        "lat_p50": p50,
        "lat_p95": p95,
        "lat_n": len(latencies),
        **_server_figures(before, after),
    }


def run_socket(live, seconds: float, warmup: float, encoding: Encoding) -> dict[str, float]:
    """The plain WebSocket client on this process's main thread, beside the server's threads."""
    marks: dict[str, dict[str, float]] = {}

    def mark(event: str) -> None:
        marks[event] = _server_snapshot(live.metrics)

    client = _socket_client(live.ws_url, live.auth, seconds, warmup, encoding, mark)
    figures = asyncio.run(client)
    return {**figures, **_server_figures(marks["warm"], marks["done"])}


def run_socket_process(live, seconds: float, warmup: float, encoding: Encoding) -> dict[str, float]:
    """The same client in a process of its own, as a browser is: it shares the CPU, not the
    server's interpreter (its GIL)."""
    import multiprocessing

    spawn = multiprocessing.get_context("spawn")
    ours, theirs = spawn.Pipe()
    args = (theirs, live.ws_url, live.auth, seconds, warmup, encoding)
    child = spawn.Process(target=_socket_process, args=args, daemon=True)
    child.start()
    marks: dict[str, dict[str, float]] = {}
    try:
        while True:
            if not ours.poll(seconds + warmup + 60):
                raise RuntimeError("the socket client process stopped answering")
            event, figures = ours.recv()
            if event == "figures":
                break
            marks[event] = _server_snapshot(live.metrics)
    finally:
        child.join(10)
        if child.is_alive():
            child.kill()
    return {**figures, **_server_figures(marks["warm"], marks["done"])}


def _socket_process(conn, url: str, auth, seconds: float, warmup: float, encoding: Encoding):
    def mark(event: str) -> None:
        conn.send((event, None))

    figures = asyncio.run(_socket_client(url, auth, seconds, warmup, encoding, mark))
    conn.send(("figures", figures))


async def _socket_client(
    url: str, auth, seconds: float, warmup: float, encoding: Encoding, mark
) -> dict[str, float]:
    """Frames per second and pointer-to-frame latency as a plain client sees them; `mark` is
    called with "warm" when the timed window starts and "done" when it ends (the server's
    figures are taken there)."""
    from gazehdr.video import Decoder

    async with await FrameClient.connect(f"{url}/ws/view", auth) as ws:
        stream = encoding not in RAW
        decoder = Decoder(encoding.name) if stream else None
        decode_s, lost = 0.0, 0
        if stream:
            await ws.send(json.dumps({"type": "encoding", "name": encoding.name}))
        sent: dict[int, float] = {}
        latencies: list[float] = []
        frames, t0 = 0, None
        pointer = asyncio.create_task(_move_pointer(ws, sent))
        start = time.monotonic()
        while True:
            now = time.monotonic()
            if t0 is None and now - start >= warmup:
                t0, frames = now, 0
                mark("warm")
            if t0 is not None and now - t0 >= seconds:
                break
            message = await ws.recv()
            if isinstance(message, str):
                continue
            header, payload = split_frame(message)
            if decoder is not None:
                await ws.send(json.dumps({"type": "ack", "frame": header.frame}))
                started = time.perf_counter()
                try:
                    decoder.planes(bytes(payload), header.keyframe)
                except ValueError:  # a gap or a bad packet: as the page does
                    lost += 1
                    await ws.send(json.dumps({"type": "keyframe"}))
                    continue
                finally:
                    decode_s += time.perf_counter() - started
            if header.encoding is not encoding:
                continue  # raw frames made before the choice took effect
            frames += 1
            if header.gaze_seq in sent and t0 is not None:
                latencies.append(1e3 * (time.monotonic() - sent.pop(header.gaze_seq)))
            for old in [s for s in sent if s < header.gaze_seq]:
                sent.pop(old)
        elapsed = time.monotonic() - t0
        mark("done")
        pointer.cancel()
    p50, p95 = _percentiles(latencies)
    return {
        "fps": frames / elapsed,
        "lat_p50": p50,
        "lat_p95": p95,
        "lat_n": len(latencies),
        "decode_ms": 1e3 * decode_s / max(frames, 1),
        "lost": lost,
    }


async def _move_pointer(ws, sent: dict[int, float]) -> None:
    """Pointer moves every 100 ms on average, at times of their own (a hand's are not in step
    with the frames: a move sent just as a frame arrives would wait a fixed part of a step),
    each noted in `sent` by its seq."""
    rng = random.Random(0)
    seq = 0
    while True:
        await asyncio.sleep(rng.uniform(0.05, 0.15))
        seq += 1
        sent[seq] = time.monotonic()
        gaze = {"type": "gaze", "x": rng.random(), "y": rng.random(), "seq": seq}
        await ws.send(json.dumps(gaze))


def _choices(parser: argparse.ArgumentParser, flag: str, text: str, known: tuple) -> list[str]:
    """`text` split at commas, each one of `known`, or the parser's error naming the flag."""
    picked = text.split(",")
    if any(v not in known for v in picked):
        parser.error(f"{flag} takes a comma-separated list of {', '.join(known)}, not {text!r}")
    return picked


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="gazehdr bench-live", description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=size_list_arg, default="1280x720,1920x1080")
    parser.add_argument("--encodings", default="f16,rgb10a2")
    parser.add_argument(
        "--clients",
        default="browser,socket",
        help="browser (headless Chromium), socket (a plain WebSocket client in this process), "
        "process (the same in a process of its own); default browser,socket",
    )
    parser.add_argument("--scene", default="lamp")
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--warmup", type=float, default=3.0)
    parser.add_argument(
        "--late-gaze",
        default="on",
        help="on, off or on,off: frames from the gaze read once the step is simulated "
        "(SessionSettings.late_gaze), or from the one it started with; both compares them",
    )
    parser.add_argument(
        "--link-mbit",
        type=float,
        help="run over a link of this many Mbit/s (a network namespace, loopback shaped by tc)",
    )
    parser.add_argument("--link-delay-ms", type=float, default=0.0, help="and this delay each way")
    args = parser.parse_args(argv)
    clients = _choices(parser, "--clients", args.clients, ("browser", "socket", "process"))
    lates = _choices(parser, "--late-gaze", args.late_gaze, ("on", "off"))
    if args.link_mbit and netlink.link() is None:
        import sys

        return netlink.run_capped(
            args.link_mbit, args.link_delay_ms, sys.argv[1:] if argv is None else argv
        )

    from gazehdr.app import ServerConfig
    from gazehdr.serve import BackgroundServer
    from gazehdr.session import SessionSettings

    print(f"link: {netlink.link() or 'loopback, not shaped'}")
    print(
        f"{'size':>10} {'encoding':>8} {'client':>7} {'late':>4} {'fps':>6} {'steps/s':>7} "
        f"{'KiB/frame':>10} "
        f"{'sim ms':>7} {'enc ms':>7} {'send ms':>7} {'lat p50':>8} {'lat p95':>8} {'n':>4} "
        f"{'srv lat':>7} "
        f"{'Mbit/s':>7} {'dec ms':>7} {'lost':>4}"
    )
    runs = [
        (size, encoding, client, late)
        for size in args.sizes
        for encoding in args.encodings.split(",")
        for client in clients
        for late in lates
    ]
    for size, encoding, client, late in runs:
        chosen = Encoding[encoding]
        settings = SessionSettings(
            width=size[0], height=size[1], fps=args.fps, scene=args.scene,
            encoding=chosen if chosen in RAW else Encoding.rgb10a2, fit_viewport=False,
            late_gaze=late == "on",
        )  # fmt: skip
        with tempfile.TemporaryDirectory() as data:
            live = BackgroundServer(ServerConfig(session=settings, data_dir=Path(data)))
            try:
                if client == "browser":
                    r = run_browser(live, size, args.seconds, args.warmup, chosen)
                else:
                    run = run_socket if client == "socket" else run_socket_process
                    r = run(live, args.seconds, args.warmup, chosen)
            finally:
                live.stop()
        print(
            f"{size[0]:>5}x{size[1]:<4} {encoding:>8} {client:>7} {late:>4} {r['fps']:6.1f} "
            f"{r['steps_per_s']:7.1f} "
            f"{r['bytes_per_frame'] / 1024:10.0f} {r['sim_ms']:7.1f} "
            f"{r['encode_ms']:7.2f} {r['send_ms']:7.2f} {r['lat_p50']:8.0f} "
            f"{r['lat_p95']:8.0f} {r['lat_n']:4d} {r['server_lat_ms']:7.1f} "
            f"{r['bytes_per_frame'] * 8 * r['fps'] / 1e6:7.1f} "
            f"{r.get('decode_ms', float('nan')):7.2f} {r.get('lost', 0):4d}",
            flush=True,
        )
    return 0


if __name__ == "__main__":  # what gazehdr.bench.netlink runs in its namespace
    raise SystemExit(main())
