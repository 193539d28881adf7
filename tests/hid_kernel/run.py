"""The real-kernel HID harness: a QEMU guest with Debian's kernel, uhid and hidraw.

    .venv/bin/python tests/hid_kernel/run.py            # boot, list the trackers, print timings
    .venv/bin/python tests/hid_kernel/run.py --shell    # boot, then a shell in the guest
    .venv/bin/python -m pytest -m hid_kernel            # the tests (tests/test_hid_kernel.py)

Needs Debian's `qemu-system-x86`, `linux-image-amd64` and `busybox-static` (the kernel in
/boot and its modules in /lib/modules; `GAZEHDR_HID_KERNEL=/boot/vmlinuz-...` picks another).

The guest is the distribution kernel with a small initramfs: busybox (static) and the modules
that reach the host's files (virtio-pci, 9p) and its network (virtio-net), plus hid,
hid-generic and uhid. Its root file system is this machine's own `/`, shared read-only over
9p, with fresh tmpfs on /tmp and /run (a checkout or venv under them is bound through again):
so the guest runs this checkout and this venv's Python, hidapi, hid-tools and numpy as they
are, and the host's glibc, with nothing to install. A second 9p share (read-write) is the
run's own folder: the command the init runs, the logs and the paths to bind through.

The initramfs is built once and kept in a cache folder (`GAZEHDR_HID_KERNEL_CACHE`, else
`$XDG_CACHE_HOME/gazehdr/hid-kernel`, else `~/.cache/gazehdr/hid-kernel`), named by a hash of
everything it is made from (kernel release, the module files, busybox, the init script).

KVM is used where `/dev/kvm` opens and the CPU shows VMX/SVM; else QEMU's TCG emulates the CPU
(`GAZEHDR_HID_KERNEL_ACCEL=kvm|tcg` forces either), as a Nehalem (x86-64-v2, what numpy's
wheels need; the emulated CPU with fewer features is the faster one to emulate).

The guest's init runs tests/hid_kernel/agent.py, which connects back to the host over QEMU's
user network (the host is 10.0.2.2 there; `Guest.call` sends it requests) and owns the virtual
devices through /dev/uhid. A gazehdr server on the host is reached as ws://10.0.2.2:PORT.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
#: The host as the guest sees it (QEMU's user network).
HOST_FROM_GUEST = "10.0.2.2"
#: Modules the guest loads, in an order that satisfies modules.dep (their dependencies are
#: added before them): 9p and its virtio transport for the root file system, virtio-net for
#: the network, then the HID core, hid-generic (which makes the hidraw nodes: hidraw itself is
#: built into Debian's kernel) and uhid.
GUEST_MODULES = ("virtio_pci", "9p", "9pnet_virtio", "virtio_net", "hid", "hid_generic", "uhid")
#: Everything the guest's image is made from that is not a file: part of its cache key.
IMAGE_VERSION = "1"
BOOT_TIMEOUT_S = 300.0  # from QEMU's start to the agent's hello; TCG on a busy 2-core machine

INIT = r"""#!/bin/busybox sh
# The guest's init (PID 1): modules, the host's / over 9p, tmpfs, network, then the run's
# command in a chroot of the host's /; powers off when it ends.
/bin/busybox --install -s /bin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
for m in $(cat /modules.order); do insmod "/modules/$m.ko" || echo "init: insmod $m failed"; done
mount -t 9p -o trans=virtio,version=9p2000.L,ro,cache=loose,msize=524288 hostroot /root
mkdir /host && mount --bind /root /host  # the host's / without the tmpfs about to cover parts
for fs in proc sys dev; do mount --bind /$fs /root/$fs; done
mount -t tmpfs -o mode=1777 tmp /root/tmp
mount -t tmpfs run /root/run
mkdir -p /root/run/gazehdr
mount -t 9p -o trans=virtio,version=9p2000.L,msize=524288 rundir /root/run/gazehdr
# a checkout or venv under /tmp or /run (a clone in /tmp): shown again through the tmpfs
while read -r p; do mkdir -p "/root$p" && mount --bind "/host$p" "/root$p"; done \
  < /root/run/gazehdr/expose
