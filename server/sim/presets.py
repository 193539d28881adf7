"""Named parameter presets: the paper's values, and ours for a plain monitor.

`Params()` is the `paper` preset: Appendix A, and of our values only those the paper's results
need (docs/model.md, "Presets"). `visible` adds our tuning that makes bleaching afterimages
visible on an ordinary monitor in a lit room, at the cost of Sec. 4.1's measured luminances.
A preset is the set of values it changes over `Params()`; what it does not name is the paper's.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from gazehdr.drivers.errors import InputError
from gazehdr.sim.params import Params

#: Each preset's values over `Params()`.
PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    # Eq. 12's bleaching term 32 times stronger on the display (Fig. 4's flash reaches display
    # white in the dark) and masked by its equivalent light, so that a bright background hides
    # it and the lamp of Fig. 9 keeps its dark spot (Params, bleach_display_gain).
    "visible": {"bleach_display_gain": 32.0, "bleach_equivalent_light": True},
}
#: Where results are made (figures, experiments, renders, the Python API) and where `serve`
#: starts: the paper's numbers unless a user asks for ours (docs/model.md, "Presets").
DEFAULT_PRESET = "paper"
#: Parameters the server sets from the gaze source (the tracker's accuracy and rate), which
#: say nothing of the preset a user chose.
FROM_THE_SOURCE = ("tracker_accuracy_deg", "tracker_rate_hz")


def preset(name: str) -> Params:
    """The parameters of preset `name`."""
    if name not in PRESETS:
        raise InputError(f"no preset {name!r}; the presets are {', '.join(PRESETS)}")
    return Params().replace(**PRESETS[name])


def load_params(name: str = DEFAULT_PRESET, path: str | Path | None = None) -> Params:
    """Preset `name` with the values of a parameter file over it (JSON, partial is fine): what
    `serve --preset NAME --params FILE` and `render` run with. Errors name the file."""
    params = preset(name)
    if path is None:
        return params
    try:
        values = json.loads(Path(path).read_text())
        if not isinstance(values, dict):
            raise InputError("must be a JSON object of parameter values")
        return Params.from_dict(params.to_dict() | values)
    except OSError as e:
        raise InputError(f"parameter file {path}: {e.strerror}") from None
    except (TypeError, ValueError) as e:
        raise InputError(f"parameter file {path}: {e}") from None


def nearest_preset(params: Params) -> tuple[str, list[str]]:
    """The preset `params` differ from least, and the names of the parameters they change over
    it (the gaze source's figures not counted): ("paper", []) for the defaults."""
    ours = params.to_dict()
    best: tuple[str, list[str]] | None = None
    for name in PRESETS:
        theirs = preset(name).to_dict()
        edits = [k for k in ours if k not in FROM_THE_SOURCE and ours[k] != theirs[k]]
        if best is None or len(edits) < len(best[1]):
            best = (name, edits)
    assert best is not None
    return best


def describe(params: Params) -> str:
    """One line for the HUD and the panel: "paper", "visible", or "paper + j1, j2"."""
    name, edits = nearest_preset(params)
    if not edits:
        return name
    shown = ", ".join(edits[:3]) + (f" and {len(edits) - 3} more" if len(edits) > 3 else "")
    return f"{name} + {shown}"
