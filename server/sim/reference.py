"""NumPy reference of the model: the oracle the OpenCL kernels are tested against.

It mirrors the kernels stage by stage (same maps, same sampling conventions, same taps) but is
written for clarity, in float64. Equation numbers refer to Jacobs et al. 2015.

Conventions shared with the kernels:
- maps are planar (channels, rows, columns); pixel i has its centre at coordinate i + 0.5;
- the low-resolution maps average `cell`×`cell` screen pixels; the retina grid has the same
  cells and spans twice the screen, centred on the gaze (retinal offset 0 = grid centre); off
  the screen it sees the surround map at the nearest screen cell (`layout.surround_map`);
- calcium is stored normalised, c = C / C_max, so c_inf = 1 - R (Eq. 10 divided by C_max).
"""

from __future__ import annotations

import math

import numpy as np

from gazehdr.sim.layout import (
    LMS_TO_RGB,
    RGB_TO_LMS,
    Layout,
    NoiseFrame,
    acuity_increments,
    adaptation_window,
    bilinear,
    blind_spot_strength,
    gaussian_taps,
    map_blur_sigma,
    settle_plan,
    surround_map,
)
from gazehdr.sim.params import Params

LN10 = math.log(10.0)


# --- shared primitives -------------------------------------------------------------------------


def blur_axis(img: np.ndarray, taps: np.ndarray, axis: int) -> np.ndarray:
    """Convolve along one axis with edge clamping (as the kernels read clamped coordinates)."""
    r = len(taps) // 2
    if r == 0:
        return img.copy()
    pad = [(0, 0)] * img.ndim
    pad[axis] = (r, r)
    padded = np.pad(img, pad, mode="edge")
    n = img.shape[axis]
    out = np.zeros(img.shape, np.float64)
    for k, t in enumerate(taps):
        out += float(t) * np.take(padded, np.arange(k, k + n), axis=axis)
    return out


def blur2d(img: np.ndarray, sigma: float) -> np.ndarray:
    taps = gaussian_taps(sigma)
    return blur_axis(blur_axis(img, taps, -1), taps, -2)


def tone(I: np.ndarray, A: float, p: Params) -> np.ndarray:
    """Naka-Rushton response, Eq. 1-2, with the plateau M(I) = I^m / (I^m + K^m) (ours).

    sigma^n = I_bar^(n-m) K^m, evaluated in logs so that 1e10 cd/m^2 stays finite; the exponent
    is capped at 80 (R < 1e-34) and no light gives exactly R = 0, so black stays black.
    """
    m = p.n * p.plateau_m_over_n
    ln_sigma_n = (p.n - m) * A * LN10 + m * math.log(p.plateau_K)
    I = np.asarray(I, np.float64)
    lnI = np.log(np.where(I > 0, I, 1.0))
    R = 1.0 / (1.0 + np.exp(np.minimum(ln_sigma_n - p.n * lnI, 80.0)))
    return np.where(I > 0, R, 0.0)


def rho_of(L_log: np.ndarray, p: Params) -> np.ndarray:
    """Eq. 13, unclamped."""
    return (L_log - p.m2) / (p.m1 - p.m2)


def gamut_map(rgb: np.ndarray, w_P) -> np.ndarray:
    """Bring linear RGB into [0,1]^3 along the line to the grey of equal luminance (no hue flip).

    Luminance is clamped to [0,1]; then the largest t in [0,1] with grey + t*(rgb - grey)
    inside the cube is taken, so a colour keeps its hue and loses only saturation.
    """
    Y = np.clip(np.tensordot(np.asarray(w_P), rgb, axes=1), 0.0, 1.0)
    d = rgb - Y
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # inf: not taken
        t_hi = np.where(d > 0, (1.0 - Y) / np.where(d > 0, d, 1.0), np.inf)
        t_lo = np.where(d < 0, Y / np.where(d < 0, -d, 1.0), np.inf)
    t = np.clip(np.minimum(t_hi, t_lo).min(axis=0), 0.0, 1.0)
    return np.clip(Y + t * d, 0.0, 1.0)


# --- stages --------------------------------------------------------------------------------------


def downsample(scene: np.ndarray, lay: Layout, p: Params, eyes: float) -> np.ndarray:
    """Average cell×cell blocks of the (eyes-gated) scene into L, M, S, Y_P, Y_S."""
    c, H, W = scene.shape
    s = lay.cell
    padded = np.zeros((c, lay.low_h * s, lay.low_w * s))
    padded[:, :H, :W] = scene
    mask = np.zeros((lay.low_h * s, lay.low_w * s))
    mask[:H, :W] = 1.0
    sums = padded.reshape(c, lay.low_h, s, lay.low_w, s).sum(axis=(2, 4))
    counts = mask.reshape(lay.low_h, s, lay.low_w, s).sum(axis=(1, 3))
    rgb = eyes * sums / counts
    lms = np.tensordot(RGB_TO_LMS, rgb, axes=1)
    yp = np.tensordot(np.asarray(p.w_P), rgb, axes=1)
    ys = np.tensordot(np.asarray(p.w_S), rgb, axes=1)
    return np.concatenate([lms, yp[None], ys[None]])


