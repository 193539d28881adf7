"""The `ritschel` afterimage model (Ritschel & Eisemann 2012): oRGB, kinetics, colours, backends.

Tolerances: oRGB round trips 1e-12 in float64 (reference), 2e-5 relative in float32 (kernel);
OpenCL against the reference: state (in [0, 1]) and maps (linear display RGB, 1 = white)
absolute 1e-4, v absolute 2e-3 (half an 8-bit step) outside pixels whose acuity band differs.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from gazehdr.figures.common import Context, hue_angle, native_geometry
from gazehdr.figures.look_away import (
    FIELD_GAZE,
    afterimage_ratio,
    mean_over,
    square_rects,
    squares_run,
    surround_rects,
)
from gazehdr.sim import Params, Simulator
from gazehdr.sim.baselines.ritschel import (
    hue_forward,
    hue_inverse,
    opponent,
    opponent_chroma,
    orgb_to_rgb,
    rgb_to_orgb,
)
from gazehdr.sim.layout import LMS_TO_RGB, RGB_TO_LMS
from tests.measures import spread

BACKENDS = ["reference", "opencl"]
W, H = 64, 48
GAZE = (32.0, 24.0)
GREY = 30.0  # cd/m^2, the background of the flash tests


def sim(backend: str, params: Params | None = None, **kw) -> Simulator:
    return Simulator(W, H, params=params, backend=backend, seed=5, afterimage="ritschel", **kw)


def patch_scene(colour, background: float = GREY) -> np.ndarray:
    scene = np.full((H, W, 3), background, np.float32)
    scene[18:30, 26:38] = colour
    return scene


def centre_add(s: Simulator) -> np.ndarray:
    """The additive afterimage (linear RGB) at the retina cell the gaze rests on."""
    maps = s._backend.get("maps")
    return maps[3:, maps.shape[1] // 2, maps.shape[2] // 2].astype(np.float64)


def flash_then(backend: str, colour, after_s: float, eyes_open: bool) -> Simulator:
    """1 s on the patch, then `after_s` on the plain background (or with the eyes closed)."""
    s = sim(backend)
    s.load_scene(patch_scene(colour))
    s.step(0.0, gaze=GAZE)
    for _ in range(10):
        s.step(0.1, gaze=GAZE)
    s.load_scene(patch_scene(GREY), reset=False)
    for _ in range(round(after_s / 0.1)):
        s.step(0.1, gaze=GAZE, eyes_open=eyes_open)
    return s


# --- oRGB ----------------------------------------------------------------------------------------


def test_orgb_round_trip_float64() -> None:
    rng = np.random.default_rng(0)
    rgb = rng.uniform(-1.0, 2.0, (3, 5000))  # gamma-encoded, out-of-gamut values included
    assert np.abs(orgb_to_rgb(rgb_to_orgb(rgb)) - rgb).max() < 1e-12
    orgb = np.concatenate([rng.uniform(0, 1, (1, 5000)), rng.uniform(-1, 1, (2, 5000))])
    assert np.abs(rgb_to_orgb(orgb_to_rgb(orgb)) - orgb).max() < 1e-12
    # The opponent is an involution in oRGB, for any colour and flight angle ...
    assert np.abs(opponent_chroma(opponent_chroma(orgb, 0.7), -0.7) - orgb).max() < 1e-12
    # ... and so through gamma coding where both colours lie in the gamut (near the grey axis).
    lin = rng.uniform(0.3, 0.6, (3, 1000))
    assert np.abs(opponent(opponent(lin, 0.0, 0.455), 0.0, 0.455) - lin).max() < 1e-12


def test_orgb_is_the_published_space() -> None:
    """Bratkova et al.: primaries and yellow land on the opponent axes, hue map piecewise."""
    cases = {  # R'G'B' -> (L', C_yb, C_rg)
        (1, 0, 0): (0.299, 0.0, 1.0),
        (0, 1, 0): (0.587, 0.0, -1.0),
        (0, 0, 1): (0.114, -1.0, 0.0),
        (1, 1, 0): (0.886, 1.0, 0.0),
        (0.5, 0.5, 0.5): (0.5, 0.0, 0.0),
    }
    for rgb, orgb in cases.items():
        assert rgb_to_orgb(np.array(rgb, float)) == pytest.approx(orgb, abs=1e-4)
    pi = math.pi
    theta = np.array([0.0, pi / 6, pi / 3, pi / 2, 2 * pi / 3, pi])
    expect = np.array([0.0, pi / 4, pi / 2, pi / 2 + pi / 8, 3 * pi / 4, pi])
    assert hue_forward(theta) == pytest.approx(expect, abs=1e-12)
    assert hue_forward(-theta) == pytest.approx(-expect, abs=1e-12)
    t = np.linspace(-pi, pi, 1001)
    assert hue_inverse(hue_forward(t)) == pytest.approx(t, abs=1e-12)


@pytest.mark.parametrize("backend", BACKENDS)
def test_kernel_orgb_round_trip(backend: str) -> None:
    """A flight-of-colours half turn undoes the opponent: in darkness with c_d = 0 and no blur
    the maps are then exactly max(LMS_TO_RGB r, 0), through gamma, oRGB and back."""
    p = Params(c_d=0.0, ritschel_N_sigma_deg=0.0, ritschel_flight_rate=math.pi)
    s = sim(backend, p)
    s.step(0.0, gaze=GAZE)  # the first step settles the eye; the state is set after it
    rng = np.random.default_rng(1)
    r = rng.uniform(0.0, 1.0, s._backend.get("state").shape)
    s._backend.put("state", r)
    s.step(1.0, gaze=GAZE)
    expect = np.maximum(np.tensordot(LMS_TO_RGB, r, axes=1), 0.0)
    got = s._backend.get("maps")[3:]
    assert (expect < 0.05).mean() > 0.05  # clamped negative chroma was among the cases
    assert np.abs(got - expect).max() < 2e-5 * max(1.0, expect.max())
    assert (s._backend.get("maps")[:3] == 1.0).all()


def bleaching_add(backend: str, e_lms) -> np.ndarray:
    """maps[3:6] for a uniform excess bleaching `e_lms` (L, M, S): in darkness r_inf = 0, and
    with c_d = 0 (no recovery) and no diffusion r stays what it was set to, so e = r."""
    s = sim(backend, Params(c_d=0.0, ritschel_N_sigma_deg=0.0))
    s.step(0.0, gaze=GAZE)  # the first step settles the eye; the state is set after it
    shape = s._backend.get("state").shape
    s._backend.put("state", np.broadcast_to(np.asarray(e_lms, float)[:, None, None], shape))
    s.step(1.0, gaze=GAZE)
    return s._backend.get("maps")[3:].reshape(3, -1).astype(np.float64)


@pytest.mark.parametrize("backend", BACKENDS)
def test_blue_bleaching_leaves_the_orgb_yellow(backend: str) -> None:
    """The opponent colour of a blue bleaching, by hand from oRGB's definition (Bratkova et al.
    Eq. 1-2), gamma v = J^0.455, default strength 1.

    (a) A bleaching whose linear RGB is (-0.05, 0, 0.4) (its LMS is >= 0; an S-dominated excess
    has small negative components like this one, Fig. 9's squares leave -0.057 in R):
      encoded: only what a display can show, max(J, 0)^γ = (0, 0, β), β = 0.4^γ;
      oRGB: L' = 0.114 β, C1 = 0.5 (0 + 0) - β = -β, C2 = 0.866 (0 - 0) = 0: the angle is π,
        which the hue map keeps: (L', C_yb, C_rg) = (0.114 β, -β, 0), pure blue;
      opponent: (0.114 β, +β, 0), on the +C_yb (yellow) axis; angle 0, kept by the inverse map;
      back: R' = G' = x, B' = y with 0.886 x + 0.114 y = 0.114 β and x - y = β: x = 0.228 β,
        y = -0.772 β, outside the gamut;
      into the gamut at the same luma and hue: R'G'B' - L' = (0.114, 0.114, -0.886) β shrunk by
        s = L' / (L' - B') = 0.114 / 0.886: R' = G' = 0.114 β / 0.886, B' = 0;
      decoded: R = G = 0.4 (0.114 / 0.886)^(1/γ) = 0.004414, B = 0: yellow, hue 60°.
    (b) A bleaching of the S cone alone, e = (0, 0, 1): LMS_TO_RGB[:, 2] = (0.196, -0.207, 1.149)
      (layout.py), encoded (0.476, 0, 1.065); C1 = 0.238 - 1.065 = -0.827, C2 = 0.866 × 0.476 =
      0.412, angle 153.5°, mapped to 90° + 0.75 (153.5° - 60°) = 160.1°; the opponent is at
      -19.9°: on the +C_yb (yellow) side, towards -C_rg (green); unmapped -13.3°, radius 0.924:
      C1 = 0.899, C2 = -0.212, L' = 0.299 × 0.476 + 0.114 × 1.065 = 0.264; back R' = 0.209,
      G' = 0.454, B' = -0.568; into the gamut (s = 0.264 / 0.832 = 0.317) R' = 0.246,
      G' = 0.324, B' = 0; decoded (0.0460, 0.0840, 0): a green-leaning yellow, hue 87°, the
      yellow-green that complements violet (the S cone's own colour).

    Guards (each measured to fail, in the reference and in the kernel): the sign-preserving
    gamma of the linear RGB (R' = -0.05^γ = -0.26 makes (a) a cyan-blue, its opponent red), the
    per-channel clamp of the opponent in place of the gamut mapping ((a) R = G = 0.4 ×
    0.228^(1/γ) = 0.0155; (b) green, 109°), both together (the former model), and (reference)
    dropping the gamma or the inverse hue map. Tolerance: 1e-4 relative (float32 kernel);
    (b) 2e-3, the hand derivation's three digits."""
    blue = bleaching_add(backend, RGB_TO_LMS @ np.array([-0.05, 0.0, 0.4]))
    yellow = 0.4 * (0.114 / 0.886) ** (1 / Params().gamma) * np.array([1.0, 1.0, 0.0])
    assert np.abs(blue - yellow[:, None]).max() < 1e-4 * yellow.max()
    s_only = bleaching_add(backend, [0.0, 0.0, 1.0])
    assert np.abs(s_only - s_only[:, :1]).max() < 1e-6  # uniform
    assert s_only[:, 0] == pytest.approx([0.0460, 0.0840, 0.0], rel=2e-3, abs=1e-6)
    assert 60.0 < hue_angle(s_only[:, 0]) < 90.0


# --- the kinetics of Listing 1 -------------------------------------------------------------------


def test_defaults_are_the_papers() -> None:
    """Sec. 3.1: c_a = 0.3 and c_d = 1.0 c_a; Listing 1 with a single iteration (n = 1)."""
    p = Params()
    assert p.c_a == 0.3 and p.c_d == p.c_a and p.ritschel_steps == 1


def cone_input(scene: np.ndarray, s: Simulator, gaze: tuple[int, int]) -> np.ndarray:
    """L of Eq. 3 at every retina cell, for 1-px cells and a whole-pixel gaze: cell (i, j)
    sees pixel (gaze + (i, j) - grid/2) exactly, nothing off screen; divided by L_ref."""
    lay = s.layout
    assert lay.cell == 1
    lms = np.einsum("ij,hwj->ihw", RGB_TO_LMS, scene.astype(np.float64))
    L = np.zeros((3, lay.grid_h, lay.grid_w))
    y0, x0 = lay.grid_h // 2 - gaze[1], lay.grid_w // 2 - gaze[0]
    L[:, y0 : y0 + H, x0 : x0 + W] = lms / s.params.ritschel_L_ref
    return L


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(
    ("dt", "c_a", "c_d", "n"),
    [(0.2, 0.3, 0.3, 1), (5.0, 0.3, 0.3, 1), (3.0, 0.5, 0.2, 3)],
    ids=["small step", "clamped step", "c_a != c_d, n = 3, each clamped"],
)
def test_one_frame_is_listing_1(backend: str, dt: float, c_a: float, c_d: float, n: int) -> None:
    """With both blurs off, a frame from a random state is n explicit Euler steps of Eq. 3 of
    length dt/n, each clamped to [0, 1], per cell and cone, in closed form here. c_a != c_d
    tells the two constants apart. Tolerance: 1e-12 (float64), 2e-6 (float32 kernel)."""
    p = Params(
        c_a=c_a, c_d=c_d, ritschel_steps=n, ritschel_N_sigma_deg=0.0,
        ritschel_saccade_sigma_deg=0.0, surround=0.0,  # a dark room off screen, as cone_input
    )  # fmt: skip
    s = sim(backend, p)
    rng = np.random.default_rng(7)
    scene = np.exp(rng.uniform(np.log(10.0), np.log(3e4), (H, W, 3))).astype(np.float32)
    gaze = (32, 24)
    s.load_scene(scene)
    s.step(0.0, gaze=gaze)
    s._backend.put("state", rng.uniform(0.0, 1.0, s._backend.get("state").shape))
    r = s._backend.get("state").astype(np.float64)  # as stored (float32 on OpenCL)
    s.step(dt, gaze=gaze)
    L = cone_input(scene, s, gaze)
    for _ in range(n):
        r = np.clip(r + dt / n * (c_a * L * (1.0 - r) - c_d * r), 0.0, 1.0)
    got = s._backend.get("state").astype(np.float64)
    assert np.abs(got - r).max() < (1e-12 if backend == "reference" else 2e-6)
    if dt == 5.0:  # the clamp was exercised at both ends: dark cells off screen, bright on it
        assert (r == 0.0).mean() > 0.5 and (r == 1.0).mean() > 0.01


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("sigma_deg", [Params().ritschel_saccade_sigma_deg, 0.4])
def test_micro_saccade_blur_has_its_sigma(backend: str, sigma_deg: float) -> None:
    """One lit retina cell: after one step from r = 0 (c_d = 0, no diffusion) r = dt c_a L of
    the blurred input, so the spread of r is the micro-saccade sigma, ritschel_saccade_sigma_deg
    in cells (within 2 %: a sampled, truncated Gaussian), and the blur keeps the input's sum.
    At the paper's pixel density (64 px/°, 6-px cells), where 0.08° is 0.85 cells."""
    w, h = 192, 128
    p = native_geometry(w, h).replace(
        c_d=0.0, ritschel_N_sigma_deg=0.0, ritschel_saccade_sigma_deg=sigma_deg
    )
    s = Simulator(w, h, params=p, backend=backend, afterimage="ritschel")
    lay, c = s.layout, s.layout.cell
    gx, gy = lay.low_w // 2, lay.low_h // 2
    gaze = (float(gx * c), float(gy * c))  # a cell corner: the lit cell's centre is sampled
    scene = np.zeros((h, w, 3), np.float32)
    s.load_scene(scene)
    s.step(0.0, gaze=gaze)  # darkness: r = 0
    scene[gy * c : (gy + 1) * c, gx * c : (gx + 1) * c] = p.ritschel_L_ref  # L = 1, all cones
    s.load_scene(scene, reset=False)
    s.step(1.0, gaze=gaze)
    expect = lay.px(sigma_deg) / c
    for plane in s._backend.get("state").astype(np.float64):
        assert plane.sum() == pytest.approx(p.c_a, rel=1e-4) and plane.max() < 1.0
        for axis, centre in ((0, lay.grid_w // 2), (1, lay.grid_h // 2)):
            offset, sigma = spread(plane, axis, centre)
            assert offset == pytest.approx(0.0, abs=1e-4) and sigma == pytest.approx(
                expect, rel=0.02
            )


# --- behaviour -----------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
def test_steady_view_leaves_no_afterimage(backend: str) -> None:
    """A reset is the equilibrium, and fixating long enough returns to it: r -> r_inf(L).
    (Without diffusion: the diffusion of r keeps a faint halo at edges, see the docs.)"""
    s = sim(backend, Params(ritschel_N_sigma_deg=0.0))
    s.load_scene(patch_scene((2e4, 5e3, 1e3)))
    s.step(0.0, gaze=GAZE)
    assert s._backend.get("maps")[3:].max() < 1e-6  # reset: equilibrium (float32 rounding)
    s.step(0.5, gaze=(10.0, 10.0))
    assert s._backend.get("maps")[3:].max() > 0.05  # a move leaves an afterimage ...
    for _ in range(40):
        s.step(0.5, gaze=GAZE)  # ... 20 s of fixation let it settle
    assert s._backend.get("maps")[3:].max() < 1e-3


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("eyes_open", [False, True], ids=["eyes closed", "grey background"])
def test_white_flash_leaves_neutral_brightening_afterimage(backend: str, eyes_open: bool) -> None:
    flash = flash_then(backend, (2e4, 2e4, 2e4), 0.5, eyes_open)
    plain = flash_then(backend, (GREY, GREY, GREY), 0.5, eyes_open)
    add = centre_add(flash)
    assert add.min() > 0.05  # a visible afterimage
    assert np.ptp(add) < 1e-4 * add.max()  # neutral: R = G = B
    assert flash._backend.get("maps")[3:].min() >= 0.0
    v_flash, v_plain = (s._backend.get("v")[24, 32].astype(float) for s in (flash, plain))
    assert (v_flash > v_plain + 0.05).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_red_leaves_green_cyan_afterimage(backend: str) -> None:
    r, g, b = centre_add(flash_then(backend, (3e4, 0.0, 0.0), 0.3, False))
    assert g > 0.02 and g > 3 * r and g >= b


@pytest.mark.parametrize("backend", BACKENDS)
def test_blue_leaves_yellow_afterimage(backend: str) -> None:
    r, g, b = centre_add(flash_then(backend, (0.0, 0.0, 1e5), 0.3, False))
    assert r > 0.02 and g > 0.01 and b < 0.2 * min(r, g)


@pytest.mark.parametrize("backend", BACKENDS)
def test_fig9_blue_squares_leave_a_brighter_yellow(backend: str, tmp_path) -> None:
    """Fig. 9's bottom row at 128×72 (Jacobs et al.: "the blue squares become yellow", and
    Ritschel and Eisemann's afterimage is "strictly brighter than the background"): 3 s on blue
    squares (6000 cd/m² in B) on 100 cd/m² grey, then 0.3 s on the grey beside them. Where the
    squares were, the frame over the grey around it (linear RGB, `afterimage_ratio`) is >= 1 in
    every channel and > 1 in R and G, with a hue of 30-90° (measured 38.8°, on both backends:
    the S pigment saturates before M, so the excess leans to cyan and its opponent to orange).
    Guards (each measured to fail): the sign-preserving gamma of the excess' RGB (hue 29°), the
    per-channel clamp of the opponent in place of the gamut mapping (25°), both (6°, red)."""
    ctx = Context(tmp_path, 128, 72, backend, 0)
    run = squares_run(ctx, "ritschel")
    colours = {
        "afterimage_rgb": mean_over(run.after, square_rects(128, 72, FIELD_GAZE), 0.5),
        "surround_rgb": mean_over(run.after, surround_rects(128, 72, FIELD_GAZE), 1.0),
    }
    ratio = afterimage_ratio(colours)
    assert ratio.min() > 1.0 - 1e-6 and ratio[:2].min() > 1.02  # an overlay, brighter
    assert 30.0 <= hue_angle(ratio) <= 90.0


@pytest.mark.parametrize("backend", BACKENDS)
def test_afterimage_fades(backend: str) -> None:
    s = flash_then(backend, (2e4, 2e4, 2e4), 0.0, False)
    levels = []
    for _ in range(8):
        for _ in range(5):
            s.step(0.1, gaze=GAZE, eyes_open=False)
        levels.append(centre_add(s).mean())
    assert levels[0] > 0.1
    assert all(b < a for a, b in itertools.pairwise(levels))
    assert levels[-1] < 0.5 * levels[0]


@pytest.mark.parametrize("backend", BACKENDS)
def test_diffusion_after_one_second_is_independent_of_frame_rate(backend: str) -> None:
    """σ = N_σ / sqrt(f) per frame: the spread of a point after 1 s is N_σ at any f and n."""
    n_sigma_deg = 3.0
    spreads = []
    for fps, n in ((1, 1), (10, 1), (30, 2)):
        p = Params(c_d=0.0, ritschel_N_sigma_deg=n_sigma_deg, ritschel_steps=n)
        s = sim(backend, p)
        s.step(0.0, gaze=GAZE, eyes_open=False)  # the first step settles; set the state after
        lay = s.layout
        r = np.zeros(s._backend.get("state").shape)
        r[:, lay.grid_h // 2, lay.grid_w // 2] = 1.0
        s._backend.put("state", r)
        for _ in range(fps):
            s.step(1.0 / fps, gaze=GAZE, eyes_open=False)
        plane = s._backend.get("state")[1].astype(np.float64)
        assert plane.sum() == pytest.approx(1.0, rel=1e-4)
        spreads.append(spread(plane, 0, lay.grid_w // 2)[1])
    expect = lay.px(n_sigma_deg) / lay.cell
    assert spreads == pytest.approx([expect] * 3, rel=0.02)


# --- backends, edges, determinism ----------------------------------------------------------------


def mixed_scene(w: int, h: int) -> np.ndarray:
    rng = np.random.default_rng(3)
    scene = np.exp(rng.normal(np.log(0.05), 1.0, (h, w, 3))).astype(np.float32)
    scene[:, w // 2 :] *= 2000
    scene[20:34, 70:90] = 5e6
    scene[40:60, 10:30] = (3e4, 1e3, 10.0)
    scene[5:15, 40:55] = (1.0, 20.0, 3e5)
    return scene


def assert_backends_agree(ref: Simulator, cl: Simulator) -> None:
    a, b = ref._backend, cl._backend
    for name in ("state", "maps"):
        err = np.abs(a.get(name) - b.get(name).astype(np.float64))
        assert err.max() < 1e-4, f"{name}: worst {err.max():.3g}"
    keep = a.get("d") == b.get("d")
    assert keep.mean() > 0.99
    err = np.abs(a.get("v")[keep] - b.get("v")[keep])
    assert err.max() < 2e-3, f"v: worst {err.max():.3g}"


@pytest.mark.parametrize(
    "params",
    [
        Params(),
        # n = 3 steps, colours in flight, strong blurs, 2-pixel retina cells
        Params(
            ritschel_steps=3, ritschel_flight_rate=2.0, ritschel_strength=0.7,
            ritschel_saccade_sigma_deg=1.0, ritschel_N_sigma_deg=3.0, retina_cell_deg=0.5,
        ),
    ],
    ids=["defaults", "steps+flight+blur"],
)  # fmt: skip
def test_opencl_matches_reference(params: Params) -> None:
    w, h = 120, 68
    scene = mixed_scene(w, h)
    sims = [
        Simulator(w, h, params=params, backend=b, seed=1, afterimage="ritschel") for b in BACKENDS
    ]
    for s in sims:
        s.load_scene(scene)
    moves = [
        ((60.0, 34.0), 1 / 30, True),
        ((80.3, 27.1), 0.5, True),
        ((-40.0, 10.0), 1 / 24, False),
        ((15.5, 60.25), 1 / 60, True),
        ((50.0, 30.0), 1.0, False),
    ]
    for i, (gaze, dt, eyes) in enumerate(moves):
        for s in sims:
            s.step(dt, gaze=gaze, eyes_open=eyes)
        assert_backends_agree(*sims)
        if i == 1:  # the lights go down: afterimages everywhere
            for s in sims:
                s.load_scene(scene * 1e-3, reset=False)
    assert sims[0]._backend.get("maps")[3:].max() > 0.1  # there was something to compare


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("level", [0.0, 1e8])
def test_no_nan_or_inf(backend: str, level: float) -> None:
    s = sim(backend)
    scene = patch_scene((level, level, level), background=0.0)
    scene[:, : W // 3] = level
    s.load_scene(scene)
    for dt in (0.0, 1 / 60, 1.0, 0.0):
        for gaze in (GAZE, (-1e6, 3e9), (W + 500.0, -20.0), (0.0, 0.0)):
            for eyes in (True, False):
                v = s.step(dt, gaze=gaze, eyes_open=eyes)
                assert np.isfinite(v).all() and v.min() >= 0.0 and v.max() <= 1.0
                state, maps = s._backend.get("state"), s._backend.get("maps")
                assert np.isfinite(state).all() and np.isfinite(maps).all()
                assert state.min() >= 0.0 and state.max() <= 1.0 + 1e-6 and maps.min() >= 0.0


@pytest.mark.parametrize("backend", BACKENDS)
def test_deterministic(backend: str) -> None:
    p = Params(ritschel_flight_rate=1.5)
    runs = []
    for _ in range(2):
        s = sim(backend, p)
        s.load_scene(patch_scene((3e4, 2e3, 5e4)))
        frames = [s.step(dt, gaze=(30.0 + 3 * k, 20.0), eyes_open=k != 3)
                  for k, dt in enumerate((1 / 30, 0.2, 0.0, 1.0))]  # fmt: skip
        runs.append((frames, s._backend.get("state"), s._backend.get("maps")))
    (f0, s0, m0), (f1, s1, m1) = runs
    assert all(np.array_equal(a, b) for a, b in zip(f0, f1, strict=True))
    assert np.array_equal(s0, s1) and np.array_equal(m0, m1)
