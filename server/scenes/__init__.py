"""HDR scenes in absolute units (cd/m^2): built-in procedural ones and image files.

A scene is anything with `render(t, width, height)`: the radiance at time `t` seconds as an
H×W×3 float32 array of linear Rec.709 cd/m^2. Procedural scenes draw at the size asked for;
a file scene (OpenEXR, Radiance .hdr, PFM: `gazehdr.scenes.image`) returns its pixels and
lets the simulator fit them.
"""

from __future__ import annotations

from pathlib import Path

from gazehdr.drivers.errors import InputError
from gazehdr.scenes.scene import Scene


def builtin_names() -> list[str]:
    from gazehdr.scenes.procedural import BUILTIN

    return sorted(BUILTIN)


def open_scene(spec: str, scale: float | None = None, layer: str | None = None) -> Scene:
    """A built-in scene by name, or an image file by path (`scale`: cd/m^2 per unit, which
    overrides the file's and the estimate; `layer`: an EXR layer)."""
    from gazehdr.scenes.procedural import BUILTIN

    if spec in BUILTIN:
        return BUILTIN[spec]()
    path = Path(spec)
    if path.suffix.lower() in (".exr", ".hdr", ".pic", ".pfm") or path.exists():
        from gazehdr.scenes.image import ImageScene

        return ImageScene.open(path, scale=scale, layer=layer)
    raise InputError(
        f"unknown scene {spec!r}: not a built-in ({', '.join(builtin_names())}) nor an image "
        "file (.exr, .hdr, .pfm)"
    )


__all__ = ["Scene", "builtin_names", "open_scene"]
