"""XDF files written as the specification says (sccn/xdf wiki, "Specifications"), for tests:
what LabRecorder writes for the streams a test recorded (`Recorder`s: each stream's header XML
as liblsl gives it, its samples with their time stamps, its clock offsets), and the pieces to
build malformed files from. gazehdr itself writes no XDF."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

CODES = {"int8": "b", "int16": "h", "int32": "i", "int64": "q", "float32": "f", "double64": "d"}
FILE_HEADER = b'<?xml version="1.0"?><info><version>1.0</version></info>'
BOUNDARY = bytes.fromhex("43A546DCCBF5410FB30ED5467383CBE4")


def varlen(n: int) -> bytes:
    """A varlen integer: its byte count (1, 4 or 8), then the value, little-endian."""
    if n < 1 << 8:
        return b"\x01" + n.to_bytes(1, "little")
    if n < 1 << 32:
        return b"\x04" + n.to_bytes(4, "little")
    return b"\x08" + n.to_bytes(8, "little")


def chunk(tag: int, content: bytes) -> bytes:
    return varlen(len(content) + 2) + struct.pack("<H", tag) + content


def samples_chunk(sid: int, fmt: str, rows: Sequence[Sequence[Any]], stamps: Sequence[float]):
    """A Samples chunk, every sample with its time stamp (as LabRecorder writes them)."""
    body = bytearray(struct.pack("<I", sid) + varlen(len(rows)))
    for row, stamp in zip(rows, stamps, strict=True):
        body += b"\x08" + struct.pack("<d", stamp)
        if fmt == "string":
            for value in row:
                raw = str(value).encode()
                body += varlen(len(raw)) + raw
        else:
            body += struct.pack(f"<{len(row)}{CODES[fmt]}", *row)
    return chunk(3, bytes(body))


@dataclass
class Stream:
    """One recorded stream: its `<info>` XML, samples, stamps and (time, offset) pairs."""

    header: str
    rows: list[Any]
    stamps: list[float]
    offsets: list[tuple[float, float]] = field(default_factory=list)

    @classmethod
    def of(cls, recorder: Any) -> Stream:
        return cls(recorder.header, recorder.rows, recorder.stamps, recorder.offsets)

    @property
    def fmt(self) -> str:
        return ElementTree.fromstring(self.header).findtext("channel_format") or "float32"


def xdf_bytes(streams: Sequence[Stream], per_chunk: int = 1 << 20) -> bytes:
    """A whole file: header, stream headers, samples (`per_chunk` to a Samples chunk), clock
    offsets, a boundary, footers."""
    out = bytearray(b"XDF:" + chunk(1, FILE_HEADER))
    for sid, s in enumerate(streams, 1):
        out += chunk(2, struct.pack("<I", sid) + s.header.encode())
    for sid, s in enumerate(streams, 1):
        for i in range(0, len(s.rows), per_chunk):
            rows, stamps = s.rows[i : i + per_chunk], s.stamps[i : i + per_chunk]
            out += samples_chunk(sid, s.fmt, rows, stamps)
        for t, offset in s.offsets:
            out += chunk(4, struct.pack("<Idd", sid, t, offset))
    out += chunk(5, BOUNDARY)
    for sid, s in enumerate(streams, 1):
        first, last = (s.stamps[0], s.stamps[-1]) if s.stamps else (0.0, 0.0)
        footer = (
            f"<?xml version='1.0'?><info><first_timestamp>{first}</first_timestamp>"
            f"<last_timestamp>{last}</last_timestamp><sample_count>{len(s.rows)}"
            "</sample_count></info>"
        )
        out += chunk(6, struct.pack("<I", sid) + footer.encode())
    return bytes(out)


def write_xdf(path: Path, streams: Sequence[Stream]) -> Path:
    path.write_bytes(xdf_bytes(streams))
    return path
