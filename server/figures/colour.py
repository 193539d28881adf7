"""Fig. 9 with the hue circle: Fig. 9's colour row repeated for saturated squares of twelve hues
at the grey's luminance, each afterimage's hue against the complement of its squares' hue.

The complement of a colour about a grey is grey - k (colour - grey), the hue 180° away; the
afterimage's hue is that of its linear RGB over the grey around it. docs/model.md ("Adaptation
colour") shows the table this measures, before and after the model chose where the calcium gain
acts.
"""

from __future__ import annotations

import colorsys

import numpy as np

from gazehdr.figures import look_away
from gazehdr.figures.common import (
    HUE_NAMES,
    LUMA,
    Context,
    Result,
    crop,
    display,
    grid,
    hue_angle,
    hue_difference,
    linear,
    save,
    zoom,
)
from gazehdr.sim import Params

_PARAMS = Params()
HUE_STEPS = 12  # inducer hues, 30° apart from red: the RGB colour wheel's twelve
EXAGGERATE = 5  # the third row: the afterimage's change from the grey, this many times larger


def inducer(hue_deg: float) -> np.ndarray:
    """The saturated colour of `hue_deg` (HSV s = v = 1) at the grey field's luminance, cd/m^2."""
    rgb = np.array(colorsys.hsv_to_rgb(hue_deg / 360, 1.0, 1.0))
    return rgb * look_away.GREY_FIELD / float(rgb @ LUMA)


def _hue_circle(ctx: Context, res: Result) -> dict[str, list[float]]:
    """One look-away run per hue with the jacobs model; the panels show one square."""
    w, h = ctx.width, ctx.height
    where = look_away.square_rects(w, h, look_away.FIELD_GAZE)
    around = look_away.surround_rects(w, h, look_away.FIELD_GAZE)
    x0, y0, x1, y1 = look_away.square_rects(w, h, look_away.SQUARES_GAZE)[0]
    size = (1.6 * (x1 - x0), 1.6 * (y1 - y0))
    offset = (look_away.FIELD_GAZE[0] - look_away.SQUARES_GAZE[0], 0.0)
    seen, after = ((x0 + x1) / 2, (y0 + y1) / 2), ((x0 + x1) / 2 + offset[0], (y0 + y1) / 2)
    scale = max(1, round(64 / (size[0] * w)))
    hues = [360 * k / HUE_STEPS for k in range(HUE_STEPS)]
    panels: list[list[np.ndarray]] = [[], [], []]
    measured = []
    for hue in hues:
        run = look_away.squares_run(ctx, "jacobs", inducer(hue))
        grey = look_away.mean_over(run.after, around, 1.0)
        measured.append(hue_angle(look_away.mean_over(run.after, where, 0.5) / grey))
        change = grey + EXAGGERATE * (linear(run.after, _PARAMS) - grey)
        shown = (run.fixating, run.after, display(change, _PARAMS))
        for row, v, centre in zip(panels, shown, (seen, after, after), strict=True):
            row.append(zoom(crop(v, centre, size), scale))
    labels = ["squares fixated", "their afterimage", f"afterimage, change x{EXAGGERATE}"]
    alt = "Afterimages of saturated squares of twelve hues on grey: each the complement"
    image = grid(panels, labels, [f"{hue:.0f}°" for hue in hues])
    save(ctx, res, "fig09_hue_circle.png", image, alt)
    complements = [(hue + 180) % 360 for hue in hues]
    return {
        "inducer_hue_deg": hues,
        "complement_hue_deg": complements,
        "afterimage_hue_deg": [round(x, 1) for x in measured],
        "error_deg": [
            round(hue_difference(m, c), 1) for m, c in zip(measured, complements, strict=True)
        ],
    }


def fig9(ctx: Context) -> Result:
    """Fig. 9 (look_away.fig9) and the hue circle."""
    res = look_away.fig9(ctx)
    circle = _hue_circle(ctx, res)
    res.measures["hue_circle"] = circle
    errors = np.array(circle["error_deg"])
    worst = int(errors.argmax())
    res.findings.append(
        f"Hue circle ({HUE_STEPS} saturated hues at the grey's luminance, jacobs): afterimage "
        f"hues are {errors.mean():.0f}° from the complement on average, at most "
        f"{errors.max():.0f}° (squares of {circle['inducer_hue_deg'][worst]:.0f}°: afterimage "
        f"{circle['afterimage_hue_deg'][worst]:.0f}°, complement "
        f"{circle['complement_hue_deg'][worst]:.0f}°). "
        + "; ".join(
            f"{i:.0f}° → {a:.0f}° ({HUE_NAMES[round(a / 30) % 12]})"
            for i, a in zip(circle["inducer_hue_deg"], circle["afterimage_hue_deg"], strict=True)
        )
        + "."
    )
    return res
