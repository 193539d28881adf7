"""Figures 10-12: the Purkinje shift, mesopic hue shift and desaturation, and acuity (Sec. 2.3).

The global adaptation A never falls below A_min = 2 (Sec. 2.4), so a scene at 0.01 cd/m^2 is
displayed almost black. Like the paper's Fig. 11 ("keeping the mean pixel brightnesses
constant"), these panels are scaled in linear light to one mean luminance per figure; scaling
keeps chromaticity and luminance ratios, which is what the figures are about.
"""

from __future__ import annotations

import functools
import itertools

import numpy as np

from gazehdr.figures.common import (
    LUMA,
    Context,
    Result,
    grey,
    grid,
    linear,
    native_geometry,
    normalise,
    rect_mean,
    saturation,
    save,
    simulator,
)
from gazehdr.scenes.procedural import CheckerNight
from gazehdr.sim import Params

#: Luminance of the white patch (cd/m^2), the columns of Fig. 11; Fig. 10 uses the last four.
LEVELS = (10.0, 1.0, 0.3, 0.1, 0.01)
#: Photopic rendering, "without any mesopic cues" (Fig. 10, left): rho >= 1 everywhere.
PHOTOPIC = {"m1": -10.0, "m2": -12.0}
#: The normalised displays put the white patch's share of the mean where an 85 % white would be.
WHITE = 0.85
RED, BLUE = 14, 12  # ColorChecker patches "red" and "blue" (reading order from 0)
CHROMATIC, NEUTRALS = range(18), range(19, 23)  # patches 19-22: neutral 8 to 3.5


def _target(scene: np.ndarray, peak: float) -> float:
    """Mean linear luminance of the display if the scene's `peak` were shown at WHITE."""
    return WHITE * float((scene @ LUMA).mean()) / peak


@functools.lru_cache(maxsize=16)
def checker(ctx: Context, white: float, photopic: bool) -> np.ndarray:
    """The ColorChecker with its white patch at `white` cd/m^2, fixated at its centre, as
    displayed after equilibrium, normalised (module docstring)."""
    w, h = ctx.width, ctx.height
    params = Params(**PHOTOPIC) if photopic else Params()
    sim = simulator(ctx, params=params)
    scene = CheckerNight(white_luminance=white).render(0.0, w, h)
    sim.start(scene, (w / 2, h / 2))
    return normalise(sim.step(0.0), params, _target(scene, white))


def _patches(v: np.ndarray) -> np.ndarray:
    """24 x 3 mean linear RGB of the patches (central half of each)."""
    h, w = v.shape[:2]
    J = linear(v, Params())
    return np.array([rect_mean(J, r) for r in CheckerNight().patch_rects(w, h)])


def fig10(ctx: Context) -> Result:
    res, rows, ratio = Result(), [], {"photopic": [], "purkinje": []}
    for white in LEVELS[1:]:
        photopic, mesopic = checker(ctx, white, True), checker(ctx, white, False)
        rows.append([photopic, grey(photopic, Params()), grey(mesopic, Params())])
        for key, v in (("photopic", photopic), ("purkinje", mesopic)):
            Y = _patches(v) @ LUMA
            ratio[key].append(round(float(Y[BLUE] / Y[RED]), 4))
    labels = [f"white {w:g} cd/m^2" for w in LEVELS[1:]]
    columns = ["no mesopic cues", "luminance", "luminance with Purkinje"]
    alt = "ColorChecker at falling luminance: colour, luminance, luminance with Purkinje"
    save(ctx, res, "fig10_purkinje.png", grid(rows, labels, columns), alt)
    res.measures = {"white_cd_m2": list(LEVELS[1:]), "blue_over_red_luminance": ratio}
    res.findings = [
        f"Luminance of the blue patch over the red one at white = {w:g} cd/m²: "
        f"{a:.2f} photopic, {b:.2f} with Purkinje."
        for w, a, b in zip(LEVELS[1:], ratio["photopic"], ratio["purkinje"], strict=True)
    ]
    return res


