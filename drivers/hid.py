"""Gaze from eye trackers that implement USB HID usage page 0x12, Eye and Head Trackers.

The usage page (HID Usage Tables, "Eye and Head Trackers", from HUTRR74) defines an Eye Tracker
application collection with a Tracking Data input report: Sensor Timestamp (0x20, µs on the
tracker's clock) and a Gaze Point physical collection (0x24) holding Position X / Position Y
(0x21 / 0x22, µm from the top-left corner of the calibrated screen); and feature reports:
Capabilities (0x11), Configuration (0x12: Calibrated Screen Width / Height 0x204 / 0x205, µm),
Status (0x13: Sampling Frequency 0x300, Configuration Status 0x301) and Control (0x14: Device Mode
Request 0x400, a bit mask, 1 = gaze point, 2 = eye position, 4 = head position). Nothing here
assumes where a field sits: report ids, offsets, sizes, counts, logical and physical ranges,
units, unit exponents and collections all come from the device's report descriptor.

Descriptor parser: `hid-tools` (`hidtools.hid.ReportDescriptor`, by the Linux HID maintainers),
chosen over `hid-parser` (FFY00). Both install on Python 3.11 and are pure Python. Evaluated on
the descriptors in `tests/test_hid.py`:

- hid-parser 0.1.0 (its latest release) parses `tests/test_hid.py`'s tracker descriptor only
  with the warning "Data specifies a unit or unit exponent, but we don't support those yet" (it
  keeps neither), and then cannot decode its input report at all: `parse_input_report` raises
  ValueError "Sub-data not available", because it decodes through its own table of usage types,
  which has no page 0x12. Beyond that: values are decoded unsigned (`int.from_bytes` without
  sign), no collections are kept and results are keyed by usage alone (Position X inside Gaze
  Point and inside Left Eye Position would overwrite each other), and Push raises
  NotImplementedError ("Unsupported global tag"), so the Microsoft-style descriptor there fails.
- hid-tools 0.12 keeps per field: report id, bit offset, size, count, logical and physical
  ranges, Unit (decoded by `HidUnit`), Unit Exponent, the enclosing application / physical /
  logical collection usages, and the main item flags; it decodes input reports
  (`HidField.get_values`, signed when the logical minimum is negative) and encodes them
  (`HidField.fill_values`, used here for the Device Mode feature report). It keeps
  Constant-flagged fields that carry usages as real fields (trackers such as Microsoft's
  reference eye-tracker driver, MSREnable/GazeHid, flag their Capabilities and Configuration
  values Const,Var,Abs, its `HID_FEATURE_STATIC_VALUE`); only Constant items without usages
  become padding. It is maintained by the Linux HID maintainers.
  Its licence is GPL-2.0 (the package metadata says GPL-2.0-only): gazehdr imports it only in
  this module, and only the `daemon` extra installs it.

Work-arounds for hid-tools 0.12, all in `_descriptor_class` (a subclass that hooks its per-item
`_parse_item`; nothing is re-parsed here):

- End Collection does not restore the enclosing collection's usages: a field after a closed
  Gaze Point would still claim to be inside it. The subclass keeps the collection stack and gives
  each field `path`, the usages of all enclosing collections, outermost first.
- Push copies Unit Exponent into Unit (`self.unit = other.unit_exp`): the subclass pushes a
  plain copy of the globals instead.
- Logical and Physical Maximum are never read as signed: when the minimum is negative, a
  maximum with its sign bit set is reinterpreted as two's complement (as the kernel does).
- Unit Exponent is read as a 4-bit two's-complement nibble (HID 1.11, 6.2.2.7); a descriptor that
  writes it as a whole signed byte (0xFC for −4) is also accepted.
- A value array (Report Count > 1 under one usage, in one main item) reads as one little-endian
  number, as Windows' `HidP_GetUsageValueArray` does: the Microsoft reference driver sends its
  64-bit Sensor Timestamp as 8 × 8 bits. hid-tools splits it into fields; they are joined here.

hidapi backend, on purpose: the PyPI `hidapi` package builds two modules. On Linux `hidraw` uses
the kernel's hidraw interface: it works with the kernel HID driver bound (nothing is detached,
the tracker keeps working for everything else), needs no root once a udev rule grants access to
`/dev/hidraw*` (see `list_devices`), reports `usage_page` per top-level collection in
`enumerate()` (read from sysfs, so even without access), and gives the report descriptor
(`get_report_descriptor`: checked present in hidapi 0.15.0; for a wrapper without it the
descriptor is read from sysfs). The `hid` module is built on libusb on Linux: it detaches the
kernel driver from the interface and needs write access to the USB device node. On macOS and
Windows the `hid` module uses the native backend, so it is the one used there.

Unplug shows as an `OSError` from `read`: the source closes the device and reconnects with
exponential back-off; samples already yielded stay yielded (the generator never buffers), and a
note with the count so far is logged.

Timestamps are host `time.monotonic_ns()`, the clock of every live source (the daemon's clock
echo maps it to the server's). The Sensor Timestamp (a counter narrower than 64 bits unwrapped)
gives the spacing; `TrackerClock` places it on the host clock. Each report is read at
host = sensor + offset + latency with latency ≥ 0 (the tracker's work after stamping, USB
polling, the OS), so the smallest host − sensor over the last `clock_window_s` (2 s) of reads is
the offset plus the least latency in that window: a sample lands late by that least latency,
typically well under a millisecond on USB HID at 1 kHz polling, and the spacing of samples is the
tracker's own except where the window's minimum changes. The window, rather than all time,
follows the drift between the two crystals: a tracker running fast is followed at once, one
running slow by r lags by at most r · window (0.2 ms at 100 ppm). The estimate restarts after a
re-plug and when the tracker's clock goes back (it rebooted); times are kept strictly increasing
and never later than the read. A tracker without a Sensor Timestamp gets the host time of the read.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import functools
import logging
import math
import os
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from gazehdr.drivers.samples import GazeSample, ScreenGeometry
from gazehdr.drivers.sources import SourceInfo

log = logging.getLogger(__name__)

#: The Eye and Head Trackers usage page.
USAGE_PAGE = 0x12

#: How far (log ratio, ≈ 3 %) the calibrated screen's shape may differ from the shape of the
#: screen in pixels before we warn: beyond rounding of whole mm and pixels, a wrong pixel size.
_ASPECT_TOLERANCE = 0.03


def _shape_differs(size_um: tuple[float, float], size_px: tuple[int, int]) -> bool:
    """Whether a screen of `size_um` cannot be one of `size_px` square pixels."""
    return abs(math.log(size_um[0] / size_um[1] * size_px[1] / size_px[0])) > _ASPECT_TOLERANCE


def usage(usage_id: int) -> int:
    """A usage of the Eye and Head Trackers page as a 32-bit extended usage (page << 16 | id)."""
    return USAGE_PAGE << 16 | usage_id


EYE_TRACKER = usage(0x01)
HEAD_TRACKER = usage(0x02)
TRACKING_DATA = usage(0x10)
CAPABILITIES = usage(0x11)
CONFIGURATION = usage(0x12)
STATUS = usage(0x13)
CONTROL = usage(0x14)
SENSOR_TIMESTAMP = usage(0x20)
POSITION_X = usage(0x21)
POSITION_Y = usage(0x22)
POSITION_Z = usage(0x23)
GAZE_POINT = usage(0x24)
LEFT_EYE_POSITION = usage(0x25)
RIGHT_EYE_POSITION = usage(0x26)
HEAD_POSITION = usage(0x27)
TRACKER_QUALITY = usage(0x100)
MINIMUM_TRACKING_DISTANCE = usage(0x101)
OPTIMUM_TRACKING_DISTANCE = usage(0x102)
MAXIMUM_TRACKING_DISTANCE = usage(0x103)
MAXIMUM_SCREEN_PLANE_WIDTH = usage(0x104)
MAXIMUM_SCREEN_PLANE_HEIGHT = usage(0x105)
CALIBRATED_SCREEN_WIDTH = usage(0x204)
CALIBRATED_SCREEN_HEIGHT = usage(0x205)
SAMPLING_FREQUENCY = usage(0x300)
CONFIGURATION_STATUS = usage(0x301)
DEVICE_MODE_REQUEST = usage(0x400)

#: Device Mode Request bits.
MODE_GAZE_POINT = 1
MODE_EYE_POSITION = 2
MODE_HEAD_POSITION = 4

#: Canonical unit of each usage (what the usage table says it reports); values are converted to
#: it from the descriptor's Unit and Unit Exponent. Usages not listed are dimensionless.
_UM, _US, _HZ = "µm", "µs", "Hz"
CANONICAL_UNITS: dict[int, str] = {
    SENSOR_TIMESTAMP: _US,
    POSITION_X: _UM,
    POSITION_Y: _UM,
    POSITION_Z: _UM,
    MINIMUM_TRACKING_DISTANCE: _UM,
    OPTIMUM_TRACKING_DISTANCE: _UM,
    MAXIMUM_TRACKING_DISTANCE: _UM,
    MAXIMUM_SCREEN_PLANE_WIDTH: _UM,
    MAXIMUM_SCREEN_PLANE_HEIGHT: _UM,
    CALIBRATED_SCREEN_WIDTH: _UM,
    CALIBRATED_SCREEN_HEIGHT: _UM,
    SAMPLING_FREQUENCY: _HZ,
}

INPUT, FEATURE, OUTPUT = "Input", "Feature", "Output"


class DescriptorError(ValueError):
    """The report descriptor cannot be used: malformed, or no usable Tracking Data report."""


class ReportError(ValueError):
    """A report does not match the descriptor (unknown report id, too short)."""


# --- descriptor -------------------------------------------------------------------------------


def _twos(value: int, bits: int) -> int:
    return value - (1 << bits) if value >> (bits - 1) & 1 else value


@functools.cache
def _descriptor_class() -> type:
    """hid-tools' ReportDescriptor with the work-arounds listed in the module docstring."""
    try:
        from hidtools import hid as ht
    except ModuleNotFoundError as e:  # pragma: no cover - depends on the installation
        raise ModuleNotFoundError(
            "the HID tracker source needs hid-tools: install gazehdr[daemon]", name=e.name
        ) from None

    class TrackedDescriptor(ht.ReportDescriptor):  # type: ignore[misc]
        def __init__(self, items: list[Any]) -> None:
            self._path: list[int] = []
            self._saved: list[tuple[Any, Any, Any]] = []
            super().__init__(items)
            del self._path, self._saved

        def _report_pool(self, kind: str) -> dict[int, Any]:
            return {INPUT: self.input_reports, FEATURE: self.feature_reports}.get(
                kind, self.output_reports
            )

        def _parse_item(self, rdesc_item: Any) -> None:
            name = rdesc_item.item
            if name in (INPUT, FEATURE, OUTPUT):
                self._main(rdesc_item)
                return
            if name == "Push":
                rdesc_item.usage_page = self.glob.usage_page
                self.global_stack.append(self.glob)
                self.glob = copy.copy(self.glob)
                return
            if name == "Collection":
                self._concatenate_usages()
                full = self.local.usages[-1] if self.local.usages else 0
                self._saved.append((self.glob.application, self.glob.physical, self.glob.logical))
                super()._parse_item(rdesc_item)
                self._path.append(full)
                return
            if name == "End Collection":
                if not self._path:
                    raise DescriptorError("End Collection without a Collection")
                self._path.pop()
                self.glob.application, self.glob.physical, self.glob.logical = self._saved.pop()
                return
            super()._parse_item(rdesc_item)
            # The payload width of the maxima travels with the globals (Push/Pop included).
            if name == "Logical Maximum":
                self.glob.lmax_bytes = max(1, len(rdesc_item.raw_value))
            elif name == "Physical Maximum":
                self.glob.pmax_bytes = max(1, len(rdesc_item.raw_value))
            elif name == "Unit Exponent" and not -8 <= self.glob.unit_exp <= 7:
                self.glob.unit_exp = int.from_bytes(rdesc_item.raw_value, "little", signed=True)
            return

        # Main items: fix a signed Logical/Physical Maximum before hid-tools creates the fields,
        # then annotate the new fields with their collection path and their main item.
        def _main(self, rdesc_item: Any) -> None:
            g = self.glob
            bits = 8 * getattr(g, "lmax_bytes", 1)
            if g.logical_min < 0 and g.logical_max > 0 and g.logical_max >> (bits - 1) & 1:
                g.logical_max = _twos(g.logical_max, bits)
            bits = 8 * getattr(g, "pmax_bytes", 1)
            if g.physical_min < 0 and g.physical_max > 0 and g.physical_max >> (bits - 1) & 1:
                g.physical_max = _twos(g.physical_max, bits)
            pool = self._report_pool(rdesc_item.item)
            report = pool.get(self.local.report_ID)
            before = len(report.fields) if report is not None else 0
            ht.ReportDescriptor._parse_item(self, rdesc_item)
            for f in pool[self.local.report_ID].fields[before:]:
                f.path = tuple(self._path)
                f.main_item = rdesc_item.index_in_report

    return TrackedDescriptor


