"""A fake USB HID eye tracker for the tests of `gazehdr.drivers.hid`, without hardware.

Report descriptors are written item by item from the HID 1.11 item encoding and the Eye and
Head Trackers usage table (`item` and the encoders after it, `tracker_descriptor`,
`microsoft_style_descriptor`, `gaze_only_descriptor`); reports are packed byte by byte with
`struct` (`tracking_report`, `FEATURES`). The device is a fake with the hidapi interface
(`FakeBus`: `enumerate`, `device`; `FakeDevice`: `open_path`, `get_report_descriptor`,
`get_feature_report`, `send_feature_report`, `read`, `close`), since this kernel has no uhid;
`FakeTracker` is the device's side, which a test plugs, unplugs and fills with reports
(`timed_stream`). Used by tests/test_hid.py, tests/test_hid_core.py, the fuzz corpus's seeds
(tests/fuzz_corpus/make_seeds.py) and the daemon a test of test_hid.py runs in a process of its
own.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from gazehdr.drivers.hid.source import HidGazeSource

# --- HID 1.11 short items ---------------------------------------------------------------------


def item(prefix: int, value: int | None = None, nbytes: int | None = None) -> bytes:
    """One short item: prefix (tag and type, size bits 0) and a little-endian payload."""
    if value is None:
        return bytes([prefix])
    if nbytes is None:
        nbytes = 1 if -128 <= value <= 255 else 2 if -32768 <= value <= 0xFFFF else 4
    size_code = {1: 1, 2: 2, 4: 3}[nbytes]
    payload = (value & ((1 << (8 * nbytes)) - 1)).to_bytes(nbytes, "little")
    return bytes([prefix | size_code]) + payload


def usage_page(p: int) -> bytes:
    return item(0x04, p)


def usage(u: int) -> bytes:
    return item(0x08, u & 0xFFFF)


def logical(lo: int, hi: int, nbytes: int | None = None) -> bytes:
    return item(0x14, lo, nbytes) + item(0x24, hi, nbytes)


def physical(lo: int, hi: int, nbytes: int | None = None) -> bytes:
    return item(0x34, lo, nbytes) + item(0x44, hi, nbytes)


def unit(u: int) -> bytes:
    return item(0x64, u)


def unit_exponent(e: int, nibble: bool = True) -> bytes:
    return item(0x54, e & 0xF if nibble else e & 0xFF, 1)


def size(bits: int) -> bytes:
    return item(0x74, bits)


def count(n: int) -> bytes:
    return item(0x94, n)


def report_id(r: int) -> bytes:
    return item(0x84, r)


def collection(kind: int) -> bytes:  # 0 physical, 1 application, 2 logical
    return item(0xA0, kind, 1)


END = bytes([0xC0])
PUSH, POP = bytes([0xA4]), bytes([0xB4])
DATA, CONST = 0x02, 0x03  # Data,Var,Abs / Const,Var,Abs
PADDING = 0x01  # Const,Array,Abs


def input_(flags: int) -> bytes:
    return item(0x80, flags, 1)


def feature(flags: int) -> bytes:
    return item(0xB0, flags, 1)


# Units: system nibble 1 (SI linear); length nibble 1 = cm; time nibble 1 = s, F (−1) = 1/s.
UNIT_CM, UNIT_S, UNIT_HZ = 0x11, 0x1001, 0xF001


def tracker_descriptor(*, gaze_flags: int = DATA) -> bytes:
    """An eye tracker as the usage table describes it, with the awkward parts on purpose.

    Input report 0x10 (Tracking Data): 3 padding bytes; Sensor Timestamp, u32 in s·10⁻⁶ (µs);
    Left Eye Position X/Y/Z, i16 in cm·10⁻¹ (mm) *before* the Gaze Point; Gaze Point X/Y, i32 in
    cm·10⁻⁴ (µm), logical range ±1 000 000; a 1-bit flag and 7 bits padding after the Gaze Point
    collection closed. Feature reports 0x11 Capabilities (Constant), 0x12 Configuration
    (Constant, calibrated screen in µm without a Unit item), 0x13 Status (Sampling Frequency in
    Hz), 0x14 Control (Device Mode Request).
    """
    return b"".join(
        [
            usage_page(0x12),
            usage(0x01),
            collection(1),
            usage(0x10),
            collection(0),
            report_id(0x10),
            size(8),
            count(3),
            input_(PADDING),
            usage(0x20),
            logical(0, 0xFFFFFFFF, 4),
            unit(UNIT_S),
            unit_exponent(-6),
            size(32),
            count(1),
            input_(DATA),
            usage(0x25),
            collection(0),
            usage(0x21),
            usage(0x22),
            usage(0x23),
            logical(-32767, 32767),
            unit(UNIT_CM),
            unit_exponent(-1),
            size(16),
            count(3),
            input_(DATA),
            END,
            usage(0x24),
            collection(0),
            usage(0x21),
            usage(0x22),
            logical(-1_000_000, 1_000_000, 4),
            unit(UNIT_CM),
            unit_exponent(-4),
            size(32),
            count(2),
            input_(gaze_flags),
            END,
            usage(0x23),  # a Position Z outside every eye/gaze collection
            logical(0, 1),
            unit(0),
            unit_exponent(0),
            size(1),
            count(1),
            input_(DATA),
            size(7),
            input_(PADDING),
            END,
            # Capabilities: Tracker Quality, Maximum Screen Plane Width/Height, Constant-flagged
            usage(0x11),
            collection(2),
            report_id(0x11),
            usage(0x100),
            logical(0, 4),
            size(8),
            count(1),
            feature(CONST),
            usage(0x104),
            usage(0x105),
            logical(0, 0x7FFFFFFF, 4),
            size(32),
            count(2),
            feature(CONST),
            END,
            # Configuration: calibrated screen in µm (the usage's own unit, no Unit item)
            usage(0x12),
            collection(2),
            report_id(0x12),
            size(8),
            count(1),
            feature(PADDING),
            usage(0x204),
            usage(0x205),
            logical(0, 0x7FFFFFFF, 4),
            size(32),
            count(2),
            feature(CONST),
            END,
            # Status: Configuration Status, Sampling Frequency in Hz
            usage(0x13),
            collection(2),
            report_id(0x13),
            usage(0x301),
            logical(0, 4),
            size(8),
            count(1),
            feature(DATA),
            usage(0x300),
            logical(0, 0x7FFF),
            unit(UNIT_HZ),
            unit_exponent(0),
            size(16),
            feature(DATA),
            unit(0),
            END,
            # Control: Device Mode Request
            usage(0x14),
            collection(2),
            report_id(0x14),
            usage(0x400),
            logical(0, 7),
            size(8),
            count(1),
            feature(DATA),
            END,
            END,
        ]
    )


def tracking_report(ts_us: int, left_mm: tuple[int, int, int], gaze_um: tuple[int, int]) -> bytes:
    """Input report 0x10 of `tracker_descriptor`, packed by hand."""
    return (
        bytes([0x10, 0xAA, 0xBB, 0xCC])  # report id, 3 bytes of padding (any content)
        + struct.pack("<I", ts_us)
        + struct.pack("<3h", *left_mm)
        + struct.pack("<2i", *gaze_um)
        + bytes([0x01])  # the flag bit set, padding zero
    )


FEATURES = {
    0x11: bytes([0x11, 2]) + struct.pack("<2I", 600_000, 340_000),
    0x12: bytes([0x12, 0]) + struct.pack("<2I", 527_040, 296_460),
    0x13: bytes([0x13, 1]) + struct.pack("<H", 120),
    0x14: bytes([0x14, 0]),
}


def microsoft_style_descriptor() -> bytes:
    """The Microsoft reference driver's layout: an 8 × 8-bit timestamp under one usage, 32-bit
    signed gaze without units, one report id; plus a Push/Pop around a unit and a Unit Exponent
    written as a whole byte (0xFC), both of which hid-tools needs help with."""
    return b"".join(
        [
            usage_page(0x12),
            usage(0x01),
            collection(1),
            collection(2),
            report_id(0x10),
            logical(0, 0xFF),
            size(8),
            count(3),
            input_(CONST),  # padding
            usage(0x20),
            count(8),
            input_(DATA),
            count(1),
            size(32),
            logical(-0x80000000, 0x7FFFFFFF, 4),
            usage(0x24),
            collection(0),
            count(2),
            usage(0x21),
            usage(0x22),
            input_(DATA),
            END,
            unit(UNIT_CM),
            unit_exponent(-4, nibble=False),
            PUSH,
            usage(0x25),
            collection(0),
            count(3),
            usage(0x21),
            usage(0x22),
            usage(0x23),
            input_(DATA),
            END,
            POP,
            END,
            END,
        ]
    )


def gaze_only_descriptor(*more: bytes) -> bytes:
    """An eye tracker without report ids and without Sensor Timestamp: Gaze Point X/Y as i16
    (µm, the usage's own unit), then the items `more` inside its application collection."""
    return b"".join(
        [
            usage_page(0x12),
            usage(0x01),
            collection(1),
            usage(0x24),
            collection(0),
            usage(0x21),
            usage(0x22),
            logical(-32767, 32767),
            size(16),
            count(2),
            input_(DATA),
            END,
            *more,
            END,
        ]
    )


# --- a fake hidapi ----------------------------------------------------------------------------


class UnpluggedError(OSError):
    pass


class FakeTracker:
    """The device side: descriptor, feature reports, and a queue of input reports.

    `read_at_ns` runs parallel to `queue`: reading a report moves the host clock `now_ns` (what
    the tests pass as the source's `clock_ns`) to the time that report is read at.
    """

    def __init__(self, path: bytes, descriptor: bytes, features: dict[int, bytes]) -> None:
        self.path = path
        self.descriptor = descriptor
        self.features = dict(features)
        self.sent: list[list[int]] = []
        self.queue: list[bytes] = []
        self.read_at_ns: list[int] = []
        self.now_ns = 0
        self.plugged = True
        self.unplug_after: int | None = None  # unplug after this many more reads
        self.reads = 0
        self.idle_read_s = 0.0  # an empty read waits this long, as a real one times out


class FakeBus:
    """What the source calls the backend module: `enumerate()` and `device()`."""

    def __init__(self, *trackers: FakeTracker, others: Iterable[dict[str, Any]] = ()) -> None:
        self.trackers = {t.path: t for t in trackers}
        self.others = list(others)
        self.opened = 0

    def enumerate(self) -> list[dict[str, Any]]:
        out = list(self.others)
        for t in self.trackers.values():
            if t.plugged:
                out.append(
                    {
                        "path": t.path,
                        "vendor_id": 0x2104,
                        "product_id": 0x0127,
                        "serial_number": "TT-1",
                        "manufacturer_string": "Test Trackers",
                        "product_string": "Gaze 120",
                        "usage_page": 0x12,
                        "usage": 0x01,
                    }
                )
        return out

    def device(self) -> FakeDevice:
        return FakeDevice(self)


class FakeDevice:
    def __init__(self, bus: FakeBus) -> None:
        self.bus = bus
        self.t: FakeTracker | None = None

    def _tracker(self) -> FakeTracker:
        if self.t is None:
            raise ValueError("not open")
        if not self.t.plugged:
            raise UnpluggedError("read error")
        return self.t

    def open_path(self, path: bytes) -> None:
        t = self.bus.trackers.get(path)
        if t is None or not t.plugged:
            raise OSError("open failed")
        self.t = t
        self.bus.opened += 1

    def get_report_descriptor(self) -> list[int]:
        return list(self._tracker().descriptor)

    def get_feature_report(self, report_num: int, max_length: int) -> list[int]:
        return list(self._tracker().features[report_num][:max_length])

    def send_feature_report(self, buff: Any) -> int:
        t = self._tracker()
        t.sent.append(list(buff))
        rid = buff[0]
        if rid in t.features:
            t.features[rid] = bytes(buff)
        return len(buff)

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        t = self._tracker()
        if t.unplug_after is not None:
            if t.unplug_after == 0:
                t.plugged = False
                t.unplug_after = None
                t.queue.clear()  # whatever the device held is gone with it
                t.read_at_ns.clear()
                raise UnpluggedError("read error")
            t.unplug_after -= 1
        t.reads += 1
        if not t.queue:
            time.sleep(t.idle_read_s)
            return []
        if t.read_at_ns:
            t.now_ns = t.read_at_ns.pop(0)
        return list(t.queue.pop(0)[:max_length])

    def close(self) -> None:
        self.t = None


PATH = b"/dev/hidraw-test-0"


def make_tracker(descriptor: bytes | None = None) -> FakeTracker:
    return FakeTracker(PATH, descriptor or tracker_descriptor(), FEATURES)


#: The host's monotonic clock when a stream starts: far from the tracker's own clock.
HOST0_NS = 7_000_000_000_000


@dataclass
class Stream:
    """Reports of a tracker sampling at host times `taken_ns`, read at host times `read_ns`."""

    reports: list[bytes]
    sensor_us: list[int]
    taken_ns: list[int]
    read_ns: list[int]

    def queue(self, t: FakeTracker) -> None:
        t.queue, t.read_at_ns = list(self.reports), list(self.read_ns)


def timed_stream(
    n: int,
    *,
    t0_us: int = 1_000_000,
    period_ns: int = 8_333_000,
    host0_ns: int = HOST0_NS,
    ppm: float = 0.0,
    latency_ns: Callable[[int], int] = lambda i: 200_000,
) -> Stream:
    """`n` gaze samples taken every `period_ns` of host time by a tracker whose clock runs `ppm`
    fast (sensor = t0 + elapsed · (1 + ppm · 10⁻⁶), whole µs, wrapping at 32 bits), sample i
    read `latency_ns(i)` after it was taken."""
    taken = [host0_ns + i * period_ns for i in range(n)]
    sensor = [t0_us + round(i * period_ns * (1 + ppm * 1e-6) / 1000) for i in range(n)]
    reports = [
        tracking_report(us % (1 << 32), (0, 0, 0), (10_000 * (i + 1), 5_000 * (i + 1)))
        for i, us in enumerate(sensor)
    ]
    read = [h + latency_ns(i) for i, h in enumerate(taken)]
    return Stream(reports, sensor, taken, read)


def timed_source(t: FakeTracker, **options: Any) -> HidGazeSource:
    """A source on `t` whose host clock is the fake's (moved by each read)."""
    return HidGazeSource(backend=FakeBus(t), clock_ns=lambda: t.now_ns, **options)
