"""OpenEXR scenes: loading radiance in absolute units, and writing float frames.

Scale. Pixel values are multiplied by one scene scale to give cd/m^2, chosen in this order:

1. an explicit ``scale`` argument, when given (it overrides the file, so a user can correct a
   wrong header);
2. the file's standard ``whiteLuminance`` attribute (the luminance of RGB = 1, 1, 1);
3. ``DEFAULT_SCALE`` = 1.0: pixel values are taken to be cd/m^2 already.

Channels. Of the first part: ``R``, ``G``, ``B`` (``A`` and any other channel or layer is
ignored); else luminance ``Y``, with ``RY``/``BY`` chroma when both are present (OpenEXR's
luminance/chroma encoding, subsampled chroma upsampled linearly, no saturation fix-up), else grey.
HALF and FLOAT are read; UINT is refused (it holds ids, not radiance). The image is the data
window; the display window is ignored.

Colour. A ``chromaticities`` attribute other than Rec.709 is honoured: pixels go through XYZ
into linear Rec.709 with a Bradford adaptation from the file's white to D65, so neutrals stay
neutral (ACES AP0 files, for instance, come out right).

Bad files. Anything unreadable raises ``SceneError`` naming the file and the fault: missing,
empty, not an EXR, corrupted or truncated header or pixels, no usable channels, too large. The
pixel count (all parts, as the library reads them all) is checked against ``max_pixels`` from the
header alone, before any pixel data is allocated.

NaN and Inf in a file are passed through unchanged: the simulator sanitises its input.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenEXR

#: Scene scale when neither the caller nor the file gives one: pixel values are cd/m^2.
DEFAULT_SCALE = 1.0
#: Largest image accepted by default: 64 Mi pixels (8192 × 8192), 768 MiB as float32 RGB.
MAX_PIXELS = 64 * 1024 * 1024

_MAGIC = b"\x76\x2f\x31\x01"
#: Rec.709 / sRGB primaries and D65 white as OpenEXR writes them: xy of R, G, B, white.
_REC709 = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
_BRADFORD = np.array(
    [[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]]
)
_HALF_MAX = float(np.finfo(np.float16).max)


class SceneError(ValueError):
    """A scene file that cannot be used; the message names the file and what is wrong."""


@dataclass(eq=False)
class ExrScene:
    """A static scene from an EXR file, in cd/m^2 (`scale` is the factor that was applied)."""

    name: str
    pixels: np.ndarray
    scale: float = DEFAULT_SCALE
    animated: bool = False

    @classmethod
    def open(
        cls,
        path: str | os.PathLike[str],
        scale: float | None = None,
        *,
        max_pixels: int = MAX_PIXELS,
    ) -> ExrScene:
        """Load `path` (see the module docstring for the scale order and what is accepted)."""
        path = Path(path)
        if scale is not None and not (math.isfinite(scale) and scale > 0):
            raise SceneError(f"{path}: scale must be a positive finite number, got {scale!r}")
        _check_magic(path)
        header, total_pixels = _read_header(path)
        width, height = _data_size(path, header)
        if total_pixels > max_pixels:
            raise SceneError(
                f"{path}: image of {width}×{height} ({total_pixels:,} pixels) is larger than the "
                f"limit of {max_pixels:,} pixels"
            )
        if scale is None:
            scale = _file_scale(path, header)
        rgb = _read_rgb(path, header, width, height)
        rgb *= np.float32(scale)
        return cls(name=path.stem, pixels=np.ascontiguousarray(rgb), scale=float(scale))

    def render(self, t: float, width: int, height: int) -> np.ndarray:
        """The loaded pixels whatever `t`, `width`, `height`: the simulator fits them. The same
        array every call, not a copy: copy it before modifying it."""
        return self.pixels

    def state_at(self, t: float) -> object:
        return None

    def next_change(self, t: float) -> float | None:
        return None


def write_exr(
    path: str | os.PathLike[str],
    rgb: np.ndarray,
    *,
    half: bool = False,
    compression: OpenEXR.Compression | str = OpenEXR.ZIP_COMPRESSION,
) -> None:
    """Write an H×W×3 linear RGB image as a scanline EXR, replacing `path` atomically.

    `half` stores 16-bit floats (finite values above 65504 are refused rather than turned into
    Inf). `compression` is an `OpenEXR.Compression` or its name ("zip", "piz", "none", ...).
    """
    path = Path(path)
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise ValueError(f"{path}: expected an H×W×3 image, got shape {rgb.shape}")
    if half:
        finite = np.abs(rgb[np.isfinite(rgb)])
        if finite.size and finite.max() > _HALF_MAX:
            raise ValueError(
                f"{path}: values up to {finite.max():.4g} do not fit in half floats "
                f"(max {_HALF_MAX:g}); write float or scale the image down"
            )
    pixels = np.ascontiguousarray(rgb, dtype=np.float16 if half else np.float32)
    header = {"compression": _compression(compression), "type": OpenEXR.scanlineimage}
    # A unique name beside the target (so the rename is atomic), created by the library so
    # that the file gets the usual permissions.
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    try:
        OpenEXR.File(header, {"RGB": pixels}).write(str(tmp))
        os.replace(tmp, path)
    except Exception as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise OSError(f"{path}: cannot write EXR: {e}") from e


def _compression(c: OpenEXR.Compression | str) -> OpenEXR.Compression:
    if not isinstance(c, str):
        return c
    key = c.upper()
    key = "NO_COMPRESSION" if key == "NONE" else key.removesuffix("_COMPRESSION") + "_COMPRESSION"
    members = {
        k: v for k, v in OpenEXR.Compression.__members__.items() if k.endswith("_COMPRESSION")
    }
    if key not in members:
        names = ", ".join(m.removesuffix("_COMPRESSION").lower() for m in members)
        raise ValueError(f"unknown EXR compression {c!r}; one of {names.replace('no,', 'none,')}")
    return members[key]


def _check_magic(path: Path) -> None:
    """Fail early, with a plain message, on what is not an EXR file at all."""
    try:
        with path.open("rb") as f:
            magic = f.read(len(_MAGIC))
    except FileNotFoundError:
        raise SceneError(f"{path}: no such file") from None
    except OSError as e:
        raise SceneError(f"{path}: cannot read: {e.strerror or e}") from None
    if not magic:
        raise SceneError(f"{path}: empty file, not an EXR image")
    if magic != _MAGIC:
        raise SceneError(f"{path}: not an OpenEXR file (bad magic number)")


def _read_header(path: Path) -> tuple[dict, int]:
    """The first part's header and the pixel count of all parts, without reading pixels."""
    try:
        f = OpenEXR.File(str(path), header_only=True)
        headers = [part.header for part in f.parts]
    except Exception as e:
        raise SceneError(f"{path}: corrupted or truncated EXR header ({e})") from None
    if not headers:
        raise SceneError(f"{path}: EXR file has no image parts")
    total = sum(_box_area(h.get("dataWindow")) for h in headers)
    return headers[0], total


