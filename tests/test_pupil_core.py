"""The Pupil Capture source's pure parts, with bytes and numbers alone: the spec, Pupil Remote's
replies, surface messages and their datums as samples, the clock arithmetic, and a seeded fuzz
of the decoder. The sockets are tests/test_pupil.py's."""

from __future__ import annotations

import math
import random
import re
import subprocess
import sys
import time
from typing import Any

import msgpack
import pytest
from pupil_capture import frames, gaze_datum, surface_message

from gazehdr.drivers.pupil.clock import (
    FUTURE_NS,
    JUMP_TOLERANCE_NS,
    PAST_NS,
    PupilClock,
    SampleTimes,
    describe,
)
from gazehdr.drivers.pupil.protocol import (
    GazeOnSurface,
    MessageError,
    PupilAddress,
    SurfaceMessage,
    decode,
    parse_address,
    parse_port,
    parse_time,
)
from gazehdr.drivers.samples import ScreenGeometry

# --- the spec ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("arg", "expected"),
    [
        ("", PupilAddress("127.0.0.1", 50020, "screen")),
        ("10.0.0.7", PupilAddress("10.0.0.7", 50020, "screen")),
        ("tracker.lab:50021", PupilAddress("tracker.lab", 50021, "screen")),
        ("127.0.0.1:50020/monitor left", PupilAddress("127.0.0.1", 50020, "monitor left")),
        ("host/a/b", PupilAddress("host", 50020, "a/b")),
        ("/wall", PupilAddress("127.0.0.1", 50020, "wall")),
        (":50030", PupilAddress("127.0.0.1", 50030, "screen")),
        ("[::1]:50020/screen", PupilAddress("::1", 50020, "screen")),
    ],
)
def test_the_spec(arg: str, expected: PupilAddress) -> None:
    assert parse_address(arg) == expected


def test_addresses_as_zeromq_endpoints() -> None:
    assert parse_address("[::1]:7/s").remote_url == "tcp://[::1]:7"
    address = parse_address("10.0.0.7/my screen")
    assert (address.remote_url, address.url(41234)) == (
        "tcp://10.0.0.7:50020",
        "tcp://10.0.0.7:41234",
    )
    assert (address.topic, str(address)) == ("surfaces.my screen", "10.0.0.7:50020/my screen")


@pytest.mark.parametrize(
    ("arg", "message"),
    [
        ("host:port", "the port must be a number from 1 to 65535"),
        ("host:0", "the port must be a number from 1 to 65535"),
        ("host:65536", "the port must be a number from 1 to 65535"),
        ("host:/", "the port must be a number"),
        ("host/", "the surface name after '/' is empty"),
        ("a:1:2", "the port must be a number"),
        ("[::1", "expected pupil:HOST"),
    ],
)
def test_bad_specs_say_what_is_wrong(arg: str, message: str) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        parse_address(arg)


# --- Pupil Remote's replies -------------------------------------------------------------------


def test_remote_replies() -> None:
    assert parse_port(b"41234") == 41234
    assert parse_time(repr(5123.456789012).encode()) == 5123.456789012
    assert parse_time(b"-12.5") == -12.5  # Pupil time has an arbitrary epoch: it may be negative
    for reply, message in [
        (b"Unknown command.", "answered 'SUB_PORT' with 'Unknown command.', not a port"),
        (b"70000", "not a port"),
        (b"\xff", "'SUB_PORT' with bytes that are not UTF-8"),
    ]:
        with pytest.raises(MessageError, match=re.escape(message)):
            parse_port(reply)
    for reply in (b"Unknown command.", b"nan", b"inf", b""):
        with pytest.raises(MessageError, match=r"answered 't' with .*, not a time"):
            parse_time(reply)


# --- surface messages -------------------------------------------------------------------------


