"""The distributions as users get them, and the import structure a newcomer relies on.

The wheel and the sdist are built with `build` (the wheel from the sdist, so the sdist is shown
complete), the wheel is installed, not editable, into a fresh virtual environment, and gazehdr is
run from there in a folder that holds a `server.py` and a `drivers/`: the viewer is served, frames
stream, and nothing but `gazehdr` was installed at the top level.

The fresh environment borrows this one's third-party packages (a .pth file naming its
site-packages, whose own .pth files, this checkout's editable finder among them, are not run), so
the test needs no network. `.ci/run` sets GAZEHDR_WHEEL_DEPS=install: the wheel's dependencies
are then installed from the index as a user's pip would, proving its metadata too.
"""

from __future__ import annotations

import ast
import asyncio
import fcntl
import os
import re
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import pytest
import websockets
from conftest import run_folder

from gazehdr.viewer import ViewerMissingError, viewer_files

if sys.version_info >= (3, 11):
    import tomllib
else:  # the test extra installs tomli on Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
SETUPTOOLS = PYPROJECT["tool"]["setuptools"]


def _folder_of(package: str) -> Path:
    """The folder a package maps to under `package-dir` (the longest mapped prefix wins)."""
    mapping = SETUPTOOLS["package-dir"]
    parts = package.split(".")
    for n in range(len(parts), 0, -1):
        head = ".".join(parts[:n])
        if head in mapping:
            return ROOT / mapping[head] / Path(*parts[n:])
    raise AssertionError(f"{package} is under no package-dir entry")


def _packages_on_disk() -> set[str]:
    """Every folder with an __init__.py under the mapped folders, by its package name."""
    found = set()
    for name, folder in SETUPTOOLS["package-dir"].items():
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / folder)
            found.add(".".join([name, *rel.parts]))
    return found


# --- the layout, checked against the folders -------------------------------------------------


def test_the_package_list_is_every_package_folder() -> None:
    """Every package folder, and the data folders that package-data names (they have no
    __init__.py, and setuptools warns of a data folder it was not told is a package)."""
    data_only = {
        p for p in SETUPTOOLS["package-data"] if not (_folder_of(p) / "__init__.py").exists()
    }
    assert set(SETUPTOOLS["packages"]) == _packages_on_disk() | data_only
    for package in set(SETUPTOOLS["packages"]) - data_only:
        assert (_folder_of(package) / "__init__.py").is_file(), package


def test_everything_installs_under_gazehdr() -> None:
    assert {p.split(".")[0] for p in SETUPTOOLS["packages"]} == {"gazehdr"}


def test_an_extra_named_after_a_daemon_source_installs_the_daemon() -> None:
    """docs/gaze.md tells a Pupil or LSL user `pip install 'gazehdr[pupil]'` / `[lsl]` for
    `gazehdr daemon --source pupil|lsl`: such an extra must bring the daemon's own packages."""
    from gazehdr.drivers import registry

    extras = PYPROJECT["project"]["optional-dependencies"]
    named = [k.name for k in registry.kinds(registry.STREAM) if k.name in extras]
    assert named, "no extra is named after a source"
    for name in named:
        assert "gazehdr[daemon]" in extras[name], f"gazehdr[{name}] lacks gazehdr[daemon]"


def test_package_data_patterns_each_match_files() -> None:
    for package, patterns in SETUPTOOLS["package-data"].items():
        for pattern in patterns:
            assert list(_folder_of(package).glob(pattern)), f"{package}: {pattern} matches nothing"


def test_licence_file_is_the_declared_licence() -> None:
    project = PYPROJECT["project"]
    assert project["license"] == "MIT"
    text = (ROOT / "LICENSE").read_text()
    assert project["license-files"] == ["LICENSE"]
    assert text.startswith("MIT License") and "Permission is hereby granted" in text


# --- the import graph --------------------------------------------------------------------------


def _modules() -> dict[str, Path]:
    modules = {}
    for package in SETUPTOOLS["packages"]:
        for path in _folder_of(package).glob("*.py"):
            name = package if path.name == "__init__.py" else f"{package}.{path.stem}"
            modules[name] = path
    return modules


