"""Scenes from HDR image files (OpenEXR, Radiance RGBE, PFM), in cd/m^2 at a stated scale.

The format is told by the file's first bytes, not its name. A scene keeps the file's values
as decoded and its scale (cd/m^2 per unit) with where the scale came from, in this order:

1. `user`: a scale given for it (`serve --scale`, the panel, `PATCH /api/scenes/NAME`);
2. `file`: the file's standard `whiteLuminance` (EXR), the luminance of RGB = (1, 1, 1);
3. `estimate`: `gazehdr.scenes.estimate`'s rule, for a file that states no unit.

`set_scale` changes it without reading the file again. The file's description (`file_info`:
format, size, layers, notes, whiteLuminance and the estimate's statistic) is all a scale and
`describe` need, so an upload's description is kept apart from its pixels
(`gazehdr.scenes.library`), and a scene opened from a reduced level of a file
(`gazehdr.scenes.level`) describes and scales as the file does.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gazehdr.scenes.decoding import MAX_PIXELS, Decoded, SceneError, read_head
from gazehdr.scenes.estimate import check_kind, estimate_from, guess_kind, median_log10_luminance
from gazehdr.scenes.exr import MAGIC as EXR_MAGIC
from gazehdr.scenes.exr import read_exr
from gazehdr.scenes.hdr import is_pfm, is_rgbe, read_pfm, read_rgbe
from gazehdr.scenes.level import level_size, reduce

#: File name suffixes of the formats, for uploads and the file picker.
SUFFIXES = {"exr": ".exr", "hdr": ".hdr", "pfm": ".pfm"}
SCALE_SOURCES = ("user", "file", "estimate")


def file_format(path: Path) -> str:
    """ "exr", "hdr" or "pfm", from the file's first bytes; SceneError for anything else."""
    head = read_head(path, 8)
    if not head:
        raise SceneError(f"{path}: empty file, not an HDR image")
    if head.startswith(EXR_MAGIC):
        return "exr"
    if is_rgbe(head):
        return "hdr"
    if is_pfm(head):
        return "pfm"
    raise SceneError(f"{path}: not an HDR image this viewer reads (OpenEXR, Radiance .hdr or PFM)")


def decode(path: Path, layer: str | None = None, *, max_pixels: int = MAX_PIXELS) -> Decoded:
    """The file's values and what its header says (see the readers' docstrings)."""
    kind = file_format(path)
    if kind == "exr":
        return read_exr(path, layer, max_pixels=max_pixels)
    if layer:
        raise SceneError(f"{path}: a {kind.upper()} file has no layers (asked for {layer!r})")
    reader = read_rgbe if kind == "hdr" else read_pfm
    return reader(path, max_pixels=max_pixels)


def identity(path: Path) -> tuple[str, int, int] | None:
    """Tells a file from the one that replaced it: path, modification time, size."""
    try:
        st = path.stat()
    except OSError:
        return None
    return (str(path), st.st_mtime_ns, st.st_size)


def check_scale(scale: float | None) -> float | None:
    if scale is not None and not (
        isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0
    ):
        raise SceneError(f"scale must be a positive finite number (cd/m² per unit), got {scale!r}")
    return None if scale is None else float(scale)


@dataclass(frozen=True)
class Scale:
    value: float  # cd/m^2 per unit
    source: str  # one of SCALE_SOURCES
    note: str  # for people: where it came from
    kind: str | None = None  # the estimate's scene kind


