"""Server memory over sessions, measured on a real `gazehdr serve` process.

    .venv/bin/python tests/session_memory.py [--sessions 8] [--viewers 30] [--size 640x360]

Starts `gazehdr serve --port 0` in a subprocess, reads its resident memory (VmRSS in
/proc/PID/status) idle after one warm-up session (kernels are built once per process: that is
the baseline), while SESSIONS sessions run (VIEWERS new viewers connect at once, the server
keeps at most 8 sessions), and after every session ended. Prints idle / peak / after and
whether `after` is within 10% of `idle`; exits 1 when it is not.
"""

from __future__ import annotations

import argparse
import asyncio
import functools
import json
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import websockets

TOKEN = "session-memory"  # the credential the measured server is started with


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


def settled_rss(pid: int, timeout: float = 10.0) -> float:
    """RSS once it stops falling (a session's memory goes back just after its end is
    announced: its last step finishes, then the heap is trimmed), at most `timeout` s."""
    deadline = time.monotonic() + timeout
    last, steady = rss_mib(pid), 0
    while time.monotonic() < deadline and steady < 4:  # unchanged (within 1 MiB) for 2 s
        time.sleep(0.5)
        now = rss_mib(pid)
        steady = steady + 1 if abs(now - last) < 1 else 0
        last = now
    return last


def health(url: str) -> dict:
    with urllib.request.urlopen(f"{url}/api/health", timeout=10) as r:
        return json.loads(r.read())


def wait_sessions(url: str, n: int, timeout: float = 60.0) -> None:
    """Poll the server (a benchmark, not a test) until it runs `n` sessions."""
    deadline = time.monotonic() + timeout
    while health(url)["sessions"] != n:
        if time.monotonic() > deadline:
            raise RuntimeError(f"the server still runs {health(url)['sessions']} sessions")
        time.sleep(0.2)


async def viewer(ws_url: str, frames: int, hold: asyncio.Event) -> str:
    """Connect, take `frames` frames, wait for `hold`, leave. Returns 'ok' or the close reason."""
    try:
        auth = {"Authorization": f"Bearer {TOKEN}"}
        async with websockets.connect(
            f"{ws_url}/ws/view", max_size=None, additional_headers=auth
        ) as ws:
            got = 0
            while got < frames:
                if isinstance(await ws.recv(), bytes):
                    got += 1
            await hold.wait()
            return "ok"
    except websockets.ConnectionClosed as e:
        return f"closed {e.rcvd.code if e.rcvd else None}: {e.rcvd.reason if e.rcvd else ''}"


async def crowd(ws_url: str, n: int, frames: int, on_peak) -> list[str]:
    hold = asyncio.Event()
    tasks = [asyncio.create_task(viewer(ws_url, frames, hold)) for _ in range(n)]
    # Everyone admitted has its frames (or was refused) once all but the refused wait on hold.
    while sum(t.done() for t in tasks) + _waiting(tasks, hold) < n:
        await asyncio.sleep(0.1)
    on_peak()
    hold.set()
    return list(await asyncio.gather(*tasks))


def _waiting(tasks, hold: asyncio.Event) -> int:
    return len(hold._waiters)  # type: ignore[attr-defined]  (a benchmark's shortcut)


def _note_rss(into: list[float], pid: int) -> None:
    into.append(rss_mib(pid))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--viewers", type=int, default=30)
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=1)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as data:
        cmd = [sys.executable, "-m", "gazehdr", "serve", "--port", "0", "--size", args.size,
               "--data-dir", data, "--fps", "30", "--token", TOKEN]  # fmt: skip
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
        try:
            first = proc.stdout.readline()
            url = first.split("open ")[1].split("/ (")[0]
            ws_url = url.replace("http://", "ws://")
            deadline = time.monotonic() + 30
            while True:
                try:
                    health(url)
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.1)
            start = rss_mib(proc.pid)
            asyncio.run(crowd(ws_url, 1, args.frames, lambda: None))
            wait_sessions(url, 0)
            idle = settled_rss(proc.pid)
            print(f"start {start:.0f} MiB; idle after one warm-up session {idle:.0f} MiB")
            for r in range(args.rounds):
                peak: list[float] = []
                on_peak = functools.partial(_note_rss, peak, proc.pid)
                outcome = asyncio.run(crowd(ws_url, args.viewers, args.frames, on_peak))
                wait_sessions(url, 0)
                after = settled_rss(proc.pid)
                ok = outcome.count("ok")
                refused = sorted(set(o for o in outcome if o != "ok"))
                print(f"round {r + 1}: {args.viewers} viewers at once: {ok} served, "
                      f"{len(outcome) - ok} refused {refused}")  # fmt: skip
                print(f"  idle {idle:.0f} MiB / with sessions {peak[0]:.0f} MiB / "
                      f"after {after:.0f} MiB ({100 * (after / idle - 1):+.1f}%)")  # fmt: skip
            return 0 if after <= 1.1 * idle else 1
        finally:
            proc.terminate()
            proc.wait(timeout=30)


if __name__ == "__main__":
    sys.exit(main())
