"""The live path's ordering (server/live.py): what a step reads and when the next one may
start, checked by events and orderings, never by the clock."""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import math
import random
import statistics
import time

import pyopencl as cl
import pytest
from sessions import new_session

from gazehdr.gaze import REMOTE_PREFIX
from gazehdr.live import (
    GAZE_PULL,
    MAX_PENDING_CONTROLS,
    WINDOW,
    LiveSession,
    Viewer,
    next_due,
    step_start,
)
from gazehdr.metrics import Metrics
from gazehdr.protocol import Gaze, ProtocolError, Reset
from gazehdr.scenes import open_scene
from gazehdr.serve import build_kernels
from gazehdr.session import NAMED_TRACKS, SessionSettings
from gazehdr.sim import Simulator

SETTINGS = SessionSettings(width=64, height=32, scene="lamp", fps=30.0)


def _live() -> LiveSession:
    return LiveSession(new_session(SETTINGS, "pipe"), Metrics())


def test_a_pointer_behind_a_full_control_queue_is_used_by_the_next_step() -> None:
    live = _live()
    for _ in range(MAX_PENDING_CONTROLS):
        live.submit(Reset())
    with pytest.raises(ProtocolError):  # the queue is full: a control is a flood ...
        live.submit(Reset())
    live.submit(Gaze(0.25, 0.75, 7))  # ... the pointer is not a control: it never queues
    assert len(live.controls) == MAX_PENDING_CONTROLS
    controls, live.controls = live.controls, []
    frame, _ = live._tick(0.0, controls)
    assert frame.header.gaze_seq == 7
    assert (frame.header.gaze_x, frame.header.gaze_y) == (0.25, 0.75)


def test_a_step_reads_the_gaze_when_it_starts_not_when_its_controls_were_taken() -> None:
    live = _live()
    live.submit(Gaze(0.1, 0.1, 1))
    first, _ = live._tick(0.0, [])
    assert first.header.gaze_seq == 1 and first.gaze_received_at is not None
    controls, live.controls = live.controls, []  # the loop takes the controls ...
    live.submit(Gaze(0.6, 0.4, 2))  # ... a pointer move arrives before the step starts
    second, _ = live._tick(1 / SETTINGS.fps, controls)
    assert second.header.gaze_seq == 2
    assert (second.header.gaze_x, second.header.gaze_y) == (0.6, 0.4)
    third, _ = live._tick(1 / SETTINGS.fps, [])  # no move since: the same gaze, not new
    assert third.header.gaze_seq == 2 and third.gaze_received_at is None


def test_scene_maps_are_made_only_when_the_loop_says_a_viewer_inspects() -> None:
    live = _live()
    _, notes = live._tick(0.0, [], False)
    assert not any(isinstance(n, bytes) for n in notes)
    _, notes = live._tick(0.0, [], True)
    assert [n for n in notes if isinstance(n, bytes)] == [live.scene_map]


async def _nothing(_: object) -> None:
    return None


def test_the_next_step_may_start_while_a_waiting_viewer_takes_the_last_frame() -> None:
    viewer = Viewer(_nothing, _nothing, Metrics())
    frame, _ = _live()._tick(0.0, [])
    assert viewer.wants_frame()
    viewer.mailbox.put(frame)
    assert not viewer.wants_frame()  # its task is busy sending: the frame would wait
    viewer.taking = True  # its task waits on the mailbox: the frame is on its way
    assert viewer.wants_frame()
    # A viewer that acks: the frame in the mailbox counts against its window.
    viewer.ack()
    viewer.sent, viewer.acks = WINDOW - 1, 0
    assert not viewer.wants_frame()
    viewer.acks = 1
    assert viewer.wants_frame()
    viewer.mailbox.frame = None
    viewer.taking = False
    viewer.sent, viewer.acks = WINDOW, 0
    assert not viewer.wants_frame()  # out of credit, whatever its task does


