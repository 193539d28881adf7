"""The harness's process inside the guest: it owns the virtual devices (uhid) and runs commands.

Started by the guest's init (tests/hid_kernel/run.py writes the command), it connects to the
host's control socket (through QEMU's user network, 10.0.2.2) and answers one JSON request per
line with one JSON reply per line, in order. It imports the standard library only, so that it
is ready in a second even under software emulation; the gazehdr commands it is asked to run
(`gazehdr devices`, `gazehdr daemon`) are processes of their own, as a user would start them.

Requests (`op` and its arguments; every reply has `ok`, and `error` when not ok):

- `now`: the guest's monotonic clock (ns), for the host's clock-offset estimate;
- `plug`: make a device (`dev` names it) from `descriptor` (hex), `features` (report id →
  hex), `errors` (report id → errno), `silent` (report ids never answered), `vendor`,
  `product`, `name`; waits for its hidraw node (`hidraw` in the reply, null when the kernel
  refused the device) or for the kernel to say no;
- `unplug` / `replug`: UHID_DESTROY / UHID_CREATE2 again for `dev` (`unplug` with `close`:
  and forget it);
- `stream`: run a schedule of `steps` on `dev` (`Stream`: input reports, unplug, replug, each
  at its time after a start `lead_ns` from now); returns at once with the guest time it starts
  at; `stream_wait` returns when it is done, with the guest time each report was written
  (`written_ns`) and each unplug / replug happened (`actions`);
- `events`: the kernel's uhid events for `dev` so far (open, close, get_report, set_report...);
- `spawn`: start `argv` in the background as `name` (stdout and stderr to files); `stop`:
  send it `signal` and wait; `wait`: wait for it; both return its exit status and output;
- `run`: run `argv` to the end (`timeout` s), with its exit status and output;
- `dmesg`: the kernel's log since the last `dmesg`;
- `quit`: close every device and end (the init powers the guest off).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from uhid import Features, UhidDevice

#: How long `plug` waits for the kernel to bind the device and make its hidraw node.
PLUG_TIMEOUT_S = 20.0


class Stream:
    """A schedule run on a thread of its own: each step at `at_ns` after the start (`lead_ns`
    from now), an input report (`report`, hex), or `unplug` (UHID_DESTROY) or `replug`
    (UHID_CREATE2 again). The guest time each step happened is kept."""

    def __init__(self, dev: UhidDevice, args: dict[str, Any]) -> None:
        self.dev = dev
        self.steps = [(int(s["at_ns"]), s.get("report"), s.get("action")) for s in args["steps"]]
        self.start_ns = time.monotonic_ns() + int(args.get("lead_ns", 200_000_000))
        self.written_ns: list[int] = []  # per input report, in order
        self.actions: list[tuple[str, int]] = []
        self.error: str | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _sleep_until(self, t_ns: int) -> None:
        while (left := t_ns - time.monotonic_ns()) > 0:
            time.sleep(min(left / 1e9, 0.05))

    def _run(self) -> None:
        try:
            for at, report, action in self.steps:
                self._sleep_until(self.start_ns + at)
                if action == "unplug":
                    self.dev.destroy()
                elif action == "replug":
                    self.dev.create()
                if action:
                    self.actions.append((action, time.monotonic_ns()))
                if report is not None:
                    self.written_ns.append(self.dev.input(bytes.fromhex(report)))
        except OSError as e:  # a report the kernel refused (too long, device gone)
            self.error = f"step {len(self.written_ns) + len(self.actions)}: {e}"

    def result(self) -> dict[str, Any]:
        self.thread.join()
        return {
            "start_ns": self.start_ns,
            "written_ns": self.written_ns,
            "actions": self.actions,
            "error": self.error,
        }


class Agent:
    def __init__(self) -> None:
        self.devices: dict[str, UhidDevice] = {}
        self.streams: dict[str, Stream] = {}
        self.procs: dict[str, tuple[subprocess.Popen[bytes], Path, Path]] = {}
        self.kmsg = os.open("/dev/kmsg", os.O_RDONLY | os.O_NONBLOCK)
        self._kept: list[str] = []  # kernel log lines read for a check, not yet returned

    # --- devices ---

    def op_plug(self, a: dict[str, Any]) -> dict[str, Any]:
        features = Features(
            reports={int(k): bytes.fromhex(v) for k, v in a.get("features", {}).items()},
            errors={int(k): int(v) for k, v in a.get("errors", {}).items()},
            silent={int(k) for k in a.get("silent", [])},
        )
        dev = UhidDevice(
            bytes.fromhex(a["descriptor"]),
            name=a.get("name", a["dev"]),
            vendor=int(a.get("vendor", 0x2104)),
            product=int(a.get("product", 0x0127)),
            uniq=a["dev"],
            features=features,
        )
        self.devices[a["dev"]] = dev
        dev.create()
        return {"hidraw": self._hidraw(a["dev"])}

    def _hidraw(self, uniq: str, timeout_s: float = PLUG_TIMEOUT_S) -> str | None:
        """The hidraw node of the HID device whose HID_UNIQ is `uniq`, once the kernel made it;
        None when the kernel bound no driver (it refused the descriptor) or made none in time."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for d in Path("/sys/bus/hid/devices").iterdir():
                try:
                    uevent = (d / "uevent").read_text()
                except OSError:
                    continue
                if f"HID_UNIQ={uniq}\n" not in uevent:
                    continue
                nodes = list((d / "hidraw").glob("hidraw*")) if (d / "hidraw").is_dir() else []
                if nodes and Path("/dev", nodes[0].name).exists():
                    return f"/dev/{nodes[0].name}"
                if not (d / "driver").exists() and self._probe_failed(d.name):
                    return None
            time.sleep(0.05)
        return None

    def _probe_failed(self, hid_name: str) -> bool:
        """Whether the kernel's log says it could not bind the device `hid_name`."""
        log = self._read_kmsg(keep=True)
        return any(hid_name in line and "failed" in line for line in log)

    def op_unplug(self, a: dict[str, Any]) -> dict[str, Any]:
        """UHID_DESTROY; with `close`, the device is forgotten too (its /dev/uhid closed)."""
        dev = self.devices[a["dev"]]
        dev.destroy()
        if a.get("close"):
            dev.close()
            del self.devices[a["dev"]]
        return {"t_ns": time.monotonic_ns()}

    def op_replug(self, a: dict[str, Any]) -> dict[str, Any]:
        self.devices[a["dev"]].create()
        return {"t_ns": time.monotonic_ns(), "hidraw": self._hidraw(a["dev"])}

    def op_events(self, a: dict[str, Any]) -> dict[str, Any]:
        return {"events": [e.as_dict() for e in self.devices[a["dev"]].events]}

    def op_stream(self, a: dict[str, Any]) -> dict[str, Any]:
        stream = self.streams[a["dev"]] = Stream(self.devices[a["dev"]], a)
        return {"start_ns": stream.start_ns}

    def op_stream_wait(self, a: dict[str, Any]) -> dict[str, Any]:
        return self.streams.pop(a["dev"]).result()

    # --- processes ---

    def op_run(self, a: dict[str, Any]) -> dict[str, Any]:
        t0 = time.monotonic()
        done = subprocess.run(
            a["argv"],
            capture_output=True,
            timeout=float(a.get("timeout", 300)),
            env=self._env(a),
            check=False,
        )
        return {
            "rc": done.returncode,
            "stdout": done.stdout.decode(errors="replace"),
            "stderr": done.stderr.decode(errors="replace"),
            "seconds": time.monotonic() - t0,
        }

    def op_spawn(self, a: dict[str, Any]) -> dict[str, Any]:
        out, err = Path(f"/tmp/{a['name']}.out"), Path(f"/tmp/{a['name']}.err")
        with out.open("wb") as o, err.open("wb") as e:
            proc = subprocess.Popen(a["argv"], stdout=o, stderr=e, env=self._env(a))
        self.procs[a["name"]] = (proc, out, err)
        return {"pid": proc.pid}

    def op_stop(self, a: dict[str, Any]) -> dict[str, Any]:
        proc = self.procs[a["name"]][0]
        if proc.poll() is None:
            proc.send_signal(int(a.get("signal", signal.SIGTERM)))
        return self.op_wait(a)

    def op_wait(self, a: dict[str, Any]) -> dict[str, Any]:
        proc, out, err = self.procs[a["name"]]
        try:
            rc = proc.wait(timeout=float(a.get("timeout", 60)))
        except subprocess.TimeoutExpired:
            proc.kill()
            rc = None  # it hung: killed
            proc.wait()
        return {
            "rc": rc,
            "stdout": out.read_text(errors="replace"),
            "stderr": err.read_text(errors="replace"),
        }

    def op_poll(self, a: dict[str, Any]) -> dict[str, Any]:
        proc, _, err = self.procs[a["name"]]
        return {"rc": proc.poll(), "stderr": err.read_text(errors="replace")}

    def op_read(self, a: dict[str, Any]) -> dict[str, Any]:
        return {"text": Path(a["path"]).read_text(errors="replace")}

    @staticmethod
    def _env(a: dict[str, Any]) -> dict[str, str]:
        return {**os.environ, **a.get("env", {})}

    # --- the rest ---

    def op_now(self, a: dict[str, Any]) -> dict[str, Any]:
        return {"t_ns": time.monotonic_ns()}

    def op_dmesg(self, a: dict[str, Any]) -> dict[str, Any]:
        return {"lines": self._read_kmsg()}

    def _read_kmsg(self, keep: bool = False) -> list[str]:
        """New kernel log lines (the text after each record's header), oldest first."""
        lines = self._kept
        while True:
            try:
                record = os.read(self.kmsg, 8192).decode(errors="replace")
            except BlockingIOError:
                break
            except OSError as e:  # EPIPE: records were overwritten before we read them
                if e.errno != errno.EPIPE:
                    raise
                continue
            lines.append(record.split(";", 1)[-1].split("\n", 1)[0])
        self._kept = lines if keep else []
        return lines

    def close(self) -> None:
        for proc, _, _ in self.procs.values():
            if proc.poll() is None:
                proc.kill()
        for dev in self.devices.values():
            with contextlib.suppress(OSError):
                dev.close()


def serve(host: str, port: int) -> None:
    agent = Agent()
    for _ in range(100):  # the network may come up a moment after us
        try:
            sock = socket.create_connection((host, port), timeout=5)
            break
        except OSError:
            time.sleep(0.1)
    else:
        raise SystemExit(f"agent: cannot reach the host at {host}:{port}")
    sock.settimeout(None)
    reader, writer = sock.makefile("r"), sock.makefile("w")
    writer.write(json.dumps({"ok": True, "hello": os.uname().release}) + "\n")
    writer.flush()
    try:
        for line in reader:
            request = json.loads(line)
            op = request.pop("op")
            if op == "quit":
                writer.write(json.dumps({"ok": True}) + "\n")
                writer.flush()
                break
            try:
                reply = {"ok": True, **getattr(agent, f"op_{op}")(request)}
            except Exception as e:  # reported to the host, which fails the test with it
                reply = {"ok": False, "error": f"{type(e).__name__}: {e}"}
            writer.write(json.dumps(reply) + "\n")
            writer.flush()
    finally:
        agent.close()


if __name__ == "__main__":
    host, _, port = sys.argv[1].rpartition(":")
    serve(host, int(port))