@dataclass(frozen=True)
class Value:
    """One decoded value of a report.

    `raw` is the logical value as sent (joined, for a value array). `value` is in the usage's
    canonical unit (µm, µs, Hz; see `CANONICAL_UNITS`) after the physical range, Unit and Unit
    Exponent of the descriptor; None when the raw value lies outside the logical range (HID's
    "no data" / null state).
    """

    usage: int
    path: tuple[int, ...]
    raw: int
    value: float | None
    bits: int
    constant: bool

    def inside(self, collection: int) -> bool:
        return collection in self.path


class DecodedReport:
    """The values of one report, in descriptor order, with lookups by usage and collection."""

    def __init__(self, report_id: int | None, values: list[Value]) -> None:
        self.report_id = report_id
        self.values = values

    def find(self, usage_: int, inside: int | None = None) -> Value | None:
        for v in self.values:
            if v.usage == usage_ and (inside is None or v.inside(inside)):
                return v
        return None

    def __repr__(self) -> str:
        return f"DecodedReport(report_id={self.report_id}, values={self.values!r})"


def _length_to_um(unit: Any, ht: Any) -> float | None:
    factors = {ht.Unit.CENTIMETER: 1e4, ht.Unit.INCH: 25400.0}
    if len(unit.units) == 1:
        ((u, e),) = unit.units.items()
        if u in factors and e == 1:
            return factors[u]
    return None