def _paced_starts(
    step_seconds: list[float],
    interval: float,
    gazes: list[float] = (),
    read_after: float = 0.0,
) -> list[float]:
    """When steps of these durations start under the loop's pacing (LiveSession._run), with
    gazes arriving at `gazes` (s, ascending): each wakes the wait, and a step reads those that
    came before its late read, `read_after` s after it starts."""
    now = due = 0.0
    starts: list[float] = []
    for took in step_seconds:
        read = starts[-1] + read_after if starts else -math.inf
        first = next((g for g in gazes if g > read), None)
        pull = first if first is not None and first < due else None
        now = max(now, step_start(due, interval, pull))  # sleeps, or starts at once when late
        starts.append(now)
        now += took
        due = next_due(due, interval, now)
    return starts


def test_pacing_makes_up_a_late_step_so_the_rate_holds_its_setting() -> None:
    """Steps alternately slower and faster than the interval (21 and 12 ms at 60 fps, as on
    the 2-core machines): on a fixed cadence the average interval is the setting's (paced from
    each step's own start, it was (21 + 16.7) / 2 ms); a step never starts before the last
    one ended."""
    interval, took = 1 / 60, [0.021, 0.012] * 50
    starts = _paced_starts(took, interval)
    late = max(took) - interval  # the last start may be late by a slow step's overrun
    mean = (starts[-1] - starts[0]) / (len(starts) - 1)
    assert interval <= mean <= interval + late / (len(starts) - 1)
    assert all(b >= a + t for (a, b), t in zip(itertools.pairwise(starts), took, strict=False))


def test_pacing_never_runs_faster_than_the_setting_or_bursts_after_a_stall() -> None:
    interval = 1 / 60
    starts = _paced_starts([0.001] * 20, interval)  # fast steps: one per interval, no faster
    assert min(b - a for a, b in itertools.pairwise(starts)) == pytest.approx(interval)
    # a 0.5 s stall, then fast steps: at most one step made up at once, then the cadence
    gaps = [b - a for a, b in itertools.pairwise(_paced_starts([0.5] + [0.001] * 10, interval))]
    assert sum(g < interval / 2 for g in gaps) <= 1
    assert gaps[-1] == pytest.approx(interval)


def test_a_new_gaze_starts_the_next_step_early_and_the_rate_holds_its_setting() -> None:
    """Steps of 9 ms at 60 fps (720p on 2 cores) reading the gaze late, 6 ms in, and a pointer
    moving every 50-150 ms at times of its own: with the pull a gaze waits less for the step
    that reads it (median and 95th percentile), never more than an interval after the last
    read; steps are never closer than half an interval, and the rate is the setting's."""
    interval, took, read_after = 1 / 60, 0.009, 0.006
    rng = random.Random(1)
    gazes = list(itertools.accumulate(rng.uniform(0.05, 0.15) for _ in range(300)))
    steps = int(gazes[-1] / interval)

    def waits(starts: list[float]) -> list[float]:
        """From each gaze to the late read of the step that shows it."""
        return [min(s + read_after for s in starts if s + read_after >= g) - g for g in gazes[:-5]]

    def p50_p95(values: list[float]) -> tuple[float, float]:
        q = statistics.quantiles(values, n=20)
        return statistics.median(values), q[18]

    pulled = _paced_starts([took] * steps, interval, gazes, read_after)
    on_cadence = _paced_starts([took] * steps, interval)
    (p50, p95), (p50_cadence, p95_cadence) = p50_p95(waits(pulled)), p50_p95(waits(on_cadence))
    assert p50 < 0.8 * p50_cadence and p95 < 0.8 * p95_cadence, (p50, p95, p50_cadence, p95_cadence)
    assert max(waits(pulled)) <= interval + read_after
    gaps = [b - a for a, b in itertools.pairwise(pulled)]
    assert min(gaps) >= (1 - GAZE_PULL) * interval - 1e-9
    assert (pulled[-1] - pulled[0]) / (len(pulled) - 1) == pytest.approx(interval, rel=1e-3)


