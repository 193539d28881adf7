"""OpenEXR: reading a file's radiance (any part and layer), and writing float frames.

Layers. A file may hold several parts (multi-part) and, in each, several layers (channels
named `LAYER.R`, `LAYER.G`, ...). A layer is usable when it has `R`, `G`, `B`, else luminance
`Y` (with `RY`/`BY` chroma when both are present: OpenEXR's luminance/chroma encoding, chroma
upsampled linearly, no saturation fix-up), else nothing. Layers are named `LAYER` (the
unnamed one is ""), prefixed `PART/` in a multi-part file; without a choice the first part's
unnamed layer is read, else the first usable one. `A` and any other channel are ignored.
HALF and FLOAT are read; UINT is refused (it holds ids, not radiance). The image is the part's
data window; the display window is ignored.

Scale. The standard `whiteLuminance` attribute (cd/m^2 of RGB = 1, 1, 1) is reported; the
scene applies it (`gazehdr.scenes.image`).

Colour. A `chromaticities` attribute other than Rec.709 is honoured: pixels go through XYZ
into linear Rec.709 with a Bradford adaptation from the file's white to D65, so neutrals stay
neutral (ACES AP0 files, for instance, come out right).

Bad files. Anything unreadable raises `SceneError` naming the file and the fault: missing,
empty, not an EXR, corrupted or truncated header or pixels, a channel name that is not UTF-8
(shown as escaped bytes), no usable channels, an unknown layer, too large. An attribute we read
(`whiteLuminance`, `chromaticities`, a part's `name`) of a type the library does not know is
ignored with a note, refused, or replaced by `partN`. The pixel count (all parts, as the library
reads them all) is checked against `max_pixels` from the header alone, before any pixel data is
allocated.

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

from gazehdr.drivers.errors import InputError
from gazehdr.scenes.decoding import (
    MAX_PIXELS,
    REC709,
    Decoded,
    SceneError,
    check_primaries,
    check_size,
    into_rec709,
    read_head,
    rgb_to_xyz,
)

MAGIC = b"\x76\x2f\x31\x01"
_HALF_MAX = float(np.finfo(np.float16).max)


@dataclass(frozen=True)
class _Layer:
    name: str  # as the user picks it: "LAYER" or "PART/LAYER"
    part: int
    prefix: str  # channel name prefix, "" or "LAYER."
    channels: tuple[str, ...]  # R, G, B or Y[, RY, BY], without the prefix


def read_exr(path: Path, layer: str | None = None, *, max_pixels: int = MAX_PIXELS) -> Decoded:
    """The radiance of `layer` (default: see the module docstring), unscaled."""
    _check_magic(path)
    headers = _read_headers(path)
    total = sum(_box_area(h.get("dataWindow")) for h in headers)
    layers = _layers(headers)
    chosen = _choose(path, headers, layers, layer)
    header = headers[chosen.part]
    width, height = _data_size(path, header)
    check_size(path, width, height, total, max_pixels)
    white, notes = _white_luminance(path, header if "whiteLuminance" in header else headers[0])
    rgb = _read_rgb(path, header, chosen, width, height)
    return Decoded(rgb, "exr", white, tuple(l.name for l in layers), chosen.name, notes)


def write_exr(
    path: str | os.PathLike[str],
    rgb: np.ndarray,
    *,
    half: bool = False,
    compression: OpenEXR.Compression | str = OpenEXR.ZIP_COMPRESSION,
    white_luminance: float | None = None,
) -> None:
    """Write an H×W×3 linear RGB image as a scanline EXR, replacing `path` atomically.

    `half` stores 16-bit floats (finite values above 65504 are refused rather than turned into
    Inf). `compression` is an `OpenEXR.Compression` or its name ("zip", "piz", "none", ...).
    `white_luminance` (cd/m^2 per unit) is stored as the standard attribute, so a reader
    knows the values' absolute scale.
    """
    path = Path(path)
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise InputError(f"{path}: expected an H×W×3 image, got shape {rgb.shape}")
    if half:
        finite = np.abs(rgb[np.isfinite(rgb)])
        if finite.size and finite.max() > _HALF_MAX:
            raise InputError(
                f"{path}: values up to {finite.max():.4g} do not fit in half floats "
                f"(max {_HALF_MAX:g}); write float or scale the image down"
            )
    pixels = np.ascontiguousarray(rgb, dtype=np.float16 if half else np.float32)
    header = {"compression": _compression(compression), "type": OpenEXR.scanlineimage}
    if white_luminance is not None:
        header["whiteLuminance"] = float(white_luminance)
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
        raise InputError(f"unknown EXR compression {c!r}; one of {names.replace('no,', 'none,')}")
    return members[key]


def _check_magic(path: Path) -> None:
    """Fail early, with a plain message, on what is not an EXR file at all."""
    magic = read_head(path, len(MAGIC))
    if not magic:
        raise SceneError(f"{path}: empty file, not an EXR image")
    if magic != MAGIC:
        raise SceneError(f"{path}: not an OpenEXR file (bad magic number)")


def _read_headers(path: Path) -> list[dict]:
    """Every part's header, without reading pixels."""
    try:
        f = OpenEXR.File(str(path), header_only=True)
        headers = [part.header for part in f.parts]
    except Exception as e:
        raise SceneError(f"{path}: corrupted or truncated EXR header ({e})") from None
    if not headers:
        raise SceneError(f"{path}: EXR file has no image parts")
    for header in headers:
        for channel in header.get("channels", []):
            try:
                channel.name  # noqa: B018 - the bindings decode the name (UTF-8) when asked
            except UnicodeDecodeError:
                raise SceneError(f"{path}: {_bad_channel_name(path)}") from None
    return headers


