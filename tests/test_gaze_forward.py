"""A tracker's gaze forwarded to the viewers that warp, against a real server on loopback: a
real gaze daemon connection feeds it, real /ws/view clients receive it (or not)."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import time
from typing import Any

import websockets
from websockets.exceptions import ConnectionClosed

from gazehdr.serve import BackgroundServer
from tests.test_server import Client, run

#: How long the forwarded count may stand still before the warping viewer's socket is taken to
#: be full (its reader stopped): far longer than a note takes to go on loopback.
STALL_S = 2.0
STEP = 0.0002  # between two gazes of the daemon, in frame fractions


async def _daemon(server: BackgroundServer, tracker: str) -> Any:
    """A gaze daemon connection that said hello as `tracker`."""
    d = await websockets.connect(server.ws_url + "/ws/gaze", additional_headers=server.auth)
    await d.send(json.dumps({"type": "hello", "protocol": 1, "tracker": tracker}))
    assert json.loads(await d.recv())["type"] == "welcome"
    return d


def _sample(i: int) -> str:
    """The daemon's i-th gaze: a new place each time, its time i ms on the daemon's clock."""
    x, y = 0.1 + STEP * i, 0.9 - STEP * i
    return json.dumps({"type": "samples", "samples": [{"t": i * 1_000_000, "x": x, "y": y}]})


def _fixation(i: int) -> str:
    """The daemon's i-th gaze as a fixation event (a daemon that sends events)."""
    x, y = 0.1 + STEP * i, 0.9 - STEP * i
    return json.dumps({"type": "event", "kind": "fixation_start", "id": i, "t": i, "x": x, "y": y})


async def _read_for(client: Client, seconds: float) -> int:
    """Read (frames and notes) for `seconds`; how many frames came."""
    frames = [0]
    with contextlib.suppress(asyncio.TimeoutError):
        await asyncio.wait_for(_read_on(client, frames), seconds)
    return frames[0]


async def _read_on(client: Client, frames: list[int] | None = None) -> None:
    """Read on, counting the frames in `frames[0]`."""
    while True:
        got = await client._next()
        if frames is not None:
            frames[0] += got is not None


async def _read_until_gaze(client: Client, index: int) -> int:
    """Read until the note of the daemon's gaze `index` has come; how many frames came."""
    frames = 0
    while not any(_index(g) == index for g in _gazes(client)):
        frames += await client._next() is not None
    return frames


def _gazes(client: Client) -> list[dict[str, Any]]:
    return [n for n in client.notes if n["type"] == "gaze"]


def _index(note: dict[str, Any]) -> int:
    """Which of the daemon's gazes (`_sample`) a note forwards."""
    return round((note["x"] - 0.1) / STEP)


def test_tracker_gaze_goes_to_warping_viewers_only_newest_first(live_server) -> None:
    """With a daemon's tracker as the gaze, a viewer with the warp on gets each of its gazes
    as a `gaze` note while its socket takes them, and once its socket is full only the newest
    (one note may already be on its way): never a queue, and not held back by frames, which
    it does not ack. A viewer of the same session with the warp off gets none."""
    server = live_server(gaze_source="remote:rig")
    forwarded = server.hub.metrics.gaze_forwarded

    async def check() -> None:
        warping = await Client.open(server, max_queue=1)
        session = warping.hello["session"]
        plain = await Client.open(server, f"?session={session}")
        await warping.send(type="warp", on=True)
        reading = asyncio.create_task(_read_on(plain))
        daemon = await _daemon(server, "rig")
        # Each gaze is forwarded as it comes while the socket takes it; the warping viewer
        # reads nothing, so its frames fill the buffers and a send waits, at last.
        sent, stalled_at = 0, None
        deadline = time.monotonic() + 20.0
        while stalled_at is None:
            assert time.monotonic() < deadline, "the warping viewer's socket never filled"
            await daemon.send(_sample(sent))
            sent += 1
            await asyncio.sleep(0.02)  # about a tracker's rate: the frames fill the buffers
            waited = time.monotonic()
            while forwarded.value < sent and time.monotonic() - waited < STALL_S:
                await asyncio.sleep(0.005)
            if forwarded.value < sent:
                stalled_at = sent - 1  # taken from the slot, waiting for the socket
        for _ in range(50):  # while it waits: each replaces the last in the one slot
            await daemon.send(_sample(sent))
            sent += 1
        await asyncio.sleep(0.5)  # handled by the server (its loop is free: nothing waits)
        assert forwarded.value == stalled_at, "the socket was not full after all"
        await _read_until_gaze(warping, sent - 1)
        await daemon.close()
        await plain.ws.close()  # its reader ends with it
        with contextlib.suppress(ConnectionClosed):
            await reading
        warping.ws.transport.abort()  # megabytes of frames still on their way: no handshake
        gazes = _gazes(warping)
        assert [_index(g) for g in gazes] == [*range(stalled_at + 1), sent - 1]
        last = gazes[-1]
        assert abs(last["y"] - (0.9 - STEP * (sent - 1))) < 1e-9 and last["eyes_open"]
        assert all(a["t"] <= b["t"] for a, b in itertools.pairwise(gazes))
        assert not _gazes(plain)
        assert forwarded.value == len(gazes)

    run(check())


def test_warp_on_gets_the_newest_gaze_at_once_beside_held_frames_and_off_none(live_server) -> None:
    """A viewer that turns the warp on gets the tracker's newest gaze straight away (eyes
    closed, a blink: the place the tracker had, as the session holds it); then each new one
    while its frames wait for an ack that does not come (the notes are outside the window);
    turned off, no more."""
    server = live_server(gaze_source="remote:rig")

    async def check() -> None:
        viewer = await Client.open(server)
        daemon = await _daemon(server, "rig")
        await daemon.send(_sample(7))
        await daemon.send(json.dumps({"type": "event", "kind": "blink_start", "id": 1, "t": 8}))
        await _read_for(viewer, 0.5)
        assert not _gazes(viewer)
        await viewer.send(type="warp", on=True)
        note = await viewer.note("gaze")
        assert (_index(note), note["eyes_open"]) == (7, False)
        await viewer.send(type="ack", frame=0)  # flow control on: no frame until the next ack
        await _read_for(viewer, 0.5)
        assert await _read_for(viewer, 0.5) == 0, "frames are not held"
        for i in range(20, 25):
            await daemon.send(_fixation(i))
            assert await _read_until_gaze(viewer, i) == 0
        assert _gazes(viewer)[-1]["eyes_open"]
        await viewer.send(type="warp", on=False)
        await _read_for(viewer, 0.5)
        viewer.notes.clear()
        await daemon.send(_fixation(30))
        await _read_for(viewer, 0.5)
        assert not _gazes(viewer)
        await daemon.close()
        await viewer.ws.close()

    run(check())