def _field_scale(f: Any, ht: Any) -> tuple[float, float]:
    """(offset, factor) taking a logical value to the usage's canonical unit: v = off + f·l."""
    lmin, lmax = f.logical_min, f.logical_max
    pmin, pmax = f.physical_min, f.physical_max
    if (pmin == 0 and pmax == 0) or lmax == lmin:
        offset, factor = 0.0, 1.0
    else:
        factor = (pmax - pmin) / (lmax - lmin)
        offset = pmin - lmin * factor
    canonical = CANONICAL_UNITS.get(f.usage)
    try:
        unit = ht.HidUnit.from_value(f.unit) if f.unit else None
    except ValueError:
        raise DescriptorError(f"usage 0x{f.usage:08x}: unknown unit 0x{f.unit:x}") from None
    if unit is None:
        # No Unit item: the usage table's own unit (µm, µs, Hz) is what the value is in.
        return offset, factor
    scale = 10.0**f.unit_exp
    units = unit.units
    if canonical == _UM:
        to = _length_to_um(unit, ht)
    elif canonical == _US:
        to = 1e6 if units == {ht.Unit.SECONDS: 1} else None
    elif canonical == _HZ:
        to = 1.0 if units == {ht.Unit.SECONDS: -1} else None
    else:
        to = 1.0
    if to is None:
        raise DescriptorError(
            f"usage 0x{f.usage:08x} ({f.usage_name}) has unit {unit}, not convertible to "
            f"{canonical}"
        )
    return offset * scale * to, factor * scale * to


