"""The scenes a server offers: the built-ins, image files given at start, and uploads.

Uploads live in `DATA_DIR/scenes/NAME.exr` (or `.hdr`, `.pfm`: the format the file's bytes
are), with their settings beside them in `NAME.json` (`scale`, the estimate's `kind`, the EXR
`layer`). Names are checked against one pattern before any path is built, so nothing is ever
read or written outside that folder; a file is moved into place only after it opened as a
valid scene, and never over an existing upload unless asked to (`overwrite`).

Settings apply to every session showing the scene: each change bumps the name's `version`,
which sessions compare with theirs at every step (`refresh`), so a new scale is applied to
the pixels already loaded, without reading the file again.

Bounds. An upload is only ever decoded in a worker process (`gazehdr.scenes.sandbox`), and a
scene opened for a session comes back from it reduced to its level for this server's frames
(`gazehdr.scenes.level`), as a scene opened at start is reduced here: what the server holds
of a scene is bounded by its frame size. All sessions showing one file (and layer) share one
level, kept while any of them shows it. An
upload's description (`describe`: format, size, layers, notes, scale) is taken once, when it
is stored (or first decoded, for a file stored before this server started), and kept in memory
under the file's identity (path, modification time, size): describing an upload never decodes
it again. At most `decodes` decodes run at once, and at most `waiters` callers wait for one of
them (the same file asked for again while it decodes); any more is refused at once with
`SceneBusyError`, never queued. Errors name the scene, never a path of the server's.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import threading
import uuid
import weakref
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from pathlib import Path
from typing import Any, TypeVar

from gazehdr import atomic
from gazehdr.scenes import Scene, builtin_names, open_scene
from gazehdr.scenes.decoding import Decoded, SceneError
from gazehdr.scenes.estimate import check_kind
from gazehdr.scenes.image import (
    SUFFIXES,
    ImageScene,
    check_scale,
    choose_scale,
    describe_file,
    describe_scale,
    file_format,
    file_info,
    identity,
)
from gazehdr.scenes.level import ANY_FRAME
from gazehdr.scenes.sandbox import TIME_S, check_upload, open_level

NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
MAX_UPLOAD_BYTES = 256 * 1024 * 1024  # an upload is held in memory until validated
#: What a built-in (procedural) scene says of its scale: it is drawn in cd/m^2.
BUILTIN_INFO = {
    "format": "built-in", "scale": 1.0, "scale_source": "built-in",
    "scale_note": "drawn in cd/m² by gazehdr", "kind": None, "layers": [""], "layer": "",
}  # fmt: skip
SETTINGS = ("scale", "kind", "layer")
#: Decodes at once (each a worker process of up to sandbox.MEMORY_MIB), and callers that may
#: wait for one of them (asking for the file it decodes) rather than be refused.
DECODES = 2
WAITERS = 2
T = TypeVar("T")


class SceneExistsError(SceneError):
    """An upload under a name already taken by an upload."""


class NoSuchSceneError(SceneError):
    """A name that is no scene of this library."""


class SceneBusyError(SceneError):
    """As many decodes as the server runs at once are running (and waited for): try again."""


class DecodeSlots:
    """At most `decodes` decodes at once and `waiters` callers waiting for one; more: refused.
    Neither waits for a slot: a caller that finds none full is refused at once."""

    def __init__(self, decodes: int = DECODES, waiters: int = WAITERS) -> None:
        self.decodes, self.waiters = decodes, waiters
        self.busy = {"decoding": 0, "waiting": 0}
        self._lock = threading.Lock()

    @contextlib.contextmanager
    def take(self, what: str) -> Iterator[None]:
        """A slot of `what` ("decoding" or "waiting") while the block runs."""
        limit = self.decodes if what == "decoding" else self.waiters
        with self._lock:
            if self.busy[what] >= limit:
                raise SceneBusyError(
                    f"the server decodes {self.decodes} scene files at once (its limit) and all "
                    "are busy; try again shortly"
                )
            self.busy[what] += 1
        try:
            yield
        finally:
            with self._lock:
                self.busy[what] -= 1


def check_name(name: str) -> str:
    """A scene name safe as a file stem: letters, digits, `_.-`, not starting with a dot."""
    if not NAME.fullmatch(name) or name.endswith(".") or ".." in name:
        raise SceneError(
            f"scene name {name!r} is not allowed: use up to 64 letters, digits, '_', '.' or '-', "
            "starting with a letter or digit"
        )
    return name


def check_settings(values: dict[str, Any]) -> dict[str, Any]:
    """`scale` (positive, or None), `kind` (an estimate kind, or None), `layer` (str or None)."""
    unknown = sorted(set(values) - set(SETTINGS))
    if unknown:
        names = ", ".join(unknown)
        raise SceneError(f"unknown scene setting(s) {names}; known: scale, kind, layer")
    out = dict(values)
    if "scale" in out:
        out["scale"] = check_scale(out["scale"])
    if out.get("kind") is not None:
        try:
            check_kind(out["kind"])
        except ValueError as e:
            raise SceneError(str(e)) from None
    if out.get("layer") is not None and not isinstance(out["layer"], str):
        raise SceneError("layer must be a layer name (a string) or null")
    return out


class SceneLibrary:
    def __init__(
        self,
        data_dir: Path | None = None,
        loaded: dict[str, Scene] | None = None,
        *,
        frames: Iterable[tuple[int, int]] = ANY_FRAME,
        decodes: int = DECODES,
        waiters: int = WAITERS,
    ):
        """`loaded`: scenes opened at start (files named on the command line), shared by all
        sessions; their settings change in memory only. `frames`: the frame sizes the sessions
        can have (`level.session_frames`), which bound the level a scene is kept at (default:
        any frame size the simulator allows). `decodes`, `waiters`: `DecodeSlots`."""
        self.upload_dir = data_dir / "scenes" if data_dir else None
        self.loaded = dict(loaded or {})
        self.frames = tuple(frames)
        for scene in self.loaded.values():
            if isinstance(scene, ImageScene):
                scene.keep_level(self.frames)
        self.slots = DecodeSlots(decodes, waiters)
        self._versions: dict[str, int] = {}
        self._lock = threading.Lock()
        # Levels sessions show, by (file identity, layer asked for), kept while one shows it.
        self._levels: weakref.WeakValueDictionary[tuple, Decoded] = weakref.WeakValueDictionary()
        # Uploads' descriptions: name -> (file identity, {layer asked for: file_info}).
        self._infos: dict[str, tuple[tuple, dict[str | None, dict[str, Any]]]] = {}
        self._pending: dict[tuple, Future] = {}  # decodes running, for the callers that wait

    def names(self) -> list[str]:
        return sorted({*builtin_names(), *self.loaded, *self.uploads()})

    def uploads(self) -> dict[str, Path]:
        """Uploaded scenes by name (one file each)."""
        if not self.upload_dir or not self.upload_dir.is_dir():
            return {}
        return {
            p.stem: p
            for suffix in SUFFIXES.values()
            for p in self.upload_dir.glob(f"*{suffix}")
            if NAME.fullmatch(p.stem)
        }

    def version(self, name: str) -> int:
        """Bumped by every change of the scene's file or settings."""
        return self._versions.get(name, 0)

    def open(self, name: str) -> Scene:
        if name in builtin_names():
            return open_scene(name)
        if name in self.loaded:
            return self.loaded[name]
        path = self._upload(name)
        s = self.settings(name)
        layer, source = s.get("layer"), identity(path)
        with self._lock:
            decoded = self._levels.get((source, layer))
        if decoded is None:
            decoded = self._decode(
                name, path, ("level", source, layer), lambda: open_level(path, layer, self.frames)
            )
            with self._lock:
                self._levels[(source, layer)] = decoded
            self._remember(name, source, layer, file_info(decoded))
        scene = ImageScene(name, decoded, s.get("scale"), s.get("kind"))
        scene.source = source
        return scene

    def refresh(self, name: str, scene: Scene) -> Scene:
        """`scene` (opened as `name`) with the settings now in force: the same object with a
        new scale, or the file opened again when its layer or the file itself changed."""
        if name in self.loaded or not isinstance(scene, ImageScene):
            return scene
        s = self.settings(name)
        layer = s.get("layer")
        path = self.uploads().get(name)
        replaced = path is None or scene.source != identity(path)
        if replaced or layer not in (None, scene.decoded.layer):
            return self.open(name)  # another layer, or the upload was replaced
        scene.set_scale(s.get("scale"), s.get("kind"))
        return scene

    def describe(self, name: str) -> dict[str, Any]:
        """What `GET /api/scenes/NAME` and `gazehdr scenes` show: format, size, scale, source.
        An upload's comes from its description, taken once (module docstring)."""
        if name in builtin_names() or name in self.loaded:
            scene = self.open(name)
            where = "built-in" if name in builtin_names() else "configured"
            info = scene.describe() if isinstance(scene, ImageScene) else dict(BUILTIN_INFO)
            return {"name": name, "origin": where, **info}
        path = self._upload(name)
        s = self.settings(name)
        info = self._info(name, path, s.get("layer"))
        scale = choose_scale(
            name, info["white_luminance"], lambda: info["median_log10"], s.get("scale"),
            s.get("kind"),
        )  # fmt: skip
        return {"name": name, "origin": "upload", **describe_file(info), **describe_scale(scale)}

    def settings(self, name: str) -> dict[str, Any]:
        """An upload's saved settings (empty for other scenes and unreadable files)."""
        path = self._sidecar(name)
        try:
            values = json.loads(path.read_text()) if path else {}
            return check_settings(values if isinstance(values, dict) else {})
        except (OSError, ValueError):
            return {}

    def configure(self, name: str, values: dict[str, Any]) -> dict[str, Any]:
        """Change a scene's `scale`, `kind` or `layer` (None: back to the default) for every
        session; an upload keeps them. Returns the scene's description."""
        values = check_settings(values)
        if name in builtin_names():
            raise SceneError(f"{name!r} is a built-in scene: it is drawn in cd/m², no scale to set")
        if name in self.loaded:
            scene = self.loaded[name]
            if "layer" in values:
                raise SceneError(f"{name!r} was opened at start: its layer is serve --layer's")
            if isinstance(scene, ImageScene):
                merged = {"scale": None, "kind": None, **values}
                scene.set_scale(merged["scale"], merged["kind"])
        else:
            path = self.uploads().get(check_name(name))
            if path is None:
                raise NoSuchSceneError(f"no scene named {name!r}; see GET /api/scenes")
            merged = {**self.settings(name), **values}
            if "scale" in values and values["scale"] is not None:
                merged.pop("kind", None)  # a number given: no estimate to keep
            self._info(name, path, merged.get("layer"))  # refuses a bad layer now
            self._write_settings(name, {k: v for k, v in merged.items() if v is not None})
        self._bump(name)
        return self.describe(name)

    def store(self, name: str, chunks: list[bytes], *, overwrite: bool = False) -> Path:
        """Validate an uploaded image and move it into place; nothing is kept if it is bad.
        An upload of the same name is replaced only with `overwrite` (its settings go)."""
        if self.upload_dir is None:
            raise SceneError("this server has no data directory for uploads")
        check_name(name)
        if name in builtin_names() or name in self.loaded:
            raise SceneError(f"scene name {name!r} is taken by a built-in or configured scene")
        existing = self.uploads().get(name)
        if existing is not None and not overwrite:
            raise SceneExistsError(
                f"scene {name!r} exists already; replace it with overwrite (PUT "
                f"/api/scenes/{name}?overwrite=true) or choose another name"
            )
        self.upload_dir.mkdir(parents=True, exist_ok=True)
        tmp = self.upload_dir / f".upload-{uuid.uuid4().hex}.tmp"
        try:
            with open(tmp, "wb") as f:
                for chunk in chunks:
                    f.write(chunk)
            try:
                kind = file_format(tmp)
                with self.slots.take("decoding"):
                    info = check_upload(tmp)  # in a worker process (gazehdr.scenes.sandbox)
            except SceneError as e:
                raise type(e)(self._scrub(str(e), tmp, f"upload {name!r}")) from None
            path = self.upload_dir / f"{name}{SUFFIXES[kind]}"
            with self._lock:  # checked again where it is acted on: uploads decode in parallel
                existing = self.uploads().get(name)
                if existing is not None and not overwrite:
                    raise SceneExistsError(
                        f"scene {name!r} was uploaded while this upload was checked; replace "
                        f"it with overwrite (PUT /api/scenes/{name}?overwrite=true)"
                    )
                os.replace(tmp, path)
                if existing is not None and existing != path:
                    existing.unlink(missing_ok=True)
                if existing is not None:
                    (self._sidecar(name) or path).unlink(missing_ok=True)
                self._infos.pop(name, None)
            self._remember(name, identity(path), None, info)
        finally:
            tmp.unlink(missing_ok=True)
        self._bump(name)
        return path

    # --- internals ---------------------------------------------------------------------------

    def _upload(self, name: str) -> Path:
        path = self.uploads().get(check_name(name))
        if path is None:
            raise NoSuchSceneError(f"no scene named {name!r}; available: {', '.join(self.names())}")
        return path

    def _info(self, name: str, path: Path, layer: str | None) -> dict[str, Any]:
        """The upload's description for `layer` (None: the file's default): kept, else taken
        (decoding the file in a worker) and kept."""
        source = identity(path)
        with self._lock:
            kept, infos = self._infos.get(name, (None, {}))
            if kept == source and layer in infos:
                return infos[layer]
        info = self._decode(name, path, ("info", source, layer), lambda: check_upload(path, layer))
        self._remember(name, source, layer, info)
        return info

    def _remember(
        self, name: str, source: tuple | None, layer: str | None, info: dict[str, Any]
    ) -> None:
        """Keep `info`, the description of `layer` of the file `source` is `name`'s."""
        if source is None:
            return
        with self._lock:
            kept, infos = self._infos.get(name, (None, {}))
            if kept != source:  # another file (or none yet): what was kept was of the old one
                infos = {}
            infos[layer] = info
            self._infos[name] = (source, infos)

    def _decode(self, name: str, path: Path, key: tuple, work: Callable[[], T]) -> T:
        """`work()` (a decode in a worker) for `key`, in a decode slot; a caller asking for a
        `key` being decoded waits for that decode instead (in a waiting slot). SceneErrors
        name the scene, not the file."""
        with self._lock:
            pending = self._pending.get(key)
            mine = pending is None
            if mine:
                pending = self._pending[key] = Future()
        assert pending is not None
        try:
            if not mine:
                with self.slots.take("waiting"):
                    try:
                        return pending.result(timeout=2 * TIME_S + 30)
                    except FutureTimeout:
                        raise SceneBusyError(f"scene {name!r} is still being decoded") from None
            try:
                with self.slots.take("decoding"):
                    value = work()
            except BaseException as e:
                pending.set_exception(e)
                raise
            pending.set_result(value)
            return value
        except SceneError as e:
            raise type(e)(self._scrub(str(e), path, f"scene {name!r}")) from None
        finally:
            if mine:
                with self._lock:
                    self._pending.pop(key, None)

    def _scrub(self, message: str, path: Path, what: str) -> str:
        """`message` with `path` said as `what`, and nothing else of the server's folders."""
        message = message.replace(str(path), what)
        if self.upload_dir is not None:
            for folder in {str(self.upload_dir.resolve()), str(self.upload_dir)}:
                message = message.replace(folder, "(uploads)")
        return message

    def _bump(self, name: str) -> None:
        with self._lock:
            self._versions[name] = self._versions.get(name, 0) + 1

    def _sidecar(self, name: str) -> Path | None:
        return self.upload_dir / f"{name}.json" if self.upload_dir else None

    def _write_settings(self, name: str, values: dict[str, Any]) -> None:
        path = self._sidecar(name)
        assert path is not None  # an upload exists, so there is an upload folder
        atomic.write_text(path, json.dumps(values))
