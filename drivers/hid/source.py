"""The HID eye-tracker source: device I/O over the pure decoding in `descriptor` and `tracker`.

Everything that touches the device is here: hidapi's `enumerate`, `open_path`, the report
descriptor, `get_feature_report`, `send_feature_report` and `read`, and reconnecting with back-off;
what the bytes mean is decided in `descriptor`, `tracker` and `clock`.

hidapi backend, on purpose: the PyPI `hidapi` package builds two modules. On Linux `hidraw` uses
the kernel's hidraw interface: it works with the kernel HID driver bound (nothing is detached,
the tracker keeps working for everything else), needs no root once a udev rule grants access to
`/dev/hidraw*` (see `gazehdr.drivers.hid.devices.list_devices`), reports `usage_page` per
top-level collection in `enumerate()` (read from sysfs, so even without access), and gives the
report descriptor (`get_report_descriptor`: checked present in hidapi 0.15.0; for a wrapper without
it the descriptor is read from sysfs). The `hid` module is built on libusb on Linux: it detaches
the kernel driver from the interface and needs write access to the USB device node. On macOS and
Windows the `hid` module uses the native backend, so it is the one used there.

Unplug shows as an `OSError` from `read`: the source closes the device and reconnects with
exponential back-off; samples already yielded stay yielded (the generator never buffers), and a
note with the count so far is logged. The back-off spaces the attempts and their messages, not
the noticing of a re-plug: while it waits, the HID devices are listed every `REPLUG_POLL_S`
(a walk of sysfs), and a tracker that appears is opened at once.

Reports lost before they were read (the kernel keeps 64 unread reports per reader) and reports
faster than the tracker's declared rate are counted from the Sensor Timestamp
(`gazehdr.drivers.hid.clock.ReportGaps`) and logged, at most every `GAP_LOG_S`, and on `close`
and when the iteration ends.

The source's state (`HidState`) says whether a tracker is open:

    DISCONNECTED --connect()--> OPEN --unplug, or the iteration ends--> DISCONNECTED
    DISCONNECTED, OPEN --close()--> CLOSED
    OPEN --close() while iterated--> CLOSING --the iteration's next read--> CLOSED

`connect` is refused (`InvalidStateError`) while a tracker is open, where a second handle would
leak the first, and once closed, where nothing would close the device it opened.
"""

from __future__ import annotations

import contextlib
import enum
import logging
import math
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from typing import Any

from gazehdr.drivers.backoff import retry
from gazehdr.drivers.errors import InputError
from gazehdr.drivers.hid.clock import ReportClock, ReportGaps
from gazehdr.drivers.hid.descriptor import DecodedReport, Descriptor, DescriptorError, ReportError
from gazehdr.drivers.hid.tracker import (
    TrackerInfo,
    TrackerReports,
    gaze_sample,
    path_str,
    screen_geometry,
    shape_differs,
)
from gazehdr.drivers.hid.usages import SENSOR_TIMESTAMP, USAGE_PAGE
from gazehdr.drivers.registry import SourceUnavailableError
from gazehdr.drivers.samples import GazeSample, ScreenGeometry, StreamRequest
from gazehdr.drivers.sources import SourceInfo
from gazehdr.drivers.states import InvalidStateError

log = logging.getLogger(__name__)

#: While waiting to reconnect, how often the HID devices are listed for a tracker plugged in.
REPLUG_POLL_S = 0.25
#: For this long after a tracker appeared, a failed open is retried at each look (a udev rule
#: may not have given access to its node yet), before the back-off's own pace again.
REPLUG_SETTLE_S = 1.0
#: Lost and early reports are logged at most this often (and when the iteration ends).
GAP_LOG_S = 10.0
#: What Linux's hidraw keeps per reader before it drops reports (drivers/hid/hidraw.c).
HIDRAW_BUFFER_REPORTS = 64


def default_backend() -> Any:
    """`hidraw` on Linux (kernel driver stays bound), the native `hid` elsewhere."""
    try:
        if sys.platform.startswith("linux"):
            import hidraw as backend
        else:  # pragma: no cover - not Linux
            import hid as backend
    except ModuleNotFoundError as e:  # pragma: no cover - depends on the installation
        raise ModuleNotFoundError(
            "the HID tracker source needs hidapi: install gazehdr[daemon]", name=e.name
        ) from None
    return backend