@dataclass
class _Item:
    """A field or a value array as decoded here: one or more hid-tools fields, joined."""

    fields: list[Any]
    offset: float
    factor: float

    @property
    def head(self) -> Any:
        return self.fields[0]


class Descriptor:
    """A parsed report descriptor (hid-tools underneath) and the decoder of its reports."""

    def __init__(self, data: bytes | Sequence[int]) -> None:
        from hidtools import hid as ht

        self.data = bytes(data)
        try:
            items = ht._HidRDescItem.from_bytes(list(self.data))
            self._rd = _descriptor_class()(items)
        except DescriptorError:
            raise
        except (KeyError, IndexError, ValueError, AttributeError, ht.ParseError) as e:
            raise DescriptorError(f"malformed report descriptor: {e}") from None
        self.numbered = any(
            rid >= 0
            for pool in (self._rd.input_reports, self._rd.feature_reports, self._rd.output_reports)
            for rid in pool
        )
        self._items: dict[tuple[str, int | None], list[_Item]] = {}
        for kind, pool in (
            (INPUT, self._rd.input_reports),
            (FEATURE, self._rd.feature_reports),
            (OUTPUT, self._rd.output_reports),
        ):
            for rid, report in pool.items():
                self._items[(kind, None if rid < 0 else rid)] = self._group(report.fields, ht)

    @staticmethod
    def _group(fields: list[Any], ht: Any) -> list[_Item]:
        items: list[_Item] = []
        for f in fields:
            prev = items[-1].head if items else None
            if (
                prev is not None
                and not f.is_array
                and not prev.is_array
                and f.usage
                and f.usage == prev.usage
                and f.main_item == prev.main_item
                and f.size == prev.size
            ):
                items[-1].fields.append(f)
                continue
            offset, factor = (0.0, 1.0) if f.is_array or not f.usage else _field_scale(f, ht)
            items.append(_Item([f], offset, factor))
        return items

    def report_ids(self, kind: str) -> list[int | None]:
        return [rid for (k, rid) in self._items if k == kind]

    def report_bytes(self, kind: str, report_id: int | None) -> int:
        """Length of a report in bytes, the report id byte included when reports are numbered."""
        items = self._items.get((kind, report_id))
        if items is None:
            raise ReportError(f"no {kind} report with id {report_id}")
        bits = max((f.start + f.size * f.count for i in items for f in i.fields), default=0)
        return max((bits + 7) // 8, 1 if report_id is not None else 0)

    def find(self, kind: str, usage_: int, inside: int | None = None) -> tuple[int | None, Any]:
        """(report id, first hid-tools field) of a usage, optionally inside a collection."""
        for (k, rid), items in self._items.items():
            if k != kind:
                continue
            for item in items:
                f = item.head
                if not f.is_array and f.usage == usage_ and (inside is None or inside in f.path):
                    return rid, f
        raise KeyError(f"no {kind} usage 0x{usage_:08x}")

    def has(self, kind: str, usage_: int, inside: int | None = None) -> bool:
        try:
            self.find(kind, usage_, inside)
        except KeyError:
            return False
        return True

    def decode(self, kind: str, report: bytes | Sequence[int]) -> DecodedReport:
        """Decode one report as read from the device (report id first when numbered)."""
        data = list(report)
        rid = (data[0] if data else None) if self.numbered else None
        items = self._items.get((kind, rid))
        if items is None:
            raise ReportError(f"no {kind} report with id {rid}")
        need = self.report_bytes(kind, rid)
        if len(data) < need:
            raise ReportError(f"{kind} report {rid}: {len(data)} bytes, the descriptor says {need}")
        values: list[Value] = []
        for item in items:
            f = item.head
            if f.is_array or not f.usage:
                continue  # padding, or an array of selectors (none on this usage page)
            if len(item.fields) == 1:
                raw = int(f.get_values(data)[0])
                in_range = f.logical_min <= raw <= f.logical_max
                bits = f.size
            else:
                raw = 0
                for i, part in enumerate(item.fields):
                    chunk = int(part.get_values(data)[0]) & ((1 << part.size) - 1)
                    raw |= chunk << (i * part.size)
                in_range = True
                bits = f.size * len(item.fields)
            value = item.offset + item.factor * raw if in_range else None
            values.append(Value(f.usage, f.path, raw, value, bits, f.is_const))
        return DecodedReport(rid, values)

    def encode_feature(
        self, report_id: int | None, values: dict[int, int], base: Any = None
    ) -> list[int]:
        """A feature report with the given usages set (others from `base`, else zero)."""
        size = self.report_bytes(FEATURE, report_id)
        buf = list(base)[:size] if base is not None else []
        buf += [0] * (size - len(buf))
        if report_id is not None:
            buf[0] = report_id
        for item in self._items[(FEATURE, report_id)]:
            f = item.head
            if not f.is_array and f.usage in values:
                f.fill_values(buf, [values[f.usage]])
        return buf


# --- tracker ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrackerInfo:
    """What the tracker told us when it was opened (for hello messages and log headers)."""

    path: str
    vendor_id: int
    product_id: int
    manufacturer: str
    product: str
    serial: str
    calibrated_screen_um: tuple[float, float] | None
    sampling_hz: float | None
    configuration_status: int | None
    device_mode: int | None
    features: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "kind": "hid",
            "path": self.path,
            "vendor_id": f"{self.vendor_id:04x}",
            "product_id": f"{self.product_id:04x}",
            "manufacturer": self.manufacturer,
            "product": self.product,
            "serial": self.serial,
            "calibrated_screen_um": list(self.calibrated_screen_um)
            if self.calibrated_screen_um
            else None,
            "sampling_hz": self.sampling_hz,
            "configuration_status": self.configuration_status,
            "device_mode": self.device_mode,
        }


