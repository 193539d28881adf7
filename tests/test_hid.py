"""The HID eye-tracker source (usage page 0x12), without hardware: descriptors, reports and
the device are `tests/hid_device.py`'s fake, since this kernel has no uhid."""

from __future__ import annotations

import asyncio
import itertools
import logging
import math
import random
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import samples_received, sole_tracker
from hid_device import (
    CONST,
    DATA,
    END,
    FEATURES,
    HOST0_NS,
    PATH,
    UNIT_CM,
    FakeBus,
    FakeTracker,
    collection,
    count,
    gaze_only_descriptor,
    input_,
    logical,
    make_tracker,
    microsoft_style_descriptor,
    physical,
    size,
    timed_source,
    timed_stream,
    tracker_descriptor,
    tracking_report,
    unit,
    usage,
    usage_page,
)

from gazehdr.drivers import wire
from gazehdr.drivers.daemon import Daemon
from gazehdr.drivers.hid.descriptor import (
    FEATURE,
    INPUT,
    Descriptor,
    DescriptorError,
    ReportError,
)
from gazehdr.drivers.hid.devices import devices_main, list_devices
from gazehdr.drivers.hid.source import HidGazeSource, HidState
from gazehdr.drivers.hid.tracker import TrackerReports
from gazehdr.drivers.hid.usages import (
    CALIBRATED_SCREEN_HEIGHT,
    CALIBRATED_SCREEN_WIDTH,
    GAZE_POINT,
    LEFT_EYE_POSITION,
    POSITION_X,
    POSITION_Y,
    POSITION_Z,
    SAMPLING_FREQUENCY,
    SENSOR_TIMESTAMP,
    TRACKER_QUALITY,
    TRACKING_DATA,
)
from gazehdr.drivers.registry import open_source
from gazehdr.drivers.samples import ScreenGeometry
from gazehdr.drivers.sessionlog import read_session_log
from gazehdr.drivers.sources import Source
from gazehdr.drivers.states import InvalidStateError

# --- descriptor and decoding ------------------------------------------------------------------


def test_descriptor_layout_comes_from_the_descriptor() -> None:
    d = Descriptor(tracker_descriptor())
    assert d.numbered
    assert sorted(d.report_ids(INPUT)) == [0x10]
    assert sorted(d.report_ids(FEATURE)) == [0x11, 0x12, 0x13, 0x14]
    # 1 id + 3 pad + 4 ts + 6 left eye + 8 gaze + 1 flag/pad
    assert d.report_bytes(INPUT, 0x10) == 23
    assert d.report_bytes(FEATURE, 0x12) == 10
    rid, fx = d.find(INPUT, POSITION_X, inside=GAZE_POINT)
    assert rid == 0x10
    assert (fx.logical_min, fx.logical_max, fx.size) == (-1_000_000, 1_000_000, 32)
    assert fx.unit_exp == -4
    _, lx = d.find(INPUT, POSITION_X, inside=LEFT_EYE_POSITION)
    assert lx is not fx and lx.start < fx.start  # the left eye comes first in the report


def test_input_report_decodes_to_micrometres_and_microseconds() -> None:
    d = Descriptor(tracker_descriptor())
    report = tracking_report(4_000_000_123, (-31, 12, 654), (263_520, -1_500))
    decoded = d.decode(INPUT, report)
    assert decoded.report_id == 0x10
    ts = decoded.find(SENSOR_TIMESTAMP)
    assert ts is not None and ts.raw == 4_000_000_123  # u32 above 2³¹ stays unsigned
    assert ts.value == pytest.approx(4_000_000_123.0)  # s·10⁻⁶ → µs
    gx = decoded.find(POSITION_X, inside=GAZE_POINT)
    gy = decoded.find(POSITION_Y, inside=GAZE_POINT)
    assert gx is not None and gy is not None
    assert (gx.raw, gy.raw) == (263_520, -1_500)  # signed
    assert gx.value == pytest.approx(263_520.0) and gy.value == pytest.approx(-1_500.0)
    # Left eye: i16 in mm (cm·10⁻¹) → µm
    lx = decoded.find(POSITION_X, inside=LEFT_EYE_POSITION)
    lz = decoded.find(POSITION_Z, inside=LEFT_EYE_POSITION)
    assert lx is not None and lz is not None
    assert lx.raw == -31 and lx.value == pytest.approx(-31_000.0)
    assert lz.value == pytest.approx(654_000.0)
    # The Position Z after the Gaze Point collection closed is in no eye/gaze collection.
    flags = [v for v in decoded.values if v.usage == POSITION_Z]
    assert len(flags) == 2
    assert flags[1].raw == 1
    assert GAZE_POINT not in flags[1].path and LEFT_EYE_POSITION not in flags[1].path
    assert TRACKING_DATA in flags[1].path


