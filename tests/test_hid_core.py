"""The HID driver's pure parts, fed directly: bytes and numbers in, values out.

No device, no fake bus, no clock: what `gazehdr.drivers.hid.source` does around these is in
`tests/test_hid.py`. Descriptors and reports are built with `tests/hid_device.py`'s item
encoders.
"""

from __future__ import annotations

import logging
import math
import struct
from dataclasses import replace

import pytest
from hid_device import (
    DATA,
    END,
    FEATURES,
    collection,
    count,
    feature,
    gaze_only_descriptor,
    input_,
    logical,
    microsoft_style_descriptor,
    size,
    tracker_descriptor,
    tracking_report,
    usage,
    usage_page,
)

from gazehdr.drivers.hid.clock import ReportClock, TrackerClock
from gazehdr.drivers.hid.descriptor import (
    INPUT,
    MAX_REPORT_SIZE,
    Descriptor,
    ReportError,
    Value,
)
from gazehdr.drivers.hid.tracker import (
    TrackerInfo,
    TrackerReports,
    gaze_sample,
    screen_geometry,
    shape_differs,
)
from gazehdr.drivers.hid.usages import DEVICE_MODE_REQUEST, SENSOR_TIMESTAMP
from gazehdr.drivers.samples import ScreenGeometry

ENTRY = {
    "path": b"/dev/hidraw7",
    "vendor_id": 0x2104,
    "product_id": 0x0127,
    "manufacturer_string": "Test Trackers",
    "product_string": "Gaze 120",
    "serial_number": "TT-1",
}


def unnumbered_descriptor() -> bytes:
    """A tracker without report ids: Gaze Point X/Y, i16 µm; a Device Mode Request feature."""
    mode = [usage(0x14), collection(2), usage(0x400), logical(0, 7), size(8), count(1)]
    return gaze_only_descriptor(*mode, feature(DATA), END)


def reports(descriptor: bytes | None = None) -> TrackerReports:
    return TrackerReports(Descriptor(descriptor or tracker_descriptor()))


# --- tracker: what the descriptor and the feature reports say ---------------------------------


def test_tracking_report_read_size_and_feature_ids() -> None:
    r = reports()
    assert r.report_id == 0x10 and r.read_size == 23
    assert sorted(r.feature_ids) == [0x11, 0x12, 0x13, 0x14]  # type: ignore[type-var]
    assert r.decode(bytes([0x11, 2, 0, 0, 0, 0, 0, 0, 0])) is None  # another report id
    decoded = r.decode(tracking_report(5, (0, 0, 0), (10, 20)))
    assert decoded is not None and decoded.report_id == 0x10
    u = reports(unnumbered_descriptor())
    assert u.report_id is None and u.read_size == 4 and u.feature_ids == [None]


def test_feature_reports_as_hidapi_returns_them() -> None:
    """hidraw gives the id first; an unnumbered report may come with a 0 before it, and a
    numbered one without its id: all three decode to the same values."""
    r = reports()
    status = FEATURES[0x13]
    for data in (status, status[1:]):
        values = [v.value for v in r.decode_feature(0x13, data).values]
        assert values == [1.0, pytest.approx(120.0)]
    with pytest.raises(ReportError):
        r.decode_feature(0x13, status[2:])  # two bytes short: not a report with its id dropped
    u = reports(unnumbered_descriptor())
    assert [v.raw for v in u.decode_feature(None, [0, 5]).values] == [5]
    assert [v.raw for v in u.decode_feature(None, [5]).values] == [5]


def test_device_mode_request() -> None:
    r = reports()
    assert r.mode_request(None) == (3, [0x14, 3])  # gaze point + eye position (it reports them)
    assert r.mode_request(1) == (1, [0x14, 1])
    with pytest.raises(ValueError, match=r"device mode 9 is outside the tracker's range 0\.\.7"):
        r.mode_request(9)
    assert reports(unnumbered_descriptor()).mode_request(None) == (1, [1])  # no eye positions
    assert reports(microsoft_style_descriptor()).mode_request(None) is None  # no Device Mode
    d = Descriptor(tracker_descriptor())
    assert d.encode_feature(0x14, {DEVICE_MODE_REQUEST: 5}, base=[0x14, 2, 9]) == [0x14, 5]