def _default_backend() -> Any:
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


def _path_str(path: bytes | str) -> str:
    return path.decode(errors="replace") if isinstance(path, bytes) else str(path)


def _read_descriptor(dev: Any, path: bytes | str) -> bytes:
    getter = getattr(dev, "get_report_descriptor", None)
    if getter is not None:
        return bytes(getter())
    # hidapi before the wrapper had get_report_descriptor: sysfs has it (world-readable).
    name = os.path.basename(_path_str(path))
    sysfs = f"/sys/class/hidraw/{name}/device/report_descriptor"
    try:
        with open(sysfs, "rb") as fh:
            return fh.read()
    except OSError:
        raise DescriptorError(
            f"{_path_str(path)}: this hidapi cannot read report descriptors; install hidapi>=0.14"
        ) from None


def _tracking_report(desc: Descriptor) -> int | None:
    """The id of the input report with the gaze point; DescriptorError if there is none."""
    try:
        rid_x, _ = desc.find(INPUT, POSITION_X, inside=GAZE_POINT)
        rid_y, _ = desc.find(INPUT, POSITION_Y, inside=GAZE_POINT)
    except KeyError:
        raise DescriptorError(
            "no Tracking Data input report with Position X/Y inside a Gaze Point collection"
        ) from None
    if rid_x != rid_y:
        raise DescriptorError("Gaze Point Position X and Y are in different reports")
    return rid_x


class HidTracker:
    """One opened HID eye tracker: descriptor, feature reports, and decoding of gaze reports."""

    def __init__(
        self, dev: Any, entry: dict[str, Any], *, mode: int | None = None, set_mode: bool = True
    ) -> None:
        self.dev = dev
        path = entry["path"]
        self.descriptor = Descriptor(_read_descriptor(dev, path))
        self.report_id = _tracking_report(self.descriptor)
        # Room for the longest input report, so that no other report is cut short.
        self.read_size = max(
            self.descriptor.report_bytes(INPUT, rid) for rid in self.descriptor.report_ids(INPUT)
        )
        self.timestamped = self.descriptor.has(INPUT, SENSOR_TIMESTAMP)
        features: dict[int, float] = {}
        status: int | None = None
        for rid in self.descriptor.report_ids(FEATURE):
            decoded = self._get_feature(rid)
            if decoded is None:
                continue
            for v in decoded.values:
                if v.usage >> 16 == USAGE_PAGE and v.value is not None:
                    features.setdefault(v.usage, v.value)
        if CONFIGURATION_STATUS in features:
            status = int(features[CONFIGURATION_STATUS])
        w, h = features.get(CALIBRATED_SCREEN_WIDTH), features.get(CALIBRATED_SCREEN_HEIGHT)
        calibrated = (w, h) if w and h and w > 0 and h > 0 else None
        self.device_mode = self._set_mode(mode) if set_mode else None
        self.info = TrackerInfo(
            path=_path_str(path),
            vendor_id=int(entry.get("vendor_id") or 0),
            product_id=int(entry.get("product_id") or 0),
            manufacturer=entry.get("manufacturer_string") or "",
            product=entry.get("product_string") or "",
            serial=entry.get("serial_number") or "",
            calibrated_screen_um=calibrated,
            sampling_hz=features.get(SAMPLING_FREQUENCY),
            configuration_status=status,
            device_mode=self.device_mode,
            features={f"0x{u & 0xFFFF:04x}": v for u, v in features.items()},
        )

    def _get_feature(self, rid: int | None) -> DecodedReport | None:
        size = self.descriptor.report_bytes(FEATURE, rid)
        try:
            data = list(self.dev.get_feature_report(rid or 0, size + 1))
        except (OSError, ValueError) as e:
            log.warning("feature report %s: %s", rid, e)
            return None
        # hidraw returns the report id first; an unnumbered report may come with a 0 before it.
        if rid is None and len(data) == size + 1 and data[0] == 0:
            data = data[1:]
        elif rid is not None and (not data or data[0] != rid) and len(data) == size - 1:
            data = [rid, *data]
        try:
            return self.descriptor.decode(FEATURE, data)
        except ReportError as e:
            log.warning("feature report %s: %s", rid, e)
            return None

    def _set_mode(self, mode: int | None) -> int | None:
        try:
            rid, f = self.descriptor.find(FEATURE, DEVICE_MODE_REQUEST)
        except KeyError:
            return None
        if mode is None:
            mode = MODE_GAZE_POINT
            both_eyes = self.descriptor.has(INPUT, LEFT_EYE_POSITION) or self.descriptor.has(
                INPUT, POSITION_X, inside=LEFT_EYE_POSITION
            )
            if both_eyes and f.logical_max >= MODE_GAZE_POINT | MODE_EYE_POSITION:
                mode |= MODE_EYE_POSITION
        if not f.logical_min <= mode <= f.logical_max:
            raise ValueError(
                f"device mode {mode} is outside the tracker's range "
                f"{f.logical_min}..{f.logical_max}"
            )
        buf = self.descriptor.encode_feature(rid, {DEVICE_MODE_REQUEST: mode})
        self.dev.send_feature_report(buf)
        return mode

    def decode(self, report: Sequence[int]) -> DecodedReport | None:
        """The Tracking Data values of a report, or None for a report of another id."""
        data = list(report)
        if self.descriptor.numbered and (not data or data[0] != self.report_id):
            return None
        return self.descriptor.decode(INPUT, data)