_CHLIST = b"channels\x00chlist\x00"


def _bad_channel_name(path: Path) -> str:
    """What is wrong with a channel name that is not UTF-8, the name shown as escaped bytes.

    OpenEXR's bindings cannot hand such a name to Python, so it is read from the file's
    channel lists (`channels`, type `chlist`: each entry a NUL-terminated name and 16 bytes of
    pixel type, linearity and sampling; a NUL ends the list)."""
    data = read_head(path, 1 << 20)
    start = data.find(_CHLIST)
    while start >= 0:
        pos = start + len(_CHLIST) + 4  # after the attribute's size
        while 0 <= pos < len(data) and data[pos] != 0:
            end = data.find(b"\x00", pos)
            name = data[pos : end if end >= 0 else len(data)]
            try:
                name.decode("utf-8")
            except UnicodeDecodeError as e:
                return f"EXR channel name {name!r} is not UTF-8 text ({e.reason} at byte {e.start})"
            pos = end + 1 + 16 if end >= 0 else -1
        start = data.find(_CHLIST, start + 1)
    return "an EXR channel name is not UTF-8 text"


def _layers(headers: list[dict]) -> list[_Layer]:
    """The usable layers of every part, in file order, each part's unnamed layer first."""
    found = []
    for i, header in enumerate(headers):
        names = [c.name for c in header.get("channels", [])]
        prefixes = sorted({n.rpartition(".")[0] for n in names}, key=lambda p: (p != "", p))
        name = header.get("name")
        part = (name if isinstance(name, str) and name else f"part{i}") if len(headers) > 1 else ""
        for prefix in prefixes:
            dot = f"{prefix}." if prefix else ""
            own = {n.removeprefix(dot) for n in names if n.rpartition(".")[0] == prefix}
            if {"R", "G", "B"} <= own:
                channels: tuple[str, ...] = ("R", "G", "B")
            elif "Y" in own:
                channels = ("Y", "RY", "BY") if {"RY", "BY"} <= own else ("Y",)
            else:
                continue
            name = "/".join(n for n in (part, prefix) if n) if part else prefix
            found.append(_Layer(name, i, dot, channels))
    return found