def read_descriptor(dev: Any, path: bytes | str) -> bytes:
    """The report descriptor of an opened device: from hidapi, else from sysfs."""
    getter = getattr(dev, "get_report_descriptor", None)
    if getter is not None:
        return bytes(getter())
    # hidapi before the wrapper had get_report_descriptor: sysfs has it (world-readable).
    name = os.path.basename(path_str(path))
    sysfs = f"/sys/class/hidraw/{name}/device/report_descriptor"
    try:
        with open(sysfs, "rb") as fh:
            return fh.read()
    except OSError:
        raise DescriptorError(
            f"{path_str(path)}: this hidapi cannot read report descriptors; install hidapi>=0.14"
        ) from None


class HidTracker:
    """One opened HID eye tracker: reads its descriptor and feature reports and, with
    `set_mode`, sends its Device Mode Request; `reports` decodes what `dev.read` returns."""

    def __init__(
        self, dev: Any, entry: dict[str, Any], *, mode: int | None = None, set_mode: bool = True
    ) -> None:
        self.dev = dev
        self.reports = TrackerReports(Descriptor(read_descriptor(dev, entry["path"])))
        features = [f for f in map(self._feature, self.reports.feature_ids) if f is not None]
        self.device_mode = self._set_mode(mode) if set_mode else None
        self.info = TrackerInfo.of(entry, features, self.device_mode)

    def _feature(self, rid: int | None) -> DecodedReport | None:
        """A feature report, or None (logged) when it cannot be read or does not decode."""
        try:
            data = self.dev.get_feature_report(rid or 0, self.reports.feature_size(rid) + 1)
        except (OSError, ValueError) as e:
            log.warning("feature report %s: %s", rid, e)
            return None
        try:
            return self.reports.decode_feature(rid, data)
        except ReportError as e:
            log.warning("feature report %s: %s", rid, e)
            return None

    def _set_mode(self, mode: int | None) -> int | None:
        request = self.reports.mode_request(mode)
        if request is None:
            return None
        mode, report = request
        self.dev.send_feature_report(report)
        return mode


class HidState(enum.Enum):
    """Whether a `HidGazeSource` has a tracker open (the module docstring has the diagram)."""

    DISCONNECTED = "disconnected"  # none open: not yet, or unplugged (an iteration reconnects)
    OPEN = "open"
    CLOSING = "closing"  # closed while iterated: the iteration closes the device at its next read
    CLOSED = "closed"  # nothing is opened again