def test_a_surface_message_as_capture_sends_it() -> None:
    gaze = [
        gaze_datum(0.5, 0.5, 100.010),
        gaze_datum(0.25, 0.75, 100.005, confidence=0.3, gaze_topic="gaze.3d.0."),
        gaze_datum(1.5, -0.25, 100.015),
    ]
    message = decode(frames(surface_message("screen", gaze, 100.02)), "screen")
    assert message == SurfaceMessage(
        (
            GazeOnSurface(100.005, 0.25, 0.75, 0.3),  # in Pupil-time order
            GazeOnSurface(100.010, 0.5, 0.5, 0.95),
            GazeOnSurface(100.015, 1.5, -0.25, 0.95),
        )
    )
    empty = decode(frames(surface_message("screen", [], 100.0)), "screen")
    assert empty == SurfaceMessage(())
    raw_data = decode([*frames(surface_message("screen", gaze[:1], 1.0)), b"\x00raw"], "screen")
    assert raw_data == SurfaceMessage((GazeOnSurface(100.010, 0.5, 0.5, 0.95),))


def test_another_surface_whose_name_begins_with_ours_is_not_ours() -> None:
    """A SUB socket subscribed to `surfaces.screen` also gets `surfaces.screen 2`."""
    assert decode(frames(surface_message("screen 2", [], 1.0)), "screen") is None


def test_datums_as_samples_on_the_screen() -> None:
    screen = ScreenGeometry(screen_width_px=1000, screen_height_px=500)
    sample = GazeOnSurface(1.0, 0.25, 0.75, 0.9).sample(7, screen)
    assert (sample.t_ns, sample.x, sample.y, sample.valid) == (7, 250.0, 125.0, True)
    # Off the surface: the eye is open and tracked, so a valid sample off the screen, not an
    # invalid one (a run of those would be a blink).
    off = GazeOnSurface(1.0, -0.5, 1.25, 0.9).sample(8, screen)
    assert (off.x, off.y, off.valid) == (-500.0, -125.0, True)
    low = GazeOnSurface(1.0, 0.5, 0.5, 0.59).sample(9, screen)  # Player's 0.6
    assert not low.valid and math.isnan(low.x) and math.isnan(low.y)
    assert GazeOnSurface(1.0, 0.5, 0.5, 0.6).sample(9, screen).valid
    assert not GazeOnSurface(1.0, 0.5, 0.5, 0.7).sample(9, screen, min_confidence=0.8).valid
    assert not GazeOnSurface(1.0, math.inf, 0.5, 0.9).sample(9, screen).valid


def _payload(**changes: Any) -> dict[str, Any]:
    payload = surface_message("screen", [gaze_datum(0.5, 0.5, 10.0)], 10.0)
    payload.update(changes)
    return payload


def _packed(payload: Any, topic: bytes = b"surfaces.screen") -> list[bytes]:
    return [topic, msgpack.packb(payload, use_bin_type=True)]


@pytest.mark.parametrize(
    ("message", "error"),
    [
        ([b"surfaces.screen"], "1 frames; a message is [topic, msgpack payload, ...]"),
        ([], "0 frames"),
        ([b"\xffsurfaces", b""], "the topic frame b'\\xffsurfaces' is not UTF-8"),
        (frames(_payload(topic="gaze.3d.01.")), "topic 'gaze.3d.01.', not 'surfaces.screen'"),
        ([b"surfaces.screen", b"\xc1"], "surfaces.screen: the payload is not msgpack"),
        ([b"surfaces.screen", b"\x93\x01"], "the payload is not msgpack"),  # cut short
        ([b"surfaces.screen", msgpack.packb(1) + b"x"], "the payload is not msgpack"),
        (_packed([1, 2]), "surfaces.screen: the payload is a list, not a map"),
        (_packed(_payload(topic="surfaces.other")), "the payload's 'topic' is 'surfaces.other'"),
        (_packed(_payload(name="other")), "the payload's 'name' is 'other'"),
        (_packed({"topic": "surfaces.screen"}), "'gaze_on_surfaces' is missing, not a list"),
        (_packed(_payload(gaze_on_surfaces={})), "'gaze_on_surfaces' is dict, not a list"),
    ],
)
def test_malformed_messages_say_what_is_wrong(message: list[bytes], error: str) -> None:
    with pytest.raises(MessageError, match=re.escape(error)):
        decode(message, "screen")


