"""The `mikamo` afterimage model (Mikamo et al. 2012): its colour sequence file, the trigger,
the sequence it plays, and the OpenCL kernel against the NumPy reference.

Tolerances, OpenCL (float32, relaxed math) vs reference (float64):
- state: the previous input (L, M, S) relative 1e-4; Z, (Delta a, Delta b) absolute 2e-4;
  age absolute 1e-5 s;
- maps: absolute 2e-4 (display units; the afterimage starts at about 1 = display white).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from gazehdr.figures.common import native_geometry
from gazehdr.sim import Params, Simulator
from gazehdr.sim.baselines.mikamo import (
    XYZ_TO_RGB,
    SequenceError,
    load_sequence,
    xy_of_rgb,
    xyY_to_XYZ,
)
from gazehdr.sim.layout import RGB_TO_XYZ
from tests.measures import spread

W, H = 64, 48
CENTRE = (32.0, 24.0)
BACKENDS = ("reference", "opencl")


def colour(Y: float, x: float, y: float) -> np.ndarray:
    """Linear RGB (cd/m^2) of luminance Y and chromaticity (x, y)."""
    return XYZ_TO_RGB @ xyY_to_XYZ(Y, x, y)


def flash_scene(rgb: np.ndarray, background: float = 0.01) -> np.ndarray:
    """A dim room with a 16x16 px light in the middle (8 % of the frame: the top 5 %)."""
    scene = np.full((H, W, 3), background, np.float32)
    scene[16:32, 24:40] = rgb
    return scene


def make(backend: str = "reference", **params) -> Simulator:
    return Simulator(W, H, params=Params(**params), backend=backend, afterimage="mikamo")


def additive(sim: Simulator) -> np.ndarray:
    """maps[3:6] (linear RGB) of the retina cell at the gaze."""
    maps = sim._backend.get("maps").astype(np.float64)
    gh, gw = maps.shape[1:]
    return maps[3:, gh // 2, gw // 2]


def light_off(sim: Simulator, scene: np.ndarray, how: str) -> None:
    """The light goes off (the room goes dark) or the viewer closes the eyes: age 0."""
    if how == "scene":
        sim.load_scene(np.zeros_like(scene), reset=False)
        sim.step(0.0, gaze=CENTRE)
    else:
        sim.step(0.0, gaze=CENTRE, eyes_open=False)


def flash_then_off(
    sim: Simulator, how: str = "scene", rgb: np.ndarray | None = None, reset: bool = True
) -> None:
    """Look at a bright light (of Padgham's reference colour) for a second, then it goes off;
    `reset=False` keeps the retina's state from before."""
    xy = Params().mikamo_reference_xy
    scene = flash_scene(colour(1e5, *xy) if rgb is None else rgb)
    sim.load_scene(scene, reset=reset)
    sim.step(1.0, gaze=CENTRE)
    light_off(sim, scene, how)


def follow(sim: Simulator, times, how: str) -> list[np.ndarray]:
    """The afterimage at the gaze at each age in `times` (ascending, from 0)."""
    out, age = [], 0.0
    for t in times:
        sim.step(float(t - age), gaze=CENTRE, eyes_open=how == "scene")
        age = t
        out.append(additive(sim))
    return out


def luminance(rgb: np.ndarray) -> float:
    return float(RGB_TO_XYZ[1] @ rgb)


# --- the sequence file -------------------------------------------------------------------------


def test_shipped_sequence_loads() -> None:
    seq = load_sequence("")
    assert seq.t[0] == 0 and np.all(np.diff(seq.t) > 0)
    assert (seq.x[0], seq.y[0]) == Params().mikamo_reference_xy  # starts as Padgham's light
    assert 10.0 <= seq.duration <= 120.0  # "tens of seconds"
    assert seq.Y[0] > 0 and seq.Y[-1] == 0 and np.all(np.diff(seq.Y) <= 0)
    assert len(seq.t) >= 6  # Weve's five colours after the light's own


GOOD = "t_s,Y,x,y\n0,1,0.43,0.40\n2,0.5,0.3,0.3\n"


@pytest.mark.parametrize(
    ("text", "line", "field"),
    [
        ("# c\nt_s,Y,x,y\n0,1,0.43,0.40\n2,0.5,abc,0.3\n", 4, "'x'"),
        ("t_s,Y,x,y\n0,1,0.43,0.40\n0,0.5,0.3,0.3\n", 3, "'t_s'"),  # not increasing
        ("t_s,Y,x,y\n1,1,0.43,0.40\n2,0.5,0.3,0.3\n", 2, "'t_s'"),  # does not start at 0
        ("t_s,Y,x,y\n0,1,0.43,0.40\n2,-0.5,0.3,0.3\n", 3, "'Y'"),
        ("t_s,Y,x,y\n0,0,0.43,0.40\n2,0,0.3,0.3\n", 2, "'Y'"),  # no afterimage to scale
        ("t_s,Y,x,y\n0,1,0.43,0.40\n2,0.5,0.6,0.5\n", 3, "'y'"),  # x + y > 1
        ("t_s,Y,x,y\n0,1,0.43,0.40\n2,0.5,0.3,0\n", 3, "'y'"),
        ("t_s,Y,x,y\n0,1,0.43,0.40\n2,inf,0.3,0.3\n", 3, "'Y'"),
        ("t_s,Y,x\n0,1,0.43\n", 1, "header"),
        ("t_s,Y,x,y\n0,1,0.43,0.40\n2,0.5,0.3\n", 3, "fields"),
        ("t_s,Y,x,y\n0,1,0.43,0.40\n", 2, "two rows"),
    ],
)
def test_malformed_sequence_is_refused(tmp_path: Path, text: str, line: int, field: str) -> None:
    path = tmp_path / "mine.csv"
    path.write_text(text)
    with pytest.raises(SequenceError) as err:
        load_sequence(path)
    message = str(err.value)
    assert str(path) in message and f"line {line}" in message and field in message
    with pytest.raises(SequenceError):  # the simulator refuses it as well, at once
        make(mikamo_sequence=str(path))
    path.write_text(GOOD)
    assert load_sequence(path).duration == 2.0  # the same file, mended, loads


def test_missing_sequence_file_is_refused(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere.csv"
    with pytest.raises(SequenceError, match=r"nowhere\.csv"):
        make(mikamo_sequence=str(missing))


# --- what the model shows ----------------------------------------------------------------------


@pytest.mark.parametrize("how", ["scene", "eyes"])
def test_afterimage_follows_the_shipped_sequence(how: str) -> None:
    """At the centre of a light of the reference colour Z = 1 and Delta = 0, so at each row's
    time the afterimage has the row's chromaticity and luminance (display white = 1), and
    nothing is left after the last row."""
    seq = load_sequence("")
    sim = make()
    flash_then_off(sim, how)
    lit = seq.Y > 0
    times = [*seq.t, seq.duration + 0.5]
    seen = [additive(sim), *follow(sim, times[1:], how)]
    for k in np.flatnonzero(lit):
        rgb = seen[k]
        assert np.all(rgb >= 0)
        np.testing.assert_allclose(xy_of_rgb(rgb[:, None])[:, 0], (seq.x[k], seq.y[k]), atol=1e-3)
        assert luminance(rgb) == pytest.approx(seq.Y[k], rel=1e-3)
    assert np.all(seen[-1] == 0)
    assert np.all(sim._backend.get("maps")[3:] == 0)  # the whole retina is clear again


def test_a_users_sequence_sets_colour_and_duration(tmp_path: Path) -> None:
    path = tmp_path / "short.csv"
    path.write_text("# two rows\nt_s,Y,x,y\n0,0.8,0.30,0.50\n4,0.4,0.30,0.50\n")
    sim = make(mikamo_sequence=str(path))
    flash_then_off(sim)
    at0 = additive(sim)
    at2, at4, after = follow(sim, [2.0, 4.0, 4.25], "scene")
    for rgb in (at0, at2, at4):
        np.testing.assert_allclose(xy_of_rgb(rgb[:, None])[:, 0], (0.30, 0.50), atol=1e-3)
    assert luminance(at0) == pytest.approx(0.8, rel=1e-3)
    assert 0.4 < luminance(at2) < 0.8  # between the rows (interpolated in L*a*b*)
    assert luminance(at4) == pytest.approx(0.4, rel=1e-3)  # still there at the last row
    assert np.all(after == 0)
    shipped = make()  # the shipped sequence is still going at 4.25 s
    flash_then_off(shipped)
    assert luminance(follow(shipped, [4.25], "scene")[0]) > 0.1


def test_gamut_fix_clamps_and_keeps_luminance(tmp_path: Path) -> None:
    """A spectral green outside the display's gamut: negative RGB is clamped away and the
    luminance is set back to the file's."""
    path = tmp_path / "green.csv"
    path.write_text("t_s,Y,x,y\n0,0.5,0.20,0.70\n4,0.25,0.20,0.70\n")
    assert colour(0.5, 0.20, 0.70).min() < -0.05  # the row itself is out of gamut
    sim = make(mikamo_sequence=str(path))
    flash_then_off(sim)
    rgb = additive(sim)
    assert rgb.min() >= 0 and rgb.min() < 1e-9  # clamped, not shifted
    assert luminance(rgb) == pytest.approx(0.5, rel=1e-3)


def test_strength_scales_the_afterimage() -> None:
    one, half = make(), make(mikamo_strength=0.5)
    for sim in (one, half):
        flash_then_off(sim)
    np.testing.assert_allclose(additive(half), 0.5 * additive(one), rtol=1e-9)


def test_no_afterimage_without_a_sharp_drop() -> None:
    scene = flash_scene(colour(1e5, 0.43, 0.40))
    steady, dimming, sudden = make(), make(), make()
    for sim in (steady, dimming, sudden):
        sim.load_scene(scene)
    for k in range(12):  # 0.5 log units a step: 6 log units in all, never 1 in one step
        steady.step(0.5, gaze=CENTRE)
        dimming.load_scene(scene * 10 ** (-0.5 * (k + 1)), reset=False)
        dimming.step(0.5, gaze=CENTRE)
        for sim in (steady, dimming):
            assert np.all(sim._backend.get("maps")[3:] == 0)
    sudden.step(0.5, gaze=CENTRE)
    sudden.load_scene(scene * 10**-1.2, reset=False)  # 1.2 log units at once: it fires
    sudden.step(0.5, gaze=CENTRE)
    assert luminance(additive(sudden)) > 0.5


def test_only_the_brightest_part_leaves_an_afterimage() -> None:
    """The mask: a lamp and, beside it, a wall 100x dimmer (outside the top 5 %) both go off."""
    scene = flash_scene(colour(1e5, 0.43, 0.40))
    scene[2:12, 2:20] = colour(1e3, 0.31, 0.33)
    sim = make(mikamo_lowpass_deg=0.0)
    sim.load_scene(scene)
    sim.step(1.0, gaze=CENTRE)
    sim.load_scene(np.zeros_like(scene), reset=False)
    sim.step(0.0, gaze=CENTRE)
    maps = sim._backend.get("maps")[3:]
    gh, gw = maps.shape[1:]
    lay = sim.layout
    row = lambda y: int(gh / 2 + (y - CENTRE[1]) / lay.cell)  # noqa: E731
    col = lambda x: int(gw / 2 + (x - CENTRE[0]) / lay.cell)  # noqa: E731
    assert luminance(maps[:, row(24), col(32)]) > 0.5  # the lamp
    assert np.all(maps[:, row(3) : row(11), col(3) : col(19)] == 0)  # the wall


def test_colour_of_the_light_steers_the_afterimage() -> None:
    """Eq. 1: a redder light than the reference shifts a* up, a bluer one b* down, by tau_M
    times a unit vector; a re-trigger restarts the sequence."""
    red = make()
    blue = make()
    ref = make()
    flash_then_off(red, rgb=colour(1e5, 0.55, 0.33))
    flash_then_off(blue, rgb=colour(1e5, 0.25, 0.22))
    flash_then_off(ref)
    d_red = red._backend.get("state")[4:6, red.layout.grid_h // 2, red.layout.grid_w // 2]
    d_blue = blue._backend.get("state")[4:6, blue.layout.grid_h // 2, blue.layout.grid_w // 2]
    assert np.hypot(*d_red) == pytest.approx(1.0, abs=1e-6) and d_red[0] > 0.5
    assert np.hypot(*d_blue) == pytest.approx(1.0, abs=1e-6) and d_blue[1] < -0.5
    assert not np.allclose(additive(red), additive(ref), rtol=1e-3)
    # 10 s later the light comes back on and goes off again: the sequence starts over.
    first = additive(ref)
    later = follow(ref, [10.0], "scene")[0]
    assert not np.allclose(later, first, rtol=1e-3)
    flash_then_off(ref, reset=False)
    np.testing.assert_allclose(additive(ref), first, rtol=1e-9)


# Independent CIE L*a*b* (the model's own conversions are what these tests check).
_EPS = (6 / 29) ** 3
DISPLAY_WHITE = RGB_TO_XYZ.sum(axis=1)  # XYZ of RGB (1, 1, 1): the L*a*b* white, Y = 1


def cie_lab(xyz: np.ndarray, white: np.ndarray) -> np.ndarray:
    t = np.asarray(xyz, np.float64) / white
    f = np.where(t > _EPS, np.cbrt(t), t * (29 / 6) ** 2 / 3 + 4 / 29)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def cie_xyz(lab: np.ndarray, white: np.ndarray) -> np.ndarray:
    L, a, b = lab
    f = np.array([(L + 16) / 116 + a / 500, (L + 16) / 116, (L + 16) / 116 - b / 200])
    return white * np.where(f > 6 / 29, f**3, 3 * (6 / 29) ** 2 * (f - 4 / 29))


def test_image_term_is_tau_times_delta_at_a_middle_row() -> None:
    """Eq. 1-4 in closed form for a light redder than Padgham's: at the light's centre Z = 1
    (it is the brightest part of I_on); Eq. 1: (Delta a, Delta b) = the unit vector from the
    reference chromaticity to the light's, in L*a*b* with the white at the light's luminance;
    at a middle row's time L_A = L_M, a_A = a_M + tau_M Delta a, b_A = b_M + tau_M Delta b,
    tau_M = L_M / L_M(0); then XYZ -> RGB and the gamut fix. The afterimage of a light of the
    reference colour (Delta = 0) differs from it by exactly tau_M Delta in L*a*b*."""
    seq, p = load_sequence(""), Params()
    k = (len(seq.t) - 1) // 2
    red = flash_scene(colour(1e5, 0.55, 0.33))[24, 32].astype(np.float64)  # as the sim sees it
    seen = {}
    for name, rgb in (("red", red), ("reference", None)):
        sim = make()
        flash_then_off(sim, rgb=rgb)
        seen[name] = follow(sim, [seq.t[k]], "scene")[0]

    xyz = RGB_TO_XYZ @ red
    white = DISPLAY_WHITE * xyz[1]  # L* = 100 for the light and for the reference at its Y
    light = cie_lab(xyz, white)[1:]
    ref = cie_lab(xyY_to_XYZ(xyz[1], *p.mikamo_reference_xy), white)[1:]
    delta = (light - ref) / np.hypot(*(light - ref))
    row = cie_lab(xyY_to_XYZ(seq.Y[k], seq.x[k], seq.y[k]), DISPLAY_WHITE)
    tau = row[0] / cie_lab(xyY_to_XYZ(seq.Y[0], seq.x[0], seq.y[0]), DISPLAY_WHITE)[0]
    assert 0.2 < tau < 0.8 and np.hypot(*(light - ref)) > 10  # a middle row, a real colour
    lab_A = np.array([row[0], row[1] + tau * delta[0], row[2] + tau * delta[1]])
    xyz_A = cie_xyz(lab_A, DISPLAY_WHITE)
    rgb_A = XYZ_TO_RGB @ xyz_A
    assert rgb_A.min() > 0  # in gamut: the gamut fix leaves it alone, so L*a*b* compares exactly
    np.testing.assert_allclose(seen["red"], rgb_A, rtol=1e-7)
    shift = cie_lab(RGB_TO_XYZ @ seen["red"], DISPLAY_WHITE) - cie_lab(
        RGB_TO_XYZ @ seen["reference"], DISPLAY_WHITE
    )
    # 1e-5: the reference light, rounded to float32, is ~1e-6 Delta E off the reference colour,
    # below the Delta E floor, so its own Delta is ~1e-6 rather than exactly 0.
    np.testing.assert_allclose(shift, [0.0, *(tau * delta)], atol=1e-5)


def one_cell_light(backend: str, **params) -> tuple[Simulator, tuple[float, float]]:
    """Darkness but one low-resolution cell lit with Padgham's light for a second, fixated so
    that a single retina cell sees it (the gaze on its corner), then the light goes off. At
    the paper's pixel density (64 px/°, 6-px cells): 0.25° is 2.7 cells."""
    w, h = 128, 96
    sim = Simulator(
        w, h, params=native_geometry(w, h).replace(**params), backend=backend, afterimage="mikamo"
    )
    lay, c = sim.layout, sim.layout.cell
    gx, gy = lay.low_w // 2, lay.low_h // 2
    gaze = (float(gx * c), float(gy * c))
    scene = np.zeros((h, w, 3), np.float32)
    scene[gy * c : (gy + 1) * c, gx * c : (gx + 1) * c] = colour(1e5, *Params().mikamo_reference_xy)
    sim.step(0.0, gaze=gaze)  # the eye is there before the light: no retinal move fires
    sim.load_scene(scene)
    sim.step(1.0, gaze=gaze)
    sim.load_scene(np.zeros_like(scene), reset=False)
    sim.step(0.0, gaze=gaze)
    return sim, gaze


@pytest.mark.parametrize("backend", BACKENDS)
def test_fixed_low_pass_spreads_one_cell_by_its_sigma(backend: str) -> None:
    """The afterimage of one retina cell is the low-pass kernel: its spread is
    mikamo_lowpass_deg in cells (2 %: a sampled, truncated Gaussian), around that cell; and
    the low-pass is fixed: 5 s later the afterimage has another colour, the same spread."""
    sim, gaze = one_cell_light(backend)
    lay = sim.layout
    expect = lay.px(Params().mikamo_lowpass_deg) / lay.cell
    assert 2 < expect < 4
    for later in (False, True):
        if later:
            sim.step(5.0, gaze=gaze)
        maps = sim._backend.get("maps")[3:].astype(np.float64)
        assert maps.sum() > 0.1
        for plane in maps:
            for axis, centre in ((0, lay.grid_w // 2), (1, lay.grid_h // 2)):
                mean, sigma = spread(plane, axis, centre)  # axis 0: along x
                assert mean == pytest.approx(0.0, abs=1e-3)
                assert sigma == pytest.approx(expect, rel=0.02)


@pytest.mark.parametrize("backend", BACKENDS)
def test_background_dark_adapts_while_the_afterimage_plays(backend: str) -> None:
    """The blend is over a dark-adapting background: a lamp in a dim room (1 cd/m^2) goes
    off; while its afterimage plays, the global adaptation A falls step after step (at a2, so
    0.1 log units per 0.5 s) and the room, unchanged, is shown brighter each step."""
    p = Params()
    scene = flash_scene(colour(1e5, *p.mikamo_reference_xy), background=1.0)
    room = scene.copy()
    room[16:32, 24:40] = 1.0
    sim = make(backend)
    sim.load_scene(scene)
    sim.step(1.0, gaze=CENTRE)
    sim.load_scene(room, reset=False)
    A, wall = [], []
    for _ in range(8):
        v = sim.step(0.5, gaze=CENTRE)
        assert luminance(additive(sim)) > 0.05  # the afterimage is playing
        A.append(sim.adaptation)
        wall.append(float(v[4:8, 4:8].mean()))
    assert A[-1] > p.A_min + 0.5  # never reached the floor: A fell all the time
    np.testing.assert_allclose(np.diff(A), -0.5 * p.a2, rtol=1e-3)
    assert all(b > a for a, b in itertools.pairwise(wall)), wall


# --- OpenCL, edges, determinism ------------------------------------------------------------


def run_script(sim: Simulator) -> list[tuple[np.ndarray, np.ndarray]]:
    """Coloured lights, eye movements across them (retinal triggers), lights off, eyes closed,
    dt 0 and long steps; returns (state, maps) after every step."""
    rng = np.random.default_rng(3)
    scene = np.exp(rng.normal(np.log(0.05), 1.0, (H, W, 3))).astype(np.float32)
    scene[16:32, 24:40] = colour(1e5, 0.43, 0.40)
    scene[4:12, 4:14] = colour(1e7, 0.55, 0.33)  # the others get Z < 0.5
    scene[36:44, 46:60] = colour(2e5, 0.20, 0.30)
    sim.load_scene(scene)
    script = [
        (0.5, (32.0, 24.0), True, None),
        (0.0, (32.0, 24.0), True, scene * 1e-3),  # lights off
        (1 / 30, (37.3, 20.6), True, None),
        (1.0, (37.3, 20.6), True, scene),  # on again
        (0.25, (20.0, 30.0), True, None),  # the eye moves off the lights
        (0.5, (20.0, 30.0), False, None),  # eyes closed
        (2.0, (-50.0, 10.0), False, None),
        (7.0, (90.0, 60.0), True, None),
    ]
    out = []
    for dt, gaze, eyes, new_scene in script:
        if new_scene is not None:
            sim.load_scene(new_scene, reset=False)
        sim.step(dt, gaze=gaze, eyes_open=eyes)
        b = sim._backend
        out.append((b.get("state").astype(np.float64), b.get("maps").astype(np.float64)))
    return out


def test_opencl_matches_reference() -> None:
    ref, cl = (run_script(make(b)) for b in BACKENDS)
    fired = False
    for k, ((s_ref, m_ref), (s_cl, m_cl)) in enumerate(zip(ref, cl, strict=True)):
        rel = np.abs(s_cl[:3] - s_ref[:3]) / np.maximum(s_ref[:3], 1e-6)
        assert rel.max() <= 1e-4, f"step {k}: previous input off by {rel.max():.3g}"
        for plane, tol in ((3, 2e-4), (4, 2e-4), (5, 2e-4), (6, 1e-5)):
            err = np.abs(s_cl[plane] - s_ref[plane]).max()
            assert err <= tol, f"step {k}: state plane {plane} off by {err:.3g}"
        err = np.abs(m_cl - m_ref).max()
        assert err <= 2e-4, f"step {k}: maps off by {err:.3g}"
        fired |= bool(m_ref[3:].max() > 0.1)
    assert fired  # the script did make afterimages to compare


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(
    ("level", "gaze", "dt"),
    [
        (0.0, CENTRE, 1 / 60),  # total darkness
        (1e8, CENTRE, 1.0),
        (1e8, (-500.0, -400.0), 0.0),  # gaze far off screen
        (1e10, (70.0, 50.0), 1.0),  # the radiance cap
    ],
)
def test_no_nan_or_inf(backend: str, level: float, gaze, dt: float) -> None:
    sim = make(backend)
    scene = np.full((H, W, 3), level, np.float32)
    scene[10:20, 10:20] = level * 0.3  # a bit of structure
    sim.load_scene(scene)
    for step in range(4):
        if step == 2:  # everything goes off at once
            sim.load_scene(np.zeros_like(scene), reset=False)
        v = sim.step(dt, gaze=gaze, eyes_open=step != 3)
        assert np.all(np.isfinite(v)) and v.min() >= 0 and v.max() <= 1
        for name in ("state", "maps"):
            assert np.all(np.isfinite(sim._backend.get(name))), name
    if level >= 1e8 and gaze == CENTRE:  # a uniform light is all top 5 %: it fired
        assert luminance(additive(sim)) > 0.1


@pytest.mark.parametrize("backend", BACKENDS)
def test_deterministic(backend: str) -> None:
    a, b = (run_script(make(backend)) for _ in range(2))
    for (sa, ma), (sb, mb) in zip(a, b, strict=True):
        assert np.array_equal(sa, sb) and np.array_equal(ma, mb)


def test_letterbox_bars_are_not_part_of_the_top_fraction() -> None:
    """A wide image letterboxed in a pane: 80 % of the cells are black bars. The mask's top 5 %
    is of the scene's light, so only the lamp (5 % of the image) can leave an afterimage; with
    the bars counted the whole wall did, an olive blob over the bars."""
    from gazehdr.sim.baselines.mikamo import scene_stats

    yp = np.zeros((50, 40))
    yp[20:30] = 50.0  # the image: a wall at 50 cd/m² ...
    yp[20:30, :2] = 5e4  # ... with a lamp, 5 % of it
    threshold, top = scene_stats(yp, Params())
    assert 50.0 < threshold <= 5e4 and top == 5e4
    assert scene_stats(np.zeros((4, 4)), Params())[0] == 0.0  # all dark: no light, no mask


@pytest.mark.parametrize("backend", BACKENDS)
def test_no_olive_blob_in_a_letterboxed_split_pane(backend: str, tmp_path: Path) -> None:
    """End to end, the olive blob: split view (gazehdr.eye.Eye, as a session runs it)
    with mikamo in the right pane, on a wide image file letterboxed in the 64×48 pane (fitted
    to 64×16: two thirds of the pane are black bars). The image is a wall at 1000 cd/m² with
    a lamp at 3000 cd/m² over its left 10 %: the lamp is the image's top 5 %, the wall is not.

    After 2 s fixating the image's middle, the gaze moves 16 px down into the bottom bar. The
    retina is locked to the eye, so the cells that saw the wall now look at the bar, and those
    that saw the lamp at the bar's left end: the lamp's afterimage there is legitimate (and
    checked to appear, so the model did fire). The wall's is not: it is no top 5 % of the
    scene's light, and only counting the bars in (the bug) made it one, an olive blob over the
    bar. So the bar right of the lamp's columns (x >= 16) must stay black: v < 0.02 (with
    the bars counted it reached ~0.9). The left pane's own (Jacobs) afterimage is not checked."""
    import cv2

    from gazehdr.eye import Eye
    from gazehdr.scenes.image import ImageScene
    from gazehdr.sim.models import Models

    image = np.full((32, 128, 3), 1000.0, np.float32)
    image[:, :13] = 3000.0
    path = tmp_path / "wide.pfm"
    assert cv2.imwrite(str(path), image[..., ::-1])
    panes = [Models("jacobs", "none"), Models("mikamo", "none")]
    eye = Eye(
        ImageScene.open(path, 1.0), (128, 48), Params(), panes,
        backend=backend, seed=0, gaze=(0.25, 0.5), eyes_open=True,
    )  # fmt: skip
    assert eye.pane_size == (64, 48)
    for _ in range(20):
        eye.step(0.1, (0.25, 0.5), True)
    _, right = eye.step(0.05, (0.25, 0.5), True)
    assert right[:16].max() < 0.02 and right[32:].max() < 0.02  # the bars, before: black
    assert right[16:32].mean() > 0.3  # the image shows
    for _ in range(5):
        _, right = eye.step(0.1, (0.25, 40 / 48), True)  # in the bottom bar
        bar = right[32:]
        assert bar[:, :16].max() > 0.3  # the lamp's afterimage, where the retina carries it
        lit = float(bar[:, 16:].max())
        assert lit < 0.02, f"the bar lit up (an olive blob): v up to {lit:.3f}"
