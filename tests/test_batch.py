"""Batch rendering (server/batch.py): many logs × models × presets as Dask tasks.

The pure part (jobs, their ids and folders, what is finished) is tested without Dask; the rest
on real LocalClusters of 2 worker processes, each rendering on its own OpenCL context, against
serial `gazehdr render` runs of the same jobs, byte for byte.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from waiting import wait_until

from gazehdr import batch
from gazehdr.cli import main
from gazehdr.render import RenderRequest, render_request

TINY = {"width": 64, "height": 36, "fps": 10.0, "seconds": 0.5, "backend": "opencl"}
TINY_ARGS = ["--size", "64x36", "--fps", "10", "--seconds", "0.5", "--quiet"]
MANIFEST = """
logs = ["logs/*.jsonl"]
models = ["jacobs", "ritschel+gaussian"]
presets = ["presets/low.json", "presets/high.json"]
[render]
size = "64x36"
fps = 10
seconds = 0.5
"""


def write_log(path: Path, scene: str, seed: int, points: list[tuple[float, float]]) -> Path:
    """A small session log: its scene, models, seed and a gaze sample every 0.1 s."""
    header = {
        "format": "gazehdr-session", "version": 2, "created": "2026-01-01T00:00:00.000+00:00",
        "tracker": {"name": "test", "gaze_source": "mouse", "frame": [64, 36], "seed": seed},
        "screen": {"screen_diagonal_m": 0.6, "screen_width_px": 1920, "screen_height_px": 1080,
                   "viewing_distance_m": 1.0},
        "clock": {"source": "simulation_ns", "offset_ns": None, "offset_uncertainty_ns": None},
    }  # fmt: skip
    lines = [header, {"k": "scene", "t": 0, "name": scene}]
    lines.append({"k": "model", "t": 0, "model": "jacobs+stochastic", "split": None})
    for i, (x, y) in enumerate(points):
        lines.append({"k": "s", "t": i * 100_000_000, "v": 1, "x": x, "y": y})
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(line) + "\n" for line in lines), encoding="utf-8")
    return path


def make_logs(root: Path, n: int = 2) -> list[Path]:
    scenes = ["lamp", "flash", "checker-night", "lamp"]
    return [
        write_log(root / f"s{i}.jsonl", scenes[i % 4], i, [(300.0 + 200 * i, 500.0), (1500, 600)])
        for i in range(n)
    ]


def outputs(folder: Path) -> dict[str, bytes]:
    """A folder's files, the job manifest aside."""
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.name != batch.MANIFEST_NAME}


def serial(job: batch.Job, out: Path) -> dict[str, bytes]:
    """The job rendered by the serial `gazehdr render` command line, one log in this process."""
    r = job.request
    assert r.seed is None  # the log's own, as the command line takes it
    args = ["render", "--gaze", r.gaze, "--out", str(out)]
    args += ["--size", f"{r.width}x{r.height}", "--fps", str(r.fps), "--seconds", str(r.seconds)]
    args += ["--afterimage", r.afterimage or "jacobs", "--acuity", r.acuity or "stochastic"]
    args += ["--params", r.params] if r.params else []
    assert main([*args, "--data-dir", str(r.data_dir), "--quiet"]) == 0
    return outputs(out)


@pytest.fixture(scope="module")
def cluster() -> Iterator[object]:
    """A 2-worker local cluster, as `gazehdr render` makes one, for tests that use
    `--scheduler ADDRESS`."""
    with batch.local_cluster(2) as c:
        yield c


# --- jobs, ids, folders and what is finished (no Dask) -----------------------------------------