# --- the source -------------------------------------------------------------------------------


class TrackerClock:
    """Tracker time → host time: the sensor gives the spacing, the window's minimum the placement.

    A report stamped `sensor_ns` and read at `host_ns` has host − sensor = offset + latency, the
    latency ≥ 0 and varying; the smallest difference over the last `window_ns` of host time is
    the offset plus the least latency in the window (a monotone deque of the candidates, O(1)
    amortised per report). A window rather than all time follows crystal drift. The mapped time
    is never later than its read: the current report is in the window.
    """

    def __init__(self, window_ns: int) -> None:
        if window_ns <= 0:
            raise ValueError(f"the clock window must be positive, got {window_ns} ns")
        self.window_ns = window_ns
        self._mins: deque[tuple[int, int]] = deque()  # (host ns, host − sensor), both increasing

    def restart(self) -> None:
        """Forget the offset (a re-plug, or a tracker clock that went back)."""
        self._mins.clear()

    def to_host(self, sensor_ns: int, host_ns: int) -> int:
        d = host_ns - sensor_ns
        mins = self._mins
        while mins and mins[-1][1] >= d:
            mins.pop()
        mins.append((host_ns, d))
        while mins[0][0] <= host_ns - self.window_ns:
            mins.popleft()
        return sensor_ns + mins[0][1]


