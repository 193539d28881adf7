"""What an eye tracker's descriptor and feature reports say, and its gaze in screen pixels.

Pure: everything here takes a `Descriptor`, reports as hidapi returns them (bytes) or decoded
ones, and returns values; opening the device, reading and sending reports is
`gazehdr.drivers.hid.source`, which calls these in that order: `TrackerReports` from the
descriptor, `TrackerReports.decode_feature` for each feature report, `TrackerReports.mode_request`
for the Device Mode to send, `TrackerInfo.of` for what the tracker said, then
`TrackerReports.decode` and `gaze_sample` for each report read.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.hid.descriptor import (
    FEATURE,
    INPUT,
    DecodedReport,
    Descriptor,
    DescriptorError,
)
from gazehdr.drivers.hid.usages import (
    CALIBRATED_SCREEN_HEIGHT,
    CALIBRATED_SCREEN_WIDTH,
    CONFIGURATION_STATUS,
    DEVICE_MODE_REQUEST,
    GAZE_POINT,
    LEFT_EYE_POSITION,
    MODE_EYE_POSITION,
    MODE_GAZE_POINT,
    POSITION_X,
    POSITION_Y,
    SAMPLING_FREQUENCY,
    USAGE_PAGE,
)
from gazehdr.drivers.samples import GazeSample, ScreenGeometry

#: How far (log ratio, ≈ 3 %) the calibrated screen's shape may differ from the shape of the
#: screen in pixels before we warn: beyond rounding of whole mm and pixels, a wrong pixel size.
_ASPECT_TOLERANCE = 0.03


def shape_differs(size_um: tuple[float, float], size_px: tuple[int, int]) -> bool:
    """Whether a screen of `size_um` cannot be one of `size_px` square pixels."""
    return abs(math.log(size_um[0] / size_um[1] * size_px[1] / size_px[0])) > _ASPECT_TOLERANCE


def path_str(path: bytes | str) -> str:
    """A hidapi device path (bytes on Linux) as text."""
    return path.decode(errors="replace") if isinstance(path, bytes) else str(path)


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

    @classmethod
    def of(
        cls,
        entry: Mapping[str, Any],
        features: Iterable[DecodedReport],
        device_mode: int | None,
    ) -> TrackerInfo:
        """From hidapi's enumeration `entry` and the decoded feature reports: the first value of
        each usage of page 0x12 counts; a calibrated screen needs both sides positive."""
        values: dict[int, float] = {}
        for decoded in features:
            for v in decoded.values:
                if v.usage >> 16 == USAGE_PAGE and v.value is not None:
                    values.setdefault(v.usage, v.value)
        status = int(values[CONFIGURATION_STATUS]) if CONFIGURATION_STATUS in values else None
        w, h = values.get(CALIBRATED_SCREEN_WIDTH), values.get(CALIBRATED_SCREEN_HEIGHT)
        return cls(
            path=path_str(entry["path"]),
            vendor_id=int(entry.get("vendor_id") or 0),
            product_id=int(entry.get("product_id") or 0),
            manufacturer=entry.get("manufacturer_string") or "",
            product=entry.get("product_string") or "",
            serial=entry.get("serial_number") or "",
            calibrated_screen_um=(w, h) if w and h and w > 0 and h > 0 else None,
            sampling_hz=values.get(SAMPLING_FREQUENCY),
            configuration_status=status,
            device_mode=device_mode,
            features={f"0x{u & 0xFFFF:04x}": v for u, v in values.items()},
        )

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


class TrackerReports:
    """An eye tracker's reports as its descriptor lays them out.

    `report_id` is the input report with the gaze point (DescriptorError when there is none),
    `read_size` the room a read needs for the longest input report (so that no other report is
    cut short), `feature_ids` the feature reports to ask for.
    """

    def __init__(self, descriptor: Descriptor) -> None:
        self.descriptor = descriptor
        try:
            rid_x, _ = descriptor.find(INPUT, POSITION_X, inside=GAZE_POINT)
            rid_y, _ = descriptor.find(INPUT, POSITION_Y, inside=GAZE_POINT)
        except KeyError:
            raise DescriptorError(
                "no Tracking Data input report with Position X/Y inside a Gaze Point collection"
            ) from None
        if rid_x != rid_y:
            raise DescriptorError("Gaze Point Position X and Y are in different reports")
        self.report_id = rid_x
        self.read_size = max(
            descriptor.report_bytes(INPUT, rid) for rid in descriptor.report_ids(INPUT)
        )
        self.feature_ids = descriptor.report_ids(FEATURE)

    def feature_size(self, report_id: int | None) -> int:
        return self.descriptor.report_bytes(FEATURE, report_id)

    def decode_feature(self, report_id: int | None, data: Sequence[int]) -> DecodedReport:
        """A feature report as hidapi returns it (ReportError when it does not fit): hidraw
        gives the report id first, an unnumbered report may come with a 0 before it, and a
        numbered one without its id."""
        size = self.feature_size(report_id)
        data = list(data)
        if report_id is None and len(data) == size + 1 and data[0] == 0:
            data = data[1:]
        elif report_id is not None and (not data or data[0] != report_id) and len(data) == size - 1:
            data = [report_id, *data]
        return self.descriptor.decode(FEATURE, data)

    def mode_request(self, mode: int | None) -> tuple[int, list[int]] | None:
        """(mode, the feature report that requests it), or None for a tracker without a Device
        Mode Request. `mode` None: gaze point, plus eye position where the tracker reports it
        and takes it; ValueError for a mode outside the tracker's range."""
        d = self.descriptor
        try:
            rid, f = d.find(FEATURE, DEVICE_MODE_REQUEST)
        except KeyError:
            return None
        if mode is None:
            mode = MODE_GAZE_POINT
            both_eyes = d.has(INPUT, LEFT_EYE_POSITION) or d.has(
                INPUT, POSITION_X, inside=LEFT_EYE_POSITION
            )
            if both_eyes and f.logical_max >= MODE_GAZE_POINT | MODE_EYE_POSITION:
                mode |= MODE_EYE_POSITION
        if not f.logical_min <= mode <= f.logical_max:
            raise InputError(
                f"device mode {mode} is outside the tracker's range "
                f"{f.logical_min}..{f.logical_max}"
            )
        return mode, d.encode_feature(rid, {DEVICE_MODE_REQUEST: mode})

    def decode(self, report: Sequence[int]) -> DecodedReport | None:
        """The Tracking Data values of a report, or None for a report of another id."""
        data = list(report)
        if self.descriptor.numbered and (not data or data[0] != self.report_id):
            return None
        return self.descriptor.decode(INPUT, data)


