"""What gazehdr publishes on LSL: a gaze stream and a marker stream, for LabRecorder to record
beside EEG.

- the gaze stream (type `Gaze`, double64, `meta.OUTLET_CHANNELS`: ScreenX/ScreenY of the gaze and
  of each eye in pixels, a Confidence of 1 or 0, each eye's pupil Diameter in mm and in the
  tracker's own units (`a.u.`); NaN where there is none) with the XDF gaze meta-data in its
  description, plus `acquisition` (manufacturer gazehdr, the tracker as model, the
  application) and gazehdr's `screen` (size in pixels, diagonal and viewing distance), so that
  its samples read back in screen terms;
- the marker stream (type `Markers`, one string channel, irregular rate), named after the gaze
  stream with " events": every other record as its session log JSON line (fixation and blink
  events; notes; for `serve`, scene, parameter and model changes), its description naming
  the gaze stream's source_id (`gaze_source_id`), so an XDF reader pairs them.

Times: records stamped on this machine's monotonic clock (a live source's) are pushed at the
LSL time they stand for (`clock.ClockLink`); others (a replay's, a session's simulation time)
at the moment they are published.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterable, Mapping
from dataclasses import asdict
from typing import Any

from gazehdr.drivers.lsl import load_pylsl
from gazehdr.drivers.lsl.clock import ClockLink
from gazehdr.drivers.lsl.meta import OUTLET_CHANNELS, marker_text, outlet_values
from gazehdr.drivers.samples import GazeSample, ScreenGeometry

MARKERS_SUFFIX = " events"
LINGER_S = 0.5  # how long closed outlets stay, so that inlets get what was pushed last


class GazeOutlets:
    """The gaze and marker outlets of one tracker (the daemon) or one session (`serve`).

    `name` names the gaze stream, `source_id` identifies it across restarts (LabRecorder and
    inlets find it again by it). `model` describes the gaze's origin, `application` who
    publishes. `rate_hz` is the nominal rate (None: irregular). With `monotonic` the records'
    times are this machine's monotonic ns and are published at the LSL time they stand for;
    otherwise at the time they are pushed.
    """

    def __init__(
        self,
        name: str,
        *,
        source_id: str,
        geometry: ScreenGeometry,
        model: str = "",
        application: str = "gazehdr",
        rate_hz: float | None = None,
        monotonic: bool = True,
        extra: Mapping[str, str] | None = None,
    ) -> None:
        self.lsl = load_pylsl()
        lsl = self.lsl
        self.link = ClockLink.measure(lsl.local_clock, time.monotonic_ns) if monotonic else None
        gaze = lsl.StreamInfo(
            name, "Gaze", len(OUTLET_CHANNELS), rate_hz or lsl.IRREGULAR_RATE, "double64",
            source_id,
        )  # fmt: skip
        desc = gaze.desc()
        acquisition = desc.append_child("acquisition")
        for key, value in (("manufacturer", "gazehdr"), ("model", model),
                           ("application", application), *(extra or {}).items()):  # fmt: skip
            acquisition.append_child_value(key, str(value))
        screen = desc.append_child("screen")
        for key, value in asdict(geometry).items():
            screen.append_child_value(key, repr(value))
        channels = desc.append_child("channels")
        for channel in OUTLET_CHANNELS:
            element = channels.append_child("channel")
            for key, value in channel.items():
                element.append_child_value(key, value)
        markers = lsl.StreamInfo(
            name + MARKERS_SUFFIX, "Markers", 1, lsl.IRREGULAR_RATE, "string",
            source_id + MARKERS_SUFFIX.replace(" ", ":"),
        )  # fmt: skip
        markers.desc().append_child_value("gaze_source_id", source_id)
        markers.desc().append_child_value("format", "gazehdr session log JSON, one per marker")
        self.gaze = lsl.StreamOutlet(gaze)
        self.markers = lsl.StreamOutlet(markers)
        self.published = [0, 0]  # samples, markers

    def _stamp(self, t_ns: int) -> float:
        return self.link.to_lsl(t_ns) if self.link is not None else self.lsl.local_clock()

    def push(self, record: Any) -> None:
        """Publish one record: a sample on the gaze stream, anything else a session log holds
        on the marker stream (records that are neither are not published)."""
        if isinstance(record, GazeSample):
            self.gaze.push_sample(outlet_values(record), self._stamp(record.t_ns))
            self.published[0] += 1
            return
        try:
            text = marker_text(record)
        except TypeError:
            return
        self.markers.push_sample([text], self._stamp(int(record.t_ns)))
        self.published[1] += 1

    def push_all(self, records: Iterable[Any]) -> None:
        for record in records:
            self.push(record)

    def close(self, *, wait: bool = False) -> None:
        """Withdraw both streams (inlets see them lost; LabRecorder stops recording them),
        `LINGER_S` from now: liblsl has no flush, and destroying an outlet at once can lose
        what was pushed last. `wait`: wait for that here (a process about to exit), else in
        a timer thread (a server's session ending on its event loop)."""
        outlets, self.gaze, self.markers = (self.gaze, self.markers), None, None
        if wait:
            time.sleep(LINGER_S)
            return
        threading.Timer(LINGER_S, outlets.__len__).start()  # holds them until it fires


def default_source_id(application: str, name: str) -> str:
    """A source_id that stays the same when the same thing is published again on this host."""
    return f"gazehdr:{application}:{name}@{socket.gethostname()}"


def session_outlets(name: str, session_id: str, geometry: ScreenGeometry) -> GazeOutlets:
    """The outlets of one `gazehdr serve --lsl-outlet NAME` session: the gaze it follows (its
    journal, at the time each step publishes it), one source_id per session."""
    return GazeOutlets(
        name,
        source_id=default_source_id("serve", f"{name}:{session_id}"),
        geometry=geometry,
        model=f"session {session_id}",
        application="gazehdr serve",
        monotonic=False,
        extra={"session": session_id},
    )
