"""The scenes a server offers: the built-ins, EXR files given at start, and uploads.

Uploads live in `DATA_DIR/scenes/NAME.exr`. Names are checked against one pattern before any
path is built, so nothing is ever read or written outside that folder, and a file is only
moved into place after it opened as a valid scene.
"""

from __future__ import annotations

import os
import re
import uuid
from pathlib import Path

from gazehdr.scenes import Scene, builtin_names, open_scene
from gazehdr.scenes.exr import ExrScene, SceneError

NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
MAX_UPLOAD_BYTES = 256 * 1024 * 1024  # an upload is held in memory until validated


def check_name(name: str) -> str:
    """A scene name safe as a file stem: letters, digits, `_.-`, not starting with a dot."""
    if not NAME.fullmatch(name) or name.endswith(".") or ".." in name:
        raise SceneError(
            f"scene name {name!r} is not allowed: use up to 64 letters, digits, '_', '.' or '-', "
            "starting with a letter or digit"
        )
    return name


class SceneLibrary:
    def __init__(self, data_dir: Path | None = None, loaded: dict[str, Scene] | None = None):
        """`loaded`: scenes opened at start (files named on the command line), shared by all
        sessions; they are read-only."""
        self.upload_dir = data_dir / "scenes" if data_dir else None
        self.loaded = dict(loaded or {})

    def names(self) -> list[str]:
        uploads = sorted(p.stem for p in self.upload_dir.glob("*.exr")) if self.upload_dir else []
        return sorted({*builtin_names(), *self.loaded, *uploads})

    def open(self, name: str) -> Scene:
        if name in builtin_names():
            return open_scene(name)
        if name in self.loaded:
            return self.loaded[name]
        path = self._upload_path(check_name(name))
        if path is None or not path.is_file():
            raise SceneError(f"no scene named {name!r}; available: {', '.join(self.names())}")
        return ExrScene.open(path)

    def store(self, name: str, chunks: list[bytes]) -> Path:
        """Validate an uploaded EXR and move it into place; nothing is kept if it is bad."""
        path = self._upload_path(check_name(name))
        if path is None:
            raise SceneError("this server has no data directory for uploads")
        if name in builtin_names() or name in self.loaded:
            raise SceneError(f"scene name {name!r} is taken by a built-in or configured scene")
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".upload-{uuid.uuid4().hex}.exr")
        try:
            with open(tmp, "wb") as f:
                for chunk in chunks:
                    f.write(chunk)
            try:
                ExrScene.open(tmp)
            except SceneError as e:
                raise SceneError(str(e).replace(str(tmp), f"upload {name!r}")) from None
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        return path

    def _upload_path(self, name: str) -> Path | None:
        return self.upload_dir / f"{name}.exr" if self.upload_dir else None
