"""The acuity baselines (server/sim/baselines/acuity*.py): OpenCL against the NumPy reference,
and what each model must do.

Frames are small, seen at about 64 px/deg (the paper's geometry: the viewing distance is scaled
with the frame width), so the blurs are as wide in pixels as on the paper's monitor.

Tolerances: G of OpenCL (float32, relaxed math) against the float64 reference, relative 1e-4
(measured below 2e-6) plus the 2^-11 of G's 16 bits on the device (lum16.py); `none` exactly
the scene in those 16 bits; v absolute 2e-3 (as tests/test_sim_backends.py).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from gazehdr.sim import Params, Simulator, lum16
from gazehdr.sim.baselines.acuity import (
    ThompsonAcuityReference,
    acuity_limit_cpd,
    sigma_constants,
)
from gazehdr.sim.layout import Layout, NoiseField
from gazehdr.sim.params import Geometry
from gazehdr.sim.reference import ReferenceBackend

W, H = 64, 48
MODELS = ("none", "gaussian", "bilateral", "thompson")
BACKENDS = ("reference", "opencl")
LEVELS = {"photopic": 300.0, "mesopic": 0.1, "scotopic": 3e-4}  # cd/m^2, mean of the texture
REL_TOL = 1e-4 + lum16.PRECISION


def params_64ppd(width: int = W, **changes) -> Params:
    """The paper's 64 px/deg for a frame `width` px wide: the default screen seen from farther."""
    return Params(geometry=Geometry(viewing_distance_m=1920 / width), **changes)


def textured(level: float, seed: int = 0, width: int = W, height: int = H) -> np.ndarray:
    """Log-normal texture with a bright bar and a dark patch, scaled so its mean is ~ level."""
    rng = np.random.default_rng(seed)
    scene = np.exp(rng.normal(0.0, 0.6, (height, width, 3)))
    scene[10:14, 5:40] *= 30.0
    scene[30:40, 40:55] *= 0.05
    return (level * scene / scene.mean()).astype(np.float32)


def run(model: str, backend: str, scene: np.ndarray, params: Params, seed: int = 0, **step):
    sim = Simulator(scene.shape[1], scene.shape[0], params, backend, seed, acuity=model)
    sim.load_scene(scene)
    v = sim.step(step.pop("dt", 1 / 30), **step)
    return sim, sim._backend.get("G").astype(np.float64), v


def as_stored(backend: str, scene: np.ndarray) -> np.ndarray:
    """The scene as `backend` keeps G (3×H×W float64): OpenCL's in its 16 bits."""
    planes = scene.transpose(2, 0, 1)
    return (lum16.decode(lum16.encode(planes)) if backend == "opencl" else planes).astype(float)


def high_frequency(img: np.ndarray) -> float:
    """Energy of neighbour differences, relative to the image's own energy."""
    img = np.asarray(img, np.float64)
    return float((np.diff(img, axis=-1) ** 2).mean() + (np.diff(img, axis=-2) ** 2).mean()) / float(
        (img**2).mean()
    )


@pytest.mark.parametrize("level", LEVELS)
@pytest.mark.parametrize("model", MODELS)
def test_opencl_matches_reference(model: str, level: str) -> None:
    p = params_64ppd()
    scene = textured(LEVELS[level], seed=3)
    for gaze, dt in (((20.0, 12.0), 1 / 30), ((50.5, 35.25), 0.4), ((-30.0, 100.0), 1 / 60)):
        _, ref, v_ref = run(model, "reference", scene, p, seed=5, gaze=gaze, dt=dt)
        _, dev, v_dev = run(model, "opencl", scene, p, seed=5, gaze=gaze, dt=dt)
        err = np.abs(dev - ref) / np.maximum(np.abs(ref), 1e-9 * LEVELS[level])
        if model == "none":
            assert np.array_equal(dev, as_stored("opencl", scene))
        assert err.max() <= REL_TOL, f"{model} at {level}: worst relative error {err.max():.3g}"
        assert np.abs(v_dev - v_ref).max() <= 2e-3


@pytest.mark.parametrize("backend", BACKENDS)
def test_none_is_the_identity(backend: str) -> None:
    scene = textured(1e-3, seed=1)
    _, G, _ = run("none", backend, scene, params_64ppd())
    assert np.array_equal(G, as_stored(backend, scene))


