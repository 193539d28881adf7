"""The retina's geometry and start-up: an afterimage lands where the retina saw the light, what
the retina sees off the screen draws no edges, and the documented API starts at equilibrium.

Every test runs on both backends.
"""

from __future__ import annotations

import numpy as np
import pytest

from gazehdr.scenes import open_scene
from gazehdr.sim import Params, Simulator

W, H = 128, 72
CENTRE = (64.0, 36.0)
BACKENDS = ["reference", "opencl"]
F16 = np.finfo(np.float16)


def uniform(value: float) -> np.ndarray:
    return np.full((H, W, 3), value, np.float32)


def disc(centre: tuple[float, float], radius: float, value: float, base: np.ndarray):
    out = base.copy()
    yy, xx = np.mgrid[:H, :W] + 0.5
    out[(xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 < radius**2] = value
    return out


def centroid(plane: np.ndarray) -> np.ndarray:
    yy, xx = np.mgrid[: plane.shape[0], : plane.shape[1]] + 0.5
    return np.array([(plane * xx).sum(), (plane * yy).sum()]) / plane.sum()


# --- retinal locking, with the light away from the gaze -----------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("offset", [(21.0, -9.0), (-13.0, 15.0)])
def test_an_afterimage_lands_where_the_retina_saw_the_light(
    backend: str, offset: tuple[float, float]
) -> None:
    """A flash at `offset` from the gaze (both axes, |dx| != |dy|), then darkness and a jump:
    the retina keeps it at that offset (grid centre = the gaze, x right, y down), and the
    screen shows it at that offset from the new gaze; not mirrored, not transposed."""
    g1, g2 = (50.0, 36.0), (78.0, 30.0)
    dark = uniform(0.0)
    sim = Simulator(W, H, backend=backend)
    sim.start(dark, g1)
    sim.step(0.0, gaze=g1)
    sim.load_scene(disc((g1[0] + offset[0], g1[1] + offset[1]), 4.0, 1e7, dark), reset=False)
    sim.step(1 / 8, gaze=g1)
    sim.load_scene(dark, reset=False)

    lay = sim.layout
    bleached = sim._backend.get("state")[0].astype(np.float64)  # B of the L cones
    at = centroid(bleached) * lay.cell  # retinal position, screen px from the grid's corner
    expected = (lay.grid_w / 2 * lay.cell + offset[0], lay.grid_h / 2 * lay.cell + offset[1])
    np.testing.assert_allclose(at, expected, atol=0.5)

    v = sim.step(0.1, gaze=g2)
    assert v.max() > 0.1  # there is an afterimage to find
    np.testing.assert_allclose(centroid(v.sum(axis=2)), np.add(g2, offset), atol=0.5)


# --- the surround: what the retina sees off the screen ------------------------------------------


def edge_change_after_a_shift(sim: Simulator, scene: np.ndarray, shift) -> float:
    """Largest relative change of an edge pixel over 1 s after a gaze shift from the centre."""
    sim.start(scene, CENTRE)
    before = sim.step(1 / 30, gaze=CENTRE)
    edges = (np.s_[0], np.s_[-1], np.s_[:, 0], np.s_[:, -1])
    worst = 0.0
    for dt in (1 / 30, 0.2, 0.3, 0.5):
        v = sim.step(dt, gaze=(CENTRE[0] + shift[0], CENTRE[1] + shift[1]))
        for e in edges:
            worst = max(worst, float(np.abs(v[e] / before[e] - 1).max()))
    return worst


SHIFTS = [(W / 4, 0.0), (0.0, -H / 4), (-W / 4, H / 4)]  # a quarter screen, both axes


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("level", [0.01, 100.0, 1e4])
def test_a_gaze_shift_on_a_uniform_scene_draws_no_edge(backend: str, level: float) -> None:
    """The retina that a gaze shift brings onto the screen was looking past the frame; by
    default it saw the frame's edge go on, so it is adapted as the screen is."""
    for shift in SHIFTS:
        sim = Simulator(W, H, backend=backend)
        assert edge_change_after_a_shift(sim, uniform(level), shift) < 0.01, shift


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_dark_room_around_the_screen_draws_bands(backend: str) -> None:
    """surround = 0, the model before: the retina off the screen dark-adapts and comes back
    more sensitive, a band brighter by several percent along the edges."""
    sim = Simulator(W, H, params=Params(surround=0.0), backend=backend)
    assert edge_change_after_a_shift(sim, uniform(100.0), SHIFTS[0]) > 0.04


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_surround_goes_on_from_the_edge_not_from_inside(backend: str) -> None:
    """Off the screen the retina sees the frame's edge continued: a bright strip on the left
    edge goes on past it, a flash 20 px inside the top edge does not leak out (the surround
    is an average along the edge, not a blur of the frame)."""
    scene = disc((64.0, 24.0), 4.0, 1e7, uniform(1.0))
    scene[:, :4] = 1e3
    sim = Simulator(W, H, backend=backend)
    sim.start(scene, CENTRE)
    sim.step(0.0)
    surround = sim._backend.get("surround")[1].astype(np.float64)  # M cones; white: M = Y
    lay = sim.layout
    assert surround[lay.low_h // 2, 0] == pytest.approx(1e3, rel=1e-3)  # the strip goes on
    assert surround[0, lay.low_w // 2] == pytest.approx(1.0, rel=1e-3)  # no flash above it
    assert 1.0 < surround[0, lay.low_w // 16] < 1e3  # the corner: between the two


# --- equilibrium at the start -------------------------------------------------------------------


def assert_static(frames: list[np.ndarray]) -> None:
    """No pixel moves by more than float16 resolves: its epsilon times v, and near black its
    smallest normal number (6e-5, far below one 10-bit step)."""
    first = frames[0].astype(np.float64)
    tol = np.maximum(F16.eps * np.abs(first), float(F16.tiny))
    for k, v in enumerate(frames[1:], 1):
        moved = np.abs(v - first) > tol
        assert not moved.any(), f"frame {k}: {moved.any(axis=2).sum()} pixels moved"


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(
    ("gaze", "adapted"), [((10.0, 8.0), 2.0), ((64.0, 26.0), 5.3)], ids=["dark corner", "bulb"]
)
def test_the_documented_api_starts_at_equilibrium(backend: str, gaze, adapted: float) -> None:
    """docs/python-api.md: `load_scene`, then `step(dt, gaze=...)`. The eye starts adapted at
    that gaze, and over the first second of a static scene and gaze nothing moves: no start-up
    afterimage, and no halo grows around the bulb (the settled retina includes the map blur).
    The stochastic acuity varies in time by design, so it is off here."""
    lamp = open_scene("lamp").render(0.0, W, H)
    sim = Simulator(W, H, backend=backend, acuity="none")
    sim.load_scene(lamp)
    frames = [sim.step(1 / 60, gaze=gaze) for _ in range(61)]
    started = Simulator(W, H, backend=backend, acuity="none")
    started.start(lamp, gaze)
    assert sim.adaptation == pytest.approx(adapted, abs=0.05)  # adapted where it looks
    assert sim.adaptation == pytest.approx(started.adaptation, abs=1e-4)
    np.testing.assert_allclose(frames[0], started.step(1 / 60, gaze=gaze), atol=1e-5)
    assert_static(frames)


def test_the_readmes_api_block_is_the_api_docs_sequence() -> None:
    """README.md's Python block is python-api.md's, line for line (the sequence the test above
    runs: `load_scene`, then `step` with the gaze), so the two cannot drift apart."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]

    def code(path: str) -> list[str]:
        (block,) = re.findall(r"```python\n(.*?)```", (root / path).read_text(), re.S)[:1]
        lines = (line.split("#")[0].rstrip() for line in block.splitlines())
        return [line for line in lines if line]

    readme, api = code("README.md"), code("docs/python-api.md")
    assert readme and all(line in api for line in readme), set(readme) - set(api)
    calls = [
        line.split("(")[0].strip() for line in readme if line.startswith("sim.") or "= sim." in line
    ]
    assert calls == ["sim.load_scene", "v = sim.step"]
    assert "gaze=" in readme[-1]


@pytest.mark.parametrize("backend", BACKENDS)
def test_reset_settles_at_the_next_gaze(backend: str) -> None:
    """After a long look at the bulb, `reset` and a step elsewhere: the eye is as a fresh one
    started there (no afterimage of the bulb, adapted there), and stays so."""
    lamp = open_scene("lamp").render(0.0, W, H)
    sim = Simulator(W, H, backend=backend, acuity="none")
    sim.start(lamp, (64.0, 26.0))
    for _ in range(5):
        sim.step(1.0, gaze=(64.0, 26.0))
    sim.reset()
    frames = [sim.step(1 / 30, gaze=(20.0, 60.0)) for _ in range(31)]
    fresh = Simulator(W, H, backend=backend, acuity="none")
    fresh.start(lamp, (20.0, 60.0))
    np.testing.assert_allclose(frames[0], fresh.step(1 / 30, gaze=(20.0, 60.0)), atol=1e-5)
    assert_static(frames)
