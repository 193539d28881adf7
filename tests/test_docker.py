"""The Docker images and the compose file: checked without a Docker engine, and built and run
where one answers.

The Dockerfiles are parsed with `dockerfile` (Docker's own Go parser, from PyPI) and the compose
files with PyYAML; the server's CMD goes through gazehdr's own argument parser, so a renamed
option breaks this test rather than the container.

The tests marked `docker` (at the end) build the images on a base made by docker/make-base.sh,
run the server container and take a frame from it over /ws/view, and stream gaze into it from
the daemon container. The default run leaves them out (pyproject.toml: `-m "not docker"`); run
them with `pytest -n 0 -m docker` where `docker info` answers (they skip, saying so, where it does
not). See docker/README.md, "Checks".
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

import dockerfile
import numpy as np
import pytest
import websockets
import yaml

from gazehdr.cli import build_parser
from gazehdr.drivers.daemon import gaze_url
from gazehdr.drivers.daemon_cli import RECORD_DIR_ENV
from gazehdr.drivers.daemon_cli import build_parser as daemon_parser
from gazehdr.protocol import FrameHeader, decode_frame

if sys.version_info >= (3, 11):
    import tomllib
else:  # the test extra installs tomli on Python 3.10
    import tomli as tomllib


ROOT = Path(__file__).resolve().parents[1]
DOCKER = ROOT / "docker"
SERVER = DOCKER / "server.Dockerfile"
DAEMON = DOCKER / "daemon.Dockerfile"
DOCKERFILES = [SERVER, DAEMON]
COMPOSE = DOCKER / "compose.yaml"
COMPOSE_GPU = DOCKER / "compose.gpu.yaml"
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


# --- helpers --------------------------------------------------------------------------------------


def stages(path: Path) -> list[tuple[str | None, list[dockerfile.Command]]]:
    """The Dockerfile's stages in order: (name from `FROM … AS name`, instructions after FROM).
    The ARGs before the first FROM are no stage's (`global_args`)."""
    result: list[tuple[str | None, list[dockerfile.Command]]] = []
    for command in dockerfile.parse_file(str(path)):
        if command.cmd == "FROM":
            value = command.value
            name = value[2] if len(value) == 3 and value[1].upper() == "AS" else None
            result.append((name, [command]))
        elif result:
            result[-1][1].append(command)
        else:
            assert command.cmd == "ARG", (
                f"{path.name}:{command.start_line}: {command.cmd} before the first FROM"
            )
    assert result, f"{path.name}: no FROM"
    return result


def global_args(path: Path) -> dict[str, str | None]:
    """The ARGs before the first FROM (the only variables FROM can use), with their defaults."""
    args: dict[str, str | None] = {}
    for command in dockerfile.parse_file(str(path)):
        if command.cmd == "FROM":
            break
        for item in command.value:
            name, has_default, default = item.partition("=")
            args[name] = default if has_default else None
    return args


def from_image(path: Path, image: str) -> str:
    """A FROM's image with the global ARGs' defaults put in for `${NAME}` and `$NAME`."""
    args = global_args(path)

    def default(match: re.Match[str]) -> str:
        name = match[1] or match[2]
        assert args.get(name), f"{path.name}: FROM {image}: {name} is no global ARG with a default"
        return args[name] or ""

    return re.sub(r"\$\{(\w+)\}|\$(\w+)", default, image)


def final_stage(path: Path) -> list[dockerfile.Command]:
    return stages(path)[-1][1]


def only(commands: list[dockerfile.Command], cmd: str) -> dockerfile.Command:
    found = [c for c in commands if c.cmd == cmd]
    assert len(found) == 1, f"expected one {cmd}, found {len(found)}"
    return found[0]


def env(commands: list[dockerfile.Command]) -> dict[str, str]:
    """ENV values of a stage (`ENV K=V K2=V2` form, which the parser gives as pairs)."""
    values: dict[str, str] = {}
    for c in commands:
        if c.cmd == "ENV":
            pairs = c.value
            values.update(zip(pairs[::2], pairs[1::2], strict=True))
    return values


def local_copies(path: Path) -> list[tuple[dockerfile.Command, list[str], str]]:
    """(command, sources, destination) of every COPY/ADD from the build context."""
    copies = []
    for _, commands in stages(path):
        for c in commands:
            if c.cmd in ("COPY", "ADD") and not any(f.startswith("--from=") for f in c.flags):
                *sources, dest = c.value
                copies.append((c, sources, dest))
    return copies


def runs(path: Path) -> list[str]:
    return [c.value[0] for _, commands in stages(path) for c in commands if c.cmd == "RUN"]


