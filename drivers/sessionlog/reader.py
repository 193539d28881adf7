"""Reading a log back, also one cut short by a crash.

The reader reads everything up to the last whole line and says that the file was cut
(`SessionLog.truncated`). A line that is malformed anywhere else is an error naming the file,
the line and the field (`codec`).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import GazeSample
from gazehdr.drivers.sessionlog.codec import decode_header, decode_record
from gazehdr.drivers.sessionlog.log import SessionLog
from gazehdr.drivers.sessionlog.records import FormatError, Record
from gazehdr.drivers.sessionlog.track import SessionTrack


def _reject_constant(name: str) -> float:
    raise InputError(f"{name} is not a number JSON allows")


def _loads(raw: bytes) -> Any:
    """One line's JSON value; ValueError (or UnicodeDecodeError) when it is not JSON."""
    try:
        return json.loads(raw.decode("utf-8"), parse_constant=_reject_constant)
    except RecursionError:  # Python's parser recurses once per level of nesting
        raise InputError("JSON nested too deeply") from None


class SessionLogReader:
    """Streams a log's records in file order (what the live source emitted, in that order).

    `header` is read on opening. Iterating stops cleanly at a final line cut short by a crash
    (no newline, or the NUL bytes a file system may leave after a crash) and sets `truncated`
    and `truncated_line`; a malformed line anywhere else raises `FormatError`.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.truncated = False
        self.truncated_line: int | None = None
        self._file: BinaryIO = open(self.path, "rb")  # noqa: SIM115 - closed by close()
        try:
            raw = self._file.readline()
            if not raw.strip(b"\x00 \t\r\n"):
                raise FormatError(self.path, 1, None, "empty file: no session log header")
            try:
                obj = _loads(raw)
            except (UnicodeDecodeError, ValueError) as e:
                cut = "" if raw.endswith(b"\n") else " (cut short: nothing was recorded)"
                raise FormatError(self.path, 1, None, f"header is not JSON{cut}: {e}") from None
            self.header = decode_header(obj, self.path)
        except BaseException:
            self._file.close()
            raise

    def __enter__(self) -> SessionLogReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._file.close()

    def __iter__(self) -> Iterator[Record]:
        last_sample: int | None = None
        line = 1
        for raw in self._file:
            line += 1
            if not raw.strip(b" \t\r\n"):
                continue
            try:
                obj = _loads(raw)
            except (UnicodeDecodeError, ValueError) as e:
                rest = self._file.read()
                cut = not raw.endswith(b"\n") or b"\x00" in raw
                if cut and not rest.strip(b"\x00 \t\r\n"):
                    self.truncated, self.truncated_line = True, line
                    return
                raise FormatError(self.path, line, None, f"not a JSON record: {e}") from None
            record = decode_record(obj, self.path, line)
            if isinstance(record, GazeSample):
                if last_sample is not None and record.t_ns < last_sample:
                    raise FormatError(
                        self.path,
                        line,
                        "t",
                        f"sample time {record.t_ns} goes back from {last_sample}",
                    )
                last_sample = record.t_ns
            yield record


def read_session_log(path: str | Path) -> SessionLog:
    """Read a whole log; stops cleanly at a cut final line (`truncated` says so)."""
    with SessionLogReader(path) as reader:
        log = SessionLog(reader.header, path=reader.path)
        for record in reader:
            log.add(record)
        log.truncated, log.truncated_line = reader.truncated, reader.truncated_line
    for items in (
        log.events,
        log.scenes,
        log.params,
        log.models,
        log.resets,
        log.notes,
        log.clocks,
    ):
        items.sort(key=lambda r: r.t_ns)
    return log


def read_session_track(path: Path) -> SessionTrack:
    """A session log as a gaze track (`LOG.jsonl` in `gazehdr.drivers.registry`): the log's
    fixations, as a live session replaying it follows them."""
    return read_session_log(path).fixation_track()
