"""Figures 4-7: bleaching afterimages (Sec. 2.2) through a flash, from the simulator.

Fig. 4 and 5 follow one point of the retina through a flash; Fig. 6/7 close the eyes after the
built-in `flash` scene and after HDR photographs. Fig. 8 and 9 (looking at something, then
away) are in `look_away`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from gazehdr.figures import photos
from gazehdr.figures.common import (
    LUMA,
    Context,
    Result,
    advance,
    crop,
    display,
    grid,
    hue_angle,
    hue_name,
    linear,
    rect_mean,
    saturation,
    save,
    simulator,
)
from gazehdr.scenes.procedural import Flash
from gazehdr.sim import Params, Simulator

_PARAMS = Params()

# --- Fig. 4 and 5: one retinal point through a flash -----------------------------------------

#: Fig. 4 and 5 read one retina cell and one pixel; a small frame holds the flash disc.
POINT_SIZE = (64, 36)
FLASH_SECONDS = 0.125  # 1/8 s (Fig. 4)
FLASH_STEPS = 8
AFTER_DT = 0.05
AFTER_SECONDS = 8.0
#: Radius of the uniform flash disc: far more than the state blur reaches in 8 s (0.1° sqrt(8)).
DISC_DEG = 3.0
INTENSITIES = (3, 4, 5, 6, 7)  # log10 cd/m^2, the rows of Fig. 5
HUE_TIMES = (AFTER_DT, 1.0, 2.0, 4.0, AFTER_SECONDS)  # s after the flash: Fig. 5's hues on the page


@dataclass(frozen=True)
class FlashTrace:
    t: np.ndarray  # seconds; 0 = the end of the flash
    bleach: np.ndarray  # (n, 3) B of the L, M, S cones at the gaze
    v: np.ndarray  # (n, 3) display value at the gaze (eyes closed after the flash)


@functools.lru_cache(maxsize=8)
def flash_trace(ctx: Context, log_luminance: float) -> FlashTrace:
    """A white disc of 10^log_luminance cd/m^2 on black for 1/8 s, fixated; then eyes closed."""
    w, h = POINT_SIZE
    sim = simulator(ctx, POINT_SIZE)
    gaze = (w / 2, h / 2)
    sim.step(0.0, gaze=gaze)
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    r = sim.layout.px(DISC_DEG)
    disc = ((xs - gaze[0]) ** 2 + (ys - gaze[1]) ** 2 <= r * r).astype(np.float32)
    scene = np.repeat(disc[..., None], 3, axis=2) * np.float32(10.0**log_luminance)

    # Retina cell whose centre is half a cell from the gaze (the grid centre is a cell corner);
    # the disc is uniform there. Reading the state is the point of Fig. 4.
    gy, gx = sim.layout.grid_h // 2, sim.layout.grid_w // 2
    cy, cx = int(gaze[1]), int(gaze[0])
    t, bleach, v = [], [], []

    def record(time: float, frame: np.ndarray) -> None:
        t.append(time)
        bleach.append(sim._backend.get("state")[:3, gy, gx])
        v.append(frame[cy, cx])

    dark = sim.step(FLASH_SECONDS, gaze=gaze)  # on black, at equilibrium already
    record(-FLASH_SECONDS, dark)
    sim.load_scene(scene, reset=False)
    for i in range(FLASH_STEPS):
        record(FLASH_SECONDS * ((i + 1) / FLASH_STEPS - 1), sim.step(FLASH_SECONDS / FLASH_STEPS))
    sim.load_scene(np.zeros_like(scene), reset=False)
    for i in range(round(AFTER_SECONDS / AFTER_DT)):
        record((i + 1) * AFTER_DT, sim.step(AFTER_DT, eyes_open=False))
    return FlashTrace(np.array(t), np.array(bleach, np.float64), np.array(v, np.float64))


def _half_life(t: np.ndarray, b: np.ndarray) -> float:
    """Seconds after t = 0 until `b` falls to half its value at t = 0 (interpolated)."""
    after = t >= 0
    t, b = t[after], b[after]
    below = np.nonzero(b <= b[0] / 2)[0]
    if not below.size or below[0] == 0:
        return float("nan")
    i = below[0]
    return float(t[i - 1] + (t[i] - t[i - 1]) * (b[i - 1] - b[0] / 2) / (b[i - 1] - b[i]))


def fig4(ctx: Context) -> Result:
    import matplotlib.pyplot as plt

    b2 = np.array(_PARAMS.b2)
    tr = flash_trace(ctx, 7.0)
    res = Result()
    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=100)
    ax.axvspan(-FLASH_SECONDS, 0, color="0.85", label="flash (1/8 s, $10^7$ cd/m²)")
    for k, (name, colour) in enumerate((("L", "tab:red"), ("M", "tab:green"), ("S", "tab:blue"))):
        ax.plot(tr.t, tr.bleach[:, k], color=colour, label=f"{name} cone")
    ax.set_xlim(-2 * FLASH_SECONDS, 6.0)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("time after the flash (s)")
    ax.set_ylabel("bleaching level B")
    ax.legend(loc="upper right", frameon=False)
    fig.tight_layout()
    fig.savefig(ctx.out_dir / "fig04_bleaching.png")
    plt.close(fig)
    res.images.append(("fig04_bleaching.png", "Bleaching level of L, M, S cones over time"))

    at0 = tr.bleach[tr.t == 0][0]
    halves = [_half_life(tr.t, tr.bleach[:, k]) for k in range(3)]
    res.measures = {
        "t": tr.t.round(6).tolist(),
        "B": tr.bleach.round(6).tolist(),
        "B_at_end_of_flash": at0.round(4).tolist(),
        "half_life_s": [round(x, 3) for x in halves],
        "half_life_eq5_s": (np.log(2) / b2).round(3).tolist(),
    }
    res.findings = [
        "At the end of the flash B = {:.2f} (L), {:.2f} (M), {:.2f} (S).".format(*at0),
        "Half-lives in the dark: {:.2f} s (L), {:.2f} s (M), {:.2f} s (S); Eq. 5 with I = 0 "
        "gives ln 2 / b2 = {:.2f}, {:.2f}, {:.2f} s.".format(*halves, *np.log(2) / b2),
    ]
    return res


def fig5(ctx: Context) -> Result:
    import matplotlib.pyplot as plt

    traces = {e: flash_trace(ctx, float(e)) for e in INTENSITIES}
    after = traces[7].t > 0
    t = traces[7].t[after]
    rows = np.stack([traces[e].v[after] for e in reversed(INTENSITIES)])  # 10^7 on top
    peak = rows.max(axis=2, keepdims=True)
    hue_only = np.where(peak > 1 / 255, rows / np.maximum(peak, 1e-12), 0.0)
    res = Result()
    fig, axes = plt.subplots(2, 1, figsize=(7.0, 4.6), dpi=100)
    for ax, img, title in (
        (axes[0], rows, "as displayed (eyes closed)"),
        (axes[1], hue_only, "each swatch scaled to full brightness (hue only)"),
    ):
        ax.imshow(img, aspect="auto", interpolation="nearest", extent=(0, t[-1], 5, 0))
        ax.set_yticks(np.arange(5) + 0.5, [f"$10^{e}$" for e in reversed(INTENSITIES)])
        ax.set_ylabel("flash (cd/m²)")
        ax.set_title(title, fontsize=10)
    axes[1].set_xlabel("time after the flash (s)")
    fig.tight_layout()
    fig.savefig(ctx.out_dir / "fig05_flash_intensity.png")
    plt.close(fig)
    res.images.append(("fig05_flash_intensity.png", "Afterimage colour over time per flash"))

    start = 0
    lin = {e: linear(traces[e].v[after], _PARAMS) for e in INTENSITIES}
    at = [int(np.searchsorted(t, s - 1e-9)) for s in HUE_TIMES]
    # Hues as the display shows them (v, gamma-encoded, as the paper's figure is seen) and of
    # the light (linear); the last sample is the end of the record.
    hues = {
        space: {str(e): [round(hue_angle(x[e][i]), 1) for i in at] for e in INTENSITIES}
        for space, x in (("display", {e: traces[e].v[after] for e in INTENSITIES}), ("linear", lin))
    }
    res.measures = {
        "times_s": t.round(4).tolist(),
        "rgb_linear": {str(e): lin[e].round(6).tolist() for e in INTENSITIES},
        "green_share_at_start": {
            str(e): round(float(lin[e][start, 1] / max(lin[e][start].sum(), 1e-12)), 4)
            for e in INTENSITIES
        },
        "hue_times_s": [round(float(t[i]), 4) for i in at],
        "hue_deg": hues,
    }
    res.findings = [
        f"10^{e} cd/m²: "
        + ", ".join(
            f"{'starts' if k == 0 else f'{t[i]:g} s'} {hue_name(traces[e].v[after][i], 0.0)} "
            f"({hues['display'][str(e)][k]:.0f}° on the display, {hues['linear'][str(e)][k]:.0f}° "
            "in light)"
            for k, i in enumerate(at)
        )
        + "."
        for e in INTENSITIES
    ]
    return res


# --- Fig. 6/7: eyes closed after a flash, three models -----------------------------------------

#: Seconds after the eyes close (the columns of Fig. 7). Mikamo et al.'s afterimage lasts longer
#: and the paper's Fig. 6 plays it at 2x: its column t shows its simulated time 2t.
KEY_TIMES = (0.5, 1.0, 2.0, 4.0, 8.0)
AFTERIMAGE_MODELS = (("jacobs", 1.0), ("ritschel", 1.0), ("mikamo", 2.0))
FRAME_DT = 1 / 30  # around the flash: the frame rate of the live viewer
#: Afterwards frames of 0.1 s for the first second, then 0.25 s: the afterimages change over
#: seconds (Jacobs' steps are exact for any dt; the baselines integrate per frame).
SEQUENCE_DT = ((1.0, 0.1), (float("inf"), 0.25))
#: The part of the frame around the flash head that the panels show (fractions of the frame).
FLASH_CROP = (0.3, 0.4)
BRIGHTEN = 4  # the second image of Fig. 6/7: linear light times this, to show dim colours


def flash_sequence(ctx: Context, model: str, speed: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """The `flash` scene fixated at its flash head: the frame that ends the 1/8 s flash, then the
    eyes close at once and the afterimage is taken at speed x KEY_TIMES."""
    scene, (w, h) = Flash(), (ctx.width, ctx.height)
    sim = simulator(ctx, afterimage=model)
    gaze = (scene.flash_centre[0] * w, scene.flash_centre[1] * h)
    sim.start(scene.render(0.0, w, h), gaze)
    advance(sim, 2 * FRAME_DT, FRAME_DT)
    sim.load_scene(scene.render(scene.first, w, h), reset=False)
    flash = advance(sim, scene.duration, FRAME_DT)
    sim.load_scene(scene.render(0.0, w, h), reset=False)
    return flash, eyes_closed(sim, speed)


def eyes_closed(sim: Simulator, speed: float) -> list[np.ndarray]:
    """The eyes close at once: the frames at speed x KEY_TIMES (steps of SEQUENCE_DT)."""
    frames, now = [], 0.0
    for t in KEY_TIMES:
        for until, dt in SEQUENCE_DT:
            if now < min(speed * t, until):
                v = advance(sim, min(speed * t, until) - now, dt, eyes_open=False)
                now = min(speed * t, until)
        frames.append(v)
    return frames


def fig6_7(ctx: Context) -> Result:
    for photo in photos.PHOTOS:  # a missing photograph fails the figure before any run
        photos.load(photo)
    res, scene = Result(), Flash()
    (cx, cy), (hw, hh), aspect = scene.flash_centre, scene.flash_half_size, ctx.width / ctx.height
    head = (cx - hw / aspect, cy - hh, cx + hw / aspect, cy + hh)  # the flash head, fractions
    rows, labels, colours = [], [], {}
    for model, speed in AFTERIMAGE_MODELS:
        flash, frames = flash_sequence(ctx, model, speed)
        rows.append([crop(v, scene.flash_centre, FLASH_CROP) for v in (flash, *frames)])
        labels.append(f"{model}" + (f" (at {speed:g}x)" if speed != 1 else ""))
        colours[model] = [rect_mean(linear(v, _PARAMS), head, keep=1.0) for v in frames]
    cols = ["flash (eyes open)", *(f"t = {t:g} s" for t in KEY_TIMES)]
    scale = max(1, math.ceil(160 / rows[0][0].shape[1]))
    alt = "Afterimage of a camera flash with the eyes closed: Jacobs, Ritschel, Mikamo"
    save(ctx, res, "fig06_07_flash_afterimages.png", grid(rows, labels, cols, scale=scale), alt)
    bright = [[display(BRIGHTEN * linear(v, _PARAMS), _PARAMS) for v in row] for row in rows]
    image = grid(bright, labels, cols, scale=scale)
    save(ctx, res, "fig06_07_flash_afterimages_x4.png", image, f"The same, {BRIGHTEN}x brighter")
    res.measures = {
        "key_times_s": list(KEY_TIMES),
        "spot_rgb_linear": {m: np.round(c, 6).tolist() for m, c in colours.items()},
        "spot_saturation": {
            m: [round(float(saturation(x)), 4) for x in c] for m, c in colours.items()
        },
    }
    res.findings = [
        f"{model}: "
        + ", ".join(f"{t:g} s {hue_name(x)}" for t, x in zip(KEY_TIMES, c, strict=True))
        for model, c in colours.items()
    ]
    _photo_rows(ctx, res)
    return res


# Fig. 7's top rows: HDR photographs (gazehdr.figures.photos), ours and Ritschel's.

PHOTO_MODELS = ("jacobs", "ritschel")
#: The eye settles on the photograph (as after a look of a few seconds: the bleaching's time
#: constant 1/(b1 I + b2) is at most 0.55 s at 10^3.5 cd/m^2), sees it for OPEN_SECONDS more
#: (the first panel), then the eyes close.
OPEN_SECONDS = 2 * FRAME_DT
#: The region whose afterimage colour is measured: where the photograph is at least this
#: fraction of its peak luminance (the lamp, the sky).
BRIGHT_FRACTION = 0.5


def photo_sequence(
    ctx: Context, photo: photos.Photo, model: str
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Look at `photo` (at its peak) from its gaze, settled; then the eyes close at once."""
    rgb, _ = photos.radiance(photo, ctx.width, ctx.height)
    sim = simulator(ctx, afterimage=model)
    sim.start(rgb, (photo.gaze[0] * ctx.width, photo.gaze[1] * ctx.height))
    seen = advance(sim, OPEN_SECONDS, FRAME_DT)
    return seen, eyes_closed(sim, 1.0)


