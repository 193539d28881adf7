"""The model against the paper's own equations and the effects it is meant to show.

Every test runs on both backends: the reference is the oracle, but what users see comes from
the kernels.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from gazehdr.sim import Params, Simulator

W, H = 128, 72
CENTRE = (64.0, 36.0)
BACKENDS = ["reference", "opencl"]


def uniform(value, w: int = W, h: int = H) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, np.float32), (h, w, 3)).copy()


def state_at_gaze(sim: Simulator) -> np.ndarray:
    """B (L, M, S) and c (L, M, S) at the retina cell under the gaze (the grid centre)."""
    lay = sim.layout
    st = sim._backend.get("state")
    return st[:, lay.grid_h // 2, lay.grid_w // 2].astype(np.float64)


def test_defaults_are_appendix_a_as_printed() -> None:
    """The paper's Appendix A, typed from the paper, and A_min = log10(100 cd/m^2) of Sec. 2.4.
    The tests below read rates and weights from Params, so they alone would pass wrong
    defaults. H, the LMS bleaching levels -> RGB afterimage colour matrix, is printed in
    Appendix A too (rows as printed)."""
    p = Params()
    printed = {
        "gamma": 0.455, "n": 0.7, "a1": 0.75, "a2": 0.2,
        "b1": (1.2e-3, 1.4e-4, 5.5e-7), "b2": (6.9e-1, 1.4e0, 5.5e0),
        "c1": 1.0, "c2": 1.0, "j1": 0.03, "j2": 0.15, "m1": 0.0, "m2": -2.0,
        "w_P": (0.2126, 0.7152, 0.0722), "w_S": (0.0, 0.8451, 0.1459),
        "sigma_0": 0.75, "rho_step": 0.286, "g": 0.25, "A_min": 2.0, "bands": 8,
        "H": ((1.14, -1.18, 0.36), (0.08, 1.02, 0.18), (0.30, -0.11, 1.25)),
    }  # fmt: skip
    assert {name: getattr(p, name) for name in printed} == printed
    ppd = p.geometry.pixels_per_degree()  # sigma_i = 0.75 2^(i/4) px, i = 0..7
    assert p.sigma_i(ppd) == pytest.approx([0.75 * 2 ** (i / 4) for i in range(8)])
    # rho_i = 0.286 i in log10 luminance, finest band (i = 7) first, over m1 - m2 = 2
    assert p.rho_i() == pytest.approx([0.286 * i / 2 for i in range(7, -1, -1)])


@pytest.mark.parametrize("backend", BACKENDS)
def test_bleaching_after_flash_matches_eq5_6(backend: str) -> None:
    """A 1/8 s, 1e7 cd/m^2 white flash on a dark field; then darkness (Fig. 4)."""
    p = Params()
    sim = Simulator(W, H, backend=backend)
    sim.load_scene(uniform(0.0))
    flash, steps = 1e7, 8
    sim.load_scene(uniform(flash), reset=False)
    for _ in range(steps):
        sim.step(1 / 8 / steps, gaze=CENTRE)
    b1, b2 = np.array(p.b1), np.array(p.b2)
    B_inf = b1 * flash / (b1 * flash + b2)
    expected = B_inf * (1 - np.exp(-(b1 * flash + b2) / 8))  # Eq. 5 from B = 0
    np.testing.assert_allclose(state_at_gaze(sim)[:3], expected, rtol=2e-4, atol=1e-6)
    assert expected[0] > 0.99 and expected[2] < 0.5  # L saturates, S barely moves

    sim.load_scene(uniform(0.0), reset=False)
    for _ in range(10):
        sim.step(0.1, gaze=CENTRE)
    np.testing.assert_allclose(state_at_gaze(sim)[:3], expected * np.exp(-b2 * 1.0), rtol=5e-4)


@pytest.mark.parametrize("backend", BACKENDS)
def test_adaptation_rates_follow_eq3(backend: str) -> None:
    p = Params()
    sim = Simulator(W, H, backend=backend)
    sim.load_scene(uniform(1e3))
    assert sim.adaptation == pytest.approx(3.0, abs=1e-4)
    sim.load_scene(uniform(1e4), reset=False)
    dt = 1 / 30
    n_up = round(1 / p.a1 / dt)
    for _ in range(n_up - 1):
        sim.step(dt, gaze=CENTRE)
    assert sim.adaptation == pytest.approx(3.0 + (n_up - 1) * dt * p.a1, abs=1e-4)
    sim.step(dt, gaze=CENTRE)
    assert sim.adaptation == pytest.approx(4.0, abs=1e-4)  # 1 log unit in 1/a1 s
    sim.step(dt, gaze=CENTRE)
    assert sim.adaptation == pytest.approx(4.0, abs=1e-4)  # no overshoot

    sim.load_scene(uniform(1e3), reset=False)
    for _ in range(round(1 / p.a2 / dt)):
        sim.step(dt, gaze=CENTRE)
    assert sim.adaptation == pytest.approx(3.0, abs=1e-4)  # 1 log unit down in 1/a2 s


@pytest.mark.parametrize("backend", BACKENDS)
def test_adaptation_floor_holds(backend: str) -> None:
    sim = Simulator(W, H, backend=backend)
    sim.load_scene(uniform(0.01))
    assert sim.adaptation == pytest.approx(2.0)
    sim.load_scene(uniform(1e4))
    for _ in range(20):
        sim.step(1.0, gaze=CENTRE, eyes_open=False)
    assert sim.adaptation == pytest.approx(2.0)


def flash_then_dark(backend: str, gaze, radius: int = 8) -> Simulator:
    sim = Simulator(W, H, backend=backend)
    dark = uniform(0.0)
    sim.load_scene(dark)
    spot = dark.copy()
    yy, xx = np.mgrid[:H, :W]
    spot[(xx + 0.5 - gaze[0]) ** 2 + (yy + 0.5 - gaze[1]) ** 2 < radius**2] = 1e7
    sim.load_scene(spot, reset=False)
    sim.step(1 / 8, gaze=gaze)
    sim.load_scene(dark, reset=False)
    return sim


@pytest.mark.parametrize("backend", BACKENDS)
def test_afterimage_moves_with_the_gaze(backend: str) -> None:
    g = (50.0, 30.0)
    sim = flash_then_dark(backend, g)
    before = sim.step(0.2, gaze=g)
    delta = (23.0, 11.0)
    after = sim.step(0.0, gaze=(g[0] + delta[0], g[1] + delta[1]))
    dx, dy = int(delta[0]), int(delta[1])
    np.testing.assert_allclose(after[dy:, dx:], before[: H - dy, : W - dx], atol=1e-5)
    assert before.max() > 0.1  # there is an afterimage to move

    # A shift that is not a whole number of cells moves the centroid by the same amount.
    shift = (7.4, -5.3)
    moved = sim.step(0.0, gaze=(g[0] + shift[0], g[1] + shift[1]))

    def centroid(v):
        w = v.sum(axis=2)
        yy, xx = np.mgrid[:H, :W]
        return np.array([(w * xx).sum(), (w * yy).sum()]) / w.sum()

    np.testing.assert_allclose(centroid(moved) - centroid(before), shift, atol=0.3)


@pytest.mark.parametrize("backend", BACKENDS)
def test_negative_adaptation_afterimage_where_the_lamp_was(backend: str) -> None:
    grey = uniform(100.0)
    lamp = grey.copy()
    lamp[26:46, 54:74] = 1e4
    sim = Simulator(W, H, backend=backend)
    sim.load_scene(lamp)
    for _ in range(25):
        sim.step(0.2, gaze=CENTRE)
    sim.load_scene(grey, reset=False)
    v = sim.step(1 / 30, gaze=CENTRE)
    lum = v @ np.array([0.2126, 0.7152, 0.0722])
    inside = lum[32:40, 60:68].mean()
    outside = lum[32:40, 20:28].mean()
    assert inside < outside - 0.02  # darker where the lamp was: a negative afterimage
    for _ in range(60):
        v = sim.step(0.1, gaze=CENTRE)
    lum = v @ np.array([0.2126, 0.7152, 0.0722])
    assert abs(lum[32:40, 60:68].mean() - lum[32:40, 20:28].mean()) < 0.01  # and it fades


@pytest.mark.parametrize("backend", BACKENDS)
def test_white_flash_leaves_a_coloured_afterimage_cyan_to_magenta(backend: str) -> None:
    """Fig. 5, 1e7 cd/m^2: the afterimage of a neutral flash starts green/cyan, ends magenta."""
    g = CENTRE
    sim = flash_then_dark(backend, g, radius=10)
    early = sim.step(0.1, gaze=g)[36, 64]
    for _ in range(30):
        late = sim.step(0.1, gaze=g)[36, 64]
    assert early.max() - early.min() > 0.1 * early.max()  # coloured, not neutral
    assert early[1] > early[0]  # green above red: cyan/green
    assert late[0] > late[1] and late[2] > late[1]  # red and blue above green: magenta
    assert late.max() > 0.02  # still visible after 3 s


def hsv_saturation(v: np.ndarray) -> float:
    return float((v.max() - v.min()) / max(v.max(), 1e-9))


@pytest.mark.parametrize("backend", BACKENDS)
def test_mesopic_desaturation_and_purple_grey(backend: str) -> None:
    """Fig. 11: a colour patch loses saturation as the scene dims; grey drifts to dull purple."""
    red, grey = (0.45, 0.06, 0.05), (0.18, 0.18, 0.18)
    scene = uniform(grey)
    scene[:, : W // 2] = red
    sats, greys = [], []
    for white in (10.0, 1.0, 0.3, 0.1, 0.03, 0.01):
        sim = Simulator(W, H, backend=backend)
        sim.load_scene(scene * (white / 0.18))
        v = sim.step(0.0, gaze=CENTRE)
        sats.append(hsv_saturation(v[36, 20]))
        greys.append(v[36, 100])
    assert all(a > b for a, b in itertools.pairwise(sats)), sats
    assert sats[0] > 0.6 and sats[-1] < 0.3
    assert hsv_saturation(greys[0]) < 0.01  # photopic grey is neutral
    dark = greys[-1]
    assert dark[2] > dark[1] and dark[0] > dark[1]  # purple: red and blue above green


def grating_scene(level: float) -> np.ndarray:
    """Fine (2 px period) and coarse (32 px period) vertical gratings, one above the other."""
    x = np.arange(W)
    fine = 1 + 0.5 * np.where(x % 2 == 0, 1.0, -1.0)
    coarse = 1 + 0.5 * np.sign(np.sin(2 * np.pi * (x + 0.5) / 32))
    img = np.empty((H, W), np.float32)
    img[: H // 2] = fine
    img[H // 2 :] = coarse
    return np.repeat((img * level)[:, :, None], 3, axis=2)


def band_energy(sim: Simulator, rows: slice) -> float:
    G = sim._backend.get("G")[1, rows, 8:-8].astype(np.float64)
    return float(np.abs(np.diff(G, axis=1)).mean() / G.mean())


@pytest.mark.parametrize("backend", BACKENDS)
def test_acuity_loses_fine_detail_first(backend: str) -> None:
    params = Params(geometry=Params().geometry.__class__(screen_width_px=W, screen_height_px=H))
    kept = []
    for level in (10.0, 0.1, 0.03, 0.01, 0.001):
        sim = Simulator(W, H, params=params, backend=backend, seed=1)
        sim.load_scene(grating_scene(level))
        sim.step(0.0, gaze=CENTRE)
        fine = band_energy(sim, slice(4, H // 2 - 4))
        coarse = band_energy(sim, slice(H // 2 + 4, H - 4))
        kept.append((fine, coarse))
    full_fine, full_coarse = kept[0]
    assert full_fine > 0.9 and full_coarse > 0.02
    # somewhere the fine grating is mostly gone while the coarse one is mostly there
    assert any(f < 0.5 * full_fine and c > 0.7 * full_coarse for f, c in kept[1:]), kept


@pytest.mark.parametrize("backend", BACKENDS)
def test_acuity_varies_in_time_and_is_seeded(backend: str) -> None:
    def run(seed: int) -> list[np.ndarray]:
        sim = Simulator(W, H, backend=backend, seed=seed)
        sim.load_scene(grating_scene(0.05))
        return [sim.step(0.25, gaze=CENTRE) for _ in range(4)]

    a, b, c = run(4), run(4), run(5)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, y) for x, y in zip(a, c, strict=True))
    assert not np.array_equal(a[0], a[2])  # the pattern of kept detail changes in time


def test_noise_key_frames_do_not_depend_on_frame_rate() -> None:
    """Same simulation time, different step sizes: the same acuity pattern."""
    sims = [Simulator(W, H, backend="reference", seed=2) for _ in range(2)]
    for s in sims:
        s.load_scene(grating_scene(0.05))
    for _ in range(6):
        sims[0].step(1 / 12, gaze=CENTRE)
    for _ in range(3):
        sims[1].step(1 / 6, gaze=CENTRE)
    assert math.isclose(sims[0].time, sims[1].time)
    np.testing.assert_array_equal(sims[0]._backend.get("d"), sims[1]._backend.get("d"))
