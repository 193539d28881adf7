"""LabRecorder's XDF files → a session log: one gaze stream and the markers beside it.

Written from the XDF specification (sccn/xdf wiki, "Specifications"): the magic `XDF:`, then
chunks of `[NumLengthBytes: 1, 4 or 8][Length][Tag: uint16][Content]`, little-endian. Tags: 1
FileHeader (XML), 2 StreamHeader (uint32 StreamId, then the stream's `<info>` XML), 3 Samples
(StreamId, a varlen sample count, then per sample a time stamp flag byte (0: deduced, 8: a
double follows) and the values: each numeric value in its `channel_format`, each string a
varlen length and its bytes), 4 ClockOffset (StreamId, collection time, offset: doubles), 5
Boundary, 6 StreamFooter (StreamId, XML).

`check_structure` walks the chunks first, reading lengths, tags, headers and the samples'
layout: what is not XDF (a wrong magic, a length of another size, an unknown tag, samples of a
stream without a header, more samples than the chunk can hold, samples that do not fill their
chunk exactly, an `<info>` without a channel count or format) is refused with the byte where it
is wrong, before pyxdf allocates anything from such numbers. (pyxdf reads a Samples chunk
sample by sample and does not seek to its end: samples that end elsewhere, or that it cannot
read, make it take what follows for chunks, after scanning forward to a Boundary chunk's
signature, where a sample count of billions can be.) A
file cut short (LabRecorder stopped by a crash) is read as far as it goes, and says so in a
note. pyxdf then reads it with the recorded clock offsets applied (`synchronize_clocks`, clock
resets handled) and no dejittering: a tracker's own time stamps are kept. What pyxdf warns of
becomes a note too.

The gaze stream is one whose type is a gaze type (`lsl.meta.GAZE_TYPES`, any case) or whose
channels carry the conventional ScreenX and ScreenY; its channels are read as the `lsl` source
reads them (`gazehdr.drivers.lsl.meta`). With several, `stream` names the one to import (by
name or source_id); otherwise they are listed. Markers: the marker stream gazehdr publishes
beside a gaze stream (`gaze_source_id` in its description) gives back its events, notes and
changes; any other string stream's markers become notes `NAME: TEXT`. Times are the recording
machine's LSL seconds → integer ns; a sample time that goes back (after a clock correction) is
held at the last one, and counted in a note. The screen is the one gazehdr's own outlet
records in its description, else `geometry` (default `ScreenGeometry()`).
"""

from __future__ import annotations

import io
import logging
import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, BinaryIO
from xml.etree import ElementTree

import numpy as np

from gazehdr.drivers.lsl.meta import (
    GAZE_TYPES,
    MIN_CONFIDENCE,
    ChannelLayout,
    LayoutError,
    StreamDescription,
    channel_layout,
    marker_record,
)
from gazehdr.drivers.samples import ScreenGeometry
from gazehdr.drivers.sessionlog import ClockInfo, FormatError, Note, SessionHeader, SessionLog

MAGIC = b"XDF:"
TAGS = {1: "FileHeader", 2: "StreamHeader", 3: "Samples", 4: "ClockOffset", 5: "Boundary",
        6: "StreamFooter"}  # fmt: skip
VALUE_BYTES = {"int8": 1, "int16": 2, "int32": 4, "int64": 8, "float32": 4, "double64": 8}
_GAZE_TYPES = {t.lower() for t in GAZE_TYPES}


@dataclass(frozen=True)
class _Stream:
    channels: int
    value_bytes: int  # 0: strings (each value at least a 2-byte varlen length)


def _varlen(f: BinaryIO, what: str, path: Path, at: int) -> int | None:
    """A varlen integer (its byte count, 1, 4 or 8, then the value); None at the end."""
    head = f.read(1)
    if not head:
        return None
    size = head[0]
    if size not in (1, 4, 8):
        raise FormatError(path, None, what, f"byte {at}: a length of {size} bytes (1, 4 or 8)")
    raw = f.read(size)
    if len(raw) < size:
        return None
    return int.from_bytes(raw, "little")


