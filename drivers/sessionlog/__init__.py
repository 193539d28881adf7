"""The native session log: JSON Lines, append-only, readable after a crash up to the last line.

Line 1 is a header (tracker, screen geometry, clock); then one record per line: gaze samples,
fixation and blink events, scene, parameter and model changes, resets, notes, clock updates.
Import everything from here (`from gazehdr.drivers.sessionlog import SessionLogWriter`); the
modules, in the order a record goes through them:

- `records`: the records in memory (frozen dataclasses), the header, `FormatError`.
- `codec`: a record ↔ its JSON object, with errors that name the field; its docstring is the
  file format.
- `writer`: `SessionLogWriter`, one flushed line per record; `write_session_log`.
- `reader`: `SessionLogReader`, which stops cleanly at a line cut by a crash;
  `read_session_log`, `read_session_track`.
- `log`: `SessionLog`, a whole log in memory, and its gaze tracks.
- `track`: `SessionTrack`, a log replayed as a `GazeTrack`; `fixation_places` and, for
  fixations their events do not place, `detected_fixations` and `places_at_samples`.
"""

from gazehdr.drivers.sessionlog.codec import decode_header, decode_record, encode_record
from gazehdr.drivers.sessionlog.log import SessionLog
from gazehdr.drivers.sessionlog.reader import (
    SessionLogReader,
    read_session_log,
    read_session_track,
)
from gazehdr.drivers.sessionlog.records import (
    EVENT_KINDS,
    FORMAT,
    READS,
    VERSION,
    ClockInfo,
    ClockUpdate,
    EyeReset,
    FormatError,
    GazeEvent,
    ModelChange,
    Note,
    ParamsChange,
    Record,
    SceneChange,
    SessionHeader,
)
from gazehdr.drivers.sessionlog.track import (
    FixationPlace,
    SessionTrack,
    detected_fixations,
    fixation_places,
    places_at_samples,
)
from gazehdr.drivers.sessionlog.writer import SessionLogWriter, write_session_log

__all__ = [
    "EVENT_KINDS",
    "FORMAT",
    "READS",
    "VERSION",
    "ClockInfo",
    "ClockUpdate",
    "EyeReset",
    "FixationPlace",
    "FormatError",
    "GazeEvent",
    "ModelChange",
    "Note",
    "ParamsChange",
    "Record",
    "SceneChange",
    "SessionHeader",
    "SessionLog",
    "SessionLogReader",
    "SessionLogWriter",
    "SessionTrack",
    "decode_header",
    "decode_record",
    "detected_fixations",
    "encode_record",
    "fixation_places",
    "places_at_samples",
    "read_session_log",
    "read_session_track",
    "write_session_log",
]