class HidGazeSource:
    """Gaze samples from a HID eye tracker, reconnecting after an unplug.

    Iterate it (or call `samples()`) for `GazeSample`s: `t_ns` is host monotonic ns (`clock_ns`),
    spaced by the tracker's Sensor Timestamp and placed by the smallest host − sensor difference
    over the last `clock_window_s` of reads (late by the least latency in that window; see the
    module docstring and `TrackerClock`); x/y are screen pixels (µm over the calibrated screen
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
            raise ValueError(f"clock_window_s must be a positive number, got {clock_window_s}")
        self._tracker_clock = TrackerClock(round(clock_window_s * 1e9))
        self.tracker: HidTracker | None = None
        self.samples_yielded = 0
        self.reconnects = 0
        self._closed = False
        self._running = False
        self._last_raw: int | None = None
        self._wraps = 0
        self._last_sensor_ns: int | None = None
        self._last_t_ns: int | None = None
        if open_now:
            self.connect()

    @property
    def geometry(self) -> ScreenGeometry:
        """The screen: as given, or the tracker's (see the class docstring), then `screen`."""
        return self._geometry

    def _screen_geometry(self) -> ScreenGeometry:
        """`geometry` for the tracker now connected (made once per connection, not per sample)."""
        base = self._given_geometry
        if base is None:
            base = ScreenGeometry()
            calibrated = self.tracker_info.calibrated_screen_um if self.tracker_info else None
            if calibrated is not None:
                diagonal_m = math.hypot(*calibrated) / 1e6
                base = replace(base, screen_diagonal_m=diagonal_m)
        return replace(base, **self.screen)

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
            self._backend = _default_backend()
        return self._backend

    # connection

    def _pick(self) -> dict[str, Any]:
        entries = list(self.backend.enumerate())
        for e in entries:
            if self.path is not None:
                if _path_str(e["path"]) == _path_str(self.path):
                    return e
            elif e.get("usage_page") == USAGE_PAGE:
                return e
        wanted = _path_str(self.path) if self.path is not None else "usage page 0x12"
        raise OSError(f"no HID eye tracker found ({wanted}); see 'gazehdr devices'")

    def connect(self) -> HidTracker:
        """Open the tracker once (OSError when there is none or it cannot be opened)."""
        entry = self._pick()
        dev = self.backend.device()
        dev.open_path(entry["path"])
        try:
            tracker = HidTracker(dev, entry, mode=self.mode)
        except BaseException:
            dev.close()
            raise
        self.tracker, self.tracker_info = tracker, tracker.info
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
        elif _shape_differs(calibrated, (g.screen_width_px, g.screen_height_px)):
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
        delay = self.backoff_initial_s
        start = self._clock()
        while True:
            if self._closed:
                return None
            try:
                return self.connect()
            except OSError as e:
                waited = self._clock() - start
                if self.give_up_after_s is not None and waited >= self.give_up_after_s:
                    raise OSError(f"no HID eye tracker for {waited:.1f} s: {e}") from e
                log.info("HID tracker not available (%s); retrying in %.2f s", e, delay)
                self._sleep(delay)
                delay = min(delay * 2.0, self.backoff_max_s)

    def _drop(self) -> None:
        if self.tracker is not None:
            with contextlib.suppress(Exception):  # the device is gone; closing is best effort
                self.tracker.dev.close()
        self.tracker = None

    def close(self) -> None:
        """Stop: the running iteration ends at its next read (within `read_timeout_ms`) and
        closes the device itself, so no device is closed under a read in another thread."""
        self._closed = True
        if not self._running:
            self._drop()

    # conversion

    def _screen_um(self) -> tuple[float, float]:
        if self.tracker_info is not None and self.tracker_info.calibrated_screen_um is not None:
            return self.tracker_info.calibrated_screen_um
        g = self.geometry
        diag_px = math.hypot(g.screen_width_px, g.screen_height_px)
        um_per_px = g.screen_diagonal_m * 1e6 / diag_px
        return g.screen_width_px * um_per_px, g.screen_height_px * um_per_px

    def _sensor_ns(self, ts: Value) -> int:
        """The Sensor Timestamp in ns, unwrapped when the counter is narrower than 64 bits."""
        raw = ts.raw & ((1 << ts.bits) - 1) if ts.bits < 64 else ts.raw
        if (
            self._last_raw is not None
            and ts.bits < 64
            and self._last_raw - raw > (1 << (ts.bits - 1))
        ):
            self._wraps += 1
        self._last_raw = raw
        unwrapped = raw + (self._wraps << ts.bits) if ts.bits < 64 else raw
        scale = ts.value / ts.raw if ts.value is not None and ts.raw else 1.0
        return round(unwrapped * scale * 1000.0)

    def _time_ns(self, ts: Value | None, host_ns: int, reconnected: bool) -> int:
        """Host time of a report read at `host_ns`; strictly after the previous sample's."""
        if ts is None:
            t_ns = host_ns  # tracker without a Sensor Timestamp
        else:
            if reconnected:  # the tracker's clock may have restarted: anchor afresh
                self._last_raw, self._wraps, self._last_sensor_ns = None, 0, None
                self._tracker_clock.restart()
            sensor_ns = self._sensor_ns(ts)
            if self._last_sensor_ns is not None and sensor_ns < self._last_sensor_ns:
                log.warning(
                    "tracker clock went back by %d ns; re-anchoring it on the host clock",
                    self._last_sensor_ns - sensor_ns,
                )
                self._tracker_clock.restart()
            self._last_sensor_ns = sensor_ns
            t_ns = self._tracker_clock.to_host(sensor_ns, host_ns)
        if self._last_t_ns is not None and t_ns <= self._last_t_ns:
            t_ns = self._last_t_ns + 1  # a coarse host clock, or a repeated timestamp
        self._last_t_ns = t_ns
        return t_ns

    def sample(self, decoded: DecodedReport, host_ns: int, reconnected: bool = False) -> GazeSample:
        """The GazeSample of one decoded Tracking Data report, read at host time `host_ns`."""
        t_ns = self._time_ns(decoded.find(SENSOR_TIMESTAMP), host_ns, reconnected)
        x = decoded.find(POSITION_X, inside=GAZE_POINT)
        y = decoded.find(POSITION_Y, inside=GAZE_POINT)
        if x is None or y is None or x.value is None or y.value is None:
            return GazeSample(t_ns, math.nan, math.nan, valid=False)
        w_um, h_um = self._screen_um()
        px = x.value / w_um * self.geometry.screen_width_px
        py = y.value / h_um * self.geometry.screen_height_px
        return GazeSample(t_ns, px, py)

    # the stream

    def samples(self) -> Iterator[GazeSample]:
        if self._running:
            raise RuntimeError("this HID source is already being iterated")
        self._running = True
        try:
            yield from self._stream()
        finally:
            self._running = False
            self._drop()

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
                data = tracker.dev.read(tracker.read_size, self.read_timeout_ms)
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
                decoded = tracker.decode(data)
            except ReportError as e:
                log.warning("skipping a malformed report: %s", e)
                continue
            if decoded is None:
                continue
            s = self.sample(decoded, host_ns, reconnected)
            reconnected = False
            self.samples_yielded += 1
            yield s

    def __iter__(self) -> Iterator[GazeSample]:
        return self.samples()


