"""The HID tracker path through a real Linux kernel: uhid devices in a QEMU guest, read by the
unchanged `gazehdr devices` and `gazehdr daemon` through hidapi's hidraw backend, streaming to
a real server on the host (tests/hid_kernel/run.py says how the guest is made).

Left out of the default run (pyproject.toml: the `hid_kernel` marker); run them with

    .venv/bin/python -m pytest -m hid_kernel

where Debian's qemu-system-x86, linux-image-amd64 and busybox-static are installed. One guest
is booted for the module; each test plugs its own virtual devices.
"""

from __future__ import annotations

import asyncio
import errno
import itertools
import math
import random
import re
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from hid_kernel.descriptors import LIARS, Tracker, fake_tracker, hut_tracker
from hid_kernel.run import HOST_FROM_GUEST, Guest

from gazehdr import gaze_link
from gazehdr.drivers import wire
from gazehdr.drivers.sessionlog import read_session_log
from gazehdr.serve import BackgroundServer

pytestmark = [pytest.mark.hid_kernel, pytest.mark.slow, pytest.mark.timeout(900)]

NAME = "kernel-tracker"  # the daemon's --name: sessions follow remote:NAME
SCREEN_PX = (1920, 1080)
PERIOD_NS = 8_333_333  # the schedule: 120 Hz of the guest's clock
STEP_US = 8_333  # the tracker's own clock between two samples (40 ppm slow: a real crystal)
PX = 1.0  # positions must arrive within one pixel
#: How long after its hidraw node opened the daemon may take to be ready (TCG: imports, hid-tools).
READY_TIMEOUT_S = 240.0


@pytest.fixture(scope="module")
def guest() -> Iterator[Guest]:
    with Guest() as g:
        yield g


# --- the host's side: what the server got -------------------------------------------------------


@dataclass
class Tap:
    """Everything the server's /ws/gaze handled, with the host time it came (monotonic ns)."""

    samples: list[tuple[int, wire.Sample]]
    events: list[tuple[int, wire.Event]]
    hellos: list[wire.Hello]


@pytest.fixture
def tap(monkeypatch: pytest.MonkeyPatch) -> Tap:
    got = Tap([], [], [])
    handle = gaze_link.GazeLink.handle

    def tapped(self: gaze_link.GazeLink, msg: wire.Message, now: float) -> Any:
        at = time.monotonic_ns()
        if isinstance(msg, wire.Samples):
            got.samples += [(at, s) for s in msg.samples]
        elif isinstance(msg, wire.Event):
            got.events.append((at, msg))
        elif isinstance(msg, wire.Hello):
            got.hellos.append(msg)
        return handle(self, msg, now)

    monkeypatch.setattr(gaze_link.GazeLink, "handle", tapped)
    return got


class ViewerThread:
    """A viewer on /ws/view with the late warp on, in a thread of its own: it keeps the
    tracker's gaze notes and the gaze of each frame header it receives."""

    def __init__(self, server: BackgroundServer) -> None:
        from tests.test_server import Client

        self.server, self.client_class = server, Client
        self.notes: list[dict[str, Any]] = []
        self.frames: list[tuple[float, float, float]] = []  # (host s, gaze_x, gaze_y)
        self.session: str | None = None
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self._thread.start()

    async def _run(self) -> None:
        try:
            client = await self.client_class.open(self.server)
            self.session = client.hello["session"]
            await client.send(type="warp", on=True)
            while not self._stop.is_set():
                try:
                    got = await asyncio.wait_for(client._next(), 0.5)
                except asyncio.TimeoutError:
                    continue
                if got is not None:
                    self.frames.append((time.monotonic(), got[0].gaze_x, got[0].gaze_y))
                self.notes += [n for n in client.notes if n["type"] == "gaze"]
                client.notes.clear()
            await client.ws.close()
        except BaseException as e:  # reported by stop()
            self.error = e

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=30)
        if self.error is not None:
            raise self.error


