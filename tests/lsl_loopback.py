"""Real liblsl on loopback for the tests, and the stream layouts of real trackers' LSL apps.

Importing this sets `LSLAPICFG` to tests/data/lsl_api.cfg (unless set already) before liblsl
reads its configuration (at its first use in the process, and in every daemon the tests start):
streams are resolved on this machine only, nothing is sent to a multicast group or broadcast.
Under pytest-xdist each worker gets a copy with a SessionID of its own: liblsl shows a resolver
only the streams of its session, so tests running side by side never find each other's.

The layouts are those the apps publish (read in their sources: labstreaminglayer/App-TobiiPro
`mainwindow.cpp`, App-EyeLink `eyelink.py`, App-PupilLabs `channel.py`, Gazepoint's
`LSLGazepoint.py`), built here with real `pylsl.StreamInfo`s.
"""

from __future__ import annotations

import gc
import os
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


def _config() -> str:
    """tests/data/lsl_api.cfg, or under an xdist worker its copy in the session of that worker
    of this run (PYTEST_XDIST_TESTRUNUID, PYTEST_XDIST_WORKER)."""
    shared = Path(__file__).parent / "data" / "lsl_api.cfg"
    worker, run = os.environ.get("PYTEST_XDIST_WORKER"), os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if not (worker and run):
        return str(shared)
    own = Path(tempfile.gettempdir()) / f"gazehdr-lsl-{run}-{worker}.cfg"
    text = shared.read_text().replace("[lab]\n", f"[lab]\nSessionID = gazehdr-{run}-{worker}\n")
    assert "SessionID" in text, "tests/data/lsl_api.cfg has no [lab] section"
    own.write_text(text)
    return str(own)


os.environ.setdefault("LSLAPICFG", _config())

import pylsl  # noqa: E402 (liblsl reads LSLAPICFG when it loads)

Channel = tuple[str, str, str, str]  # label, eye, type, unit ("" where the app gives none)

TOBII: list[Channel] = [
    ("left_x", "left", "ScreenX", "screencoords"),
    ("left_y", "left", "ScreenY", "screencoords"),
    ("left_pupil", "left", "pupilsize", ""),
    ("right_x", "right", "ScreenX", "screencoords"),
    ("right_y", "right", "ScreenY", "screencoords"),
    ("right_pupil", "right", "pupilsize", ""),
]
EYELINK: list[Channel] = [
    (label, "", "eyetracking", "")
    for label in (
        "leftEyeX", "leftEyeY", "rightEyeX", "rightEyeY", "leftPupilArea", "rightPupilArea",
        "pixelsPerDegreeX", "pixelsPerDegreeY", "eyelink_timestamp", "LSL_timestamp",
    )
]  # fmt: skip
PUPIL_CAPTURE: list[Channel] = [
    ("confidence", "both", "Confidence", "normalized"),
    ("norm_pos_x", "both", "ScreenX", "normalized"),
    ("norm_pos_y", "both", "ScreenY", "normalized"),
    ("diameter0_2d", "right", "Diameter", "pixels"),
    ("diameter1_2d", "left", "Diameter", "pixels"),
    ("diameter0_3d", "right", "Diameter", "mm"),
    ("diameter1_3d", "left", "Diameter", "mm"),
]
GAZEPOINT: list[Channel] = [
    (label, "", kind, unit)
    for label, kind, unit in (
        ("FPOGX", "gaze", "percent"), ("FPOGY", "gaze", "percent"), ("FPOGV", "gaze", "boolean"),
        ("LPOGX", "gaze", "percent"), ("LPOGY", "gaze", "percent"), ("LPOGV", "gaze", "boolean"),
        ("RPOGX", "gaze", "percent"), ("RPOGY", "gaze", "percent"), ("RPOGV", "gaze", "boolean"),
        ("BPOGX", "gaze", "percent"), ("BPOGY", "gaze", "percent"), ("BPOGV", "gaze", "boolean"),
        ("LPD", "diameter", "float"), ("LPMM", "diameter", "float"), ("LPMMV", "pupil", "boolean"),
        ("RPD", "diameter", "float"), ("RPMM", "diameter", "float"), ("RPMMV", "pupil", "boolean"),
    )
]  # fmt: skip