#: The name `gazehdr.drivers.sources.open_source` imports.
HidSource = HidGazeSource


# --- `gazehdr devices` ------------------------------------------------------------------------


@dataclass(frozen=True)
class DeviceReport:
    """One HID interface found by enumeration, and whether gazehdr can use it."""

    path: str
    vendor_id: int
    product_id: int
    product: str
    usage_page: int
    usage: int
    usable: bool
    reason: str
    udev_rule: str | None = None
    info: TrackerInfo | None = None


def udev_rule(vendor_id: int, product_id: int) -> str:
    return (
        f'SUBSYSTEM=="hidraw", ATTRS{{idVendor}}=="{vendor_id:04x}", '
        f'ATTRS{{idProduct}}=="{product_id:04x}", MODE="0660", GROUP="plugdev"'
    )


def list_devices(
    backend: Any = None, *, access: Callable[[str, int], bool] = os.access
) -> list[DeviceReport]:
    """Every HID interface hidapi enumerates, with why it is usable or skipped.

    Eye trackers (usage page 0x12) are opened to read their descriptor and feature reports (their
    Device Mode is left alone). One that cannot be opened because of permissions gets the udev
    rule that grants access.
    """
    backend = backend or _default_backend()
    out: list[DeviceReport] = []
    for e in backend.enumerate():
        path = _path_str(e["path"])
        vid, pid = int(e.get("vendor_id") or 0), int(e.get("product_id") or 0)
        page, use = int(e.get("usage_page") or 0), int(e.get("usage") or 0)
        base = {
            "path": path,
            "vendor_id": vid,
            "product_id": pid,
            "product": e.get("product_string") or "",
            "usage_page": page,
            "usage": use,
        }
        if page != USAGE_PAGE:
            why = f"usage page 0x{page:04x} is not Eye and Head Trackers (0x0012)"
            out.append(DeviceReport(**base, usable=False, reason=why))
            continue
        dev = backend.device()
        try:
            dev.open_path(e["path"])
        except OSError as err:
            if os.path.exists(path) and not access(path, os.R_OK | os.W_OK):
                why = f"permission denied on {path}"
                out.append(
                    DeviceReport(**base, usable=False, reason=why, udev_rule=udev_rule(vid, pid))
                )
            else:
                out.append(DeviceReport(**base, usable=False, reason=f"cannot open: {err}"))
            continue
        try:
            tracker = HidTracker(dev, e, set_mode=False)
        except (DescriptorError, OSError, ValueError) as err:
            out.append(DeviceReport(**base, usable=False, reason=str(err)))
            continue
        finally:
            dev.close()
        info = tracker.info
        parts = ["eye tracker"]
        if info.calibrated_screen_um:
            w, h = info.calibrated_screen_um
            parts.append(f"calibrated screen {w / 1000:.1f} × {h / 1000:.1f} mm")
        else:
            parts.append("no calibrated screen size (the screen geometry is used)")
        if info.sampling_hz:
            parts.append(f"{info.sampling_hz:g} Hz")
        out.append(DeviceReport(**base, usable=True, reason=", ".join(parts), info=info))
    return out


def devices_main(argv: Sequence[str] | None = None, *, backend: Any = None) -> int:
    """`gazehdr devices`: list HID interfaces; 0 when an eye tracker is usable, else 1."""
    parser = argparse.ArgumentParser(
        prog="gazehdr devices",
        description="List HID devices and whether each is a usable eye tracker (usage page "
        "0x12); for one that cannot be opened, print the udev rule that grants access.",
    )
    parser.add_argument(
        "--trackers-only", action="store_true", help="list only usage page 0x12 devices"
    )
    args = parser.parse_args(list(argv) if argv is not None else None)
    try:
        found = list_devices(backend)
    except ModuleNotFoundError as e:
        print(f"gazehdr devices: {e}", file=sys.stderr)
        return 2
    shown = [d for d in found if d.usage_page == USAGE_PAGE or not args.trackers_only]
    if not shown:
        print("no HID devices found" if not found else "no HID eye trackers found")
    rules: list[str] = []
    for d in shown:
        mark = "ok  " if d.usable else "skip"
        name = f" {d.product}" if d.product else ""
        print(f"{mark} {d.path} {d.vendor_id:04x}:{d.product_id:04x}{name}: {d.reason}")
        if d.udev_rule and d.udev_rule not in rules:
            rules.append(d.udev_rule)
    if rules:
        print(
            "\nTo use the tracker without root, add to /etc/udev/rules.d/70-gazehdr.rules:\n"
            + "\n".join(f"  {r}" for r in rules)
            + "\nthen run 'sudo udevadm control --reload-rules && sudo udevadm trigger', be in "
            "the plugdev group, and re-plug the tracker."
        )
    return 0 if any(d.usable for d in found) else 1
