"""The late gaze warp's frame payload (docs/protocol.md, encoding `warp`).

As a VR runtime reprojects its last frame to the newest head pose, the viewer places the
retina-locked part of the frame, the afterimage maps, at its newest gaze at every display
refresh, whatever the simulation's rate. So the server sends compose's two halves apart
(`reference.compose_base`, `reference.apply_afterimages`): the linear RGB before Eq. 12, which
stays on the screen, and the maps at their grid resolution; the viewer's shader (web/warp.js)
does Eq. 12, the gamut mapping and the gamma at the gaze it has, then dithers as ever.

Precision: the RGB and the maps' additive planes as half floats; the gain planes as gain - 1,
so an afterimage's small gains keep half floats' 11 significant bits (a gain near 1 in a half
float is off by up to 2.4e-4, which LMS_TO_RGB's large coefficients magnify to several codes
of 1023 in saturated colours). `compose` here is the shader's oracle.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.sim.layout import LMS_TO_RGB, RGB_TO_LMS, Layout
from gazehdr.sim.params import Params
from gazehdr.sim.reference import apply_afterimages
from gazehdr.sim.simulator import WarpLayers

#: After the frame header: panes, pane width, grid width and height (u16); cell (screen px
#: per retina cell), the foveal fall-off's sigma (px), gamma (f32); w_P (3 f32); RGB_TO_LMS and
#: LMS_TO_RGB (9 f32 each, row-major); then per pane (two, the second zero without split view)
#: its gaze (pane px) and visibility (f32) and a reserved f32. 136 bytes: the planes stay aligned.
_HEAD = struct.Struct("<4H3f3f9f9f")
_PANE = struct.Struct("<4f")
MAX_PANES = 2
HEAD_BYTES = _HEAD.size + MAX_PANES * _PANE.size


@dataclass(frozen=True)
class WarpFrame:
    """A warp payload decoded (tests and tools): everything the shader gets."""

    rgb: np.ndarray  # H×W×3 float32, the frame's panes side by side
    maps: list[np.ndarray]  # per pane 6×grid_h×grid_w float32 (gains, not gain - 1)
    gazes: list[tuple[float, float]]  # per pane, pane px
    visibility: list[float]
    pane_width: int
    cell: int
    fovea_sigma_px: float
    gamma: float
    w_P: tuple[float, float, float]


def pack(panes: Sequence[WarpLayers], width: int, params: Params) -> bytearray:
    """The payload of one warp frame (`width` px wide; panes side by side from the left, as a
    plain frame has them, `Eye.step`)."""
    if not 1 <= len(panes) <= MAX_PANES:
        raise InputError(f"a warp frame has 1 or {MAX_PANES} panes, not {len(panes)}")
    first = panes[0]
    h, pw, _ = first.rgb.shape
    grid_h, grid_w = first.maps.shape[1:3]
    head = _HEAD.pack(
        len(panes), pw, grid_w, grid_h, first.cell, first.fovea_sigma_px, params.gamma,
        *params.w_P, *RGB_TO_LMS.ravel(), *LMS_TO_RGB.ravel(),
    )  # fmt: skip
    rows = [_PANE.pack(*p.gaze, p.visibility, 0.0) for p in panes]
    rows += [_PANE.pack(0, 0, 0, 0)] * (MAX_PANES - len(panes))
    # Written in place into the one buffer sent (a 720p frame's layers are 8 MB): the base
    # image, then per pane gain - 1 and the additive term, each grid_h×grid_w×3 (one texture
    # of RGB texels, the panes' images stacked: web/warp.js).
    maps_size = first.maps.size
    out = bytearray(HEAD_BYTES + 2 * (h * width * 3 + len(panes) * maps_size))
    out[:HEAD_BYTES] = b"".join([head, *rows])
    rgb = np.frombuffer(out, "<f2", h * width * 3, HEAD_BYTES).reshape(h, width, 3)
    for i, p in enumerate(panes):
        rgb[:, i * pw : (i + 1) * pw] = p.rgb
    rgb[:, len(panes) * pw :] = 0  # an odd last column in split view: black
    at = HEAD_BYTES + rgb.nbytes
    for p in panes:
        np.frombuffer(out, "<f2", maps_size, at)[:] = p.maps.ravel()
        at += 2 * maps_size
    return out


def unpack(payload: bytes | memoryview, width: int, height: int) -> WarpFrame:
    """The inverse of `pack`."""
    fields = _HEAD.unpack_from(payload)
    n, pw, grid_w, grid_h = fields[:4]
    cell, sigma, gamma = fields[4:7]
    w_P = tuple(fields[7:10])
    rows = [_PANE.unpack_from(payload, _HEAD.size + i * _PANE.size) for i in range(n)]
    at = HEAD_BYTES
    rgb = np.frombuffer(payload, "<f2", width * height * 3, at).reshape(height, width, 3)
    at += rgb.nbytes
    maps = []
    for _ in range(n):
        m = np.frombuffer(payload, "<f2", 6 * grid_h * grid_w, at)
        at += m.nbytes
        maps.append(planar(m.reshape(2, grid_h, grid_w, 3)))
    return WarpFrame(
        rgb.astype(np.float32), maps, [(r[0], r[1]) for r in rows], [r[2] for r in rows],
        pw, round(cell), sigma, gamma, w_P,  # type: ignore[arg-type]
    )  # fmt: skip


def planar(maps: np.ndarray) -> np.ndarray:
    """`WarpLayers.maps` (gain - 1, additive; 2×grid_h×grid_w×3) as the simulator's planar
    6×grid_h×grid_w maps, float32."""
    m = maps.astype(np.float32).transpose(0, 3, 1, 2).reshape(6, *maps.shape[1:3])
    return np.concatenate([m[:3] + 1.0, m[3:]])


def compose(frame: WarpFrame, gaze: tuple[float, float] | None = None) -> np.ndarray:
    """H×W×3 `v` as the viewer's shader makes it, at `gaze` (pane px; None: each pane's own),
    in float64: the oracle of web/warp.js (reference.apply_afterimages per pane)."""
    h, width, _ = frame.rgb.shape
    pw = frame.pane_width
    out = np.zeros((h, width, 3))
    for i, maps in enumerate(frame.maps):
        gh, gw = maps.shape[1:]
        lay = Layout(pw, h, 1.0, frame.cell, gw // 2, gh // 2, gw, gh)
        p = Params(gamma=frame.gamma, w_P=frame.w_P, fovea_sigma_deg=frame.fovea_sigma_px)
        rgb = frame.rgb[:, i * pw : (i + 1) * pw].astype(np.float64).transpose(2, 0, 1)
        at = frame.gazes[i] if gaze is None else gaze
        out[:, i * pw : (i + 1) * pw] = apply_afterimages(
            rgb, maps.astype(np.float64), at, lay, p, frame.visibility[i]
        )
    return out
