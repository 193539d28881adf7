"""Pure helpers both backends share: colour matrices, frame layout, filter taps, sampling,
noise, fitting.

Everything here is host-side NumPy and deterministic; the kernels and the reference model get
their constants from these functions so that the two cannot drift apart.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.sim.params import Params

MIN_SIZE = 16
MAX_SIZE = (7680, 4320)

# Linear Rec.709/sRGB (D65) -> CIE XYZ.
RGB_TO_XYZ = np.array(
    [
        [0.4124564, 0.3575761, 0.1804375],
        [0.2126729, 0.7151522, 0.0721750],
        [0.0193339, 0.1191920, 0.9503041],
    ]
)
# Stockman & Sharpe (2000) 2-degree cone fundamentals (the CIE 170-1:2006 LMS) as a linear map of
# CIE 1931 XYZ, the XYZ that sRGB is defined in: the least-squares fit over 390-780 nm of the
# 1-nm CVRL tables (RMS error 1 % of the peak for L and M, 4 % for S; docs/model.md, "Cone
# space", shows the fit). The CIE's own XYZ -> LMS matrix maps the CIE 2012 XYZ, not 1931's.
XYZ_TO_LMS_SS2 = np.array(
    [
        [0.268274, 0.846614, -0.034892],
        [-0.385945, 1.164877, 0.102851],
        [0.021247, -0.024552, 0.534161],
    ]
)


def rgb_to_lms_matrix() -> np.ndarray:
    """RGB -> LMS through XYZ with Stockman & Sharpe's cone fundamentals, rows scaled so that
    the display white gives L = M = S = Y (von Kries to the adapting white, D65).

    With this normalisation a neutral stimulus of luminance Y excites every cone by Y, so the
    paper's per-cone bleaching rates b1 (per cd/m^2) apply to each cone directly, and white
    stimulates all cone types equally (Fig. 4).
    """
    m = XYZ_TO_LMS_SS2 @ RGB_TO_XYZ
    return m / m.sum(axis=1, keepdims=True)


RGB_TO_LMS = rgb_to_lms_matrix()
LMS_TO_RGB = np.linalg.inv(RGB_TO_LMS)


def check_frame_size(width: int, height: int) -> None:
    """The one rule for frame sizes, so every entry point refuses the same things alike."""
    for name, value, limit in (("width", width, MAX_SIZE[0]), ("height", height, MAX_SIZE[1])):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool):
            raise InputError(f"{name} must be an integer, got {value!r}")
        if not MIN_SIZE <= value <= limit:
            raise InputError(f"{name} must be in [{MIN_SIZE}, {limit}], got {value}")


#: The widest Gaussian any stage may run, in the pixels or cells it blurs (radius 3 sigma):
#: `Params.WORK_BOUNDS` bound each value, this their combination with a frame's pixels per
#: degree (a large frame of a small screen multiplies every size in degrees).
MAX_BLUR_SIGMA = 128.0


def check_work(params: Params, ppd: float, cell: int) -> None:
    """Refuse parameters whose blurs at `ppd` (frame pixels per degree, retina cells of `cell`
    pixels) would be wider than MAX_BLUR_SIGMA, naming the widest."""
    scale = ppd / params.geometry.pixels_per_degree()
    screen = {  # sigmas in frame pixels
        "sigma_0": params.sigma_0 * 2 ** ((params.bands - 1) / 4) * scale,
        "acuity_sigma_max_deg": params.acuity_sigma_max_deg * ppd,
    }
    cells = {  # sigmas in retina cells (the low-resolution maps)
        name: getattr(params, name) * ppd / cell
        for name in ("adaptation_sigma_deg", "rho_sigma_deg", "map_blur_deg",
                     "surround_sigma_deg", "ritschel_saccade_sigma_deg", "ritschel_N_sigma_deg",
                     "mikamo_lowpass_deg")
    }  # fmt: skip
    cells["rod_free_radius_deg"] = 2 * params.rod_free_radius_deg * ppd / cell
    for unit, sigmas in (("px", screen), ("cells", cells)):
        name, sigma = max(sigmas.items(), key=lambda kv: kv[1])
        if sigma > MAX_BLUR_SIGMA:
            raise InputError(
                f"parameter {name} gives a blur of sigma {sigma:.4g} {unit} at {ppd:.4g} px per "
                f"degree, over the {MAX_BLUR_SIGMA:g} any stage may run; make it or the frame "
                "smaller"
            )


@dataclass(frozen=True)
class Layout:
    """Sizes of every map for one frame size, in pixels, derived from the viewing geometry.

    The retina grid has cells of `cell` screen pixels and spans twice the screen in each
    direction, so it covers the whole screen for any gaze on it.
    """

    width: int
    height: int
    ppd: float  # pixels per degree of this frame
    cell: int  # retina / low-resolution cell size in screen pixels
    low_w: int
    low_h: int
    grid_w: int
    grid_h: int

    @classmethod
    def for_frame(cls, width: int, height: int, params: Params) -> Layout:
        check_frame_size(width, height)
        ppd = params.geometry.pixels_per_degree(int(width))
        cell = max(1, round(params.retina_cell_deg * ppd))
        check_work(params, ppd, cell)
        low_w, low_h = math.ceil(width / cell), math.ceil(height / cell)
        return cls(int(width), int(height), ppd, cell, low_w, low_h, 2 * low_w, 2 * low_h)

    def px(self, degrees: float) -> float:
        return degrees * self.ppd


def gaussian_taps(sigma: float) -> np.ndarray:
    """Normalised 1-D Gaussian taps (odd length) whose variance is sigma^2, also for tiny sigma.

    A sampled Gaussian narrower than about 0.7 px has the wrong variance; there the 3-tap
    kernel [v/2, 1-v, v/2] has variance exactly v = sigma^2, so blurs compose correctly.
    """
    if not math.isfinite(sigma) or sigma <= 0:
        return np.ones(1, np.float32)
    v = sigma * sigma
    if v <= 0.5:
        return np.array([v / 2, 1 - v, v / 2], np.float32)
    radius = math.ceil(3 * sigma)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    taps = np.exp(-(x * x) / (2 * v))
    return (taps / taps.sum()).astype(np.float32)


def acuity_increments(params: Params, ppd: float) -> list[float]:
    """Sigmas that blur level i-1 into level i of the bank (level -1 is the input)."""
    sig = params.sigma_i(ppd)
    return [sig[0]] + [math.sqrt(max(b * b - a * a, 0.0)) for a, b in itertools.pairwise(sig)]


# --- sampling conventions, host side ---------------------------------------------------------
# Pixel centres at i + 0.5, as in the kernels (common.cl). The reference model and the OpenCL
# backend's host side (the adaptation window, rho at the gaze) both use these: the production
# backend must not depend on the oracle it is tested against.


def bilinear(
    img: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    border: Sequence[float] | None = None,
    outside: np.ndarray | None = None,
) -> np.ndarray:
    """Sample planar `img` at continuous coordinates; outside taps clamp, or take `border`, or
    read `outside` (a map of `img`'s shape) at the clamped tap."""
    c, h, w = img.shape
    u, v = xs - 0.5, ys - 0.5
    x0, y0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    fx, fy = u - x0, v - y0
    out = np.zeros((c, *xs.shape), np.float64)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            xi, yi = x0 + dx, y0 + dy
            inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
            yc, xc = np.clip(yi, 0, h - 1), np.clip(xi, 0, w - 1)
            val = img[:, yc, xc]
            if outside is not None:
                val = np.where(inside, val, outside[:, yc, xc])
            elif border is not None:
                val = np.where(inside, val, np.asarray(border, np.float64)[:, None, None])
            out += wx * wy * val
    return out


def bilinear_at(img: np.ndarray, x: float, y: float) -> float:
    """`bilinear` of one H×W plane at one point, in plain floats and the same arithmetic (so
    the same bits): the array version costs 0.13 ms a call, on the live step's path once a
    frame (the header's rho at the gaze)."""
    h, w = img.shape
    u, v = x - 0.5, y - 0.5
    x0, y0 = math.floor(u), math.floor(v)
    fx, fy = u - x0, v - y0
    out = 0.0
    for yi, wy in ((y0, 1 - fy), (y0 + 1, fy)):
        for xi, wx in ((x0, 1 - fx), (x0 + 1, fx)):
            out += wx * wy * float(img[min(max(yi, 0), h - 1), min(max(xi, 0), w - 1)])
    return out


def adaptation_window(
    gaze: Sequence[float], lay: Layout, p: Params
) -> tuple[float, float, float, int, int, int, int]:
    """Centre, sigma and inclusive integer low-res window (x0, x1, y0, y1) of the Gaussian patch
    of A_T (Sec. 2.1; gaze clamped to the screen)."""
    cx = min(max(gaze[0], 0.0), lay.width)
    cy = min(max(gaze[1], 0.0), lay.height)
    sig = lay.px(p.adaptation_sigma_deg)
    x0 = max(0, math.floor((cx - 3 * sig) / lay.cell))
    x1 = min(lay.low_w - 1, math.floor((cx + 3 * sig) / lay.cell))
    y0 = max(0, math.floor((cy - 3 * sig) / lay.cell))
    y1 = min(lay.low_h - 1, math.floor((cy + 3 * sig) / lay.cell))
    return cx, cy, sig, x0, x1, y0, y1


# --- the surround: what the retina sees off the screen (Sec. 2.2) -----------------------------
# Off the screen the retina reads the surround map at the nearest screen cell, always one of the
# frame's outermost cells. There the map holds the Gaussian average along the frame's edge
# (around its corners) of the cells on it: the frame's edge goes on past it as it is on
# average near that point (Params.surround).


def edge_loop(w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    """The outermost cells of a w×h grid as a closed loop, (x, y) of each loop position: along
    the top row, down the right column, back along the bottom row, up the left column (one row:
    out along it and back). Kernels: edge_cell in kernels/sec2_2_afterimages.cl."""
    k = np.arange(max(2 * (w - 1) + 2 * (h - 1), 1))
    right, bottom, left = w - 1, (w - 1) + (h - 1), 2 * (w - 1) + (h - 1)
    x = np.select([k < right, k < bottom, k < left], [k, w - 1, w - 1 - (k - bottom)], 0)
    y = np.select([k < right, k < bottom, k < left], [0, k - right, h - 1], h - 1 - (k - left))
    return x, y


def edge_position(x: np.ndarray, y: np.ndarray, w: int, h: int) -> np.ndarray:
    """The loop position (first, where a cell has two) of cells on the edge of a w×h grid."""
    return np.select(
        [y == 0, x == w - 1, y == h - 1],
        [x, (w - 1) + y, (w - 1) + (h - 1) + (w - 1 - x)],
        2 * (w - 1) + (h - 1) + (h - 1 - y),
    )


def surround_map(lms: np.ndarray, lay: Layout, p: Params) -> np.ndarray:
    """The surround of planar low-res `lms` (L, M, S first), on its outermost cells (zero
    inside): `surround` times the Gaussian average along the edge, sigma surround_sigma_deg
    (kernel: surround_map in kernels/sec2_2_afterimages.cl)."""
    w, h = lay.low_w, lay.low_h
    xs, ys = edge_loop(w, h)
    taps = gaussian_taps(lay.px(p.surround_sigma_deg) / lay.cell)
    r, k = len(taps) // 2, np.arange(len(xs))
    edge = np.asarray(lms, np.float64)[:3, ys, xs]
    mean = sum(float(t) * edge[:, (k + i - r) % len(xs)] for i, t in enumerate(taps))
    out = np.zeros((3, h, w))
    out[:, ys, xs] = p.surround * mean[:, edge_position(xs, ys, w, h)]
    return out


# --- settling the retina (Sec. 2.2, 2.4) ------------------------------------------------------
# A step relaxes the state toward its equilibrium s_inf (Eq. 5, 9: s' = R s + (1 - R) s_inf) and
# then blurs it (G, Sec. 2.4). Around sharp edges of s_inf the blur and the relaxation balance
# only at s = G(R s + (1 - R) s_inf), not at s_inf: settled means that fixed point. Both
# backends find it by Jacobi iterations, s <- (b + G(R s) - d R s) / (1 - d R), b = G((1 - R)
# s_inf), d the diagonal of G. These give how many.

SETTLE_MIN_DT = 1 / 240  # s; a shorter (or zero) step settles for this one (1 - dR ~ rounding)
# What is left of the first error (the halo s_inf lacks): 1e-4 of it, below a float16 step of
# the frames; 1e-7 took twice the iterations, the most of a new viewer's first step.
SETTLE_TOL = 1e-4
SETTLE_MAX_ITERATIONS = 200  # reached only for very slow rates (b2, c2 far below Appendix A)


def blur_diagonal(taps: np.ndarray, n: int) -> np.ndarray:
    """Weight of each element of an n-long axis on itself in the edge-clamped blur `taps`."""
    r = len(taps) // 2
    j = np.arange(n)
    return sum(float(t) * (np.clip(j + k - r, 0, n - 1) == j) for k, t in enumerate(taps))


def contrast_floor(p: Params) -> float:
    """The light (over sigma) whose response is alpha_eps: below it a cone counts as dark, as
    Eq. 11's guard has it; `reference.linear_contrast` divides by no less (the kernels read it
    from the parameter block, kernel_params)."""
    return math.exp((math.log(p.alpha_eps) - math.log1p(-p.alpha_eps)) / p.n)


def map_blur_sigma(dt: float, lay: Layout, p: Params) -> float:
    """Sigma, in retina cells, of the B and C map blur after a step of dt (Sec. 2.4)."""
    return lay.px(p.map_blur_deg) * math.sqrt(dt) / lay.cell


@dataclass(frozen=True)
class SettlePlan:
    """The blur of a step of dt, its diagonal along each grid axis, and the iterations."""

    sigma: float  # in retina cells
    diag_x: np.ndarray  # (grid_w,)
    diag_y: np.ndarray  # (grid_h,)
    iterations: int


def settle_plan(dt: float, lay: Layout, p: Params) -> SettlePlan:
    """Each Jacobi iteration shrinks the error by at most (1 - d) R / (1 - d R): largest at the
    smallest diagonal d and the slowest decay R = exp(-min(b2, c2) dt) (Eq. 5, 9 in the dark)."""
    sigma = map_blur_sigma(dt, lay, p)
    taps = gaussian_taps(sigma)
    dx, dy = blur_diagonal(taps, lay.grid_w), blur_diagonal(taps, lay.grid_h)
    d, r = float(dx.min() * dy.min()), math.exp(-min(*p.b2, p.c2) * dt)
    rate = (1 - d) * r / (1 - d * r)
    n = 1 if rate <= 0 else math.ceil(math.log(SETTLE_TOL) / math.log(rate))
    return SettlePlan(sigma, dx, dy, min(n, SETTLE_MAX_ITERATIONS))


# --- Sec. 5 cues -----------------------------------------------------------------------------


def blind_spot_strength(p: Params) -> float:
    """How much of the foveal blind spot can be shown: `foveal_blind_spot` times the share of
    the drawn rod-free zone that lies on the true one (two discs of rod_free_radius_deg,
    tracker_accuracy_deg apart), times the share of a fixation it spends there (it lands one
    sample late: 1 - 1 / (rate fixation_s)). The paper's tracker (1 deg, 30 Hz) gives 9 %."""
    r, e = p.rod_free_radius_deg, p.tracker_accuracy_deg
    if p.foveal_blind_spot == 0 or e >= 2 * r:
        return 0.0
    lens = 2 * r * r * math.acos(e / (2 * r)) - 0.5 * e * math.sqrt(4 * r * r - e * e)
    on_time = max(0.0, 1 - 1 / (p.tracker_rate_hz * p.fixation_s))
    return p.foveal_blind_spot * lens / (math.pi * r * r) * on_time


# --- acuity noise field (Sec. 2.3.3) ---------------------------------------------------------


@dataclass(frozen=True)
class NoiseFrame:
    """Two key frames of the coarse N(0,1) field and where between them this frame lies."""

    key0: np.ndarray  # (ny, nx) float32
    key1: np.ndarray
    frac: float  # time weight of key1 in [0, 1)
    spacing: float  # grid spacing in screen pixels


class NoiseField:
    """Seeded key frames drawn on a coarse grid at a low rate; key k depends only on (seed, k).

    Replaying with the same seed and the same simulation times gives the same field, whatever
    the frame rate was.
    """

    def __init__(self, layout: Layout, params: Params, seed: int) -> None:
        self.seed = int(seed)
        self.rate = params.noise_rate_hz
        self.spacing = max(layout.px(params.noise_cell_deg), 1.0)
        self.shape = (
            math.floor(layout.height / self.spacing) + 2,
            math.floor(layout.width / self.spacing) + 2,
        )
        self._cache: dict[int, np.ndarray] = {}

    def key(self, k: int) -> np.ndarray:
        if k not in self._cache:
            if len(self._cache) > 4:
                self._cache.clear()
            rng = np.random.default_rng([self.seed, k & 0xFFFFFFFF, k >> 32])
            self._cache[k] = rng.standard_normal(self.shape).astype(np.float32)
        return self._cache[k]

    def at(self, t: float) -> NoiseFrame:
        u = max(t, 0.0) * self.rate
        k = math.floor(u)
        return NoiseFrame(self.key(k), self.key(k + 1), float(u - k), float(self.spacing))


# --- fitting a scene to the frame --------------------------------------------------------------


def _resample_axis(img: np.ndarray, axis: int, n_out: int) -> np.ndarray:
    """Area average when shrinking, linear interpolation when growing (pixel-centre grid)."""
    n_in = img.shape[axis]
    if n_out == n_in:
        return img
    img = np.moveaxis(img, axis, 0).astype(np.float64)
    if n_out < n_in:
        # Integral image along the axis; each output pixel averages the span it covers.
        edges = np.linspace(0.0, n_in, n_out + 1)
        cum = np.concatenate([np.zeros((1, *img.shape[1:])), np.cumsum(img, axis=0)])
        idx = np.floor(edges).astype(int)
        frac = (edges - idx)[:, None, None]
        idx_next = np.minimum(idx + 1, n_in)
        integral = cum[idx] + frac * (cum[idx_next] - cum[idx])
        out = (integral[1:] - integral[:-1]) / (n_in / n_out)
    else:
        pos = (np.arange(n_out) + 0.5) * n_in / n_out - 0.5
        i0 = np.clip(np.floor(pos).astype(int), 0, n_in - 1)
        i1 = np.clip(i0 + 1, 0, n_in - 1)
        f = np.clip(pos - i0, 0.0, 1.0)[:, None, None]
        out = img[i0] * (1 - f) + img[i1] * f
    return np.moveaxis(out, 0, axis)


def fit_to_frame(rgb: np.ndarray, width: int, height: int) -> np.ndarray:
    """Fit an H×W×3 image inside the frame keeping its aspect; the bars are black (0 cd/m^2)."""
    h, w = rgb.shape[:2]
    if (w, h) == (width, height):
        return rgb
    scale = min(width / w, height / h)
    new_w, new_h = max(1, round(w * scale)), max(1, round(h * scale))
    resized = _resample_axis(_resample_axis(rgb, 0, new_h), 1, new_w)
    out = np.zeros((height, width, 3), np.float32)
    y0, x0 = (height - new_h) // 2, (width - new_w) // 2
    out[y0 : y0 + new_h, x0 : x0 + new_w] = resized
    return out


def sanitize_radiance(rgb: np.ndarray, params: Params) -> np.ndarray:
    """Any array-like -> finite float32 H×W×3 in [0, radiance_max]; bad shapes are an error."""
    arr = np.asarray(rgb)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise InputError(f"scene must be an H×W×3 array of cd/m^2, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise InputError(f"scene must be numeric, got dtype {arr.dtype}")
    cap = params.radiance_max
    wide = arr.dtype.kind == "f" and arr.dtype.itemsize > 4  # clip before float32 overflows
    out = np.nan_to_num(
        arr.astype(np.float64 if wide else np.float32), nan=0.0, posinf=cap, neginf=0.0
    )
    return np.clip(out, 0.0, cap, out=out).astype(np.float32, copy=False)


#: What `Simulator.step` can return: v itself, or v made ready for the viewer's wire formats.
OUTPUTS = ("float32", "float16", "rgb10a2")


def encode_output(v: np.ndarray, output: str) -> np.ndarray:
    """H×W×3 `v` in [0, 1] as `output`: float32, float16 (round to nearest even), or H×W uint32
    RGB10_A2 words `r | g << 10 | b << 20` of round(1023 v), the layout WebGL2 uploads."""
    if output == "float32":
        return np.asarray(v, np.float32)
    if output == "float16":
        return np.asarray(v, np.float16)
    if output == "rgb10a2":
        q = np.rint(np.clip(v, 0.0, 1.0) * 1023.0).astype(np.uint32)
        return q[..., 0] | (q[..., 1] << 10) | (q[..., 2] << 20)
    raise InputError(f"output must be one of {', '.join(OUTPUTS)}, got {output!r}")
