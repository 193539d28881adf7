"""The kernels' own transcendentals to display precision (kernels/common.cl: log2_shownv,
exp2_shownv, log_shownv, exp_shownv, gammav, tonev_shown), run on the OpenCL device against
float64 NumPy, over every binade they take and past their ends: compose's gamma and tone curve
and the afterimage maps rest on them. And floorv, which every lookup and exp rests on."""

from __future__ import annotations

import os
from functools import cache

import numpy as np
import pyopencl as cl
import pytest

from gazehdr.sim.cl_program import (
    VECTOR_WIDTHS,
    build_options,
    kernel_source,
    native_width,
    shared_context,
    vector_width,
)
from gazehdr.sim.kernel_params import pack_params, plateau_m
from gazehdr.sim.params import POWER_MAX, Params

OUTPUTS = ("log2", "gamma", "tone_shown", "tone", "exp2", "log", "exp", "floor")
KERNEL = """
__kernel void shown(__constant const params_t *P, __global const float *x,
                    __global const float *z, float lsn, __global float *out) {
    int i = get_global_id(0) * VEC;
    size_t n = get_global_size(0) * VEC;
    floatv v = LOADV_G(x + i), w = LOADV_G(z + i);
    STOREV_G(out + i, log2_shownv(MAX(v, FLT_MIN)));
    STOREV_G(out + i + n, gammav(P, v));
    STOREV_G(out + i + 2 * n, tonev_shown(P, lsn, v));
    STOREV_G(out + i + 3 * n, tonev(P, lsn, v));
    STOREV_G(out + i + 4 * n, exp2_shownv(w));
    STOREV_G(out + i + 5 * n, log_shownv(MAX(v, FLT_MIN)));
    STOREV_G(out + i + 6 * n, exp_shownv(w));
    STOREV_G(out + i + 7 * n, floorv(w));
}
"""


@cache
def kernel(vec: int, portable: bool) -> cl.Kernel:
    """The test kernel for `vec` lanes, as GPUs build it where `portable` (the caller has set
    GAZEHDR_CL_PORTABLE to match: build_options reads it)."""
    assert bool(os.environ.get("GAZEHDR_CL_PORTABLE")) == portable
    ctx = shared_context()
    prg = cl.Program(ctx, kernel_source(("common.cl",)) + KERNEL).build(build_options(ctx, vec))
    return cl.Kernel(prg, "shown")


