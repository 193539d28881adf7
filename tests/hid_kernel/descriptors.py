"""Report descriptors and reports for the virtual trackers of the real-kernel harness.

`hut_tracker()` is written by hand, byte by byte as a device's firmware would carry it, from
the HID Usage Tables' Eye and Head Trackers page (0x12) and HID 1.11's item encoding (6.2.2),
independently of tests/hid_device.py's encoders: an Eye Tracker application collection with

- input report 1, Tracking Data: Sensor Timestamp (0x20) as one 64-bit field in µs (the usage's
  own unit, no Unit item); Gaze Point (0x24) with Position X / Y (0x21/0x22), i32 in cm·10⁻⁴
  (µm) through Unit / Unit Exponent; Left and Right Eye Position (0x25/0x26), X/Y/Z each i16 in
  mm (cm·10⁻¹); a Tracker Quality byte;
- feature report 2, Capabilities (0x11): Tracker Quality, Minimum / Optimum / Maximum Tracking
  Distance and Maximum Screen Plane Width / Height (µm, u32);
- feature report 3, Configuration (0x12): Display Manufacturer ID / Product ID, Calibrated
  Screen Width / Height (µm, u32);
- feature report 4, Status (0x13): Configuration Status, Sampling Frequency (Hz, 1/s unit);
- feature report 5, Control (0x14): Device Mode Request.

`fake_tracker()` is the descriptor the fake device layer uses (tests/hid_device.py), so that the
same bytes go through the real kernel too. The rest are devices that lie (`LIARS`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from hid_device import FEATURES as FAKE_FEATURES
from hid_device import tracker_descriptor as fake_tracker_descriptor

# fmt: off
HUT_TRACKER = bytes([
    0x05, 0x12,                    # Usage Page (Eye and Head Trackers)
    0x09, 0x01,                    # Usage (Eye Tracker)
    0xA1, 0x01,                    # Collection (Application)
    # --- input report 1: Tracking Data ---
    0x85, 0x01,                    #   Report ID (1)
    0x09, 0x10,                    #   Usage (Tracking Data)
    0xA1, 0x00,                    #   Collection (Physical)
    0x09, 0x20,                    #     Usage (Sensor Timestamp): µs, the usage's own unit
    0x15, 0x00,                    #     Logical Minimum (0)
    0x27, 0xFF, 0xFF, 0xFF, 0x7F,  #     Logical Maximum (2^31 - 1: the kernel's items are 32-bit)
    0x75, 0x40,                    #     Report Size (64)
    0x95, 0x01,                    #     Report Count (1)
    0x81, 0x02,                    #     Input (Data,Var,Abs)
    0x09, 0x24,                    #     Usage (Gaze Point)
    0xA1, 0x00,                    #     Collection (Physical)
    0x09, 0x21,                    #       Usage (Position X)
    0x09, 0x22,                    #       Usage (Position Y)
    0x17, 0x01, 0x00, 0x00, 0x80,  #       Logical Minimum (-2^31 + 1)
    0x27, 0xFF, 0xFF, 0xFF, 0x7F,  #       Logical Maximum (2^31 - 1)
    0x66, 0x11, 0x00,              #       Unit (SI Linear: cm)
    0x55, 0x0C,                    #       Unit Exponent (-4): µm
    0x75, 0x20,                    #       Report Size (32)
    0x95, 0x02,                    #       Report Count (2)
    0x81, 0x02,                    #       Input (Data,Var,Abs)
    0xC0,                          #     End Collection
    0x09, 0x25,                    #     Usage (Left Eye Position)
    0xA1, 0x00,                    #     Collection (Physical)
    0x09, 0x21, 0x09, 0x22, 0x09, 0x23,  # Usage (Position X, Y, Z)
    0x16, 0x01, 0x80,              #       Logical Minimum (-32767)
    0x26, 0xFF, 0x7F,              #       Logical Maximum (32767)
    0x55, 0x0F,                    #       Unit Exponent (-1): mm (Unit stays cm)
    0x75, 0x10,                    #       Report Size (16)
    0x95, 0x03,                    #       Report Count (3)
    0x81, 0x02,                    #       Input (Data,Var,Abs)
    0xC0,                          #     End Collection
    0x09, 0x26,                    #     Usage (Right Eye Position)
    0xA1, 0x00,                    #     Collection (Physical)
    0x09, 0x21, 0x09, 0x22, 0x09, 0x23,  # Usage (Position X, Y, Z)
    0x81, 0x02,                    #       Input (Data,Var,Abs): same globals
    0xC0,                          #     End Collection
    0x65, 0x00,                    #     Unit (None)
    0x55, 0x00,                    #     Unit Exponent (0)
    0x0A, 0x00, 0x01,              #     Usage (Tracker Quality)
    0x15, 0x00,                    #     Logical Minimum (0)
    0x25, 0x04,                    #     Logical Maximum (4)
    0x75, 0x08,                    #     Report Size (8)
    0x95, 0x01,                    #     Report Count (1)
    0x81, 0x02,                    #     Input (Data,Var,Abs)
    0xC0,                          #   End Collection
    # --- feature report 2: Capabilities ---
    0x85, 0x02,                    #   Report ID (2)
    0x09, 0x11,                    #   Usage (Capabilities)
    0xA1, 0x02,                    #   Collection (Logical)
    0x0A, 0x00, 0x01,              #     Usage (Tracker Quality)
    0x25, 0x04,                    #     Logical Maximum (4)
    0xB1, 0x03,                    #     Feature (Const,Var,Abs)
    0x0A, 0x01, 0x01,              #     Usage (Minimum Tracking Distance)
    0x0A, 0x02, 0x01,              #     Usage (Optimum Tracking Distance)
    0x0A, 0x03, 0x01,              #     Usage (Maximum Tracking Distance)
    0x0A, 0x04, 0x01,              #     Usage (Maximum Screen Plane Width)
    0x0A, 0x05, 0x01,              #     Usage (Maximum Screen Plane Height)
    0x27, 0xFF, 0xFF, 0xFF, 0x7F,  #     Logical Maximum (2^31 - 1)
    0x75, 0x20,                    #     Report Size (32)
    0x95, 0x05,                    #     Report Count (5)
    0xB1, 0x03,                    #     Feature (Const,Var,Abs): µm, the usages' own unit
    0xC0,                          #   End Collection
    # --- feature report 3: Configuration ---
    0x85, 0x03,                    #   Report ID (3)
    0x09, 0x12,                    #   Usage (Configuration)
    0xA1, 0x02,                    #   Collection (Logical)
    0x0A, 0x00, 0x02,              #     Usage (Display Manufacturer ID)
    0x0A, 0x01, 0x02,              #     Usage (Display Product ID)
    0x26, 0xFF, 0x7F,              #     Logical Maximum (32767)
    0x75, 0x10,                    #     Report Size (16)
    0x95, 0x02,                    #     Report Count (2)
    0xB1, 0x03,                    #     Feature (Const,Var,Abs)
    0x0A, 0x04, 0x02,              #     Usage (Calibrated Screen Width)
    0x0A, 0x05, 0x02,              #     Usage (Calibrated Screen Height)
    0x27, 0xFF, 0xFF, 0xFF, 0x7F,  #     Logical Maximum (2^31 - 1)
    0x75, 0x20,                    #     Report Size (32)
    0x95, 0x02,                    #     Report Count (2)
    0xB1, 0x02,                    #     Feature (Data,Var,Abs): µm
    0xC0,                          #   End Collection
    # --- feature report 4: Status ---
    0x85, 0x04,                    #   Report ID (4)
    0x09, 0x13,                    #   Usage (Status)
    0xA1, 0x02,                    #   Collection (Logical)
    0x0A, 0x01, 0x03,              #     Usage (Configuration Status)
    0x25, 0x04,                    #     Logical Maximum (4)
    0x75, 0x08,                    #     Report Size (8)
    0x95, 0x01,                    #     Report Count (1)
    0xB1, 0x02,                    #     Feature (Data,Var,Abs)
    0x0A, 0x00, 0x03,              #     Usage (Sampling Frequency)
    0x26, 0xFF, 0x7F,              #     Logical Maximum (32767)
    0x67, 0x01, 0xF0, 0x00, 0x00,  #     Unit (SI Linear: 1/s)
    0x75, 0x10,                    #     Report Size (16)
    0xB1, 0x02,                    #     Feature (Data,Var,Abs)
    0x65, 0x00,                    #     Unit (None)
    0xC0,                          #   End Collection
    # --- feature report 5: Control ---
    0x85, 0x05,                    #   Report ID (5)
    0x09, 0x14,                    #   Usage (Control)
    0xA1, 0x02,                    #   Collection (Logical)
    0x0A, 0x00, 0x04,              #     Usage (Device Mode Request)
    0x25, 0x07,                    #     Logical Maximum (7): gaze point | eye position | head
    0x75, 0x08,                    #     Report Size (8)
    0x95, 0x01,                    #     Report Count (1)
    0xB1, 0x02,                    #     Feature (Data,Var,Abs)
    0xC0,                          #   End Collection
    0xC0,                          # End Collection
])
# fmt: on

#: Bytes of input report 1 of HUT_TRACKER: id, u64 timestamp, 2 × i32 gaze, 6 × i16 eyes, quality.
HUT_REPORT = struct.Struct("<BQ2i6hB")


@dataclass(frozen=True)
class Tracker:
    """A virtual tracker: its descriptor, how to pack its Tracking Data report, its feature
    reports as the device answers them, and the screen it says it is calibrated for."""

    name: str
    descriptor: bytes
    features: dict[int, bytes]
    screen_um: tuple[int, int]
    rate_hz: float
    #: Report ids the device answers with an errno, or never answers (it lies about them).
    errors: dict[int, int] = field(default_factory=dict)
    silent: frozenset[int] = frozenset()

    def report(self, ts_us: int, gaze_um: tuple[int, int]) -> bytes:
        raise NotImplementedError


class HutTracker(Tracker):
    def report(self, ts_us: int, gaze_um: tuple[int, int]) -> bytes:
        eyes = (-32, 15, 640, 31, 15, 641)  # mm: left X/Y/Z, right X/Y/Z
        return HUT_REPORT.pack(1, ts_us, *gaze_um, *eyes, 4)


class FakeLayoutTracker(Tracker):
    """tests/hid_device.py's descriptor: 32-bit Sensor Timestamp, which wraps."""

    def report(self, ts_us: int, gaze_um: tuple[int, int]) -> bytes:
        from hid_device import tracking_report

        return tracking_report(ts_us % (1 << 32), (-31, 12, 654), gaze_um)


