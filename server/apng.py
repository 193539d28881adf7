"""Animated PNG, written one frame at a time.

`gazehdr render --video` assembles its dithered frames into one lossless file that browsers
play. Lossless matters: the dither's per-frame noise is what carries the extra bits, and a lossy
codec would smooth it away. Pillow can write APNG too, but it holds every frame in memory until
the end; this writer streams, so a long 1080p render costs one frame of memory.

Format: the APNG specification (https://wiki.mozilla.org/APNG_Specification): PNG signature,
IHDR, acTL, then per frame an fcTL and the frame's zlib stream (IDAT for the first frame, which
is also the still image shown by viewers without APNG, fdAT after), IEND.
"""

from __future__ import annotations

import io
import struct
import zlib
from fractions import Fraction
from pathlib import Path
from types import TracebackType

import numpy as np
from PIL import Image

from gazehdr.drivers.errors import InputError

SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _chunks(png: bytes):
    """(kind, data) of every chunk of a PNG file."""
    pos = len(SIGNATURE)
    while pos < len(png):
        (length,) = struct.unpack_from(">I", png, pos)
        yield png[pos + 4 : pos + 8], png[pos + 8 : pos + 8 + length]
        pos += 12 + length


class ApngWriter:
    """Write `frames` H×W×3 uint8 frames shown at `fps` (looping forever) to `path`."""

    def __init__(self, path: str | Path, frames: int, fps: float, compress_level: int = 6):
        if frames < 1:
            raise InputError("an animation needs at least one frame")
        delay = Fraction(1.0 / fps).limit_denominator(65535)
        if not 0 < delay.numerator <= 65535:
            raise InputError(f"fps {fps} gives a frame delay APNG cannot store")
        self.delay = (delay.numerator, delay.denominator)
        self.frames, self.written, self.seq = frames, 0, 0
        self.compress_level = compress_level
        self.size: tuple[int, int] | None = None
        self._f = open(path, "wb")  # noqa: SIM115 (closed in close(), the writer streams)

    def add(self, rgb: np.ndarray) -> None:
        if self.written >= self.frames:
            raise InputError(f"all {self.frames} frames are written already")
        h, w = rgb.shape[:2]
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format="PNG", compress_level=self.compress_level)
        chunks = list(_chunks(buf.getvalue()))
        if self.size is None:
            self.size = (w, h)
            ihdr = next(data for kind, data in chunks if kind == b"IHDR")
            self._f.write(SIGNATURE + _chunk(b"IHDR", ihdr))
            self._f.write(_chunk(b"acTL", struct.pack(">II", self.frames, 0)))  # 0: loop
        elif self.size != (w, h):
            raise InputError(f"frame {self.written} is {w}x{h}, the animation {self.size}")
        fctl = struct.pack(">IIIIIHHBB", self.seq, w, h, 0, 0, *self.delay, 0, 0)
        self._f.write(_chunk(b"fcTL", fctl))
        self.seq += 1
        data = b"".join(data for kind, data in chunks if kind == b"IDAT")
        if self.written == 0:
            self._f.write(_chunk(b"IDAT", data))
        else:
            self._f.write(_chunk(b"fdAT", struct.pack(">I", self.seq) + data))
            self.seq += 1
        self.written += 1

    def close(self) -> None:
        if self._f.closed:
            return
        if self.written == self.frames:
            self._f.write(_chunk(b"IEND", b""))
        self._f.close()
        if self.written != self.frames:
            raise InputError(f"animation closed after {self.written} of {self.frames} frames")

    def __enter__(self) -> ApngWriter:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if kind is None:
            self.close()
        else:
            self._f.close()  # the error that stopped us matters more than the short count