def _box_area(window: object) -> int:
    try:
        (x0, y0), (x1, y1) = window  # type: ignore[misc]
    except (TypeError, ValueError):
        return 0
    return max(int(x1) - int(x0) + 1, 0) * max(int(y1) - int(y0) + 1, 0)


def _data_size(path: Path, header: dict) -> tuple[int, int]:
    if header.get("type") in (OpenEXR.deepscanline, OpenEXR.deeptile):
        raise SceneError(f"{path}: deep EXR images are not supported")
    try:
        (x0, y0), (x1, y1) = header["dataWindow"]
    except (KeyError, TypeError, ValueError):
        raise SceneError(f"{path}: EXR header has no valid dataWindow") from None
    width, height = int(x1) - int(x0) + 1, int(y1) - int(y0) + 1
    if width <= 0 or height <= 0:
        raise SceneError(f"{path}: empty data window {width}×{height}")
    return width, height


def _file_scale(path: Path, header: dict) -> float:
    white = header.get("whiteLuminance")
    if white is None:
        return DEFAULT_SCALE
    if not (isinstance(white, (int, float)) and math.isfinite(white) and white > 0):
        raise SceneError(
            f"{path}: whiteLuminance {white!r} is not a positive number; give an explicit scale"
        )
    return float(white)