def hut_features(screen_um: tuple[int, int], rate_hz: int) -> dict[int, bytes]:
    return {
        2: struct.pack("<BB5I", 2, 3, 450_000, 650_000, 900_000, 700_000, 400_000),
        3: struct.pack("<BHH2I", 3, 0x10AC, 0x4321, *screen_um),
        4: struct.pack("<BBH", 4, 1, rate_hz),
        5: struct.pack("<BB", 5, 0),
    }


def hut_tracker(screen_um: tuple[int, int] = (597_000, 336_000), rate_hz: int = 120) -> HutTracker:
    return HutTracker(
        "hut", HUT_TRACKER, hut_features(screen_um, rate_hz), screen_um, float(rate_hz)
    )


def fake_tracker() -> FakeLayoutTracker:
    (w, h) = struct.unpack("<2I", FAKE_FEATURES[0x12][2:])
    return FakeLayoutTracker(
        "fake-layout", fake_tracker_descriptor(), dict(FAKE_FEATURES), (w, h), 120.0
    )


# --- devices that lie --------------------------------------------------------------------------

# A Report Size of 300 bits: Linux's parser stops at 256 (hid-core.c, "invalid report_size"),
# so the kernel refuses the whole device and makes no hidraw node.
OVERSIZED_FIELD = bytes([
    0x05, 0x12, 0x09, 0x01, 0xA1, 0x01,  # Eye Tracker application collection
    0x09, 0x24, 0xA1, 0x00,              #   Gaze Point
    0x09, 0x21, 0x09, 0x22,              #     Position X, Y
    0x15, 0x00, 0x26, 0xFF, 0x7F,        #     Logical 0..32767
    0x76, 0x2C, 0x01,                    #     Report Size (300)
    0x95, 0x02, 0x81, 0x02,              #     Report Count (2), Input
    0xC0, 0xC0,
])  # fmt: skip