def _stream_header(xml: bytes, path: Path, at: int) -> _Stream:
    try:
        root = ElementTree.fromstring(xml.decode("utf-8", "replace"))
    except ElementTree.ParseError as e:
        raise FormatError(path, None, "StreamHeader", f"byte {at}: not XML ({e})") from None
    try:
        channels = int((root.findtext("channel_count") or "").strip())
    except ValueError:
        channels = 0
    fmt = (root.findtext("channel_format") or "").strip()
    if root.tag != "info" or not 0 < channels <= 1 << 16 or fmt not in (*VALUE_BYTES, "string"):
        raise FormatError(
            path, None, "StreamHeader",
            f"byte {at}: an <info> with a channel_count and a channel_format is required, got "
            f"<{root.tag}>, channel_count {root.findtext('channel_count')!r}, format {fmt!r}",
        )  # fmt: skip
    return _Stream(channels, VALUE_BYTES.get(fmt, 0))


def check_structure(path: Path) -> list[str]:
    """Walk the chunks (see the module docstring); FormatError for what is not XDF, and the
    notes on what pyxdf will have to skip (a file cut short)."""
    return _walk(path)[0]


def _walk(path: Path) -> tuple[list[str], int]:
    """`check_structure`'s notes, and where the whole chunks end (pyxdf reads no further)."""
    streams: dict[int, _Stream] = {}
    size = path.stat().st_size
    with path.open("rb") as f:
        if f.read(4) != MAGIC:
            raise FormatError(path, None, None, "not an XDF file: it does not begin with 'XDF:'")
        n = 0
        while True:
            at = f.tell()
            length = _varlen(f, "chunk", path, at)
            if length is None:
                return [], at
            n += 1
            start = f.tell()
            if start + length > size:
                note = f"cut short: chunk {n} at byte {at} runs past the end; read up to it"
                # A cut header stays in: pyxdf's XML parser then says the file is truncated.
                header = f.read(2) in (b"\x01\x00", b"\x02\x00")
                return [note], size if header else at
            raw = f.read(2)
            tag = int.from_bytes(raw, "little") if len(raw) == 2 else -1
            if length < 2 or tag not in TAGS:
                raise FormatError(path, None, "chunk", f"byte {at}: chunk {n} has tag {tag}")
            if tag in (2, 3, 4, 6):
                _stream_chunk(f, tag, length - 2, streams, path, at)
            f.seek(start + length)


def _stream_chunk(
    f: BinaryIO, tag: int, content: int, streams: dict[int, _Stream], path: Path, at: int
) -> None:
    """Check one chunk that belongs to a stream (the file is at its StreamId)."""
    what = TAGS[tag]
    if content < 4:
        raise FormatError(path, None, what, f"byte {at}: no room for a StreamId")
    (sid,) = struct.unpack("<I", f.read(4))
    if tag == 2:
        if sid in streams:
            raise FormatError(path, None, what, f"byte {at}: a second header for stream {sid}")
        streams[sid] = _stream_header(f.read(content - 4), path, at)
        return
    if sid not in streams:
        raise FormatError(path, None, what, f"byte {at}: stream {sid} has no StreamHeader")
    if tag == 4 and content != 20:
        raise FormatError(path, None, what, f"byte {at}: {content} bytes, 20 expected")
    if tag == 3:
        before = f.tell()
        count = _varlen(f, what, path, at) or 0
        room = content - 4 - (f.tell() - before)
        s = streams[sid]
        least = 1 + s.channels * (s.value_bytes or 2)
        if count * least > room:
            raise FormatError(
                path, None, what,
                f"byte {at}: {count} samples of stream {sid} cannot fit in {room} bytes",
            )  # fmt: skip
        wrong = _samples_layout(f.read(room), count, s)
        if wrong:
            raise FormatError(path, None, what, f"byte {at}: stream {sid}: {wrong}")


