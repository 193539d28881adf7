"""Writing a log: append-only, so that a crash loses at most the line being written.

One JSON object per line (`codec`), UTF-8, `\\n`-terminated. The writer writes each record with
one `write` and flushes it at once (and `os.fsync`s every `fsync_every` records if asked, and
always on close).
"""

from __future__ import annotations

import errno
import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.sessionlog.codec import encode_record
from gazehdr.drivers.sessionlog.log import SessionLog
from gazehdr.drivers.sessionlog.records import (
    ClockUpdate,
    Note,
    ParamsChange,
    SceneChange,
    SessionHeader,
)


def _dumps(obj: dict[str, Any]) -> str:
    return json.dumps(obj, ensure_ascii=False, separators=(",", ":"), allow_nan=False)


class SessionLogWriter:
    """Appends records to a new log, one flushed line each; a context manager.

    Refuses to replace an existing file unless `overwrite=True`. `fsync_every=N` also forces
    the data to disk every N records (a flush alone survives a crash of this process, not of
    the machine); `close()` always fsyncs. Sample times must not go back.
    """

    def __init__(
        self,
        path: str | Path,
        header: SessionHeader,
        *,
        overwrite: bool = False,
        fsync_every: int | None = None,
    ) -> None:
        if fsync_every is not None and fsync_every < 1:
            raise InputError(f"fsync_every must be a positive number of records, got {fsync_every}")
        self.path = Path(path)
        self.header = header
        self.fsync_every = fsync_every
        self.records_written = 0
        self._last_sample_ns: int | None = None
        try:
            self._file = open(  # noqa: SIM115 - closed by close()
                self.path, "w" if overwrite else "x", encoding="utf-8", newline="\n"
            )
        except FileExistsError:
            raise FileExistsError(
                errno.EEXIST,
                "session log already exists (choose another name, or overwrite it on purpose)",
                str(self.path),
            ) from None
        self._line(header.to_json())
        self._sync()

    def __enter__(self) -> SessionLogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        return self._file.closed

    def _line(self, obj: dict[str, Any]) -> None:
        self._file.write(_dumps(obj) + "\n")
        self._file.flush()

    def _sync(self) -> None:
        os.fsync(self._file.fileno())

    def write(self, record: Any) -> None:
        """Append one record (a `GazeSample`, an event, `SceneChange`, `ParamsChange`, ...)."""
        if self._file.closed:
            raise InputError(f"{self.path}: session log is closed")
        obj = encode_record(record)
        if obj["k"] == "s":
            if self._last_sample_ns is not None and obj["t"] < self._last_sample_ns:
                raise InputError(
                    f"{self.path}: sample time {obj['t']} goes back from {self._last_sample_ns}"
                )
            self._last_sample_ns = obj["t"]
        self._line(obj)
        self.records_written += 1
        if self.fsync_every and self.records_written % self.fsync_every == 0:
            self._sync()

    def write_all(self, records: Iterable[Any]) -> None:
        for record in records:
            self.write(record)

    def scene(self, t_ns: int, name: str) -> None:
        self.write(SceneChange(t_ns, name))

    def params(self, t_ns: int, values: dict[str, Any]) -> None:
        self.write(ParamsChange(t_ns, values))

    def note(self, t_ns: int, text: str) -> None:
        self.write(Note(t_ns, text))

    def clock(self, t_ns: int, offset_ns: int | None, uncertainty_ns: int | None = None) -> None:
        self.write(ClockUpdate(t_ns, offset_ns, uncertainty_ns))

    def close(self) -> None:
        if self._file.closed:
            return
        try:
            self._file.flush()
            self._sync()
        finally:
            self._file.close()


def write_session_log(path: str | Path, log: SessionLog, *, overwrite: bool = False) -> Path:
    """Write a log held in memory (an import, say), its records in time order."""
    with SessionLogWriter(path, log.header, overwrite=overwrite) as writer:
        writer.write_all(log.records())
    return Path(path)