def test_malformed_datums_are_left_out_and_said() -> None:
    good = gaze_datum(0.5, 0.5, 10.0)
    no_confidence = {k: v for k, v in good.items() if k != "confidence"}
    bad = [
        ("not a datum", "a str, not a map"),
        (no_confidence, "'confidence' is missing, not a number"),
        ({**good, "timestamp": True}, "'timestamp' is bool, not a number"),
        ({**good, "timestamp": math.nan}, "'timestamp' is nan"),
        ({**good, "timestamp": None}, "'timestamp' is missing, not a number"),
        ({**good, "confidence": 1.5}, "'confidence' 1.5 is not in [0, 1]"),
        ({**good, "confidence": math.nan}, "'confidence' nan is not in [0, 1]"),
        ({**good, "norm_pos": [0.5]}, "'norm_pos' is list, not a pair of numbers"),
        ({**good, "norm_pos": "0.5 0.5"}, "'norm_pos' is str, not a pair of numbers"),
        ({**good, "norm_pos": [0.5, "x"]}, "'norm_pos'[1] is str, not a number"),
    ]
    payload = _payload(gaze_on_surfaces=[good, *(datum for datum, _ in bad)])
    message = decode(_packed(payload), "screen")
    assert message is not None
    assert message.gaze == (GazeOnSurface(10.0, 0.5, 0.5, 0.95),)
    assert message.problems == tuple(
        f"surfaces.screen: gaze_on_surfaces[{i}]: {text}" for i, (_, text) in enumerate(bad, 1)
    )


# --- the clock --------------------------------------------------------------------------------


def test_offset_and_uncertainty_from_round_trips() -> None:
    """Pupil time read between t0 and t1: offset = pupil − (t0 + t1)/2 within RTT/2; the best is
    the smallest RTT of the window, as the daemon's echo does."""
    clock = PupilClock(window=3)
    assert clock.best is None
    with pytest.raises(ValueError, match="offset is unknown"):
        clock.host_ns(1.0)
    assert not clock.plausible(1.0, 0)
    assert not clock.add(1_000, 5.000_000_600, 1_400)  # RTT 400 ns
    assert not clock.add(2_000, 5.000_001_650, 2_200)  # RTT 200 ns: the best
    assert not clock.add(3_000, 5.000_002_700, 3_600)
    best = clock.best
    assert best is not None
    assert (best.offset_ns, best.uncertainty_ns, best.rtt_ns) == (4_999_999_550, 100, 200)
    assert clock.host_ns(5.0) == 450  # 5 s of Pupil time, on the host clock
    assert describe(best) == "pupil time = host monotonic + 4.999999550 s ± 0.1 µs (RTT 0.2 µs)"
    for t in (4_000, 5_000, 6_000):  # the window moves on: the RTT-200 answer leaves it
        clock.add(t, (t + 250 + 4_999_999_550) / 1e9, t + 500)
    assert clock.best is not None and clock.best.rtt_ns == 500
    assert not clock.add(7_000, 5.0, 6_999)  # the host clock went back: no measurement
    clock.restart()
    assert clock.best is None


def test_a_jump_of_pupil_time_restarts_the_estimate() -> None:
    """`T` sent to Pupil Remote by someone else, or a restarted Capture: the new answer's
    interval misses the best one's, and it alone is the estimate."""
    clock = PupilClock()
    clock.add(0, 1.0, 1_000)  # offset 1 s − 500 ns, ± 500 ns
    # The next interval misses this one by the tolerance exactly: drift, not a jump.
    assert not clock.add(10_000, (1e9 + 10_500 + JUMP_TOLERANCE_NS + 500) / 1e9, 11_000)
    assert clock.jumps == 0
    assert clock.add(20_000, (1e9 + 20_500 + JUMP_TOLERANCE_NS + 501) / 1e9, 21_000)
    assert clock.jumps == 1
    assert clock.add(30_000, 3.0, 31_000)  # Pupil time set to 3 s
    assert clock.jumps == 2
    assert clock.best is not None and clock.best.offset_ns == 3_000_000_000 - 30_500
    assert clock.host_ns(3.0) == 30_500


def test_plausible_times() -> None:
    clock = PupilClock()
    clock.add(0, 1000.0, 2_000)  # ± 1 µs
    at = clock.host_ns(1000.5)
    assert clock.plausible(1000.5, at)
    assert clock.plausible(1000.5, at + PAST_NS)
    assert not clock.plausible(1000.5, at + PAST_NS + 1)  # older than 10 s when it came
    assert clock.plausible(1000.5, at - FUTURE_NS - 1_000)
    assert not clock.plausible(1000.5, at - FUTURE_NS - 1_001)  # from the future