def dockerignore_excludes(rel: str) -> bool:
    """Whether .dockerignore keeps `rel` (or a folder above it) out of the build context.

    Docker's rules: patterns are Go filepath.Match patterns from the context root, `**` spans any
    number of folders, `!` re-includes, the last matching line wins, and a matched folder takes
    its contents along.
    """
    rules = []
    for line in (ROOT / ".dockerignore").read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        negate = line.startswith("!")
        pattern = line.lstrip("!").strip().strip("/")
        regex = ""
        for token in re.split(r"(\*\*/|\*\*|\*|\?|\[[^\]]*\])", pattern):
            if token.startswith("[") and token.endswith("]") and len(token) > 2:
                regex += "[^" + token[2:] if token.startswith(("[^", "[!")) else token
            else:
                regex += {"**/": "(?:.*/)?", "**": ".*", "*": "[^/]*", "?": "[^/]"}.get(
                    token, re.escape(token)
                )
        rules.append((re.compile(regex + r"\Z"), negate))
    parts = Path(rel).parts
    candidates = ["/".join(parts[: i + 1]) for i in range(len(parts))]
    excluded = False
    for regex, negate in rules:
        if any(regex.match(c) for c in candidates):
            excluded = not negate
    return excluded


def compose(path: Path = COMPOSE) -> dict:
    data = yaml.safe_load(path.read_text())
    assert isinstance(data, dict) and isinstance(data.get("services"), dict), path.name
    return data


def environment(service: dict) -> dict[str, str | None]:
    """A service's environment as a mapping; None is a pass-through of the host's variable."""
    raw = service.get("environment") or {}
    if isinstance(raw, dict):
        return {k: None if v is None else str(v) for k, v in raw.items()}
    variables: dict[str, str | None] = {}
    for item in raw:
        name, has_value, value = item.partition("=")
        variables[name] = value if has_value else None
    return variables


def interpolate(text: str) -> str:
    """Compose's `${VAR:-default}` and `${VAR}` with no variables set: the defaults."""
    return re.sub(r"\$\{\w+(?::?-([^}]*))?\}", lambda m: m[1] or "", text)


def expose_port(path: Path) -> int:
    return int(only(final_stage(path), "EXPOSE").value[0].split("/")[0])


def mounted_volume(data: dict, service: dict, path: str) -> str | None:
    """The named volume of `data` that `service` mounts at `path` or a folder above it."""
    for volume in service.get("volumes", []):
        source, target = volume.split(":")[:2]
        if source in (data.get("volumes") or {}) and Path(path).is_relative_to(target):
            return source
    return None


def parse_daemon_args(command: list[str] | str, what: str) -> argparse.Namespace:
    """`command` through `gazehdr daemon`'s own parser (an option it lacks fails here), with
    none of gazehdr's variables set here, so the values are the command's or the defaults."""
    argv = shlex.split(command) if isinstance(command, str) else list(command)
    with pytest.MonkeyPatch.context() as mp:
        for name in [n for n in os.environ if n.startswith("GAZEHDR_")]:
            mp.delenv(name)
        try:
            return daemon_parser().parse_args(argv)
        except SystemExit as e:
            pytest.fail(f"gazehdr daemon rejects the {what} {argv} (exit {e.code})")


# --- Dockerfiles ----------------------------------------------------------------------------------


@pytest.mark.parametrize("path", DOCKERFILES, ids=lambda p: p.name)
def test_every_stage_starts_from_a_pinned_tag(path: Path) -> None:
    """By default: a build argument's default is what a plain `docker build` pulls."""
    seen: list[str] = []
    for name, commands in stages(path):
        image = from_image(path, commands[0].value[0])
        if image not in seen and "@sha256:" not in image:  # not an earlier stage, not a digest
            repo, _, tag = image.rpartition(":")
            assert repo and "/" not in tag, f"{path.name}: FROM {image} has no tag"
            assert tag != "latest", f"{path.name}: FROM {image}: 'latest' is not a pin"
        if name:
            seen.append(name)


@pytest.mark.parametrize("path", DOCKERFILES, ids=lambda p: p.name)
def test_final_stage_runs_as_a_user_it_creates(path: Path) -> None:
    commands = final_stage(path)
    users = [c.value[0] for c in commands if c.cmd == "USER"]
    assert users, f"{path.name}: the final stage never sets USER, so it runs as root"
    user = users[-1].split(":")[0]
    assert user not in ("root", "0"), f"{path.name}: USER {users[-1]}"
    runs = " ".join(c.value[0] for c in commands if c.cmd == "RUN")
    assert re.search(rf"useradd\b[^&;]*\s{re.escape(user)}(\s|$)", runs), (
        f"{path.name}: USER {user} is never created with useradd in the final stage"
    )


@pytest.mark.parametrize("path", DOCKERFILES, ids=lambda p: p.name)
def test_copy_sources_exist_and_reach_the_build_context(path: Path) -> None:
    names = [name for name, _ in stages(path) if name]
    for _, commands in stages(path):
        for c in commands:
            for flag in c.flags:
                if flag.startswith("--from="):
                    assert flag.removeprefix("--from=") in names, f"{path.name}: {c.original}"
    for c, sources, _ in local_copies(path):
        for source in sources:
            assert not source.startswith(("/", "..")), f"{path.name}: {c.original}"
            assert (ROOT / source).exists(), f"{path.name}:{c.start_line}: no {source} in the repo"
            assert not dockerignore_excludes(source), (
                f"{path.name}:{c.start_line}: .dockerignore keeps {source} out of the context"
            )


