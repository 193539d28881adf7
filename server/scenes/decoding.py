"""What every image reader shares: its result, its error, the pixel cap, and colour spaces.

Each reader (`exr`, `hdr`) turns one file into a `Decoded`: linear Rec.709 RGB as stored (not
yet in cd/m^2: `gazehdr.scenes.image` applies the scale), plus what the header said. Anything
unusable is a `SceneError` naming the file and the fault, and the pixel count is checked
against the cap from the header alone, before any pixel data is allocated.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gazehdr.drivers.errors import InputError

#: Largest image accepted by default: 64 Mi pixels (8192 × 8192), 768 MiB as float32 RGB.
MAX_PIXELS = 64 * 1024 * 1024
#: Rec.709 / sRGB primaries and D65 white: xy of R, G, B, white (as OpenEXR writes them).
REC709 = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
_BRADFORD = np.array(
    [[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]]
)


class SceneError(InputError):
    """A scene file that cannot be used; the message names the file and what is wrong."""


@dataclass(frozen=True)
class Decoded:
    """One image as a reader found it."""

    rgb: np.ndarray  # H×W×3 float32, linear Rec.709, unscaled
    format: str  # "exr", "hdr" or "pfm"
    #: cd/m^2 of RGB = (1, 1, 1) when the file says so (EXR `whiteLuminance`), else None.
    white_luminance: float | None = None
    layers: tuple[str, ...] = ("",)  # the file's RGB (or Y) layers; "" is the unnamed one
    layer: str = ""
    notes: tuple[str, ...] = ()  # what was done to the values on the way (header facts)
    #: The file's width and height when `rgb` is a reduced level of it (`gazehdr.scenes.level`);
    #: None: `rgb` is the file's size.
    size: tuple[int, int] | None = None
    #: The estimate's statistic over the file's pixels (`estimate.median_log10_luminance`),
    #: when it was taken before `rgb` was reduced; None: taken from `rgb` when needed.
    median_log10: float | None = None

    @property
    def file_size(self) -> tuple[int, int]:
        """The file's width and height (not the level's)."""
        return self.size or (self.rgb.shape[1], self.rgb.shape[0])


def check_size(path: Path, width: int, height: int, total: int, max_pixels: int) -> None:
    """Refuse an image before allocating it: empty, or more than `max_pixels` in all."""
    if width <= 0 or height <= 0:
        raise SceneError(f"{path}: empty image {width}×{height}")
    if total > max_pixels:
        raise SceneError(
            f"{path}: image of {width}×{height} ({total:,} pixels) is larger than the "
            f"limit of {max_pixels:,} pixels"
        )


def read_head(path: Path, size: int) -> bytes:
    """The first `size` bytes of `path` (fewer if shorter), with plain errors."""
    try:
        with path.open("rb") as f:
            return f.read(size)
    except FileNotFoundError:
        raise SceneError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise SceneError(f"{path}: is a directory, not an image") from None
    except OSError as e:
        raise SceneError(f"{path}: cannot read: {e.strerror or e}") from None


def rgb_to_xyz(primaries: tuple[float, ...]) -> np.ndarray:
    """The RGB→XYZ matrix of primaries (xy of R, G, B, white), white → Y = 1."""
    xy = np.asarray(primaries, dtype=np.float64).reshape(4, 2)
    xyz = np.column_stack([xy[:, 0] / xy[:, 1], np.ones(4), (1 - xy.sum(axis=1)) / xy[:, 1]])
    m = xyz[:3].T
    return m * np.linalg.solve(m, xyz[3])


def to_rec709(primaries: tuple[float, ...]) -> np.ndarray:
    """File RGB → Rec.709 RGB, with a Bradford adaptation of the file's white to D65."""
    src, dst = rgb_to_xyz(primaries), rgb_to_xyz(REC709)
    lms_src, lms_dst = _BRADFORD @ src.sum(axis=1), _BRADFORD @ dst.sum(axis=1)
    adapt = np.linalg.solve(_BRADFORD, np.diag(lms_dst / lms_src) @ _BRADFORD)
    return np.linalg.solve(dst, adapt @ src)


def check_primaries(path: Path, primaries: object) -> tuple[float, ...]:
    """Chromaticities as 8 floats, refused when they define no RGB space."""
    try:
        values = tuple(float(c) for c in primaries)  # type: ignore[union-attr]
        with np.errstate(all="ignore"):
            usable = len(values) == 8 and np.isfinite(to_rec709(values)).all()
    except (TypeError, ValueError, np.linalg.LinAlgError):
        usable = False
    if not usable:
        raise SceneError(f"{path}: invalid chromaticities {primaries!r}")
    return values


def into_rec709(rgb: np.ndarray, primaries: tuple[float, ...]) -> np.ndarray:
    """`rgb` in `primaries` as Rec.709 (unchanged when they are Rec.709 already)."""
    if np.allclose(primaries, REC709, atol=1e-4):
        return rgb
    return (rgb @ to_rec709(primaries).T.astype(np.float32)).astype(np.float32, copy=False)