ip link set lo up
ip link set eth0 up
ip addr add 10.0.2.15/24 dev eth0
ip route add default via 10.0.2.2
echo "init: up after $(cut -d' ' -f1 /proc/uptime) s"
chroot /root /bin/sh /run/gazehdr/run.sh > /root/run/gazehdr/agent.log 2>&1
echo "init: the run ended ($?) after $(cut -d' ' -f1 /proc/uptime) s"
sync
poweroff -f
"""


class HarnessError(RuntimeError):
    """The guest cannot be made or booted here (what is missing is in the message)."""


# --- what the guest is made of ----------------------------------------------------------------


@dataclass(frozen=True)
class Kernel:
    release: str
    image: Path
    modules: Path  # /lib/modules/RELEASE


def find_kernel() -> Kernel:
    """The kernel to boot: $GAZEHDR_HID_KERNEL, else the newest /boot/vmlinuz-* whose modules
    are installed."""
    given = os.environ.get("GAZEHDR_HID_KERNEL")
    images = [Path(given)] if given else sorted(Path("/boot").glob("vmlinuz-*"), reverse=True)
    for image in images:
        release = image.name.removeprefix("vmlinuz-")
        modules = Path("/lib/modules", release)
        if image.is_file() and (modules / "modules.dep").is_file():
            if not os.access(image, os.R_OK):  # Debian's are root's alone (mode 0600)
                raise HarnessError(
                    f"{image} is not readable: run as root, or copy it readable and set "
                    "GAZEHDR_HID_KERNEL to the copy"
                )
            return Kernel(release, image, modules)
    raise HarnessError(
        "no kernel with its modules: install Debian's linux-image-amd64 "
        "(/boot/vmlinuz-* and /lib/modules/*), or set GAZEHDR_HID_KERNEL"
    )


def find_qemu() -> str:
    qemu = shutil.which("qemu-system-x86_64")
    if qemu is None:
        raise HarnessError("qemu-system-x86_64 not found: install Debian's qemu-system-x86")
    return qemu


def _is_static(path: Path) -> bool:
    """Whether an ELF executable has no program interpreter (needs no libc to start)."""
    data = path.read_bytes()
    if data[:4] != b"\x7fELF" or data[4] != 2:  # 64-bit ELF only
        return False
    phoff, phentsize, phnum = (
        struct.unpack_from("<Q", data, 0x20)[0],
        *struct.unpack_from("<HH", data, 0x36),
    )
    return all(
        struct.unpack_from("<I", data, phoff + i * phentsize)[0] != 3  # PT_INTERP
        for i in range(phnum)
    )


def find_busybox() -> Path:
    for candidate in (os.environ.get("GAZEHDR_HID_BUSYBOX"), "/bin/busybox", "/usr/bin/busybox"):
        if candidate and Path(candidate).is_file() and _is_static(Path(candidate)):
            return Path(candidate)
    raise HarnessError("no static busybox: install Debian's busybox-static")


def module_order(kernel: Kernel, wanted: tuple[str, ...] = GUEST_MODULES) -> list[Path]:
    """The module files to insmod, dependencies first (modules.dep, whose names use - or _)."""
    deps: dict[str, list[str]] = {}
    for line in (kernel.modules / "modules.dep").read_text().splitlines():
        path, _, rest = line.partition(":")
        deps[path] = rest.split()
    by_name = {Path(p).name.split(".ko")[0].replace("-", "_"): p for p in deps}
    order: list[str] = []

    def add(path: str) -> None:
        if path in order:
            return
        for dep in deps[path]:
            add(dep)
        order.append(path)

    for name in wanted:
        path = by_name.get(name.replace("-", "_"))
        if path is None:  # built in (or missing: the guest's init reports what fails)
            continue
        add(path)
    for path in order:
        if not path.endswith(".ko"):
            raise HarnessError(f"{path}: compressed modules are not supported here")
    return [kernel.modules / p for p in order]


def _cpio_newc(entries: list[tuple[str, int, bytes]]) -> bytes:
    """An initramfs: a newc cpio archive of (path, mode, content) (directories: no content)."""
    out = bytearray()

    def pad() -> None:
        out.extend(b"\0" * (-len(out) % 4))

    for ino, (name, mode, data) in enumerate([*entries, ("TRAILER!!!", 0, b"")], start=1):
        fields = [ino, mode, 0, 0, 1, 0, len(data), 0, 0, 0, 0, len(name) + 1, 0]
        out += b"070701" + b"".join(b"%08X" % f for f in fields) + name.encode() + b"\0"
        pad()
        out += data
        pad()
    return bytes(out)


def cache_root() -> Path:
    given = os.environ.get("GAZEHDR_HID_KERNEL_CACHE")
    if given:
        return Path(given)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base, "gazehdr", "hid-kernel")


@dataclass(frozen=True)
class Image:
    kernel: Kernel
    initramfs: Path
    built: bool  # made by this call (else found in the cache)
    seconds: float  # to find or make it


def guest_image(kernel: Kernel | None = None) -> Image:
    """The guest's initramfs for `kernel`: from the cache, else made and kept there."""
    t0 = time.monotonic()
    kernel = kernel or find_kernel()
    busybox = find_busybox()
    modules = module_order(kernel)
    key = hashlib.sha256()
    for part in (IMAGE_VERSION, kernel.release, INIT, busybox.read_bytes()):
        key.update(part.encode() if isinstance(part, str) else part)
    for m in modules:
        key.update(m.name.encode() + hashlib.sha256(m.read_bytes()).digest())
    folder = cache_root() / f"{kernel.release}-{key.hexdigest()[:16]}"
    initramfs = folder / "initramfs.cpio"
    if initramfs.is_file():
        return Image(kernel, initramfs, False, time.monotonic() - t0)
    dirs = ["bin", "dev", "proc", "sys", "root", "modules"]
    names = [m.name.split(".ko")[0] for m in modules]
    entries: list[tuple[str, int, bytes]] = [(d, 0o40755, b"") for d in dirs]
    entries += [
        ("init", 0o100755, INIT.encode()),
        ("bin/busybox", 0o100755, busybox.read_bytes()),
        ("modules.order", 0o100644, "\n".join(names).encode() + b"\n"),
    ]
    entries += [(f"modules/{m.name}", 0o100644, m.read_bytes()) for m in modules]
    folder.mkdir(parents=True, exist_ok=True)
    tmp = folder / f"initramfs.cpio.{os.getpid()}"
    tmp.write_bytes(_cpio_newc(entries))
    tmp.replace(initramfs)  # whole or not at all, should two runs build at once
    (folder / "made-from.json").write_text(
        json.dumps(
            {
                "kernel": str(kernel.image),
                "busybox": str(busybox),
                "modules": [str(m) for m in modules],
                "image_version": IMAGE_VERSION,
            },
            indent=1,
        )
    )
    return Image(kernel, initramfs, True, time.monotonic() - t0)