@pytest.mark.parametrize("path", DOCKERFILES, ids=lambda p: p.name)
def test_builder_copies_what_pip_install_needs(path: Path) -> None:
    """pyproject.toml, its readme, its licence files, MANIFEST.in (setuptools includes the package
    data it names) and every folder `package-dir` maps."""
    copied = {
        Path(s).as_posix().strip("/") for _, sources, _ in local_copies(path) for s in sources
    }
    project, setuptools = PYPROJECT["project"], PYPROJECT["tool"]["setuptools"]
    needed = {"pyproject.toml", project["readme"], *project["license-files"]}
    needed |= set(setuptools["package-dir"].values())
    if (ROOT / "MANIFEST.in").exists():
        needed.add("MANIFEST.in")
    assert needed <= copied, f"{path.name}: not copied: {sorted(needed - copied)}"


def test_server_installs_the_server_extra() -> None:
    commands = runs(SERVER)
    assert any(re.search(r"pip install\s+'?\.\[server\]'?", r) for r in commands), commands


def test_daemon_installs_the_daemon_extra_and_never_pyopencl() -> None:
    commands = runs(DAEMON)
    assert any(re.search(r"pip install\s+'?\.\[daemon\]'?", r) for r in commands), commands
    text = DAEMON.read_text()
    for forbidden in ("pyopencl", "pocl", "[server]", "[test]", "[bench]", "'server']"):
        # Comments may say what is left out; instructions may not bring it in.
        code = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#"))
        assert forbidden not in code.lower(), f"daemon.Dockerfile mentions {forbidden}"


def test_daemon_extra_does_not_pull_in_pyopencl() -> None:
    """Follows `gazehdr[...]` self-references in pyproject.toml from the base and `daemon`."""
    extras = PYPROJECT["project"]["optional-dependencies"]
    todo, seen, requirements = ["daemon"], set(), list(PYPROJECT["project"]["dependencies"])
    while todo:
        extra = todo.pop()
        if extra in seen:
            continue
        seen.add(extra)
        for requirement in extras[extra]:
            match = re.match(r"gazehdr\[([^\]]+)\]", requirement)
            if match:
                todo += [e.strip() for e in match[1].split(",")]
            else:
                requirements.append(requirement)
    names = {re.split(r"[\s\[<>=!~;]", r, maxsplit=1)[0].lower() for r in requirements}
    assert not names & {"pyopencl", "pocl-binary-distribution"}, sorted(names)


def test_server_cmd_parses_with_the_gazehdr_cli() -> None:
    cmd = only(final_stage(SERVER), "CMD")
    assert cmd.json, "CMD must be exec form, so that gazehdr is PID 1 and gets SIGTERM"
    program, *argv = cmd.value
    assert program in PYPROJECT["project"]["scripts"], program
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:
        pytest.fail(f"gazehdr rejects the server image's CMD {cmd.value} (exit {e.code})")
    assert args.command == "serve"
    assert args.host == "0.0.0.0", "inside a container only 0.0.0.0 is reachable from outside"
    assert args.port == expose_port(SERVER)


def test_daemon_entrypoint_is_gazehdr_daemon() -> None:
    entrypoint = only(final_stage(DAEMON), "ENTRYPOINT")
    assert entrypoint.json and list(entrypoint.value) == ["gazehdr", "daemon"], entrypoint.value


def test_daemon_cmd_reads_the_tracker_and_records_into_the_volume() -> None:
    """Without arguments the image runs the tracker (not the synthetic default) and, as no
    `--record` overrides it, records into GAZEHDR_RECORD_DIR, which lies in the volume."""
    commands = final_stage(DAEMON)
    cmd = only(commands, "CMD")
    assert cmd.json, "CMD must be exec form: a shell form reaches the ENTRYPOINT as sh -c ..."
    args = parse_daemon_args(cmd.value, "daemon image's CMD")
    assert args.source.partition(":")[0] == "hid"
    assert args.record is None and args.record_dir is None
    record_dir = env(commands).get(RECORD_DIR_ENV)
    volumes = [v for c in commands if c.cmd == "VOLUME" for v in c.value]
    assert record_dir and any(Path(record_dir).is_relative_to(v) for v in volumes), record_dir


def test_server_healthcheck_gets_api_health_with_the_stdlib() -> None:
    check = only(final_stage(SERVER), "HEALTHCHECK")
    assert check.json and check.value[0] == "CMD", "exec form: no shell needed"
    program, *argv = check.value[1:]
    assert program in ("python", "python3", "/opt/venv/bin/python"), "slim images have no curl"
    assert argv[0] == "-c"
    code = argv[1]
    compile(code, "<HEALTHCHECK>", "exec")
    urls = re.findall(r"https?://[^'\"\s]+", code)
    assert len(urls) == 1, code
    url = urlsplit(urls[0])
    assert url.path == "/api/health"
    assert url.hostname == "127.0.0.1" and url.port == expose_port(SERVER)
    assert "timeout=" in code, "a hung server must fail the check, not hang it"