def test_tracker_info_from_feature_reports() -> None:
    r = reports()
    features = [r.decode_feature(rid, FEATURES[rid]) for rid in (0x11, 0x12, 0x13, 0x14)]
    info = TrackerInfo.of(ENTRY, features, device_mode=3)
    assert info.path == "/dev/hidraw7" and (info.vendor_id, info.product_id) == (0x2104, 0x0127)
    assert (info.manufacturer, info.product, info.serial) == ("Test Trackers", "Gaze 120", "TT-1")
    assert info.calibrated_screen_um == (527_040.0, 296_460.0)
    assert info.sampling_hz == pytest.approx(120.0) and info.configuration_status == 1
    assert info.features["0x0104"] == 600_000.0 and info.features["0x0100"] == 2.0
    assert info.as_dict()["calibrated_screen_um"] == [527_040.0, 296_460.0]
    no_screen = r.decode_feature(0x12, bytes([0x12, 0]) + struct.pack("<2I", 527_040, 0))
    bare = TrackerInfo.of({"path": "p"}, [no_screen], device_mode=None)
    assert bare.calibrated_screen_um is None and bare.sampling_hz is None
    assert (bare.vendor_id, bare.product, bare.configuration_status) == (0, "", None)
    assert bare.as_dict()["calibrated_screen_um"] is None


# --- tracker: gaze in pixels ------------------------------------------------------------------


def test_gaze_sample_in_pixels() -> None:
    decoded = reports().decode(tracking_report(5, (0, 0, 0), (263_520, 74_115)))
    assert decoded is not None
    g = ScreenGeometry(0.6, 1920, 1080, 1.0)
    s = gaze_sample(decoded, 42, g, (527_040.0, 296_460.0))
    assert (s.t_ns, s.x, s.y, s.valid) == (42, pytest.approx(960.0), pytest.approx(270.0), True)
    # No calibrated size: the geometry's, 0.6 m across the diagonal in square pixels.
    um_per_px = 0.6e6 / math.hypot(1920, 1080)
    s = gaze_sample(decoded, 42, g, None)
    assert (s.x, s.y) == (pytest.approx(263_520 / um_per_px), pytest.approx(74_115 / um_per_px))
    no_gaze = reports().decode(tracking_report(5, (0, 0, 0), (2_000_000, 0)))
    assert no_gaze is not None
    s = gaze_sample(no_gaze, 43, g, None)
    assert not s.valid and math.isnan(s.x) and s.t_ns == 43


def test_screen_geometry_and_shape() -> None:
    calibrated = (527_040.0, 296_460.0)
    diagonal = math.hypot(0.527_040, 0.296_460)
    assert screen_geometry(None, calibrated, {}) == ScreenGeometry(diagonal, 1920, 1080, 1.0)
    assert screen_geometry(None, None, {}) == ScreenGeometry()
    given = ScreenGeometry(0.5, 1280, 1024, 0.7)
    assert screen_geometry(given, calibrated, {}) == given  # given: used as it is
    flags = {"screen_width_px": 2560, "viewing_distance_m": 0.65}
    assert screen_geometry(given, calibrated, flags) == replace(given, **flags)
    with pytest.raises(ValueError, match="screen_width_px"):
        screen_geometry(None, None, {"screen_width_px": 0})
    assert not shape_differs(calibrated, (1920, 1080))
    assert shape_differs(calibrated, (1280, 1024))


# --- descriptor: value arrays ----------------------------------------------------------------


def sensor_timestamp_array(n: int, bits: int) -> bytes:
    """An Eye Tracker whose input report is one Sensor Timestamp as a value array of n × bits."""
    items = [usage_page(0x12), usage(0x01), collection(1), usage(0x20), size(bits), count(n)]
    return b"".join([*items, input_(DATA), END])


