"""A virtual HID device through Linux's uhid (`/dev/uhid`), with the standard library only.

The kernel ABI is `include/uapi/linux/uhid.h`: every message either way is one packed
`struct uhid_event`, a u32 type and a union whose largest member (`uhid_create2_req`) makes it
4376 bytes. The device side writes UHID_CREATE2 (name, ids, bus, report descriptor), UHID_INPUT2
(an input report) and UHID_DESTROY; the kernel writes UHID_START / UHID_STOP, UHID_OPEN /
UHID_CLOSE (a reader such as a hidraw node opened or closed it), UHID_GET_REPORT and
UHID_SET_REPORT (a feature report asked for or sent, e.g. through hidraw's HIDIOCGFEATURE /
HIDIOCSFEATURE, which hidapi's `get_feature_report` / `send_feature_report` are), each of which
must be answered with its id, else the kernel gives up on it after 5 s (-EIO).

`UhidDevice` runs in the guest's harness process (tests/hid_kernel/agent.py): a thread reads the
kernel's events and answers feature reports from a table (or with an error, or not at all,
as a device that lies would), and `input()` writes input reports.
"""

from __future__ import annotations

import errno
import os
import select
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

# enum uhid_event_type
UHID_DESTROY = 1
UHID_START = 2
UHID_STOP = 3
UHID_OPEN = 4
UHID_CLOSE = 5
UHID_OUTPUT = 6
UHID_GET_REPORT = 9
UHID_GET_REPORT_REPLY = 10
UHID_CREATE2 = 11
UHID_INPUT2 = 12
UHID_SET_REPORT = 13
UHID_SET_REPORT_REPLY = 14

# enum uhid_report_type
UHID_FEATURE_REPORT = 0
UHID_OUTPUT_REPORT = 1
UHID_INPUT_REPORT = 2

EVENT_NAMES = {
    UHID_DESTROY: "destroy",
    UHID_START: "start",
    UHID_STOP: "stop",
    UHID_OPEN: "open",
    UHID_CLOSE: "close",
    UHID_OUTPUT: "output",
    UHID_GET_REPORT: "get_report",
    UHID_SET_REPORT: "set_report",
}

BUS_USB = 0x03
DATA_MAX = 4096  # UHID_DATA_MAX, and HID_MAX_DESCRIPTOR_SIZE
# struct uhid_create2_req: name[128] phys[64] uniq[64] rd_size u16 bus u16 vendor u32 product u32
# version u32 country u32 rd_data[4096]
CREATE2 = struct.Struct(f"<I128s64s64sHHIIII{DATA_MAX}s")
EVENT_SIZE = CREATE2.size  # 4376: the union's largest member decides sizeof(struct uhid_event)
INPUT2 = struct.Struct(f"<IH{DATA_MAX}s")
GET_REPORT = struct.Struct("<IIBB")  # type, id, rnum, rtype
GET_REPORT_REPLY = struct.Struct(f"<IIHH{DATA_MAX}s")  # type, id, err, size, data
SET_REPORT = struct.Struct("<IIBBH")  # type, id, rnum, rtype, size; data follows
SET_REPORT_REPLY = struct.Struct("<IIH")  # type, id, err


def _event(packed: bytes) -> bytes:
    return packed.ljust(EVENT_SIZE, b"\0")


@dataclass
class KernelEvent:
    """One event the kernel wrote, as the harness reports it."""

    kind: str
    t_ns: int  # guest monotonic
    report: int | None = None
    rtype: int | None = None
    data: str = ""  # hex (SET_REPORT)
    answer: str = ""  # what the device replied: "data", an errno name, or "none"

    def as_dict(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if v not in (None, "")}


@dataclass
class Features:
    """How the device answers feature reports, by report id (0 when unnumbered).

    `reports` hold each report as the device sends it (report id first when numbered);
    `errors` are answered with that errno instead; `silent` are never answered (the kernel
    times out). A SET_REPORT for a known id replaces its content, like a real device's state.
    """

    reports: dict[int, bytes] = field(default_factory=dict)
    errors: dict[int, int] = field(default_factory=dict)
    silent: set[int] = field(default_factory=set)


