"""A structure-aware mutator for JSON messages and JSON Lines, for atheris' `custom_mutator`.

Byte mutations of a JSON message mostly make text that is not JSON at all, which the parser
refuses on its first line; the bugs worth finding sit behind it, in values of the wrong type,
size or depth. So most of the time an input that parses is mutated as a tree: one value is
replaced by another of any JSON type (with the edge cases that break code that assumes a
type: integers too large for a float, 2^63, -1, 1e308, empty and non-ASCII strings, nesting
deeper than Python's recursion limit), a key is removed or added (the protocols' own keys
among them), or a list is grown. The rest of the time, and for text that does not parse,
libFuzzer's own byte mutation runs, so the JSON scanner itself is fuzzed as well.

For JSON Lines (the session log) one line is chosen and mutated that way.
"""

from __future__ import annotations

import json
import random
from collections.abc import Callable
from typing import Any

#: Keys of the messages and records we parse, so that added keys are ones a parser reads.
KEYS = (
    "type", "x", "y", "seq", "width", "height", "open", "name", "afterimage", "acuity", "split",
    "values", "scale", "kind", "layer", "send", "frame", "protocol", "tracker", "screen",
    "samples", "t", "valid", "id", "t0", "server_ns", "message", "format", "version", "clock",
    "left", "right", "scene", "params", "model", "text", "screen_width_px", "screen_height_px",
    "screen_diagonal_m", "viewing_distance_m", "source", "offset_ns", "duration_ns",
)  # fmt: skip
TYPES = (
    "viewport", "gaze", "eyes", "scene", "model", "gaze_source", "params", "scene_settings",
    "scene_maps", "warp", "reset", "ack", "hello", "samples", "event", "echo", "welcome", "error",
    "sample", "fixation_start", "fixation_end", "blink_start", "blink_end", "note", "clock",
)  # fmt: skip
#: Values that break code assuming a type or a range.
EDGES: tuple[Any, ...] = (
    0, -1, 1, 2**31, 2**32, 2**63, -(2**63), 2**64, 10**400, -(10**400), 1e308, -1e308, 5e-324,
    0.5, -0.0, True, False, None, "", "x", "é\u2028\U0001f600", "\ud800", [], {}, [[]], {"": {}},
)  # fmt: skip


def _scalar(rng: random.Random) -> Any:
    pick = rng.randrange(5)
    if pick == 0:
        return rng.choice(EDGES)
    if pick == 1:
        return rng.choice(TYPES)
    if pick == 2:
        return rng.randint(-(2**70), 2**70) if rng.random() < 0.2 else rng.randint(-5, 5000)
    if pick == 3:
        return rng.uniform(-10, 10) * 10.0 ** rng.randint(-10, 300)
    return "".join(chr(rng.randrange(0x20, 0x3000)) for _ in range(rng.randrange(6)))


def _value(rng: random.Random, depth: int = 0) -> Any:
    r = rng.random()
    if depth > 3 or r < 0.6:
        return _scalar(rng)
    if r < 0.8:
        return [_value(rng, depth + 1) for _ in range(rng.randrange(4))]
    return {rng.choice(KEYS): _value(rng, depth + 1) for _ in range(rng.randrange(4))}


def _containers(node: Any, out: list[Any]) -> list[Any]:
    if isinstance(node, (dict, list)):
        out.append(node)
        for child in node.values() if isinstance(node, dict) else node:
            _containers(child, out)
    return out


def mutate_tree(doc: Any, rng: random.Random) -> str:
    """The JSON text of `doc` with one structural change."""
    if rng.random() < 0.03:  # nesting deeper than the recursion limit, around a real message
        depth = rng.choice((100, 1000, 5000, 100_000))
        return "[" * depth + json.dumps(doc) + "]" * depth
    nodes = _containers(doc, [])
    if not nodes:
        return json.dumps(_value(rng), allow_nan=False)
    node = rng.choice(nodes)
    if isinstance(node, dict):
        keys = list(node)
        op = rng.randrange(4)
        if op == 0 or not keys:
            node[rng.choice(KEYS)] = _value(rng)
        elif op == 1:
            del node[rng.choice(keys)]
        else:
            node[rng.choice(keys)] = _value(rng)
    else:
        if node and rng.random() < 0.5:
            node[rng.randrange(len(node))] = _value(rng)
        elif node and rng.random() < 0.3:
            node.extend(node[: rng.randrange(1, 300)] * rng.randrange(1, 4))
        else:
            node.append(_value(rng))
    return json.dumps(doc, allow_nan=False)


def _parse(text: bytes) -> Any:
    return json.loads(text.decode("utf-8"))


def json_mutator(mutate: Callable[[bytes, int], bytes]) -> Callable[[bytes, int, int], bytes]:
    """atheris' custom_mutator for one JSON message; `mutate` is `atheris.Mutate`."""

    def mutator(data: bytes, max_size: int, seed: int) -> bytes:
        rng = random.Random(seed)
        if rng.random() < 0.75:
            try:
                out = mutate_tree(_parse(data), rng).encode("utf-8", "surrogatepass")
            except (ValueError, RecursionError):
                pass
            else:
                return out[:max_size]
        return mutate(data, max_size)

    return mutator


def jsonl_mutator(mutate: Callable[[bytes, int], bytes]) -> Callable[[bytes, int, int], bytes]:
    """atheris' custom_mutator for JSON Lines: one line mutated as a tree, else bytes."""

    def mutator(data: bytes, max_size: int, seed: int) -> bytes:
        rng = random.Random(seed)
        lines = data.split(b"\n")
        if rng.random() < 0.75 and lines:
            i = rng.randrange(len(lines))
            try:
                lines[i] = mutate_tree(_parse(lines[i]), rng).encode("utf-8", "surrogatepass")
            except (ValueError, RecursionError):
                pass
            else:
                if rng.random() < 0.2:  # a line repeated or moved
                    lines.insert(rng.randrange(len(lines) + 1), lines[i])
                return b"\n".join(lines)[:max_size]
        return mutate(data, max_size)

    return mutator