def accelerator() -> tuple[str, str]:
    """(accel, cpu) for QEMU: KVM where it works, else TCG emulating an x86-64-v2 CPU."""
    forced = os.environ.get("GAZEHDR_HID_KERNEL_ACCEL")
    cpu = os.environ.get("GAZEHDR_HID_KERNEL_CPU")
    kvm = forced == "kvm"
    if forced is None:
        try:
            os.close(os.open("/dev/kvm", os.O_RDWR))
            flags = Path("/proc/cpuinfo").read_text()
            kvm = " vmx" in flags or " svm" in flags  # /dev/kvm without them hangs the boot
        except OSError:
            kvm = False
    if kvm:
        return "kvm", cpu or "host"
    return "tcg,thread=multi", cpu or "Nehalem"


# --- the guest --------------------------------------------------------------------------------


class GuestError(RuntimeError):
    """The agent in the guest answered a request with an error, or went away."""


class Guest:
    """A booted guest and its agent: `call(op, **args)` sends a request and returns the reply
    (agent.py lists them). Use as a context manager, or `boot()` then `close()`."""

    def __init__(self, *, memory_mb: int = 1024, cpus: int = 2) -> None:
        self.image = guest_image()
        self.memory_mb, self.cpus = memory_mb, cpus
        self.rundir = Path(tempfile.mkdtemp(prefix="gazehdr-hid-kernel-"))
        self.qemu: subprocess.Popen[bytes] | None = None
        self.sock: socket.socket | None = None
        self.boot_s: float | None = None
        self.release: str | None = None

    def __enter__(self) -> Guest:
        self.boot()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def command(self, port: int) -> list[str]:
        accel, cpu = accelerator()
        k = self.image.kernel
        append = "console=ttyS0 quiet loglevel=4 panic=-1 mitigations=off"
        return [
            find_qemu(),
            *("-accel", accel, "-cpu", cpu, "-m", str(self.memory_mb)),
            *("-smp", str(self.cpus), "-nodefaults", "-no-user-config", "-display", "none"),
            *("-no-reboot", "-bios", "qboot.rom"),
            *("-kernel", str(k.image), "-initrd", str(self.image.initramfs), "-append", append),
            *("-serial", f"file:{self.rundir / 'console.log'}"),
            "-fsdev",
            "local,id=hostroot,path=/,security_model=none,readonly=on,multidevs=remap",
            *("-device", "virtio-9p-pci,fsdev=hostroot,mount_tag=hostroot"),
            *("-fsdev", f"local,id=rundir,path={self.rundir},security_model=none"),
            *("-device", "virtio-9p-pci,fsdev=rundir,mount_tag=rundir"),
            *("-netdev", "user,id=net0", "-device", "virtio-net-pci,netdev=net0,romfile="),
        ]

    def boot(self, timeout_s: float = BOOT_TIMEOUT_S) -> None:
        t0 = time.monotonic()
        listener = socket.create_server(("127.0.0.1", 0))
        listener.settimeout(1.0)
        port = listener.getsockname()[1]
        venv_bin = Path(sys.executable).parent
        covered = [Path("/tmp"), Path("/run")]  # the guest's own tmpfs hide the host's
        needed = {HERE.parent.parent, Path(sys.prefix).resolve()}
        expose = sorted(str(p) for p in needed if any(p.is_relative_to(c) for c in covered))
        (self.rundir / "expose").write_text("".join(f"{p}\n" for p in expose))
        (self.rundir / "run.sh").write_text(
            "cd /tmp\n"
            f"exec env -i PATH={venv_bin}:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:"
            "/sbin:/bin HOME=/tmp LANG=C.UTF-8 PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 "
            f"{sys.executable} -S {HERE / 'agent.py'} {HOST_FROM_GUEST}:{port}\n"
        )
        with (self.rundir / "qemu.log").open("wb") as log:
            self.qemu = subprocess.Popen(
                self.command(port), stdin=subprocess.DEVNULL, stdout=log, stderr=log
            )
        try:
            while True:
                try:
                    self.sock, _ = listener.accept()
                    break
                except TimeoutError:
                    if self.qemu.poll() is not None:
                        raise GuestError(f"QEMU exited ({self.qemu.returncode})") from None
                    if time.monotonic() - t0 > timeout_s:
                        raise GuestError(f"the guest did not boot in {timeout_s:.0f} s") from None
        except GuestError as e:
            self.close()
            raise GuestError(f"{e}\n{self.logs()}") from None
        finally:
            listener.close()
        self.sock.settimeout(None)
        self._reader = self.sock.makefile("r")
        hello = json.loads(self._reader.readline())
        self.release = hello["hello"]
        self.boot_s = time.monotonic() - t0

    def call(self, op: str, *, timeout_s: float = 600.0, **args: Any) -> dict[str, Any]:
        if self.sock is None:
            raise GuestError("the guest is not running")
        self.sock.settimeout(timeout_s)
        self.sock.sendall(json.dumps({"op": op, **args}).encode() + b"\n")
        line = self._reader.readline()
        if not line:
            raise GuestError(f"the agent went away during {op}\n{self.logs()}")
        reply = json.loads(line)
        if not reply.pop("ok"):
            raise GuestError(f"{op}: {reply['error']}")
        return reply

    def clock_offset(self, rounds: int = 20) -> tuple[int, int]:
        """(offset, uncertainty) in ns: host monotonic ≈ guest monotonic + offset, ± the
        uncertainty (half the shortest round trip)."""
        best: tuple[int, int] | None = None
        for _ in range(rounds):
            t0 = time.monotonic_ns()
            guest = self.call("now")["t_ns"]
            t1 = time.monotonic_ns()
            estimate = ((t0 + t1) // 2 - guest, (t1 - t0 + 1) // 2)
            if best is None or estimate[1] < best[1]:
                best = estimate
        assert best is not None
        return best

    def logs(self, tail: int = 60) -> str:
        """The guest's console, the agent's output and QEMU's, last lines of each."""
        parts = []
        for name in ("console.log", "agent.log", "qemu.log"):
            path = self.rundir / name
            if path.is_file():
                lines = path.read_text(errors="replace").splitlines()[-tail:]
                parts.append(f"--- {name} ---\n" + "\n".join(lines))
        return "\n".join(parts)

    def close(self) -> None:
        if self.sock is not None:
            with contextlib.suppress(OSError, GuestError, ValueError):
                self.call("quit", timeout_s=10)
            self.sock.close()
            self.sock = None
        if self.qemu is not None:
            try:
                self.qemu.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.qemu.kill()
                self.qemu.wait()
        if not os.environ.get("GAZEHDR_HID_KERNEL_KEEP"):
            shutil.rmtree(self.rundir, ignore_errors=True)


# --- the command line -------------------------------------------------------------------------


def _smoke(guest: Guest) -> int:
    """Plug the hand-written tracker, list it with `gazehdr devices`, unplug it."""
    sys.path.insert(0, str(REPO / "tests"))
    from hid_kernel.descriptors import hut_tracker

    t = hut_tracker()
    t0 = time.monotonic()
    plugged = guest.call(
        "plug",
        dev="smoke",
        descriptor=t.descriptor.hex(),
        features={str(k): v.hex() for k, v in t.features.items()},
    )
    print(f"plugged: {plugged['hidraw']} ({time.monotonic() - t0:.1f} s)")
    done = guest.call("run", argv=["gazehdr", "devices"], timeout=300)
    print(done["stdout"] + done["stderr"], end="")
    print(f"gazehdr devices: exit {done['rc']}, {done['seconds']:.1f} s in the guest")
    return done["rc"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--shell", action="store_true", help="a shell in the guest, then stop")
    parser.add_argument("--rebuild", action="store_true", help="make the cached image anew")
    args = parser.parse_args(argv)
    if args.rebuild:
        shutil.rmtree(cache_root(), ignore_errors=True)
    t0 = time.monotonic()
    image = guest_image()
    how = "made" if image.built else "from the cache"
    print(f"kernel {image.kernel.release}; initramfs {how}: {image.initramfs}")
    print(f"  ({image.seconds:.2f} s); accelerator {accelerator()[0]}")
    with Guest() as guest:
        print(f"guest {guest.release} up in {guest.boot_s:.1f} s")
        if args.shell:
            while True:
                try:
                    line = input("guest$ ")
                except EOFError:
                    break
                done = guest.call("run", argv=["sh", "-c", line], timeout=600)
                print(done["stdout"] + done["stderr"], end="")
            rc = 0
        else:
            rc = _smoke(guest)
    print(f"total {time.monotonic() - t0:.1f} s")
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
