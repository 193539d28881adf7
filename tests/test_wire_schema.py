"""The JSON Schema of /ws/gaze (drivers/wire.schema.json) agrees with drivers/wire.py both ways."""

from __future__ import annotations

import json
import math
from pathlib import Path

import jsonschema
import pytest

from gazehdr.drivers import wire

SCHEMA = json.loads((Path(wire.__file__).parent / "wire.schema.json").read_text())


def _validator(part: str | None = None):
    schema = SCHEMA if part is None else {**SCHEMA, "anyOf": [{"$ref": f"#/$defs/{part}"}]}
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


TO_SERVER = [
    wire.Hello(1, "Tobii Pro Fusion", {"screen_width_px": 1920.0, "screen_height_px": 1080.0}),
    wire.Hello(1, "", {}),
    wire.Hello(1, "rig", {"screen_width_px": 1280.0, "refresh_hz": 0.0}),  # a later field
    wire.Hello(1, "Tobii Pro Spectrum", {"screen_width_px": 1920.0, "accuracy_deg": 0.3}),
    wire.Hello(1, "exact", {"accuracy_deg": 0.0}),
    wire.Samples(()),
    wire.Samples(
        (
            wire.Sample(0, 0.5, 0.25, True),
            wire.Sample(4_000_000, math.nan, math.nan, False),
            wire.Sample(2**63 - 1, -3.0, 4.0, True),
        )
    ),
    wire.Samples(tuple(wire.Sample(i, 0.1, 0.9, True) for i in range(wire.MAX_BATCH))),
    *(wire.Event(kind, 7, 123, 0.3, 0.7) for kind in wire.EVENT_KINDS),
    wire.Echo(987654321),
]
TO_DAEMON = [
    wire.Welcome(1),
    wire.EchoReply(5, 6),
    wire.Notice("rate limit: 12 samples dropped; at most 2000 samples/s are accepted"),
]


@pytest.mark.parametrize("message", TO_SERVER, ids=lambda m: type(m).__name__)
def test_daemon_messages_follow_the_schema_and_parse_back(message):
    text = wire.dumps(message)
    obj = json.loads(text)
    _validator("to_server").validate(obj)
    _validator().validate(obj)
    assert not _validator("to_daemon").is_valid(obj)
    parsed = wire.parse(text)
    assert type(parsed) is type(message)
    if isinstance(message, wire.Event) and message.kind.startswith("blink"):
        assert parsed.kind == message.kind and parsed.id == message.id
    elif not isinstance(message, wire.Samples):
        assert parsed == message
    else:
        assert [s.t_ns for s in parsed.samples] == [s.t_ns for s in message.samples]


@pytest.mark.parametrize("message", TO_DAEMON, ids=lambda m: type(m).__name__)
def test_server_replies_follow_the_schema_and_parse_back(message):
    text = wire.dumps(message)
    _validator("to_daemon").validate(json.loads(text))
    assert wire.parse_reply(text) == message


def test_the_servers_own_replies_follow_the_schema():
    """What server/gaze_link.py's GazeLink writes, literally."""
    from gazehdr.gaze_link import GAZE_RATE_HZ

    v = _validator("to_daemon")
    v.validate({"type": "welcome", "protocol": wire.PROTOCOL})
    v.validate({"type": "echo", "t0": 1, "server_ns": 2})
    note = f"rate limit: 3 samples dropped; at most {GAZE_RATE_HZ:g} samples/s are accepted"
    v.validate({"type": "error", "message": note})


