"""HID report descriptors and the reports they describe, from bytes alone (no device, no I/O).

Nothing here assumes where a field sits: report ids, offsets, sizes, counts, logical and physical
ranges, units, unit exponents and collections all come from the device's report descriptor.
`Descriptor(bytes)` parses one; `Descriptor.decode` turns a report as read from the device into
`Value`s in the usage's canonical unit (µm, µs, Hz; `usages.CANONICAL_UNITS`), and
`Descriptor.encode_feature` builds a feature report to send.

Descriptor parser: `hid-tools` (`hidtools.hid.ReportDescriptor`, by the Linux HID maintainers),
chosen over `hid-parser` (FFY00). Both install on Python 3.11 and are pure Python. Evaluated on
the descriptors in `tests/hid_device.py`:

- hid-parser 0.1.0 (its latest release) parses `tests/hid_device.py`'s tracker descriptor only
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
  64-bit Sensor Timestamp as 8 × 8 bits. hid-tools splits it into fields; they are joined here,
  up to MAX_REPORT_SIZE bits in all, as for one field: a report holding a wider one does not
  decode (ReportError; its number may not fit a float), and a descriptor that has one still
  opens, for a report gazehdr never decodes may hold it.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.hid.usages import CANONICAL_UNITS, HZ, UM, US

#: The kinds of report, as hid-tools names their main items.
INPUT, FEATURE, OUTPUT = "Input", "Feature", "Output"


class DescriptorError(InputError):
    """The report descriptor cannot be used: malformed, or no usable Tracking Data report."""


class ReportError(InputError):
    """A report does not match the descriptor (unknown report id, too short)."""


# --- descriptor -------------------------------------------------------------------------------


#: Limits of Linux's HID parser (drivers/hid/hid-core.c: HID_MAX_USAGES, and the largest
#: Report Size it accepts); a descriptor beyond them is refused there too. Without them a
#: 4-byte Report Count or Usage Minimum..Maximum makes hid-tools build billions of fields.
MAX_USAGES = 12288
MAX_REPORT_SIZE = 256


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
                if not 0 <= rdesc_item.value <= 0xFF:  # hid-tools asserts it
                    raise DescriptorError(
                        f"Collection type {rdesc_item.value:#x} does not fit in a byte"
                    )
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
                if not -8 <= self.glob.unit_exp <= 7:
                    raise DescriptorError(
                        f"Unit Exponent {self.glob.unit_exp} is outside -8..7 (HID 1.11, 6.2.2.7)"
                    )
            return

        # Main items: fix a signed Logical/Physical Maximum before hid-tools creates the fields,
        # then annotate the new fields with their collection path and their main item.
        def _main(self, rdesc_item: Any) -> None:
            g = self.glob
            self._concatenate_usages()  # what hid-tools does first; done twice, no change
            lo, hi = self.local.usage_min, self.local.usage_max
            if g.count > MAX_USAGES or (lo and hi and hi - lo >= MAX_USAGES):
                what = f"Report Count {g.count}" if g.count > MAX_USAGES else "Usage range"
                raise DescriptorError(f"{what} beyond {MAX_USAGES} usages in one main item")
            if g.item_size > MAX_REPORT_SIZE:
                raise DescriptorError(f"Report Size {g.item_size} bits; at most {MAX_REPORT_SIZE}")
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
    canonical unit (µm, µs, Hz; see `usages.CANONICAL_UNITS`) after the physical range, Unit
    and Unit Exponent of the descriptor; None when the raw value lies outside the logical range
    (HID's "no data" / null state).
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
    if canonical == UM:
        to = _length_to_um(unit, ht)
    elif canonical == US:
        to = 1e6 if units == {ht.Unit.SECONDS: 1} else None
    elif canonical == HZ:
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
            if f.size == 0 and f.usage and not f.is_array:
                raise DescriptorError(
                    f"usage 0x{f.usage:08x} has Report Size 0: a value of no bits"
                )
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
                if f.size * len(item.fields) > MAX_REPORT_SIZE:
                    raise ReportError(
                        f"{kind} report {rid}: usage 0x{f.usage:08x} is a value array of "
                        f"{len(item.fields)} × {f.size} bits; at most {MAX_REPORT_SIZE} bits "
                        "are read as one number"
                    )
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
                value = values[f.usage]
                bits = (
                    range(-(1 << (f.size - 1)), 1 << (f.size - 1))
                    if f.logical_min < 0
                    else range(1 << f.size)
                )
                if not (f.logical_min <= value <= f.logical_max and value in bits):
                    raise ReportError(
                        f"feature report {report_id}: usage 0x{f.usage:08x} cannot hold {value} "
                        f"(logical range {f.logical_min}..{f.logical_max}, {f.size} bits)"
                    )
                f.fill_values(buf, [value])
        return buf