def test_logs_models_and_presets_expand_to_jobs_with_stable_distinct_ids(tmp_path: Path) -> None:
    logs = make_logs(tmp_path / "logs", 3)
    presets = [str(tmp_path / "a.json"), str(tmp_path / "b.json")]
    base = RenderRequest(**TINY)
    jobs = batch.expand(logs, base, models=["jacobs", "mikamo+none"], presets=presets)
    assert len(jobs) == 12 and len({j.id for j in jobs}) == 12
    assert jobs[0].id.startswith("s0_jacobs+stochastic_a-") and jobs[-1].id.startswith(
        "s2_mikamo+none_b-"
    )
    assert [(j.request.afterimage, j.request.acuity) for j in jobs[:4]] == [
        ("jacobs", "stochastic"), ("jacobs", "stochastic"), ("mikamo", "none"), ("mikamo", "none"),
    ]  # fmt: skip
    again = batch.expand(logs, base, models=["jacobs", "mikamo+none"], presets=presets)
    assert [j.id for j in again] == [j.id for j in jobs]  # stable across runs
    # Anything that changes the frames changes the id; a log named twice is one job.
    other = batch.expand(logs[:1], RenderRequest(**(TINY | {"seed": 1})))
    assert other[0].id not in {j.id for j in batch.expand(logs[:1], base)}
    assert len(batch.expand([logs[0], logs[0]], base)) == 1
    with pytest.raises(ValueError, match="unknown afterimage"):
        batch.expand(logs, base, models=["nosuch"])


def test_logs_are_found_by_path_and_glob_once_each(tmp_path: Path) -> None:
    logs = make_logs(tmp_path / "logs", 3)
    found = batch.find_logs(["logs/s1.jsonl", "logs/*.jsonl"], tmp_path)
    assert found == [logs[1].resolve(), logs[0].resolve(), logs[2].resolve()]
    with pytest.raises(ValueError, match="matches no file"):
        batch.find_logs(["logs/*.csv"], tmp_path)
    with pytest.raises(ValueError, match="not found"):
        batch.find_logs(["logs/none.jsonl"], tmp_path)


def test_manifest_format_and_its_mistakes(tmp_path: Path) -> None:
    path = tmp_path / "batch.toml"
    path.write_text(MANIFEST, encoding="utf-8")
    b = batch.load_manifest(path)
    assert b.logs == ["logs/*.jsonl"] and b.models == ["jacobs", "ritschel+gaussian"]
    assert batch.manifest_fields(b) == {"width": 64, "height": 36, "fps": 10, "seconds": 0.5}
    for text, message in [
        ('logs = ["a"]\nmodel = ["jacobs"]', "unknown keys"),
        ("models = ['jacobs']", "'logs' is missing"),
        ("logs = []", "non-empty list"),
        ('logs = ["a"]\n[render]\nfps = 1\nframes = 3', "render"),
        ("logs = [", "batch manifest"),
    ]:
        path.write_text(text, encoding="utf-8")
        with pytest.raises(ValueError, match=message):
            batch.load_manifest(path)


