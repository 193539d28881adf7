"""The wire formats without sockets: frame headers and payloads, control and gaze messages."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gazehdr.drivers import wire
from gazehdr.metrics import Histogram
from gazehdr.protocol import (
    HEADER_BYTES,
    MAX_CONTROL_BYTES,
    RAW,
    SIM_OUTPUT,
    Choose,
    Encoding,
    Eyes,
    FrameHeader,
    Gaze,
    ModelChange,
    ModelPick,
    ParamChange,
    ProtocolError,
    Reset,
    SceneMaps,
    SceneSettings,
    Viewport,
    decode_frame,
    encode_pixels,
    frame_buffer,
    parse_control,
    payload,
    split_frame,
)
from gazehdr.session import fit_size
from gazehdr.sim import Simulator


def _header(w: int, h: int, encoding: Encoding) -> FrameHeader:
    return FrameHeader(
        frame=7, gaze_seq=42, time=12.5, gaze_x=-0.25, gaze_y=1.5, adaptation=3.25, rho=-0.5,
        width=w, height=h, encoding=encoding, eyes_open=False, tracker=True, server_ms=8.5,
        dropped=3, split=True,
    )  # fmt: skip


@pytest.mark.parametrize("encoding", RAW)  # av1: tests/test_video.py; warp: tests/test_warp.py
def test_frame_round_trip(encoding: Encoding) -> None:
    rng = np.random.default_rng(0)
    v = rng.random((5, 7, 3)).astype(np.float32)
    header = _header(7, 5, encoding)
    data = header.pack() + encode_pixels(v, encoding)
    assert data[:4] == b"GZHF" and len(header.pack()) == HEADER_BYTES == 56
    assert data[45] == 0b110  # flags: eyes closed, tracker, split (docs/protocol.md)
    assert int.from_bytes(data[6:8], "little") == HEADER_BYTES
    got, back = decode_frame(data)
    assert got == header
    assert back.shape == v.shape
    # f16 keeps 11 significant bits (relative 2^-11); rgb10a2 rounds to the nearest 1/1023.
    tol = 2.0**-11 * v + 1e-7 if encoding is Encoding.f16 else np.full_like(v, 0.5 / 1023 + 1e-7)
    assert np.all(np.abs(back - v) <= tol)


def test_a_payload_is_the_array_in_order_and_little_endian() -> None:
    """Arrays of the other byte order or not contiguous go on the wire as the plain ones do."""
    rng = np.random.default_rng(1)
    halves = rng.random((5, 7, 3)).astype(np.float16)
    words = rng.integers(0, 2**30, (5, 7), dtype=np.uint32)
    assert payload(words) == b"".join(int(w).to_bytes(4, "little") for w in words.flat)
    assert payload(words.astype(">u4")) == payload(words)
    assert payload(words[:, ::2]) == payload(words[:, ::2].copy())
    assert payload(halves.transpose(1, 0, 2)) == payload(halves.transpose(1, 0, 2).copy())


@pytest.mark.parametrize("encoding", RAW)
def test_a_frame_buffer_is_laid_out_as_a_header_then_a_payload(encoding: Encoding) -> None:
    """A step's pixels composed into `frame_buffer`'s array, its header packed into the first
    HEADER_BYTES, give the bytes `header.pack() + payload(pixels)` does, for the arrays the
    simulator makes for the encoding (their shape and dtype, which `PIXELS` states)."""
    sim = Simulator(19, 16, backend="reference")
    sim.load_scene(np.random.default_rng(1).uniform(0.0, 500.0, (16, 19, 3)))
    step = sim.step(0.05, output=SIM_OUTPUT[encoding])
    message, pixels = frame_buffer(19, 16, encoding)
    assert (pixels.shape, pixels.dtype) == (step.shape, step.dtype.newbyteorder("<"))
    sim.frame(SIM_OUTPUT[encoding], out=pixels)
    header = _header(19, 16, encoding)
    message[:HEADER_BYTES] = header.pack()
    assert bytes(message) == header.pack() + payload(step)
    assert split_frame(message)[0] == header


@pytest.mark.parametrize("encoding", RAW)  # av1: tests/test_video.py; warp: tests/test_warp.py
def test_both_encodings_keep_ten_bits_everywhere(encoding: Encoding) -> None:
    """SPEC §2.4: the dither needs v to at least 1/1024 anywhere in [0, 1], darks included."""
    v = np.linspace(0.0, 1.0, 128 * 1024, dtype=np.float32).reshape(128, 1024, 1).repeat(3, 2)
    _, back = decode_frame(_header(1024, 128, encoding).pack() + encode_pixels(v, encoding))
    assert np.max(np.abs(back - v)) <= 0.5 / 1023 + 1e-7
    assert back[0, 0, 0] == 0.0 and back[-1, -1, 0] == 1.0


def test_decode_refuses_foreign_bytes() -> None:
    with pytest.raises(ProtocolError, match="magic"):
        decode_frame(b"PNG\x00" + bytes(80))
    bad_version = bytearray(_header(1, 1, Encoding.f16).pack() + bytes(6))
    bad_version[4] = 9
    with pytest.raises(ProtocolError, match="version 9"):
        decode_frame(bytes(bad_version))


@pytest.mark.parametrize(
    ("message", "expected"),
    [
        ({"type": "viewport", "width": 1280, "height": 720}, Viewport(1280, 720)),
        ({"type": "gaze", "x": 0.25, "y": -1, "seq": 3}, Gaze(0.25, -1.0, 3)),
        ({"type": "eyes", "open": False}, Eyes(False)),
        ({"type": "scene", "name": "lamp"}, Choose("scene", "lamp")),
        (
            {"type": "model", "afterimage": "ritschel", "acuity": "none"},
            ModelChange(ModelPick("ritschel", "none")),
        ),
        ({"type": "model", "acuity": "gaussian"}, ModelChange(ModelPick(acuity="gaussian"))),
        (
            {"type": "model", "split": {"afterimage": "mikamo", "acuity": "stochastic"}},
            ModelChange(ModelPick(), ModelPick("mikamo", "stochastic")),
        ),
        ({"type": "model", "split": {}}, ModelChange(ModelPick(), ModelPick())),
        (
            {"type": "model", "afterimage": "jacobs", "split": None},
            ModelChange(ModelPick("jacobs"), None),
        ),
        ({"type": "gaze_source", "name": "remote"}, Choose("gaze_source", "remote")),
        ({"type": "params", "values": {"j1": 0.1}}, ParamChange({"j1": 0.1})),
        ({"type": "reset"}, Reset()),
        ({"type": "scene_settings", "scale": 250}, SceneSettings({"scale": 250})),
        (
            {"type": "scene_settings", "scale": None, "kind": "median", "layer": "beauty/diffuse"},
            SceneSettings({"scale": None, "kind": "median", "layer": "beauty/diffuse"}),
        ),
        ({"type": "scene_settings", "layer": None}, SceneSettings({"layer": None})),
        ({"type": "scene_maps", "send": True}, SceneMaps(True)),
        ({"type": "scene_maps", "send": False}, SceneMaps(False)),
    ],
)
def test_controls_parse(message: dict, expected: object) -> None:
    assert parse_control(json.dumps(message)) == expected


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("{not json", "malformed JSON"),
        ("[1, 2]", "a message is a JSON object with a string 'type'"),
        ('{"x": 1}', "a message is a JSON object with a string 'type'"),
        ('{"type": "teleport"}', "unknown message type 'teleport'"),
        ('{"type": "gaze", "x": NaN, "y": 0.5, "seq": 1}', "NaN is not a number"),
        ('{"type": "gaze", "x": Infinity, "y": 0.5, "seq": 1}', "Infinity"),
        ('{"type": "gaze", "x": 1e9, "y": 0.5, "seq": 1}', r"'x' must be a finite number in"),
        ('{"type": "gaze", "x": "0.5", "y": 0.5, "seq": 1}', "'x' must be a number"),
        ('{"type": "gaze", "x": true, "y": 0.5, "seq": 1}', "'x' must be a number"),
        ('{"type": "gaze", "x": 0.5, "y": 0.5, "seq": -1}', "'seq' must be in"),
        ('{"type": "gaze", "x": 0.5, "y": 0.5}', "'seq' must be an integer"),
        ('{"type": "viewport", "width": 0, "height": 10}', "'width' must be a finite number"),
        ('{"type": "eyes", "open": 1}', "'open' must be true or false"),
        ('{"type": "params", "values": [1]}', "'values' must be an object"),
        ('{"type": "scene", "name": 3}', "'name' must be a string"),
        ('{"type": "model", "name": "jacobs"}', "'model' needs 'afterimage', 'acuity' or 'split'"),
        ('{"type": "model", "afterimage": 1}', "'afterimage' must be a model name"),
        ('{"type": "model", "split": "jacobs"}', "'split' must be an object of model names"),
        ('{"type": "model", "split": {"acuity": [1]}}', "'split.acuity' must be a model name"),
        ('{"type": "scene_settings"}', "'scene_settings' needs 'scale', 'kind' or 'layer'"),
        ('{"type": "scene_settings", "gain": 2}', "needs 'scale', 'kind' or 'layer'"),
        ('{"type": "scene_settings", "scale": "250"}', "'scale' must be a number"),
        ('{"type": "scene_settings", "scale": true}', "'scale' must be a number"),
        ('{"type": "scene_settings", "kind": 3}', "'kind' must be a string"),
        ('{"type": "scene_settings", "layer": ["a"]}', "'layer' must be a string"),
        ('{"type": "scene_maps"}', "'send' must be true or false"),
        ('{"type": "scene_maps", "send": 1}', "'send' must be true or false"),
    ],
)
def test_bad_controls_are_refused_with_a_reason(text: str, match: str) -> None:
    with pytest.raises(ProtocolError, match=match):
        parse_control(text)


def test_oversized_control_is_refused_before_parsing() -> None:
    text = json.dumps({"type": "reset", "pad": "x" * MAX_CONTROL_BYTES})
    with pytest.raises(ProtocolError, match="limit is 65536"):
        parse_control(text)


def test_error_names_the_message_type() -> None:
    with pytest.raises(ProtocolError) as info:
        parse_control('{"type": "gaze", "x": 0, "y": 0, "seq": "a"}')
    assert info.value.in_type == "gaze"


@pytest.mark.parametrize(
    ("budget", "viewport", "expected"),
    [
        ((640, 360), (1920, 1080), (640, 360)),  # same aspect: the budget itself
        ((640, 360), (1000, 1000), (480, 480)),  # square window: same pixel count, square
        ((640, 360), (360, 640), (360, 640)),  # portrait
        ((64, 36), (100000, 1), (7680, 16)),  # absurd aspect: clamped to the frame limits
    ],
)
def test_fit_size(budget, viewport, expected) -> None:
    assert fit_size(budget, viewport) == expected


# --- gaze wire --------------------------------------------------------------------------------


def test_wire_round_trip() -> None:
    messages = [
        wire.Hello(1, "tobii-x", {"width_mm": 520.0}),
        wire.Samples(
            (wire.Sample(10, 0.25, 0.75, True), wire.Sample(20, math.nan, math.nan, False))
        ),
        wire.Event("fixation_start", 3, 30, 0.5, 0.5),
        wire.Event("blink_end", 4, 40, math.nan, math.nan),
        wire.Echo(123456789),
    ]
    for message in messages:
        back = wire.parse(wire.dumps(message))
        assert repr(back) == repr(message)  # repr: NaN != NaN but prints the same


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ('{"type": "hello", "protocol": 2}', "protocol 2"),
        ('{"type": "samples", "samples": 3}', "'samples' must be a list"),
        ('{"type": "samples", "samples": [{"t": 1, "x": NaN, "y": 0}]}', "NaN"),
        ('{"type": "samples", "samples": [{"t": -1, "x": 0, "y": 0}]}', r"samples\[0\]: 't'"),
        ('{"type": "samples", "samples": [{"t": 1, "x": 0, "y": 99}]}', r"samples\[0\]: 'y'"),
        ('{"type": "event", "kind": "saccade", "id": 1, "t": 1}', "'kind' must be one of"),
        ('{"type": "echo"}', "echo: 't0'"),
        ('{"type": "command", "run": "rm"}', "unknown message type 'command'"),
    ],
)
def test_wire_refuses_bad_messages(text: str, match: str) -> None:
    with pytest.raises(wire.WireError, match=match):
        wire.parse(text)


def test_wire_batch_limit() -> None:
    batch = [{"t": i, "x": 0.5, "y": 0.5} for i in range(wire.MAX_BATCH + 1)]
    with pytest.raises(wire.WireError, match="at most 1000"):
        wire.parse(json.dumps({"type": "samples", "samples": batch}))


def test_histogram_is_cumulative_prometheus_text() -> None:
    h = Histogram("x_seconds", "test", buckets=(0.1, 1.0))
    for value in (0.05, 0.1, 0.5, 2.0):
        h.observe(value)
    lines = h.render()
    assert 'x_seconds_bucket{le="0.1"} 2' in lines
    assert 'x_seconds_bucket{le="1"} 3' in lines
    assert 'x_seconds_bucket{le="+Inf"} 4' in lines
    assert "x_seconds_count 4" in lines and "x_seconds_sum 2.65" in lines
