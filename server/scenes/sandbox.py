"""Decoding uploaded images in a worker process, so that a decoder's crash costs one request.

An upload is decoded by C++ (OpenEXR) and our Python around it; a file made to crash it
(a segfault, an abort) or to make it allocate without end would otherwise take the server, and
every session, down with it. `check_upload` and `open_level` decode in a child process of a
`forkserver` (started once, with the decoders imported, so a child costs a fork, not an
interpreter start) under an address-space limit (`RLIMIT_AS`) and a time limit. The child says
what happened over a pipe: the file's description (`image.file_info`: format, size, layers,
notes, whiteLuminance, and the estimate's statistic over all its pixels), and, for a scene
opened for a session, its pixels reduced in the child to their level for the server's frames
(`gazehdr.scenes.level`), as a temporary `.npy` file (read once, then deleted) rather than
pickled through the pipe. The server never holds a file's pixels at more than that size. What
went wrong is a `SceneError` the user reads: the decoder crashed (signal ...), ran out of memory
(limit N MiB), or took longer than N s.

Test hook: with GAZEHDR_TEST_DECODE_FAULTS=1 in the server's environment, a file whose bytes
hold `GAZEHDR-FAULT:abort` (or `:segv`, `:alloc`, `:hang`; e.g. appended to a valid EXR) does
that in the worker (never in the server: the hook is in the worker's code only).
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import resource
import signal
import tempfile
from collections.abc import Sequence
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from gazehdr.scenes.decoding import Decoded, SceneError
from gazehdr.scenes.image import ImageScene, decode, file_info, identity
from gazehdr.scenes.level import ANY_FRAME, level_size, reduce

#: Address space a decode may add to the worker's (its interpreter and libraries come first):
#: the largest image allowed (64 Mi pixels, 768 MiB as float32 RGB) with room for the
#: decoder's own copies and the estimate's statistic.
MEMORY_MIB = 3072
TIME_S = float(os.environ.get("GAZEHDR_DECODE_TIME_S", "60"))
FAULT_ENV = "GAZEHDR_TEST_DECODE_FAULTS"
Frames = Sequence[tuple[int, int]]
_context = multiprocessing.get_context("forkserver")
_context.set_forkserver_preload(["gazehdr.scenes.sandbox"])


def check_upload(path: Path, layer: str | None = None) -> dict[str, Any]:
    """Decode `path` (its `layer`) in a worker: its description (`image.file_info`), or a
    SceneError saying why it is no scene."""
    answer = _run(path, layer, None, (), memory_mib=MEMORY_MIB, time_s=TIME_S)
    return answer["info"]


def open_level(path: Path, layer: str | None = None, frames: Frames = ANY_FRAME) -> Decoded:
    """`path` decoded in a worker and reduced there to its level for `frames`
    (`gazehdr.scenes.level`): `size` and `median_log10` say what the file itself is."""
    answer = _run(path, layer, tempfile.gettempdir(), frames, memory_mib=MEMORY_MIB, time_s=TIME_S)
    info, npy = answer["info"], answer["npy"]
    try:
        rgb = np.load(npy)
    finally:
        os.unlink(npy)
    reduced = rgb.shape[:2] != (info["height"], info["width"])
    return Decoded(
        rgb, info["format"], info["white_luminance"], tuple(info["layers"]), info["layer"],
        tuple(info["notes"]), size=(info["width"], info["height"]) if reduced else None,
        median_log10=info["median_log10"],
    )  # fmt: skip


def open_upload(
    path: Path,
    scale: float | None,
    *,
    layer: str | None = None,
    kind: str | None = None,
    frames: Frames = ANY_FRAME,
) -> ImageScene:
    """`ImageScene.open(path, ...)` with the decoding (and the reduction to the level for
    `frames`) done in a worker."""
    scene = ImageScene(path.stem, open_level(path, layer, frames), scale, kind)
    scene.source = identity(path)
    return scene


def _run(
    path: Path,
    layer: str | None,
    out_dir: str | None,
    frames: Frames,
    *,
    memory_mib: int,
    time_s: float,
) -> dict[str, Any]:
    """Decode in a child; its answer, or a SceneError saying how it failed."""
    receive, send = _context.Pipe(duplex=False)
    child = _context.Process(
        target=_worker,
        args=(send, str(path), layer, out_dir, [tuple(f) for f in frames], memory_mib),
        daemon=True,
    )
    child.start()
    send.close()
    try:
        answer = receive.recv() if receive.poll(time_s) else None
        timed_out = answer is None and child.is_alive()
    except EOFError:  # the child died without an answer
        answer, timed_out = None, False
    finally:
        receive.close()
    if timed_out:
        child.kill()
    child.join()
    if timed_out:
        raise SceneError(f"{path}: decoding took longer than {time_s:g} s; the file was refused")
    if answer is None:
        code = child.exitcode or 0
        how = f"signal {signal.Signals(-code).name}" if code < 0 else f"exit status {code}"
        raise SceneError(f"{path}: the decoder crashed ({how}) on this file")
    status, value = answer
    if status == "error":
        raise SceneError(value)
    if status == "memory":
        raise SceneError(f"{path}: decoding ran out of memory (limit {memory_mib} MiB)")
    return value


def _worker(
    send: Connection,
    path: str,
    layer: str | None,
    out_dir: str | None,
    frames: list[tuple[int, int]],
    memory_mib: int,
) -> None:
    """In the child: limits on, decode, answer ("ok", {"info": ..., "npy": ...}),
    ("error", message) or ("memory", None)."""
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))  # a crash leaves no core file behind
    limit = _address_space() + memory_mib * 1024 * 1024
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    try:
        _test_fault(Path(path))
        decoded = decode(Path(path), layer)
        info = file_info(decoded)  # the statistic over every pixel, before any reduction
        answer: tuple[str, Any] = ("ok", {"info": info})
        if out_dir is not None:  # opened for a session: the level, through a file
            rgb = decoded.rgb
            del decoded
            size = level_size(info["width"], info["height"], frames)
            if size is not None:
                rgb = reduce(rgb, size)
            fd, npy = tempfile.mkstemp(suffix=".npy", dir=out_dir)
            with os.fdopen(fd, "wb") as f:
                np.save(f, rgb)
            answer = ("ok", {"info": info, "npy": npy})
    except SceneError as e:
        answer = ("error", str(e))
    except MemoryError:
        answer = ("memory", None)
    send.send(answer)
    send.close()


def _address_space() -> int:
    """The worker's address space now (bytes): the limit is set above it."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmSize:"):
            return int(line.split()[1]) * 1024
    return 0


def _test_fault(path: Path) -> None:
    """The test hook (module docstring): only with FAULT_ENV set, only in the worker."""
    if os.environ.get(FAULT_ENV) != "1":
        return
    data = path.read_bytes()
    at = data.find(b"GAZEHDR-FAULT:")
    if at < 0:
        return
    fault = data[at:].split(b":")[1].split()[0]
    if fault == b"abort":
        os.abort()
    if fault == b"segv":
        ctypes.string_at(0)  # reads address 0: SIGSEGV
    if fault == b"alloc":
        np.ones(1 << 40, np.uint8)  # a terabyte: MemoryError under the limit
    if fault == b"hang":
        signal.pause()
