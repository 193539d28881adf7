"""NumPy reference of the model: the oracle the OpenCL kernels are tested against.

It mirrors the kernels stage by stage (same maps, same sampling conventions, same taps) but is
written for clarity, in float64. Equation numbers refer to Jacobs et al. 2015.

Conventions shared with the kernels:
- maps are planar (channels, rows, columns); pixel i has its centre at coordinate i + 0.5;
- the low-resolution maps average `cell`×`cell` screen pixels; the retina grid has the same
  cells and spans twice the screen, centred on the gaze (retinal offset 0 = grid centre); off
  the screen it sees the surround map at the nearest screen cell (`layout.surround_map`);
- calcium is stored normalised, c = C / C_max, so c_inf = 1 - R (Eq. 10 divided by C_max);
- the retina state has nine planes: B (Eq. 5), c (Eq. 9) and x, the light each cone is adapted
  to over sigma (ours, `adapted_light`), which gives the calcium gain its direction.
"""

from __future__ import annotations

import math
from collections.abc import Callable

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
    contrast_floor,
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


def ln_sigma_n(A: float, p: Params) -> float:
    """ln sigma^n of Eq. 2 with the plateau (ours): sigma^n = I_bar^(n-m) K^m, I_bar = 10^A."""
    m = p.n * p.plateau_m_over_n
    return (p.n - m) * A * LN10 + m * math.log(p.plateau_K)


def tone(I: np.ndarray, A: float, p: Params) -> np.ndarray:
    """Naka-Rushton response, Eq. 1-2, with the plateau M(I) = I^m / (I^m + K^m) (ours).

    sigma^n = I_bar^(n-m) K^m, evaluated in logs so that 1e10 cd/m^2 stays finite; the exponent
    is capped at 80 (R < 1e-34) and no light gives exactly R = 0, so black stays black.
    """
    I = np.asarray(I, np.float64)
    lnI = np.log(np.where(I > 0, I, 1.0))
    R = 1.0 / (1.0 + np.exp(np.minimum(ln_sigma_n(A, p) - p.n * lnI, 80.0)))
    return np.where(I > 0, R, 0.0)


def rho_of(L_log: np.ndarray, p: Params) -> np.ndarray:
    """Eq. 13, unclamped."""
    return (L_log - p.m2) / (p.m1 - p.m2)


def gamut_map(rgb: np.ndarray, w_P) -> np.ndarray:
    """Bring linear RGB into [0,1]^3 within its hue plane (ours): never a hue flip.

    d = rgb - Y is the colour's chroma direction (w_P . d = 0); the most saturated colour of
    that hue, its cusp, has luminance Y_c = -min(d) / (max(d) - min(d)). A colour outside the
    cube moves toward the grey of luminance min(Y, Y_c) (Y clamped to [0, 1]) just far enough
    to fit: a dark one keeps its luminance and loses saturation; a bright one trades luminance
    for saturation, as gamut mapping toward the lightness of the cusp does (Morovic's CUSP), so
    that a bright saturated blue stays blue instead of turning white.
    """
    Y = np.tensordot(np.asarray(w_P), rgb, axes=1)
    d = rgb - Y
    spread = d.max(axis=0) - d.min(axis=0)  # 0 for a grey: then any anchor gives min(Y, 1)
    # In [0, 1] but for rounding, which can leave a grey's d all of one sign: clamped.
    Y_c = np.clip(-d.min(axis=0) / np.maximum(spread, np.finfo(np.float32).tiny), 0.0, 1.0)
    anchor = np.minimum(np.clip(Y, 0.0, 1.0), Y_c)
    e = rgb - anchor
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # inf: not taken
        t_hi = np.where(e > 0, (1.0 - anchor) / np.where(e > 0, e, 1.0), np.inf)
        t_lo = np.where(e < 0, anchor / np.where(e < 0, -e, 1.0), np.inf)
    t = np.clip(np.minimum(t_hi, t_lo).min(axis=0), 0.0, 1.0)
    return np.clip(anchor + t * e, 0.0, 1.0)


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


def adapted_light(I: np.ndarray, A: float, p: Params) -> np.ndarray:
    """The light each cone adapts to, in units of the semi-saturation sigma of Eq. 2 (ours):
    I / sigma, the Naka-Rushton odds R / (1 - R) to the power 1/n, the target of the linear
    adaptation state (`retina_update`) as 1 - R(I) is the calcium's."""
    return np.asarray(I, np.float64) * math.exp(-ln_sigma_n(A, p) / p.n)