def _samples_layout(data: bytes, count: int, stream: _Stream) -> str | None:
    """What is wrong with `count` samples laid out in `data` (a Samples chunk after its
    count) as pyxdf reads them, or None when they fill it exactly: per sample a time stamp
    flag byte (not 0: a double follows), then each value, a string as a varlen length and
    its bytes."""
    pos, end = 0, len(data)
    fixed = stream.channels * stream.value_bytes
    for k in range(count):
        if pos >= end:
            return f"sample {k + 1} of {count} starts past the chunk's end"
        pos += 9 if data[pos] else 1
        if fixed:
            pos += fixed
            continue
        for _ in range(stream.channels):
            size = data[pos] if pos < end else 1
            if size not in (1, 4, 8):
                return f"sample {k + 1}: a string length of {size} bytes (1, 4 or 8)"
            pos += 1 + size + int.from_bytes(data[pos + 1 : pos + 1 + size], "little")
            if pos > end:
                return f"sample {k + 1} of {count} runs past the chunk's end"
    if pos != end:
        how = "past" if pos > end else f"{end - pos} bytes before"
        return f"its {count} samples end {how} the chunk's end"
    return None


class _Warnings(logging.Handler):
    """pyxdf's warnings while it reads, kept for the log's notes."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.texts: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.texts.append(record.getMessage().splitlines()[0])


class _Upto(io.RawIOBase):
    """The file up to byte `end`, for pyxdf: a chunk cut short is never handed to it (it would
    allocate for all the samples the chunk's count claims, then drop the chunk: a count of
    10^8 in a few bytes made it allocate gigabytes)."""

    def __init__(self, path: Path, end: int) -> None:
        super().__init__()
        self._f = open(path, "rb")  # noqa: SIM115 - closed by close()
        self._end = end

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        data = self._f.read(max(0, min(len(buffer), self._end - self._f.tell())))
        buffer[: len(data)] = data
        return len(data)

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        if whence == io.SEEK_END:
            return self._f.seek(self._end + offset)
        return self._f.seek(offset, whence)

    def tell(self) -> int:
        return self._f.tell()

    def close(self) -> None:
        self._f.close()
        super().close()


def _load(path: Path, end: int) -> tuple[list[dict[str, Any]], list[str]]:
    try:
        import pyxdf
    except ModuleNotFoundError as e:
        raise ModuleNotFoundError(
            "reading XDF needs pyxdf: install gazehdr[xdf]", name=e.name
        ) from None
    logger = logging.getLogger("pyxdf")
    handler = _Warnings()
    logger.addHandler(handler)
    try:
        whole = io.BufferedReader(_Upto(path, end))
        streams, _ = pyxdf.load_xdf(whole, synchronize_clocks=True, dejitter_timestamps=False)
    except ElementTree.ParseError as e:  # the XML of the file header or a stream header
        raise FormatError(
            path,
            None,
            None,
            f"truncated, or malformed XML in its file header or a stream header ({e}): pyxdf "
            "cannot read it",
        ) from None
    except struct.error as e:  # a chunk shorter than its length says
        raise FormatError(
            path, None, None, f"truncated: it ends inside a chunk ({e}): pyxdf cannot read it"
        ) from None
    except Exception as e:  # pyxdf raises what its parsing meets: report it as the file's fault
        raise FormatError(path, None, None, f"pyxdf cannot read it: {e}") from None
    finally:
        logger.removeHandler(handler)
    return streams, [f"pyxdf: {text}" for text in handler.texts]


def _is_gaze(stream: StreamDescription) -> bool:
    typed = {(c.get("type") or c.get("metatype") or "").lower() for c in stream.channels}
    return stream.type.lower() in _GAZE_TYPES or {"screenx", "screeny"} <= typed


def _pick(
    streams: list[dict[str, Any]], wanted: str | None, path: Path
) -> tuple[dict[str, Any], ChannelLayout]:
    """The gaze stream to import, with its layout; FormatError listing the choices."""
    found: list[tuple[dict[str, Any], ChannelLayout]] = []
    unusable: list[str] = []
    described: list[str] = []
    for s in streams:
        try:
            desc = StreamDescription.of(s.get("info"))
        except LayoutError as e:
            unusable.append(str(e))
            continue
        described.append(desc.title())
        if not _is_gaze(desc):
            continue
        try:
            found.append((s, channel_layout(desc)))
        except LayoutError as e:
            unusable.append(str(e))
    if wanted is not None:
        named = [g for g in found if wanted in (g[1].stream.name, g[1].stream.source_id)]
        if len(named) == 1:
            return named[0]
        names = ", ".join(g[1].stream.title() for g in found) or "none"
        how = "no" if not named else "more than one"
        raise FormatError(path, None, None, f"{how} gaze stream named {wanted!r}; found {names}")
    if len(found) == 1:
        return found[0]
    if found:
        names = "; ".join(g[1].stream.title() for g in found)
        raise FormatError(
            path, None, None, f"several gaze streams: {names}; choose one with --stream NAME"
        )
    why = "; ".join(unusable) if unusable else f"its streams: {', '.join(described) or 'none'}"
    raise FormatError(path, None, None, f"no gaze stream to import ({why})")


def _screen(desc: StreamDescription, geometry: ScreenGeometry | None) -> ScreenGeometry:
    """The screen gazehdr's outlet recorded (`<screen>`), else `geometry`, else the defaults."""
    try:
        values = {f.name: float(desc.desc_text("screen", f.name)) for f in fields(ScreenGeometry)}
        width, height = values.pop("screen_width_px"), values.pop("screen_height_px")
        return ScreenGeometry(**values, screen_width_px=int(width), screen_height_px=int(height))
    except (ValueError, OverflowError):  # none recorded, or not numbers
        return geometry or ScreenGeometry()