INVALID_TO_SERVER = [
    {"type": "hello", "protocol": 2, "tracker": "x", "screen": {}},
    {"type": "hello", "protocol": 1, "tracker": 5},
    {"type": "hello", "protocol": 1, "screen": {"screen_width_px": "wide"}},
    {"type": "hello", "protocol": 1, "screen": {"screen_width_px": 0}},
    {"type": "hello", "protocol": 1, "screen": {"screen_height_px": -1080}},
    {"type": "hello", "protocol": 1, "screen": {"screen_diagonal_m": 0.0}},
    {"type": "hello", "protocol": 1, "screen": {"viewing_distance_m": -0.6}},
    {"type": "hello", "protocol": 1, "screen": {"accuracy_deg": -0.5}},
    {"type": "hello", "protocol": 1, "screen": {"accuracy_deg": "1 deg"}},
    {"type": "samples"},
    {"type": "samples", "samples": {"t": 1}},
    {"type": "samples", "samples": [{"x": 0.5, "y": 0.5}]},
    {"type": "samples", "samples": [{"t": 1, "x": 0.5}]},
    {"type": "samples", "samples": [{"t": -1, "x": 0.5, "y": 0.5}]},
    {"type": "samples", "samples": [{"t": 1.5, "x": 0.5, "y": 0.5}]},
    {"type": "samples", "samples": [{"t": 1, "x": 9.0, "y": 0.5}]},
    {"type": "samples", "samples": [{"t": 1, "x": 0.5, "y": 0.5, "valid": "yes"}]},
    {"type": "samples", "samples": [{"t": i, "x": 0.5, "y": 0.5} for i in range(1001)]},
    {"type": "event", "kind": "saccade_start", "id": 1, "t": 1},
    {"type": "event", "kind": "fixation_start", "id": 1, "t": 1},
    {"type": "event", "kind": "blink_start", "t": 1},
    {"type": "event", "kind": "blink_start", "id": 1, "t": 1, "x": 9.0},
    {"type": "event", "kind": "blink_end", "id": 1, "t": 1, "y": -3.5},
    {"type": "event", "kind": "blink_end", "id": 1, "t": 1, "x": "left"},
    {"type": "echo"},
    {"type": "echo", "t0": "now"},
    {"type": "echo", "t0": 1, "server_ns": 2},  # a reply, sent the wrong way
    {"type": "gaze", "x": 0.5, "y": 0.5},
    {"samples": []},
]


@pytest.mark.parametrize("obj", INVALID_TO_SERVER, ids=lambda o: json.dumps(o)[:60])
def test_invalid_messages_fail_the_schema_and_the_parser(obj):
    assert not _validator("to_server").is_valid(obj)
    with pytest.raises(wire.WireError):
        wire.parse(json.dumps(obj))


@pytest.mark.parametrize(
    "obj",
    [
        {"type": "welcome", "protocol": 2},
        {"type": "echo", "t0": 1},
        {"type": "echo", "t0": 1, "server_ns": -5},
        {"type": "error", "message": 3},
        {"type": "error"},
        {"type": "hello", "protocol": 1},
    ],
    ids=lambda o: json.dumps(o),
)
def test_invalid_replies_fail_the_schema_and_the_reply_parser(obj):
    assert not _validator("to_daemon").is_valid(obj)
    with pytest.raises(wire.WireError):
        wire.parse_reply(json.dumps(obj))


def test_the_hello_gives_the_trackers_accuracy_when_it_has_one():
    """`screen.accuracy_deg` (optional) is the tracker's accuracy, in degrees."""
    hello = wire.parse(wire.dumps(wire.Hello(1, "t", {"accuracy_deg": 0.5})))
    assert isinstance(hello, wire.Hello) and hello.accuracy_deg == 0.5
    assert wire.parse('{"type": "hello", "protocol": 1}').accuracy_deg is None
    accuracy = SCHEMA["$defs"]["hello"]["properties"]["screen"]["properties"]["accuracy_deg"]
    assert accuracy["minimum"] == 0


def test_an_echo_reply_is_not_an_echo_request():
    assert not _validator("to_server").is_valid({"type": "echo", "t0": 1, "server_ns": 2})
    assert _validator("to_daemon").is_valid({"type": "echo", "t0": 1, "server_ns": 2})
