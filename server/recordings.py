"""Recorded sessions a live session can replay as its gaze, kept in `DATA_DIR/recordings/`.

A recording is a native session log (`drivers/sessionlog/`); it becomes the gaze source
`replay:NAME` of any session, looping. The session follows the recording's fixations (detected
with I-VT when the log has none), never the samples of a saccade.
Uploads are checked by reading them whole before they are moved into place; the server's own
recordings of its sessions (`gazehdr serve --record`) are written here as they happen.
"""

from __future__ import annotations

import math
import os
import uuid
from pathlib import Path

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.sessionlog import (
    SessionHeader,
    SessionLogWriter,
    SessionTrack,
    read_session_log,
)
from gazehdr.gaze import TrackerFigures
from gazehdr.scenes.library import check_name

MAX_UPLOAD_BYTES = 64 * 1024 * 1024


class RecordingLibrary:
    def __init__(self, data_dir: Path | None) -> None:
        self.folder = data_dir / "recordings" if data_dir else None

    def names(self) -> list[str]:
        return sorted(p.stem for p in self.folder.glob("*.jsonl")) if self.folder else []

    def track(self, name: str) -> SessionTrack:
        return self.replay(name)[0]

    def replay(self, name: str) -> tuple[SessionTrack, TrackerFigures]:
        """The recording's fixations as a track, and the figures of the tracker that recorded
        it as its header gives them (`tracker.accuracy_deg`, `tracker.rate_hz`; None where it
        does not: the replay is then exact, gazehdr.gaze.TrackGaze)."""
        path = self._path(name)
        if not path.is_file():
            raise InputError(f"no recording named {name!r}; available: {', '.join(self.names())}")
        log = read_session_log(path)
        tracker = log.header.tracker
        return log.fixation_track(), TrackerFigures(
            _figure(tracker.get("accuracy_deg"), 0.0), _figure(tracker.get("rate_hz"), 1e-9)
        )

    def store(self, name: str, chunks: list[bytes]) -> Path:
        """Validate an uploaded session log and move it into place; nothing is kept if bad."""
        path = self._path(name)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".upload-{uuid.uuid4().hex}.jsonl")
        try:
            tmp.write_bytes(b"".join(chunks))
            try:
                log = read_session_log(tmp)
                log.track()  # a log without samples cannot drive a gaze
            except ValueError as e:
                raise InputError(str(e).replace(str(tmp), f"upload {name!r}")) from None
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        return path

    def create(self, name: str, header: SessionHeader) -> SessionLogWriter:
        """A new log `name` to write as a session runs (never replacing one)."""
        path = self._path(name)
        path.parent.mkdir(parents=True, exist_ok=True)
        return SessionLogWriter(path, header)

    def _path(self, name: str) -> Path:
        if self.folder is None:
            raise InputError("this server has no data directory for recordings")
        return self.folder / f"{check_name(name)}.jsonl"


def _figure(value: object, least: float) -> float | None:
    """A figure from a log header: a finite number of at least `least`, else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) and value >= least else None
