"""Radiance RGBE (`.hdr`, `.pic`) and PFM files, decoded by OpenCV.

OpenCV (`opencv-python-headless`, Apache-2.0) does the pixel work: RGBE's run-length coding
and PFM's byte orders. Its RGBE reader takes only the standard `-Y H +X W` orientation and
ignores the header's meaning, so the header is read here, from at most `MAX_HEADER` bytes
and before any pixel data is allocated:

- the resolution line in any of the eight orientations (`+Y` rows go bottom to top, `-X`
  columns right to left, `+X W -Y H` stores columns as scanlines): OpenCV decodes the
  scanlines as given and the array is flipped and transposed here;
- `EXPOSURE=` and `COLORCORR=` (the values were multiplied by them: they are divided out),
  `PRIMARIES=` (converted to Rec.709, white adapted to D65), `FORMAT=32-bit_rle_xyze` (CIE
  XYZ, converted to Rec.709).

Radiance's own unit is W/sr/m² (179 lm/W gives cd/m²), but most `.hdr` files (photographs,
HDRIs) are not calibrated: their scale is estimated (`gazehdr.scenes.estimate`) unless the user
gives one. PFM: `PF` (RGB) or `Pf` (grey), rows bottom to top, a negative scale meaning
little-endian; the scale's magnitude is not applied (writers put 1 there).
"""

from __future__ import annotations

import contextlib
import math
import re
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

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

MAX_HEADER = 64 * 1024  # bytes of RGBE header (text lines) accepted before the resolution
_RESOLUTION = re.compile(rb"([-+])([XY]) +(\d+) +([-+])([XY]) +(\d+)")
_PFM = re.compile(rb"(P[Ff])\s+(\d+)\s+(\d+)\s+(\S+)\s")


def is_rgbe(head: bytes) -> bool:
    return head.startswith(b"#?")


def is_pfm(head: bytes) -> bool:
    return head[:2] in (b"PF", b"Pf") and head[2:3].isspace()


def read_rgbe(path: Path, *, max_pixels: int = MAX_PIXELS) -> Decoded:
    """Radiance RGBE: see the module docstring."""
    head = read_head(path, MAX_HEADER)
    end = head.find(b"\n\n")
    if not is_rgbe(head) or end < 0:
        what = "no blank line ends the header" if is_rgbe(head) else "no #? signature"
        raise SceneError(f"{path}: not a Radiance RGBE file ({what} in its first 64 KiB)")
    lines = head[:end].decode("latin-1").splitlines()[1:]
    resolution_end = head.find(b"\n", end + 2)
    match = _RESOLUTION.fullmatch(head[end + 2 : resolution_end].strip())
    if resolution_end < 0 or match is None or match[2] == match[5]:
        raise SceneError(f"{path}: RGBE resolution line is missing or malformed")
    sign1, axis1, n1, sign2, _, n2 = match.groups()
    n1, n2 = int(n1), int(n2)
    width, height = (n1, n2) if axis1 == b"X" else (n2, n1)
    check_size(path, width, height, width * height, max_pixels)
    fields = dict(_header_fields(path, lines))
    # Flat scanlines are 4 bytes a pixel, run-length ones at most 4 + 129/128 of that.
    budget = resolution_end + 1 + n1 * (8 + math.ceil(n2 * 4 * 129 / 128))
    data = read_head(path, budget)[resolution_end + 1 :]
    standard = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (n1, n2)
    scan = _decode(path, standard + data, "RGBE")
    if scan.ndim != 3 or scan.shape != (n1, n2, 3):
        raise SceneError(f"{path}: corrupted or truncated RGBE pixel data")
    scan = scan[..., ::-1]  # OpenCV's BGR
    # scan[i, j]: scanline i along the first axis, pixel j along the second.
    if sign1 == (b"+" if axis1 == b"Y" else b"-"):
        scan = scan[::-1]
    if sign2 == (b"-" if axis1 == b"Y" else b"+"):
        scan = scan[:, ::-1]
    rgb = np.ascontiguousarray(scan.transpose(1, 0, 2) if axis1 == b"X" else scan)
    return _meaning(path, rgb, fields)


