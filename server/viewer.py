"""The browser viewer's files: found through the installed package, and checked complete.

The viewer (web/, installed as the package `gazehdr.web`) travels inside the wheel and the sdist,
so `gazehdr serve` finds it with importlib.resources wherever gazehdr is installed. A server
without its viewer would answer 404 to the browser with no word to the user; `check_viewer`
refuses that up front, naming the missing file. What counts as complete is read from the files
themselves: `index.html`, what it links, and every module those import, followed transitively.
"""

from __future__ import annotations

import os
import posixpath
import re
from importlib import resources
from pathlib import Path

from gazehdr.drivers.errors import InputError

#: Overrides where the viewer's files are read from (a viewer being edited beside an install).
WEB_DIR_ENV = "GAZEHDR_WEB_DIR"
ENTRY = "index.html"
# Same-origin references: <script src="/x.js">, <link href="/x.css">, `import ... from './x.js'`.
_HTML_REF = re.compile(r"""<(?:script|link)\b[^>]*?\b(?:src|href)=["']/?([\w./-]+)["']""")
_JS_IMPORT = re.compile(r"""\bfrom\s+["']\./([\w./-]+)["']|\bimport\s+["']\./([\w./-]+)["']""")


class ViewerMissingError(InputError):
    """The viewer's files are not all there; the text names the first one missing."""


def default_web_dir() -> Path:
    """`$GAZEHDR_WEB_DIR`, else the installed `gazehdr.web` package's folder."""
    given = os.environ.get(WEB_DIR_ENV)
    if given:
        return Path(given)
    files = resources.files("gazehdr.web")
    if not isinstance(files, Path):  # e.g. installed inside a zip: StaticFiles needs a folder
        raise ViewerMissingError(f"the viewer's files are not in a folder on disk ({files})")
    return files


def viewer_files(web_dir: Path) -> list[str]:
    """The files the viewer needs, as paths relative to `web_dir`, `index.html` first.

    Raises ViewerMissingError naming the first that is missing and what needs it."""
    needed: list[tuple[str, str | None]] = [(ENTRY, None)]
    found: list[str] = []
    while needed:
        name, needed_by = needed.pop(0)
        if name in found:
            continue
        path = web_dir / name
        if not path.is_file():
            by = f" (imported by {needed_by})" if needed_by else ""
            raise ViewerMissingError(
                f"the viewer's {name} is missing from {web_dir}{by}; "
                f"reinstall gazehdr, or set {WEB_DIR_ENV} to a complete web/ folder"
            )
        found.append(name)
        text = path.read_text(encoding="utf-8")
        if name.endswith(".html"):
            refs = [ref for ref in _HTML_REF.findall(text) if "." in ref]
        else:  # a module's imports are relative to its own folder
            folder = posixpath.dirname(name)
            refs = [posixpath.normpath(posixpath.join(folder, a or b)) for a, b in
                    _JS_IMPORT.findall(text)]  # fmt: skip
        needed += [(ref, name) for ref in refs]
    return found