def retina_update(state, down, surround, A, gaze, dt, reset, lay: Layout, p: Params):
    """Bleaching Eq. 5-6 and calcium Eq. 9-10 per cone, then the sqrt(dt)-scaled map blur.
    Planes: B (3), c = C / C_max (3), and x (3), the light each cone is adapted to
    (`adapted_light`), relaxing in linear units with the calcium's rate c2 (ours: it keeps the
    direction of the calcium gain, `opponent_gain`). With reset, the equilibrium: s_inf, or
    for dt > 0 the fixed point of such steps."""
    I = retina_input(down, surround, gaze, lay)
    b1 = np.asarray(p.b1)[:, None, None]
    b2 = np.asarray(p.b2)[:, None, None]
    B_inf, R_I, x_inf = b1 * I / (b1 * I + b2), tone(I, A, p), adapted_light(I, A, p)
    s_inf = np.concatenate([B_inf, 1.0 - R_I, x_inf])  # Eq. 6, Eq. 10 / C_max, x
    decay_c = np.full((6, *I.shape[1:]), math.exp(-p.c2 * dt))
    R = np.concatenate([np.exp(-(b1 * I + b2) * dt), decay_c])
    if reset and dt > 0:  # calcium settles as 1 - c (see settle)
        z = settle(np.concatenate([B_inf, R_I, x_inf]), R, dt, lay, p)
        return np.concatenate([z[:3], 1.0 - z[3:6], z[6:]])
    if reset:
        return s_inf
    new = (state - s_inf) * R + s_inf  # Eq. 5, 9; x alike
    new = np.concatenate([np.clip(new[:6], 0, 1), np.maximum(new[6:], 0)])
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


#: Cap on ln(I_adapt / I_now) in `opponent_gain`: the squares of the cone contrasts stay finite in
#: float32. With the default n the Eq. 11 guard keeps it below 19.7, so it never binds there.
LN_CONTRAST_MAX = 20.0
#: The cosine between the calcium's gain and -u below which the gain fades out (`opponent_gain`).
AGREE_COS = 0.5


def linear_contrast(x: np.ndarray, x_inf: np.ndarray, p: Params) -> np.ndarray:
    """u = x / x_inf - 1 per cone, the linear cone contrast of the light the eye is adapted to
    (the state's x) against the light now (`adapted_light`), x_inf at least `contrast_floor`."""
    return (x - x_inf) / np.maximum(x_inf, contrast_floor(p))


def eq11_ln_gain(c: np.ndarray, c_inf: np.ndarray, p: Params) -> np.ndarray:
    """ln alpha^j2 per cone, Eq. 11 guarded: alpha = (1 - c_inf + eps) / (1 - c + eps), so that
    equilibrium gives exactly 1 and total darkness 1 instead of 0/0 (eps = alpha_eps, ours)."""
    eps = p.alpha_eps
    return p.j2 * (np.log(1.0 - c_inf + eps) - np.log(1.0 - c + eps))


def opponent_gain(
    c: np.ndarray, c_inf: np.ndarray, p: Params, u: np.ndarray | None = None
) -> np.ndarray:
    """The local adaptation gain of Eq. 11-12 per cone, pointed along the adapting light (ours).

    Eq. 11 gives each cone its own gain alpha^j2; these keep their strength here (the length of
    the vector of ln alpha^j2) but act along -u, u the linear cone contrast of the light the eye
    adapted to against the light now. A gain along -u leaves the additive complement of the
    adapting light, the linear rebound of subtractive adaptation in the cone-opponent retinal
    ganglion cells (Zaidi et al. 2012); per-cone gains would compress a blue's large S contrast
    far more than its small L - M contrast and turn its afterimage orange.

    The model passes u from the linear adaptation state (`linear_contrast`), which relaxes in
    linear units, so u keeps its direction as the afterimage fades. Without u it is read from
    the calcium through the tone curve: the odds R / (1 - R) = (I / sigma)^n, and c, c_inf store
    1 - R, so I_adapt / I_now = (odds(1 - c) / odds(1 - c_inf))^(1/n); exact when the gaze
    moves, but as the calcium relaxes in response units the S cone's large contrast shrinks
    fastest and a blue's afterimage drifts to orange (docs/model.md, "Adaptation colour").

    The calcium decides the sign: the gain points the way of Eq. 11's vector of ln alpha^j2
    (-u or u, whichever is nearer). Where the two are almost at right angles (cosine below
    AGREE_COS, histories in which the calcium and the linear state disagree) it fades through
    1, continuously. A neutral light (u along (1, 1, 1)) gives exactly alpha^j2 in every cone.
    """
    eps, side = p.alpha_eps, None
    ln_R_now, ln_R_then = np.log(1.0 - c_inf + eps), np.log(1.0 - c + eps)
    ln_gain = eq11_ln_gain(c, c_inf, p)
    length = np.sqrt((ln_gain**2).sum(axis=0))
    if u is None:  # read back from the calcium: points against ln_gain, cone by cone
        ln_ratio = (ln_R_then - np.log(c + eps) - ln_R_now + np.log(c_inf + eps)) / p.n
        u = np.expm1(np.minimum(ln_ratio, LN_CONTRAST_MAX))
        side = 1.0
    tiny = np.finfo(np.float32).tiny
    u = u / np.maximum(np.abs(u).max(axis=0), tiny)  # in [-1, 1]: its square cannot overflow
    u = u / np.maximum(np.sqrt((u**2).sum(axis=0)), tiny)
    if side is None:
        cosine = -(ln_gain * u).sum(axis=0) / np.maximum(length, tiny)
        side = np.clip(cosine / AGREE_COS, -1.0, 1.0)
    return np.exp(-length * side * u)


