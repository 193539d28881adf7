"""Batch rendering: many session logs (× models × parameter presets) as Dask tasks.

`gazehdr render --logs LOG... | --batch MANIFEST.toml --out DIR` (docs/cli.md, "Batch
rendering"). The pure part expands the logs, models and presets into `Job`s, each with a stable
id (its name and a digest of everything that decides its frames) and its own folder under DIR,
and tells from a folder's `manifest.json` whether its job is finished: the manifest is written
last and atomically (a temporary file renamed over it), so a folder that a killed worker left
half-written is not. The Dask part sends the unfinished jobs to a cluster, a `LocalCluster` of
one-thread worker processes by default or an existing one's scheduler, and each task calls the
serial command's own `gazehdr.render.render_request` in its worker process, which holds its
own OpenCL context (`gazehdr.sim.opencl` keeps one per process): the frames are the bytes a
serial render with the same seed writes.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import glob
import hashlib
import json
import os
import re
import socket
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gazehdr import atomic
from gazehdr.drivers.cli_args import screen_size_arg
from gazehdr.drivers.errors import InputError
from gazehdr.render import RenderRequest, render_request
from gazehdr.sim.models import Models

#: The file in each job's folder that says what made it; its presence marks the job finished.
MANIFEST_NAME = "manifest.json"
MANIFEST_FORMAT = "gazehdr-batch-job"
#: Keys of a batch manifest's [render] table: the command line's render options.
RENDER_KEYS = (
    "scene", "seconds", "fps", "size", "seed", "backend", "afterimage", "acuity", "params",
    "data_dir", "scale", "exr", "video",
)  # fmt: skip
_PATH_KEYS = ("params", "data_dir")


@dataclass(frozen=True)
class Job:
    """One render: `request` into the folder `id` under the batch's output directory."""

    id: str
    request: RenderRequest


@dataclass(frozen=True)
class Batch:
    """What a batch manifest asks for; paths in it are relative to its folder `base`."""

    logs: list[str]
    models: list[str | None] = field(default_factory=lambda: [None])
    presets: list[str | None] = field(default_factory=lambda: [None])
    render: dict[str, Any] = field(default_factory=dict)
    base: Path = Path(".")


def _strings(value: Any, key: str, source: str) -> list[str]:
    value = [value] if isinstance(value, str) else value
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise InputError(f"{source}: '{key}' must be a string or a non-empty list of strings")
    return value


def load_manifest(path: str | Path) -> Batch:
    """A batch manifest (TOML): `logs`, optional `models` and `presets`, optional [render]."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10: the batch extra brings tomli
        import tomli as tomllib

    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"batch manifest {path}: {e}") from None
    unknown = set(data) - {"logs", "models", "presets", "render"}
    if unknown:
        raise InputError(f"batch manifest {path}: unknown keys {sorted(unknown)}")
    if "logs" not in data:
        raise InputError(f"batch manifest {path}: 'logs' is missing")
    render = data.get("render", {})
    if not isinstance(render, dict) or set(render) - set(RENDER_KEYS):
        bad = sorted(set(render) - set(RENDER_KEYS)) if isinstance(render, dict) else render
        raise InputError(f"batch manifest {path}: [render] takes {', '.join(RENDER_KEYS)}: {bad}")
    models = [None] if "models" not in data else _strings(data["models"], "models", str(path))
    presets = [None] if "presets" not in data else _strings(data["presets"], "presets", str(path))
    return Batch(
        _strings(data["logs"], "logs", str(path)), models, presets, render, path.parent.resolve()
    )


def manifest_fields(batch: Batch) -> dict[str, Any]:
    """The [render] table as `RenderRequest` fields, its paths resolved against the manifest."""
    fields = dict(batch.render)
    if "size" in fields:
        try:
            fields["width"], fields["height"] = screen_size_arg(str(fields.pop("size")))
        except argparse.ArgumentTypeError as e:
            raise InputError(f"batch manifest: size: {e}") from None
    for key in _PATH_KEYS:
        if isinstance(fields.get(key), str):
            fields[key] = str(batch.base / fields[key])
    scene = fields.get("scene")
    if isinstance(scene, str) and (batch.base / scene).exists():  # a file, not a built-in name
        fields["scene"] = str(batch.base / scene)
    return fields


def find_logs(patterns: Sequence[str], base: Path = Path(".")) -> list[Path]:
    """The files `patterns` name (paths or globs, relative to `base`), each once, in order."""
    found: dict[Path, None] = {}
    for pattern in patterns:
        full = str(base / os.path.expanduser(pattern))
        if glob.has_magic(full):
            matches = sorted(Path(p) for p in glob.glob(full, recursive=True))
            if not matches:
                raise InputError(f"{pattern!r} matches no file")
        elif not Path(full).exists():
            raise InputError(f"session log {pattern!r} not found")
        else:
            matches = [Path(full)]
        found |= dict.fromkeys(p.resolve() for p in matches)
    return list(found)


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.+=-]+", "-", text).strip("-.") or "x"


def request_dict(request: RenderRequest) -> dict[str, Any]:
    """`request` as JSON values, as a job's manifest holds it."""
    return json.loads(json.dumps(dataclasses.asdict(request)))


