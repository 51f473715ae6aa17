"""Capture statistics: frames per camera, drops, sync spread; written as ``capture_stats.toml``.

Counters are updated by the recorder's capture loop (received, drops, late,
overflow, missing, spread) and its writer thread (recorded); a display thread
may read a :meth:`CaptureStats.snapshot` at any time (plain ints, so a
snapshot is at worst a few frames stale). The file layout is documented in
docs/formats.md ("Capture statistics").
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["CameraStats", "CaptureStats", "STATS_FILE"]

STATS_FILE = "capture_stats.toml"
"""Name of the statistics file inside the session folder."""


@dataclass
class CameraStats:
    """Counters of one camera."""

    received: int = 0
    """Frames delivered by the driver."""
    recorded: int = 0
    """Images written to the session."""
    dropped: int = 0
    """Frames lost before reaching polycam (gaps in the driver's sequence numbers)."""
    late: int = 0
    """Frames discarded by the synchroniser (arrived after their multi-frame was emitted)."""
    overflow: int = 0
    """Frames discarded because the writer queue was full (disk or CPU too slow)."""
    unwritten: int = 0
    """Frames queued but not written because writing failed."""
    missing: int = 0
    """Multi-frames without this camera."""
    first_ns: int | None = None
    last_ns: int | None = None
    last_sequence: int | None = None
    lost: str | None = None
    """Why the camera disconnected, if it did."""
    lost_after_frames: int | None = None
    """Frames received before it disconnected."""
    recent: list[int] = field(default_factory=list)
    """[ns] timestamps of the last few frames (live fps)."""

    @property
    def fps(self) -> float:
        """[Hz] mean delivered frame rate over the run."""
        if self.first_ns is None or self.last_ns is None or self.received < 2 or self.last_ns <= self.first_ns:
            return 0.0
        return (self.received - 1) * 1e9 / (self.last_ns - self.first_ns)

    @property
    def live_fps(self) -> float:
        """[Hz] frame rate over the last few frames."""
        r = self.recent
        if len(r) < 2 or r[-1] <= r[0]:
            return 0.0
        return (len(r) - 1) * 1e9 / (r[-1] - r[0])


class CaptureStats:
    """Counters of a whole capture (see the module docstring)."""

    _RECENT = 16

    def __init__(self, cameras: list[str] | tuple[str, ...], tolerance_ns: int):
        self.cameras = tuple(cameras)
        self.per_camera = {c: CameraStats() for c in self.cameras}
        self.tolerance_ns = int(tolerance_ns)
        self.multiframes = 0
        """Multi-frames emitted by the synchroniser."""
        self.written = 0
        """Multi-frames written to the session (frames.csv rows)."""
        self.complete = 0
        """Multi-frames with every camera present."""
        self.spreads_ns: list[int] = []
        self.writer_busy_s = 0.0
        """[s] time the writer thread spent writing (the rest it waited for frames)."""
        self.queue_max = 0
        self.queue_size = 1
        self.started = time.monotonic()
        self.ended: float | None = None
        self.stopped_by = ""
        self.error: str | None = None
        self.first_frame_ns: int | None = None
        self.last_frame_ns: int | None = None
        self._lock = threading.Lock()

    # -- updates (capture loop)

    def frame(self, cam: str, timestamp_ns: int, sequence: int) -> int:
        """Count a delivered frame; returns the number of frames dropped before it."""
        s = self.per_camera[cam]
        gap = 0
        if s.last_sequence is not None:
            gap = sequence - s.last_sequence - 1
            if gap < 0:  # counter reset (device restarted): not a drop
                gap = 0
        s.last_sequence = sequence
        s.dropped += gap
        s.received += 1
        if s.first_ns is None:
            s.first_ns = timestamp_ns
        s.last_ns = timestamp_ns
        s.recent.append(timestamp_ns)
        if len(s.recent) > self._RECENT:
            del s.recent[0]
        return gap

    def lost(self, cam: str, reason: str) -> None:
        s = self.per_camera[cam]
        if s.lost is None:
            s.lost = reason
            s.lost_after_frames = s.received

    def multiframe(self, timestamp_ns: int, spread_ns: int, missing: tuple[str, ...]) -> None:
        self.multiframes += 1
        if not missing:
            self.complete += 1
        for c in missing:
            self.per_camera[c].missing += 1
        with self._lock:
            self.spreads_ns.append(int(spread_ns))
        if self.first_frame_ns is None:
            self.first_frame_ns = timestamp_ns
        self.last_frame_ns = timestamp_ns

    # -- reports

    def spread_percentiles_ms(self) -> dict[str, float]:
        """``p50``, ``p90``, ``p99``, ``max``, ``mean`` of the multi-frame spread [ms]."""
        with self._lock:
            s = np.asarray(self.spreads_ns, dtype=float) / 1e6
        if s.size == 0:
            return {"p50": 0.0, "p90": 0.0, "p99": 0.0, "max": 0.0, "mean": 0.0}
        p50, p90, p99 = np.percentile(s, [50, 90, 99])
        return {"p50": float(p50), "p90": float(p90), "p99": float(p99), "max": float(s.max()),
                "mean": float(s.mean())}

    @property
    def duration_s(self) -> float:
        """[s] wall-clock duration so far (or of the whole run once ended)."""
        return (self.ended if self.ended is not None else time.monotonic()) - self.started

    @property
    def writer_headroom(self) -> float:
        """Wall time over the writer's busy time: how many times faster the writer could go
        (0 when nothing was written)."""
        if self.writer_busy_s <= 0:
            return 0.0
        return self.duration_s / self.writer_busy_s

    @property
    def total_dropped(self) -> int:
        """Frames lost anywhere: driver drops, late, queue overflow, unwritten."""
        return sum(s.dropped + s.late + s.overflow + s.unwritten for s in self.per_camera.values())

    def snapshot(self) -> dict[str, Any]:
        """A plain copy for a live display."""
        cams = {}
        for c, s in self.per_camera.items():
            cams[c] = {"received": s.received, "recorded": s.recorded, "fps": s.live_fps,
                       "dropped": s.dropped, "late": s.late, "overflow": s.overflow, "missing": s.missing,
                       "lost": s.lost}
        return {"cameras": cams, "multiframes": self.multiframes, "written": self.written,
                "complete": self.complete, "spread_ms": self.spread_percentiles_ms(),
                "queue": self.queue_max, "queue_size": self.queue_size, "duration_s": self.duration_s}

    def to_toml(self, extra: dict[str, Any] | None = None) -> str:
        """The ``capture_stats.toml`` text (docs/formats.md)."""
        import tomli_w

        span = 0.0
        if self.first_frame_ns is not None and self.last_frame_ns is not None:
            span = (self.last_frame_ns - self.first_frame_ns) / 1e9
        cap: dict[str, Any] = {
            "stopped_by": self.stopped_by or "unknown",
            "multiframes": self.multiframes,
            "written": self.written,
            "complete": self.complete,
            "dropped_total": self.total_dropped,
            "tolerance_ms": self.tolerance_ns / 1e6,
            "duration_s": round(self.duration_s, 3),
            "timestamp_span_s": round(span, 6),
            "queue_size": self.queue_size,
            "queue_max": self.queue_max,
            "writer_busy_s": round(self.writer_busy_s, 3),
            "writer_headroom": round(self.writer_headroom, 3),
        }
        if self.error:
            cap["error"] = self.error
        doc: dict[str, Any] = {"capture": cap,
                               "spread_ms": {k: round(v, 6) for k, v in self.spread_percentiles_ms().items()}}
        cams: dict[str, Any] = {}
        for c, s in self.per_camera.items():
            e: dict[str, Any] = {"received": s.received, "recorded": s.recorded, "dropped": s.dropped,
                                 "late": s.late, "overflow": s.overflow, "unwritten": s.unwritten,
                                 "missing": s.missing, "fps": round(s.fps, 4)}
            if s.lost is not None:
                e["lost"] = s.lost
                e["lost_after_frames"] = s.lost_after_frames
            cams[c] = e
        doc["camera"] = cams
        if extra:
            doc["driver"] = _plain(extra)
        return "# polycam capture statistics (docs/formats.md)\n" + tomli_w.dumps(doc)


def _plain(v: Any) -> Any:
    """A value TOML can hold (None dropped, numpy scalars converted)."""
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items() if x is not None}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v if x is not None]
    if isinstance(v, np.generic):
        return v.item()
    return v
