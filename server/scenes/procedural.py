"""Built-in procedural scenes in absolute units (cd/m^2), drawn at the size asked for.

Positions are fractions of the frame (x right, y down, 0..1); sizes are fractions of the frame
height, so round things stay round at any aspect ratio. Edges are anti-aliased by exact box
coverage (a pixel half covered by a 1e7 cd/m^2 flash gets 5e6), except markers whose luminance
matters more than their exact size (the flash head, the fixation cross): their edges are rounded
to whole pixels and they are at least one pixel wide, so even a thumbnail shows them crisp and
at full luminance.

Colours are linear Rec.709; a number given for a surface is its photopic luminance
Y = 0.2126 R + 0.7152 G + 0.0722 B, whatever its tint. Scenes are deterministic (no random
state), and each keeps its last few frames: `render` costs a copy unless the size or the scene's
state (flash on/off, before/after the switch) changed.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass, field
from numbers import Integral
from typing import ClassVar

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.scenes.exr import MAX_PIXELS
from gazehdr.scenes.scene import Scene

#: Rec.709 photopic luminance weights.
LUMA = np.array([0.2126, 0.7152, 0.0722])

#: ColorChecker Classic patches 1-24 (reading order, white at the start of the bottom row) as
#: 8-bit sRGB (D65): BabelColor's averaged measurements, D. Pascale, "RGB coordinates of the
#: Macbeth ColorChecker", The BabelColor Company, 2006 (the values X-Rite's charts are made to).
COLORCHECKER_SRGB8: tuple[tuple[int, int, int], ...] = (
    (115, 82, 68),  # dark skin
    (194, 150, 130),  # light skin
    (98, 122, 157),  # blue sky
    (87, 108, 67),  # foliage
    (133, 128, 177),  # blue flower
    (103, 189, 170),  # bluish green
    (214, 126, 44),  # orange
    (80, 91, 166),  # purplish blue
    (193, 90, 99),  # moderate red
    (94, 60, 108),  # purple
    (157, 188, 64),  # yellow green
    (224, 163, 46),  # orange yellow
    (56, 61, 150),  # blue
    (70, 148, 73),  # green
    (175, 54, 60),  # red
    (231, 199, 31),  # yellow
    (187, 86, 149),  # magenta
    (8, 133, 161),  # cyan
    (243, 243, 242),  # white 9.5
    (200, 200, 200),  # neutral 8
    (160, 160, 160),  # neutral 6.5
    (122, 122, 121),  # neutral 5
    (85, 85, 85),  # neutral 3.5
    (52, 52, 52),  # black 2
)
_WHITE_PATCH = 18

Rect = tuple[float, float, float, float]


def _colour(luminance: float, tint: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> np.ndarray:
    """RGB of the given tint whose photopic luminance is `luminance`."""
    rgb = np.asarray(tint, dtype=np.float64)
    return luminance * rgb / (LUMA @ rgb)


def srgb_to_linear(srgb8: np.ndarray) -> np.ndarray:
    """8-bit sRGB code values → linear light in 0..1 (the sRGB EOTF, IEC 61966-2-1)."""
    c = np.asarray(srgb8, dtype=np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _span(a0: float, a1: float, n: int, snap: bool) -> tuple[slice, np.ndarray]:
    """The pixels of `n` that the interval [a0, a1] (frame fractions) touches, and how much of
    each it covers. With `snap`, its ends are rounded to pixel edges, keeping at least the pixel
    that holds its middle."""
    lo, hi = a0 * n, a1 * n
    if snap:
        middle = min(max(math.floor((lo + hi) / 2), 0), n - 1)
        lo, hi = min(math.floor(lo + 0.5), middle), max(math.floor(hi + 0.5), middle + 1)
    i = np.arange(max(math.floor(lo), 0), min(math.ceil(hi), n))
    index = slice(int(i[0]), int(i[-1]) + 1) if i.size else slice(0, 0)
    return index, np.clip(np.minimum(hi, i + 1) - np.maximum(lo, i), 0, 1)


#: A colour: an RGB triple, or a function of pixel coordinates (u, v) giving an RGB field.
_Colour = np.ndarray | Callable[[np.ndarray, np.ndarray], np.ndarray]


class _Canvas:
    """A float32 RGB frame and the few anti-aliased primitives the scenes need.

    `u` and `v` are pixel-centre coordinates in frame heights: `u` from the vertical centre
    line, `v` from the top, so distances computed from them are isotropic. Shapes only touch
    the pixels around them, which keeps a full-HD frame well under a second.
    """

    def __init__(self, width: int, height: int, background: np.ndarray) -> None:
        self.width, self.height = width, height
        self.aspect = width / height
        u = ((np.arange(width) + 0.5) / width - 0.5) * self.aspect
        self.u = u.astype(np.float32)[None, :]
        self.v = ((np.arange(height) + 0.5) / height).astype(np.float32)[:, None]
        self.image = np.empty((height, width, 3), dtype=np.float32)
        self.image[:] = background

    def rect(self, cx: float, cy: float, half_w: float, half_h: float) -> Rect:
        """The rectangle centred at frame fractions (cx, cy) with half sizes in frame heights."""
        return (cx - half_w / self.aspect, cy - half_h, cx + half_w / self.aspect, cy + half_h)

    def box(self, rect: Rect, colour: _Colour, *, snap: bool = False) -> None:
        """Paint a rectangle (frame fractions) with exact pixel coverage."""
        x0, y0, x1, y1 = rect
        (cols, cx), (rows, cy) = _span(x0, x1, self.width, snap), _span(y0, y1, self.height, snap)
        self._paint(rows, cols, cy[:, None] * cx[None, :], colour)

    def shape(
        self, bounds: Rect, inside: Callable[[np.ndarray, np.ndarray], np.ndarray], colour: _Colour
    ) -> None:
        """Paint the shape whose signed distance (frame heights, positive inside) is
        `inside(u, v)`; `bounds` (frame fractions) must contain it."""
        x0, y0, x1, y1 = bounds
        pad = 1 / self.height  # room for the edge ramp
        (cols, _), (rows, _) = (
            _span(x0 - pad / self.aspect, x1 + pad / self.aspect, self.width, False),
            _span(y0 - pad, y1 + pad, self.height, False),
        )
        d = inside(self.u[:, cols], self.v[rows, :])
        self._paint(rows, cols, np.clip(d * self.height + 0.5, 0.0, 1.0), colour)

    def disc(self, cx: float, cy: float, radius: float, colour: _Colour) -> None:
        """Paint a disc centred at frame fractions (cx, cy), radius in frame heights."""
        uc = (cx - 0.5) * self.aspect
        self.shape(
            self.rect(cx, cy, radius, radius),
            lambda u, v: radius - np.hypot(u - uc, v - cy),
            colour,
        )

    def _paint(self, rows: slice, cols: slice, coverage: np.ndarray, colour: _Colour) -> None:
        if callable(colour):
            colour = colour(self.u[:, cols], self.v[rows, :])
        img = self.image[rows, cols]
        img += np.broadcast_to(coverage, img.shape[:2])[..., None] * (colour - img)


def _log_mix(lo: float, hi: float, g: np.ndarray) -> np.ndarray:
    """`lo` at g = 0 to `hi` at g = 1, evenly in log luminance."""
    return lo * (hi / lo) ** g


def _require_positive(obj: object, *names: str) -> None:
    for n in names:
        value = getattr(obj, n)
        for x in value if isinstance(value, tuple) else (value,):
            if not (math.isfinite(x) and x > 0):
                raise InputError(f"{type(obj).__name__}.{n} must be positive and finite: {value}")


@dataclass(frozen=True, kw_only=True)
class _Procedural:
    """Common part: size checks and the per-(size, state) frame cache."""

    name: str = field(init=False)
    animated: bool = field(default=False, init=False)
    _cache: dict[tuple[int, int, object], np.ndarray] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

    def render(self, t: float, width: int, height: int) -> np.ndarray:
        """H×W×3 float32 radiance in cd/m^2 at time `t` seconds (a fresh array each call)."""
        if not (isinstance(width, Integral) and isinstance(height, Integral)):
            raise TypeError(f"{self.name}: size must be integers, got {width!r}×{height!r}")
        width, height = int(width), int(height)
        if width <= 0 or height <= 0:
            raise InputError(f"{self.name}: size must be positive, got {width}×{height}")
        if width * height > MAX_PIXELS:
            raise InputError(f"{self.name}: {width}×{height} is over {MAX_PIXELS:,} pixels")
        key = (width, height, self.state_at(t))
        frame = self._cache.get(key)
        if frame is None:
            if any(k[:2] != (width, height) for k in self._cache):
                self._cache.clear()
            frame = self._draw(width, height, key[2]).astype(np.float32, copy=False)
            self._cache[key] = frame
        return frame.copy()

    def state_at(self, t: float) -> object:
        """What `render` depends on besides the size (static scenes: nothing)."""
        return None

    def next_change(self, t: float) -> float | None:
        """The first time after `t` at which `state_at` changes (None: never)."""
        return None

    def _draw(self, width: int, height: int, state: object) -> np.ndarray:
        raise NotImplementedError


@dataclass(frozen=True, kw_only=True)
class Flash(_Procedural):
    """A camera flash on a dark wall: the biggest, briefest stimulus, for bleaching afterimages.

    A photographer's camera in a dim room (plaster wall ~0.7-1.3 cd/m^2 with a picture, a door
    and a floor, all within 0.5-2; the black camera 0.08-0.3). The flash head fires for
    `duration` (1/8 s) every `period` seconds from `first`: a xenon flash seen head-on is of the
    order of 1e7 cd/m^2 (neutral white), its reflector rim glowing 1e5 at the head down to 1e4 at
    `halo_radius`. Off, the head is a grey diffuser. Its position is `flash_centre` (frame
    fractions), its size `flash_half_size` (frame heights).
    """

    name: str = field(default="flash", init=False)
    animated: bool = field(default=True, init=False)
    period: float = 4.0
    first: float = 1.0
    duration: float = 0.125
    flash_luminance: float = 1e7
    #: Reflector glow at the edge of the head and at `halo_radius` from it.
    halo_luminance: tuple[float, float] = (1e5, 1e4)
    halo_radius: float = 0.03
    wall_luminance: float = 1.0
    flash_centre: tuple[float, float] = (0.5, 0.42)
    #: Half width and half height of the flash head, in frame heights.
    flash_half_size: tuple[float, float] = (0.03, 0.012)

    def __post_init__(self) -> None:
        _require_positive(self, "period", "duration", "flash_luminance", "halo_luminance")
        _require_positive(self, "halo_radius", "wall_luminance", "flash_half_size")
        if self.duration >= self.period:
            raise InputError("Flash.duration must be shorter than Flash.period")
        if not math.isfinite(self.first):
            raise InputError(f"Flash.first must be finite: {self.first}")

    def flash_on(self, t: float) -> bool:
        """Whether the flash is firing at `t`: for [first + k·period, + duration), k ≥ 0."""
        return t >= self.first and (t - self.first) % self.period < self.duration

    def state_at(self, t: float) -> bool:
        return self.flash_on(t)

    def next_change(self, t: float) -> float | None:
        if t < self.first:
            return self.first
        k, phase = divmod(t - self.first, self.period)
        start = self.first + k * self.period
        return start + self.duration if phase < self.duration else start + self.period

    def _draw(self, width: int, height: int, state: object) -> np.ndarray:
        wall = self.wall_luminance
        c = _Canvas(width, height, _colour(wall, (0.92, 0.97, 1.06)))
        u, v, two_pi = c.u, c.v, 2 * np.pi
        # Plaster: +-25 % blotches and a +-8 % fine grain.
        texture = 1 + 0.25 * np.sin(two_pi * (2.3 * u + 0.6 * v)) * np.sin(
            two_pi * (1.7 * v - 0.5 * u)
        )
        c.image *= (texture + 0.08 * np.sin(two_pi * 23 * u) * np.sin(two_pi * 19 * v))[..., None]
        c.box((0, 0.80, 1, 0.82), _colour(1.6 * wall))  # skirting board
        c.box((0, 0.82, 1, 1), _colour(0.6 * wall, (1.0, 0.8, 0.6)))  # floor
        c.box(c.rect(0.2, 0.33, 0.16, 0.12), _colour(0.5 * wall, (1.0, 0.75, 0.5)))  # frame
        c.box(c.rect(0.2, 0.28, 0.14, 0.05), _colour(1.8 * wall, (0.7, 0.85, 1.1)))  # sky
        c.box(c.rect(0.2, 0.38, 0.14, 0.05), _colour(1.1 * wall, (0.6, 1.0, 0.5)))  # meadow
        c.disc(0.2 + 0.07 / c.aspect, 0.27, 0.025, _colour(2.0 * wall, (1.0, 0.9, 0.6)))  # sun
        c.box(c.rect(0.84, 0.49, 0.13, 0.31), _colour(0.8 * wall, (1.0, 0.85, 0.7)))  # door
        c.disc(0.84 - 0.1 / c.aspect, 0.5, 0.012, _colour(1.8 * wall))  # door knob

        cx, cy = self.flash_centre
        hw, hh = self.flash_half_size
        c.box(c.rect(cx, cy + hh + 0.085, 0.09, 0.06), _colour(0.15))  # camera body
        c.box(c.rect(cx, cy + hh + 0.01, 0.012, 0.012), _colour(0.15))  # hot shoe
        c.disc(cx, cy + hh + 0.09, 0.04, _colour(0.3))  # lens barrel
        c.disc(cx, cy + hh + 0.09, 0.028, _colour(0.08, (0.8, 0.9, 1.2)))  # lens glass
        head = c.rect(cx, cy, hw, hh)
        if not state:
            c.box(head, _colour(1.5), snap=True)  # a grey diffuser in room light
            return c.image
        uc, radius = (cx - 0.5) * c.aspect, self.halo_radius

        def outside_head(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            """Distance from the head rectangle, in frame heights (0 inside)."""
            return np.hypot(np.maximum(np.abs(u - uc) - hw, 0), np.maximum(np.abs(v - cy) - hh, 0))

        c.shape(
            c.rect(cx, cy, hw + radius, hh + radius),
            lambda u, v: radius - outside_head(u, v),
            lambda u, v: (
                _log_mix(*self.halo_luminance, outside_head(u, v) / radius)[..., None]
                * _colour(1.0)
            ),
        )
        c.box(head, _colour(self.flash_luminance), snap=True)
        return c.image


@dataclass(frozen=True, kw_only=True)
class Lamp(_Procedural):
    """A bare lamp over an open book in a dim room: seven decades in one view.

    The bulb (1e6 cd/m^2, a frosted incandescent bulb) peeks out under a translucent shade that
    glows 1e3 at the top to 1e4 at its rim; the book's pages under it are ~1e2 (paper at a few
    hundred lux) with text lines at 6 % of the paper, fine detail for acuity; the desk is 3-30
    and the walls fall from 1 beside the lamp to 0.1 in the far corners.
    """

    name: str = field(default="lamp", init=False)
    bulb_luminance: float = 1e6
    #: Shade glow at its top and at its bottom rim.
    shade_luminance: tuple[float, float] = (1e3, 1e4)
    page_luminance: float = 100.0
    ink_fraction: float = 0.06
    #: Wall in the far corners and beside the lamp.
    wall_luminance: tuple[float, float] = (0.1, 1.0)
    #: Desk at its edges and under the lamp.
    desk_luminance: tuple[float, float] = (3.0, 30.0)

    bulb_centre: ClassVar[tuple[float, float]] = (0.5, 0.36)
    book_centre: ClassVar[tuple[float, float]] = (0.5, 0.85)

    def __post_init__(self) -> None:
        _require_positive(self, "bulb_luminance", "shade_luminance", "page_luminance")
        _require_positive(self, "ink_fraction", "wall_luminance", "desk_luminance")

    def _draw(self, width: int, height: int, state: object) -> np.ndarray:
        bx, by = self.bulb_centre
        px, py = self.book_centre
        c = _Canvas(width, height, _colour(1.0, (1.0, 0.93, 0.82)))
        near = np.clip(1 - np.hypot(c.u - (bx - 0.5) * c.aspect, c.v - by + 0.06) / 0.8, 0, 1)
        c.image *= _log_mix(*self.wall_luminance, near**2)[..., None]

        def desk(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            lit = np.exp(-((u - (px - 0.5) * c.aspect) ** 2 + (v - py) ** 2) / 0.35**2)
            return _log_mix(*self.desk_luminance, lit)[..., None] * _colour(1.0, (1, 0.7, 0.45))

        c.box((0, 0.7, 1, 1), desk)

        top, bottom = by - 0.2, by
        c.box(c.rect(bx, top / 2, 0.004, top / 2), _colour(0.3))  # cord
        c.disc(bx, by, 0.06, _colour(self.bulb_luminance, (1.0, 0.8, 0.55)))
        uc = (bx - 0.5) * c.aspect

        def shade_inside(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            """Signed distance into the trapezoid (0.07 to 0.17 half width, top to bottom)."""
            half_width = 0.07 + 0.1 * np.clip((v - top) / (bottom - top), 0, 1)
            return np.minimum(half_width - np.abs(u - uc), np.minimum(v - top, bottom - v))

        def shade(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            s = np.clip((v - top) / (bottom - top), 0, 1)
            return _log_mix(*self.shade_luminance, s)[..., None] * _colour(1.0, (1, 0.85, 0.6))

        c.shape(c.rect(bx, (top + bottom) / 2, 0.17, 0.1), shade_inside, shade)

        c.box(c.rect(px, py, 0.335, 0.12), _colour(8.0, (1.0, 0.35, 0.3)))  # cover

        def paper(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            page = self.page_luminance * (1 - 0.2 * ((u - (px - 0.5) * c.aspect) / 0.32) ** 2)
            return page[..., None] * _colour(1.0, (1.0, 0.96, 0.88))

        ink = _colour(self.page_luminance * self.ink_fraction)
        words = random.Random(2015)  # a fixed layout: the same text at every size
        for side in (-1, 1):
            x0, x1 = sorted((px + side * 0.005 / c.aspect, px + side * 0.32 / c.aspect))
            c.box((x0, py - 0.11, x1, py + 0.11), paper)
            for line in range(13):
                y = py - 0.09 + 0.014 * line
                x, end = x0 + 0.03 / c.aspect, x1 - (0.15 if line == 12 else 0.03) / c.aspect
                while True:
                    length = words.uniform(0.015, 0.06) / c.aspect
                    if x + length > end:
                        break
                    c.box((x, y, x + length, y + 0.006), ink)
                    x += length + 0.01 / c.aspect
        c.box(c.rect(px, py, 0.005, 0.11), _colour(0.3 * self.page_luminance))  # gutter
        return c.image


@dataclass(frozen=True, kw_only=True)
class CheckerNight(_Procedural):
    """A ColorChecker at night (the paper's Fig. 11): colours fade and shift towards blue.

    24 patches (COLORCHECKER_SRGB8) decoded to linear and scaled so the white patch (bottom-left)
    has luminance `white_luminance` (0.05 cd/m^2, mesopic: Purkinje shift and loss of colour),
    on a dark grey ground at `background_fraction` of the white.
    """

    name: str = field(default="checker-night", init=False)
    white_luminance: float = 0.05
    background_fraction: float = 0.1

    #: Gap between patches (and around the chart), in patch sizes.
    gap: ClassVar[float] = 0.25

    def __post_init__(self) -> None:
        _require_positive(self, "white_luminance", "background_fraction")

    @property
    def patch_rgb(self) -> np.ndarray:
        """24×3 linear RGB of the patches in cd/m^2, reading order."""
        linear = srgb_to_linear(np.array(COLORCHECKER_SRGB8))
        return linear * (self.white_luminance / (LUMA @ linear[_WHITE_PATCH]))

    def patch_rects(self, width: int, height: int) -> list[Rect]:
        """(x0, y0, x1, y1) of the 24 patches in frame fractions, reading order (6 × 4)."""
        aspect, g = width / height, self.gap
        size = min(0.8 / (4 + 5 * g), 0.92 * aspect / (6 + 7 * g))
        left, top = -(6 + 7 * g) * size / 2, 0.5 - (4 + 5 * g) * size / 2
        rects = []
        for i in range(24):
            row, col = divmod(i, 6)
            u = left + (g + col * (1 + g)) * size
            y = top + (g + row * (1 + g)) * size
            rects.append((0.5 + u / aspect, y, 0.5 + (u + size) / aspect, y + size))
        return rects

    def _draw(self, width: int, height: int, state: object) -> np.ndarray:
        c = _Canvas(width, height, _colour(self.background_fraction * self.white_luminance))
        for rect, rgb in zip(self.patch_rects(width, height), self.patch_rgb, strict=True):
            c.box(rect, rgb)
        return c.image


@dataclass(frozen=True, kw_only=True)
class AdaptationCross(_Procedural):
    """The paper's Fig. 3(b)/(c): fixate the cross, then see the checkerboard reversed.

    A checkerboard of `columns` × `rows` (2 × 2 quadrants, top-left light) at 300 and 30 cd/m^2
    (one decade, both photopic) with a dark fixation cross at the centre; from `switch_at`
    seconds it is replaced by a uniform field at `grey_luminance` (default the geometric mean,
    ~95, where each half of the retina is equally far from its adaptation) with the same cross,
    so the local adaptation shows as a negative afterimage.
    """

    name: str = field(default="adaptation-cross", init=False)
    animated: bool = field(default=True, init=False)
    light_luminance: float = 300.0
    dark_luminance: float = 30.0
    grey_luminance: float | None = None
    switch_at: float = 6.0
    cross_luminance: float = 1.0
    #: Half length of the cross arms and their thickness, in frame heights.
    cross_size: float = 0.04
    cross_thickness: float = 0.008
    columns: int = 2
    rows: int = 2

    def __post_init__(self) -> None:
        if self.grey_luminance is None:
            object.__setattr__(
                self, "grey_luminance", math.sqrt(self.light_luminance * self.dark_luminance)
            )
        _require_positive(self, "light_luminance", "dark_luminance", "grey_luminance")
        _require_positive(self, "cross_luminance", "cross_size", "cross_thickness")
        _require_positive(self, "columns", "rows")

    def state_at(self, t: float) -> bool:
        return t >= self.switch_at

    def next_change(self, t: float) -> float | None:
        return self.switch_at if t < self.switch_at else None

    def _draw(self, width: int, height: int, state: object) -> np.ndarray:
        if state:
            c = _Canvas(width, height, _colour(self.grey_luminance))
        else:
            c = _Canvas(width, height, _colour(self.dark_luminance))
            light = _colour(self.light_luminance)
            for j in range(self.rows):
                for i in range(j % 2, self.columns, 2):
                    c.box(
                        (
                            i / self.columns,
                            j / self.rows,
                            (i + 1) / self.columns,
                            (j + 1) / self.rows,
                        ),
                        light,
                    )
        ink, arm, half = _colour(self.cross_luminance), self.cross_size, self.cross_thickness / 2
        c.box(c.rect(0.5, 0.5, arm, half), ink, snap=True)
        c.box(c.rect(0.5, 0.5, half, arm), ink, snap=True)
        return c.image


#: Built-in scenes by name: zero-argument factories with the documented defaults.
BUILTIN: dict[str, Callable[[], Scene]] = {
    "flash": Flash,
    "lamp": Lamp,
    "checker-night": CheckerNight,
    "adaptation-cross": AdaptationCross,
}