class HidGazeSource:
    """Gaze samples from a HID eye tracker, reconnecting after an unplug.

    Iterate it (or call `samples()`) for `GazeSample`s: `t_ns` is host monotonic ns (`clock_ns`),
    spaced by the tracker's Sensor Timestamp and placed by the smallest host − sensor difference
    over the last `clock_window_s` of reads (late by the least latency in that window; see
    `gazehdr.drivers.hid.clock`); x/y are screen pixels (µm over the calibrated screen
    size from the Configuration feature report, times the screen's size in pixels from
    `geometry`); a report whose gaze is out of the logical range (the tracker has no gaze) gives
    an invalid sample.

    `geometry` is the screen's: given, it is used as it is; by default it is the tracker's, its
    diagonal from the calibrated screen size the tracker reports (the defaults' where it reports
    none), its size in pixels and viewing distance the defaults (HID reports neither). `screen`
    (`ScreenGeometry` field names → values: the daemon's `--screen`, `--diagonal`, `--distance`)
    then overrides single fields.

    `path` picks a device (else the first with usage page 0x12), `backend` is the hidapi module
    (`hidraw` on Linux; tests pass a fake with `enumerate()` and `device()`), `mode` the Device
    Mode Request (default: gaze point, plus eye position where the tracker reports it).
    `give_up_after_s` ends the iteration with an OSError when no tracker answered for that long
    (None: retry forever). With `open_now` (the default) the constructor opens the tracker and
    raises OSError when there is none (DescriptorError when it is not usable): only a tracker
    that was there and went away is waited for, unless `open_now=False` (then the first read
    waits, or `wait_for_tracker()` does). `sleep` and `clock` (s, for the back-off) and
    `clock_ns` (the host clock samples are stamped with) are injectable for tests.
    `info` is a `gazehdr.drivers.sources.SourceInfo`; `tracker_info` what the tracker reported.
    """

    def __init__(
        self,
        geometry: ScreenGeometry | None = None,
        *,
        screen: Mapping[str, float] | None = None,
        path: bytes | str | None = None,
        backend: Any = None,
        mode: int | None = None,
        read_timeout_ms: int = 200,
        backoff_initial_s: float = 0.25,
        backoff_max_s: float = 8.0,
        give_up_after_s: float | None = None,
        open_now: bool = True,
        sleep: Callable[[float], None] = time.sleep,
        clock: Callable[[], float] = time.monotonic,
        clock_ns: Callable[[], int] = time.monotonic_ns,
        clock_window_s: float = 2.0,
    ) -> None:
        self._given_geometry = geometry
        self.screen = dict(screen or {})
        self.tracker_info: TrackerInfo | None = None
        self._geometry = self._screen_geometry()  # refuses a bad field or value now
        self.path = path
        self._backend = backend
        self.mode = mode
        self.read_timeout_ms = read_timeout_ms
        self.backoff_initial_s = backoff_initial_s
        self.backoff_max_s = backoff_max_s
        self.give_up_after_s = give_up_after_s
        self._sleep = sleep
        self._clock = clock
        self._clock_ns = clock_ns
        if not (math.isfinite(clock_window_s) and clock_window_s > 0):
            raise InputError(f"clock_window_s must be a positive number, got {clock_window_s}")
        self._report_clock = ReportClock(round(clock_window_s * 1e9))
        self.tracker: HidTracker | None = None  # open exactly in OPEN and CLOSING
        self.state = HidState.DISCONNECTED
        self._lock = threading.Lock()  # close() may come from another thread than the reads
        self.samples_yielded = 0
        self.reconnects = 0
        #: Reports lost before they were read, and faster than declared (`ReportGaps`).
        self.gaps = ReportGaps()
        self._gaps_logged = (0, 0, -math.inf)  # lost, early, when
        self._seen_present = False  # whether a tracker was listed at the last look
        self._appeared_at = -math.inf
        self._running = False
        if open_now:
            self.connect()

    @property
    def geometry(self) -> ScreenGeometry:
        """The screen: as given, or the tracker's (see the class docstring), then `screen`."""
        return self._geometry

    def _calibrated_um(self) -> tuple[float, float] | None:
        return self.tracker_info.calibrated_screen_um if self.tracker_info else None

    def _screen_geometry(self) -> ScreenGeometry:
        """`geometry` for the tracker now connected (made once per connection, not per sample)."""
        return screen_geometry(self._given_geometry, self._calibrated_um(), self.screen)

    @property
    def info(self) -> SourceInfo:
        """What `drivers.sources` wants of a source: name, geometry, rate, tracker details."""
        t = self.tracker_info
        if t is None:
            return SourceInfo(name="hid", geometry=self.geometry, live=True)
        name = " ".join(p for p in ("hid", t.manufacturer, t.product) if p)
        return SourceInfo(
            name=name, geometry=self.geometry, rate_hz=t.sampling_hz, tracker=t.as_dict()
        )

    @property
    def backend(self) -> Any:
        if self._backend is None:
            self._backend = default_backend()
        return self._backend

    # connection

    def _pick(self) -> dict[str, Any]:
        entries = list(self.backend.enumerate())
        for e in entries:
            if self.path is not None:
                if path_str(e["path"]) == path_str(self.path):
                    return e
            elif e.get("usage_page") == USAGE_PAGE:
                return e
        wanted = path_str(self.path) if self.path is not None else "usage page 0x12"
        raise OSError(f"no HID eye tracker found ({wanted}); see 'gazehdr devices'")

    @property
    def _closed(self) -> bool:
        return self.state in (HidState.CLOSING, HidState.CLOSED)

    def connect(self) -> HidTracker:
        """Open the tracker once, DISCONNECTED → OPEN (OSError when there is none or it cannot
        be opened). InvalidStateError while one is open or once the source is closed."""
        tracker = self._connect()
        if tracker is None:
            raise InvalidStateError("HidGazeSource", "connect", self.state, "the source is closed")
        return tracker

    def _connect(self) -> HidTracker | None:
        """`connect`, but None when the source is closed, before or while it opens (by another
        thread: the device it opened is closed again)."""
        if self.state is HidState.OPEN:
            why = "a tracker is open already (a second handle would leak it)"
            raise InvalidStateError("HidGazeSource", "connect", self.state, why)
        if self._closed:
            return None
        entry = self._pick()
        dev = self.backend.device()
        dev.open_path(entry["path"])
        try:
            tracker = HidTracker(dev, entry, mode=self.mode)
        except BaseException:
            dev.close()
            raise
        with self._lock:
            opened = self.state is HidState.DISCONNECTED
            if opened:
                self.tracker, self.state = tracker, HidState.OPEN
        if not opened:
            with contextlib.suppress(Exception):
                dev.close()
            return None
        self.tracker_info = tracker.info
        self.gaps.declared(tracker.info.sampling_hz)
        self._geometry = self._screen_geometry()
        calibrated = tracker.info.calibrated_screen_um
        g = self.geometry
        if calibrated is None:
            log.warning(
                "%s reports no calibrated screen size; using the screen geometry's "
                "(%.3f m diagonal)",
                tracker.info.path,
                g.screen_diagonal_m,
            )
        elif shape_differs(calibrated, (g.screen_width_px, g.screen_height_px)):
            log.warning(
                "%s is calibrated for a %.0f × %.0f mm screen, not the shape of %d × %d pixels: "
                "pass the screen's size in pixels (gazehdr daemon --screen WxH)",
                tracker.info.path,
                calibrated[0] / 1000,
                calibrated[1] / 1000,
                g.screen_width_px,
                g.screen_height_px,
            )
        return tracker

    def wait_for_tracker(self) -> HidTracker:
        """Open the tracker, waiting with back-off until one is plugged in (a one-line message
        per attempt); OSError after `give_up_after_s`. How `gazehdr daemon --source hid`
        starts, so that a daemon started before its tracker does not exit."""
        tracker = self._reconnect()
        if tracker is None:
            raise OSError("the HID source was closed while waiting for a tracker")
        return tracker

    def _reconnect(self) -> HidTracker | None:
        """Open the tracker, waiting with back-off; None when the source was closed meanwhile."""
        return retry(
            self._connect,
            name="HID tracker",
            missing="HID eye tracker",
            closed=lambda: self._closed,
            log=log,
            initial_s=self.backoff_initial_s,
            max_s=self.backoff_max_s,
            give_up_after_s=self.give_up_after_s,
            sleep=self._wait_for_replug,
            clock=self._clock,
        )

    def _present(self) -> bool:
        try:
            self._pick()
        except OSError:
            return False
        return True

    def _wait_for_replug(self, delay_s: float) -> None:
        """The back-off's wait of `delay_s`, cut short when a tracker appears (listed every
        `REPLUG_POLL_S`), and at each look for `REPLUG_SETTLE_S` after it appeared."""
        looks = max(1, math.ceil(delay_s / REPLUG_POLL_S - 1e-9))
        for i in range(looks):
            if self._closed:
                return
            self._sleep(min(REPLUG_POLL_S, delay_s - i * REPLUG_POLL_S))
            present, now = self._present(), self._clock()
            if present and not self._seen_present:
                self._appeared_at = now
            self._seen_present = present
            if present and now - self._appeared_at < REPLUG_SETTLE_S:
                return

    def _drop(self) -> None:
        """Close the device: OPEN → DISCONNECTED, CLOSING → CLOSED."""
        with self._lock:
            tracker, self.tracker = self.tracker, None
            if self.state is HidState.OPEN:
                self.state = HidState.DISCONNECTED
            elif self.state is HidState.CLOSING:
                self.state = HidState.CLOSED
        if tracker is not None:
            with contextlib.suppress(Exception):  # the device is gone; closing is best effort
                tracker.dev.close()

    def close(self) -> None:
        """Stop: the running iteration ends at its next read (within `read_timeout_ms`) and
        closes the device itself (CLOSING), so no device is closed under a read in another
        thread; else the device is closed now. Again: nothing more happens. Lost and early
        reports not yet logged are logged now (a daemon may exit before the iteration ends)."""
        self._log_gaps(force=True)
        with self._lock:
            if self._closed:
                return
            iterated = self._running and self.tracker is not None
            self.state = HidState.CLOSING if iterated else HidState.CLOSED
            if iterated:
                return
            tracker, self.tracker = self.tracker, None
        if tracker is not None:
            with contextlib.suppress(Exception):
                tracker.dev.close()

    # the stream

    def sample(self, decoded: DecodedReport, host_ns: int, reconnected: bool = False) -> GazeSample:
        """The GazeSample of one decoded Tracking Data report, read at host time `host_ns`."""
        t_ns = self._report_clock.time_ns(decoded.find(SENSOR_TIMESTAMP), host_ns, reconnected)
        return gaze_sample(decoded, t_ns, self.geometry, self._calibrated_um())

    def samples(self) -> Iterator[GazeSample]:
        if self._running:
            raise RuntimeError("this HID source is already being iterated")
        self._running = True
        try:
            yield from self._stream()
        finally:
            self._running = False
            self._drop()
            self._log_gaps(force=True)

    def _log_gaps(self, force: bool = False) -> None:
        """Say how many reports were lost or came early, when that changed, at most every
        GAP_LOG_S (`force`: now, at the end)."""
        g, (lost, early, at) = self.gaps, self._gaps_logged
        now = self._clock()
        if (g.lost, g.early) == (lost, early) or (not force and now - at < GAP_LOG_S):
            return
        self._gaps_logged = (g.lost, g.early, now)
        rate = f"{1e9 / g.period_ns:g} Hz" if g.period_ns else "its declared rate"
        if g.lost > lost:
            log.warning(
                "HID tracker: %d reports lost before they were read (%d in all; Sensor "
                "Timestamp gaps at %s): the kernel keeps %d unread reports, the reader fell "
                "behind or the tracker sent a backlog at once",
                g.lost - lost,
                g.lost,
                rate,
                HIDRAW_BUFFER_REPORTS,
            )
        if g.early > early:
            log.warning(
                "HID tracker: %d reports faster than its declared %s (%d in all): reports "
                "beyond the kernel's %d unread ones are lost without a count",
                g.early - early,
                rate,
                g.early,
                HIDRAW_BUFFER_REPORTS,
            )

    def _stream(self) -> Iterator[GazeSample]:
        reconnected = False
        while not self._closed:
            if self.tracker is None:
                first = self.reconnects == 0 and self.samples_yielded == 0
                if self._reconnect() is None:
                    return
                reconnected = not first
                if reconnected:
                    log.info(
                        "HID tracker reconnected: %s",
                        self.tracker_info.path if self.tracker_info else "",
                    )
            tracker = self.tracker
            assert tracker is not None
            try:
                data = tracker.dev.read(tracker.reports.read_size, self.read_timeout_ms)
            except OSError as e:
                self.reconnects += 1
                log.warning(
                    "HID tracker read failed (%s), probably unplugged; %d samples recorded so "
                    "far are kept; reconnecting",
                    e,
                    self.samples_yielded,
                )
                self._drop()
                continue
            if not data:
                continue  # read timeout
            host_ns = self._clock_ns()
            try:
                decoded = tracker.reports.decode(data)
            except ReportError as e:
                log.warning("skipping a malformed report: %s", e)
                continue
            if decoded is None:
                continue
            s = self.sample(decoded, host_ns, reconnected)
            reconnected = False
            if self.gaps.add(self._report_clock.step_ns) or self.gaps.early:
                self._log_gaps()
            self.samples_yielded += 1
            yield s

    def __iter__(self) -> Iterator[GazeSample]:
        return self.samples()


def open_hid(request: StreamRequest) -> HidGazeSource:
    """The `hid[:PATH]` stream of `gazehdr.drivers.registry`: the tracker at PATH (else the
    first on usage page 0x12); `geometry` replaces what it reports, `screen` overrides single
    fields; with `wait`, waits for a tracker to be plugged in. SourceUnavailableError when there
    is none or it cannot be used (the registry reports a missing hidapi, an ImportError)."""
    options = dict(request.options)
    if request.arg:
        options.setdefault("path", request.arg)
    if request.geometry is not None:
        options.setdefault("geometry", request.geometry)
    if request.screen:
        options.setdefault("screen", request.screen)
    options.setdefault("open_now", not request.wait)
    try:
        source = HidGazeSource(**options)
        if request.wait:
            source.wait_for_tracker()
        return source
    except (OSError, LookupError, ValueError) as e:  # no tracker, or not one we can use
        raise SourceUnavailableError(f"HID source unavailable: {e}") from None
