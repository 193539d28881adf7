"""Counters and histograms in Prometheus text format, with no client library.

A handful of metrics is all the server exports, so a few dozen lines beat a dependency. Labels
are fixed per metric at creation; values are only touched from the event loop and the render
threads through `+=` on floats, which the GIL makes safe enough for monitoring.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

#: Bucket edges in seconds for frame and latency histograms: 1 ms .. 1 s.
TIME_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.02, 0.033, 0.05, 0.1, 0.2, 0.5, 1.0)


@dataclass
class Counter:
    name: str
    help: str
    value: float = 0.0

    def inc(self, amount: float = 1.0) -> None:
        self.value += amount

    def render(self) -> list[str]:
        return [f"# HELP {self.name} {self.help}", f"# TYPE {self.name} counter",
                f"{self.name} {self.value:g}"]  # fmt: skip


@dataclass
class Gauge(Counter):
    def set(self, value: float) -> None:
        self.value = value

    def render(self) -> list[str]:
        return [f"# HELP {self.name} {self.help}", f"# TYPE {self.name} gauge",
                f"{self.name} {self.value:g}"]  # fmt: skip


@dataclass
class Histogram:
    name: str
    help: str
    buckets: tuple[float, ...] = TIME_BUCKETS
    counts: list[int] = field(default_factory=list)
    total: float = 0.0
    n: int = 0

    def __post_init__(self) -> None:
        self.counts = [0] * (len(self.buckets) + 1)

    def observe(self, value: float) -> None:
        self.counts[bisect.bisect_left(self.buckets, value)] += 1
        self.total += value
        self.n += 1

    def render(self) -> list[str]:
        lines = [f"# HELP {self.name} {self.help}", f"# TYPE {self.name} histogram"]
        cumulative = 0
        for edge, count in zip((*self.buckets, float("inf")), self.counts, strict=True):
            cumulative += count
            le = "+Inf" if edge == float("inf") else f"{edge:g}"
            lines.append(f'{self.name}_bucket{{le="{le}"}} {cumulative}')
        lines += [f"{self.name}_sum {self.total:g}", f"{self.name}_count {self.n}"]
        return lines


class Metrics:
    """Everything `/metrics` reports."""

    def __init__(self) -> None:
        self.frames_sent = Counter("gazehdr_frames_sent_total", "Frames sent to viewers.")
        self.frames_dropped = Counter(
            "gazehdr_frames_dropped_total", "Frames replaced before a slow viewer could take them."
        )
        self.bytes_sent = Counter("gazehdr_frame_bytes_sent_total", "Frame bytes sent.")
        self.sim_seconds = Histogram("gazehdr_sim_seconds", "Simulation step time per frame.")
        self.encode_seconds = Histogram(
            "gazehdr_encode_seconds", "Time to encode a step's frame in the session's encoding."
        )
        self.stream_encode_seconds = Histogram(
            "gazehdr_stream_encode_seconds", "Time to encode a frame for a stream (h264, av1)."
        )
        self.send_seconds = Histogram("gazehdr_send_seconds", "Time to hand a frame to a socket.")
        self.gaze_latency = Histogram(
            "gazehdr_gaze_latency_seconds",
            "From a gaze update reaching the server to the first frame that used it being sent.",
        )
        self.sessions = Gauge("gazehdr_sessions", "Live viewing sessions.")
        self.viewers = Gauge("gazehdr_viewers", "Connected viewers.")
        self.trackers = Gauge("gazehdr_trackers", "Connected gaze daemons.")
        self.gaze_samples = Counter("gazehdr_gaze_samples_total", "Gaze samples received.")
        self.gaze_forwarded = Counter(
            "gazehdr_gaze_forwarded_total",
            "Tracker gaze notes sent to viewers with the late gaze warp on.",
        )
        self.gaze_rate_limited = Counter(
            "gazehdr_gaze_samples_rate_limited_total", "Gaze samples dropped by the rate limit."
        )
        self.gaze_events_rate_limited = Counter(
            "gazehdr_gaze_events_rate_limited_total", "Gaze events dropped by the rate limit."
        )
        self.gaze_echoes_rate_limited = Counter(
            "gazehdr_gaze_echoes_rate_limited_total",
            "Clock echoes left unanswered by the rate limit.",
        )
        self.protocol_errors = Counter(
            "gazehdr_protocol_errors_total", "Messages refused as malformed or invalid."
        )
        self.messages_held = Counter(
            "gazehdr_messages_held_total",
            "Messages of /ws/view and /ws/gaze read only after their connection's share refilled.",
        )

    def render(self) -> str:
        lines: list[str] = []
        for metric in vars(self).values():
            lines += metric.render()
        return "\n".join(lines) + "\n"