def fill_map(down: np.ndarray, lay: Layout, p: Params) -> np.ndarray:
    """What fills the foveal blind spot (Sec. 5): L, M, S averaged over a Gaussian as wide
    (sigma) as the rod-free zone is across, which an object inside the zone barely changes."""
    return blur2d(down[:3], lay.px(2 * p.rod_free_radius_deg) / lay.cell)


def local_rho(down: np.ndarray, lay: Layout, p: Params) -> np.ndarray:
    """rho of Eq. 13 from the locally averaged photopic luminance (sigma = rho_sigma_deg)."""
    yp = blur2d(down[3:4], lay.px(p.rho_sigma_deg) / lay.cell)[0]
    return rho_of(np.log10(np.maximum(yp, p.Y_min)), p)


def adapt(A: float, down, rho, gaze, dt: float, reset: bool, lay: Layout, p: Params) -> float:
    """Eq. 3 with the floor A >= A_min; A_T from the mean mesopic luminance around the gaze."""
    cx, cy, sig, x0, x1, y0, y1 = adaptation_window(gaze, lay, p)
    ys, xs = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
    d2 = ((xs + 0.5) * lay.cell - cx) ** 2 + ((ys + 0.5) * lay.cell - cy) ** 2
    w = np.exp(-d2 / (2 * sig * sig))
    rc = np.clip(rho[y0 : y1 + 1, x0 : x1 + 1], 0.0, 1.0)
    ymes = rc * down[3, y0 : y1 + 1, x0 : x1 + 1] + (1 - rc) * down[4, y0 : y1 + 1, x0 : x1 + 1]
    mean = float((w * ymes).sum() / max(w.sum(), 1e-30))
    target = max(math.log10(max(mean, p.Y_min)), p.A_min)
    if reset:
        return target
    if A < target:
        return min(A + p.a1 * dt, target)
    return max(A - p.a2 * dt, target)


def retina_input(down, surround, gaze, lay: Layout) -> np.ndarray:
    """Cone input at every retina cell: the scene at gaze + retinal offset; taps off the screen
    read `surround` (L, M, S on the low-res grid) at the nearest screen cell."""
    j = np.arange(lay.grid_w)
    i = np.arange(lay.grid_h)
    sx = gaze[0] + (j + 0.5 - lay.grid_w / 2) * lay.cell
    sy = gaze[1] + (i + 0.5 - lay.grid_h / 2) * lay.cell
    X, Y = np.meshgrid(sx / lay.cell, sy / lay.cell)
    return bilinear(down[:3], X, Y, outside=surround)


def retina_update(state, down, surround, A, gaze, dt, reset, lay: Layout, p: Params):
    """Bleaching Eq. 5-6 and calcium Eq. 9-10 per cone, then the sqrt(dt)-scaled map blur.
    With reset, the equilibrium: s_inf, or for dt > 0 the fixed point of such steps."""
    I = retina_input(down, surround, gaze, lay)
    b1 = np.asarray(p.b1)[:, None, None]
    b2 = np.asarray(p.b2)[:, None, None]
    s_inf = np.concatenate([b1 * I / (b1 * I + b2), 1.0 - tone(I, A, p)])  # Eq. 6, Eq. 10 / C_max
    R = np.concatenate([np.exp(-(b1 * I + b2) * dt), np.full(I.shape, math.exp(-p.c2 * dt))])
    if reset and dt > 0:  # calcium settles as 1 - c (see settle)
        z = settle(np.concatenate([s_inf[:3], tone(I, A, p)]), R, dt, lay, p)
        return np.concatenate([z[:3], 1.0 - z[3:]])
    if reset:
        return s_inf
    new = np.clip((state - s_inf) * R + s_inf, 0, 1)  # Eq. 5, 9
    return blur2d(new, map_blur_sigma(dt, lay, p))


def settle(s_inf, R, dt: float, lay: Layout, p: Params) -> np.ndarray:
    """The state that steps of dt leave as it is, s = G(R s + (1 - R) s_inf), by Jacobi
    iterations (layout.settle_plan). G keeps a constant, so 1 - s obeys the same equation:
    calcium settles as 1 - c, small in the dark, where float32 (the kernels) rounds c."""
    plan = settle_plan(dt, lay, p)
    d = plan.diag_y[:, None] * plan.diag_x[None, :]
    b = blur2d((1 - R) * s_inf, plan.sigma)
    s = s_inf
    for _ in range(plan.iterations):
        s = (b + blur2d(R * s, plan.sigma) - d * R * s) / (1 - d * R)
    return s