def _photo_rows(ctx: Context, res: Result) -> None:
    """The photographs' rows (Fig. 7's top two) as a second pair of images, and their numbers
    under `photos` in the measures."""
    rows, labels, measures = [], [], {}
    for photo in photos.PHOTOS:
        rgb, factor = photos.radiance(photo, ctx.width, ctx.height)
        Y = rgb @ LUMA
        bright = Y >= BRIGHT_FRACTION * Y.max()
        y, x = np.unravel_index(int(np.argmax(Y)), Y.shape)
        peak = (slice(max(y - 1, 0), y + 2), slice(max(x - 1, 0), x + 2))  # 3×3 around it
        colours, at_peak = {}, {}
        for model in PHOTO_MODELS:
            seen, frames = photo_sequence(ctx, photo, model)
            rows.append([seen, *frames])
            labels.append(f"{photo.title}, 10^{photo.peak_log:g} cd/m^2: {model}")
            colours[model] = [linear(v, _PARAMS)[bright].mean(axis=0) for v in frames]
            at_peak[model] = [linear(v, _PARAMS)[peak].reshape(-1, 3).mean(axis=0) for v in frames]
        measures[photo.key] = {
            "file": f"{photo.key}.exr",
            "peak_cd_m2": round(float(Y.max()), 3),
            "scale_factor": factor,
            "bright_pixels": int(bright.sum()),
            "bright_rgb_linear": {m: np.round(c, 6).tolist() for m, c in colours.items()},
            "bright_saturation": {
                m: [round(float(saturation(x)), 4) for x in c] for m, c in colours.items()
            },
            "peak_rgb_linear": {m: np.round(c, 6).tolist() for m, c in at_peak.items()},
        }
        res.findings += [
            f"{photo.title} (peak 10^{photo.peak_log:g} cd/m², the file's values × "
            f"{factor:.4g}), {model}: at its brightest pixel "
            + ", ".join(
                f"{t:g} s {hue_name(x)}" for t, x in zip(KEY_TIMES, at_peak[model], strict=True)
            )
            + "; over its brightest part "
            + ", ".join(f"{t:g} s {hue_name(x)}" for t, x in zip(KEY_TIMES, c, strict=True))
            for model, c in colours.items()
        ]
    cols = ["photograph (eyes open)", *(f"t = {t:g} s" for t in KEY_TIMES)]
    scale = max(1, math.ceil(160 / ctx.width))
    alt = "Afterimages of two HDR photographs with the eyes closed: Jacobs, Ritschel"
    _save_photo(ctx, res, "fig07_photo_afterimages.png", grid(rows, labels, cols, scale=scale), alt)
    bright_rows = [[display(BRIGHTEN * linear(v, _PARAMS), _PARAMS) for v in r] for r in rows]
    image = grid(bright_rows, labels, cols, scale=scale)
    _save_photo(
        ctx, res, "fig07_photo_afterimages_x4.png", image, f"The same, {BRIGHTEN}x brighter"
    )
    res.measures["photos"] = measures


def _save_photo(ctx: Context, res: Result, name: str, image, alt: str) -> None:
    """As `save`, at zlib's default level: `optimize` takes 1.5 s per image of photographs at
    320×180 and makes them only 8 % smaller."""
    image.save(ctx.out_dir / name)
    res.images.append((name, alt))