def test_constant_flagged_gaze_is_data_not_padding() -> None:
    d = Descriptor(tracker_descriptor(gaze_flags=CONST))
    decoded = d.decode(INPUT, tracking_report(7, (0, 0, 0), (1000, 2000)))
    gx = decoded.find(POSITION_X, inside=GAZE_POINT)
    assert gx is not None and gx.constant and gx.value == pytest.approx(1000.0)


def test_feature_reports_constant_fields_and_units() -> None:
    d = Descriptor(tracker_descriptor())
    conf = d.decode(FEATURE, FEATURES[0x12])
    w = conf.find(CALIBRATED_SCREEN_WIDTH)
    h = conf.find(CALIBRATED_SCREEN_HEIGHT)
    assert w is not None and h is not None and w.constant
    assert (w.value, h.value) == (527_040.0, 296_460.0)
    caps = d.decode(FEATURE, FEATURES[0x11])
    assert caps.find(TRACKER_QUALITY).raw == 2  # type: ignore[union-attr]
    status = d.decode(FEATURE, FEATURES[0x13])
    assert status.find(SAMPLING_FREQUENCY).value == pytest.approx(120.0)  # type: ignore[union-attr]


def test_out_of_logical_range_means_no_data() -> None:
    d = Descriptor(tracker_descriptor())
    decoded = d.decode(INPUT, tracking_report(5, (0, 0, 0), (-0x80000000, 1_000_001)))
    assert decoded.find(POSITION_X, inside=GAZE_POINT).value is None  # type: ignore[union-attr]
    assert decoded.find(POSITION_Y, inside=GAZE_POINT).value is None  # type: ignore[union-attr]


def test_value_array_push_pop_and_byte_unit_exponent() -> None:
    d = Descriptor(microsoft_style_descriptor())
    report = (
        bytes([0x10, 0, 0, 0])
        + struct.pack("<Q", 0x0123_4567_89AB_CDEF)
        + struct.pack("<2i", -42, 100_000)
        + struct.pack("<3i", 1, -2, 650_000)
    )
    assert d.report_bytes(INPUT, 0x10) == len(report)
    decoded = d.decode(INPUT, report)
    ts = decoded.find(SENSOR_TIMESTAMP)
    assert ts is not None and ts.raw == 0x0123_4567_89AB_CDEF and ts.bits == 64
    gx = decoded.find(POSITION_X, inside=GAZE_POINT)
    assert gx is not None and gx.value == pytest.approx(-42.0)  # no Unit item: µm as tabled
    # Unit cm with exponent 0xFC (−4) survives the Push: µm
    rz = decoded.find(POSITION_Z, inside=LEFT_EYE_POSITION)
    assert rz is not None and rz.value == pytest.approx(650_000.0)


def test_signed_logical_maximum_and_physical_range() -> None:
    desc = b"".join(
        [
            usage_page(0x12),
            usage(0x01),
            collection(1),
            usage(0x24),
            collection(0),
            usage(0x21),
            usage(0x22),
            logical(-100, -1),  # Logical Maximum −1 is 0xFF on the wire
            physical(-2000, -20),  # µm
            size(8),
            count(2),
            input_(DATA),
            END,
            usage(0x23),  # a second main item with the same globals
            count(1),
            input_(DATA),
            END,
        ]
    )
    d = Descriptor(desc)
    assert not d.numbered
    decoded = d.decode(INPUT, bytes([0x9C, 0xFF, 0xFF]))  # −100, −1, −1
    z = decoded.find(POSITION_Z)
    assert z is not None and z.raw == -1 and z.value == pytest.approx(-20.0)
    gx = decoded.find(POSITION_X, inside=GAZE_POINT)
    gy = decoded.find(POSITION_Y, inside=GAZE_POINT)
    assert gx is not None and gy is not None
    assert gx.value == pytest.approx(-2000.0) and gy.value == pytest.approx(-20.0)
    # 0 is above the logical maximum −1: no data
    assert d.decode(INPUT, bytes([0x9C, 0x00, 0xFF])).values[1].value is None


def test_bad_inputs_are_errors() -> None:
    d = Descriptor(tracker_descriptor())
    with pytest.raises(ReportError, match="no Input report with id 99"):
        d.decode(INPUT, bytes([99, 0, 0]))
    with pytest.raises(ReportError, match="bytes"):
        d.decode(INPUT, tracking_report(1, (0, 0, 0), (0, 0))[:10])
    with pytest.raises(DescriptorError):
        Descriptor(b"\x05\x12\x09\x01\xa1\x01\xc0\xc0")  # one End Collection too many
    no_gaze = b"".join([usage_page(1), usage(2), collection(1), END])
    with pytest.raises(DescriptorError, match="Gaze Point"):
        TrackerReports(Descriptor(no_gaze))
    length_as_time = b"".join(
        [
            usage_page(0x12),
            usage(0x20),
            logical(0, 255),
            unit(UNIT_CM),
            size(8),
            count(1),
            input_(DATA),
        ]
    )
    with pytest.raises(DescriptorError, match="not convertible to µs"):
        Descriptor(length_as_time)


