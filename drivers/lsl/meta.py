"""What an LSL gaze stream's description says, without pylsl: the query, the channel layout, the
samples, and what gazehdr publishes.

A stream describes itself in XML (`<info>`: name, type, channel_count, channel_format, ...,
`<desc>`). The XDF "Gaze Meta-Data" conventions (sccn/xdf wiki) put a channel list in `desc`:
`<channels><channel><label/><eye/><type/><unit/><coordinate_system/></channel>...`, types
`ScreenX`, `ScreenY` (screen coordinates, "usually in pixels"), `Confidence` (normalised),
`Diameter` (pupil, mm or pixels), eye `left`, `right` or `both`. pyxdf gives the same tree as
nested dicts (`stream["info"]`), so `StreamDescription.of` reads both; `from_xml` parses the
text liblsl gives.

Real trackers' LSL apps follow the conventions only in part; `channel_layout` reads what they
publish (their sources were read for this, not run):

- Pupil Capture's relay (labstreaminglayer/App-PupilLabs, type `Gaze`): `norm_pos_x/y`,
  ScreenX/Y normalised, eye both, origin **bottom-left** (Pupil's "2D normalized space", as
  `gazehdr.drivers.formats.pupil` reads it); `confidence`; per-eye `Diameter` (pixels, and mm
  for 3d). Pupil Invisible's relay writes the type as `metatype` (`x`, `y`, pixels).
- Tobii Pro's app (labstreaminglayer/App-TobiiPro, type `Eyetracker`): `left_x`, `left_y`,
  `right_x`, `right_y` ScreenX/Y in unit `screencoords` (Tobii's active display area,
  normalised, origin top-left; NaN when invalid), `left_pupil`/`right_pupil` type `pupilsize`
  (mm).
- EyeLink's app (labstreaminglayer/App-EyeLink, type `Gaze`): every type `eyetracking`, so the
  labels say it: `leftEyeX`, `leftEyeY`, `rightEyeX`, `rightEyeY` (screen pixels),
  `leftPupilArea`, `rightPupilArea` (0 for an eye it does not track; EyeLink's missing-data
  values, -32768 and 1e8, likewise mark an eye with no gaze).
- Gazepoint's `LSLGazepoint.py` (type `gaze`): labels `BPOGX/Y` (best point of gaze), `FPOGX/Y`
  (fixation-filtered; used when no BPOG), `LPOGX/Y`, `RPOGX/Y`, fractions of the screen (its
  unit says "percent"), validity `BPOGV`, `FPOGV`, `LPOGV`, `RPOGV`, pupils `LPMM`/`RPMM` (mm).

A sample's position is the `both` eye's channels where valid, else the mean of the valid eyes;
invalid (NaN coordinates) when none is, or when the stream's confidence is below
`min_confidence`. Normalised coordinates scale by the screen's size in pixels. An eye's pupil
in mm (unit `mm`, type `pupilsize`) and one in any other unit (the tracker's own: EyeLink's
area, Pupil's or Gazepoint's camera pixels) are both kept, as `pupil_mm` and `pupil_au`.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.common import mean_of_eyes
from gazehdr.drivers.samples import EyeSample, GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import Record, decode_record, encode_record

#: Stream types that carry gaze: the XDF convention's, Gazepoint's app's, Tobii Pro's app's.
GAZE_TYPES = ("Gaze", "gaze", "Eyetracker")
#: What `lsl` alone resolves.
DEFAULT_PREDICATE = " or ".join(f"type='{t}'" for t in GAZE_TYPES)
#: Properties a query may name as `PROPERTY=VALUE`.
QUERY_PROPERTIES = ("name", "type", "source_id", "hostname", "uid", "session_id")
MIN_CONFIDENCE = 0.6  # Pupil Player's default, as gazehdr.drivers.formats.pupil
MAX_CHANNELS = 4096
_MAX_DEPTH = 16  # a description nested deeper than this is cut there
#: EyeLink's missing-data values: gaze at or beyond them is no gaze.
_MISSING_LOW, _MISSING_HIGH = -32768.0, 1e7


class LayoutError(InputError):
    """A stream whose description gazehdr cannot read gaze from; the text says why."""


# --- which stream -----------------------------------------------------------------------------


def xpath_literal(value: str) -> str:
    """`value` as an XPath string literal (no escapes exist: a value with both quotes can't be)."""
    if "'" not in value:
        return f"'{value}'"
    if '"' not in value:
        return f'"{value}"'
    raise InputError(f"an LSL query value cannot hold both kinds of quote: {value!r}")


def stream_predicate(query: str) -> str:
    """The liblsl predicate (XPath 1.0 over `<info>`) for an `lsl:QUERY` spec.

    Empty: a stream of a gaze type (`GAZE_TYPES`). `PROPERTY=VALUE` (`QUERY_PROPERTIES`): that
    property. A comparison with a quoted value: the predicate as written (`name='Tobii' and
    hostname='lab3'`). Anything else: the stream's name.
    """
    text = query.strip()
    if not text:
        return DEFAULT_PREDICATE
    if re.search(r"""[=<>]\s*['"]""", text):
        return text
    prop, sep, value = text.partition("=")
    if sep and prop.strip() in QUERY_PROPERTIES:
        if not value.strip():
            raise InputError(f"lsl:{text}: {prop.strip()}= needs a value")
        return f"{prop.strip()}={xpath_literal(value.strip())}"
    return f"name={xpath_literal(text)}"


# --- the description --------------------------------------------------------------------------


def _tree(element: ElementTree.Element, depth: int = 0) -> Any:
    """An element as pyxdf's `_xml2dict` gives it: children by tag, each a list; a leaf's text."""
    children = list(element)
    if not children or depth >= _MAX_DEPTH:
        return element.text
    out: dict[str, list[Any]] = {}
    for child in children:
        out.setdefault(str(child.tag), []).append(_tree(child, depth + 1))
    return out


def _first(tree: Any, key: str) -> Any:
    values = tree.get(key) if isinstance(tree, dict) else None
    return values[0] if isinstance(values, list) and values else None


def _text(tree: Any, key: str) -> str:
    value = _first(tree, key)
    return value.strip() if isinstance(value, str) else ""


def _texts(tree: Any) -> dict[str, str]:
    """A node's leaf children as {tag: text} (the first of each tag)."""
    if not isinstance(tree, dict):
        return {}
    return {key: _text(tree, key) for key in tree if isinstance(_first(tree, key), str)}


@dataclass(frozen=True)
class StreamDescription:
    """A stream's `<info>`: what LSL and XDF say about every stream, and its channel list.

    `channels` holds each `<channel>`'s text fields in order (empty where the description has
    none); `desc` the whole `<desc>` tree."""

    name: str
    type: str
    channel_count: int
    channel_format: str
    nominal_srate: float = 0.0
    source_id: str = ""
    hostname: str = ""
    channels: tuple[Mapping[str, str], ...] = ()
    desc: Any = None

    @classmethod
    def of(cls, info: Any) -> StreamDescription:
        """From an `<info>` tree (pyxdf's `stream["info"]`); LayoutError when it is not one."""
        if not isinstance(info, dict):
            raise LayoutError("a stream description is an <info> element with children")
        name = _text(info, "name") or "(unnamed)"
        count_text = _text(info, "channel_count")
        try:
            count = int(count_text)
        except ValueError:
            raise LayoutError(
                f"stream '{name}': channel_count {count_text!r} is not a whole number"
            ) from None
        if not 0 < count <= MAX_CHANNELS:
            raise LayoutError(f"stream '{name}': channel_count {count} (1 to {MAX_CHANNELS})")
        try:
            rate = float(_text(info, "nominal_srate") or 0.0)
        except ValueError:
            rate = 0.0
        desc = _first(info, "desc")
        listed = _first(desc, "channels")
        raw = listed.get("channel", []) if isinstance(listed, dict) else []
        channels = tuple(_texts(c) for c in raw) if isinstance(raw, list) else ()
        return cls(
            name=name,
            type=_text(info, "type"),
            channel_count=count,
            channel_format=_text(info, "channel_format") or "float32",
            nominal_srate=rate if math.isfinite(rate) and rate > 0 else 0.0,
            source_id=_text(info, "source_id"),
            hostname=_text(info, "hostname"),
            channels=channels,
            desc=desc,
        )

    @classmethod
    def from_xml(cls, text: str) -> StreamDescription:
        """From the XML text liblsl gives (`StreamInfo.as_xml()`)."""
        try:
            root = ElementTree.fromstring(text)
        except ElementTree.ParseError as e:
            raise LayoutError(f"the stream's description is not XML: {e}") from None
        if root.tag != "info":
            raise LayoutError(f"the stream's description is <{root.tag}>, not <info>")
        return cls.of(_tree(root))

    def title(self) -> str:
        """How messages name the stream: name, type, channels, host."""
        host = f" on {self.hostname}" if self.hostname else ""
        kind = f"{self.type}, " if self.type else ""
        plural = "s" if self.channel_count != 1 else ""
        count = f"{self.channel_count} {self.channel_format} channel{plural}"
        return f"'{self.name}' ({kind}{count}{host})"

    def pinned_predicate(self) -> str:
        """The predicate that finds this very stream again: its source_id, else name and host."""
        if self.source_id:
            return f"source_id={xpath_literal(self.source_id)}"
        return f"name={xpath_literal(self.name)} and hostname={xpath_literal(self.hostname)}"

    def desc_text(self, *path: str) -> str:
        """The text at `path` under `<desc>` (the first element of each name), or ""."""
        node = self.desc
        for key in path[:-1]:
            node = _first(node, key)
        return _text(node, path[-1]) if path else ""

    def acquisition(self) -> dict[str, str]:
        """The `<acquisition>` fields (manufacturer, model, ...) where the stream gives them."""
        return _texts(_first(self.desc, "acquisition"))


# --- the channel layout -----------------------------------------------------------------------

_TYPES = {
    "screenx": "x",
    "screeny": "y",
    "confidence": "confidence",
    "diameter": "pupil",
    "pupilsize": "pupil",  # Tobii Pro's app
    "validity": "validity",
}
_EYES = {"left": "left", "right": "right", "both": "both", "l": "left", "r": "right"}
_GAZEPOINT_EYES = {"b": "both", "f": "both", "l": "left", "r": "right"}
_PIXELS = {"pixels", "pixel", "px"}
#: Units of normalised screen coordinates: the convention's, Tobii Pro's app's
#: (`screencoords`), Gazepoint's app's (`percent`, for fractions of the screen).
_NORMALIZED = {"normalized", "normalised", "norm", "screencoords", "percent"}


@dataclass(frozen=True)
class _Role:
    """What one channel is: its eye, role (x, y, pupil, confidence, validity), group (channels
    of one group go together: Gazepoint's B, F, L, R), rank (lower wins), default unit."""

    eye: str
    role: str
    group: str = ""
    rank: int = 1
    normalized: bool = False
    y_up: bool = False


def _by_label(label: str) -> _Role | None:
    """The role the label names, for apps that do not give a conventional type."""
    text = label.strip().lower()
    if m := re.fullmatch(r"(left|right)_?(?:eye_?)?(?:gaze_?)?([xy])", text):
        return _Role(m[1], m[2])
    if m := re.fullmatch(r"(?:gaze_?|screen_?)?([xy])", text):
        return _Role("both", m[1])
    if m := re.fullmatch(r"norm_pos_([xy])", text):  # Pupil: normalised, origin bottom-left
        return _Role("both", m[1], normalized=True, y_up=True)
    if m := re.fullmatch(r"([bflr])pog([xyv])", text):  # Gazepoint
        role = {"x": "x", "y": "y", "v": "validity"}[m[2]]
        return _Role(_GAZEPOINT_EYES[m[1]], role, m[1], 2 if m[1] == "f" else 1, True)
    if m := re.fullmatch(r"(left|right)_?pupil(?:_?(?:area|size|diameter))?", text):
        return _Role(m[1], "pupil")
    if m := re.fullmatch(r"([lr])pmm", text):  # Gazepoint, mm
        return _Role(_EYES[m[1]], "pupil", rank=0)
    if m := re.fullmatch(r"([lr])pd", text):  # Gazepoint, camera pixels
        return _Role(_EYES[m[1]], "pupil")
    return None


def _role(channel: Mapping[str, str]) -> _Role | None:
    """A channel's role: by its conventional type (and eye), else by its label; a pupil not in
    mm is the role `pupil_au` (the tracker's own units), kept beside one in mm."""
    label = channel.get("label", "")
    by_label = _by_label(label) if label else None
    kind = (channel.get("type") or channel.get("metatype") or "").lower()
    role = _TYPES.get(kind)
    if role is None:
        base = by_label
    else:
        eye = _EYES.get(channel.get("eye", "").lower()) or (by_label.eye if by_label else "both")
        same = by_label is not None and by_label.role == role
        base = replace(by_label, eye=eye) if same else _Role(eye, role, rank=0)
    if base is None or base.role != "pupil":
        return base
    mm = channel.get("unit", "").lower() == "mm" or kind == "pupilsize" or base.rank == 0
    return base if mm else replace(base, role="pupil_au")


@dataclass(frozen=True)
class EyeChannels:
    """Where one eye's gaze is in a sample: x and y (normalised or pixels, y up or down), its
    pupil in mm and in the tracker's own units, and the channels that say it has none
    (validity at least 0.5, a pupil of 0)."""

    x: int
    y: int
    normalized: bool = False
    y_up: bool = False
    validity: int | None = None
    pupil_mm: int | None = None
    pupil_au: int | None = None
    confidence: int | None = None

    def read(
        self, values: Sequence[float], geometry: ScreenGeometry, min_confidence: float
    ) -> EyeSample | None:
        """This eye in `values` (screen pixels), or None when it has no valid gaze."""
        x, y = float(values[self.x]), float(values[self.y])
        if not (math.isfinite(x) and math.isfinite(y)):
            return None
        if self.validity is not None and not _at_least(values[self.validity], 0.5):
            return None
        if self.confidence is not None and not _at_least(values[self.confidence], min_confidence):
            return None
        mm, au = (
            float(values[i]) if i is not None else math.nan for i in (self.pupil_mm, self.pupil_au)
        )
        if mm == 0.0 or au == 0.0:  # no pupil: the eye is closed or not tracked
            return None
        if self.normalized:
            w, h = geometry.screen_width_px, geometry.screen_height_px
            x, y = x * w, ((1.0 - y) if self.y_up else y) * h
        elif min(x, y) <= _MISSING_LOW or max(x, y) >= _MISSING_HIGH:
            return None
        # in mm, and in the tracker's own units (EyeLink's area, Pupil Core's pixels)
        return EyeSample(x, y, mm if math.isfinite(mm) else None, au if math.isfinite(au) else None)


def _at_least(value: float, threshold: float) -> bool:
    v = float(value)
    return math.isfinite(v) and v >= threshold


@dataclass(frozen=True)
class ChannelLayout:
    """Which channels of a stream hold which eye's gaze; `sample` reads one sample with it."""

    stream: StreamDescription
    eyes: Mapping[str, EyeChannels]
    confidence: int | None = None
    ignored: tuple[str, ...] = field(default=())

    def sample(
        self,
        values: Sequence[float],
        t_ns: int,
        geometry: ScreenGeometry,
        min_confidence: float = MIN_CONFIDENCE,
    ) -> GazeSample:
        """One sample's values (in channel order) at `t_ns` as a `GazeSample` in pixels."""
        if len(values) != self.stream.channel_count:
            raise LayoutError(
                f"stream '{self.stream.name}': a sample of {len(values)} values, "
                f"{self.stream.channel_count} expected"
            )
        read = {eye: c.read(values, geometry, min_confidence) for eye, c in self.eyes.items()}
        left, right = read.get("left"), read.get("right")
        confident = self.confidence is None or _at_least(values[self.confidence], min_confidence)
        both = read.get("both")
        point = (both.x, both.y) if both is not None else mean_of_eyes(left, right)
        if point is None or not confident:
            return GazeSample(int(t_ns), math.nan, math.nan, False)
        return GazeSample(int(t_ns), point[0], point[1], True, left, right)

    def describe(self) -> dict[str, Any]:
        """The layout as a session log header keeps it: each eye's channel labels and units."""
        labels = [c.get("label", "") or f"#{i}" for i, c in enumerate(self.stream.channels)]
        out: dict[str, Any] = {}
        for eye, c in self.eyes.items():
            unit = "normalized" + (" (origin bottom-left)" if c.y_up else "")
            out[eye] = {"x": labels[c.x], "y": labels[c.y]} | {
                "unit": unit if c.normalized else "pixels"
            }
        if self.confidence is not None:
            out["confidence"] = labels[self.confidence]
        if self.ignored:
            out["ignored"] = list(self.ignored)
        return out


def channel_layout(stream: StreamDescription) -> ChannelLayout:
    """Read the channel layout from a stream's description; LayoutError when no eye's screen
    x and y can be found (naming what the stream has)."""
    if stream.channel_format == "string":
        raise LayoutError(f"stream {stream.title()} carries text, not gaze")
    if stream.channels and len(stream.channels) != stream.channel_count:
        raise LayoutError(
            f"stream {stream.title()}: its description lists {len(stream.channels)} channels"
        )
    best: dict[tuple[str, str], tuple[int, int, _Role]] = {}
    ignored: list[str] = []
    for index, channel in enumerate(stream.channels):
        role = _role(channel)
        if role is None:
            continue
        if role.role in ("x", "y"):
            unit = channel.get("unit", "").lower()
            if unit and unit not in _PIXELS | _NORMALIZED:
                ignored.append(f"{channel.get('label') or index}: unit {unit!r}")
                continue
            if unit:
                role = replace(role, normalized=unit in _NORMALIZED)
        key = (role.eye, role.role)
        if key not in best or role.rank < best[key][0]:
            best[key] = (role.rank, index, role)
    eyes: dict[str, EyeChannels] = {}
    for eye in ("both", "left", "right"):
        x, y = best.get((eye, "x")), best.get((eye, "y"))
        if x is None or y is None:
            continue
        validity = best.get((eye, "validity"))
        mm, au = best.get((eye, "pupil")), best.get((eye, "pupil_au"))
        confidence = best.get((eye, "confidence")) if eye != "both" else None
        eyes[eye] = EyeChannels(
            x[1],
            y[1],
            normalized=x[2].normalized,
            y_up=y[2].y_up,
            validity=validity[1] if validity and validity[2].group == x[2].group else None,
            pupil_mm=mm[1] if mm else None,
            pupil_au=au[1] if au else None,
            confidence=confidence[1] if confidence else None,
        )
    if not eyes:
        raise LayoutError(_no_gaze(stream, ignored))
    confidence = best.get(("both", "confidence"))
    return ChannelLayout(stream, eyes, confidence[1] if confidence else None, tuple(ignored))


def _no_gaze(stream: StreamDescription, ignored: list[str]) -> str:
    if not stream.channels:
        found = "no <desc><channels> description"
    else:
        found = "channels " + ", ".join(
            f"{c.get('label') or '?'} ({c.get('type') or c.get('metatype') or 'no type'})"
            for c in stream.channels[:12]
        )
        found += ", ..." if len(stream.channels) > 12 else ""
    why = f"; ignored {', '.join(ignored)}" if ignored else ""
    return (
        f"stream {stream.title()} has no usable gaze channels: expected a ScreenX and a "
        f"ScreenY channel (XDF gaze meta-data; unit pixels or normalized), found {found}{why}"
    )


# --- what gazehdr publishes -------------------------------------------------------------------


def _channel(label: str, eye: str, kind: str, unit: str) -> dict[str, str]:
    return {"label": label, "eye": eye, "type": kind, "unit": unit}


#: The gaze outlet's channels, in order: the convention's fields, readable by `channel_layout`.
OUTLET_CHANNELS: tuple[dict[str, str], ...] = (
    _channel("x", "both", "ScreenX", "pixels"),
    _channel("y", "both", "ScreenY", "pixels"),
    _channel("confidence", "both", "Confidence", "normalized"),
    _channel("left_x", "left", "ScreenX", "pixels"),
    _channel("left_y", "left", "ScreenY", "pixels"),
    _channel("left_pupil", "left", "Diameter", "mm"),
    _channel("right_x", "right", "ScreenX", "pixels"),
    _channel("right_y", "right", "ScreenY", "pixels"),
    _channel("right_pupil", "right", "Diameter", "mm"),
    # the pupil in the tracker's own units (EyeLink's area or diameter), as a recording has it
    _channel("left_pupil_size", "left", "Diameter", "a.u."),
    _channel("right_pupil_size", "right", "Diameter", "a.u."),
)


def _eye_values(eye: EyeSample | None) -> list[float]:
    if eye is None:
        return [math.nan] * 3
    pupil = eye.pupil_mm if eye.pupil_mm is not None else math.nan
    return [eye.x, eye.y, pupil]


def _au(eye: EyeSample | None) -> float:
    return eye.pupil_au if eye is not None and eye.pupil_au is not None else math.nan


def outlet_values(sample: GazeSample) -> list[float]:
    """A sample as the gaze outlet's values (`OUTLET_CHANNELS`); NaN where there is none."""
    if not sample.valid:
        return [math.nan, math.nan, 0.0, *[math.nan] * 8]
    left, right = sample.left, sample.right
    return [sample.x, sample.y, 1.0, *_eye_values(left), *_eye_values(right), _au(left), _au(right)]


def marker_text(record: Any) -> str:
    """A record (an event, a note, ...) as the marker stream's string: its session log JSON
    (TypeError for what a session log does not hold)."""
    return json.dumps(encode_record(record), separators=(",", ":"))


def marker_record(text: str, t_ns: int, path: Path, index: int) -> Record:
    """A marker string of gazehdr's marker stream as its record at `t_ns` (the marker's time,
    not the one in the text); FormatError naming the file and the marker's `index` when it is
    not one."""
    try:
        obj = json.loads(text)
    except (ValueError, RecursionError):  # not JSON (or nested past the parser's depth)
        obj = text
    if isinstance(obj, dict):
        obj = {**obj, "t": int(t_ns)}
    return decode_record(obj, path, index)