class ImageScene:
    """A static scene from an image file; `pixels` are in cd/m^2."""

    animated = False

    def __init__(
        self, name: str, decoded: Decoded, scale: float | None = None, kind: str | None = None
    ) -> None:
        self.name = name
        self.decoded = decoded
        self.source: tuple[str, int, int] | None = None  # the file it came from (`identity`)
        self._pixels: np.ndarray | None = None
        self.scale = self._scale(check_scale(scale), kind)

    @classmethod
    def open(
        cls,
        path: str | os.PathLike[str],
        scale: float | None = None,
        *,
        layer: str | None = None,
        kind: str | None = None,
        name: str | None = None,
        max_pixels: int = MAX_PIXELS,
    ) -> ImageScene:
        """Load `path`; `scale`: the user's cd/m^2 per unit, `kind`: the estimate's kind."""
        path = Path(path)
        scale = check_scale(scale)
        if kind is not None:
            check_kind(kind)
        scene = cls(name or path.stem, decode(path, layer, max_pixels=max_pixels), scale, kind)
        scene.source = identity(path)
        return scene

    def set_scale(self, scale: float | None, kind: str | None = None) -> None:
        """The user's scale, or None: back to the file's or the estimate (of `kind`)."""
        self.scale = self._scale(check_scale(scale), kind)
        self._pixels = None

    def keep_level(self, frames: Iterable[tuple[int, int]]) -> None:
        """Keep no more of the pixels than frames of sizes `frames` show (its level,
        `gazehdr.scenes.level`), as an upload opened in the decode worker is: for a scene
        decoded in the server's own process (a file named at start). Its description and
        scale stay the file's."""
        d = self.decoded
        size = level_size(d.rgb.shape[1], d.rgb.shape[0], frames)
        if size is None:
            return
        median = median_of(d)
        self.decoded = dataclasses.replace(
            d, rgb=reduce(d.rgb, size), size=d.file_size, median_log10=median
        )
        self._pixels = None

    def _scale(self, scale: float | None, kind: str | None) -> Scale:
        d = self.decoded
        return choose_scale(self.name, d.white_luminance, lambda: median_of(d), scale, kind)

    @property
    def pixels(self) -> np.ndarray:
        """H×W×3 float32 cd/m^2, made once per scale."""
        if self._pixels is None:
            self._pixels = np.ascontiguousarray(self.decoded.rgb * np.float32(self.scale.value))
        return self._pixels

    def describe(self) -> dict[str, Any]:
        """What the viewer and `gazehdr scenes` show of it (of the file, not of a level)."""
        return {**_file_fields(self.decoded), **describe_scale(self.scale)}

    def render(self, t: float, width: int, height: int) -> np.ndarray:
        """The pixels whatever `t`, `width`, `height`: the simulator fits them. The same
        array every call, not a copy: copy it before modifying it."""
        return self.pixels

    def state_at(self, t: float) -> object:
        return None

    def next_change(self, t: float) -> float | None:
        return None


def median_of(decoded: Decoded) -> float:
    """The estimate's statistic of the file `decoded` came from."""
    if decoded.median_log10 is not None:
        return decoded.median_log10
    return median_log10_luminance(decoded.rgb)


def choose_scale(
    name: str,
    white: float | None,
    median: Callable[[], float],
    scale: float | None,
    kind: str | None,
) -> Scale:
    """The scale in force (module docstring): the user's, the file's `white`, or an estimate
    of `kind` (default: from the scene's `name`) from the statistic `median()` gives."""
    if scale is not None:
        return Scale(scale, "user", "given by the user")
    if white is not None and kind is None:
        return Scale(white, "file", "the file's whiteLuminance")
    kind = check_kind(kind) if kind is not None else guess_kind(name)
    guess = estimate_from(median(), kind)
    return Scale(guess.scale, "estimate", guess.note, guess.kind)


def file_info(decoded: Decoded) -> dict[str, Any]:
    """What a scale and a description need of a decoded file, as JSON values."""
    return {
        **_file_fields(decoded), "white_luminance": decoded.white_luminance,
        "median_log10": median_of(decoded),
    }  # fmt: skip


def _file_fields(decoded: Decoded) -> dict[str, Any]:
    w, h = decoded.file_size
    return {
        "format": decoded.format, "width": w, "height": h, "layers": list(decoded.layers),
        "layer": decoded.layer, "notes": list(decoded.notes),
    }  # fmt: skip


def describe_file(info: dict[str, Any]) -> dict[str, Any]:
    """The file's part of a description (`ImageScene.describe`), from its `file_info`."""
    return {
        "format": info["format"], "width": info["width"], "height": info["height"],
        "layers": list(info["layers"]), "layer": info["layer"], "notes": list(info["notes"]),
    }  # fmt: skip


def describe_scale(scale: Scale) -> dict[str, Any]:
    return {
        "scale": scale.value, "scale_source": scale.source, "scale_note": scale.note,
        "kind": scale.kind,
    }  # fmt: skip