def stream_info(
    name: str,
    kind: str,
    channels: list[Channel],
    *,
    rate: float = 0.0,
    fmt: str = "float32",
    source_id: str = "",
    metatype: bool = False,
) -> pylsl.StreamInfo:
    """A StreamInfo with a `<channels>` description; `metatype` writes the type as Pupil
    Invisible's relay does."""
    info = pylsl.StreamInfo(name, kind, len(channels), rate, fmt, source_id)
    listed = info.desc().append_child("channels")
    for label, eye, ctype, unit in channels:
        c = listed.append_child("channel")
        for key, value in (("label", label), ("eye", eye), ("type", ctype), ("unit", unit)):
            if value:
                c.append_child_value("metatype" if key == "type" and metatype else key, value)
    return info


def until(predicate: Callable[[], Any], timeout: float = 10.0, what: str = "condition") -> Any:
    """Poll `predicate` until it is truthy (returned) or `timeout` passes (AssertionError)."""
    deadline = time.monotonic() + timeout
    while not (value := predicate()):
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)
    return value


def inlet_for(predicate: str, timeout: float = 10.0) -> pylsl.StreamInlet:
    """An open inlet on the one stream `predicate` finds (as LabRecorder would record it)."""
    # 1.5 s: on this machine a second stream answers the unicast wave, sent after 0.5 s
    (found,) = until(lambda: pylsl.resolve_bypred(predicate, 1, 1.5), timeout, predicate)
    inlet = pylsl.StreamInlet(found, max_buflen=360, recover=False)
    inlet.open_stream(timeout)
    return inlet


class Recorder:
    """Records one stream as LabRecorder does, in a thread: its full header XML, every sample
    with its time stamp, and clock offsets (`time_correction`) with the times they were taken,
    until the stream is lost or `stop()` is called."""

    def __init__(self, predicate: str) -> None:
        self.inlet = inlet_for(predicate)
        self.header = self.inlet.info(5.0).as_xml()
        self.rows: list[Any] = []
        self.stamps: list[float] = []
        self.offsets: list[tuple[float, float]] = []
        self.lost = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                chunk, times = self.inlet.pull_chunk(timeout=0.05, max_samples=1024)
                self.rows += chunk
                self.stamps += times
                if len(self.offsets) < len(self.stamps) // 100 + 1:
                    self.offsets.append((pylsl.local_clock(), self.inlet.time_correction(2.0)))
        except pylsl.util.LostError:
            self.lost = True

    def stop(self) -> Recorder:
        """Stop recording and destroy the inlet here, once its thread has let it go: an inlet
        is never destroyed under a pull, nor left for the garbage collector to destroy after
        its outlet (see `Publisher`)."""
        self._stop.set()
        self._thread.join(5.0)
        assert not self._thread.is_alive(), "the recorder's thread did not stop"
        self.inlet = None
        return self


class Publisher:
    """The outlets of one test (`outlet(info)`), destroyed by `withdraw_all` once no consumer is
    connected to any: after the test, whose inlets, Recorders and sources went with its locals.

    liblsl can crash the process when an outlet is destroyed while a consumer's connection to it
    is being torn down, or while an inlet on it is still open (sccn/liblsl#218 and #220;
    mne-lsl's tests learnt to destroy inlets before outlets). A test that ends right after its
    daemon exits would otherwise destroy the daemon's tracker outlet in that window. A consumer
    that has gone leaves within milliseconds (`have_consumers`), so the wait costs nothing.
    """

    def __init__(self) -> None:
        self.outlets: list[pylsl.StreamOutlet] = []

    def outlet(self, info: pylsl.StreamInfo) -> pylsl.StreamOutlet:
        self.outlets.append(pylsl.StreamOutlet(info))
        return self.outlets[-1]

    def withdraw_all(self, timeout: float = 10.0) -> None:
        gc.collect()  # an inlet a reference cycle still holds goes first
        while self.outlets:
            self._withdraw(self.outlets.pop(), timeout)

    @staticmethod
    def _withdraw(outlet: pylsl.StreamOutlet, timeout: float) -> None:
        name = outlet.get_info().name()
        until(lambda: not outlet.have_consumers(), timeout, f"{name}'s consumers to leave")
        # returning drops the last reference: the outlet is destroyed here