def test_a_value_array_reads_as_one_number_up_to_the_widest_field() -> None:
    """8 × 32 bits is one 256-bit number; a report with 9 × 32 or 33 × 32 does not decode,
    while its descriptor still opens. Guards the width check in `Descriptor.decode`: without
    it, 33 × 32 bits (as the fuzzer's descriptor had) decoded to a number too large for a
    float, an OverflowError (and 9 × 32 to a number, with no error)."""
    d = Descriptor(sensor_timestamp_array(8, 32))
    report = bytes(range(1, 33))
    v = d.decode(INPUT, report).find(SENSOR_TIMESTAMP)
    assert v is not None and v.bits == MAX_REPORT_SIZE == 256
    assert v.raw == int.from_bytes(report, "little") and v.value == float(v.raw)
    for n in (9, 33):
        d = Descriptor(sensor_timestamp_array(n, 32))
        with pytest.raises(ReportError) as info:
            d.decode(INPUT, bytes(range(4 * n)))
        assert str(info.value) == (
            f"Input report None: usage 0x00120020 is a value array of {n} × 32 bits; at most "
            "256 bits are read as one number"
        )


# --- clock: tracker µs to host ns -------------------------------------------------------------


def test_tracker_clock_takes_the_window_minimum() -> None:
    """host − sensor: 1000, 1010, 1005, 1071 over a 100 ns window; the least in the window
    places each report, and a report older than the window no longer counts."""
    clock = TrackerClock(window_ns=100)
    pairs = [(0, 1000), (10, 1020), (20, 1025), (30, 1101)]
    assert [clock.to_host(s, h) for s, h in pairs] == [1000, 1010, 1020, 1035]
    clock.restart()
    assert clock.to_host(40, 2000) == 2000
    with pytest.raises(ValueError, match="window must be positive"):
        TrackerClock(0)


def stamp(raw: int, bits: int = 32, us_per_count: float = 1.0) -> Value:
    return Value(SENSOR_TIMESTAMP, (), raw, raw * us_per_count, bits, False)


def test_report_clock_unwraps_a_narrow_counter() -> None:
    clock = ReportClock(window_ns=2_000_000_000)
    raws = [250, 254, 2, 6]  # an 8-bit µs counter wrapping after 255
    sensor_ns = [250_000, 254_000, 258_000, 262_000]
    host = [s + 5_000_000 for s in sensor_ns]
    assert [clock.time_ns(stamp(r, bits=8), h) for r, h in zip(raws, host, strict=True)] == host
    # 100 µs counts (Unit Exponent −4 s): spaced 100 µs apart
    clock = ReportClock(window_ns=2_000_000_000)
    times = [clock.time_ns(stamp(r, us_per_count=100.0), 10**9 + r * 100_000) for r in (1, 2)]
    assert times[1] - times[0] == 100_000


def test_report_clock_reanchors_when_the_tracker_clock_goes_back(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = ReportClock(window_ns=2_000_000_000)
    assert clock.time_ns(stamp(5_000), 1_000_000_000) == 1_000_000_000
    with caplog.at_level(logging.WARNING, logger="gazehdr.drivers.hid"):
        t = clock.time_ns(stamp(100), 1_008_000_000)  # rebooted: its clock starts over
    assert t == 1_008_000_000  # placed at its read, not 4.9 ms before the previous one
    assert "tracker clock went back by 4900000 ns" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="gazehdr.drivers.hid"):
        t = clock.time_ns(stamp(50), 1_300_000_000, reconnected=True)
    assert t == 1_300_000_000 and not caplog.text  # after a re-plug: anchored afresh, silently


def test_report_clock_without_timestamps_and_a_coarse_host_clock() -> None:
    clock = ReportClock(window_ns=2_000_000_000)
    assert [clock.time_ns(None, h) for h in (500, 500, 400, 900)] == [500, 501, 502, 900]
    # the sensor would put the second report before the first: kept strictly increasing
    clock = ReportClock(window_ns=2_000_000_000)
    assert clock.time_ns(stamp(10), 1_000_000) == 1_000_000
    assert clock.time_ns(stamp(10), 1_000_000) == 1_000_001