def run(
    x: np.ndarray, z: np.ndarray, lsn: float, p: Params, build: tuple[int, bool] | None = None
) -> dict[str, np.ndarray]:
    """Each of OUTPUTS: the log2/log/gamma/tone functions at x, the exp2/exp ones at z; built
    for `build` (lanes, portable), by default this machine's width."""
    vec, portable = build or (vector_width(), False)
    size, pad = x.size, -x.size % vec  # whole work-items of VEC lanes
    x, z = np.pad(x, (0, pad), constant_values=1), np.pad(z, (0, pad))
    ctx = shared_context()
    queue = cl.CommandQueue(ctx)
    mf = cl.mem_flags
    xs = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
    zs = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=z)
    P = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=pack_params(p))
    out = np.empty((len(OUTPUTS), x.size), np.float32)
    buf = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    kernel(vec, portable)(queue, (x.size // vec,), None, P, xs, zs, np.float32(lsn), buf)
    cl.enqueue_copy(queue, out, buf)
    return dict(zip(OUTPUTS, out[:, :size].astype(np.float64), strict=True))


def exp2_inputs(x: np.ndarray) -> np.ndarray:
    return np.float32(-126.0) + np.float32(252.0) * x


@pytest.fixture(scope="module")
def unit() -> np.ndarray:
    """Floats in [0, 1]: 0, every binade down to the smallest normal, a fine linear ramp, 1."""
    x = np.concatenate([[0.0, 1.0], np.geomspace(1.2e-38, 1.0, 40_000), np.linspace(0, 1, 40_006)])
    return x.astype(np.float32)


def test_log2_and_exp2_to_display_precision(unit: np.ndarray) -> None:
    got = run(unit, exp2_inputs(unit), 0.0, Params())
    x = unit.astype(np.float64)
    on = x > 0
    assert np.abs(got["log2"][on] - np.log2(x[on])).max() < 3.5e-5
    z = exp2_inputs(unit).astype(np.float64)
    assert (np.abs(got["exp2"] / 2.0**z - 1) < 3.5e-6).all()


BUILDS = [(vec, False) for vec in VECTOR_WIDTHS] + [(8, True)]


BUILD_IDS = [f"vec{vec}" + ("-portable" if portable else "") for vec, portable in BUILDS]


def takes_tables(build: tuple[int, bool]) -> bool:
    """Whether `build` makes powers from tables (powv_binades: 16 lanes where PoCL builds for
    AVX-512) rather than from log2 and exp2 polynomials, whose error grows with the power."""
    return build == (16, False) and native_width() == 16


@pytest.mark.parametrize("build", BUILDS, ids=BUILD_IDS)
@pytest.mark.parametrize("gamma", [Params().gamma, 1 / 2.2, 1 / 2.4, 0.9, 1.0, 0.05, POWER_MAX])
def test_display_gamma_within_a_tenth_of_a_10_bit_step(
    unit: np.ndarray, gamma: float, build: tuple[int, bool], monkeypatch: pytest.MonkeyPatch
) -> None:
    """gammav at each width and as GPUs build it, over every binade of (0, 1]. Where PoCL
    builds for AVX-512 at 16 lanes, from its tables and its polynomial fitted to each gamma
    on the host; elsewhere from log2 and exp2 polynomials, whose error grows with gamma."""
    monkeypatch.setenv("GAZEHDR_CL_PORTABLE", "1" if build[1] else "")
    tol = 2.5e-6 if takes_tables(build) else 2.5e-5 * gamma + 4e-6  # 1/1023 = 9.8e-4 a 10-bit step
    p = Params(gamma=gamma)
    x = np.concatenate([unit, -unit[-100:], [np.float32(np.nextafter(np.float32(1), 0))]])
    got = run(x, np.zeros_like(x), 0.0, p, build)["gamma"]
    x = x.astype(np.float64)
    exact = np.where(x > 0, np.abs(x) ** gamma, 0.0)
    on = (x >= np.finfo(np.float32).tiny) & (exact >= 1e-30)  # normal in and out
    assert (np.abs(got[on] / exact[on] - 1) < tol).all()
    assert np.abs(got - exact).max() < tol
    assert (got[x <= 0] == 0.0).all() and (got[x == 1] == 1.0).all()  # black and white kept
    assert got.max() <= 1.0  # never past white


def test_ln_and_e_for_the_afterimage_maps(unit: np.ndarray) -> None:
    """log_shownv over (0, 1] (mapsv takes logs of R + eps and 1 - c + eps, both in it) and
    exp_shownv over [-87, 87], clamped there beyond: finite for any float. Both far inside the
    maps' oracle tolerance (5e-4)."""
    z = np.concatenate([np.linspace(-87, 87, unit.size - 6), [-1e30, -200, -87.5, 88, 200, 1e30]])
    z = z.astype(np.float32)
    got = run(unit, z, 0.0, Params())
    z = z.astype(np.float64)
    x = unit.astype(np.float64)
    on = x > 0
    assert np.abs(got["log"][on] - np.log(x[on])).max() < 2.5e-5
    inside = np.abs(z) <= 87
    # 2^(x log2 e): the product's rounding in float32 (5e-6 at |x| = 87) adds to exp2_shownv's
    assert (np.abs(got["exp"][inside] / np.exp(z[inside]) - 1) < 1e-5).all()
    np.testing.assert_allclose(got["exp"][~inside], np.exp(np.clip(z[~inside], -87, 87)), 1e-5)


@pytest.mark.parametrize("build", BUILDS, ids=BUILD_IDS)
@pytest.mark.parametrize("n", [Params().n, 0.3, 1.0, POWER_MAX])
def test_display_tone_curve_follows_the_model_tone_curve(
    unit: np.ndarray, n: float, build: tuple[int, bool], monkeypatch: pytest.MonkeyPatch
) -> None:
    """tonev_shown (compose, the maps) against tonev (the retina's) and the exact Naka-Rushton
    curve, from darkness through 1e8 cd/m^2 to the radiance cap and the largest float, at
    adaptation levels from the floor to a sunlit scene, at each width and as GPUs build it: 0
    for no light, at most 1, never NaN; relative where the curve is above 1e-30 (a large n far
    below sigma takes it past float32)."""
    monkeypatch.setenv("GAZEHDR_CL_PORTABLE", "1" if build[1] else "")
    p = Params(n=n)
    tol = 2e-5 * (1 if takes_tables(build) else max(1, n / Params().n))
    lum = np.concatenate(
        [[0.0, 1.2e-38, p.radiance_max, 3.4e38], np.geomspace(1e-6, 1e8, unit.size - 4)]
    ).astype(np.float32)
    for A in (np.log10(100.0), 3.0, 5.0):
        m = plateau_m(p)
        lsn = (p.n - m) * A * np.log(10) + m * np.log(p.plateau_K)  # sigma^n = I^(n-m) K^m
        got = run(lum, np.zeros_like(lum), lsn, p, build)
        shown, model = got["tone_shown"], got["tone"]
        assert shown[0] == 0.0 and np.isfinite(shown).all() and shown.max() <= 1.0
        exact = 1 / (1 + np.exp(lsn - p.n * np.log(lum.astype(np.float64))))
        on = exact >= 1e-30
        assert (np.abs(shown[on] / exact[on] - 1) < tol).all()
        assert (np.abs(shown[on] / model[on] - 1) < tol).all()
        assert np.abs(shown - exact).max() < tol


def test_floor8_is_floor() -> None:
    """floorv (one vroundps under PoCL with AVX, else a truncation corrected below zero) at
    integers, halves, -0, values just either side of them, and a sweep of the range the
    kernels floor (pixel and cell coordinates, exp2's exponents)."""
    edges = np.array([0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 2.5, -2.5, 1e-30, -1e-30, 8e6, -8e6])
    near = np.concatenate([np.nextafter(edges, np.inf), np.nextafter(edges, -np.inf)])
    sweep = np.linspace(-5000.0, 5000.0, 40_000 - 3 * edges.size)
    w = np.concatenate([edges, near, sweep]).astype(np.float32)
    got = run(np.ones_like(w), w, 0.0, Params())["floor"]
    np.testing.assert_array_equal(got, np.floor(w.astype(np.float64)))