# An Eye Tracker whose Tracking Data has a Head Position and no Gaze Point: the kernel takes it,
# gazehdr cannot follow it (it says why).
NO_GAZE_POINT = bytes([
    0x05, 0x12, 0x09, 0x01, 0xA1, 0x01,  # Eye Tracker application collection
    0x09, 0x10, 0xA1, 0x00,              #   Tracking Data
    0x09, 0x27, 0xA1, 0x00,              #     Head Position
    0x09, 0x21, 0x09, 0x22, 0x09, 0x23,  #       Position X, Y, Z
    0x16, 0x01, 0x80, 0x26, 0xFF, 0x7F,  #       Logical -32767..32767
    0x75, 0x10, 0x95, 0x03, 0x81, 0x02,  #       16 bits × 3, Input
    0xC0, 0xC0, 0xC0,
])  # fmt: skip

# A Gaze Point whose positions are in grams: a unit of a page it does not implement.
GAZE_IN_GRAMS = bytes([
    0x05, 0x12, 0x09, 0x01, 0xA1, 0x01,  # Eye Tracker application collection
    0x09, 0x24, 0xA1, 0x00,              #   Gaze Point
    0x09, 0x21, 0x09, 0x22,              #     Position X, Y
    0x15, 0x00, 0x26, 0xFF, 0x7F,        #     Logical 0..32767
    0x66, 0x01, 0x01,                    #     Unit (SI Linear: g)
    0x75, 0x10, 0x95, 0x02, 0x81, 0x02,  #     16 bits × 2, Input
    0xC0, 0xC0,
])  # fmt: skip

