"""`Session` without sockets or clocks: the same inputs give the same frames, controls apply."""

from __future__ import annotations

import pytest

from server.protocol import Choose, Eyes, Gaze, ParamChange, Reset, Viewport, decode_frame
from server.scenes.library import SceneLibrary
from server.session import MAX_FRAME_DT, RemoteGaze, Session, SessionSettings

SETTINGS = SessionSettings(width=96, height=54, fps=30.0, scene="flash", seed=3)


def new_session(**changes) -> Session:
    settings = SessionSettings(**{**vars(SETTINGS), **changes})
    return Session("test", settings, SceneLibrary(), RemoteGaze())


SCRIPT = [  # (dt, controls): a flash seen at one place, then the eye moves and closes
    (0.0, [Gaze(0.5, 0.42, 1)]),
    *[(1 / 30, []) for _ in range(33)],
    (1 / 30, [Gaze(0.3, 0.5, 2)]),
    (1 / 30, [Eyes(False)]),
    (0.25, []),
]


def play(session: Session) -> list[bytes]:
    return [session.tick(dt, [(c, 0.0) for c in controls])[0].payload for dt, controls in SCRIPT]


def test_same_inputs_same_frames() -> None:
    """Determinism: a replay with the same seed reproduces every frame byte for byte."""
    a, b = play(new_session()), play(new_session())
    assert a == b
    assert len(set(a)) > 10  # and the frames do change over the script
    assert play(new_session(seed=4)) != a  # the seed matters (acuity noise)


def test_header_reports_what_the_frame_used() -> None:
    session = new_session()
    frame, _ = session.tick(0.0, [(Gaze(0.25, 0.75, 7), 123.0)])
    h = frame.header
    assert (h.frame, h.gaze_seq, h.gaze_x, h.gaze_y, h.eyes_open) == (0, 7, 0.25, 0.75, True)
    assert frame.gaze_received_at == 123.0
    assert h.adaptation == pytest.approx(session.sim.adaptation)
    header, v = decode_frame(h.pack() + frame.payload)
    assert v.shape == (54, 96, 3) and header.width == 96
    frame, _ = session.tick(0.1, [])
    assert frame.gaze_received_at is None and frame.header.frame == 1  # no new gaze this time


def test_long_stall_is_clamped() -> None:
    session = new_session()
    session.tick(5.0, [])
    assert session.sim.time == MAX_FRAME_DT


def test_controls_and_refusals() -> None:
    session = new_session(scene="lamp")
    session.tick(0.5, [])
    A = session.sim.adaptation
    _, notes = session.tick(0.0, [(ParamChange({"j1": 0.1}), 0.0)])
    assert [n["type"] for n in notes] == ["state"] and session.params.j1 == 0.1
    # A parameter change continues the same eye: same time, same adaptation.
    assert session.sim.time == 0.5 and session.sim.adaptation == pytest.approx(A)

    before = session.state()
    _, notes = session.tick(
        0.0,
        [
            (ParamChange({"j1": -1.0, "n": 0}), 0.0),
            (Choose("scene", "nowhere"), 0.0),
            (Choose("model", "magic"), 0.0),
            (Choose("gaze_source", "telepathy"), 0.0),
        ],
    )
    assert [n["type"] for n in notes] == ["error"] * 4
    assert [n["in"] for n in notes] == ["params", "scene", "model", "gaze_source"]
    assert session.state() == before

    _, notes = session.tick(0.0, [(Viewport(1000, 1000), 0.0), (Reset(), 0.0)])
    assert notes[-1]["width"] == notes[-1]["height"] == 72 and session.sim.time == 0.5


def test_synthetic_gaze_source_moves_the_eye_from_fixation_to_fixation() -> None:
    session = new_session(gaze_source="synthetic")
    seen = set()
    for _ in range(40):
        frame, _ = session.tick(0.1, [(Gaze(0.9, 0.9, 1), 0.0)])  # pointer is ignored
        seen.add((round(frame.header.gaze_x, 9), round(frame.header.gaze_y, 9)))
        assert frame.header.tracker
    targets = {(round(f.x, 9), round(f.y, 9)) for f in session._track.path.fixations}
    assert len(seen) > 3 and seen <= targets  # never a point along a saccade


def _bleaching_peak(session: Session) -> float:
    state = session.sim._backend.get("state")  # B_L, B_M, B_S, C_L, C_M, C_S
    return float(state[0].max())


def test_a_flash_inside_a_long_frame_is_seen_for_its_duration() -> None:
    """The flash fires for [1, 1.125) s. A 0.5 s frame from 0.9 s ends after it: the step is
    split at the flash's edges, so the eye bleaches as much as with 10 ms frames."""
    coarse, fine = new_session(), new_session()
    for s in (coarse, fine):
        s.tick(0.0, [(Gaze(0.5, 0.42, 1), 0.0)])
        s.tick(0.9, [])
    rest = _bleaching_peak(coarse)
    coarse.tick(0.5, [])
    for _ in range(50):
        fine.tick(0.01, [])
    assert coarse.sim.time == pytest.approx(fine.sim.time)
    assert _bleaching_peak(coarse) > 5 * rest
    assert _bleaching_peak(coarse) == pytest.approx(_bleaching_peak(fine), rel=0.05)
