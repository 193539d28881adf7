"""The late gaze warp's layers (gazehdr.warp): both backends make them alike, and composed at
the frame's own gaze they give the frame the server composes.

Tolerances: the RGB layer is a half float of the backends' linear RGB, relative 1e-3 (half
rounding 4.9e-4 plus test_sim_backends' 1e-4 on G and the tone curve); the maps are compared
as test_sim_backends compares them (relative 5e-4, the additive term relative to its
largest channel) plus a half float's rounding, 1e-3. The frame composed from the layers may
differ from the server's by at most 2 codes of 1023 (`CODES`): the half floats' rounding,
magnified in saturated colours by LMS_TO_RGB (1.35 codes measured on `mixed_scene`).
"""

from __future__ import annotations

import numpy as np
import pytest

from gazehdr import warp
from gazehdr.protocol import Encoding, ProtocolError, Warp, decode_frame, parse_control
from gazehdr.session import SessionSettings
from gazehdr.sim import Params, Simulator
from tests.sessions import new_session
from tests.test_sim_backends import H, W, magnitude, mixed_scene

CODES = 2.0


def _stepped(backend: str) -> tuple[Simulator, np.ndarray]:
    """A simulator that saw `mixed_scene` from three gazes (afterimages on the screen), and
    its last frame."""
    sim = Simulator(W, H, backend=backend, seed=2)
    sim.load_scene(mixed_scene(1))
    sim.step(0.1, gaze=(W / 3, H / 2))
    sim.step(0.05, gaze=(W / 2, H / 3))
    return sim, sim.step(0.05, gaze=(W / 2 + 5, H / 3))


def test_backends_make_the_same_layers() -> None:
    ref, cl = (_stepped(b)[0].warp_layers() for b in ("reference", "opencl"))
    a, b = ref.rgb.astype(np.float64), cl.rgb.astype(np.float64)
    assert (np.abs(a - b) / np.maximum(np.abs(a), 1e-3)).max() <= 1e-3
    maps = [warp.planar(m).astype(np.float64) for m in (ref.maps, cl.maps)]
    err = np.abs(maps[0] - maps[1]) / np.maximum(magnitude("maps", maps[0]), 1e-3)
    assert err.max() <= 1e-3
    assert (ref.gaze, ref.visibility, ref.cell) == (cl.gaze, cl.visibility, cl.cell)
    assert np.abs(maps[0][:3] - 1).max() > 0.3, "the test needs strong afterimages"


@pytest.mark.parametrize("backend", ["reference", "opencl"])
def test_composed_at_its_own_gaze_it_is_the_frame(backend: str) -> None:
    sim, v = _stepped(backend)
    data = warp.pack([sim.warp_layers()], W, sim.params)
    frame = warp.unpack(data, W, H)
    composed = warp.compose(frame)
    assert np.isfinite(composed).all()
    assert np.abs(composed - v).max() * 1023 <= CODES
    # At another gaze it is another frame: the afterimages moved (what the viewer shows).
    moved = warp.compose(frame, (frame.gazes[0][0] - 20, frame.gazes[0][1] + 9))
    assert np.abs(moved - v).max() * 1023 > 50


def test_session_sends_warp_frames_to_the_viewers_that_ask() -> None:
    """Only warp viewers: no plain frame is made; both: both; split view: a pane each, and
    each pane composed at its gaze is the plain frame's."""
    session = new_session(SessionSettings(width=96, height=64, scene="lamp", backend="opencl"))
    session.tick(0.05, [])
    frame, _ = session.tick(0.05, [], plain=False, warp=True)
    assert frame.message(0) is None and frame.warp is not None
    header, v = decode_frame(frame.message(3, warp=True))
    assert header.encoding is Encoding.warp and header.dropped == 3 and v.shape == (64, 96, 3)

    session.apply(parse_control('{"type": "model", "split": {"afterimage": "none"}}'))
    frame, _ = session.tick(0.05, [], plain=True, warp=True)
    _, plain = decode_frame(frame.message(0))
    header, composed = decode_frame(frame.message(0, warp=True))
    assert header.split
    assert np.abs(composed - plain).max() * 1023 <= CODES
    unpacked = warp.unpack(frame.warp, 96, 64)
    assert len(unpacked.maps) == 2 and unpacked.gazes[0] == unpacked.gazes[1]


def test_warp_control() -> None:
    assert parse_control('{"type": "warp", "on": true}') == Warp(True)
    with pytest.raises(ProtocolError, match="'on' must be true or false"):
        parse_control('{"type": "warp", "on": 1}')


@pytest.mark.parametrize("backend", ["reference", "opencl"])
def test_no_inf_in_half_floats(backend: str) -> None:
    """A strong gain (j2 = 5: gains up to 1e10, beyond a half float's 65504) is sent clamped
    to the largest half, never as Inf, and the viewer's composition stays finite."""
    sim = Simulator(W, H, backend=backend, seed=2, params=Params(j2=5.0))
    sim.load_scene(mixed_scene(1))
    sim.step(0.1, gaze=(W / 3, H / 2))
    sim.step(0.05, gaze=(W / 2, H / 3))
    layers = sim.warp_layers()
    assert np.isfinite(layers.maps).all() and np.isfinite(layers.rgb).all()
    assert np.abs(layers.maps.astype(np.float32)).max() == 65504.0
    frame = warp.unpack(warp.pack([layers], W, sim.params), W, H)
    assert np.isfinite(warp.compose(frame)).all()
