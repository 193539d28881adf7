"""`Session` without sockets or clocks: the same inputs give the same frames, controls apply."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import sessions
from sessions import tick

from gazehdr.drivers.registry import open_track
from gazehdr.eye import pane_params
from gazehdr.protocol import (
    HEADER_BYTES,
    Choose,
    Eyes,
    Gaze,
    ModelChange,
    ModelPick,
    ParamChange,
    Reset,
    Viewport,
    decode_frame,
)
from gazehdr.scenes.library import SceneLibrary
from gazehdr.session import MAX_FRAME_DT, SYNTHETIC_LOOP_S, Session, SessionSettings
from gazehdr.sim import Params, Simulator
from gazehdr.sim.layout import Layout
from gazehdr.sim.models import ACUITY_MODELS, AFTERIMAGE_MODELS, Models

SETTINGS = SessionSettings(width=96, height=54, fps=30.0, scene="flash", seed=3)


def new_session(**changes) -> Session:
    settings = SessionSettings(**{**vars(SETTINGS), **changes})
    return sessions.new_session(settings)


SCRIPT = [  # (dt, controls): a flash seen at one place, then the eye moves and closes
    (0.0, [Gaze(0.5, 0.42, 1)]),
    *[(1 / 30, []) for _ in range(33)],
    (1 / 30, [Gaze(0.3, 0.5, 2)]),
    (1 / 30, [Eyes(False)]),
    (0.25, []),
]


def play(session: Session) -> list[bytes]:
    frames = [tick(session, dt, [(c, 0.0) for c in controls])[0] for dt, controls in SCRIPT]
    return [bytes(f.payload) for f in frames]


def test_same_inputs_same_frames() -> None:
    """Determinism: a replay with the same seed reproduces every frame byte for byte."""
    a, b = play(new_session()), play(new_session())
    assert a == b
    assert len(set(a)) > 10  # and the frames do change over the script
    assert play(new_session(seed=4)) != a  # the seed matters (acuity noise)


def test_header_reports_what_the_frame_used() -> None:
    session = new_session()
    frame, _ = tick(session, 0.0, [(Gaze(0.25, 0.75, 7), 123.0)])
    h = frame.header
    assert (h.frame, h.gaze_seq, h.gaze_x, h.gaze_y, h.eyes_open) == (0, 7, 0.25, 0.75, True)
    assert frame.gaze_received_at == 123.0
    assert h.adaptation == pytest.approx(session.sim.adaptation)
    header, v = decode_frame(h.pack() + frame.payload)
    assert v.shape == (54, 96, 3) and header.width == 96
    frame, _ = tick(session, 0.1, [])
    assert frame.gaze_received_at is None and frame.header.frame == 1  # no new gaze this time


def test_a_frame_is_sent_as_made_unless_frames_were_dropped_before_it() -> None:
    """A viewer that dropped no frame is sent the step's message itself (the event loop copies
    no pixels); one that dropped some gets the same pixels under a header that says so."""
    frame, _ = tick(new_session(), 0.0, [])
    assert frame.message(0) is frame.plain
    header, v = decode_frame(frame.plain)  # the header packs some fields as float32
    assert header.pack() == frame.header.pack() and v.shape == (54, 96, 3)
    again = frame.message(3)
    assert again[HEADER_BYTES:] == frame.plain[HEADER_BYTES:]
    assert again[:HEADER_BYTES] == dataclasses.replace(frame.header, dropped=3).pack()
    assert decode_frame(again)[0].dropped == 3
    assert frame.message(0, warp=True) is None  # no warp layers made for this step


@pytest.mark.parametrize("late", [True, False])
def test_a_gaze_that_comes_during_the_step_is_in_its_frame(late: bool) -> None:
    """A pointer move that reaches the session while its step is simulated is in that step's
    frame: its header's gaze, sequence number and arrival time, and the afterimages seen from
    there. The eye's step followed the gaze it started with; the log has the new gaze 1 ns
    after the step (which the next step follows). With late_gaze off the move waits a step."""
    session = new_session(scene="lamp", late_gaze=late, record=True)
    tick(session, 0.0, [(Gaze(0.5, 0.42, 1), 1.0)])
    tick(session, 0.5, [])  # an afterimage of the lamp forms at (0.5, 0.42)
    sim = session.eye.sims[0]
    plain_advance = sim.advance
    moves = [Gaze(0.3, 0.6, 2)]

    def simulating(*args, **kwargs) -> None:  # the move arrives while the step is simulated
        plain_advance(*args, **kwargs)
        if moves:
            session.pointer.take(moves.pop(), 2.0)

    sim.advance = simulating
    session.take_journal()
    frame, _ = tick(session, 1 / 30, [])
    h = frame.header
    logged = [r for r in session.take_journal() if type(r).__name__ == "GazeSample"]
    t_ns = round(session.sim.time * 1e9)
    assert not moves
    if not late:
        assert not logged
        assert (h.gaze_seq, h.gaze_x, frame.gaze_received_at) == (1, 0.5, None)
        frame, _ = tick(session, 1 / 30, [])
        assert (frame.header.gaze_seq, frame.gaze_received_at) == (2, 2.0)
        return
    assert (h.gaze_seq, h.gaze_x, h.gaze_y, frame.gaze_received_at) == (2, 0.3, 0.6, 2.0)
    screen = session.log_screen
    point = (0.3 * screen.screen_width_px, 0.6 * screen.screen_height_px)
    assert [(r.t_ns, r.x, r.y) for r in logged] == [(t_ns + 1, *point)]
    # The frame is the eye as stepped, seen from the new gaze: the afterimage moved with it.
    seen_there = sim.frame("float16", gaze=(0.3 * 96, 0.6 * 54))
    assert np.array_equal(decode_frame(h.pack() + frame.payload)[1], seen_there)
    at_start = sim.frame("float16", gaze=(0.5 * 96, 0.42 * 54))
    assert not np.array_equal(seen_there, at_start)
    frame, _ = tick(session, 1 / 30, [])  # the next step starts from the new gaze
    assert frame.gaze_received_at is None and frame.header.gaze_seq == 2


def test_long_stall_is_clamped() -> None:
    session = new_session()
    tick(session, 5.0, [])
    assert session.sim.time == MAX_FRAME_DT


def test_controls_and_refusals() -> None:
    session = new_session(scene="lamp")
    tick(session, 0.5, [])
    A = session.sim.adaptation
    _, notes = tick(session, 0.0, [(ParamChange({"j1": 0.1}), 0.0)])
    assert [n["type"] for n in notes] == ["state"] and session.params.j1 == 0.1
    # A parameter change continues the same eye: same time, same adaptation.
    assert session.sim.time == 0.5 and session.sim.adaptation == pytest.approx(A)

    before = session.state()
    _, notes = tick(
        session,
        0.0,
        [
            (ParamChange({"j1": -1.0, "n": 0}), 0.0),
            (Choose("scene", "nowhere"), 0.0),
            (ModelChange(ModelPick("magic")), 0.0),
            (Choose("gaze_source", "telepathy"), 0.0),
            (ParamChange({"mikamo_sequence": "/etc/passwd"}), 0.0),
        ],
    )
    assert [n["type"] for n in notes] == ["error"] * 5
    assert [n["in"] for n in notes] == ["params", "scene", "model", "gaze_source", "params"]
    assert "cannot be set remotely" in notes[-1]["message"]
    assert session.state() == before

    _, notes = tick(session, 0.0, [(Viewport(1000, 1000), 0.0), (Reset(), 0.0)])
    assert notes[-1]["width"] == notes[-1]["height"] == 72 and session.sim.time == 0.5


def test_synthetic_gaze_source_moves_the_eye_from_fixation_to_fixation() -> None:
    session = new_session(gaze_source="synthetic")
    seen = set()
    for _ in range(40):
        frame, _ = tick(session, 0.1, [(Gaze(0.9, 0.9, 1), 0.0)])  # pointer is ignored
        seen.add((round(frame.header.gaze_x, 9), round(frame.header.gaze_y, 9)))
        assert frame.header.tracker
    path = open_track("synthetic", seed=SETTINGS.seed, duration=SYNTHETIC_LOOP_S).path
    targets = {(round(f.x, 9), round(f.y, 9)) for f in path.fixations}
    assert len(seen) > 3 and seen <= targets  # never a point along a saccade


def _bleaching_peak(session: Session) -> float:
    state = session.sim._backend.get("state")  # B_L, B_M, B_S, C_L, C_M, C_S
    return float(state[0].max())


@pytest.mark.parametrize(
    "before",
    [(0.9,), (0.5, 0.5), (0.5, 0.5, 0.0)],
    ids=["across_it", "from_its_start", "from_its_start_after_dt_0"],
)
def test_a_flash_inside_a_long_frame_is_seen_for_its_duration(before: tuple[float, ...]) -> None:
    """The flash fires for [1, 1.125) s. A frame from 0.9 s to 1.5 s spans it, and one from
    exactly 1 s (the frame before ended on the flash's edge, as 2 fps frames do; or a dt = 0
    frame came there too) starts with it: the step is split at the flash's edges, each part
    seeing the scene as it is at the part's start, so the eye bleaches as much as with 10 ms
    frames."""
    coarse, fine = new_session(), new_session()
    for s in (coarse, fine):
        tick(s, 0.0, [(Gaze(0.5, 0.42, 1), 0.0)])
    for dt in before:
        tick(coarse, dt, [])
    tick(fine, 0.9, [])
    rest = _bleaching_peak(coarse)
    tick(coarse, 1.5 - coarse.sim.time, [])
    for _ in range(60):
        tick(fine, 0.01, [])
    assert coarse.sim.time == pytest.approx(fine.sim.time)
    assert _bleaching_peak(coarse) > 5 * rest
    assert _bleaching_peak(coarse) == pytest.approx(_bleaching_peak(fine), rel=0.05)


# --- models and split view --------------------------------------------------------------------

#: Every model but the defaults, each switched to on its own (the other part stays default).
SWITCHES = [ModelPick(afterimage=n) for n in AFTERIMAGE_MODELS if n != "jacobs"] + [
    ModelPick(acuity=n) for n in ACUITY_MODELS if n != "stochastic"
]
LOOK = [  # (dt, gaze): look at the lamp (0.5, 0.3 of the lamp scene) a while, then look away
    (0.0, Gaze(0.5, 0.3, 1)),
    *[(0.1, None) for _ in range(10)],
    (0.1, Gaze(0.3, 0.55, 2)),
    (0.1, None),
]


def _look(session: Session, first: list[ModelChange] = ()) -> list[bytes]:
    frames = []
    for i, (dt, gaze) in enumerate(LOOK):
        controls = [*(first if i == 0 else ()), *([gaze] if gaze else [])]
        frames.append(tick(session, dt, [(c, 0.0) for c in controls])[0].payload)
    return frames


@pytest.mark.parametrize("pick", SWITCHES, ids=lambda p: p.afterimage or p.acuity)
def test_a_model_switch_changes_the_frames_and_the_state(pick: ModelPick) -> None:
    """Reference backend: every model has one. The eye goes on (time, adaptation); a new
    acuity model keeps the retina as it was, a new afterimage model starts it settled."""
    lamp = dict(scene="lamp", backend="reference", width=64, height=36)
    default, switched = new_session(**lamp), new_session(**lamp)
    for s in (default, switched):
        tick(s, 0.5, [(Gaze(0.5, 0.3, 1), 0.0)])
    retina, A = switched.sim._backend.get("state"), switched.sim.adaptation
    _, notes = tick(switched, 0.0, [(ModelChange(pick), 0.0)])
    want = {"afterimage": pick.afterimage or "jacobs", "acuity": pick.acuity or "stochastic"}
    assert [n["type"] for n in notes] == ["state"]
    assert notes[0]["model"] == want and notes[0]["split"] is None
    assert (switched.sim.afterimage, switched.sim.acuity) == tuple(want.values())
    assert switched.sim.time == 0.5 and switched.sim.adaptation == pytest.approx(A)
    if pick.acuity:  # the same retina, after the tick's step of 0 s (rounding only)
        np.testing.assert_allclose(switched.sim._backend.get("state"), retina, rtol=1e-12)
    assert _look(switched) != _look(default)


def test_state_lists_the_models_and_unknown_names_are_refused() -> None:
    session = new_session()
    state = session.state()
    assert state["models"] == {"afterimage": [*AFTERIMAGE_MODELS], "acuity": [*ACUITY_MODELS]}
    assert state["model"] == {"afterimage": "jacobs", "acuity": "stochastic"}
    assert state["split"] is None
    sims = session.eye.sims
    _, notes = tick(
        session,
        0.1,
        [
            (ModelChange(ModelPick("magic")), 0.0),
            (ModelChange(ModelPick(acuity="blur")), 0.0),
            (ModelChange(ModelPick(), ModelPick(afterimage="magic")), 0.0),
        ],
    )
    assert [(n["type"], n["in"]) for n in notes] == [("error", "model")] * 3
    assert "unknown afterimage model 'magic'; choose one of jacobs, " in notes[0]["message"]
    assert "unknown acuity model 'blur'; choose one of stochastic, " in notes[1]["message"]
    assert session.state() == state and session.eye.sims is sims  # nothing changed
    frame, notes = tick(session, 0.1, [])  # and the session carries on
    assert notes == [] and frame.header.time == pytest.approx(0.2)
    # Asking for what runs already changes nothing and tells nobody.
    assert tick(session, 0.0, [(ModelChange(ModelPick("jacobs")), 0.0)])[1] == []


def _pane_gaze(x: float, y: float, w: int, h: int) -> tuple[float, float]:
    """docs/protocol.md, split view: the pane pixel a frame fraction looks at."""
    px = x * w
    return (px - w // 2 if px >= w // 2 else px, y * h)


SPLIT_SCRIPT = [  # (dt, controls)
    (0.0, [Gaze(0.25, 0.3, 1)]),  # the lamp in the left pane
    *[(0.1, []) for _ in range(5)],
    (0.1, [Gaze(0.8, 0.3, 2)]),  # the right pane, somewhat left of the lamp
    (0.2, [Gaze(1.2, 0.5, 3)]),  # right of the screen: off the right pane
    (0.1, [Eyes(False)]),
    (0.3, []),
]


@pytest.mark.parametrize(
    ("backend", "right"),
    [("reference", Models()), ("opencl", Models()), ("reference", Models("ritschel", "none"))],
    ids=["reference", "opencl", "reference-ritschel+none"],
)
def test_split_view_is_two_half_width_simulators_side_by_side(backend: str, right: Models) -> None:
    W, H, w = 99, 54, 49  # odd width: the last column stays black
    session = new_session(scene="lamp", width=W, height=H, backend=backend, split=right)
    assert session.state()["split"] == {"afterimage": right.afterimage, "acuity": right.acuity}
    # the session's are unchanged but for the pointer's figures: exact, once a frame
    pointer = Params(tracker_accuracy_deg=0.0, tracker_rate_hz=session.settings.fps)
    assert session.state()["params"] == pointer.to_dict()
    # A pane's pixels keep their size: the frame's pixels per degree (within the rounding of
    # the pane's share of the screen to whole screen pixels: 950 of 1920 for 49 of 99).
    params = pane_params(pointer, W, w)
    frame_ppd = Layout.for_frame(W, H, Params()).ppd
    assert Layout.for_frame(w, H, params).ppd == pytest.approx(frame_ppd, rel=1e-3)
    lamp = SceneLibrary().open("lamp").render(0.0, w, H)
    panes = []
    for model in (Models(), right):  # the same start as a session: settled at the first gaze
        sim = Simulator(w, H, params=params, backend=backend, seed=3, **vars(model))
        sim.step(0.0, gaze=_pane_gaze(0.5, 0.5, W, H))
        sim.load_scene(lamp, reset=True)
        panes.append(sim)
    gaze, eyes = (0.5, 0.5), True
    for dt, controls in SPLIT_SCRIPT:
        frame, notes = tick(session, dt, [(c, 0.0) for c in controls])
        assert notes == []
        for c in controls:
            gaze, eyes = ((c.x, c.y), eyes) if isinstance(c, Gaze) else (gaze, c.open)
        px = _pane_gaze(*gaze, W, H)
        want = [sim.step(dt, gaze=px, eyes_open=eyes, output="float16") for sim in panes]
        header, v = decode_frame(frame.header.pack() + frame.payload)
        assert header.split and (header.width, header.height) == (W, H)
        assert header.gaze_x == pytest.approx(px[0] / W) and header.gaze_y == pytest.approx(gaze[1])
        assert header.adaptation == pytest.approx(panes[0].adaptation)
        # The same arithmetic on the same inputs: equal but for float16 rounding (none here).
        for i, pane in enumerate(want):
            np.testing.assert_allclose(v[:, i * w : (i + 1) * w], pane, rtol=0, atol=1e-6)
        assert not v[:, 2 * w :].any()
    assert panes[0].time == pytest.approx(session.sim.time)


def test_either_pane_under_the_pointer_drives_the_same_gaze() -> None:
    W, H = 96, 54

    def frame_for(x: float) -> tuple[float, bytes]:
        session = new_session(scene="lamp", width=W, height=H, split=Models(acuity="none"))
        tick(session, 0.0, [(Gaze(x, 0.4, 1), 0.0)])
        frame, _ = tick(session, 0.2, [])
        return frame.header.gaze_x, frame.payload

    left, right = frame_for(0.25), frame_for(0.75)  # pane pixel 24 in both cases
    assert left == right and left[0] == 0.25
    assert frame_for(0.3)[1] != left[1]  # and the gaze does matter
    # Off the screen stays off the pane on that side.
    assert frame_for(-0.1)[0] == pytest.approx(-0.1)
    assert frame_for(1.1)[0] == pytest.approx(1.1 - 0.5)


def test_split_view_on_off_and_models_per_pane() -> None:
    session = new_session(scene="lamp", backend="reference", width=64, height=36)
    tick(session, 0.3, [(Gaze(0.5, 0.3, 1), 0.0)])
    A, whole = session.sim.adaptation, session.sim.layout
    _, notes = tick(session, 0.0, [(ModelChange(ModelPick(), ModelPick(acuity="none")), 0.0)])
    assert notes[-1]["split"] == {"afterimage": "jacobs", "acuity": "none"}
    assert [(s.width, s.acuity) for s in session.eye.sims] == [(32, "stochastic"), (32, "none")]
    # Two panes cost what the whole frame did: the retina grids add up to the whole one's.
    cells = [s.layout.grid_w * s.layout.grid_h for s in session.eye.sims]
    assert sum(cells) == whole.grid_w * whole.grid_h
    # Both panes continue the eye: its time and (up to the pane's own adaptation field) A.
    assert all(s.time == 0.3 for s in session.eye.sims)
    assert all(s.adaptation == pytest.approx(A) for s in session.eye.sims)
    # Changing only the left model keeps the right pane's.
    tick(session, 0.1, [(ModelChange(ModelPick(acuity="gaussian")), 0.0)])
    assert [s.acuity for s in session.eye.sims] == ["gaussian", "none"]
    _, notes = tick(session, 0.1, [(ModelChange(ModelPick(), None), 0.0)])
    assert notes[-1]["split"] is None and notes[-1]["model"]["acuity"] == "gaussian"
    assert len(session.eye.sims) == 1 and session.sim.width == 64
    assert not tick(session, 0.1, [])[0].header.split

    # A frame too narrow for two panes refuses split view; a viewport that makes it so ends it.
    narrow = new_session(width=24, height=54, backend="reference")
    _, notes = tick(narrow, 0.0, [(ModelChange(ModelPick(), ModelPick()), 0.0)])
    assert notes[0]["type"] == "error" and "too narrow for split view" in notes[0]["message"]
    split = new_session(split=Models(), backend="reference")
    _, notes = tick(split, 0.0, [(Viewport(1, 1000), 0.0)])
    assert notes[-1]["width"] == 16 and notes[-1]["split"] is None and len(split.eye.sims) == 1