def _imports(path: Path, name: str, modules: dict[str, Path]) -> set[str]:
    """The gazehdr modules `path` imports anywhere (functions included), by exact module."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*up, base] if base else up)
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                       for a in node.names]  # fmt: skip
        else:
            continue
        found |= {t for t in targets if t in modules and t != name}
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(path, name, modules) for name, path in modules.items()}


def test_drivers_never_import_the_server_side() -> None:
    """SPEC §1: a tracker machine installs gazehdr[daemon] only (no pyopencl, no simulation)."""
    for name, imported in _graph().items():
        if name.startswith("gazehdr.drivers"):
            outside = {m for m in imported if not m.startswith("gazehdr.drivers")}
            assert not outside, f"{name} imports {sorted(outside)}"


def test_gazehdr_package_itself_imports_nothing() -> None:
    """`import gazehdr.drivers` runs gazehdr/__init__.py: it must stay light."""
    assert _graph()["gazehdr"] == set()


def test_the_version_is_the_distributions_and_gazehdr_version_prints_it(capsys) -> None:
    """`gazehdr.__version__` from the package metadata, a message when gazehdr is not
    installed, and `gazehdr --version`."""
    import importlib.metadata

    import gazehdr
    from gazehdr.cli import main

    assert gazehdr.__version__ == importlib.metadata.version("gazehdr")
    assert main(["--version"]) == 0
    assert capsys.readouterr().out == f"gazehdr {gazehdr.__version__}\n"
    not_installed = (
        "import importlib.metadata as m\n"
        "def missing(name): raise m.PackageNotFoundError(name)\n"
        "m.version = missing\n"
        "import gazehdr\n"
        "print(gazehdr.__version__)"
    )
    run = subprocess.run(
        [sys.executable, "-c", not_installed], capture_output=True, text=True, check=True
    )
    assert run.stdout == gazehdr.NOT_INSTALLED + "\n"
    assert gazehdr.NOT_INSTALLED.startswith("unknown (") and "not installed" in run.stdout


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycles() -> None:
    assert _cycles(_graph()) == []


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


# --- the viewer's files ------------------------------------------------------------------------


def _copy_web(to: Path) -> Path:
    to.mkdir()
    for path in (ROOT / "web").iterdir():
        if path.is_file():
            (to / path.name).write_bytes(path.read_bytes())
    return to


def test_viewer_files_follow_the_page_and_its_imports() -> None:
    files = viewer_files(ROOT / "web")
    assert files[0] == "index.html"
    assert {"main.js", "style.css", "protocol.js", "renderer.js", "hud.js", "panel.js"} <= set(
        files
    )


def test_a_missing_module_is_named_with_what_imports_it(tmp_path: Path) -> None:
    web = _copy_web(tmp_path / "web")
    (web / "renderer.js").unlink()
    with pytest.raises(ViewerMissingError, match=r"renderer\.js .*imported by main\.js"):
        viewer_files(web)


def test_serve_refuses_to_start_without_its_viewer(tmp_path: Path) -> None:
    """Not a 404 viewer: exit 2 naming the file, before any URL or token is printed."""
    web = _copy_web(tmp_path / "web")
    (web / "main.js").unlink()
    env = {**os.environ, "GAZEHDR_WEB_DIR": str(web), "GAZEHDR_DATA_DIR": str(tmp_path / "d")}
    result = subprocess.run(
        [sys.executable, "-m", "gazehdr", "serve", "--port", "0", "--backend", "reference"],
        capture_output=True, text=True, env=env, timeout=120, check=False,
    )  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert "main.js is missing" in result.stderr
    assert "token" not in result.stdout and "http://" not in result.stdout


def test_serve_on_a_busy_port_fails_before_printing(tmp_path: Path) -> None:
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        result = subprocess.run(
            [sys.executable, "-m", "gazehdr", "serve", "--port", str(port),
             "--data-dir", str(tmp_path)],
            capture_output=True, text=True, timeout=120, check=False,
        )  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert f"cannot listen on 127.0.0.1 port {port}" in result.stderr
    assert "token" not in result.stdout


# --- the installed wheel -----------------------------------------------------------------------


def _run(*args: str | Path, cwd: Path | None = None, timeout: float = 600) -> str:
    result = subprocess.run(
        [str(a) for a in args], cwd=cwd, capture_output=True, text=True, timeout=timeout,
        check=False,
    )  # fmt: skip
    assert result.returncode == 0, f"{args}: {result.stdout}\n{result.stderr}"
    return result.stdout


@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The sdist, and the wheel built from it (`python -m build`, no isolation: offline). Once
    a run: the build writes its egg-info into the checkout, so two xdist workers building at
    once would race; the first builds into the run's shared folder under a lock, the other
    waits and takes that."""
    run = run_folder(tmp_path_factory)
    out = run / "dist"
    with open(run / "dist.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # let go when the file closes
        if not any(out.glob("gazehdr-*.whl")):
            out.mkdir(exist_ok=True)
            _run(sys.executable, "-m", "build", "--no-isolation", "--outdir", out, ROOT)
    (sdist,) = out.glob("gazehdr-*.tar.gz")
    (wheel,) = out.glob("gazehdr-*.whl")
    return {"sdist": sdist, "wheel": wheel}


@pytest.fixture(scope="module")
def installed(dist: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh venv with the wheel installed (not editable); returns its python."""
    home = tmp_path_factory.mktemp("venv")
    with_deps = os.environ.get("GAZEHDR_WHEEL_DEPS") == "install"
    venv.create(home, with_pip=with_deps)
    python = home / "bin" / "python"
    if with_deps:
        _run(python, "-m", "pip", "install", "-q", f"{dist['wheel']}[server]")
        return python
    _run(sys.executable, "-m", "pip", "--python", python, "install", "-q", "--no-deps",
         dist["wheel"])  # fmt: skip
    purelib = _run(python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))")
    deps = Path(purelib.strip(), "_gazehdr_test_deps.pth")
    deps.write_text(sysconfig.get_path("purelib") + "\n")
    return python


def test_wheel_and_sdist_carry_the_viewer_and_the_licence(dist: dict[str, Path]) -> None:
    with zipfile.ZipFile(dist["wheel"]) as wheel:
        names = set(wheel.namelist())
    for file in viewer_files(ROOT / "web"):
        assert f"gazehdr/web/{file}" in names
    assert "gazehdr/sim/kernels/sec2_2_afterimages.cl" in names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names), sorted(names)
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == {"gazehdr"}
    import tarfile

    with tarfile.open(dist["sdist"]) as sdist:
        members = {m.name.split("/", 1)[1] for m in sdist.getmembers() if "/" in m.name}
    assert {"LICENSE", "web/index.html", "web/main.js", "pyproject.toml"} <= members
    pages = {str(p.relative_to(ROOT)) for p in (ROOT / "docs").rglob("*.md")}
    assert pages <= members  # the sdist carries docs/
    assert {f"gazehdr/{page}" for page in pages} <= names  # and the wheel, as gazehdr.docs


def test_an_installed_user_finds_the_docs(installed: Path, elsewhere: Path) -> None:
    """`gazehdr --help` says where the documentation is, and `gazehdr docs` (and `gazehdr docs
    PAGE`) names the installed files, which exist. Guards docs that do not ship with the wheel
    (the help texts named docs/*.md, which an installed user does not have)."""
    run = lambda *args: _run(installed, "-m", "gazehdr", *args, cwd=elsewhere)  # noqa: E731
    assert "'gazehdr docs'" in run("--help")
    index = run("docs")
    assert "server" in index and "model" in index
    page = Path(run("docs", "server").strip())
    assert page.is_file() and page.name == "server.md" and "site-packages" in str(page)


@pytest.fixture
def elsewhere(tmp_path: Path) -> Path:
    """A working folder with a `server.py` and a `drivers/` that must shadow nothing."""
    (tmp_path / "server.py").write_text("raise SystemExit('the local server.py was imported')\n")
    (tmp_path / "drivers").mkdir()
    (tmp_path / "drivers" / "__init__.py").write_text("raise SystemExit('local drivers')\n")
    return tmp_path


def test_installed_gazehdr_is_the_only_top_level_name(installed: Path, elsewhere: Path) -> None:
    code = (
        "import importlib.util, gazehdr, gazehdr.sim, gazehdr.drivers.wire;"
        "from gazehdr.sim import Simulator;"
        "print(gazehdr.__file__);"
        "print(importlib.util.find_spec('server') is not None and "
        "'site-packages' in importlib.util.find_spec('server').origin);"
        "print(importlib.util.find_spec('drivers') is not None and "
        "'site-packages' in importlib.util.find_spec('drivers').origin)"
    )
    where, server, drivers = _run(installed, "-c", code, cwd=elsewhere).split()
    assert "site-packages" in where and str(ROOT) not in where
    assert (server, drivers) == ("False", "False")
    # Nothing outside the cwd: `import server` resolves to the local file or fails.
    spec = "import importlib.util as u; print(u.find_spec('server'), u.find_spec('drivers'))"
    isolated = _run(installed, "-I", "-c", spec)
    assert isolated.split() == ["None", "None"]
    assert "usage: gazehdr" in _run(installed, "-m", "gazehdr", "--help", cwd=elsewhere)


async def _first_frame(url: str, token: str) -> bytes:
    auth = {"Authorization": f"Bearer {token}"}
    async with websockets.connect(url, open_timeout=60, additional_headers=auth) as ws:
        while True:
            message = await asyncio.wait_for(ws.recv(), 120)
            if isinstance(message, bytes):
                return message


def _served_url(process: subprocess.Popen[str]) -> str:
    """The URL `gazehdr serve` printed (the port it bound, port 0 asked)."""
    assert process.stdout is not None
    for line in process.stdout:
        if m := re.search(r"open (http://\S+?)/ ", line):
            return m[1]
    raise AssertionError("gazehdr serve printed no URL")


def test_installed_server_serves_the_viewer_and_frames(installed: Path, elsewhere: Path) -> None:
    from urllib.request import urlopen

    process = subprocess.Popen(
        [installed, "-m", "gazehdr", "serve", "--port", "0", "--size", "64x36",
         "--data-dir", elsewhere / "data", "--token", "pkg-test"],
        cwd=elsewhere, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env={k: v for k, v in os.environ.items() if k != "GAZEHDR_WEB_DIR"},
    )  # fmt: skip
    try:
        url = _served_url(process)
        for file in ["", *viewer_files(ROOT / "web")]:
            with urlopen(f"{url}/{file}", timeout=30) as response:
                assert response.status == 200, file
                assert response.read() == (ROOT / "web" / (file or "index.html")).read_bytes()
        frame = asyncio.run(_first_frame(url.replace("http://", "ws://") + "/ws/view", "pkg-test"))
        assert len(frame) > 64 * 36
    finally:
        process.terminate()
        process.wait(timeout=30)


def test_serve_builds_its_kernels_before_it_prints_the_address(tmp_path: Path) -> None:
    """The first viewer gets a picture at once: `serve` builds the kernels of a session as new
    viewers get it, saying so and where they are kept, before it prints the address. Guards
    the build moved after the address (the page then waited up to a minute, saying only that
    the server was preparing)."""
    env = {**os.environ, "GAZEHDR_DATA_DIR": str(tmp_path / "d"), "PYTHONUNBUFFERED": "1"}
    server = subprocess.Popen(
        [sys.executable, "-m", "gazehdr", "serve", "--port", "0", "--size", "64x36"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
    )  # fmt: skip
    try:
        assert server.stdout is not None
        lines = []
        for line in server.stdout:
            lines.append(line)
            if "open http" in line:
                break
        said = "".join(lines)
        assert "building the simulation's kernels" in said and "kernels ready in" in said
        assert said.index("kernels ready in") < said.index("open http"), said
        from gazehdr.serve import kernel_cache_dir

        assert kernel_cache_dir() in said  # where they are kept (POCL_CACHE_DIR where set)
    finally:
        server.terminate()
        server.wait(timeout=30)