def test_server_environment_matches_the_layout() -> None:
    commands = final_stage(SERVER)
    values = env(commands)
    # The viewer travels inside the installed package; a web dir set here would override it.
    assert "GAZEHDR_WEB_DIR" not in values
    volumes = [v for c in commands if c.cmd == "VOLUME" for v in c.value]
    assert values.get("GAZEHDR_DATA_DIR") in volumes


@pytest.mark.parametrize("path", DOCKERFILES, ids=lambda p: p.name)
def test_no_token_is_baked_into_an_image(path: Path) -> None:
    for _, commands in stages(path):
        for c in commands:
            if c.cmd in ("ENV", "ARG", "LABEL"):
                assert "GAZEHDR_TOKEN" not in c.original, f"{path.name}: {c.original}"


def test_dockerignore_keeps_local_state_out() -> None:
    for rel in (".git", ".venv", "out/flash/f.png", "server/__pycache__", "x/y.pyc", "a/b.exr"):
        assert dockerignore_excludes(rel), rel
    for rel in ("pyproject.toml", "README.md", "server/cli.py", "drivers", "web/index.html"):
        assert not dockerignore_excludes(rel), rel


# --- the base image and offline builds -----------------------------------------------------------

MAKE_BASE = DOCKER / "make-base.sh"
DEFAULT_BASE = "python:3.11-slim-bookworm"


def make_base_packages() -> set[str]:
    """The Debian packages docker/make-base.sh puts into the base (its --include options)."""
    found = re.findall(r"--include=([\w.+,-]+)", MAKE_BASE.read_text())
    return {package for group in found for package in group.split(",")}


def runs_of(commands: list[dockerfile.Command]) -> list[str]:
    return [c.value[0] for c in commands if c.cmd == "RUN"]


def apt_installs(command: str) -> set[str]:
    """The packages a RUN's `apt-get install` names."""
    names: set[str] = set()
    for match in re.finditer(r"apt-get install((?:\s+[^\s&;|}]+)+)", command):
        names |= {word for word in match[1].split() if not word.startswith("-")}
    return names


@pytest.mark.parametrize("path", DOCKERFILES, ids=lambda p: p.name)
def test_every_stage_starts_from_the_base_build_argument(path: Path) -> None:
    """One `--build-arg BASE=...` swaps the base of every stage (docker/make-base.sh's, offline);
    without it the build takes python:3.11-slim-bookworm."""
    assert global_args(path).get("BASE") == DEFAULT_BASE, f"{path.name}: ARG BASE={DEFAULT_BASE}"
    names: list[str] = []
    for name, commands in stages(path):
        image = commands[0].value[0]
        assert image in names or image in ("${BASE}", "$BASE"), f"{path.name}: FROM {image}"
        if name:
            names.append(name)


def test_make_base_makes_the_default_bases_debian_and_a_supported_python() -> None:
    """make-base.sh's suite is the default base's (bookworm); the Python of both (3.11, bookworm's
    python3) is one that pyproject.toml's requires-python admits."""
    text = MAKE_BASE.read_text()
    suite = DEFAULT_BASE.rpartition("-")[2]
    assert re.search(rf"^\s+{suite} \"\$work/rootfs.tar\"", text, re.M), "mmdebstrap SUITE"
    assert f"gazehdr-base:{suite}-" in text
    assert {"python3", "python3-venv", "python-is-python3", "passwd"} <= make_base_packages()
    version = tuple(int(n) for n in re.search(r":(\d+)\.(\d+)", DEFAULT_BASE).groups())
    floor = re.fullmatch(r">=(\d+)\.(\d+)", PYPROJECT["project"]["requires-python"])
    assert floor and version >= (int(floor[1]), int(floor[2])), DEFAULT_BASE


def test_make_base_holds_what_the_server_runtime_installs() -> None:
    """PoCL links kernels with ld against libc and libgcc: the runtime stage installs them unless
    the base has them, and the made base has them, so an offline build needs no Debian mirror."""
    (command,) = [r for r in runs_of(final_stage(SERVER)) if "apt-get" in r]
    installs = apt_installs(command)
    assert {"binutils", "libc6-dev", "libgcc-12-dev"} <= installs, installs
    assert installs <= make_base_packages(), sorted(installs - make_base_packages())
    skip = re.match(r"dpkg -s ([\w.+ -]+?) >/dev/null 2>&1 \|\| \{", command)
    assert skip and set(skip[1].split()) == installs, command


@pytest.mark.parametrize("path", DOCKERFILES, ids=lambda p: p.name)
def test_pip_index_is_a_builder_argument_never_baked_in(path: Path) -> None:
    """PIP_INDEX_URL / PIP_EXTRA_INDEX_URL reach the builder's pip as build arguments (ARGs are
    environment variables to RUN); no ENV sets them and the final stage never declares them."""
    (builder_name, builder), *_, (_, final) = stages(path)
    assert builder_name == "builder"
    declared = {item.partition("=")[0] for c in builder if c.cmd == "ARG" for item in c.value}
    assert {"PIP_INDEX_URL", "PIP_EXTRA_INDEX_URL"} <= declared, declared
    for _, commands in stages(path):
        assert not {"PIP_INDEX_URL", "PIP_EXTRA_INDEX_URL"} & set(env(commands)), path.name
    assert not any(c.cmd == "ARG" and "PIP_" in c.original for c in final), path.name


def test_dockerignore_keeps_package_data_in_the_build_context() -> None:
    """Every file pyproject.toml's package-data ships reaches the image's `pip install .`
    (`**/*.exr` must not take Fig. 7's photographs along)."""
    setuptools = PYPROJECT["tool"]["setuptools"]
    folders = setuptools["package-dir"]
    for package, patterns in setuptools["package-data"].items():
        root = max((p for p in folders if package == p or package.startswith(p + ".")), key=len)
        folder = Path(folders[root], *package.removeprefix(root).split(".")[1:])
        for pattern in patterns:
            files = sorted((ROOT / folder).glob(pattern))
            assert files, f"{package}: no {folder / pattern}"
            for file in files:
                rel = file.relative_to(ROOT).as_posix()
                assert not dockerignore_excludes(rel), f".dockerignore keeps {rel} out"


# --- compose ------------------------------------------------------------------------------------


def test_compose_builds_both_images_from_the_repo_root() -> None:
    services = compose()["services"]
    for service, path in (("server", SERVER), ("daemon", DAEMON)):
        build = services[service]["build"]
        context = (COMPOSE.parent / build["context"]).resolve()
        assert context == ROOT, f"{service}: context {context}"
        assert (context / build["dockerfile"]).resolve() == path.resolve()


def test_compose_builds_on_the_dockerfiles_base_unless_told_another() -> None:
    """GAZEHDR_BASE (unset: the Dockerfiles' own default) and the pip index pass-throughs reach
    both builds, so `GAZEHDR_BASE=<make-base.sh's tag> docker compose up --build` builds offline."""
    services = compose()["services"]
    for service, path in (("server", SERVER), ("daemon", DAEMON)):
        args = services[service]["build"]["args"]
        assert re.fullmatch(r"\$\{GAZEHDR_BASE:-[^}]+\}", args["BASE"]), args
        assert interpolate(args["BASE"]) == global_args(path)["BASE"], service
        # No value: the shell's, or no build argument at all where it is unset.
        assert args["PIP_INDEX_URL"] is None and args["PIP_EXTRA_INDEX_URL"] is None, args


def test_plain_compose_up_runs_only_the_server() -> None:
    services = compose()["services"]
    default = {name for name, s in services.items() if not s.get("profiles")}
    assert default == {"server"}
    assert "tracker" in services["daemon"]["profiles"]


def test_compose_server_is_published_on_loopback_with_a_data_volume() -> None:
    data = compose()
    server = data["services"]["server"]
    assert server["ports"] == [f"127.0.0.1:{expose_port(SERVER)}:{expose_port(SERVER)}"]
    data_dir = env(final_stage(SERVER))["GAZEHDR_DATA_DIR"]
    mounts = [v.split(":") for v in server["volumes"]]
    assert any(target == data_dir and source in data["volumes"] for source, target in mounts)


def test_compose_passes_the_token_through_without_a_value() -> None:
    """A value in compose.yaml would be a secret in git; an empty one would be a token ''."""
    for name in ("server", "daemon"):
        variables = environment(compose()["services"][name])
        assert "GAZEHDR_TOKEN" in variables and variables["GAZEHDR_TOKEN"] is None, name


def test_compose_daemon_streams_the_tracker_to_the_server_and_records_it() -> None:
    data = compose()
    daemon = data["services"]["daemon"]
    args = parse_daemon_args(daemon.get("command", []), "compose daemon command")
    assert args.source.partition(":")[0] == "hid"
    server = args.server or environment(daemon).get("GAZEHDR_SERVER")
    assert server, "the daemon is told no server"
    url = urlsplit(gaze_url(server))
    build = data["services"].get(url.hostname, {}).get("build")
    assert build, f"{server}: {url.hostname} is no service this file builds"
    assert (COMPOSE.parent / build["context"] / build["dockerfile"]).resolve() == SERVER, server
    assert url.port == expose_port(SERVER), server
    assert daemon["depends_on"][url.hostname]["condition"] == "service_healthy"
    # The token only from the environment (see the pass-through test), never in the command.
    assert args.token is None
    # What records: no --record/--record-dir, so GAZEHDR_RECORD_DIR (the image's unless compose
    # sets its own), on a named volume, so recordings outlive the container.
    assert args.record is None and args.record_dir is None
    record_dir = {**env(final_stage(DAEMON)), **environment(daemon)}.get(RECORD_DIR_ENV)
    assert record_dir and mounted_volume(data, daemon, record_dir), record_dir


def test_compose_daemon_gets_the_tracker_under_its_own_path() -> None:
    daemon = compose()["services"]["daemon"]
    for device in daemon["devices"]:
        outside, inside = interpolate(device).split(":")[:2]
        assert outside == inside, f"{device}: hidapi looks the node up by its host name"
    assert daemon["group_add"], "the node belongs to the host's plugdev"


def test_pocl_kernel_cache_is_kept_on_a_volume_the_server_can_write() -> None:
    """Built kernels cut start-up from seconds to a fraction of one; a re-created container
    keeps them only on a volume, and a fresh named volume takes the ownership of the image's
    folder, which must be the user's the server runs as."""
    commands = final_stage(SERVER)
    cache = env(commands).get("POCL_CACHE_DIR")
    assert cache, "PoCL would cache in ~/.cache, lost with the container"
    user = [c.value[0] for c in commands if c.cmd == "USER"][-1].split(":")[0]
    setup = " ".join(c.value[0] for c in commands if c.cmd == "RUN")
    assert re.search(rf"mkdir -p [^&;]*{re.escape(cache)}(\s|$)", setup), setup
    assert re.search(rf"chown {user}(:\w+)? [^&;]*{re.escape(cache)}(\s|$)", setup), setup
    data = compose()
    server = data["services"]["server"]
    volume = mounted_volume(data, server, cache)
    data_volume = mounted_volume(data, server, env(commands)["GAZEHDR_DATA_DIR"])
    assert volume and volume != data_volume, "a volume of its own, not the user's data"
    assert environment(server)["GAZEHDR_POCL_CPU"] is None  # passed through when set


def test_compose_gpu_override_only_touches_the_server() -> None:
    data = compose(COMPOSE_GPU)
    assert set(data["services"]) == {"server"}
    server = data["services"]["server"]
    assert environment(server)["NVIDIA_DRIVER_CAPABILITIES"].split(",")[0] == "compute"
    devices = server["deploy"]["resources"]["reservations"]["devices"]
    assert devices[0]["driver"] == "nvidia"
    assert any(v.split(":")[1] == "/etc/OpenCL/vendors/nvidia.icd" for v in server["volumes"])


# --- udev -----------------------------------------------------------------------------------------

MATCH = DOCKER / "udev" / "gazehdr-eyetracker-match"

# A mouse collection, then an eye tracker: Usage Page 0x12, Usage 0x01, Collection (Application),
# padded so that the match straddles od's 16-byte lines.
EYE_TRACKER = bytes.fromhex("05010902a101 0901a100 c0c0 0000 05120901a101 8510 c0".replace(" ", ""))
EYE_TRACKER_LONG_PAGE = bytes.fromhex("0612000a0100a101c0")
MOUSE = bytes.fromhex("05010902a1010901a100c0c0")
# The right nibbles across byte boundaries, the wrong bytes: a0 51 20 90 1a 10.
MISALIGNED = bytes.fromhex("a05120901a10")
HEAD_TRACKER = bytes.fromhex("05120902a101c0")  # also usage page 0x12
# Usage Page 0x12 inside a collection that is not an application one (a1 00: physical).
NOT_APPLICATION = bytes.fromhex("05120901a100c0")


@pytest.mark.skipif(shutil.which("od") is None, reason="needs a POSIX shell with od")
@pytest.mark.parametrize(
    ("descriptor", "matches"),
    [
        (EYE_TRACKER, True),
        (EYE_TRACKER_LONG_PAGE, True),
        (MOUSE, False),
        (MISALIGNED, False),
        (HEAD_TRACKER, True),
        (NOT_APPLICATION, False),
        (None, False),
    ],
    ids=[
        "eye-tracker",
        "two-byte-page",
        "mouse",
        "misaligned",
        "head-tracker",
        "physical-collection",
        "no-descriptor",
    ],
)
def test_udev_matcher_finds_usage_page_0x12_by_report_descriptor(
    tmp_path: Path, descriptor: bytes | None, matches: bool
) -> None:
    assert os.access(MATCH, os.X_OK), "udev runs the matcher directly: it must be executable"
    devpath = "/devices/pci0000:00/usb1/1-1/1-1:1.0/0003:2104:0127.0001/hidraw/hidraw0"
    if descriptor is not None:
        hid = tmp_path / devpath.lstrip("/") / "device"
        hid.mkdir(parents=True)
        (hid / "report_descriptor").write_bytes(descriptor)
    result = subprocess.run(
        ["sh", str(MATCH), devpath], env={**os.environ, "SYSFS": str(tmp_path)}, check=False
    )
    assert (result.returncode == 0) == matches


def test_udev_rule_runs_the_matcher_and_hands_the_node_to_plugdev() -> None:
    rules = [
        line
        for line in (DOCKER / "udev" / "70-gazehdr-eyetracker.rules").read_text().splitlines()
        if line.strip() and not line.lstrip().startswith("#")
    ]
    assert len(rules) == 1
    rule = rules[0]
    assert 'SUBSYSTEM=="hidraw"' in rule
    assert f'PROGRAM="/usr/local/libexec/{MATCH.name} %p"' in rule
    assert 'GROUP="plugdev"' in rule and 'MODE="0660"' in rule


# --- built and run, where a Docker engine answers (pytest -m docker) -----------------------------
#
# Left out of the default run (pyproject.toml's addopts: -m "not docker"): they need a Docker
# engine, and take minutes. Module-scoped fixtures make the base (once per make-base.sh, mirrors
# and CA files: REUSE=1), build the server image and run one container for both tests.
#
# GAZEHDR_DOCKER_BASE   an image to build on instead of making one (e.g. python:3.11-slim-bookworm
#                       where a registry is reachable).
# GAZEHDR_DOCKER_CA_CERTS   CA files for make-base.sh's CA_CERTS (space-separated); default: the
#                       ones this host added to its own store (/usr/local/share/ca-certificates),
#                       so that the build's pip trusts what this host's pip does.
# PIP_INDEX_URL, PIP_EXTRA_INDEX_URL   passed on to the build when set (they must name an index
#                       the build can reach: not a file: URL of this host).

DOCKER_TIMEOUT = 1500  # s, setup included: a cold run makes the base and builds both images
SERVER_TAG = "gazehdr-server:test"
DAEMON_TAG = "gazehdr-daemon:test"
LIST_PACKAGE_DATA = (
    "from importlib.resources import files\n"
    "for module in 'gazehdr.sim.kernels', 'gazehdr.web', 'gazehdr.figures.data', 'gazehdr.docs':\n"
    "    print(*(p.name for p in files(module).iterdir()))"
)
TOKEN_LINE = re.compile(r"^gazehdr: token \(.*\): (\S+)$", re.M)
Completed = subprocess.CompletedProcess


def docker(*args: str, timeout: float = 120, check: bool = True, **kw) -> Completed:
    result = subprocess.run(
        ["docker", *args], capture_output=True, text=True, timeout=timeout, **kw
    )
    if check and result.returncode != 0:
        pytest.fail(f"docker {' '.join(args[:3])} … exited {result.returncode}:\n{tail(result)}")
    return result


def tail(result: Completed, lines: int = 40) -> str:
    return "\n".join((result.stdout + result.stderr).splitlines()[-lines:])


def poll(predicate, what: str, timeout: float, every: float = 0.5):
    """`predicate()`'s first true value, asked every `every` s; fails naming `what`."""
    deadline = time.monotonic() + timeout
    while not (value := predicate()):
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(every)
    return value


def build(path: Path, tag: str, base: str) -> None:
    # `--build-arg NAME` without a value passes this environment's NAME, and nothing where unset.
    pip = [a for n in ("PIP_INDEX_URL", "PIP_EXTRA_INDEX_URL") for a in ("--build-arg", n)]
    args = ["--build-arg", f"BASE={base}", *pip, "-f", str(path), "-t", tag, str(ROOT)]
    docker("build", *args, timeout=900)


def http_get(url: str, **headers: str) -> bytes:
    request = urllib.request.Request(url, headers=headers)
    with urllib.request.urlopen(request, timeout=10) as response:
        return response.read()


def http_json(url: str, **headers: str) -> dict:
    return json.loads(http_get(url, **headers))


@dataclass
class Container:
    name: str
    url: str  # http://127.0.0.1:PORT, published from the container's 8000
    token: str


@pytest.fixture(scope="module")
def docker_engine() -> None:
    if shutil.which("docker") is None:
        pytest.skip("no Docker engine answers: no docker command")
    try:
        info = docker("info", "--format", "{{.ServerVersion}}", timeout=30, check=False)
    except subprocess.TimeoutExpired:
        pytest.skip("no Docker engine answers: `docker info` took over 30 s")
    if info.returncode != 0:
        why = (info.stderr.strip().splitlines() or ["no output"])[-1]
        pytest.skip(f"no Docker engine answers: `docker info` failed: {why}")


@pytest.fixture(scope="module")
def base_image(docker_engine: None) -> str:
    if given := os.environ.get("GAZEHDR_DOCKER_BASE"):
        return given
    if os.geteuid() != 0 or shutil.which("mmdebstrap") is None:
        pytest.skip(
            "docker/make-base.sh needs root and mmdebstrap (apt-get install mmdebstrap); "
            "or name a base image in GAZEHDR_DOCKER_BASE"
        )
    certs = os.environ.get("GAZEHDR_DOCKER_CA_CERTS")
    if certs is None:
        local = Path("/usr/local/share/ca-certificates")
        certs = " ".join(str(p) for p in sorted(local.rglob("*.crt")))
    reuse = {**os.environ, "REUSE": "1", "CA_CERTS": certs}
    result = subprocess.run(
        ["sh", str(MAKE_BASE)], env=reuse, capture_output=True, text=True, timeout=900
    )
    assert result.returncode == 0, f"docker/make-base.sh failed:\n{tail(result)}"
    return result.stdout.split()[-1]


@pytest.fixture(scope="module")
def server_container(base_image: str) -> Iterator[Container]:
    build(SERVER, SERVER_TAG, base_image)
    name = f"gazehdr-test-server-{os.getpid()}"
    # A free port on the host's loopback, as compose publishes it; the token is the server's own.
    docker("run", "-d", "--name", name, "-p", "127.0.0.1::8000", SERVER_TAG)
    try:

        def token() -> str | None:
            state = docker("inspect", "-f", "{{.State.Running}}", name).stdout.strip()
            logs = docker("logs", name)
            assert state == "true", f"the server container stopped:\n{tail(logs)}"
            found = TOKEN_LINE.search(logs.stdout + logs.stderr)
            return found and found[1]

        # The token line comes once the kernels are built: PoCL's first build takes seconds.
        secret = poll(token, "the server to print its token", timeout=300)
        ports = docker("port", name, "8000/tcp").stdout
        (address,) = re.findall(r"^127\.0\.0\.1:\d+$", ports, re.M)
        yield Container(name, f"http://{address}", secret)
    finally:
        docker("rm", "-f", "-v", name, check=False)


def gaze_samples(server: Container) -> float:
    """The server's count of gaze samples received (/metrics, with the token: from the host the
    container sees no loopback client)."""
    text = http_get(server.url + "/metrics", Authorization=f"Bearer {server.token}").decode()
    return float(re.search(r"^gazehdr_gaze_samples_total (\S+)$", text, re.M)[1])


async def first_frame(url: str, token: str) -> tuple[dict, FrameHeader, np.ndarray]:
    """A viewer on another machine, as the container sees the host: the bearer token in the
    handshake. The session's hello and its first frame."""
    headers = {"Authorization": f"Bearer {token}"}
    async with websockets.connect(url, additional_headers=headers, max_size=None) as ws:
        hello = None
        while True:
            message = await ws.recv()
            if isinstance(message, str):
                hello = hello or json.loads(message)
                continue
            header, v = decode_frame(message)
            return hello, header, v


async def refusal(url: str) -> tuple[int, str]:
    """The close code and reason a viewer without the token gets."""
    async with websockets.connect(url) as ws:
        try:
            await ws.recv()
        except websockets.ConnectionClosed as e:
            return e.rcvd.code, e.rcvd.reason
    raise AssertionError("a viewer without the token was let in")


@pytest.mark.docker
@pytest.mark.timeout(DOCKER_TIMEOUT)
def test_server_container_serves_frames_over_ws_view(server_container: Container) -> None:
    c = server_container
    assert http_json(c.url + "/api/health")["status"] == "ok"
    # The image's own HEALTHCHECK, now rather than after its 30 s interval.
    check = json.loads(docker("inspect", "-f", "{{json .Config.Healthcheck.Test}}", c.name).stdout)
    assert check[0] == "CMD"
    docker("exec", c.name, *check[1:])
    assert docker("exec", c.name, "id", "-u").stdout.strip() == "10001"
    # Package data the context must carry (.dockerignore): kernels, viewer, Fig. 7's EXRs, docs.
    data = docker("exec", c.name, "python", "-c", LIST_PACKAGE_DATA).stdout.split()
    assert {"index.html", "courtyard.exr", "studio.exr", "server.md"} <= set(data), data
    assert any(name.endswith(".cl") for name in data), data

    ws_url = c.url.replace("http://", "ws://") + "/ws/view"
    hello, header, v = asyncio.run(asyncio.wait_for(first_frame(ws_url, c.token), 120))
    assert hello and hello["type"] == "hello", hello
    assert header.frame == 0 and header.width > 0 and header.height > 0, header
    assert v.shape == (header.height, header.width, 3)
    assert 0.0 <= v.min() and v.max() <= 1.0 and v.std() > 0.01, "a blank or broken frame"
    # From the host the viewer is no loopback client of the container: no token, no frames.
    code, reason = asyncio.run(asyncio.wait_for(refusal(ws_url), 30))
    assert code == 4401, (code, reason)


@pytest.mark.docker
@pytest.mark.timeout(DOCKER_TIMEOUT)
def test_daemon_container_streams_gaze_to_the_server_container(
    base_image: str, server_container: Container
) -> None:
    """The compose file's pairing: the daemon reaches the server as ws://server:8000 on a
    network of their own (a synthetic scan path stands in for the tracker), records into its
    volume, and stops cleanly on SIGTERM."""
    build(DAEMON, DAEMON_TAG, base_image)
    network, name = f"gazehdr-test-{os.getpid()}", f"gazehdr-test-daemon-{os.getpid()}"
    server = server_container
    docker("network", "create", network)
    try:
        docker("network", "connect", "--alias", "server", network, server.name)
        # The token from the environment, as docker/README.md runs it (not on a command line).
        options = ["-d", "--name", name, "--network", network, "-e", "GAZEHDR_TOKEN"]
        command = ["--source", "synthetic", "--server", "ws://server:8000"]
        docker(
            "run", *options, DAEMON_TAG, *command, env={**os.environ, "GAZEHDR_TOKEN": server.token}
        )
        poll(lambda: gaze_samples(server) > 0, "gaze samples at the server", timeout=60)
        assert http_json(server.url + "/api/health")["trackers"] == 1
        docker("stop", name, timeout=30)
        assert docker("inspect", "-f", "{{.State.ExitCode}}", name).stdout.strip() == "0"
        logs = docker("logs", name)
        text = logs.stdout + logs.stderr
        delivered = re.search(r"delivered (\d+) samples", text)
        assert delivered and int(delivered[1]) > 0, text
        assert "recording to /data/recordings/gaze-" in text, text
    finally:
        docker("rm", "-f", "-v", name, check=False)
        docker("network", "disconnect", "-f", network, server.name, check=False)
        docker("network", "rm", network, check=False)