def test_a_job_is_finished_only_with_its_manifest_its_inputs_and_outputs(tmp_path: Path) -> None:
    (log,) = make_logs(tmp_path / "logs", 1)
    (job,) = batch.expand([log], RenderRequest(**(TINY | {"backend": "reference"})))
    out = tmp_path / "out"
    folder = out / job.id
    assert not batch.is_finished(job, out)
    # Frames without a manifest (a worker killed before the end): not finished.
    render_request(job.request, folder, progress=False)
    assert not batch.is_finished(job, out)
    batch.render_job(job, str(out))
    assert batch.is_finished(job, out)
    manifest = json.loads((folder / batch.MANIFEST_NAME).read_text())
    assert manifest["id"] == job.id and manifest["frames"] == 5
    assert manifest["inputs"] == {str(log.resolve()): batch._sha256(log)}
    assert sorted(manifest["outputs"]) == [f"frame_0000{i}.png" for i in range(5)]
    assert not list(folder.glob(".*"))  # no temporary file left
    # Another job does not take this folder's manifest for its own.
    (other,) = batch.expand([log], RenderRequest(**(TINY | {"backend": "reference", "seed": 9})))
    (out / other.id).symlink_to(folder)
    assert not batch.is_finished(other, out)
    # A frame cut short, or a log changed since: not finished.
    frame = folder / "frame_00002.png"
    data = frame.read_bytes()
    frame.write_bytes(data[:-1])
    assert not batch.is_finished(job, out)
    frame.write_bytes(data)
    assert batch.is_finished(job, out)
    log.write_text(log.read_text() + '{"k":"s","t":400000000,"v":1,"x":5.0,"y":5.0}\n')
    assert not batch.is_finished(job, out)
    # A manifest that was being written (cut short) is not one.
    batch.render_job(job, str(out))
    text = (folder / batch.MANIFEST_NAME).read_text()
    (folder / batch.MANIFEST_NAME).write_text(text[: len(text) // 2])
    assert not batch.is_finished(job, out)


# --- on Dask ----------------------------------------------------------------------------------


def _batch_dir(tmp_path: Path) -> Path:
    """Two logs, two models, two presets: 8 jobs, described by tmp_path/batch.toml."""
    make_logs(tmp_path / "logs", 2)
    (tmp_path / "presets").mkdir()
    (tmp_path / "presets/low.json").write_text('{"gamma": 0.6}')
    (tmp_path / "presets/high.json").write_text('{"j1": 0.001, "gamma": 0.9}')
    (tmp_path / "batch.toml").write_text(MANIFEST, encoding="utf-8")
    return tmp_path / "batch.toml"


def _jobs(manifest: Path, data_dir: Path) -> list[batch.Job]:
    b = batch.load_manifest(manifest)
    request = RenderRequest(**batch.manifest_fields(b), data_dir=str(data_dir))
    presets = [str(b.base / p) for p in b.presets]
    return batch.expand(batch.find_logs(b.logs, b.base), request, models=b.models, presets=presets)


def test_eight_jobs_on_two_workers_are_the_serial_renders_bytes(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    manifest = _batch_dir(tmp_path)
    data = ["--data-dir", str(tmp_path / "data")]
    jobs = _jobs(manifest, tmp_path / "data")
    assert len(jobs) == 8
    started = time.perf_counter()
    want = {job.id: serial(job, tmp_path / "serial" / job.id) for job in jobs}
    serial_s = time.perf_counter() - started
    started = time.perf_counter()
    args = ["render", "--batch", str(manifest), "--out", str(tmp_path / "out"), "--workers", "2"]
    assert main([*args, *data, "--quiet"]) == 0
    cluster_s = time.perf_counter() - started
    assert "8 jobs" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(want)
    for job in jobs:
        got = outputs(tmp_path / "out" / job.id)
        assert len(got) == 5 and got == want[job.id], job.id
        assert batch.is_finished(job, tmp_path / "out")
    assert len({b"".join(v.values()) for v in want.values()}) == 8  # the jobs differ
    with capsys.disabled():
        print(f"\n8 jobs at 64x36, 5 frames: serial {serial_s:.1f} s, 2 workers {cluster_s:.1f} s")


def test_a_failed_job_is_reported_and_the_others_finish(
    tmp_path: Path, cluster, capsys: pytest.CaptureFixture
) -> None:
    make_logs(tmp_path / "logs", 3)
    (tmp_path / "logs/broken.jsonl").write_text("this is not a session log\n")
    args = ["render", "--logs", str(tmp_path / "logs/*.jsonl"), "--out", str(tmp_path / "out")]
    args += ["--scheduler", cluster.scheduler_address, *TINY_ARGS]
    assert main(args) == 1
    captured = capsys.readouterr()
    assert "4 jobs" in captured.out and "3 rendered" in captured.out and "1 failed" in captured.out
    (line,) = [s for s in captured.err.splitlines() if "failed" in s]
    assert line.startswith("gazehdr: job broken-") and "header is not JSON" in line
    folders = sorted(p.name for p in (tmp_path / "out").iterdir() if (p / "manifest.json").exists())
    assert [f.split("-")[0] for f in folders] == ["s0", "s1", "s2"]


def test_a_rerun_skips_finished_jobs(tmp_path: Path, cluster, capsys) -> None:
    logs = make_logs(tmp_path / "logs", 3)
    out = tmp_path / "out"
    args = ["render", "--logs", *map(str, logs), "--out", str(out), *TINY_ARGS]
    args += ["--scheduler", cluster.scheduler_address]
    assert main(args) == 0
    files = sorted(out.glob("*/*"))
    assert len(files) == 3 * 6
    stamps = {p: p.stat().st_mtime_ns for p in files}
    capsys.readouterr()
    assert main(args) == 0
    assert "0 rendered, 3 finished before" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in sorted(out.glob("*/*"))} == stamps
    # A job whose manifest is gone is rendered again, and only it.
    (gone,) = [p for p in files if p.name == "manifest.json" and "s1" in p.parent.name]
    gone.unlink()
    assert main(args) == 0
    assert "1 rendered, 2 finished before" in capsys.readouterr().out
    changed = {p for p in sorted(out.glob("*/*")) if p.stat().st_mtime_ns != stamps.get(p)}
    assert changed and {p.parent.name for p in changed} == {gone.parent.name}


def test_a_killed_worker_loses_only_its_job_which_a_rerun_completes(
    tmp_path: Path, cluster
) -> None:
    """The job on a named pipe holds its worker until the test kills it (by pid, once the
    worker has opened the pipe): nothing here waits on time."""
    from dask.distributed import Client

    logs = make_logs(tmp_path / "logs", 3)
    held = tmp_path / "logs/held.jsonl"
    os.mkfifo(held)
    jobs = batch.expand([*logs, held], RenderRequest(**TINY))
    (held_job,) = [j for j in jobs if j.id.startswith("held-")]
    out = tmp_path / "out"
    results: list[batch.BatchResult] = []
    run = threading.Thread(
        target=lambda: results.append(
            batch.run_batch(jobs, out, scheduler=cluster.scheduler_address, progress=False)
        )
    )
    run.start()
    opened: list[int] = []
    opener = threading.Thread(target=lambda: opened.append(os.open(held, os.O_WRONLY)))
    opener.start()  # returns once the job's worker has opened the pipe to read the log
    opener.join(timeout=60)
    assert opened, "the held job never started"
    with Client(cluster.scheduler_address) as client:
        (worker,) = [w for w, keys in client.processing().items() if any(
            held_job.id in str(k) for k in keys
        )]  # fmt: skip
        pid = client.run(os.getpid, workers=[worker])[worker]
    assert pid != os.getpid()
    os.kill(pid, signal.SIGKILL)
    os.close(opened[0])
    run.join(timeout=120)
    (result,) = results
    assert list(result.failed) == [held_job.id]
    assert "worker died" in result.failed[held_job.id]
    assert sorted(result.rendered) == sorted(j.id for j in jobs if j is not held_job)
    assert not (out / held_job.id / batch.MANIFEST_NAME).exists()
    # The log arrives: a rerun renders that job, and only it, to the serial render's bytes.
    held.unlink()
    write_log(held, "flash", 7, [(900.0, 400.0)])
    wait_until(lambda: len(cluster.scheduler.workers) == 2, "the restarted worker")
    again = batch.run_batch(jobs, out, scheduler=cluster.scheduler_address, progress=False)
    assert again.rendered == [held_job.id] and not again.failed
    assert sorted(again.skipped) == sorted(result.rendered)
    assert outputs(out / held_job.id) == serial(held_job, tmp_path / "serial")


def test_without_the_batch_extra_render_logs_names_the_extra(tmp_path: Path) -> None:
    """`render --logs` where Dask is not installed: one line naming the extra to install and
    the usage error's status, not a traceback. Guards the check before the batch module runs
    (a raw ModuleNotFoundError came out of a worker's setup)."""
    import subprocess
    import sys

    blocked = (
        "import sys; sys.modules['dask'] = None; from gazehdr.cli import main; "
        f"sys.exit(main(['render', '--logs', 'x.jsonl', '--out', {str(tmp_path)!r}]))"
    )
    run = subprocess.run([sys.executable, "-c", blocked], capture_output=True, text=True)
    assert run.returncode == 2, run.stderr
    assert "pip install 'gazehdr[batch]'" in run.stderr and "Traceback" not in run.stderr