def test_sample_times_increase_and_never_pass_their_arrival() -> None:
    times = SampleTimes()
    assert times.next(100, 1_000) == 100
    assert times.next(90, 1_000) == 101  # out of order by 10 ns
    assert times.next(101, 1_000) == 102
    assert times.next(5_000, 2_000) == 2_000  # mapped after it arrived
    assert times.next(2_500, 3_000) == 2_500


# --- fuzz -------------------------------------------------------------------------------------

_KEYS = ["topic", "name", "gaze_on_surfaces", "timestamp", "norm_pos", "confidence", "on_surf"]


def _random_value(rng: random.Random, depth: int = 0) -> Any:
    kind = rng.randrange(9 if depth < 3 else 6)
    if kind == 0:
        return rng.choice([None, True, False])
    if kind == 1:
        return rng.randint(-(2**63), 2**64 - 1)
    if kind == 2:
        return rng.choice([rng.uniform(-2, 2), math.nan, math.inf, -math.inf, 1e308])
    if kind == 3:
        return "".join(rng.choice("aé.\x00s") for _ in range(rng.randrange(6)))
    if kind == 4:
        return rng.randbytes(rng.randrange(6))
    if kind == 5:
        return msgpack.ExtType(rng.randrange(128), rng.randbytes(3))
    if kind in (6, 7):
        return {
            rng.choice([*_KEYS, "x"]): _random_value(rng, depth + 1)
            for _ in range(rng.randrange(5))
        }
    return [_random_value(rng, depth + 1) for _ in range(rng.randrange(4))]


def _fuzzed(rng: random.Random) -> list[bytes]:
    base = frames(
        surface_message(
            "screen",
            [gaze_datum(rng.uniform(-1, 2), rng.uniform(-1, 2), rng.uniform(0, 1e6)) for _ in "ab"],
            1.0,
        )
    )
    how = rng.randrange(5)
    if how == 0:  # bytes of a good payload flipped
        payload = bytearray(base[1])
        for _ in range(rng.randrange(1, 4)):
            payload[rng.randrange(len(payload))] = rng.randrange(256)
        return [base[0], bytes(payload)]
    if how == 1:  # cut short
        return [base[0], base[1][: rng.randrange(len(base[1]))]]
    if how == 2:  # random structure where the datums go, or as the whole payload
        payload = surface_message("screen", [_random_value(rng) for _ in "abc"], 1.0)
        if rng.random() < 0.3:
            payload = {**payload, rng.choice(_KEYS): _random_value(rng)}
        return _packed(payload if rng.random() < 0.8 else _random_value(rng))
    if how == 3:  # random bytes, random frame counts
        return [rng.randbytes(rng.randrange(20)) for _ in range(rng.randrange(4))]
    return base


def test_the_decoder_under_seeded_fuzz() -> None:
    """Whatever arrives, `decode` returns a message whose datums make samples, or None, or raises
    MessageError: nothing else, and quickly."""
    rng = random.Random(20240612)
    screen = ScreenGeometry()
    outcomes = {"decoded": 0, "datums": 0, "problems": 0, "error": 0}
    start = time.monotonic()
    for _ in range(20_000):
        message = _fuzzed(rng)
        try:
            decoded = decode(message, "screen")
        except MessageError as e:
            assert str(e)
            outcomes["error"] += 1
            continue
        assert decoded is not None  # every fuzzed topic is ours or not UTF-8 / not ours at all
        outcomes["decoded"] += 1
        outcomes["problems"] += len(decoded.problems)
        for datum in decoded.gaze:
            outcomes["datums"] += 1
            assert math.isfinite(datum.timestamp) and 0 <= datum.confidence <= 1
            datum.sample(0, screen)
    assert time.monotonic() - start < 10
    assert all(outcomes.values()), outcomes  # every path was taken


def test_the_pure_modules_need_no_zeromq() -> None:
    """`protocol` and `clock` import neither pyzmq nor the server side."""
    code = (
        "import sys, gazehdr.drivers.pupil.protocol, gazehdr.drivers.pupil.clock; "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('zmq', 'pyopencl') "
        "or m.startswith('gazehdr.') and not m.startswith('gazehdr.drivers')]; "
        "print(bad); sys.exit(1 if bad else 0)"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr
