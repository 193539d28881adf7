"""The scene's Gaussian acuity levels, made once for a scene that stays (the OpenCL backend).

Eq. 14 telescopes to one Gaussian level of the scene per pixel: level d - 1 where d bands are
dropped. The tiled bank (kernel acuity_bank) blurs every frame as far as each tile needs. For a
scene that stays the levels are the same every frame, so they are made once, one level a frame,
and each frame then only picks every pixel's level (kernel acuity_pick): whole live step 0.92×
at 1280×720 and 0.89× at 1920×1080 (docs/performance.md, "Acuity").
"""

from __future__ import annotations

import os
from typing import Any

import pyopencl as cl

#: Ours: the most memory a backend gives its stack ((bands + 1) × 3 planes of 16 bits: 112 MB at
#: 1920×1080 with 8 bands); larger frames blur per frame instead. While the stack is made, three
#: float frames more (the level before, the level and the blur's scratch) are held.
LEVEL_STACK_MAX_BYTES = 512 << 20
#: Ours: acuity frames a scene must stay before its stack is made (half a second at 60 fps).
#: Making it costs about 8 frames of the bank's work (one level a frame, so no frame spikes);
#: a scene that changes sooner (the flash while it fires) would not pay it back.
LEVEL_STACK_AFTER_FRAMES = 30


class LevelStack:
    """The backend's scene and its levels 0 .. bands - 1 in one buffer of 16-bit codes
    (lum16.py), three planes each: the scene at 0, level l at (l + 1) * `stride` codes (as
    acuity_pick reads them)."""

    def __init__(self, backend: Any) -> None:
        # `backend` (an OpenCLBackend: its context, layout, scene, blur and taps) is not kept:
        # a cycle would outlive the session until the garbage collector ran (test_limits).
        self.bands = backend.p.bands
        self.stride = self._stride(backend)
        self.buf: cl.Buffer | None = None
        self.levels = 0  # levels of the current scene made so far
        self.frames = 0  # acuity frames since the scene last changed
        self._work: list[cl.Buffer] = []  # float frames while the stack is made

    @staticmethod
    def _stride(b: Any) -> int | None:
        """Codes from one level to the next (a level's three planes, rounded up so that each
        level can be a sub-buffer), or None where no stack is used: when it would take more
        than LEVEL_STACK_MAX_BYTES, or GAZEHDR_CL_ACUITY names a bank."""
        if os.environ.get("GAZEHDR_CL_ACUITY", ""):
            return None
        align = b.ctx.devices[0].mem_base_addr_align // 8  # bits to bytes
        level = -(-2 * 3 * b.lay.width * b.lay.height // align) * align
        if level * (b.p.bands + 1) > LEVEL_STACK_MAX_BYTES:
            return None
        return level // 2

    @property
    def pending(self) -> bool:
        """Whether the current scene's acuity will move to the stack (benchmarks wait for
        that: it is the steady state of a scene that stays)."""
        return self.stride is not None and self.levels < self.bands

    def scene_changed(self) -> None:
        self.levels = self.frames = 0

    def for_frame(self, b: Any) -> cl.Buffer | None:
        """Once per acuity frame of backend `b`: the stack when it is whole; else None, after
        making its next level if the scene has stayed LEVEL_STACK_AFTER_FRAMES frames (the
        scene's codes with the first)."""
        self.frames += 1
        stride = self.stride
        if stride is None or self.frames <= LEVEL_STACK_AFTER_FRAMES:
            return None
        if self.levels == self.bands:
            return self.buf
        lay, i = b.lay, self.levels
        n = 3 * lay.width * lay.height
        if self.buf is None:
            self.buf = cl.Buffer(b.ctx, cl.mem_flags.READ_WRITE, 2 * stride * (self.bands + 1))
        if not self._work:
            self._work = [cl.Buffer(b.ctx, cl.mem_flags.READ_WRITE, 4 * n) for _ in range(3)]

        def level(k: int) -> cl.Buffer:  # the scene is level -1
            return self.buf.get_sub_region(2 * stride * (k + 1), 2 * n)

        before, made, tmp = self._work[(i + 1) % 2], self._work[i % 2], self._work[2]
        if i == 0:
            b.encode_lum16(b.buf["scene"], level(-1), n)
        b.blur(b.buf["scene"] if i == 0 else before, made, tmp, b._acuity_taps[i], lay.width,
               lay.height, 3)  # fmt: skip
        b.encode_lum16(made, level(i), n)
        self.levels += 1
        if self.levels == self.bands:
            self._work = []  # freed once the queued kernels are done with them
        return None