def bleach_term(B: np.ndarray, B_inf: np.ndarray, c: np.ndarray, p: Params) -> np.ndarray:
    """Eq. 12's bleaching term per cone, g j1 (C / C_max) max(B - B_inf, 0), with the display
    gain g = bleach_display_gain (1 in the paper's preset: the term as printed)."""
    return p.bleach_display_gain * p.j1 * c * np.maximum(B - B_inf, 0.0)


def bleach_response(
    I: np.ndarray, B: np.ndarray, B_inf: np.ndarray, c: np.ndarray, A: float, p: Params
) -> np.ndarray:
    """Eq. 12's bleaching term per cone, shown as the cone's response to an equivalent light.

    x = g j1 (C / C_max) max(B - B_inf, 0), with the display gain g = bleach_display_gain (ours),
    is the response the paper adds. The light that gives response x at the adaptation floor
    A_min, I_x = R^-1(x), is added to the cone's input, and the added response R(I + I_x) - R(I)
    at the current adaptation A is returned (Barlow's "dark light" of bleached pigment). On black
    at the floor that is x itself; a background as bright as I_x masks it (Sec. 2.2.2), and so
    does a light-adapted eye. R(I + I_x) - R(I) is computed as (1 - R(I)) R(I + I_x)
    (1 - (I / (I + I_x))^n), the last factor as -expm1(-n log1p(I_x / I)): nothing cancels
    when I_x << I (the kernel has its own log1pv and one_minus_exp_negv for float32).
    """
    x = np.minimum(bleach_term(B, B_inf, c, p), 1.0 - p.alpha_eps)  # below 1, as Eq. 11's guard
    with np.errstate(divide="ignore"):
        ln_odds = np.log(x) - np.log1p(-x)
    I_x = np.exp((ln_sigma_n(p.A_min, p) + ln_odds) / p.n)  # R^-1(x) at A_min; 0 for x = 0
    I = np.asarray(I, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):  # I = 0: all of I_x shows
        ratio = np.where(I_x > 0, I_x / I, 0.0)
    unmasked = -np.expm1(-p.n * np.log1p(ratio))  # 1 - (I / (I + I_x))^n, no cancelling
    return (1.0 - tone(I, A, p)) * tone(I + I_x, A, p) * unmasked


def afterimage_maps(state, down, surround, A, gaze, lay: Layout, p: Params) -> np.ndarray:
    """The maps every afterimage model makes for `compose`: a multiplicative gain per cone
    (here Eq. 11's, per cone or along the light of the linear state: `opponent_gain`) and an
    additive linear-RGB term (here H times Eq. 12's bleaching term, as printed or as a response
    to its equivalent light: `bleach_response`)."""
    I = retina_input(down, surround, gaze, lay)
    b1 = np.asarray(p.b1)[:, None, None]
    b2 = np.asarray(p.b2)[:, None, None]
    B_inf = b1 * I / (b1 * I + b2)  # Eq. 6
    c_inf = 1.0 - tone(I, A, p)  # Eq. 10 / C_max
    B, c = state[:3], state[3:6]
    if p.gain_along_adapting_light:
        gain = opponent_gain(c, c_inf, p, linear_contrast(state[6:9], adapted_light(I, A, p), p))
    else:
        gain = np.exp(eq11_ln_gain(c, c_inf, p))
    if p.bleach_equivalent_light:
        bleach = bleach_response(I, B, B_inf, c, A, p)
    else:
        bleach = bleach_term(B, B_inf, c, p)
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
    # A radiance: LMS to RGB of a blurred saturated colour can dip below 0, which G cannot.
    return G + w * (np.maximum(rgb, 0.0) - G)