# A vendor-defined device (usage page 0xFF00): not a tracker at all.
VENDOR_DEVICE = bytes([
    0x06, 0x00, 0xFF, 0x09, 0x01, 0xA1, 0x01,  # Usage Page (Vendor 0xFF00), Application
    0x09, 0x02, 0x15, 0x00, 0x26, 0xFF, 0x00,  #   Usage 2, Logical 0..255
    0x75, 0x08, 0x95, 0x08, 0x81, 0x02,        #   8 bytes, Input
    0xC0,
])  # fmt: skip


@dataclass(frozen=True)
class Liar:
    """A device whose descriptor lies, and what `gazehdr devices` must say of it: None when
    the kernel refuses it (no hidraw node, so it is not listed at all)."""

    name: str
    descriptor: bytes
    says: str | None
    product: int


LIARS = [
    Liar("oversized-field", OVERSIZED_FIELD, None, 0x0E01),
    Liar("no-gaze-point", NO_GAZE_POINT, "no Tracking Data input report with Position X/Y", 0x0E02),
    Liar("gaze-in-grams", GAZE_IN_GRAMS, "not convertible to µm", 0x0E03),
    Liar("vendor-device", VENDOR_DEVICE, "usage page 0xff00 is not Eye and Head Trackers", 0x0E04),
]