def afterimage_maps(state, down, surround, A, gaze, lay: Layout, p: Params) -> np.ndarray:
    """The maps every afterimage model makes for `compose`: a multiplicative gain per cone
    (here alpha^j2, Eq. 11, guarded) and an additive linear-RGB term (here H times the
    bleaching term j1 c max(B - B_inf, 0) of Eq. 12)."""
    I = retina_input(down, surround, gaze, lay)
    b1 = np.asarray(p.b1)[:, None, None]
    b2 = np.asarray(p.b2)[:, None, None]
    B_inf = b1 * I / (b1 * I + b2)
    c_inf = 1.0 - tone(I, A, p)
    B, c = state[:3], state[3:]
    eps = p.alpha_eps
    alpha = (1.0 - c_inf + eps) / (1.0 - c + eps)
    gain = alpha**p.j2
    bleach = p.j1 * c * np.maximum(B - B_inf, 0.0)
    return np.concatenate([gain, np.tensordot(np.asarray(p.H), bleach, axes=1)])


def screen_coords(lay: Layout):
    return np.meshgrid(np.arange(lay.width) + 0.5, np.arange(lay.height) + 0.5)


def acuity_levels(q: np.ndarray, p: Params) -> np.ndarray:
    """Number of finest bands dropped at each pixel: band i is kept iff q > rho_i (Eq. 15)."""
    return sum((q <= np.float32(t)).astype(np.int32) for t in p.rho_i())


def acuity_q(rho, noise: NoiseFrame, lay: Layout, p: Params) -> np.ndarray:
    """rho + g X at every pixel, X interpolated in space and time and kept N(0,1)."""
    X, Y = screen_coords(lay)
    r = bilinear(rho[None], X / lay.cell, Y / lay.cell)[0]
    u, v = X / noise.spacing, Y / noise.spacing
    i0, j0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fx, fy, ft = u - i0, v - j0, noise.frac
    acc = np.zeros_like(u)
    for key, wt in ((noise.key0, 1 - ft), (noise.key1, ft)):
        for dj, wy in ((0, 1 - fy), (1, fy)):
            for di, wx in ((0, 1 - fx), (1, fx)):
                acc += wt * wy * wx * key[j0 + dj, i0 + di]
    norm = np.sqrt(((1 - fx) ** 2 + fx**2) * ((1 - fy) ** 2 + fy**2) * ((1 - ft) ** 2 + ft**2))
    return r + p.g * acc / norm


def acuity(scene, d: np.ndarray, lay: Layout, p: Params) -> np.ndarray:
    """Eq. 14 with the shared noise: dropping the d finest bands leaves Gaussian level d - 1."""
    out = scene.copy()
    level = scene
    for i, sigma in enumerate(acuity_increments(p, lay.ppd)):
        level = blur2d(level, sigma)
        sel = d == i + 1
        out[:, sel] = level[:, sel]
    return out


def foveal_blind_spot(G, rho, fill, gaze, lay: Layout, p: Params) -> np.ndarray:
    """Sec. 5: the rod-free fovea in scotopic light; G filled in with `fill` (fill_map) by
    strength (1 - rho_c) exp(-r^2 / 2 s^2), halved at the rod-free zone's edge."""
    X, Y = screen_coords(lay)
    rc = np.clip(bilinear(rho[None], X / lay.cell, Y / lay.cell)[0], 0.0, 1.0)
    s = lay.px(p.rod_free_radius_deg) / math.sqrt(2 * math.log(2))
    r2 = (X - gaze[0]) ** 2 + (Y - gaze[1]) ** 2
    w = blind_spot_strength(p) * np.exp(-r2 / (2 * s * s)) * (1 - rc)
    rgb = np.tensordot(LMS_TO_RGB, bilinear(fill, X / lay.cell, Y / lay.cell), axes=1)
    return G + w * (rgb - G)