def compose_base(G, rho, A, eyes: float, lay: Layout, p: Params) -> np.ndarray:
    """The first half of `compose`: tone curve with Purkinje (Eq. 13) and hue shift, linear RGB
    (3×H×W) before Eq. 12. Nothing here depends on the gaze: a late gaze warp sends it (RGB,
    not LMS: LMS_TO_RGB's large coefficients would magnify a half float's rounding)."""
    X, Y = screen_coords(lay)
    G = eyes * G
    rc = np.clip(bilinear(rho[None], X / lay.cell, Y / lay.cell)[0], 0.0, 1.0)
    yp = np.tensordot(np.asarray(p.w_P), G, axes=1)
    ys = np.tensordot(np.asarray(p.tone_scotopic_weights()), G, axes=1)
    R = tone(rc * yp + (1 - rc) * ys, A, p)  # Purkinje: mesopic luminance into Eq. 1
    ratio = rc * G / np.maximum(yp, p.Y_min) + (1 - rc) * np.asarray(p.k_s)[:, None, None]
    return R * ratio


def apply_afterimages(
    rgb, maps, gaze, lay: Layout, p: Params, visibility: float = 1.0
) -> np.ndarray:
    """The second half of `compose`: the afterimage maps (Eq. 12) read at pixel - gaze and
    seen with `visibility` (Sec. 5's boost) times the foveal fall-off, gamut, gamma; H×W×3.
    The oracle of the viewer's late gaze warp (web/warp.js), which runs it at a newer gaze."""
    X, Y = screen_coords(lay)
    gx = (X - gaze[0]) / lay.cell + lay.grid_w / 2
    gy = (Y - gaze[1]) / lay.cell + lay.grid_h / 2
    m = bilinear(maps, gx, gy, border=(1.0, 1.0, 1.0, 0.0, 0.0, 0.0))
    sig_f = lay.px(p.fovea_sigma_deg)
    f = visibility * np.exp(-((X - gaze[0]) ** 2 + (Y - gaze[1]) ** 2) / (2 * sig_f * sig_f))
    lms = np.tensordot(RGB_TO_LMS, rgb, axes=1) * (1 + f * (m[:3] - 1))
    J = np.tensordot(LMS_TO_RGB, lms, axes=1) + f * m[3:]
    J = gamut_map(J, p.w_P)
    return np.power(J, p.gamma).transpose(1, 2, 0)


def compose(
    G, rho, maps, A, gaze, eyes: float, lay: Layout, p: Params, visibility: float = 1.0
) -> np.ndarray:
    """Tone curve with Purkinje (Eq. 13), hue shift, afterimages (Eq. 12) seen with
    `visibility` (Sec. 5's boost) times the foveal fall-off, gamut, gamma."""
    rgb = compose_base(G, rho, A, eyes, lay, p)
    return apply_afterimages(rgb, maps, gaze, lay, p, visibility)


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
            "state": np.zeros((9, lay.grid_h, lay.grid_w)),
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

    def wait(self) -> None:
        """Stages run at once, on the host: nothing is left to wait for."""

    def alongside(self, side: Callable[[], None], main: Callable[[], None]) -> None:
        """`side` then `main` (the OpenCL backend runs them at once)."""
        side()
        main()

    def compose(self, gaze, eyes: float, visibility: float = 1.0) -> np.ndarray:
        a = self.a
        v = compose(a["G"], a["rho"], a["maps"], self.A, gaze, eyes, self.lay, self.p, visibility)
        a["v"] = v.astype(np.float32)
        return a["v"]

    def warp_layers(self, eyes: float) -> tuple[np.ndarray, np.ndarray]:
        """What a late gaze warp sends (`gazehdr.warp`): linear RGB before Eq. 12 (H×W×3) and
        the afterimage maps of the whole retina grid as gain - 1 and the additive term
        (2×grid_h×grid_w×3; gain - 1: a small gain keeps half floats' significant bits), both
        half floats (the OpenCL kernels compose_base and warp_maps)."""
        a = self.a
        rgb = compose_base(a["G"], a["rho"], self.A, eyes, self.lay, self.p)
        m = np.concatenate([a["maps"][:3] - 1.0, a["maps"][3:]])
        maps = m.reshape(2, 3, *m.shape[1:]).transpose(0, 2, 3, 1)
        top = float(np.finfo(np.float16).max)  # as the kernels: a half float never Inf
        rgb, maps = (np.clip(x, -top, top).astype(np.float16) for x in (rgb, maps))
        return rgb.transpose(1, 2, 0), maps