def diffs(values: list[int]) -> list[int]:
    return [b - a for a, b in itertools.pairwise(values)]


# --- the source -------------------------------------------------------------------------------


def test_source_reads_features_sets_mode_and_yields_pixels() -> None:
    t = make_tracker()
    stream = timed_stream(3)
    stream.queue(t)
    geometry = ScreenGeometry(screen_width_px=1920, screen_height_px=1080)
    src = timed_source(t, geometry=geometry)
    samples = list(itertools.islice(src, 3))
    info = src.tracker_info
    assert info is not None
    assert info.calibrated_screen_um == (527_040.0, 296_460.0)
    assert info.sampling_hz == pytest.approx(120.0)
    assert info.configuration_status == 1
    assert (info.vendor_id, info.product_id, info.product) == (0x2104, 0x0127, "Gaze 120")
    assert isinstance(src, Source)
    assert src.info.name == "hid Test Trackers Gaze 120" and src.info.rate_hz == 120.0
    assert src.info.geometry == geometry and src.info.tracker["calibrated_screen_um"] == [
        527_040.0,
        296_460.0,
    ]
    # Device Mode: gaze point | eye position (the tracker reports eye positions; max is 7)
    assert t.sent == [[0x14, 3]]
    assert info.device_mode == 3
    # Host clock, spaced as the Sensor Timestamps (8 333 µs); with a constant latency the
    # smallest host − sensor is every report's, so each sample sits at its read.
    assert [s.t_ns for s in samples] == stream.read_ns
    assert diffs([s.t_ns for s in samples]) == [8_333_000, 8_333_000]
    s0 = samples[0]
    assert s0.valid
    assert s0.x == pytest.approx(10_000 / 527_040 * 1920)
    assert s0.y == pytest.approx(5_000 / 296_460 * 1080)
    src.close()


def test_open_source_builds_the_hid_source() -> None:
    t = make_tracker()
    stream = timed_stream(1)
    stream.queue(t)
    src = open_source("hid:" + PATH.decode(), backend=FakeBus(t), clock_ns=lambda: t.now_ns)
    assert isinstance(src, HidGazeSource) and src.tracker_info is not None
    assert src.tracker_info.path == PATH.decode()
    (s,) = itertools.islice(src, 1)
    assert s.t_ns == stream.read_ns[0]


def test_no_gaze_gives_an_invalid_sample() -> None:
    t = make_tracker()
    t.queue, t.read_at_ns = [tracking_report(10, (0, 0, 0), (2_000_000, 0))], [HOST0_NS]
    src = timed_source(t)
    (s,) = itertools.islice(src, 1)
    assert not s.valid and math.isnan(s.x) and math.isnan(s.y) and s.t_ns == HOST0_NS


def test_unplug_reconnects_with_backoff_and_loses_nothing_read(
    caplog: pytest.LogCaptureFixture,
) -> None:
    t = make_tracker()
    before = timed_stream(5)
    # Re-plugged 1.5 s of host time later, the tracker's clock 0.5 s on (it may have restarted
    # or stood still): the old offset would put these samples 1 s early; time is re-anchored.
    after = timed_stream(4, t0_us=1_533_000, host0_ns=before.taken_ns[-1] + 1_500_000_000)
    before.queue(t)
    t.queue.append(tracking_report(2_000_000, (0, 0, 0), (1, 1)))  # never read
    t.read_at_ns.append(before.read_ns[-1] + 8_333_000)
    t.unplug_after = 5  # five reads succeed, the sixth finds the tracker gone
    bus = FakeBus(t)
    now = [0.0]
    sleeps: list[float] = []

    def sleep(s: float) -> None:
        sleeps.append(s)
        now[0] += s
        if len(sleeps) == 3:  # re-plugged during the third wait
            t.plugged = True
            after.queue(t)

    src = HidGazeSource(
        backend=bus,
        sleep=sleep,
        clock=lambda: now[0],
        clock_ns=lambda: t.now_ns,
        backoff_initial_s=0.25,
        backoff_max_s=0.75,
    )
    with caplog.at_level(logging.INFO, logger="gazehdr.drivers.hid"):
        got = list(itertools.islice(src, 9))
    assert [s.t_ns for s in got] == before.read_ns + after.read_ns  # once each, in order
    assert [s.x for s in got[:5]] == pytest.approx(
        [10_000 * (i + 1) / 527_040 * 1920 for i in range(5)]
    )
    # The back-off's second wait (0.5 s) ends at the first look after the re-plug.
    assert sleeps == [0.25, 0.25, 0.25]
    assert "retrying in 0.25 s" in caplog.text and "retrying in 0.50 s" in caplog.text
    assert src.reconnects == 1 and bus.opened == 2
    assert t.sent == [[0x14, 3], [0x14, 3]]  # the mode is set again after the re-plug
    assert "5 samples recorded so far are kept" in caplog.text
    src.close()


