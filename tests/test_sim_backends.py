"""The OpenCL kernels against the NumPy reference, stage by stage and end to end.

Tolerances (float32 kernels vs float64 reference, relaxed math):
- maps of radiance (down, surround, fill) and the state's adapted light x (light over sigma,
  unbounded): relative 1e-4;  rho, A, the state's B and c (in [0,1]): absolute 1e-4;
- G: relative 1e-4 plus 2^-11 for each time it is stored in its 16 bits on the device
  (lum16.py): by the acuity, and again by the blind spot (Sec. 5); v keeps its tolerance;
- afterimage maps: relative 5e-4 (pow and exp of float32 inputs; the additive RGB term relative
  to its largest channel, see `magnitude`);  v: absolute 2e-3, about half an 8-bit step.
- Acuity band choices are thresholds on a continuous q; where q lies within float32 rounding of
  a threshold the two may pick neighbouring levels. We allow that on at most 0.2 % of pixels.
"""

from __future__ import annotations

import time

import numpy as np
import pyopencl as cl
import pytest

from gazehdr.sim import Geometry, Params, Simulator, lum16
from gazehdr.sim.cl_program import VECTOR_WIDTHS
from gazehdr.sim.layout import Layout, NoiseField, bilinear, bilinear_at
from gazehdr.sim.opencl import OpenCLBackend
from gazehdr.sim.reference import ReferenceBackend

W, H = 120, 68
TOL = {"down": 1e-4, "rho": 1e-4, "A": 1e-4, "state": 1e-4, "maps": 5e-4}
TOL["G"] = 1e-4 + 2 * lum16.PRECISION
TOL |= {"surround": 1e-4, "fill": 1e-4, "light": 1e-4}
RELATIVE = {"down", "surround", "fill", "maps", "G", "light"}