# --- the guest's side ---------------------------------------------------------------------------


def plug(guest: Guest, dev: str, tracker: Tracker, **extra: Any) -> str | None:
    """Plug `tracker` in as `dev` (`extra`: the agent's `plug` arguments, such as `product`,
    `errors`, `silent`); its hidraw node, or None when the kernel refused it."""
    args = {
        "descriptor": tracker.descriptor.hex(),
        "features": {str(k): v.hex() for k, v in tracker.features.items()},
        "errors": {str(k): v for k, v in tracker.errors.items()},
        "silent": sorted(tracker.silent),
        "name": dev,
        **extra,
    }
    return guest.call("plug", dev=dev, **args)["hidraw"]


def events(guest: Guest, dev: str) -> list[dict[str, Any]]:
    return guest.call("events", dev=dev)["events"]


def start_daemon(guest: Guest, server: BackgroundServer, dev: str) -> None:
    """`gazehdr daemon --source hid` in the guest, recording to /tmp/DEV.jsonl; returns once
    the server has its hello and the daemon has set the tracker's Device Mode (it reads reports
    from then on)."""
    guest.call(
        "spawn",
        name="daemon",
        argv=[
            "gazehdr", "daemon", "--source", "hid", "--name", NAME,
            "--server", f"ws://{HOST_FROM_GUEST}:{server.port}", "--token", server.token,
            "--screen", f"{SCREEN_PX[0]}x{SCREEN_PX[1]}", "--record", f"/tmp/{dev}.jsonl",
        ],
    )  # fmt: skip
    deadline = time.monotonic() + READY_TIMEOUT_S
    while True:
        feed = server.hub.trackers.sole_connected()
        if feed is not None and any(e["kind"] == "set_report" for e in events(guest, dev)):
            return
        state = guest.call("poll", name="daemon")
        assert state["rc"] is None, f"the daemon exited {state['rc']}:\n{state['stderr']}"
        assert time.monotonic() < deadline, f"the daemon never got ready:\n{state['stderr']}"
        time.sleep(0.5)


def stop_daemon(guest: Guest) -> dict[str, Any]:
    done = guest.call("stop", name="daemon", timeout=60)
    assert done["rc"] == 0, done["stderr"]
    assert "Traceback" not in done["stderr"], done["stderr"]
    return done


@dataclass
class Planned:
    """The reports of a schedule: where each looks (µm), its schedule time (ns after the start,
    without the write jitter) and which fixation of the plan it belongs to (-1: none)."""

    gaze_um: list[tuple[int, int]]
    nominal_ns: list[int]
    fixation: list[int]
    segment: list[int]


def px(gaze_um: tuple[int, int], screen_um: tuple[int, int]) -> tuple[float, float]:
    return (gaze_um[0] / screen_um[0] * SCREEN_PX[0], gaze_um[1] / screen_um[1] * SCREEN_PX[1])