def _header_fields(path: Path, lines: list[str]) -> Iterator[tuple[str, object]]:
    """The header lines that change the values' meaning, checked."""
    exposure, correction = 1.0, np.ones(3)
    for line in lines:
        key, _, value = line.partition("=")
        key = key.strip().upper()
        try:
            if key == "FORMAT":
                if value.strip() not in ("32-bit_rle_rgbe", "32-bit_rle_xyze"):
                    raise SceneError(f"{path}: RGBE FORMAT {value.strip()!r} is not supported")
                yield "xyz", value.strip().endswith("xyze")
            elif key == "EXPOSURE":
                exposure *= float(value)
            elif key == "COLORCORR":
                correction *= np.array([float(v) for v in value.split()], np.float64)
            elif key == "PRIMARIES":
                yield "primaries", check_primaries(path, value.split())
        except ValueError as e:  # float() of garbage, or COLORCORR with a wrong count
            if isinstance(e, SceneError):
                raise
            raise SceneError(f"{path}: RGBE header line {line!r} is malformed") from None
    if not (math.isfinite(exposure) and exposure > 0):
        raise SceneError(f"{path}: RGBE EXPOSURE must be positive, got {exposure:g}")
    if not (np.isfinite(correction).all() and (correction > 0).all()):
        raise SceneError(f"{path}: RGBE COLORCORR must be three positive numbers")
    yield "divide", exposure * correction


def _meaning(path: Path, rgb: np.ndarray, fields: dict) -> Decoded:
    notes = []
    divide = fields["divide"]
    if not np.allclose(divide, 1.0):
        rgb = rgb / divide.astype(np.float32)
        notes.append(f"EXPOSURE/COLORCORR {', '.join(f'{d:g}' for d in divide)} divided out")
    if fields.get("xyz"):
        rgb = rgb @ np.linalg.inv(rgb_to_xyz(REC709)).T.astype(np.float32)
        notes.append("XYZE converted to Rec.709")
    elif "primaries" in fields:
        rgb = into_rec709(rgb, fields["primaries"])
        notes.append("PRIMARIES converted to Rec.709")
    return Decoded(rgb.astype(np.float32, copy=False), "hdr", notes=tuple(notes))


def read_pfm(path: Path, *, max_pixels: int = MAX_PIXELS) -> Decoded:
    """Portable float map: see the module docstring."""
    head = read_head(path, 256)
    match = _PFM.match(head)
    if match is None:
        raise SceneError(f"{path}: not a PFM file (need 'PF' or 'Pf', width, height, scale)")
    kind, width, height, scale = match[1], int(match[2]), int(match[3]), match[4]
    try:
        usable = math.isfinite(float(scale)) and float(scale) != 0
    except ValueError:
        usable = False
    if not usable:
        raise SceneError(f"{path}: PFM scale {scale.decode('latin-1')!r} is not a non-zero number")
    check_size(path, width, height, width * height, max_pixels)
    channels = 3 if kind == b"PF" else 1
    size = match.end() + width * height * channels * 4
    data = read_head(path, size)
    if len(data) < size:
        raise SceneError(
            f"{path}: truncated PFM pixel data ({len(data) - match.end()} of "
            f"{size - match.end()} bytes)"
        )
    image = _decode(path, data, "PFM")
    # Grey to RGB; OpenCV's BGR to RGB.
    image = np.repeat(image[..., None], 3, axis=-1) if image.ndim == 2 else image[..., ::-1]
    if image.shape != (height, width, 3):
        raise SceneError(f"{path}: corrupted PFM pixel data")
    return Decoded(np.ascontiguousarray(image, np.float32), "pfm")


def _decode(path: Path, data: bytes, what: str) -> np.ndarray:
    """OpenCV's decoding of `data`; its failures (logged, not raised) become a SceneError."""
    with _opencv_quiet():
        try:
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error as e:
            raise SceneError(f"{path}: corrupted {what} pixel data ({e.err})") from None
    if image is None or image.dtype != np.float32:
        raise SceneError(f"{path}: corrupted or truncated {what} pixel data")
    return image


@contextlib.contextmanager
def _opencv_quiet() -> Iterator[None]:
    """OpenCV logs a bad file to stderr and returns None: the error says it instead."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(level)