def mixed_scene(seed: int) -> np.ndarray:
    """A dark room, a mid-grey wall, a very bright source and saturated colours, with texture."""
    rng = np.random.default_rng(seed)
    scene = np.exp(rng.normal(np.log(0.05), 1.0, (H, W, 3))).astype(np.float32)
    scene[:, W // 2 :] *= 2000
    scene[20:34, 70:90] = 5e6
    scene[40:60, 10:30] = (0.02, 0.004, 0.001)
    scene[5:15, 40:55] = (1.0, 20.0, 300.0)
    return scene


def assert_close(name: str, ref: np.ndarray, cl: np.ndarray, frac_allowed: float = 0.0) -> None:
    ref = ref.astype(np.float64)
    cl = cl.astype(np.float64)
    err = np.abs(ref - cl)
    if name in RELATIVE:
        err = err / np.maximum(magnitude(name, ref), 1e-3)
    bad = err > TOL.get(name, 2e-3)
    assert bad.mean() <= frac_allowed, (
        f"{name}: {bad.sum()} of {bad.size} values off, worst {err.max():.3g}"
    )


def assert_state_close(ref: np.ndarray, cl: np.ndarray) -> None:
    """The jacobs state: B and c (planes 0-5, in [0, 1]) and the adapted light x (6-8)."""
    assert ref.shape == cl.shape
    assert_close("state", ref[:6], cl[:6])
    assert_close("light", ref[6:], cl[6:])


def magnitude(name: str, ref: np.ndarray) -> np.ndarray:
    """What an error is relative to: the value, except for the afterimage maps' additive term,
    whose three RGB planes are H times the cones' bleaching terms: H mixes the cones with
    opposite signs, so one channel can be a small difference of large terms, and the error is
    relative to the term's size, its largest channel."""
    if name != "maps":
        return np.abs(ref)
    add = np.abs(ref[3:]).max(axis=0, keepdims=True)
    return np.concatenate([np.abs(ref[:3]), np.broadcast_to(add, ref[3:].shape)])


BUILDS = [(vec, False) for vec in VECTOR_WIDTHS] + [(8, True)]


@pytest.fixture(params=BUILDS, ids=lambda b: f"vec{b[0]}" + ("-portable" if b[1] else ""))
def vec(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> int:
    """Each width the kernels build for (pixels a work-item, cl_program.vector_width), whatever
    this machine's own: 16 where PoCL builds for AVX-512, 8 on GPUs and other CPUs; and 8 as
    GPUs build them (GAZEHDR_CL_PORTABLE: the builtins in place of PoCL's x86 ones)."""
    width, portable = request.param
    monkeypatch.setenv("GAZEHDR_VEC", str(width))
    monkeypatch.setenv("GAZEHDR_CL_PORTABLE", "1" if portable else "")
    return width


def compare_all(ref: ReferenceBackend, cl: OpenCLBackend) -> None:
    for name in ("down", "surround", "fill", "rho", "A", "maps"):
        assert_close(name, ref.get(name), cl.get(name))
    assert_state_close(ref.get("state"), cl.get("state"))
    # Pixels whose band choice differs are counted once, in d; elsewhere G and v must match.
    flipped = ref.get("d") != cl.get("d")
    assert flipped.mean() <= 0.002
    keep = ~flipped
    assert_close("G", ref.get("G")[:, keep], cl.get("G")[:, keep])
    assert_close("v", ref.get("v")[keep], cl.get("v")[keep])


@pytest.mark.parametrize("seed", [0, 1, 7])
def test_pipeline_matches_reference(seed: int, vec: int) -> None:
    rng = np.random.default_rng(100 + seed)
    sims = [Simulator(W, H, backend=b, seed=seed) for b in ("reference", "opencl")]
    assert sims[1]._backend.vec == vec
    scene = mixed_scene(seed)
    for s in sims:
        s.load_scene(scene)
    gazes = [(60.0, 34.0), (80.3, 27.1), (-40.0, 10.0), (15.5, 60.25)]
    for i, gaze in enumerate(gazes):
        dt = float(rng.choice([1 / 60, 1 / 24, 0.5]))
        eyes = i != 2
        for s in sims:
            s.step(dt, gaze=gaze, eyes_open=eyes)
        compare_all(sims[0]._backend, sims[1]._backend)
        if i == 1:  # the light goes off: afterimages everywhere
            for s in sims:
                s.load_scene(scene * 1e-3, reset=False)


OPTIONS = {
    "visible": {"bleach_display_gain": 32.0, "bleach_equivalent_light": True},
    "per-cone": {"gain_along_adapting_light": False},
    "no-purkinje": {"purkinje": False},
}


@pytest.mark.parametrize("option", list(OPTIONS))
def test_each_option_of_ours_matches_reference(option: str) -> None:
    """The `visible` preset and the switches: a kernel that ignores one differs from the
    reference where its part of the model acts (the light goes off: afterimages; a dim room:
    the Purkinje shift)."""
    p = Params(**OPTIONS[option])
    sims = [Simulator(W, H, params=p, backend=b, seed=2) for b in ("reference", "opencl")]
    scene = mixed_scene(2)
    for s in sims:
        s.load_scene(scene)
    for k, gaze in enumerate([(60.0, 34.0), (80.3, 27.1), (30.0, 40.0)]):
        for s in sims:
            s.step(0.25, gaze=gaze)
        compare_all(sims[0]._backend, sims[1]._backend)
        if k == 0:
            for s in sims:
                s.load_scene(scene * 1e-3, reset=False)


@pytest.mark.parametrize("name", ["flash", "lamp", "checker-night", "adaptation-cross"])
def test_builtin_scenes_match_reference(name: str) -> None:
    from gazehdr.scenes import open_scene

    scene = open_scene(name)
    sims = [Simulator(W, H, backend=b, seed=3) for b in ("reference", "opencl")]
    for k, t in enumerate((0.0, 1.05, 1.3)):
        rgb = scene.render(t, W, H)
        for s in sims:
            s.load_scene(rgb, reset=k == 0)
            s.step(1 / 30, gaze=(40.0 + 10 * k, 30.0))
        compare_all(sims[0]._backend, sims[1]._backend)


@pytest.mark.parametrize("size", [(480, 270), (136, 77), (17, 16)])
def test_any_frame_size_matches_reference(size: tuple[int, int], vec: int) -> None:
    """Map planes whose byte offsets are not multiples of the device's alignment (480×270
    once crashed creating a sub-buffer), odd sizes, and the smallest frame."""
    w, h = size
    scene = np.resize(mixed_scene(4), (h, w, 3))
    sims = [Simulator(w, h, backend=b, seed=2) for b in ("reference", "opencl")]
    for s in sims:
        s.load_scene(scene)
        s.step(0.1, gaze=(w / 3, h / 2))
    compare_all(sims[0]._backend, sims[1]._backend)


def _pair(params: Params | None = None):
    p = params or Params()
    lay = Layout.for_frame(W, H, p)
    return lay, p, ReferenceBackend(lay, p), OpenCLBackend(lay, p)


def _load_same(ref, cl, names, rng) -> None:
    for name in names:
        shape = ref.get(name).shape
        if name == "A":
            value = rng.uniform(2.0, 5.0, shape)
        elif name in ("state",):
            value = rng.uniform(0.0, 1.0, shape)
        elif name == "maps":
            value = np.concatenate(
                [rng.uniform(0.6, 1.6, (3, *shape[1:])), rng.uniform(0, 0.05, (3, *shape[1:]))]
            )
        elif name == "rho":
            value = rng.uniform(-1.5, 2.5, shape)
        else:
            value = np.exp(rng.normal(0.0, 3.0, shape))
        ref.put(name, value.astype(np.float32))
        cl.put(name, value.astype(np.float32))


@pytest.mark.parametrize(("seed", "bank"), [(0, ""), (5, ""), (0, "levels")])
def test_each_stage_alone(seed: int, bank: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Identical inputs into one stage at a time, so an error cannot hide in an earlier one.
    The acuity of a new scene in tiles (CPUs), and level by level as GPUs make it."""
    monkeypatch.setenv("GAZEHDR_CL_ACUITY", bank)
    rng = np.random.default_rng(seed)
    lay, p, ref, cl = _pair()
    planar = np.ascontiguousarray(mixed_scene(seed).transpose(2, 0, 1))
    ref.set_scene(planar)
    cl.set_scene(planar)

    for eyes in (1.0, 0.0):
        ref.prepare(eyes)
        cl.prepare(eyes)
        assert_close("down", ref.get("down"), cl.get("down"))
        assert_close("surround", ref.get("surround"), cl.get("surround"))
        assert_close("rho", ref.get("rho"), cl.get("rho"))

    _load_same(ref, cl, ["down", "rho", "A"], rng)
    for gaze, dt, reset in (
        ((50.0, 20.0), 0.1, False),
        ((-500.0, 900.0), 1.0, False),
        ((3.0, 4.0), 0, True),
    ):
        ref.adapt(gaze, dt, reset)
        cl.adapt(gaze, dt, reset)
        assert_close("A", ref.get("A"), cl.get("A"))

    for gaze, dt, reset in (
        ((60.2, 30.7), 1 / 60, False),
        ((10.0, 50.0), 1.0, False),
        ((0, 0), 0.0, True),
        ((-20.0, 40.0), 1 / 60, True),  # settled: the fixed point of steps of 1/60 s
    ):
        _load_same(ref, cl, ["state", "A"], rng)
        ref.retina(gaze, dt, reset)
        cl.retina(gaze, dt, reset)
        assert_state_close(ref.get("state"), cl.get("state"))
        assert_close("maps", ref.get("maps"), cl.get("maps"))

    _load_same(ref, cl, ["rho"], rng)
    noise = NoiseField(lay, p, seed).at(0.37)
    ref.acuity(noise)
    cl.acuity(noise)
    flipped = ref.get("d") != cl.get("d")
    assert flipped.mean() <= 0.002
    assert len(np.unique(ref.get("d"))) >= 4, "the test should exercise several bank levels"
    assert_close("G", ref.get("G")[:, ~flipped], cl.get("G")[:, ~flipped])

    _load_same(ref, cl, ["G", "rho", "maps", "A"], rng)
    for gaze, eyes in (((33.3, 21.7), 1.0), ((200.0, -50.0), 1.0), ((60.0, 34.0), 0.0)):
        assert_close("v", ref.compose(gaze, eyes), cl.compose(gaze, eyes))


def test_a_frame_seen_from_a_newer_gaze_matches_reference() -> None:
    """Simulator.frame(gaze): the eye steps at one gaze and its frame is seen from another
    (the live path's late gaze). The OpenCL backend then makes the afterimage maps of only
    the cells the new gaze adds to the step's window; cells outside it still hold an older
    step's maps, so a cell missed shows. Each frame against the reference, and against the
    same compose once the whole grid's maps are made."""
    sims = [Simulator(W, H, backend=b, seed=6) for b in ("reference", "opencl")]
    scene = mixed_scene(6)
    for s in sims:
        s.load_scene(scene)
    for gaze in ((20.0, 10.0), (100.0, 60.0)):  # older maps at other windows
        for s in sims:
            s.step(0.2, gaze=gaze)
    for s in sims:  # the light goes off: afterimages, unlike the older steps' maps
        s.load_scene(scene * 1e-3, reset=False)
        s.advance(1 / 30, gaze=(60.0, 34.0))
    cl = sims[1]._backend
    for late in ((61.5, 34.5), (10.0, 60.0), (-40.0, 10.0), (118.0, 2.0)):
        ref_v, cl_v = (s.frame("float32", gaze=late) for s in sims)
        assert sims[1].gaze == late
        flipped = sims[0]._backend.get("d") != cl.get("d")
        assert_close("v", ref_v[~flipped], cl_v[~flipped])
    made = cl._maps_made
    assert made is not None, "a late gaze should add the cells it needs, not the whole grid"
    cl.get("maps")  # completes the grid
    assert cl._maps_made is None
    assert np.array_equal(cl.compose(late, 1.0), cl_v)


@pytest.mark.parametrize(
    ("size", "blind_spot"), [((W, H), False), ((137, 41), False), ((W, H), True)]
)
def test_acuity_from_the_level_stack_matches_reference(
    size: tuple[int, int], blind_spot: bool, vec: int
) -> None:
    """A scene blurs in the bank until it has stayed LEVEL_STACK_AFTER_FRAMES frames, then
    makes its level stack one level a frame, then picks each pixel's level from it
    (acuity_pick); a new scene (put or set_scene) starts over. The blind spot changes G after
    the pick. Every frame against the reference (G, and v composed from it), with many rows
    of VEC pixels between two levels and some across more."""
    from gazehdr.sim.level_stack import LEVEL_STACK_AFTER_FRAMES

    w, h = size
    p = Params(foveal_blind_spot=1.0, tracker_accuracy_deg=0.0) if blind_spot else Params()
    lay = Layout.for_frame(w, h, p)
    ref, cl = ReferenceBackend(lay, p), OpenCLBackend(lay, p)
    rng = np.random.default_rng(8)
    field = NoiseField(lay, p, 8)
    frames = LEVEL_STACK_AFTER_FRAMES + p.bands + 2
    for k, scene in enumerate((mixed_scene(8), mixed_scene(9) * 1e-2)):
        planar = np.ascontiguousarray(np.resize(scene, (h, w, 3)).transpose(2, 0, 1))
        for b in (ref, cl):  # the second scene through put, as tests and tools change it
            if k:
                b.put("scene", planar)
            else:
                b.set_scene(planar)
        assert cl.level_stack_pending
        _load_same(ref, cl, ["maps", "A", "rho", "fill"], rng)
        for frame in range(frames):
            noise = field.at(0.02 * frame)
            ref.acuity(noise)
            cl.acuity(noise)
            assert cl.level_stack_pending == (frame < LEVEL_STACK_AFTER_FRAMES + p.bands - 1)
            gaze = (w * 0.4, h * 0.6)
            if blind_spot:
                ref.blind_spot(gaze)
                cl.blind_spot(gaze)
            d = cl.get("d")
            flipped = ref.get("d") != d
            assert flipped.mean() <= 0.002
            assert_close("v", ref.compose(gaze, 1.0)[~flipped], cl.compose(gaze, 1.0)[~flipped])
            runs = np.lib.stride_tricks.sliding_window_view(d[:, : w // vec * vec], vec, 1)
            span = runs[:, ::vec].max(-1) - runs[:, ::vec].min(-1)
            assert (span > 0).mean() > 0.05, "runs of VEC pixels between levels"
            assert (span > 1).any(), "runs of VEC pixels across three levels or more"
            assert_close("G", ref.get("G")[:, ~flipped], cl.get("G")[:, ~flipped])
        assert not cl.level_stack_pending, "the last frames should have picked from the stack"


def test_sec5_cues_match_reference() -> None:
    """The afterimage boost after a blink and a saccade, and the scotopic foveal blind spot
    (with a perfect tracker, so at full strength), on a scene dimmed to scotopic light."""
    p = Params(
        afterimage_boost=1.0, foveal_blind_spot=1.0, tracker_accuracy_deg=0.0,
        tracker_rate_hz=1000.0, geometry=Geometry(viewing_distance_m=3.0),
    )  # fmt: skip
    sims = [Simulator(W, H, params=p, backend=b, seed=4) for b in ("reference", "opencl")]
    for s in sims:
        s.load_scene(mixed_scene(4) * 1e-3)
    for gaze, eyes in (((50.0, 30.0), True), ((50.0, 30.0), False), ((52.0, 31.0), True),
                       ((90.0, 20.0), True)):  # fmt: skip
        for s in sims:
            s.step(1 / 30, gaze=gaze, eyes_open=eyes)
        compare_all(sims[0]._backend, sims[1]._backend)


@pytest.mark.parametrize("output", ["float16", "rgb10a2"])
def test_device_encoding_equals_host_encoding(output: str, vec: int) -> None:
    """The kernels that write f16 / RGB10_A2 for the wire give exactly what encoding the float32
    frame on the host gives (round to nearest even; round(1023 v))."""
    from gazehdr.sim.layout import encode_output

    sims = [Simulator(136, 77, backend="opencl", seed=1) for _ in range(2)]
    scene = np.resize(mixed_scene(2), (77, 136, 3))
    for s in sims:
        s.load_scene(scene)
    for gaze in [(40.0, 30.0), (100.5, 12.25)]:
        host = encode_output(sims[0].step(0.05, gaze=gaze), output)
        device = sims[1].step(0.05, gaze=gaze, output=output)
        assert device.dtype == host.dtype and device.shape == host.shape
        assert np.array_equal(device, host)
    ref = Simulator(136, 77, backend="reference", seed=1)
    ref.load_scene(scene)
    assert ref.step(0.05, output=output).dtype == host.dtype
    with pytest.raises(ValueError, match="output must be one of"):
        ref.step(0.05, output="png")


@pytest.mark.parametrize("output", ["float16", "rgb10a2"])
def test_compose_writes_into_the_message_where_the_device_shares_host_memory(output: str) -> None:
    """A frame composed into `out` (a frame message's pixels) is the frame `frame` returns, on
    both paths: written there by the kernel (PoCL: the device's memory is the host's, and the
    device's own output buffer is left as it was) or read back into it (a GPU's path, taken
    here by saying the memory is not shared); and into a pane's strided view."""
    sim = Simulator(136, 77, backend="opencl", seed=1)
    sim.load_scene(np.resize(mixed_scene(4), (77, 136, 3)))
    sim.step(0.05, gaze=(40.0, 30.0))
    backend = sim._backend
    assert backend.shares_host_memory  # PoCL's CPU device
    want = sim.frame(output)
    kept = np.full(want.shape, 7, want.dtype)
    device_own = backend.buf["v10" if output == "rgb10a2" else "v16"]
    cl.enqueue_copy(backend.queue, device_own, kept)
    direct = np.zeros_like(want)
    assert sim.frame(output, out=direct) is direct
    assert np.array_equal(direct, want)
    left = np.empty_like(want)
    cl.enqueue_copy(backend.queue, left, device_own)
    assert np.array_equal(left, kept)  # compose wrote into `direct` itself
    backend.shares_host_memory = False
    read_back = np.zeros_like(want)
    assert np.array_equal(sim.frame(output, out=read_back), want)
    wide = np.zeros((77, 300, *want.shape[2:]), want.dtype)
    sim.frame(output, out=wide[:, 136:272])
    assert np.array_equal(wide[:, 136:272], want) and not wide[:, :136].any()
    with pytest.raises(ValueError, match="out must be"):
        sim.frame(output, out=np.zeros((77, 135, *want.shape[2:]), want.dtype))


def test_one_point_bilinear_is_the_array_version_bit_for_bit() -> None:
    """`bilinear_at` (the header's rho at the gaze, the uniform models' sigma) gives the bits
    `bilinear` gives, inside, on the edges and clamped outside."""
    rng = np.random.default_rng(5)
    img = rng.random((9, 13))
    points = [(0.0, 0.0), (13.0, 9.0), (0.5, 0.5), (12.5, 8.5), (-3.2, 4.0), (20.0, -1.0)]
    points += [tuple(p) for p in rng.uniform(-1.0, 14.0, (40, 2))]
    for x, y in points:
        array = bilinear(img[None], np.array([x]), np.array([y]))[0, 0]
        assert bilinear_at(img, x, y) == array, (x, y)


def test_blur_taps_cache_stays_bounded_when_dt_varies() -> None:
    """A live session steps by a different dt every frame; each gives a new map-blur sigma."""
    from gazehdr.sim.opencl import TAPS_CACHE

    sim = Simulator(64, 48, backend="opencl")
    sim.load_scene(mixed_scene(3)[:48, :64])
    for k in range(3 * TAPS_CACHE):
        sim.step(0.01 + 1e-4 * k, gaze=(32.0, 24.0))
    assert len(sim._backend._taps) <= TAPS_CACHE
    assert np.isfinite(sim.step(1 / 30)).all()


def test_sessions_starting_at_once_share_one_context_and_program() -> None:
    """Live sessions build their simulators on threads of their own, several at once (the
    server's first viewers): each first caller must get the same OpenCL context and program,
    or kernels built on one meet buffers of another (INVALID_CONTEXT). In a fresh process, so
    that the first calls are the ones that race."""
    import subprocess
    import sys

    code = """
import threading
import gazehdr.sim.cl_program as o
import gazehdr.sim.opencl as backend
got, start = [], threading.Barrier(6)
def first_use():
    start.wait()
    got.append((o.shared_context(), o.build_program(backend.KERNEL_FILES)))
threads = [threading.Thread(target=first_use) for _ in range(6)]
for t in threads: t.start()
for t in threads: t.join()
print(len({id(c) for c, _ in got}), len({id(p) for _, p in got}))
"""
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=True
    ).stdout
    assert out.split() == ["1", "1"]


def test_a_launch_starts_its_queue_at_once() -> None:
    """A kernel launched through the backend is flushed to the device as it is enqueued (PoCL
    otherwise lets a step's kernels wait until the host has enqueued all of them): a real
    kernel on a real queue that counts its flushes."""
    from gazehdr.sim.cl_program import Launch, shared_context

    class CountingQueue(cl.CommandQueue):
        flushes = 0

        def flush(self) -> None:
            type(self).flushes += 1
            super().flush()

    ctx = shared_context()
    queue = CountingQueue(ctx)
    program = cl.Program(ctx, "__kernel void one(__global int *o) { o[get_global_id(0)] = 1; }")
    out = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 4 * 64)
    event = Launch(cl.Kernel(program.build(), "one"))(queue, (64,), None, out)
    assert CountingQueue.flushes == 1
    event.wait()
    got = np.zeros(64, np.int32)
    cl.enqueue_copy(queue, got, out)
    assert (got == 1).all()


def test_a_launch_packs_by_value_arguments_as_the_kernel_declares_them() -> None:
    """`Launch` reads a kernel's by-value argument types from the kernel (built with the
    project's options, which ask for argument info), so plain Python numbers are packed as
    those types; without argument info it launches as pyopencl does (NumPy scalars only)."""
    from gazehdr.sim.cl_program import Launch, build_options, shared_context

    ctx = shared_context()
    queue = cl.CommandQueue(ctx)
    source = "__kernel void f(__global float *o, int n, uint m, float a) {"
    source += " o[get_global_id(0)] = n * a + m; }"
    out = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 4 * 8)
    got = np.zeros(8, np.float32)
    declared = Launch(cl.Kernel(cl.Program(ctx, source).build(build_options(ctx)), "f"))
    declared(queue, (8,), None, out, -3, 7, 0.5)
    cl.enqueue_copy(queue, got, out)
    assert (got == 5.5).all()
    plain = Launch(cl.Kernel(cl.Program(ctx, source).build(), "f"))  # no argument info
    plain(queue, (8,), None, out, np.int32(2), np.uint32(1), np.float32(0.25))
    cl.enqueue_copy(queue, got, out)
    assert (got == 1.5).all()
    with pytest.raises(cl.LogicError):
        plain(queue, (8,), None, out, 2, 1, 0.25)


def test_alongside_runs_its_side_after_what_came_before_and_before_what_comes_after() -> None:
    """The OpenCL backend's `alongside` (the acuity beside the retina): the side queue's work
    starts only once everything enqueued before is done (compose's last read of G), and what
    is enqueued after waits for both sides (compose reads G). Held by user events on a real
    PoCL queue and let go in turn; each "not yet" would fail if its wait were missing."""
    p = Params()
    b = OpenCLBackend(Layout.for_frame(64, 48, p), p)
    before, side_held = cl.UserEvent(b.ctx), cl.UserEvent(b.ctx)
    cl.enqueue_barrier(b.queue, wait_for=[before])
    marks: dict[str, cl.Event] = {}

    def side() -> None:
        marks["side"] = cl.enqueue_marker(b.queue)
        cl.enqueue_barrier(b.queue, wait_for=[side_held])
        b.queue.flush()

    def main() -> None:
        marks["main"] = cl.enqueue_marker(b.queue)

    main_queue = b.queue
    b.alongside(side, main)
    assert b.queue is main_queue
    after = cl.enqueue_marker(b.queue)
    b.queue.flush()

    def done(event: cl.Event) -> bool:
        return event.command_execution_status == cl.command_execution_status.COMPLETE

    time.sleep(0.1)
    assert not done(marks["side"]) and not done(marks["main"])  # both wait for `before`
    before.set_status(cl.command_execution_status.COMPLETE)
    marks["side"].wait()
    marks["main"].wait()
    time.sleep(0.1)
    assert not done(after)  # it waits for the side's last command
    side_held.set_status(cl.command_execution_status.COMPLETE)
    after.wait()
