"""Edges: no NaN or Inf ever leaves the simulation, and bad input gets a clear error."""

from __future__ import annotations

import numpy as np
import pytest

from gazehdr.protocol import SIM_OUTPUT, frame_buffer
from gazehdr.sim import Params, Simulator
from gazehdr.sim.models import Models, each_beside_default

W, H = 96, 54
BACKENDS = ["reference", "opencl"]


def check_frame(v: np.ndarray) -> None:
    assert v.shape == (H, W, 3) and v.dtype == np.float32
    assert np.isfinite(v).all()
    assert v.min() >= 0.0 and v.max() <= 1.0


def scenes() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    bad = rng.uniform(0, 100, (H, W, 3)).astype(np.float32)
    bad[3, 4] = np.nan
    bad[10, 10:20] = np.inf
    bad[20, 5] = -np.inf
    bad[30, 30] = -5.0
    mixed = np.zeros((H, W, 3), np.float32)
    mixed[:, W // 2 :] = 1e8
    return {
        "darkness": np.zeros((H, W, 3), np.float32),
        "1e8": np.full((H, W, 3), 1e8, np.float32),
        "dark and 1e8": mixed,
        "nan/inf/negative": bad,
        "float64 huge": np.full((H, W, 3), 1e300),
    }


#: Every model beside the default, each with the other stage at its default.
MODELS = [(m.afterimage, m.acuity) for m in each_beside_default()]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("scene", list(scenes()))
@pytest.mark.parametrize("models", MODELS, ids="+".join)
def test_no_nan_or_inf_out(backend: str, scene: str, models: tuple[str, str]) -> None:
    sim = Simulator(W, H, backend=backend, afterimage=models[0], acuity=models[1])
    sim.load_scene(scenes()[scene])
    assert np.isfinite(sim.adaptation)
    gazes = [(48.0, 27.0), (-1e6, 3e9), (W + 500.0, -20.0), (0.0, 0.0), (W, H)]
    for dt in (0.0, 1 / 60, 1.0, 0.0):
        for gaze in gazes:
            check_frame(sim.step(dt, gaze=gaze))
    check_frame(sim.step(1.0, eyes_open=False))
    check_frame(sim.step(1 / 30, gaze=None))
    for name in ("state", "maps", "G", "rho", "down", "surround"):
        assert np.isfinite(sim._backend.get(name)).all(), name


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("scene", list(scenes()))
def test_sec5_cues_stay_finite(backend: str, scene: str) -> None:
    """The afterimage boost (blinks, saccades, dt = 0 jumps) and the blind spot, at full
    strength, on every edge scene."""
    p = Params(afterimage_boost=1.0, foveal_blind_spot=1.0, tracker_accuracy_deg=0.0)
    sim = Simulator(W, H, params=p, backend=backend)
    sim.load_scene(scenes()[scene])
    for dt in (0.0, 1 / 60, 1.0):
        for gaze in [(48.0, 27.0), (-1e6, 3e9), (0.0, 0.0)]:
            check_frame(sim.step(dt, gaze=gaze))
        check_frame(sim.step(dt, eyes_open=False))
    for name in ("state", "maps", "G", "surround", "fill"):
        assert np.isfinite(sim._backend.get(name)).all(), name


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("models", MODELS, ids="+".join)
def test_total_darkness_is_black(backend: str, models: tuple[str, str]) -> None:
    sim = Simulator(W, H, backend=backend, afterimage=models[0], acuity=models[1])
    sim.load_scene(np.zeros((H, W, 3), np.float32))
    for _ in range(3):
        v = sim.step(1 / 30, gaze=(10.0, 10.0))
    assert v.max() == 0.0
    assert sim.adaptation == pytest.approx(Params().A_min)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("models", MODELS, ids="+".join)
def test_long_darkness_then_light_stays_bounded(backend: str, models: tuple[str, str]) -> None:
    """Calcium saturates in the dark (the 0/0 of Eq. 11); the guard keeps alpha finite."""
    sim = Simulator(W, H, backend=backend, afterimage=models[0], acuity=models[1])
    sim.load_scene(np.zeros((H, W, 3), np.float32))
    for _ in range(30):
        sim.step(1.0, gaze=(48.0, 27.0))
    sim.load_scene(np.full((H, W, 3), 1e8, np.float32), reset=False)
    check_frame(sim.step(1 / 60, gaze=(48.0, 27.0)))


@pytest.mark.parametrize("scene", ["darkness", "1e8", "dark and 1e8", "nan/inf/negative"])
def test_the_level_stack_and_the_late_gaze_at_the_edges(scene: str, monkeypatch) -> None:
    """A scene that stays long enough for acuity from its level stack (level_stack.py),
    stepped by dt = 0 and 1/60, each frame also seen from a late gaze far off the screen
    (`Simulator.frame`): finite frames in range, and the same frames (to v's oracle tolerance)
    as a simulator that blurs every frame in the tiled bank."""
    from gazehdr.sim.level_stack import LEVEL_STACK_AFTER_FRAMES

    stacked = Simulator(W, H, backend="opencl", seed=2)
    monkeypatch.setenv("GAZEHDR_CL_ACUITY", "tiles")
    tiled = Simulator(W, H, backend="opencl", seed=2)
    for sim in (stacked, tiled):
        sim.load_scene(scenes()[scene])
    for i in range(LEVEL_STACK_AFTER_FRAMES + stacked.params.bands + 4):
        dt, gaze = (0.0, (48.0, 27.0)) if i % 3 == 0 else (1 / 60, (20.0 + i, 30.0))
        frames = [sim.step(dt, gaze=gaze) for sim in (stacked, tiled)]
        late = [sim.frame(gaze=(-1e6, 3e9)) for sim in (stacked, tiled)]
        for v in (*frames, *late):
            check_frame(v)
    assert stacked._backend._stack.levels == stacked.params.bands  # picking from the stack
    assert tiled._backend._stack.stride is None  # no stack: the tiled bank every frame
    np.testing.assert_allclose(frames[0], frames[1], atol=2e-3)
    np.testing.assert_allclose(late[0], late[1], atol=2e-3)
    assert np.isfinite(stacked._backend.get("G")).all()


@pytest.mark.parametrize("models", MODELS, ids="+".join)
def test_dt_zero_changes_nothing(models: tuple[str, str]) -> None:
    sim = Simulator(W, H, backend="reference", afterimage=models[0], acuity=models[1])
    sim.load_scene(scenes()["dark and 1e8"])
    a = sim.step(0.5, gaze=(30.0, 20.0))
    b = sim.step(0.0, gaze=(30.0, 20.0))
    # Only float rounding of (B - B_inf) + B_inf in the state; a blurring acuity model puts
    # mid-range values beside the dark/1e8 edge, where it shows as ~1e-6 in v.
    np.testing.assert_allclose(a, b, atol=1e-5)


def test_scene_is_fitted_keeping_its_aspect() -> None:
    sim = Simulator(W, H, backend="reference")
    tall = np.full((200, 50, 3), 100.0, np.float32)
    sim.load_scene(tall)
    scene = sim._backend.get("scene")
    assert scene.shape == (3, H, W)
    row = scene[0, H // 2]
    lit = np.flatnonzero(row > 0)
    assert lit.size == round(50 * H / 200)  # 54 rows tall -> 13.5 -> 14 columns wide
    assert row[0] == 0.0 and row[-1] == 0.0  # black bars at the sides
    np.testing.assert_allclose(scene[:, :, lit], 100.0, rtol=1e-5)


@pytest.mark.parametrize(
    ("width", "height", "message"),
    [(8, 54, "width"), (96, 5000, "height"), (96.5, 54, "integer"), (0, 0, "width")],
)
def test_bad_sizes_are_refused(width, height, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Simulator(width, height, backend="reference")


def test_bad_inputs_are_refused_clearly() -> None:
    sim = Simulator(W, H, backend="reference")
    with pytest.raises(ValueError, match="H×W×3"):
        sim.load_scene(np.zeros((H, W), np.float32))
    with pytest.raises(ValueError, match="numeric"):
        sim.load_scene(np.full((H, W, 3), "x"))
    for dt in (-0.1, float("nan"), float("inf"), 3600.0):
        with pytest.raises(ValueError, match="dt"):
            sim.step(dt)
    for gaze in ((float("nan"), 1.0), (1.0, float("inf")), (1.0,), "ab", None.__class__):
        with pytest.raises(ValueError, match="gaze"):
            sim.step(0.1, gaze=gaze)
    with pytest.raises(ValueError, match="backend"):
        Simulator(W, H, backend="cuda")
    sim.step(0.1)  # still usable after the errors


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ValueError, match="b2"):
        Params(b2=(0.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="m1"):
        Params(m1=-3.0)
    with pytest.raises(ValueError, match="fovea_sigma_deg"):  # the fall-off divides by it
        Params(fovea_sigma_deg=0.0)
    with pytest.raises(ValueError, match="alpha_eps"):  # contrast_floor takes log(1 - eps)
        Params(alpha_eps=1.0)
    with pytest.raises(ValueError, match="unknown parameter"):
        Params.from_dict({"a3": 1.0})
    assert Params.from_dict(Params().to_dict()) == Params()


@pytest.mark.parametrize("scene", list(scenes()))
def test_wire_outputs_stay_in_range_at_the_edges(scene: str) -> None:
    """The kernels that encode for the wire (f16, RGB10_A2) see the same extremes as `v`:
    darkness, 1e8 cd/m^2, NaN/Inf input, gaze far off screen, dt = 0 and 1 s; composed into a
    frame's message (the server's path) they give the same words, and the header's rho at
    the gaze is finite."""
    sims = {out: Simulator(W, H, backend="opencl") for out in ("float16", "rgb10a2")}
    encodings = {output: encoding for encoding, output in SIM_OUTPUT.items()}
    for out, sim in sims.items():
        sim.load_scene(scenes()[scene])
        for dt, gaze in [(0.0, (48.0, 27.0)), (1.0, (-1e6, 3e9)), (1 / 60, (W, H))]:
            frame = sim.step(dt, gaze=gaze, output=out)
            _, pixels = frame_buffer(W, H, encodings[out])
            assert np.array_equal(sim.frame(out, out=pixels), frame)
            assert np.isfinite(sim.rho_at_gaze())
            if out == "float16":
                assert np.isfinite(frame).all() and frame.min() >= 0 and frame.max() <= 1
            else:
                assert frame.shape == (H, W) and (frame >> 30 == 0).all()  # 30 bits used


def test_models_are_chosen_by_name() -> None:
    assert Models.parse("ritschel") == Models("ritschel", "stochastic")
    assert Models.parse("jacobs+thompson") == Models("jacobs", "thompson")
    assert Models.parse("+none") == Models("jacobs", "none")
    assert str(Models("mikamo", "bilateral")) == "mikamo+bilateral"
    with pytest.raises(ValueError, match=r"unknown afterimage model 'glare'.*jacobs"):
        Simulator(W, H, backend="reference", afterimage="glare")
    with pytest.raises(ValueError, match=r"unknown acuity model 'sharp'.*stochastic"):
        Models.parse("jacobs+sharp")