def job_id(request: RenderRequest, *names: str | None) -> str:
    """The log's name, the model and preset named for it, and a digest of the whole request:
    stable across runs, different for any difference that changes the frames."""
    text = json.dumps(request_dict(request), sort_keys=True, separators=(",", ":"))
    digest = hashlib.sha256(text.encode()).hexdigest()[:10]
    return "_".join(_slug(n) for n in (Path(request.gaze).stem, *names) if n) + "-" + digest


def expand(
    logs: Sequence[str | Path],
    request: RenderRequest,
    *,
    models: Sequence[str | None] = (None,),
    presets: Sequence[str | None] = (None,),
) -> list[Job]:
    """One job per log × model × preset, in that order; None keeps `request`'s (by default
    the log's own). A model is `AFTERIMAGE[+ACUITY]`; presets are paths."""
    jobs: dict[str, Job] = {}
    for log in logs:
        for model in models:
            for preset in presets:
                fields: dict[str, Any] = {"gaze": str(Path(log).resolve())}
                parsed = None if model is None else Models.parse(model)  # a wrong name: now
                if parsed is not None:
                    fields |= {"afterimage": parsed.afterimage, "acuity": parsed.acuity}
                if preset is not None:
                    fields["params"] = str(Path(preset).resolve())
                job = dataclasses.replace(request, **fields)
                stem = Path(preset).stem if preset is not None else None
                ident = job_id(job, parsed and str(parsed), stem)
                jobs.setdefault(ident, Job(ident, job))
    return list(jobs.values())


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def input_digests(request: RenderRequest) -> dict[str, str]:
    """sha256 of the files `request` reads (log, preset, scene file), by path."""
    paths = [request.gaze, request.params, request.scene]
    return {p: _sha256(Path(p)) for p in paths if p and Path(p).is_file()}


def is_finished(job: Job, out_root: str | Path) -> bool:
    """Whether `job`'s folder holds a manifest for this very job, its inputs unchanged since,
    and every output it lists at its size."""
    folder = Path(out_root) / job.id
    try:
        manifest = json.loads((folder / MANIFEST_NAME).read_text(encoding="utf-8"))
        if (
            manifest.get("format") != MANIFEST_FORMAT
            or manifest.get("id") != job.id
            or manifest.get("request") != request_dict(job.request)
            or manifest.get("inputs") != input_digests(job.request)
        ):
            return False
        outputs = manifest["outputs"]
        return bool(outputs) and all(
            (folder / name).stat().st_size == info["bytes"] for name, info in outputs.items()
        )
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return False


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("gazehdr")
    except PackageNotFoundError:
        return "unknown"


def render_job(job: Job, out_root: str) -> dict[str, Any]:
    """Render `job` into its folder, then write its manifest: the task each worker runs."""
    folder = Path(out_root) / job.id
    (folder / MANIFEST_NAME).unlink(missing_ok=True)  # unfinished from here until the end
    notes: list[str] = []
    summary = render_request(job.request, folder, progress=False, overwrite=True, note=notes.append)
    outputs = {
        p.name: {"bytes": p.stat().st_size, "sha256": _sha256(p)}
        for p in sorted(folder.iterdir())
        if p.is_file() and p.name != MANIFEST_NAME and not p.name.startswith(".")
    }
    manifest = {
        "format": MANIFEST_FORMAT,
        "version": 1,
        "id": job.id,
        "request": request_dict(job.request),
        "inputs": input_digests(job.request),
        "outputs": outputs,
        "frames": summary.frames,
        "wall_seconds": round(summary.wall_seconds, 3),
        "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "gazehdr": _version(),
        "notes": notes,
    }
    atomic.write_text(folder / MANIFEST_NAME, json.dumps(manifest, indent=1) + "\n")
    return {"id": job.id, "frames": summary.frames, "wall_seconds": summary.wall_seconds}


# --- Dask -------------------------------------------------------------------------------------