def compose(
    G, rho, maps, A, gaze, eyes: float, lay: Layout, p: Params, visibility: float = 1.0
) -> np.ndarray:
    """Tone curve with Purkinje (Eq. 13), hue shift, afterimages (Eq. 12) seen with
    `visibility` (Sec. 5's boost) times the foveal fall-off, gamut, gamma."""
    X, Y = screen_coords(lay)
    G = eyes * G
    rc = np.clip(bilinear(rho[None], X / lay.cell, Y / lay.cell)[0], 0.0, 1.0)
    yp = np.tensordot(np.asarray(p.w_P), G, axes=1)
    ys = np.tensordot(np.asarray(p.w_S), G, axes=1)
    R = tone(rc * yp + (1 - rc) * ys, A, p)  # Purkinje: mesopic luminance into Eq. 1
    ratio = rc * G / np.maximum(yp, p.Y_min) + (1 - rc) * np.asarray(p.k_s)[:, None, None]
    J = R * ratio
    gx = (X - gaze[0]) / lay.cell + lay.grid_w / 2
    gy = (Y - gaze[1]) / lay.cell + lay.grid_h / 2
    m = bilinear(maps, gx, gy, border=(1.0, 1.0, 1.0, 0.0, 0.0, 0.0))
    sig_f = lay.px(p.fovea_sigma_deg)
    f = visibility * np.exp(-((X - gaze[0]) ** 2 + (Y - gaze[1]) ** 2) / (2 * sig_f * sig_f))
    lms = np.tensordot(RGB_TO_LMS, J, axes=1) * (1 + f * (m[:3] - 1))
    J = np.tensordot(LMS_TO_RGB, lms, axes=1) + f * m[3:]
    J = gamut_map(J, p.w_P)
    return np.power(J, p.gamma).transpose(1, 2, 0)


# --- the backend ---------------------------------------------------------------------------------


class ReferenceBackend:
    """Holds the model state as NumPy arrays; same stage methods as the OpenCL backend."""

    name = "reference"
    device_name = "NumPy (reference)"

    def __init__(self, layout: Layout, params: Params) -> None:
        self.lay, self.p = layout, params
        lay = layout
        self.a: dict[str, np.ndarray] = {
            "scene": np.zeros((3, lay.height, lay.width)),
            "down": np.zeros((5, lay.low_h, lay.low_w)),
            "rho": np.zeros((lay.low_h, lay.low_w)),
            "surround": np.zeros((3, lay.low_h, lay.low_w)),
            "fill": np.zeros((3, lay.low_h, lay.low_w)),
            "A": np.array([params.A_min]),
            "state": np.zeros((6, lay.grid_h, lay.grid_w)),
            "maps": np.zeros((6, lay.grid_h, lay.grid_w)),
            "d": np.zeros((lay.height, lay.width), np.int32),
            "G": np.zeros((3, lay.height, lay.width)),
            "v": np.zeros((lay.height, lay.width, 3), np.float32),
        }

    def set_state_channels(self, n: int) -> None:
        """The afterimage model's retinal state has `n` planes (it starts at zero)."""
        self.a["state"] = np.zeros((n, self.lay.grid_h, self.lay.grid_w))

    def get(self, name: str) -> np.ndarray:
        return np.array(self.a[name], copy=True)

    def put(self, name: str, value: np.ndarray) -> None:
        self.a[name] = np.array(value, dtype=self.a[name].dtype).reshape(self.a[name].shape)

    @property
    def A(self) -> float:
        return float(self.a["A"][0])

    def set_scene(self, planar: np.ndarray) -> None:
        self.a["scene"] = planar.astype(np.float64)

    def prepare(self, eyes: float) -> None:
        self.a["down"] = downsample(self.a["scene"], self.lay, self.p, eyes)
        self.a["rho"] = local_rho(self.a["down"], self.lay, self.p)
        self.a["surround"] = surround_map(self.a["down"], self.lay, self.p)
        if blind_spot_strength(self.p) > 0:
            self.a["fill"] = fill_map(self.a["down"], self.lay, self.p)

    def adapt(self, gaze, dt: float, reset: bool) -> None:
        a = self.a
        a["A"] = np.array([adapt(self.A, a["down"], a["rho"], gaze, dt, reset, self.lay, self.p)])

    def retina(self, gaze, dt: float, reset: bool) -> None:
        a, lay, p = self.a, self.lay, self.p
        s, d = a["surround"], a["down"]
        a["state"] = retina_update(a["state"], d, s, self.A, gaze, dt, reset, lay, p)
        a["maps"] = afterimage_maps(a["state"], d, s, self.A, gaze, lay, p)

    def acuity(self, noise: NoiseFrame) -> None:
        q = acuity_q(self.a["rho"], noise, self.lay, self.p)
        self.a["d"] = acuity_levels(q.astype(np.float32), self.p)
        self.a["G"] = acuity(self.a["scene"], self.a["d"], self.lay, self.p)

    def blind_spot(self, gaze) -> None:
        a = self.a
        a["G"] = foveal_blind_spot(a["G"], a["rho"], a["fill"], gaze, self.lay, self.p)

    def compose(self, gaze, eyes: float, visibility: float = 1.0) -> np.ndarray:
        a = self.a
        v = compose(a["G"], a["rho"], a["maps"], self.A, gaze, eyes, self.lay, self.p, visibility)
        a["v"] = v.astype(np.float32)
        return a["v"]