class UhidDevice:
    """One virtual HID device: `create()` plugs it in, `destroy()` unplugs it, `input()`
    writes an input report; the kernel's events are answered on a thread and kept in
    `events`. The same object may be plugged in again after `destroy()`."""

    def __init__(
        self,
        descriptor: bytes,
        *,
        name: str = "gazehdr virtual tracker",
        vendor: int = 0x2104,
        product: int = 0x0127,
        version: int = 0x0100,
        uniq: str = "",
        bus: int = BUS_USB,
        features: Features | None = None,
        clock_ns: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        if len(descriptor) > DATA_MAX:
            raise ValueError(f"a report descriptor holds at most {DATA_MAX} bytes")
        self.descriptor = descriptor
        self.name, self.vendor, self.product, self.version = name, vendor, product, version
        self.uniq, self.bus = uniq, bus
        self.features = features or Features()
        self.events: list[KernelEvent] = []
        self.clock_ns = clock_ns
        self.fd: int | None = None
        self.created = False
        self._lock = threading.Lock()  # one event written at a time, from any thread
        self._stop = threading.Event()
        self._reader: threading.Thread | None = None

    # the device's side

    def create(self) -> None:
        """UHID_CREATE2: the kernel parses the descriptor and binds a driver (hid-generic),
        which makes the hidraw node. Opens /dev/uhid the first time."""
        if self.fd is None:
            self.fd = os.open("/dev/uhid", os.O_RDWR | os.O_CLOEXEC)
            self._stop.clear()
            self._reader = threading.Thread(target=self._read_events, daemon=True)
            self._reader.start()
        packed = CREATE2.pack(
            UHID_CREATE2,
            self.name.encode()[:127],
            b"gazehdr-harness/uhid",
            self.uniq.encode()[:63],
            len(self.descriptor),
            self.bus,
            self.vendor,
            self.product,
            self.version,
            0,
            self.descriptor,
        )
        self._write(packed)
        self.created = True

    def destroy(self) -> None:
        """UHID_DESTROY: the device is gone (readers of its hidraw node get an error)."""
        if self.created:
            self._write(struct.pack("<I", UHID_DESTROY))
            self.created = False

    def input(self, report: bytes) -> int:
        """UHID_INPUT2: one input report, as the device would send it on its interrupt IN
        endpoint (report id first when numbered). The guest monotonic time it was written."""
        if len(report) > DATA_MAX:
            raise ValueError(f"an input report holds at most {DATA_MAX} bytes")
        self._write(INPUT2.pack(UHID_INPUT2, len(report), report))
        return self.clock_ns()

    def close(self) -> None:
        """Unplug (closing /dev/uhid destroys the device too) and stop the reader."""
        self._stop.set()
        if self.fd is not None:
            fd, self.fd = self.fd, None
            self.created = False
            os.close(fd)
        if self._reader is not None:
            self._reader.join(timeout=2)

    def _write(self, packed: bytes) -> None:
        if self.fd is None:
            raise OSError(errno.EBADF, "the device is closed")
        with self._lock:
            os.write(self.fd, _event(packed))

    # the kernel's side

    def _read_events(self) -> None:
        while not self._stop.is_set():
            fd = self.fd
            if fd is None:
                return
            try:
                ready, _, _ = select.select([fd], [], [], 0.2)
                if not ready:
                    continue
                data = os.read(fd, EVENT_SIZE)
            except OSError:
                return
            if len(data) >= 4:
                self._handle(data)

    def _handle(self, data: bytes) -> None:
        (kind,) = struct.unpack_from("<I", data)
        now = self.clock_ns()
        if kind == UHID_GET_REPORT:
            _, rid, rnum, rtype = GET_REPORT.unpack_from(data)
            event = KernelEvent("get_report", now, rnum, rtype)
            event.answer = self._answer_get(rid, rnum, rtype)
        elif kind == UHID_SET_REPORT:
            _, rid, rnum, rtype, size = SET_REPORT.unpack_from(data)
            payload = data[SET_REPORT.size : SET_REPORT.size + size]
            event = KernelEvent("set_report", now, rnum, rtype, payload.hex())
            event.answer = self._answer_set(rid, rnum, rtype, payload)
        else:
            event = KernelEvent(EVENT_NAMES.get(kind, f"event {kind}"), now)
        self.events.append(event)

    def _answer_get(self, rid: int, rnum: int, rtype: int) -> str:
        f = self.features
        if rnum in f.silent:
            return "none"
        err, payload = 0, b""
        if rtype != UHID_FEATURE_REPORT:
            err = errno.EIO
        elif rnum in f.errors:
            err = f.errors[rnum]
        elif rnum in f.reports:
            payload = f.reports[rnum]
        else:
            err = errno.EIO  # a report the device does not have
        self._write(GET_REPORT_REPLY.pack(UHID_GET_REPORT_REPLY, rid, err, len(payload), payload))
        return errno.errorcode.get(err, str(err)) if err else "data"

    def _answer_set(self, rid: int, rnum: int, rtype: int, payload: bytes) -> str:
        f = self.features
        if rnum in f.silent:
            return "none"
        err = f.errors.get(rnum, 0) if rtype == UHID_FEATURE_REPORT else errno.EIO
        if not err and rnum in f.reports:
            f.reports[rnum] = payload
        self._write(SET_REPORT_REPLY.pack(UHID_SET_REPORT_REPLY, rid, err))
        return errno.errorcode.get(err, str(err)) if err else "ok"
