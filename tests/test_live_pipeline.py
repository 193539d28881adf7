"""The live path's ordering (server/live.py): what a step reads and when the next one may
start, checked by events and orderings, never by the clock."""

from __future__ import annotations

import itertools

import pytest
from sessions import new_session

from gazehdr.live import MAX_PENDING_CONTROLS, WINDOW, LiveSession, Viewer, next_due
from gazehdr.metrics import Metrics
from gazehdr.protocol import Gaze, ProtocolError, Reset
from gazehdr.session import SessionSettings

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


def _paced_starts(step_seconds: list[float], interval: float) -> list[float]:
    """When steps of these durations start under the loop's pacing (LiveSession._run)."""
    now = due = 0.0
    starts = []
    for took in step_seconds:
        now = max(now, due)  # sleeps until due, or starts at once when late
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