def local_cluster(workers: int | None = None) -> Any:
    """A LocalCluster of `workers` one-thread processes (default: one per core). Each worker
    is handed one job at a time, and a job whose worker dies fails at once instead of being
    tried on another (`gazehdr render` reports it; a rerun renders it again)."""
    import dask
    from dask.distributed import LocalCluster

    config = {
        "distributed.scheduler.allowed-failures": 0,
        "distributed.scheduler.worker-saturation": 1.0,
    }
    with dask.config.set(config):
        return LocalCluster(
            n_workers=workers or os.cpu_count() or 1,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
        )


@dataclass
class BatchResult:
    rendered: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    wall_seconds: float = 0.0


def _describe(job: Job, error: BaseException) -> str:
    from dask.distributed import KilledWorker

    if isinstance(error, KilledWorker):
        return "its worker died while rendering it (a rerun renders it again)"
    if isinstance(error, OSError) and error.strerror:
        return f"{error.filename}: {error.strerror}" if error.filename else error.strerror
    return str(error) if isinstance(error, ValueError) else f"{type(error).__name__}: {error}"


def run_batch(
    jobs: Sequence[Job],
    out_root: str | Path,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
    redo: bool = False,
) -> BatchResult:
    """Render the unfinished `jobs` (all with `redo`) as Dask tasks, on the cluster at
    `scheduler` or a `local_cluster(workers)`; one progress bar over all jobs."""
    from dask.distributed import Client, as_completed
    from tqdm import tqdm

    started = time.perf_counter()
    out_root = Path(out_root).resolve()
    out_root.mkdir(parents=True, exist_ok=True)
    result = BatchResult()
    result.skipped = [] if redo else [j.id for j in jobs if is_finished(j, out_root)]
    skipped = set(result.skipped)
    todo = [j for j in jobs if j.id not in skipped]
    bar = tqdm(total=len(jobs), initial=len(result.skipped), unit="job", disable=not progress)
    with bar, contextlib.ExitStack() as stack:
        if todo:
            if scheduler:
                client = stack.enter_context(Client(scheduler))
            else:
                cluster = stack.enter_context(local_cluster(min(workers or 1 << 30, len(todo))))
                client = stack.enter_context(Client(cluster))
            token = os.urandom(4).hex()
            futures = client.map(
                render_job, todo, out_root=str(out_root),
                key=[f"gazehdr-render-{j.id}-{token}" for j in todo], pure=False,
            )  # fmt: skip
            job_of = {f.key: j for f, j in zip(futures, todo, strict=True)}
            for future in as_completed(futures):
                job = job_of[future.key]
                if future.status == "finished":
                    result.rendered.append(job.id)
                else:
                    result.failed[job.id] = _describe(job, future.exception())
                    bar.set_postfix(failed=len(result.failed))
                bar.update(1)
                future.release()
    result.wall_seconds = time.perf_counter() - started
    return result


def main(args: Any, make_request: Callable[..., Any], *, parser_defaults: dict[str, Any]) -> int:
    """`gazehdr render --logs/--batch`: 0 when every job is finished, 1 when one failed."""
    if args.logs and args.batch:
        raise InputError("give the logs with --logs or with --batch, not both")
    if args.gaze != parser_defaults["gaze"]:
        raise InputError("--gaze names one log; batch rendering takes them with --logs/--batch")
    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers must be at least 1, got {args.workers}")
    if args.batch:
        batch = load_manifest(args.batch)
        given = {k for k, v in vars(args).items() if parser_defaults.get(k, v) != v}
        fields = {
            k: v for k, v in manifest_fields(batch).items()
            if k not in given and not (k in ("width", "height") and "size" in given)
        }  # fmt: skip
    else:
        batch, fields = Batch(args.logs), {}
    try:
        request = make_request(args, **fields)
    except TypeError as e:
        raise InputError(f"batch manifest: {e}") from None
    jobs = expand(
        find_logs(batch.logs, batch.base), request,
        models=batch.models,
        presets=[p if p is None else str(batch.base / p) for p in batch.presets],
    )  # fmt: skip
    result = run_batch(
        jobs, args.out, scheduler=args.scheduler, workers=args.workers,
        progress=not args.quiet, redo=args.overwrite,
    )  # fmt: skip
    print(
        f"{len(jobs)} jobs in {args.out}: {len(result.rendered)} rendered, "
        f"{len(result.skipped)} finished before, {len(result.failed)} failed "
        f"({result.wall_seconds:.1f} s)"
    )
    for ident, error in result.failed.items():
        print(f"gazehdr: job {ident} failed: {error}", file=sys.stderr)
    return 1 if result.failed else 0