def near(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return abs(a[0] - b[0]) <= PX and abs(a[1] - b[1]) <= PX


def offset_between(guest: Guest, before: tuple[int, int], t_ns: int) -> tuple[int, int]:
    """The host − guest clock offset at host time `t_ns`, interpolated between `before` (taken
    then) and one taken now: (offset, uncertainty)."""
    after = guest.clock_offset()
    return (before[0] + after[0]) // 2, max(before[1], after[1]) + abs(after[0] - before[0])


# --- gazehdr devices ----------------------------------------------------------------------------


def test_devices_lists_the_virtual_trackers_and_says_why_not_the_liars(guest: Guest) -> None:
    """Through the kernel: two trackers (the hand-written one from the usage tables, the fake
    layer's), one whose Configuration report fails (EIO) and whose Capabilities report is never
    answered (the kernel gives up after 5 s), and the devices whose descriptors lie. `gazehdr
    devices` opens each tracker, reads its feature reports from the uhid process, leaves its
    Device Mode alone, and says why each other device cannot be used; the device whose Report
    Size the kernel refuses gets no hidraw node at all."""
    guest.call("dmesg")
    hut, fake = hut_tracker(), fake_tracker()
    mute = Tracker("mute", hut.descriptor, hut.features, hut.screen_um, 120.0)
    nodes = {
        "hut": plug(guest, "hut", hut, product=0x0A01),
        "fake": plug(guest, "fake", fake, product=0x0A02),
        "mute": plug(guest, "mute", mute, product=0x0A03, errors={"3": errno.EIO}, silent=[2]),
    }
    for liar in LIARS:
        lying = Tracker(liar.name, liar.descriptor, {}, (1, 1), 0.0)
        nodes[liar.name] = plug(guest, liar.name, lying, product=liar.product)
    try:
        kernel_log = "\n".join(guest.call("dmesg")["lines"])
        assert nodes["oversized-field"] is None, kernel_log
        assert "invalid report_size 300" in kernel_log
        assert all(node for name, node in nodes.items() if name != "oversized-field"), nodes

        done = guest.call("run", argv=["gazehdr", "devices"], timeout=300)
        out = done["stdout"]
        assert done["rc"] == 0, out + done["stderr"]
        lines = {name: [ln for ln in out.splitlines() if f"{node} " in ln] for name, node in
                 nodes.items() if node}  # fmt: skip
        assert lines["hut"] == [
            f"ok   {nodes['hut']} 2104:0a01 hut: eye tracker, calibrated screen 597.0 × 336.0 mm, "
            "120 Hz"
        ], out
        assert lines["fake"] == [
            f"ok   {nodes['fake']} 2104:0a02 fake: eye tracker, calibrated screen 527.0 × 296.5 "
            "mm, 120 Hz"
        ], out
        assert lines["mute"] == [
            f"ok   {nodes['mute']} 2104:0a03 mute: eye tracker, no calibrated screen size (the "
            "screen geometry is used), 120 Hz"
        ], out
        assert "feature report 3: " in done["stderr"] and "feature report 2: " in done["stderr"]
        for liar in LIARS:
            if liar.says is not None:
                (line,) = lines[liar.name]
                assert line.startswith(f"skip {nodes[liar.name]} ") and liar.says in line, out
        listed = [ln for ln in out.splitlines() if ln.startswith(("ok ", "skip "))]
        assert len(listed) == len(nodes) - 1, out  # all but the one the kernel refused

        # What the kernel passed to the devices: every feature report asked for, none sent.
        for name, ids in (("hut", [2, 3, 4, 5]), ("fake", [0x11, 0x12, 0x13, 0x14])):
            got = [(e["kind"], e.get("report"), e["answer"]) for e in events(guest, name)
                   if e["kind"] in ("get_report", "set_report")]  # fmt: skip
            assert got == [("get_report", i, "data") for i in ids], got
        mute_asked = [(e.get("report"), e["answer"]) for e in events(guest, "mute")
                      if e["kind"] == "get_report"]  # fmt: skip
        assert mute_asked == [(2, "none"), (3, "EIO"), (4, "data"), (5, "data")]
        assert not any(e["kind"] == "open" for e in events(guest, "vendor-device"))
    finally:
        for name in nodes:
            guest.call("unplug", dev=name, close=True)


# --- gazehdr daemon -----------------------------------------------------------------------------

#: Fixations (µm on the calibrated screen) before the unplug, and after the re-plug.
BEFORE = [(123_457, 98_765), (480_001, 250_003), (300_000, 60_123), (55_555, 300_001)]
AFTER = [(560_000, 150_000), (250_250, 280_280), (420_420, 100_100)]
UNPLUG_S = 2.0
JITTER_NS = 6_000_000  # each report written up to 6 ms late (USB polling, the device's work)
#: How late a sample's time may be: the least read latency in a 2 s window, which a daemon
#: under TCG that fell behind at the start keeps for that long.
LATE_NS = 100_000_000


def replug_plan(tracker: Tracker, rng: random.Random) -> tuple[list[dict[str, Any]], Planned]:
    """Before: 4 fixations of 70 samples; the tracker unplugged for UNPLUG_S at the next slot;
    after: 3 fixations of 120 samples, its clock restarted (it rebooted). Each report is written
    up to JITTER_NS after its slot; its Sensor Timestamp is the slot's on the tracker's clock."""
    steps: list[dict[str, Any]] = []
    plan = Planned([], [], [], [])
    slot = 0
    for segment, (fixations, n, t0_us) in enumerate(
        [(BEFORE, 70, 1_700_000_000), (AFTER, 120, 3_000)]
    ):
        if segment == 1:
            steps.append({"at_ns": slot * PERIOD_NS, "action": "unplug"})
            slot += round(UNPLUG_S * 1e9 / PERIOD_NS)
            steps.append({"at_ns": slot * PERIOD_NS, "action": "replug"})
        first = slot
        for k, gaze in enumerate(fixations):
            for _ in range(n):
                report = tracker.report(t0_us + (slot - first) * STEP_US, gaze)
                at = slot * PERIOD_NS
                steps.append({"at_ns": at + rng.randrange(JITTER_NS), "report": report.hex()})
                plan.gaze_um.append(gaze)
                plan.nominal_ns.append(at)
                plan.fixation.append(k + segment * len(BEFORE))
                plan.segment.append(segment)
                slot += 1
    return steps, plan


def test_daemon_streams_fixations_through_the_kernel_across_a_replug(
    guest: Guest, live_server: Any, tap: Tap
) -> None:
    """The hand-written tracker plugged into the guest's kernel; `gazehdr daemon --source hid`
    (hidapi's hidraw backend) streams it to a server on the host, whose session follows it. The
    tracker is unplugged (UHID_DESTROY) mid-run and plugged in again (UHID_CREATE2), its clock
    restarted. Checked: every report read reaches the server, nothing the daemon held is lost,
    at the position the tracker reported (within a pixel) and with the tracker's own timestamps
    mapped to the server's clock; fixations follow the plan; the daemon sets the Device Mode
    at each connection; the gap the server sees is at most the unplug plus a second."""
    server = live_server(
        token="t", allow_hosts=(HOST_FROM_GUEST,), gaze_source=f"remote:{NAME}", fps=10.0
    )
    tracker = hut_tracker()
    assert plug(guest, "tracker", tracker)
    viewer = None
    try:
        start_daemon(guest, server, "tracker")
        viewer = ViewerThread(server)
        steps, plan = replug_plan(tracker, random.Random(12))
        offset0 = guest.clock_offset()
        start_ns = guest.call("stream", dev="tracker", steps=steps)["start_ns"]
        result = guest.call("stream_wait", dev="tracker", timeout_s=120)
        assert result["error"] is None, result
        time.sleep(2.0)  # delivery: the daemon sends every 20 ms; TCG is slow
        offset, offset_unc = offset_between(guest, offset0, time.monotonic_ns())
        done = stop_daemon(guest)
        viewer.stop()
        log_path = Path(guest.rundir, "daemon.jsonl")
        log_path.write_text(guest.call("read", path="/tmp/tracker.jsonl")["text"])
        recorded = read_session_log(log_path)
        uhid = events(guest, "tracker")
    finally:
        if viewer is not None and not viewer._stop.is_set():
            viewer._stop.set()
        guest.call("unplug", dev="tracker", close=True)
    err = done["stderr"]

    # -- the feature reports: asked for and the Device Mode set (gaze point | eye position)
    opens = [e["t_ns"] for e in uhid if e["kind"] == "open"]
    assert len(opens) == 2, uhid  # the second: the daemon reopened it by itself
    features = [(e["kind"], e["report"], e.get("data"), e["answer"]) for e in uhid
                if e["kind"] in ("get_report", "set_report")]  # fmt: skip
    per_open = [("get_report", i, None, "data") for i in (2, 3, 4, 5)]
    per_open.append(("set_report", 5, "0503", "ok"))
    assert features == per_open * 2, features
    assert "HID tracker reconnected" in err and "dropped 0 samples" in err, err
    assert tap.hellos and all(
        h.screen["screen_diagonal_m"] == pytest.approx(math.hypot(0.597, 0.336)) for h in tap.hellos
    )

    # -- every sample the daemon read reached the server, as recorded, nothing lost on the way
    got = [s for _, s in tap.samples]
    assert [s.t_ns for s in got] == [s.t_ns for s in recorded.samples]
    written = result["written_ns"]
    (unplug_at,) = [t for a, t in result["actions"] if a == "unplug"]
    (replug_at,) = [t for a, t in result["actions"] if a == "replug"]
    seg = (
        [i for i, s in enumerate(plan.segment) if s == 0],
        [i for i, s in enumerate(plan.segment) if s == 1],
    )
    before = [s for s in got if s.t_ns < unplug_at]
    after = [s for s in got if s.t_ns > unplug_at]
    # Before the unplug: every report but those the kernel still held when the device went
    # (hidapi's read sees the hang-up before them): the last few, written after the daemon's
    # last read, well under 100 ms before the unplug.
    unread = seg[0][len(before) :]
    assert all(unplug_at - written[i] < 100_000_000 for i in unread), (len(unread), unread)
    # After the re-plug: every report written once the daemon had the node open, and perhaps a
    # few before (the kernel drops what comes before anyone reads).
    must = [i for i in seg[1] if written[i] > opens[1]]
    assert len(must) <= len(after) <= len(seg[1])
    received = seg[0][: len(before)] + seg[1][len(seg[1]) - len(after) :]

    # -- positions: within a pixel of what the tracker reported
    for s, i in zip(before + after, received, strict=True):
        want = px(plan.gaze_um[i], tracker.screen_um)
        assert s.valid and near((s.x * SCREEN_PX[0], s.y * SCREEN_PX[1]), want), (i, s, want)

    # -- times: the tracker's spacing, not the jittery writes and reads; placed on the server's
    # clock. The samples' times step as the Sensor Timestamp does (but where the 2 s window's
    # least latency changes); the writes alone are 0 to 6 ms late, the reads later still.
    t = {i: s.t_ns for s, i in zip(before + after, received, strict=True)}
    pairs = [(i, j) for i, j in itertools.pairwise(received) if j == i + 1]
    same_step = [abs((t[j] - t[i]) - STEP_US * 1000) <= 1_000 for i, j in pairs]
    written_step = [abs((written[j] - written[i]) - PERIOD_NS) <= 1_000 for i, j in pairs]
    assert sum(same_step) >= 0.8 * len(pairs), (sum(same_step), len(pairs))
    assert sum(written_step) <= 0.05 * len(pairs)
    # Late by the least latency of the window: a few ms, tens under software emulation.
    late = {i: t[i] - (start_ns + plan.nominal_ns[i]) for i in received}  # guest ns
    assert -1_000_000 < min(late.values()) and max(late.values()) < LATE_NS, sorted(late.values())
    assert all(a < b for a, b in itertools.pairwise(s.t_ns for s in got))
    clock = [c for c in recorded.clocks if c.t_ns <= written[-1] and c.offset_ns is not None][-1]
    daemon_unc = clock.offset_uncertainty_ns or 0
    assert abs(clock.offset_ns - offset) <= daemon_unc + offset_unc + 1_000_000, (
        clock,
        offset,
        offset_unc,
    )
    for (arrived, s), i in zip(tap.samples, received, strict=True):
        taken_host = start_ns + plan.nominal_ns[i] + offset  # when the tracker sampled it
        on_server_clock = s.t_ns + clock.offset_ns  # where the daemon says it was
        assert -daemon_unc - 1_000_000 <= on_server_clock - taken_host <= LATE_NS + daemon_unc
        assert 0 <= arrived - taken_host + offset_unc < 1_000_000_000  # delivered within 1 s

    # -- the gap: at most the unplug plus one second, in sample times and in arrivals
    unplugged_ns = replug_at - unplug_at
    gap = after[0].t_ns - before[-1].t_ns
    assert gap <= unplugged_ns + 1_000_000_000, (gap, unplugged_ns)
    arrivals = [a for a, _ in tap.samples]
    assert max(b - a for a, b in itertools.pairwise(arrivals)) <= unplugged_ns + 1_000_000_000

    # -- fixations: each at its planned place, in the plan's order, the session following them
    fixations = [px(g, tracker.screen_um) for g in BEFORE + AFTER]
    starts = [e for _, e in tap.events if e.kind == "fixation_start"]
    which = []
    for e in starts:
        place = (e.x * SCREEN_PX[0], e.y * SCREEN_PX[1])
        matches = [k for k, f in enumerate(fixations) if near(place, f)]
        assert matches, (place, fixations)
        which.append(matches[0])
    assert which == sorted(set(which)) and set(range(len(BEFORE))) <= set(which), which
    assert which[-2:] == [len(fixations) - 2, len(fixations) - 1], which
    for _, e in tap.events:
        if e.kind == "fixation_update":
            assert any(near((e.x * SCREEN_PX[0], e.y * SCREEN_PX[1]), f) for f in fixations)
    notes = [(n["x"] * SCREEN_PX[0], n["y"] * SCREEN_PX[1]) for n in viewer.notes]
    assert notes and all(any(near(n, f) for f in fixations) for n in notes), notes
    assert near(notes[-1], fixations[-1])
    last_frame = viewer.frames[-1]
    assert near((last_frame[1] * SCREEN_PX[0], last_frame[2] * SCREEN_PX[1]), fixations[-1])


# --- devices that lie at run time -----------------------------------------------------------


def test_bad_reports_and_a_flood_are_dropped_and_counted_never_a_hang(
    guest: Guest, live_server: Any, tap: Tap
) -> None:
    """The fake layer's tracker (32-bit Sensor Timestamp, which wraps here) whose Configuration
    report fails, then sends: reports shorter than declared, reports of an id it never
    declared, reports longer than declared, a backlog of 1500 reports at 10 kHz with timestamps
    at its declared 120 Hz, and 60 reports faster than declared. The kernel drops the short
    ones (saying so) and the undeclared ones, and whatever its 64-report buffer cannot hold of
    the backlog; the daemon counts every report lost from the Sensor Timestamp, exactly, warns
    about the fast ones, reads on, and the fixation after it all arrives within a second."""
    server = live_server(
        token="t", allow_hosts=(HOST_FROM_GUEST,), gaze_source=f"remote:{NAME}", fps=5.0
    )
    tracker = fake_tracker()
    assert plug(guest, "liar", tracker, errors={str(0x12): errno.EIO})
    places = [(100_000, 100_000), (200_000, 150_000), (300_000, 200_000), (400_000, 100_000),
              (450_000, 250_000), (150_000, 220_000)]  # fmt: skip
    steps: list[dict[str, Any]] = []
    kinds: list[str] = []
    state = {"at": 0, "ts": (1 << 32) - 1_500_000}  # 1.5 s before the 32-bit clock wraps

    def add(kind: str, place: int, dt_ns: int, dts_us: int) -> None:
        """A report `dts_us` after the last on the tracker's clock, written `dt_ns` after it."""
        state["ts"] += dts_us
        report = tracker.report(state["ts"], places[place])
        if kind == "short":
            report = report[:12]
        elif kind == "undeclared":
            report = b"\x55" + report[1:]
        elif kind == "long":
            report += bytes(12)
        steps.append({"at_ns": state["at"], "report": report.hex()})
        kinds.append(f"{kind}:{place}")
        state["at"] += dt_ns

    for kind, place, n, dt, dts in [
        ("normal", 0, 60, PERIOD_NS, STEP_US),
        ("short", 0, 10, PERIOD_NS, STEP_US),
        ("undeclared", 0, 10, PERIOD_NS, STEP_US),
        ("long", 0, 10, PERIOD_NS, STEP_US),
        ("normal", 1, 60, PERIOD_NS, STEP_US),
        ("backlog", 2, 1500, 100_000, STEP_US),  # 10 kHz, timestamps at the declared 120 Hz
        ("normal", 3, 120, PERIOD_NS, STEP_US),  # time to catch up
        ("fast", 4, 60, 100_000, 100),  # 10 kHz with honest timestamps: the ring holds 64
        ("normal", 5, 120, PERIOD_NS, STEP_US),
    ]:
        for _ in range(n):
            add(kind, place, dt, dts)
    try:
        start_daemon(guest, server, "liar")
        guest.call("dmesg")
        offset0 = guest.clock_offset()
        guest.call("stream", dev="liar", steps=steps)
        result = guest.call("stream_wait", dev="liar", timeout_s=120)
        assert result["error"] is None, result
        time.sleep(2.0)
        offset, offset_unc = offset_between(guest, offset0, time.monotonic_ns())
        alive = guest.call("poll", name="daemon")
        assert alive["rc"] is None, alive["stderr"]  # no crash
        kernel_log = "\n".join(guest.call("dmesg")["lines"])
        done = stop_daemon(guest)
    finally:
        guest.call("unplug", dev="liar", close=True)
    err = done["stderr"]
    assert "feature report 18: " in err and "reports no calibrated screen size" in err, err

    # The kernel refused the short reports, saying so, and never passed on the undeclared id.
    assert "Event data for report 16 was too short" in kernel_log, kernel_log
    assert "skipping a malformed report" not in err  # nothing malformed reached the daemon
    got = [s for _, s in tap.samples]
    # The Configuration report failed: the default screen's diagonal (0.6 m, no --diagonal)
    # over 1920 × 1080 pixels.
    um_per_px = 0.6e6 / math.hypot(*SCREEN_PX)
    at_place = [
        sum(1 for s in got if near((s.x * SCREEN_PX[0], s.y * SCREEN_PX[1]),
                                   (p[0] / um_per_px, p[1] / um_per_px)))
        for p in places
    ]  # fmt: skip
    assert sum(at_place) == len(got), (at_place, len(got))
    assert at_place[0] == 60 + 10, at_place  # the normal ones and the long ones, as declared
    assert at_place[1] == 60 and at_place[5] == 120, at_place
    assert at_place[2] < 1500 and at_place[3] <= 120, at_place  # the kernel's buffer overflowed
    assert at_place[4] == 60, at_place  # fast, but fewer than the kernel holds

    # The daemon counted every report lost, exactly, from the Sensor Timestamp: the short ones,
    # the undeclared ones, and what the kernel dropped of the backlog and after it.
    declared = sum(1 for k in kinds if not k.startswith("fast"))
    expected = declared - (len(got) - at_place[4])
    lost = [int(m) for m in re.findall(r"reports lost before they were read \((\d+) in all", err)]
    assert lost and lost[-1] == expected, (lost, expected, at_place, err)
    early = [int(m) for m in re.findall(r"faster than its declared 120 Hz \((\d+) in all", err)]
    assert early and early[-1] == 60, err

    # It read on: the last fixation's reports reached the server within a second of being sent.
    written = result["written_ns"]
    last = [i for i, k in enumerate(kinds) if k == "normal:5"]
    arrivals = [a for a, s in tap.samples[-120:]]
    for i, arrived in zip(last, arrivals, strict=True):
        assert 0 <= arrived - (written[i] + offset) + offset_unc < 1_000_000_000
    place = (places[5][0] / um_per_px, places[5][1] / um_per_px)
    starts = [e for _, e in tap.events if e.kind == "fixation_start"]
    assert near((starts[-1].x * SCREEN_PX[0], starts[-1].y * SCREEN_PX[1]), place)