def test_step_start_pulls_the_due_step_at_most_half_an_interval() -> None:
    interval = 1.0
    assert step_start(10.0, interval, None) == 10.0  # no gaze: on the cadence
    assert step_start(10.0, interval, 9.8) == 9.8  # a gaze just before: at once
    assert step_start(10.0, interval, 3.0) == 10.0 - GAZE_PULL  # long before: half early
    assert step_start(10.0, interval, 10.5) == 10.0  # never after it was due


def test_the_pointer_wakes_the_wait_for_the_next_step() -> None:
    """A pointer move while the loop waits ends the wait at once (by the event, not a poll):
    with the step due in 10 s on a cadence of 20 s, the wait ends after the move."""
    live = _live()
    live._tick(0.0, [])  # the step read the pointer as it was

    async def run() -> tuple[float, float]:
        waiting = asyncio.create_task(live._until_start(time.monotonic() + 10.0, 20.0))
        await asyncio.sleep(0.05)
        assert not waiting.done()  # no gaze yet: it waits for the cadence
        moved = time.monotonic()
        live.submit(Gaze(0.3, 0.6, 1))
        await asyncio.wait_for(waiting, 5.0)
        return moved, time.monotonic()

    moved, ended = asyncio.run(run())
    assert moved <= ended
    assert live.session.newer_gaze_at() == pytest.approx(moved, abs=0.05)
    live._tick(0.0, [])
    assert live.session.newer_gaze_at() is None  # read: nothing pulls the step after


def test_a_pointer_move_does_not_pull_a_session_that_follows_a_track() -> None:
    settings = dataclasses.replace(SETTINGS, gaze_source=NAMED_TRACKS[0])
    live = LiveSession(new_session(settings, "pipe"), Metrics())
    live._tick(0.0, [])
    live.submit(Gaze(0.3, 0.6, 1))
    assert live.session.newer_gaze_at() is None


def test_a_followed_tracker_pulls_the_next_step_and_another_wakes_nothing() -> None:
    """A tracker's new reading wakes the wait, and pulls the next step, only in a session that
    follows it."""
    settings = dataclasses.replace(SETTINGS, gaze_source=REMOTE_PREFIX + "lab")
    live = LiveSession(new_session(settings, "pipe"), Metrics())
    live._tick(0.0, [])
    followed, other = (live.session.trackers.feed(n) for n in ("lab", "elsewhere"))
    other.fixate(0.2, 0.2, True, time.monotonic())
    live.forward_gaze(other)
    assert not live._gaze_came.is_set() and live.session.newer_gaze_at() is None
    followed.fixate(0.7, 0.4, True, came := time.monotonic())
    live.forward_gaze(followed)
    assert live._gaze_came.is_set() and live.session.newer_gaze_at() == came

    async def run() -> float:
        started = time.monotonic()  # due in 10 s on a cadence of 20 s: pulled to now
        await asyncio.wait_for(live._until_start(started + 10.0, 20.0), 5.0)
        return time.monotonic() - started

    assert asyncio.run(run()) < 5.0


def test_the_servers_warm_up_launches_every_kernel_a_still_scene_does(monkeypatch) -> None:
    """`serve.build_kernels` steps past the acuity's move to its level stack, so that no kernel
    is launched first (with an empty kernel cache: built) while the first viewer watches: a
    session's kernels over 60 steps of a scene that stays are among the warm-up's."""
    launched: set[str] = set()
    plain = cl.Kernel.__call__

    def call(kernel, *args, **kwargs):
        launched.add(kernel.function_name)
        return plain(kernel, *args, **kwargs)

    monkeypatch.setattr(cl.Kernel, "__call__", call)
    build_kernels(SETTINGS)
    warm, launched = launched, set()
    s = SETTINGS
    sim = Simulator(s.width, s.height, params=s.params, seed=1)
    sim.load_scene(open_scene(s.scene).render(0.0, s.width, s.height))
    for i in range(60):
        sim.step(1 / s.fps, gaze=(s.width * (i % 5) / 5, s.height / 2), output="float16")
    assert "acuity_pick" in launched and launched <= warm, sorted(launched - warm)
