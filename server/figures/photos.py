"""The HDR photographs of Fig. 7's top rows, and how they were made from openly licensed files.

The paper's Fig. 7 closes the eyes after two HDR photographs from Fairchild's HDR Photographic
Survey (maximum radiance about 10^3.5 and 10^4.5 cd/m^2) and after a camera flash (10^8.5). We
cannot ship Fairchild's images. Instead we ship two small views (256×144, half-float EXR) cut
from the world HDRIs that Blender ships as studio lights (Debian's `blender-data`,
/usr/share/blender/datafiles/studiolights/world/; "All HDRIs are licenses as CC0. These were
created by Greg Zaal (HDRI Haven)", says the license.txt beside them). `data/README.md` says
which files, which views, and how `make_views` made them; `python -m gazehdr.figures.photos SRC
OUT` makes them again from an installed `blender-data`.

A view is a pinhole camera (yaw, pitch, horizontal field of view) on the equirectangular
panorama, sampled bilinearly at 3×3 points per pixel and averaged. Its pixels keep the
panorama's values (relative radiance); `radiance` scales them so that the brightest pixel of the
frame the simulator sees has the paper's peak: factor = 10^peak / max(luminance) at that size.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from gazehdr.figures.common import LUMA, ModelUnavailableError
from gazehdr.scenes.decoding import SceneError
from gazehdr.scenes.exr import read_exr, write_exr
from gazehdr.sim.layout import fit_to_frame

#: Where Debian's blender-data puts the world HDRIs (the source of the shipped views).
BLENDER_WORLDS = Path("/usr/share/blender/datafiles/studiolights/world")
VIEW_SIZE = (256, 144)  # the shipped files: 16:9, as the figures' frames
SUPERSAMPLE = 3


@dataclass(frozen=True)
class Photo:
    key: str  # the file data/<key>.exr
    title: str
    source: str  # the panorama in BLENDER_WORLDS it was cut from
    yaw: float  # degrees: the view's centre, longitude on the panorama (0 its middle column)
    pitch: float  # degrees up from the horizon
    hfov: float  # horizontal field of view, degrees
    peak_log: float  # log10 cd/m^2 of the brightest pixel as the figure shows it
    gaze: tuple[float, float]  # where the eye looks, frame fractions (held, as in Fig. 7)


#: Fig. 7's top two rows, in the paper's order (maximum radiance about 3.5, then 4.5 log cd/m^2).
PHOTOS = (
    Photo("courtyard", "sunlit courtyard", "courtyard.exr", 14.0, 15.0, 90.0, 3.5, (0.5, 0.5)),
    Photo("studio", "studio lamp", "studio.exr", 62.0, 8.0, 90.0, 4.5, (0.58, 0.55)),
)


def data_dir() -> Path:
    """The folder of the shipped views (package data of gazehdr.figures)."""
    return Path(str(resources.files("gazehdr.figures") / "data"))


def path(photo: Photo) -> Path:
    return data_dir() / f"{photo.key}.exr"


def load(photo: Photo) -> np.ndarray:
    """The shipped view's pixels (relative radiance, H×W×3 float32). A missing or unreadable
    file is a `ModelUnavailableError` that names it: the figure is then not made, never drawn
    without its photographs."""
    p = path(photo)
    if not p.is_file():
        raise ModelUnavailableError(
            f"the photograph {p.name} of Fig. 7 is missing from this installation ({p}): "
            "reinstall gazehdr (its package data ships server/figures/data/*.exr), or make it "
            "again from Debian's blender-data: apt-get install blender-data && python -m "
            f"gazehdr.figures.photos {BLENDER_WORLDS} {p.parent}"
        )
    try:
        return np.asarray(read_exr(p).rgb, np.float32)
    except SceneError as e:
        raise ModelUnavailableError(f"the photograph {p.name} of Fig. 7 is unreadable: {e}") from e


def radiance(photo: Photo, width: int, height: int) -> tuple[np.ndarray, float]:
    """The view fitted to the frame in cd/m^2, its brightest pixel at 10^peak_log, and the
    factor applied to the file's values."""
    rgb = fit_to_frame(np.maximum(load(photo), 0.0), width, height)
    peak = float((rgb @ LUMA).max())
    if not peak > 0:
        raise ModelUnavailableError(f"the photograph {photo.key}.exr of Fig. 7 is black")
    factor = 10.0**photo.peak_log / peak
    return (rgb * np.float32(factor)).astype(np.float32), factor


def view(pano: np.ndarray, photo: Photo, size: tuple[int, int] = VIEW_SIZE) -> np.ndarray:
    """A pinhole view of an equirectangular panorama (row 0 the zenith, column 0 longitude
    -180°): SUPERSAMPLE² bilinear samples per pixel, averaged."""
    H, W = pano.shape[:2]
    w, h = size[0] * SUPERSAMPLE, size[1] * SUPERSAMPLE
    f = (w / 2) / math.tan(math.radians(photo.hfov) / 2)
    xc, yc = np.meshgrid(np.arange(w) + 0.5 - w / 2, h / 2 - (np.arange(h) + 0.5))
    p = math.radians(photo.pitch)
    up, ahead = yc * math.cos(p) + f * math.sin(p), f * math.cos(p) - yc * math.sin(p)
    lon = math.radians(photo.yaw) + np.arctan2(xc, ahead)
    lat = np.arctan2(up, np.hypot(xc, ahead))
    px = ((np.degrees(lon) + 180) / 360 * W - 0.5) % W
    py = np.clip((90 - np.degrees(lat)) / 180 * H - 0.5, 0, H - 1)
    x0, y0 = np.floor(px).astype(int), np.floor(py).astype(int)
    fx, fy = (px - x0)[..., None], (py - y0)[..., None]
    x1, y1 = (x0 + 1) % W, np.minimum(y0 + 1, H - 1)
    top = pano[y0, x0] * (1 - fx) + pano[y0, x1] * fx
    bottom = pano[y1, x0] * (1 - fx) + pano[y1, x1] * fx
    sampled = (top * (1 - fy) + bottom * fy).reshape(size[1], SUPERSAMPLE, size[0], SUPERSAMPLE, 3)
    return sampled.mean(axis=(1, 3)).astype(np.float32)


def make_views(source: Path, out: Path) -> list[Path]:
    """Cut every photograph's view from the panoramas in `source` into `out`/<key>.exr (half
    floats, ZIP; negative values, the panoramas' noise floor, clipped to 0)."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for photo in PHOTOS:
        pano = np.maximum(np.asarray(read_exr(source / photo.source).rgb, np.float64), 0.0)
        target = out / f"{photo.key}.exr"
        write_exr(target, view(pano, photo), half=True, compression="zip")
        written.append(target)
    return written


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2:
        sys.stderr.write(f"usage: python -m gazehdr.figures.photos [{BLENDER_WORLDS}] OUT_DIR\n")
        return 2
    for p in make_views(Path(args[0]), Path(args[1])):
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