def _times(stamps: Any) -> Iterator[tuple[int, int]]:
    """(index, ns) of each finite stamp, in order."""
    for i, stamp in enumerate(np.asarray(stamps, dtype=float)):
        if math.isfinite(stamp):
            yield i, round(float(stamp) * 1e9)


def read_xdf(
    path: Path,
    *,
    geometry: ScreenGeometry | None = None,
    stream: str | None = None,
    min_confidence: float = MIN_CONFIDENCE,
) -> SessionLog:
    """Read an XDF file's gaze stream (`stream`: its name or source_id, when there are
    several) and the markers beside it."""
    path = Path(path)
    notes, end = _walk(path)
    streams, warnings = _load(path, end)
    chosen, layout = _pick(streams, stream, path)
    desc = layout.stream
    screen = _screen(desc, geometry)
    log = SessionLog(_header(path, layout, screen), path=path)
    held = 0
    values = chosen["time_series"]
    for i, t in _times(chosen["time_stamps"]):
        if log.samples and t < log.samples[-1].t_ns:
            held += 1
            t = log.samples[-1].t_ns
        try:
            log.samples.append(layout.sample(values[i], t, screen, min_confidence))
        except (LayoutError, TypeError, ValueError) as e:
            raise FormatError(path, None, desc.name, f"sample {i}: {e}") from None
    if not log.samples:
        raise FormatError(path, None, desc.name, "the gaze stream holds no samples")
    first = log.samples[0].t_ns
    for text in [*notes, *warnings] + ([f"{held} sample times went back"] if held else []):
        log.add(Note(first, text))
    for s in streams:
        _markers(s, desc, log, path)
    log.events.sort(key=lambda e: e.t_ns)
    log.notes.sort(key=lambda e: e.t_ns)
    return log


def _markers(s: dict[str, Any], gaze: StreamDescription, log: SessionLog, path: Path) -> None:
    """A string stream's markers: gazehdr's own beside `gaze` as records, others as notes."""
    try:
        desc = StreamDescription.of(s.get("info"))
    except LayoutError:
        return
    if desc.channel_format != "string":
        return
    owner = desc.desc_text("gaze_source_id")
    if owner and owner != gaze.source_id:
        return  # another gaze stream's events
    for i, t in _times(s["time_stamps"]):
        texts = s["time_series"][i]
        text = str(texts[0]) if len(texts) else ""
        if owner:
            log.add(marker_record(text, t, path, i + 1))
        else:
            log.add(Note(t, f"{desc.name}: {text}"))


def _header(path: Path, layout: ChannelLayout, screen: ScreenGeometry) -> SessionHeader:
    desc = layout.stream
    tracker: dict[str, Any] = {
        "format": "xdf",
        "file": path.name,
        "stream": desc.name,
        "type": desc.type,
        "source_id": desc.source_id,
        "hostname": desc.hostname,
        "channels": layout.describe(),
        **{k: v for k, v in desc.acquisition().items() if v},
    }
    if desc.nominal_srate:
        tracker["rate_hz"] = desc.nominal_srate
    clock = ClockInfo("LSL local_clock of the recording machine (XDF, clock offsets applied)")
    return SessionHeader(tracker=tracker, screen=screen, clock=clock)