def _choose(path: Path, headers: list[dict], layers: list[_Layer], layer: str | None) -> _Layer:
    if not layers:
        names = sorted({c.name for h in headers for c in h.get("channels", [])})
        found = ", ".join(names) or "none"
        raise SceneError(f"{path}: no usable channels (need R, G, B or Y; found {found})")
    if layer is None:
        return layers[0]
    for candidate in layers:
        if candidate.name == layer:
            return candidate
    names = ", ".join(repr(l.name) for l in layers)
    raise SceneError(f"{path}: no layer {layer!r}; the file has {names}")


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
    return int(x1) - int(x0) + 1, int(y1) - int(y0) + 1


def _white_luminance(path: Path, header: dict) -> tuple[float | None, tuple[str, ...]]:
    """The header's whiteLuminance, or None with a note when it is absent or unusable."""
    white = header.get("whiteLuminance")
    if white is None:
        return None, ()
    if not isinstance(white, (int, float)):  # an attribute of another type: its repr may fail
        return None, (f"whiteLuminance ignored: a {type(white).__name__}, not a number",)
    if not (math.isfinite(white) and white > 0):
        return None, (f"whiteLuminance {white!r} ignored: not a positive number",)
    return float(white), ()


def _read_rgb(path: Path, header: dict, layer: _Layer, width: int, height: int) -> np.ndarray:
    """Linear Rec.709 RGB of `layer`, unscaled, as float32 H×W×3."""
    sampling = {c.name: (c.ySampling, c.xSampling) for c in header.get("channels", [])}
    wanted = [layer.prefix + c for c in layer.channels]
    # On a decoding failure the library prints a warning and returns a file with no parts: keep
    # the warning off stdout and put it in the error instead.
    warning = io.StringIO()
    try:
        with contextlib.redirect_stdout(warning):
            channels = OpenEXR.File(str(path), separate_channels=True).channels(layer.part)
        planes = {n: channels[n].pixels for n in wanted}
    except Exception as e:
        reason = warning.getvalue().strip().removeprefix("Warning: ") or str(e)
        raise SceneError(f"{path}: corrupted or truncated EXR pixel data ({reason})") from None
    for n, p in planes.items():
        steps = sampling[n]
        shape = (-(-height // max(steps[0], 1)), -(-width // max(steps[1], 1)))
        if min(steps) < 1 or not isinstance(p, np.ndarray) or p.shape != shape:
            raise SceneError(f"{path}: corrupted or truncated EXR pixel data (channel {n})")
        if p.dtype.kind != "f":
            raise SceneError(f"{path}: channel {n} holds {p.dtype} values, not HALF or FLOAT")
    chromaticities = header.get("chromaticities", REC709)
    if isinstance(chromaticities, OpenEXR.OpaqueAttribute):  # a type OpenEXR does not know
        raise SceneError(f"{path}: the chromaticities attribute is not of type chromaticities")
    primaries = check_primaries(path, chromaticities)
    if layer.channels == ("R", "G", "B") and all(sampling[n] == (1, 1) for n in wanted):
        # Straight into the one float32 array (the same values as converting each plane
        # first): a 64 Mi-pixel image costs 768 MiB here, not twice that.
        rgb = np.empty((height, width, 3), np.float32)
        for i, n in enumerate(wanted):
            rgb[..., i] = planes[n]
        return into_rec709(rgb, primaries)
    full = {
        n.removeprefix(layer.prefix): _upsample(p.astype(np.float32), sampling[n], (height, width))
        for n, p in planes.items()
    }
    if "R" in full:
        rgb = np.stack([full["R"], full["G"], full["B"]], axis=-1)
    elif "RY" in full:
        # OpenEXR's luminance/chroma encoding: RY = (R - Y)/Y, BY = (B - Y)/Y.
        yw = rgb_to_xyz(primaries)[1]
        y = full["Y"]
        r = (full["RY"] + 1) * y
        b = (full["BY"] + 1) * y
        rgb = np.stack([r, (y - r * yw[0] - b * yw[2]) / yw[1], b], axis=-1)
    else:
        return np.repeat(full["Y"][..., None], 3, axis=-1)
    return into_rec709(rgb.astype(np.float32, copy=False), primaries)


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