def screen_geometry(
    given: ScreenGeometry | None,
    calibrated_um: tuple[float, float] | None,
    screen: Mapping[str, float],
) -> ScreenGeometry:
    """The screen gaze is mapped onto: `given` as it is, else the defaults with the diagonal of
    the calibrated screen where the tracker reports one (HID says nothing of pixels or viewing
    distance); then the `screen` fields (ValueError for a bad one)."""
    base = given
    if base is None:
        base = ScreenGeometry()
        if calibrated_um is not None:
            base = replace(base, screen_diagonal_m=math.hypot(*calibrated_um) / 1e6)
    return replace(base, **screen)


def gaze_sample(
    decoded: DecodedReport,
    t_ns: int,
    geometry: ScreenGeometry,
    calibrated_um: tuple[float, float] | None,
) -> GazeSample:
    """The sample of a decoded Tracking Data report at `t_ns`: the Gaze Point in µm over the
    calibrated screen (else the size `geometry` gives), times its size in pixels; invalid when
    either coordinate is missing or has no data."""
    x = decoded.find(POSITION_X, inside=GAZE_POINT)
    y = decoded.find(POSITION_Y, inside=GAZE_POINT)
    if x is None or y is None or x.value is None or y.value is None:
        return GazeSample(t_ns, math.nan, math.nan, valid=False)
    w_px, h_px = geometry.screen_width_px, geometry.screen_height_px
    if calibrated_um is None:
        um_per_px = geometry.screen_diagonal_m * 1e6 / math.hypot(w_px, h_px)
        calibrated_um = w_px * um_per_px, h_px * um_per_px
    w_um, h_um = calibrated_um
    return GazeSample(t_ns, x.value / w_um * w_px, y.value / h_um * h_px)