@pytest.mark.parametrize("backend", BACKENDS)
def test_gaussian_blurs_more_as_light_falls(backend: str) -> None:
    p = params_64ppd()
    hf = []
    for level in (1000.0, 1.0, 0.03, 1e-3, 1e-5):
        scene = textured(level, seed=2)
        _, G, _ = run("gaussian", backend, scene, p, gaze=(32.0, 24.0))
        if level >= 10**p.A_min:  # the viewer's eye at the display resolves as much
            assert np.array_equal(G, as_stored(backend, scene))
        hf.append(high_frequency(G) / high_frequency(as_stored(backend, scene)))
    assert hf[0] == pytest.approx(1.0, abs=1e-12)
    assert all(a > b for a, b in itertools.pairwise(hf)), hf
    assert hf[-1] < 0.1, hf


def test_gaussian_passes_the_cutoff_response_at_the_acuity_limit() -> None:
    """A grating at R(L) cycles/deg keeps acuity_cutoff_response of its contrast through the
    simulated blur and the viewer's own (at 10^A_min) together: checks the px/deg units."""
    width, height, level = 256, 16, 1e-3
    p = params_64ppd(width)
    ppd = Layout.for_frame(width, height, p).ppd
    f = float(acuity_limit_cpd(math.log10(level))) / ppd  # cycles per px
    x = np.arange(width) + 0.5
    row = level * (1.0 + 0.1 * np.sin(2 * math.pi * f * x))
    scene = np.repeat(np.repeat(row[None, :, None], height, 0), 3, 2).astype(np.float32)
    _, G, _ = run("gaussian", "reference", scene, p, gaze=(width / 2, height / 2))
    mid = slice(width // 4, 3 * width // 4)
    basis = np.stack([np.sin(2 * math.pi * f * x), np.cos(2 * math.pi * f * x), np.ones(width)])
    amp = np.linalg.lstsq(basis[:, mid].T, G[1, height // 2, mid], rcond=None)[0]
    measured = math.hypot(amp[0], amp[1]) / amp[2] / 0.1
    _, s_disp2, _ = sigma_constants(p)
    eye = math.exp(-2 * math.pi**2 * s_disp2 * (f * ppd) ** 2)
    assert measured * eye == pytest.approx(p.acuity_cutoff_response, rel=0.02)


def edge_scene(width: int = W, height: int = H) -> np.ndarray:
    """Two scotopic halves two log units apart, each with a faint texture."""
    rng = np.random.default_rng(4)
    scene = np.exp(rng.normal(0.0, 0.05, (height, width, 3))) * 1e-4
    scene[:, width // 2 :] *= 100.0
    return scene.astype(np.float32)


def rise_width(G: np.ndarray) -> int:
    """Columns whose mean lies between 10 % and 90 % of the way from the dark to the bright side."""
    prof = np.log10(G[1].mean(axis=0))
    u = (prof - prof[:8].mean()) / (prof[-8:].mean() - prof[:8].mean())
    return int(((u > 0.1) & (u < 0.9)).sum())


@pytest.mark.parametrize("backend", BACKENDS)
def test_bilateral_keeps_a_strong_edge_sharper_than_gaussian(backend: str) -> None:
    p = params_64ppd()
    scene = edge_scene()
    gaze = (W / 2, H / 2)  # the uniform blur takes the luminance at the edge
    _, Gg, _ = run("gaussian", backend, scene, p, gaze=gaze)
    _, Gb, _ = run("bilateral", backend, scene, p, gaze=gaze)
    assert rise_width(Gg) >= 4
    assert rise_width(Gb) <= 1
    # ...while the faint texture on each side is still blurred.
    left = np.s_[:, 4:-4, 4 : W // 2 - 12]
    assert high_frequency(Gb[left]) < 0.5 * high_frequency(scene.transpose(2, 0, 1)[left])


def thompson_stage(scene: np.ndarray, p: Params, seed: int):
    lay = Layout.for_frame(scene.shape[1], scene.shape[0], p)
    backend = ReferenceBackend(lay, p)
    backend.set_scene(np.ascontiguousarray(scene.transpose(2, 0, 1)))
    backend.prepare(1.0)
    stage = ThompsonAcuityReference(backend, seed)
    noise = NoiseField(lay, p, seed)

    def at(t: float) -> np.ndarray:
        stage.acuity(noise.at(t), (20.0, 20.0), t)
        return backend.get("G")

    return at


def test_thompson_noise_changes_at_its_rate_and_follows_the_seed() -> None:
    p = params_64ppd()
    hz = p.thompson_noise_hz
    scene = textured(1e-3, seed=5)
    at = thompson_stage(scene, p, seed=7)
    g1, g2, g3 = at(1.2 / hz), at(1.7 / hz), at(2.2 / hz)
    assert np.array_equal(g1, g2)  # same noise frame
    assert not np.allclose(g1, g3, rtol=1e-3)  # the next one
    assert np.array_equal(thompson_stage(scene, p, seed=7)(2.2 / hz), g3)
    assert not np.allclose(thompson_stage(scene, p, seed=8)(2.2 / hz), g3, rtol=1e-3)


@pytest.mark.parametrize("backend", BACKENDS)
def test_thompson_noise_has_the_stated_sigma(backend: str) -> None:
    """On a flat field: sigma = thompson_noise (1 - rho_c), neighbours uncorrelated, mean 1."""
    width, height = 160, 120
    p = params_64ppd(width)
    for level, rho_c in ((1e-4, 0.0), (0.1, 0.5), (100.0, 1.0)):  # log10 L = m2 + rho_c (m1 - m2)
        flat = np.full((height, width, 3), level, np.float32)
        _, G, _ = run("thompson", backend, flat, p, seed=11, dt=0.25)
        ratio = G[1] / level
        sigma = p.thompson_noise * (1.0 - rho_c)
        assert ratio.std() == pytest.approx(sigma, rel=0.03, abs=1e-6)
        assert ratio.mean() == pytest.approx(1.0, abs=3 * sigma / math.sqrt(ratio.size) + 1e-6)
        if sigma:
            n = (ratio - 1.0) / sigma
            assert abs((n[:, 1:] * n[:, :-1]).mean()) < 0.03
            assert abs((n[1:] * n[:-1]).mean()) < 0.03
        assert np.allclose(G[0], G[1]) and np.allclose(G[2], G[1])  # colour kept


def test_thompson_keeps_edges_crisper_than_its_blur() -> None:
    """The edge band: Thompson's transition is steeper than the plain Gaussian of the same sigma."""
    p = params_64ppd(thompson_noise=0.0)
    scene = edge_scene()
    scene[:, W // 2 :] /= 10.0  # one log unit
    gaze = (W / 2, H / 2)
    _, Gg, _ = run("gaussian", "reference", scene, p, gaze=gaze)
    _, Gt, _ = run("thompson", "reference", scene, p, gaze=gaze)
    assert rise_width(Gt) < rise_width(Gg)


SCENES = {
    "darkness": lambda: np.zeros((H, W, 3), np.float32),
    "1e8": lambda: np.full((H, W, 3), 1e8, np.float32),
    "mixed": lambda: (
        np.where(np.arange(W)[None, :, None] < W // 2, 0.0, 1e8)
        .repeat(H, 0)
        .repeat(3, 2)
        .astype(np.float32)
    ),
}


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("model", MODELS)
def test_no_nan_or_inf_at_the_edges(model: str, backend: str) -> None:
    for name, make in SCENES.items():
        sim = Simulator(W, H, params_64ppd(), backend, seed=1, acuity=model)
        sim.load_scene(make())
        for dt, gaze in ((0.0, (W / 2, H / 2)), (1.0, (-500.0, 900.0)), (1 / 30, (0.0, 0.0))):
            v = sim.step(dt, gaze=gaze)
            G = sim._backend.get("G")
            assert np.isfinite(G).all() and (G >= 0).all(), (name, dt)
            assert np.isfinite(v).all() and (v >= 0).all() and (v <= 1).all(), (name, dt)
        if name == "darkness":
            assert not G.any()


def test_bad_acuity_parameters_are_refused() -> None:
    for change in (
        {"acuity_cutoff_response": 1.0},
        {"acuity_sigma_max_deg": 0.0},
        {"bilateral_sigma_r": -1.0},
        {"thompson_noise": float("nan")},
        {"thompson_noise_hz": 0.0},
        {"thompson_dog_ratio": 0.5},
    ):
        with pytest.raises(ValueError):
            Params(**change)
