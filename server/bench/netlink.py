"""A capped network link for benchmarks: this process again, in a network namespace of its own
whose loopback is shaped with `tc` (a token bucket at the link's rate, an MTU of 1500 as on
Ethernet, and optionally a fixed delay), so a server and its clients on 127.0.0.1 talk as over
that link. It needs `unshare` and `tc` (util-linux, iproute2) and the right to make namespaces
(root, or unprivileged user namespaces: `unshare -rn`).

This is a model of a link, not one: tbf shapes both directions of loopback at the rate, with the
queue a real switch or NIC would have replaced by tbf's (`latency` bounds it); no loss, no
jitter, no other traffic.
"""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys

#: Set in the child so that it does not start another namespace.
INSIDE = "GAZEHDR_NETNS_LINK"
#: tbf's queue: packets that would wait longer than this are dropped (TCP then slows down).
QUEUE_MS = 20


def shaping_commands(mbit: float, delay_ms: float = 0.0) -> list[str]:
    """The shell commands that make loopback a `mbit` Mbit/s link (and `delay_ms` each way)."""
    burst = max(int(mbit * 1e6 / 8 / 250), 16 * 1500)  # a 4 ms burst, at least 16 packets
    tbf = f"tbf rate {mbit}mbit burst {burst} latency {QUEUE_MS}ms"
    commands = ["ip link set lo mtu 1500", "ip link set lo up"]
    if delay_ms > 0:
        commands += [
            f"tc qdisc add dev lo root handle 1: netem delay {delay_ms}ms",
            f"tc qdisc add dev lo parent 1: handle 2: {tbf}",
        ]
    else:
        commands.append(f"tc qdisc add dev lo root {tbf}")
    return commands


def run_capped(mbit: float, delay_ms: float, argv: list[str]) -> int:
    """Run `python -m gazehdr.bench.live argv` in a new network namespace over the capped
    loopback; its exit status. Raises RuntimeError when the namespace cannot be made."""
    for tool in ("unshare", "tc", "ip"):
        if shutil.which(tool) is None:
            raise RuntimeError(f"--link-mbit needs {tool} (util-linux / iproute2)")
    setup = " && ".join(shaping_commands(mbit, delay_ms))
    child = shlex.join([sys.executable, "-m", "gazehdr.bench.live", *argv])
    ns = ["unshare", "--net"] if os.geteuid() == 0 else ["unshare", "-rn"]
    env = {**os.environ, INSIDE: f"{mbit} Mbit/s, {delay_ms} ms delay"}
    done = subprocess.run([*ns, "sh", "-c", f"{setup} && exec {child}"], env=env, check=False)
    if done.returncode:
        print(f"(the capped run exited {done.returncode})", file=sys.stderr)
    return done.returncode


def link() -> str | None:
    """The link this process runs over (set by `run_capped`), or None: plain loopback."""
    return os.environ.get(INSIDE)
