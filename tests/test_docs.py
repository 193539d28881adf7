"""The docs a newcomer reads describe the project as it is: the README's Python example runs as
written, no page says only EXR files are read, and docs/layout.md names every module (a new
one it does not name fails here). Each test names the mutation it guards."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def test_the_readmes_python_example_runs_as_written() -> None:
    """Each ```python block of README.md, executed as it is: it makes a frame. Guards an
    example that uses a name it never defines (the README's `rgb` did)."""
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert blocks, "the README has a Python example"
    for block in blocks:
        scope: dict = {}
        exec(compile(block, "README.md", "exec"), scope)  # the README's own code
        v = scope["v"]
        assert v.shape == (360, 640, 3) and np.isfinite(v).all() and v.max() > 0


def test_no_page_says_only_exr_files_are_read() -> None:
    """Scenes are OpenEXR, Radiance .hdr and PFM files; a page that says EXR only (or names a
    button "Upload EXR") misleads. Guards such a sentence written again."""
    stale = re.compile(r"EXR only|only EXR|Upload EXR|an EXR upload|EXR path", re.I)
    found = [
        f"{p.relative_to(ROOT)}: {m.group(0)}" for p in PAGES for m in stale.finditer(p.read_text())
    ]
    assert not found, found


def test_every_module_is_named_in_the_layout_page() -> None:
    """docs/layout.md names every module under server/, drivers/ and web/ (by its file name),
    so the page cannot go stale as modules come and go. Guards a module added without a line
    there."""
    text = (ROOT / "docs" / "layout.md").read_text()
    named = set(re.findall(r"`([\w./-]+\.(?:py|js|html|css|cl))`", text))
    modules = [
        p for folder in ("server", "drivers", "web") for p in (ROOT / folder).rglob("*")
        if p.suffix in (".py", ".js", ".html", ".css", ".cl") and "__pycache__" not in p.parts
        and p.name != "__init__.py"
    ]  # fmt: skip

    def is_named(path: Path) -> bool:  # by any tail of its path: `kernels/common.cl`, `cli.py`
        parts = path.relative_to(ROOT).parts
        return any("/".join(parts[i:]) in named for i in range(len(parts)))

    missing = [str(p.relative_to(ROOT)) for p in modules if not is_named(p)]
    assert not missing, f"docs/layout.md does not name: {', '.join(sorted(missing))}"
