"""Writes the seeds of tests/fuzz_corpus/ (run from the repository root with the test extra:
`.venv/bin/python tests/fuzz_corpus/make_seeds.py`). Reproducers of crashes found are added by
hand beside them (`repro-*`), never by this script; it only replaces its own `seed-*` files."""

from __future__ import annotations

import dataclasses
import gzip
import json
import sys
from pathlib import Path

import numpy as np
import OpenEXR

HERE = Path(__file__).parent
DATA = HERE.parent / "data" / "formats"
sys.path.insert(0, str(HERE.parent))  # tests/ for hid_device's descriptors


def put(target: str, name: str, data: bytes) -> None:
    folder = HERE / target
    folder.mkdir(exist_ok=True)
    (folder / f"seed-{name}").write_bytes(data)


def exr_seeds() -> None:
    import tempfile

    import cv2

    rgb = np.linspace(0.01, 300, 4 * 3 * 3, dtype=np.float32).reshape(3, 4, 3)
    tmp = Path(tempfile.mkdtemp())
    compressions = ["NO", "RLE", "ZIPS", "ZIP", "PIZ", "PXR24", "B44", "DWAA"]
    files: dict[str, tuple[dict, dict]] = {}
    for i, c in enumerate(compressions):
        header = {
            "compression": getattr(OpenEXR, f"{c}_COMPRESSION"),
            "type": OpenEXR.scanlineimage,
        }
        pixels = rgb.astype(np.float16 if i % 2 else np.float32)
        files[f"rgb-{c.lower()}.exr"] = (header, {"RGB": pixels})
    plain = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    files["y.exr"] = (plain, {"Y": rgb[..., 1].copy()})
    files["layers.exr"] = (
        {**plain, "whiteLuminance": 100.0},
        {"diffuse.R": rgb[..., 0].copy(), "diffuse.G": rgb[..., 1].copy(),
         "diffuse.B": rgb[..., 2].copy(), "A": rgb[..., 0].copy()},
    )  # fmt: skip
    tiles = OpenEXR.TileDescription()
    tiles.xSize = tiles.ySize = 2
    files["tiled.exr"] = (
        {"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.tiledimage, "tiles": tiles},
        {"RGB": rgb.astype(np.float16)},
    )
    for name, (header, channels) in files.items():
        OpenEXR.File(header, channels).write(str(tmp / name))
        put("exr", name, (tmp / name).read_bytes())
    cv2.imwrite(str(tmp / "a.hdr"), rgb[..., ::-1])  # Radiance RGBE (OpenCV writes BGR)
    put("exr", "rgbe.hdr", (tmp / "a.hdr").read_bytes())
    pfm = b"PF\n4 3\n-1.0\n" + np.ascontiguousarray(rgb[::-1], dtype="<f4").tobytes()
    put("exr", "a.pfm", pfm)


def hid_seeds() -> None:
    from hid_device import microsoft_style_descriptor, tracker_descriptor, tracking_report

    def pack(descriptor: bytes, reports: list[bytes]) -> bytes:
        body = b"".join(bytes([len(r)]) + r for r in reports)
        return len(descriptor).to_bytes(2, "little") + descriptor + body

    report = bytes(tracking_report(4_000_000_123, (-31, 12, 654), (263_520, -1_500)))
    features = [bytes([0x12, 0xE8, 0x03, 0, 0, 0xD0, 0x07, 0, 0, 0]), bytes([0x13, 60, 0, 0, 0])]
    put("hid", "tracker", pack(tracker_descriptor(), [report, *features]))
    ms = microsoft_style_descriptor()
    put("hid", "microsoft", pack(ms, [bytes([1, *range(40)])]))


def import_seeds() -> None:
    from gazehdr.drivers.formats.eyelink import read_eyelink_asc
    from gazehdr.drivers.sessionlog import (
        ModelChange,
        Note,
        ParamsChange,
        SceneChange,
        write_session_log,
    )

    for name in ("eyelink_mono.asc", "eyelink_bino.asc", "eyelink_2000hz.asc"):
        put("eyelink", name, (DATA / name).read_bytes())
    for name in ("tobii_pygaze.tsv", "tobii_ptc.tsv"):
        put("tobii", name, (DATA / name).read_bytes())
    put("pupil", "gaze_positions.csv", (DATA / "gaze_positions.csv").read_bytes())
    put("xdf", "minimal.xdf", (DATA / "xdf" / "minimal.xdf").read_bytes())
    beh = DATA / "bids" / "sub-01" / "beh"
    for eye in ("eye1", "eye2"):
        stem = f"sub-01_task-freeview_recording-{eye}_physio"
        sidecar = json.loads((beh / f"{stem}.json").read_text())
        top = json.loads((DATA / "bids" / "task-freeview_physio.json").read_text())
        parts = [
            json.dumps({**top, **sidecar}).encode(),
            gzip.decompress((beh / f"{stem}.tsv.gz").read_bytes()),
            gzip.decompress((beh / f"{stem}events.tsv.gz").read_bytes()),
        ]
        put("bids", eye, b"\n\x00--\x00\n".join(parts))
        if eye == "eye1":
            # the screen in the physio sidecar (where drafts put it; the target writes no
            # events sidecar), so that its values are fuzzed too
            events = json.loads((DATA / "bids" / "task-freeview_events.json").read_text())
            screen = {"StimulusPresentation": events["StimulusPresentation"]}
            with_screen = [json.dumps({**top, **sidecar, **screen}).encode(), *parts[1:]]
            put("bids", f"{eye}-screen", b"\n\x00--\x00\n".join(with_screen))
            # the physio part as gzip bytes, so that the gzip layer is fuzzed too
            parts[1] = gzip.compress(parts[1], mtime=0)
            put("bids", f"{eye}-gz", b"\n\x00--\x00\n".join(parts))
    log = read_eyelink_asc(DATA / "eyelink_bino.asc")
    # a fixed creation time, so that the seed is the same bytes at each run of this script
    log.header = dataclasses.replace(log.header, created="2026-11-24T21:33:18.134+00:00")
    t = log.samples[0].t_ns
    for record in (SceneChange(t, "lamp"), ParamsChange(t, {"tau": 0.2}),
                   ModelChange(t, "ritschel", "jacobs"), Note(t, "seed")):  # fmt: skip
        log.add(record)
    path = HERE / "log.jsonl"
    write_session_log(path, log, overwrite=True)
    put("sessionlog", "bino.jsonl", path.read_bytes())
    path.unlink()


def message_seeds() -> None:
    control = [
        {"type": "viewport", "width": 640, "height": 360},
        {"type": "gaze", "x": 0.5, "y": 0.25, "seq": 7},
        {"type": "eyes", "open": False},
        {"type": "scene", "name": "lamp"},
        {"type": "gaze_source", "name": "mouse"},
        {"type": "model", "afterimage": "ritschel", "split": {"acuity": "none"}},
        {"type": "params", "values": {"tau": 0.1}},
        {"type": "scene_settings", "scale": 2.5, "kind": "mean", "layer": None},
        {"type": "scene_maps", "send": True},
        {"type": "reset"},
        {"type": "ack", "frame": 12},
        {"type": "encoding", "name": "av1"},
        {"type": "keyframe"},
    ]
    for m in control:
        put("control", m["type"], json.dumps(m).encode())
    wire = [
        {"type": "hello", "protocol": 1, "tracker": "hid", "screen": {"screen_width_px": 1920}},
        {"type": "samples", "samples": [{"t": 1, "x": 0.5, "y": 0.5}, {"t": 2, "valid": False}]},
        {"type": "event", "kind": "fixation_start", "id": 1, "t": 5, "x": 0.1, "y": 0.2},
        {"type": "event", "kind": "blink_start", "id": 2, "t": 9},
        {"type": "echo", "t0": 3},
        {"type": "welcome", "protocol": 1},
        {"type": "echo", "t0": 3, "server_ns": 4},
        {"type": "error", "message": "no"},
    ]
    for i, m in enumerate(wire):
        put("wire", f"{i}-{m['type']}", json.dumps(m).encode())


if __name__ == "__main__":
    for stale in HERE.glob("*/seed-*"):
        stale.unlink()
    exr_seeds()
    hid_seeds()
    import_seeds()
    message_seeds()
