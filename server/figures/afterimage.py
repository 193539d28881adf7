"""Figures 4-9: bleaching and local-adaptation afterimages (Sec. 2.2), from the simulator.

Fig. 4 and 5 follow one point of the retina through a flash; Fig. 6/7 close the eyes after the
built-in `flash` scene; Fig. 8 and 9 fixate the bulb of the built-in `lamp` scene and then look
at the book.
"""

from __future__ import annotations

import colorsys
import functools
import math
from dataclasses import dataclass

import numpy as np

from server.figures.common import (
    LUMA,
    Context,
    Result,
    advance,
    crop,
    display,
    grid,
    linear,
    rect_mean,
    saturation,
    save,
    simulator,
    zoom,
)
from server.scenes.procedural import Flash, Lamp
from server.sim import Params, Simulator
from server.sim.reference import afterimage_maps, compose

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


#: Upper ends of HSV hue ranges (degrees) and their names, for the page's findings.
_HUES = (
    (15, "red"), (45, "orange"), (70, "yellow"), (150, "green"), (200, "cyan"), (255, "blue"),
    (285, "purple"), (335, "magenta"), (361, "red"),
)  # fmt: skip


def hue_name(rgb: np.ndarray) -> str:
    """A coarse name for the colour of linear RGB."""
    rgb = np.maximum(np.asarray(rgb, np.float64), 0.0)
    if rgb.max() <= 1e-6:
        return "black"
    if saturation(rgb) < 0.15:
        return "grey"
    hue = colorsys.rgb_to_hsv(*(rgb / rgb.max()))[0] * 360
    return next(name for limit, name in _HUES if hue < limit)


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

    start, late = 0, int(np.searchsorted(t, 3.0))
    lin = {e: linear(traces[e].v[after], _PARAMS) for e in INTENSITIES}
    res.measures = {
        "times_s": t.round(4).tolist(),
        "rgb_linear": {str(e): lin[e].round(6).tolist() for e in INTENSITIES},
        "green_share_at_start": {
            str(e): round(float(lin[e][start, 1] / max(lin[e][start].sum(), 1e-12)), 4)
            for e in INTENSITIES
        },
    }
    res.findings = [
        f"10^{e} cd/m²: starts {hue_name(lin[e][start])}, at 3 s {hue_name(lin[e][late])}."
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
    sim.step(0.0, gaze=gaze)
    sim.load_scene(scene.render(0.0, w, h))
    advance(sim, 2 * FRAME_DT, FRAME_DT)
    sim.load_scene(scene.render(scene.first, w, h), reset=False)
    flash = advance(sim, scene.duration, FRAME_DT)
    sim.load_scene(scene.render(0.0, w, h), reset=False)
    frames, now = [], 0.0
    for t in KEY_TIMES:
        for until, dt in SEQUENCE_DT:
            if now < min(speed * t, until):
                v = advance(sim, min(speed * t, until) - now, dt, eyes_open=False)
                now = min(speed * t, until)
        frames.append(v)
    return flash, frames


def fig6_7(ctx: Context) -> Result:
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
    return res


# --- Fig. 8 and 9: fixate the lamp, then look at the book ---------------------------------------

FIXATION_SECONDS = 3.0
AFTER_MOVE_SECONDS = 0.3
FIXATION_DT = 0.25  # frames while fixating the lamp (the bulb bleaches in the first one)
LOOK_DT = 0.1  # frames after the gaze moved
#: The part of the frame the "after" panels show: the book (fractions of the frame).
BOOK_CROP_CENTRE, LAMP_CROP_CENTRE, BOOK_CROP = (0.5, 0.78), (0.5, 0.36), (0.6, 0.45)


def _scale(ctx: Context) -> int:
    """Enlargement of the crops: at least 300 px wide, whole pixels."""
    return max(1, math.ceil(300 / (BOOK_CROP[0] * ctx.width)))


SPOT_RADIUS = 0.04  # frame heights: the inside of the bulb's afterimage (the bulb is 0.06)


@dataclass(frozen=True)
class LampRun:
    fixating: np.ndarray  # v while fixating the bulb
    after: np.ndarray  # v AFTER_MOVE_SECONDS after the gaze moved to the book
    gaze: tuple[float, float]  # the gaze on the book, screen px
    sim: Simulator  # in the state of `after`, for the reference recomposition of Fig. 8


@functools.lru_cache(maxsize=4)
def lamp_run(ctx: Context, model: str) -> LampRun:
    w, h = ctx.width, ctx.height
    bulb = (Lamp.bulb_centre[0] * w, Lamp.bulb_centre[1] * h)
    page = ((Lamp.book_centre[0] - 0.16 * h / w) * w, Lamp.book_centre[1] * h)  # left page
    sim = simulator(ctx, afterimage=model)
    sim.step(0.0, gaze=bulb)
    sim.load_scene(Lamp().render(0.0, w, h))
    fixating = advance(sim, FIXATION_SECONDS, FIXATION_DT, gaze=bulb)
    after = advance(sim, AFTER_MOVE_SECONDS, LOOK_DT, gaze=page)
    return LampRun(fixating, after, page, sim)


def _arrays(sim: Simulator) -> dict[str, np.ndarray]:
    b = sim._backend
    return {name: b.get(name).astype(np.float64) for name in ("state", "down", "G", "rho")}


def without_afterimage(sim: Simulator) -> np.ndarray:
    """The current frame through the NumPy reference compose with neutral maps (gain 1, add 0):
    the same scene, acuity and adaptation A, no afterimage of any model."""
    a, lay = _arrays(sim), sim.layout
    maps = np.concatenate(
        [np.ones((3, lay.grid_h, lay.grid_w)), np.zeros((3, lay.grid_h, lay.grid_w))]
    )
    return compose(a["G"], a["rho"], maps, sim.adaptation, sim.gaze, 1.0, lay, sim.params)


def recompose(sim: Simulator, *, calcium: bool) -> np.ndarray:
    """The current frame of the Jacobs model through the NumPy reference from the simulator's
    own state: Eq. 12 (`calcium`), or Eq. 7, the bleaching term without C/C_max and without the
    adaptation gain alpha^j2 (c := 1 in the bleaching term, j2 = 0)."""
    a, p = _arrays(sim), sim.params
    if not calcium:
        a["state"][3:] = 1.0
        p = p.replace(j2=0.0)
    maps = afterimage_maps(a["state"], a["down"], sim.adaptation, sim.gaze, sim.layout, p)
    return compose(a["G"], a["rho"], maps, sim.adaptation, sim.gaze, 1.0, sim.layout, p)


def _spot(v: np.ndarray, gaze: tuple[float, float]) -> np.ndarray:
    """Mean linear RGB inside the afterimage of the bulb, which lies at the new gaze."""
    h, w = v.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    inside = (xs - gaze[0]) ** 2 + (ys - gaze[1]) ** 2 <= (SPOT_RADIUS * h) ** 2
    return linear(v, _PARAMS)[inside].mean(axis=0)


def _book(ctx: Context, v: np.ndarray, centre: tuple[float, float] = BOOK_CROP_CENTRE):
    return zoom(crop(v, centre, BOOK_CROP), _scale(ctx))


def fig8(ctx: Context) -> Result:
    run, res = lamp_run(ctx, "jacobs"), Result()
    original = without_afterimage(run.sim)
    eq7 = recompose(run.sim, calcium=False)
    eq12 = recompose(run.sim, calcium=True)
    columns = ["scene (no afterimage)", "Eq. 7: without C/C_max", "Eq. 12: with C/C_max"]
    panels = [_book(ctx, v) for v in (original, eq7, run.after)]
    alt = "Bleaching afterimage of the bulb without and with the calcium term"
    save(ctx, res, "fig08_calcium.png", grid([panels], [""], columns), alt)
    scene = _spot(original, run.gaze)
    added = {"eq7": _spot(eq7, run.gaze) - scene, "eq12": _spot(run.after, run.gaze) - scene}
    error = float(np.abs(eq12 - run.after).max())
    res.measures = {
        "spot_rgb_linear_scene": np.round(scene, 6).tolist(),
        "spot_rgb_added": {k: np.round(x, 6).tolist() for k, x in added.items()},
        "reference_vs_simulator_max_abs": float(f"{error:.3g}"),
    }
    res.findings = [
        f"Inside the bulb's afterimage on the book the page is {_fmt(scene)} (linear RGB); "
        f"Eq. 7 adds {_fmt(added['eq7'])}, Eq. 12 adds {_fmt(added['eq12'])}.",
        f"The reference recomposition of the simulator's own state (Eq. 12) differs from its "
        f"frame by at most {error:.1e} in v.",
    ]
    return res


def _fmt(rgb: np.ndarray) -> str:
    return "({:+.4f}, {:+.4f}, {:+.4f})".format(*rgb)


def fig9(ctx: Context) -> Result:
    res, rows, ratios = Result(), [], {}
    for model in ("jacobs", "ritschel"):
        run = lamp_run(ctx, model)
        plain = without_afterimage(run.sim)
        lamp = _book(ctx, run.fixating, LAMP_CROP_CENTRE)
        rows.append([lamp, _book(ctx, plain), _book(ctx, run.after)])
        ratios[model] = float(_spot(run.after, run.gaze) @ LUMA / (_spot(plain, run.gaze) @ LUMA))
    columns = [
        f"fixating the lamp {FIXATION_SECONDS:g} s",
        f"{AFTER_MOVE_SECONDS:g} s on the book: no afterimage",
        "with the model's afterimage",
    ]
    alt = "Adaptation afterimage of the lamp on the book: ours dark, Ritschel bright"
    save(ctx, res, "fig09_adaptation.png", grid(rows, ["jacobs", "ritschel"], columns), alt)
    res.measures = {"spot_luminance_ratio": {k: round(v, 4) for k, v in ratios.items()}}
    res.findings = [
        f"{m}: the afterimage region has {r:.2f}x the luminance it has without the afterimage "
        f"({'darker' if r < 1 else 'brighter'})."
        for m, r in ratios.items()
    ]
    return res