def _read_rgb(path: Path, header: dict, width: int, height: int) -> np.ndarray:
    """Linear Rec.709 RGB, unscaled, as float32 H×W×3."""
    sampling = {c.name: (c.ySampling, c.xSampling) for c in header.get("channels", [])}
    if {"R", "G", "B"} <= sampling.keys():
        wanted = ["R", "G", "B"]
    elif "Y" in sampling:
        wanted = ["Y", "RY", "BY"] if {"RY", "BY"} <= sampling.keys() else ["Y"]
    else:
        found = ", ".join(sorted(sampling)) or "none"
        raise SceneError(f"{path}: no usable channels (need R, G, B or Y; found {found})")
    # On a decoding failure the library prints a warning and returns a file with no parts: keep
    # the warning off stdout and put it in the error instead.
    warning = io.StringIO()
    try:
        with contextlib.redirect_stdout(warning):
            channels = OpenEXR.File(str(path), separate_channels=True).channels(0)
        planes = {n: channels[n].pixels for n in wanted}
    except Exception as e:
        reason = warning.getvalue().strip().removeprefix("Warning: ") or str(e)
        raise SceneError(f"{path}: corrupted or truncated EXR pixel data ({reason})") from None
    full = {}
    for n, p in planes.items():
        steps = sampling[n]
        shape = (-(-height // max(steps[0], 1)), -(-width // max(steps[1], 1)))
        if min(steps) < 1 or not isinstance(p, np.ndarray) or p.shape != shape:
            raise SceneError(f"{path}: corrupted or truncated EXR pixel data (channel {n})")
        if p.dtype.kind != "f":
            raise SceneError(f"{path}: channel {n} holds {p.dtype} values, not HALF or FLOAT")
        full[n] = _upsample(p.astype(np.float32), steps, (height, width))
    primaries = _primaries(path, header)
    if "R" in full:
        rgb = np.stack([full["R"], full["G"], full["B"]], axis=-1)
    elif "RY" in full:
        # OpenEXR's luminance/chroma encoding: RY = (R - Y)/Y, BY = (B - Y)/Y.
        yw = _rgb_to_xyz(primaries)[1]
        y = full["Y"]
        r = (full["RY"] + 1) * y
        b = (full["BY"] + 1) * y
        rgb = np.stack([r, (y - r * yw[0] - b * yw[2]) / yw[1], b], axis=-1)
    else:
        return np.repeat(full["Y"][..., None], 3, axis=-1)
    if not np.allclose(primaries, _REC709, atol=1e-4):
        rgb = rgb @ _to_rec709(primaries).T.astype(np.float32)
    return rgb.astype(np.float32, copy=False)


def _primaries(path: Path, header: dict) -> tuple[float, ...]:
    """The file's chromaticities (Rec.709 when absent), refused when they define no RGB space."""
    primaries = header.get("chromaticities", _REC709)
    try:
        primaries = tuple(float(c) for c in primaries)
        with np.errstate(all="ignore"):
            usable = len(primaries) == 8 and np.isfinite(_to_rec709(primaries)).all()
    except (TypeError, ValueError, np.linalg.LinAlgError):
        usable = False
    if not usable:
        raise SceneError(f"{path}: invalid chromaticities {primaries!r}")
    return primaries


def _upsample(plane: np.ndarray, steps: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """A subsampled channel at full resolution: samples sit every `step` pixels from the
    origin, joined linearly (held at the far edge)."""
    for axis, (step, n) in enumerate(zip(steps, shape, strict=True)):
        if step == 1:
            continue
        m = plane.shape[axis]
        pos = np.arange(n) / step
        i0 = np.minimum(pos.astype(np.intp), m - 1)
        i1 = np.minimum(i0 + 1, m - 1)
        frac = np.clip(pos - i0, 0, 1).astype(np.float32).reshape((-1, 1) if axis == 0 else (1, -1))
        a0, a1 = np.take(plane, i0, axis=axis), np.take(plane, i1, axis=axis)
        plane = a0 + (a1 - a0) * frac
    return plane


def _rgb_to_xyz(primaries: tuple[float, ...]) -> np.ndarray:
    """The RGB→XYZ matrix of primaries (xy of R, G, B, white), white → Y = 1."""
    xy = np.asarray(primaries, dtype=np.float64).reshape(4, 2)
    xyz = np.column_stack([xy[:, 0] / xy[:, 1], np.ones(4), (1 - xy.sum(axis=1)) / xy[:, 1]])
    m = xyz[:3].T
    return m * np.linalg.solve(m, xyz[3])


def _to_rec709(primaries: tuple[float, ...]) -> np.ndarray:
    """File RGB → Rec.709 RGB, with a Bradford adaptation of the file's white to D65."""
    src, dst = _rgb_to_xyz(primaries), _rgb_to_xyz(_REC709)
    lms_src, lms_dst = _BRADFORD @ src.sum(axis=1), _BRADFORD @ dst.sum(axis=1)
    adapt = np.linalg.solve(_BRADFORD, np.diag(lms_dst / lms_src) @ _BRADFORD)
    return np.linalg.solve(dst, adapt @ src)