def test_a_replug_is_noticed_at_the_next_look_whatever_the_backoff(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Waiting out a back-off of 8 s, the source lists the HID devices every REPLUG_POLL_S and
    opens a tracker plugged back in at the next look; the messages keep the back-off's pace
    (one per attempt). The real kernel's re-plug test needs this: the gap a server sees is
    the unplug plus at most a second."""
    t = make_tracker()
    timed_stream(2).queue(t)
    t.unplug_after = 2
    bus = FakeBus(t)
    now = [0.0]

    def sleep(s: float) -> None:
        now[0] += s
        if now[0] >= 1.1 and not t.plugged:
            t.plugged = True
            timed_stream(1, host0_ns=HOST0_NS + 2_000_000_000).queue(t)

    src = HidGazeSource(
        backend=bus, sleep=sleep, clock=lambda: now[0], clock_ns=lambda: t.now_ns,
        backoff_initial_s=8.0, backoff_max_s=8.0,
    )  # fmt: skip
    with caplog.at_level(logging.INFO, logger="gazehdr.drivers.hid"):
        got = list(itertools.islice(src, 3))
    assert len(got) == 3 and bus.opened == 2
    assert now[0] == pytest.approx(1.25)  # the first look after the re-plug at 1.1 s
    assert caplog.text.count("retrying in 8.00 s") == 1
    src.close()


def test_a_tracker_listed_but_not_openable_is_retried_briefly_then_at_the_backoffs_pace() -> None:
    """A tracker that appears but cannot be opened yet (its udev rule not applied) is tried at
    each look for REPLUG_SETTLE_S, then at the back-off's pace again: a lasting refusal
    (permissions) is not tried four times a second."""
    t = make_tracker()
    t.plugged = False
    now = [0.0]
    opens: list[float] = []

    class Refusing(FakeBus):
        def device(self) -> Any:
            dev = super().device()

            def open_path(path: bytes) -> None:
                opens.append(now[0])
                raise PermissionError(13, "Permission denied")

            dev.open_path = open_path
            return dev

    def sleep(s: float) -> None:
        now[0] += s
        t.plugged = t.plugged or now[0] >= 0.6

    src = HidGazeSource(
        backend=Refusing(t), sleep=sleep, clock=lambda: now[0], open_now=False,
        backoff_initial_s=0.25, backoff_max_s=4.0, give_up_after_s=12.0,
    )  # fmt: skip
    with pytest.raises(OSError, match="Permission denied"):
        src.wait_for_tracker()
    assert opens[:4] == pytest.approx([0.75, 1.0, 1.25, 1.5])  # at each look, for 1 s
    assert [b - a for a, b in itertools.pairwise(opens[3:])] == pytest.approx([4.0, 4.0, 4.0])


def test_reports_lost_or_faster_than_declared_are_counted_from_the_sensor_timestamp(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """At the declared 120 Hz (Status feature report), a Sensor Timestamp that steps 3 periods
    is 2 reports lost before they were read (the kernel drops what its 64-report buffer cannot
    hold); one stepping under half a period came faster than declared. Both are logged, with the
    totals, when the iteration ends; the samples themselves are all yielded."""
    t = make_tracker()
    stream = timed_stream(8)
    period_us = 8_333
    sensor = [0, 1, 4, 5, 9, 10, 10.1, 10.2]  # in periods: lost 2 + 3, then 2 early
    stream.reports = [
        tracking_report(1_000_000 + round(k * period_us), (0, 0, 0), (1_000, 1_000)) for k in sensor
    ]
    stream.queue(t)
    src = timed_source(t)
    with caplog.at_level(logging.WARNING, logger="gazehdr.drivers.hid"):
        got = list(itertools.islice(src, 8))
        src.close()
        assert list(src) == []  # the iteration ends: the totals are logged
    assert len(got) == 8
    assert (src.gaps.lost, src.gaps.early) == (5, 2)
    assert "5 in all; Sensor Timestamp gaps at 120 Hz" in caplog.text
    assert "2 reports faster than its declared 120 Hz" in caplog.text


def test_clock_restart_after_replug_reanchors() -> None:
    t = make_tracker()
    before = timed_stream(2, t0_us=5_000_000)
    before.queue(t)
    t.unplug_after = 2
    # The tracker rebooted: its clock starts over at 100 µs, 0.3 s of host time later.
    replugged = timed_stream(2, t0_us=100, host0_ns=before.taken_ns[-1] + 300_000_000)

    def sleep(s: float) -> None:
        t.plugged = True
        replugged.queue(t)

    src = timed_source(t, sleep=sleep)
    ts = [s.t_ns for s in itertools.islice(src, 4)]
    assert ts == before.read_ns + replugged.read_ns
    assert ts[3] - ts[2] == 8_333_000  # the new clock's spacing
    src.close()


def test_clock_going_back_without_replug_reanchors(caplog: pytest.LogCaptureFixture) -> None:
    t = make_tracker()
    first = timed_stream(3, t0_us=5_000_000)
    rebooted = timed_stream(3, t0_us=100, host0_ns=first.taken_ns[-1] + 8_333_000)
    t.queue, t.read_at_ns = first.reports + rebooted.reports, first.read_ns + rebooted.read_ns
    src = timed_source(t)
    with caplog.at_level(logging.WARNING, logger="gazehdr.drivers.hid"):
        ts = [s.t_ns for s in itertools.islice(src, 6)]
    assert ts == first.read_ns + rebooted.read_ns
    assert "tracker clock went back by 5016566000 ns" in caplog.text
    src.close()


def test_32_bit_timestamp_wraps_forward() -> None:
    t = make_tracker()
    latency = [100_000, 100_000, 400_000, 400_000]
    stream = timed_stream(
        4, t0_us=0xFFFF_FFD0, period_ns=0x20 * 1000, latency_ns=latency.__getitem__
    )
    stream.queue(t)
    assert [us % (1 << 32) for us in stream.sensor_us] == [0xFFFF_FFD0, 0xFFFF_FFF0, 0x10, 0x30]
    src = timed_source(t)
    ts = [s.t_ns for s in itertools.islice(src, 4)]
    # Spaced by the sensor across the wrap, placed by the smallest latency (the first reads'):
    # a wrap taken for a clock going back would re-anchor on the later, slower reads.
    assert diffs(ts) == [0x20 * 1000] * 3
    assert ts == [taken + 100_000 for taken in stream.taken_ns]
    src.close()


def test_constant_latency_keeps_the_sensor_spacing_on_the_host_clock() -> None:
    t = make_tracker()
    stream = timed_stream(1000, period_ns=1_000_000, latency_ns=lambda i: 150_000)
    stream.queue(t)
    src = timed_source(t)
    ts = [s.t_ns for s in itertools.islice(src, 1000)]
    # On the host clock: no earlier than the first read (less the latency), no later than the
    # last read; spaced exactly as the tracker stamped them.
    assert stream.read_ns[0] - 150_000 <= min(ts) and max(ts) <= stream.read_ns[-1]
    assert diffs(ts) == [1000 * d for d in diffs(stream.sensor_us)]
    src.close()
    with pytest.raises(ValueError, match="clock_window_s"):
        timed_source(make_tracker(), clock_window_s=0.0)


def test_latency_jitter_stays_out_of_the_spacing() -> None:
    """1 kHz, each report read 100 µs + U(0, 3 ms) after it was taken (seeded).

    The mapped time is taken + 100 µs + the least jitter in the 2 s window, so it is never
    earlier than taken + 100 µs, never later than the read, and once the window holds 200 reports
    its least jitter is below 0.1 ms (P(exceeded) = (29/30)^200 ≈ 0.1 % per window): the
    spacing then differs from the sensor's by at most 0.1 ms, where the reads' differs by up
    to 3 ms.
    """
    rng = random.Random(7)
    jitter = [rng.randrange(3_000_000) for _ in range(3000)]
    stream = timed_stream(3000, period_ns=1_000_000, latency_ns=lambda i: 100_000 + jitter[i])
    t = make_tracker()
    stream.queue(t)
    src = timed_source(t)
    ts = [s.t_ns for s in itertools.islice(src, 3000)]
    late = [t_ - taken for t_, taken in zip(ts, stream.taken_ns, strict=True)]
    assert all(t_ <= read for t_, read in zip(ts, stream.read_ns, strict=True))
    assert min(late) >= 100_000
    assert max(late[200:]) <= 200_000
    sensor_spacing = [1000 * d for d in diffs(stream.sensor_us)]
    off = [abs(a - b) for a, b in zip(diffs(ts), sensor_spacing, strict=True)]
    assert max(off) <= 3_000_000 and max(off[200:]) <= 100_000
    read_off = [abs(a - b) for a, b in zip(diffs(stream.read_ns), sensor_spacing, strict=True)]
    assert max(read_off[200:]) > 2_000_000  # what stamping at the read would have given
    src.close()


@pytest.mark.parametrize("ppm", [100.0, -100.0])
def test_clock_drift_is_followed(ppm: float) -> None:
    """A tracker clock 100 ppm fast (or slow) over 60 s at 120 Hz, read 200 µs after each sample.

    Unmapped, the tracker's time would drift 6 ms from the host's by the end; so would an offset
    taken as the minimum over all time for the slow tracker. The 2 s window lags a slow tracker
    by at most 2 s · 100 ppm = 0.2 ms and follows a fast one at once (the sensor's whole µs add
    ±1 µs).
    """
    n = 60 * 120
    stream = timed_stream(n, ppm=ppm)
    t = make_tracker()
    stream.queue(t)
    src = timed_source(t)
    ts = [s.t_ns for s in itertools.islice(src, n)]
    late = [t_ - taken for t_, taken in zip(ts, stream.taken_ns, strict=True)]
    lag = 200_000 if ppm < 0 else 0
    assert min(late) >= 200_000 - lag - 1_000 and max(late) <= 200_000 + 1_000
    assert all(d > 0 for d in diffs(ts))
    src.close()


def test_tracker_without_sensor_timestamp_gets_host_time() -> None:
    no_timestamp = gaze_only_descriptor()
    t = FakeTracker(PATH, no_timestamp, {})
    report = struct.pack("<2h", 100, 200)
    t.queue = [report] * 3
    t.read_at_ns = [HOST0_NS, HOST0_NS, HOST0_NS + 5_000_000]  # a coarse host clock repeats
    src = timed_source(t)
    assert [s.t_ns for s in itertools.islice(src, 3)] == [
        HOST0_NS,
        HOST0_NS + 1,  # kept strictly increasing
        HOST0_NS + 5_000_000,
    ]
    src.close()


def test_give_up_when_no_tracker() -> None:
    now = [0.0]

    def sleep(s: float) -> None:
        now[0] += s

    with pytest.raises(OSError, match="no HID eye tracker found"):
        HidGazeSource(backend=FakeBus())  # opened at once: nothing to wait for
    src = HidGazeSource(
        backend=FakeBus(), sleep=sleep, clock=lambda: now[0], give_up_after_s=2, open_now=False
    )
    with pytest.raises(OSError, match=r"no HID eye tracker for 3\.8 s"):
        next(iter(src))


def test_connecting_while_a_tracker_is_open_is_refused_and_keeps_it() -> None:
    """Mutation: no OPEN check in `connect` (a second handle would replace the first, which
    nobody closes)."""
    t = make_tracker()
    stream = timed_stream(2)
    stream.queue(t)
    bus = FakeBus(t)
    src = HidGazeSource(backend=bus, clock_ns=lambda: t.now_ns)
    assert src.state is HidState.OPEN and bus.opened == 1
    first = src.tracker
    with pytest.raises(InvalidStateError, match=r"connect\(\) in state OPEN: a tracker is open"):
        src.connect()
    assert src.tracker is first and bus.opened == 1 and t.sent == [[0x14, 3]]
    assert [s.t_ns for s in itertools.islice(src, 2)] == stream.read_ns  # nothing lost
    src.close()


def test_connecting_a_closed_source_is_refused_and_opens_nothing() -> None:
    """Mutation: no closed check in `connect` (it would open a device that nothing closes)."""
    t = make_tracker()
    bus = FakeBus(t)
    src = HidGazeSource(backend=bus)
    device = src.tracker.dev
    src.close()
    assert src.state is HidState.CLOSED and device.t is None and bus.opened == 1
    with pytest.raises(InvalidStateError, match=r"connect\(\) in state CLOSED"):
        src.connect()
    assert bus.opened == 1 and src.tracker is None
    assert list(src) == []  # a closed source yields nothing
    src.close()  # again: nothing happens
    assert src.state is HidState.CLOSED


def test_closing_while_iterated_leaves_the_device_to_the_iteration() -> None:
    """Mutation: `close` closing the device at once while it is iterated (under a read of
    another thread) rather than going CLOSING."""
    t = make_tracker()
    stream = timed_stream(2)
    stream.queue(t)
    src = timed_source(t)
    reading = iter(src)
    assert next(reading).t_ns == stream.read_ns[0]
    device = src.tracker.dev
    src.close()
    assert src.state is HidState.CLOSING and device.t is t  # still open for the read
    assert list(reading) == []  # the iteration ends, and closes the device
    assert src.state is HidState.CLOSED and device.t is None and src.tracker is None


def test_closed_while_opening_the_iteration_ends_and_closes_what_it_opened() -> None:
    """`close` from another thread while the iteration opens the tracker: the device it opened
    is closed again and the iteration ends without an error. Mutation: `connect` making the
    source OPEN whatever its state."""
    t = make_tracker()
    timed_stream(3).queue(t)
    opened: list[Any] = []

    class ClosingBus(FakeBus):
        def device(self):
            device = super().device()
            opened.append(device)
            src.close()  # as another thread would, while this one opens the device
            return device

    src = HidGazeSource(backend=ClosingBus(t), clock_ns=lambda: t.now_ns, open_now=False)
    assert list(itertools.islice(src, 1)) == []
    assert src.state is HidState.CLOSED and src.tracker is None
    assert len(opened) == 1 and opened[0].t is None  # opened, and closed again
    assert len(t.queue) == 3  # nothing read


def test_geometry_follows_the_calibrated_screen_and_flags_override(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The Configuration report says 527.04 × 296.46 mm: that is the screen's diagonal. HID says
    nothing of pixels or viewing distance (defaults), and flags override any field."""
    calibrated_diagonal_m = math.hypot(0.527_040, 0.296_460)
    t = make_tracker()
    timed_stream(2).queue(t)
    src = timed_source(t)
    assert src.info.geometry == ScreenGeometry(calibrated_diagonal_m, 1920, 1080, 1.0)
    src.close()

    t = make_tracker()
    timed_stream(1).queue(t)
    flags = {"screen_width_px": 2560, "screen_height_px": 1440, "viewing_distance_m": 0.65}
    src = open_source("hid", screen=flags, backend=FakeBus(t), clock_ns=lambda: t.now_ns)
    assert src.info.geometry == ScreenGeometry(calibrated_diagonal_m, 2560, 1440, 0.65)
    (s,) = itertools.islice(src, 1)
    assert s.x == pytest.approx(10_000 / 527_040 * 2560)  # µm → the flags' pixels
    src.close()

    t = make_tracker()
    flags = {"screen_diagonal_m": 0.5, "screen_width_px": 1280, "screen_height_px": 1024}
    with caplog.at_level(logging.WARNING, logger="gazehdr.drivers.hid"):
        src = timed_source(t, screen=flags)
    assert src.info.geometry == ScreenGeometry(0.5, 1280, 1024, 1.0)  # the flag wins
    assert "calibrated for a 527 × 296 mm screen, not the shape of 1280 × 1024 pixels" in (
        caplog.text
    )
    src.close()

    no_screen = FakeTracker(PATH, tracker_descriptor(), {**FEATURES, 0x12: bytes([0x12, 0])})
    src = timed_source(no_screen)
    assert src.tracker_info is not None and src.tracker_info.calibrated_screen_um is None
    assert src.info.geometry == ScreenGeometry()  # nothing reported: the defaults
    src.close()
    with pytest.raises(ValueError, match="screen_width_px must be a finite positive"):
        timed_source(make_tracker(), screen={"screen_width_px": 0})


def test_daemon_records_every_sample_across_an_unplug(live_server, tmp_path, monkeypatch) -> None:
    """The daemon over the HID source with --record: unplugged after five reports, back during
    the second wait; the log holds every sample the source yielded, in order, and the server got
    them too. Its hello carries the tracker's calibrated screen."""
    from gazehdr import gaze_link  # the server is only the other end here

    hellos: list[wire.Hello] = []
    original = gaze_link.GazeLink.handle

    def handle(self, msg, now):
        if isinstance(msg, wire.Hello):
            hellos.append(msg)
        return original(self, msg, now)

    monkeypatch.setattr(gaze_link.GazeLink, "handle", handle)
    t = make_tracker()
    before = timed_stream(5)
    after = timed_stream(4, t0_us=1_533_000, host0_ns=before.taken_ns[-1] + 1_500_000_000)
    before.queue(t)
    t.unplug_after = 5
    t.idle_read_s = 0.002
    waits: list[float] = []

    def sleep(s: float) -> None:
        waits.append(s)
        if len(waits) == 2:
            t.plugged = True
            after.queue(t)
        time.sleep(s)

    src = timed_source(t, sleep=sleep, backoff_initial_s=0.01)
    server = live_server(token="t")
    record = tmp_path / "rec.jsonl"
    daemon = Daemon(src, server.ws_url, "t", record=record)

    async def scenario():
        task = asyncio.create_task(daemon.run())
        deadline = time.monotonic() + 20
        while daemon.stats.samples_produced < 9:
            assert time.monotonic() < deadline, "the samples after the re-plug never came"
            await asyncio.sleep(0.01)
        daemon.stop()
        return await task

    stats = asyncio.run(asyncio.wait_for(scenario(), 30))
    recorded = read_session_log(record)
    assert [s.t_ns for s in recorded.samples] == before.read_ns + after.read_ns
    assert [s.x for s in recorded.samples] == pytest.approx(
        [10_000 * (i + 1) / 527_040 * 1920 for i in [*range(5), *range(4)]]
    )
    assert src.reconnects == 1 and src.samples_yielded == 9 == stats.samples_recorded
    assert stats.samples_delivered == sole_tracker(server).samples == 9
    assert waits == [0.01, 0.02]
    diagonal_m = math.hypot(0.527_040, 0.296_460)
    assert recorded.header.screen.screen_diagonal_m == pytest.approx(diagonal_m)
    assert [h.screen["screen_diagonal_m"] for h in hellos] == [pytest.approx(diagonal_m)]


#: `gazehdr daemon --source hid` in a process of its own, hidapi replaced by the fake bus with a
#: tracker that is plugged in once the bus has been enumerated three times (an attempt to open
#: it, the check while the source waits 0.25 s, a second attempt) and then sends
#: `timed_stream(N)`.
LATE_TRACKER_DAEMON = """
import sys

sys.path.insert(0, sys.argv[1])
import hid_device
from gazehdr.drivers.daemon_cli import daemon_main
from gazehdr.drivers.hid import source

tracker = hid_device.make_tracker()
tracker.plugged = False
tracker.idle_read_s = 0.01


class LateBus(hid_device.FakeBus):
    enumerations = 0

    def enumerate(self):
        self.enumerations += 1
        if self.enumerations == 4:  # three enumerations without it
            tracker.plugged = True
            hid_device.timed_stream(int(sys.argv[2])).queue(tracker)
        return super().enumerate()


bus = LateBus(tracker)
source.default_backend = lambda: bus
raise SystemExit(daemon_main(sys.argv[3:]))
"""


def test_daemon_waits_for_a_tracker_plugged_in_after_it_started(live_server, tmp_path) -> None:
    """No tracker at start-up: `gazehdr daemon --source hid` says so once per attempt and waits
    with back-off (rather than exiting 2), then streams the tracker that turns up; SIGTERM ends
    it with its summary."""
    server = live_server(token="t")
    script = tmp_path / "late_tracker_daemon.py"
    script.write_text(LATE_TRACKER_DAEMON)
    tests = str(Path(__file__).parent)
    argv = ["--source", "hid", "--server", server.ws_url, "--token", "t"]
    proc = subprocess.Popen(
        [sys.executable, str(script), tests, "6", *argv], stderr=subprocess.PIPE, text=True
    )
    try:
        deadline = time.monotonic() + 20
        while samples_received(server) < 6:
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
            time.sleep(0.02)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    waits = [line for line in err.splitlines() if "HID tracker not available" in line]
    assert waits == [
        "gazehdr daemon: HID tracker not available (no HID eye tracker found (usage page "
        f"0x12); see 'gazehdr devices'); retrying in {delay} s"
        for delay in ("0.25", "0.50")
    ]
    assert "delivered 6 samples" in err and sole_tracker(server).name == (
        "hid Test Trackers Gaze 120"
    )


# --- gazehdr devices --------------------------------------------------------------------------

KEYBOARD = {
    "path": b"/dev/hidraw-test-kbd",
    "vendor_id": 0x046D,
    "product_id": 0xC31C,
    "product_string": "Keyboard",
    "usage_page": 0x01,
    "usage": 0x06,
}


def test_list_devices_says_why(tmp_path: Any) -> None:
    node = tmp_path / "hidraw9"
    node.write_bytes(b"")
    locked = {
        "path": str(node).encode(),
        "vendor_id": 0x2104,
        "product_id": 0x0313,
        "product_string": "Locked Tracker",
        "usage_page": 0x12,
        "usage": 0x01,
    }
    bus = FakeBus(make_tracker(), others=[KEYBOARD, locked])
    found = {d.path: d for d in list_devices(bus, access=lambda p, m: False)}
    kbd = found["/dev/hidraw-test-kbd"]
    assert not kbd.usable and "usage page 0x0001" in kbd.reason
    lock = found[str(node)]
    assert not lock.usable and "permission denied" in lock.reason
    assert lock.udev_rule == (
        'SUBSYSTEM=="hidraw", ATTRS{idVendor}=="2104", ATTRS{idProduct}=="0313", '
        'MODE="0660", GROUP="plugdev"'
    )
    ok = found[PATH.decode()]
    assert ok.usable and "527.0 × 296.5 mm" in ok.reason and "120 Hz" in ok.reason
    assert bus.trackers[PATH].sent == []  # listing leaves the Device Mode alone


def test_devices_main_prints_rule_and_status(capsys: pytest.CaptureFixture[str]) -> None:
    """Listing is no failure, whatever it finds: 0 with or without a tracker; `--require`
    makes a missing tracker 1, for scripts. Guards the old status (1 in ordinary use, when a
    machine simply had no tracker plugged in)."""
    bus = FakeBus(make_tracker(), others=[KEYBOARD])
    assert devices_main([], backend=bus) == 0
    out = capsys.readouterr().out
    assert "ok   /dev/hidraw-test-0 2104:0127 Gaze 120: eye tracker" in out
    assert "skip /dev/hidraw-test-kbd 046d:c31c Keyboard: usage page 0x0001" in out
    assert devices_main(["--trackers-only"], backend=FakeBus(others=[KEYBOARD])) == 0
    assert "no HID eye trackers found" in capsys.readouterr().out
    assert devices_main(["--require"], backend=FakeBus(others=[KEYBOARD])) == 1
    assert devices_main(["--require"], backend=bus) == 0


def test_drivers_hid_imports_neither_server_nor_pyopencl() -> None:
    """Every module of the HID package, imported: no server side, no pyopencl, and neither
    hidapi nor hid-tools until a tracker is opened or a descriptor parsed."""
    code = (
        "import importlib, pkgutil, sys, gazehdr.drivers.hid as h; "
        "names = [m.name for m in pkgutil.iter_modules(h.__path__, h.__name__ + '.')]; "
        "[importlib.import_module(n) for n in names]; "
        "assert {'gazehdr.drivers.hid.source', 'gazehdr.drivers.hid.descriptor'} <= set(names); "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('pyopencl', 'hidraw', 'hid', "
        "'hidtools') or m.startswith('gazehdr.') and not m.startswith('gazehdr.drivers')]; "
        "sys.exit(1 if bad else 0)"
    )
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0