def _inset(ctx: Context, white: float) -> np.ndarray:
    """The corner of four patches as the paper's monitor shows it (a crop of a 1920x1080
    rendering, simulated at 64 px/°): the acuity loss at its real size."""
    w, h = ctx.width, ctx.height
    chart = CheckerNight(white_luminance=white)
    full = chart.render(0.0, 1920, 1080)
    a, b = chart.patch_rects(1920, 1080)[7], chart.patch_rects(1920, 1080)[14]
    cx, cy = round((a[2] + b[0]) / 2 * 1920), round((a[3] + b[1]) / 2 * 1080)
    x0, y0 = min(max(cx - w // 2, 0), 1920 - w), min(max(cy - h // 2, 0), 1080 - h)
    scene = full[y0 : y0 + h, x0 : x0 + w]
    params = native_geometry(w, h)
    sim = simulator(ctx, params=params)
    sim.start(scene, (w / 2, h / 2))
    return normalise(sim.step(0.0), params, _target(scene, white))


def _sharpness(Y: np.ndarray) -> float:
    """How concentrated the luminance steps are, sum(d^2) / sum(|d|)^2 over horizontal and
    vertical neighbours: blur spreads an edge of any contrast over more, smaller steps (for k
    edges n px wide it is 1 / (k n)), so it falls with blur and ignores contrast and scale."""
    d = np.concatenate([np.diff(Y, axis=0).ravel(), np.diff(Y, axis=1).ravel()])
    return float((d * d).sum() / max(np.abs(d).sum() ** 2, 1e-30))


def fig11(ctx: Context) -> Result:
    res = Result()
    frames = [checker(ctx, white, False) for white in LEVELS]
    insets = [_inset(ctx, white) for white in LEVELS]
    columns = [f"white {w:g} cd/m^2" for w in LEVELS]
    save(ctx, res, "fig11_mesopic.png",
         grid([frames, insets], ["whole chart", "inset at 64 px/°"], columns),
         "ColorChecker at falling luminance: desaturation, purple shift, acuity")  # fmt: skip
    patches = [_patches(v) for v in frames]
    sat = [round(float(saturation(p[list(CHROMATIC)]).mean()), 4) for p in patches]
    neutral = [p[list(NEUTRALS)].mean(axis=0) for p in patches]
    neutral = [n / n.mean() for n in neutral]
    inset_Y = [linear(v, Params()) @ LUMA for v in insets]
    sharp = [round(_sharpness(Y) / _sharpness(inset_Y[0]), 4) for Y in inset_Y]
    res.measures = {
        "white_cd_m2": list(LEVELS),
        "mean_saturation_chromatic_patches": sat,
        "neutral_patch_rgb_relative": [np.round(n, 4).tolist() for n in neutral],
        "inset_sharpness_relative": sharp,
    }
    res.findings = [
        "Mean saturation of the 18 chromatic patches: "
        + ", ".join(f"{s:.2f} at {w:g}" for s, w in zip(sat, LEVELS, strict=True))
        + " cd/m².",
        "Neutral patches (R, G, B relative to their mean): "
        + ", ".join(
            f"({n[0]:.2f}, {n[1]:.2f}, {n[2]:.2f}) at {w:g}"
            for n, w in zip(neutral, LEVELS, strict=True)
        )
        + ".",
        "Sharpness of the inset relative to the first column: "
        + ", ".join(f"{s:.2f}" for s in sharp)
        + ".",
    ]
    return res


# --- Fig. 12: acuity models ---------------------------------------------------------------------

ACUITY_MODELS = ("stochastic", "gaussian", "bilateral", "thompson", "none")
FRAME_TIMES = (0.0, 0.25, 0.5, 0.75)  # the stochastic noise has a key frame every 0.25 s
PERIODS = (2, 3, 4, 6, 8, 12)  # bar periods of the chart, screen px at 64 px/°
#: Peak of the chart (cd/m^2): its local mean, about a third of it, puts rho near 0.5, the
#: middle of the mesopic range, where about half of the acuity bands are dropped.
CHART_PEAK = 0.3


def _groups(width: int, height: int):
    """(period, columns, vertical-bar rows, horizontal-bar rows) of each bar group."""
    block = width // len(PERIODS)
    margin = max(1, block // 8)
    top = slice(round(0.1 * height), round(0.45 * height))
    bottom = slice(round(0.55 * height), round(0.9 * height))
    for k, period in enumerate(PERIODS):
        yield period, slice(k * block + margin, (k + 1) * block - margin), top, bottom


def resolution_chart(width: int, height: int, peak: float) -> np.ndarray:
    """Groups of bars of PERIODS px, vertical above and horizontal below, on a grey ground."""
    lum = np.full((height, width), 0.3 * peak)
    for period, cols, top, bottom in _groups(width, height):
        x = np.arange(cols.stop - cols.start)
        lum[top, cols] = np.where(x % period < period / 2, peak, 0.05 * peak)[None, :]
        y = np.arange(bottom.stop - bottom.start)
        lum[bottom, cols] = np.where(y % period < period / 2, peak, 0.05 * peak)[:, None]
    return np.repeat(lum[..., None], 3, axis=2).astype(np.float32)


def _modulation(Y: np.ndarray, period: int) -> float:
    """Contrast left in the bar groups of `period` px: std / mean over both groups."""
    h, w = Y.shape
    _, cols, top, bottom = next(g for g in _groups(w, h) if g[0] == period)
    bars = np.concatenate([Y[top, cols].ravel(), Y[bottom, cols].ravel()])
    return float(bars.std() / max(bars.mean(), 1e-30))


def fig12(ctx: Context) -> Result:
    w, h = ctx.width, ctx.height
    res, rows, params = Result(), [], native_geometry(w, h)
    scene = resolution_chart(w, h, CHART_PEAK)
    target, chart = _target(scene, CHART_PEAK), scene @ LUMA
    change, detail = {}, {}
    for model in ACUITY_MODELS:
        sim = simulator(ctx, params=params, acuity=model)
        sim.start(scene, (w / 2, h / 2))
        frames, now = [], 0.0
        for t in FRAME_TIMES:
            frames.append(normalise(sim.step(t - now), params, target))
            now = t
        rows.append(frames)
        Ys = [linear(v, params) @ LUMA for v in frames]
        steps = [np.abs(a - b).mean() for a, b in itertools.pairwise(Ys)]
        change[model] = round(float(np.mean(steps)), 6)
        detail[model] = {
            str(period): [round(_modulation(Y, period) / _modulation(chart, period), 4) for Y in Ys]
            for period in PERIODS[:3]
        }
    columns = [f"t = {t:g} s" for t in FRAME_TIMES]
    alt = "Resolution chart at a mesopic level under five acuity models, four frames each"
    save(ctx, res, "fig12_acuity.png", grid(rows, list(ACUITY_MODELS), columns), alt)
    res.measures = {"frame_to_frame_change": change, "contrast_kept": detail}
    res.findings = [
        f"{m}: contrast kept in the 2, 3, 4 px bars (mean of the frames) "
        + ", ".join(f"{np.mean(c):.2f}" for c in detail[m].values())
        + f"; mean change between frames {change[m]:.4f}."
        for m in ACUITY_MODELS
    ]
    return res
