"""Measuring gazehdr on this machine: `gazehdr bench` (`pipeline`, with `roofline`) and
`gazehdr bench-live` (`live`, with `netlink` for a capped link), and the developers' tools run
with `python -m`: `ab` (the installed kernels against a changed copy) and `warp` (what the late
gaze warp costs). docs/performance.md has what they measured. Imports nothing: each tool brings
its own dependencies when it runs."""
