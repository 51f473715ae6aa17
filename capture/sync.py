"""Grouping frames of all cameras into synchronised multi-frames by timestamp.

:class:`Synchronizer` receives frames in any interleaving across cameras (but
in timestamp order per camera) and emits :class:`MultiFrame` groups in
timestamp order. The rule, which depends only on the timestamps (so a replay
of a recorded session regroups it identically):

1. The *anchor* ``t0`` is the earliest timestamp not yet grouped.
2. Each camera contributes its earliest pending frame if that frame's
   timestamp is within ``[t0, t0 + tolerance]``; otherwise it is *missing*
   from this multi-frame. So the spread (max − min timestamp) of a multi-frame
   never exceeds the tolerance (default: half the shortest frame period).
3. A group is emitted once every camera still connected has decided: it has a
   pending frame, or it has been disconnected, or another camera has already
   delivered a frame later than ``t0 + tolerance + wait`` (the *watermark*;
   default wait: two frame periods), after which a late camera counts as
   missing and its frame, if it still arrives, is discarded as *late*.

The multi-frame timestamp is the median of its members' timestamps (the lower
median for an even count), raised to one nanosecond after the previous
multi-frame's if needed so frame timestamps strictly increase.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field

from .source import Frame

__all__ = ["MultiFrame", "Synchronizer", "default_tolerance_ns"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MultiFrame:
    """Frames of all cameras taken at (nearly) the same time."""

    timestamp_ns: int
    """[ns] the multi-frame's timestamp (median of its members')."""
    frames: dict[str, Frame]
    """Camera id → its frame, for the cameras present."""
    missing: tuple[str, ...]
    """Ids of the cameras with no frame in this multi-frame (rig order)."""
    spread_ns: int
    """[ns] max − min timestamp of the members (0 for a single member)."""


def default_tolerance_ns(fps: list[float] | tuple[float, ...]) -> int:
    """Half the shortest frame period [ns] of cameras running at ``fps`` [Hz]."""
    return int(round(0.5e9 / max(fps)))


@dataclass
class Synchronizer:
    """Groups frames into :class:`MultiFrame` s (see the module docstring)."""

    cameras: tuple[str, ...]
    """All camera ids, in rig order (the order of :attr:`MultiFrame.missing`)."""
    tolerance_ns: int
    """[ns] max spread of a multi-frame."""
    wait_ns: int
    """[ns] how far past a group's window another camera's frames may run before a
    camera that has not delivered counts as missing."""
    late: dict[str, int] = field(init=False)
    """Camera id → frames discarded because their multi-frame was already emitted
    (or because their timestamp did not increase)."""

    def __post_init__(self) -> None:
        if self.tolerance_ns < 0 or self.wait_ns < 0:
            raise ValueError("tolerance and wait must be >= 0")
        self.cameras = tuple(self.cameras)
        self._pending: dict[str, deque[Frame]] = {c: deque() for c in self.cameras}
        self._lost: set[str] = set()
        self._done_until: dict[str, int] = {c: -1 for c in self.cameras}  # [ns] decided up to here
        self._last_ts: dict[str, int] = {c: -1 for c in self.cameras}
        self._watermark = -1            # [ns] latest timestamp delivered by any camera
        self._last_frame_ns = -1
        self.late = {c: 0 for c in self.cameras}

    # -- input

    def add(self, frame: Frame) -> list[MultiFrame]:
        """Take one frame; returns the multi-frames it completed (usually 0 or 1)."""
        c = frame.cam_id
        if c not in self._pending:
            raise KeyError(f"frame from unknown camera {c!r}")
        ts = int(frame.timestamp_ns)
        if ts <= self._last_ts[c]:
            log.warning("%s: timestamp %d does not increase (previous %d); frame discarded", c, ts,
                        self._last_ts[c])
            self.late[c] += 1
            return []
        self._last_ts[c] = ts
        if ts <= self._done_until[c] or c in self._lost:
            self.late[c] += 1
            return []
        self._pending[c].append(frame)
        self._watermark = max(self._watermark, ts)
        return self._emit_ready(final=False)

    def lose(self, cam_id: str) -> list[MultiFrame]:
        """Camera ``cam_id`` is gone: stop waiting for it (its pending frames still count)."""
        if cam_id not in self._pending:
            raise KeyError(f"unknown camera {cam_id!r}")
        self._lost.add(cam_id)
        return self._emit_ready(final=False)

    def flush(self) -> list[MultiFrame]:
        """End of capture: group everything still pending."""
        return self._emit_ready(final=True)

    @property
    def pending(self) -> int:
        """Frames waiting to be grouped."""
        return sum(len(q) for q in self._pending.values())

    # -- grouping

    def _emit_ready(self, final: bool) -> list[MultiFrame]:
        out: list[MultiFrame] = []
        while True:
            heads = [q[0].timestamp_ns for q in self._pending.values() if q]
            if not heads:
                return out
            t0 = min(heads)
            t_end = t0 + self.tolerance_ns
            if not final:
                for c in self.cameras:
                    if self._pending[c] or c in self._lost:
                        continue
                    if self._watermark > t_end + self.wait_ns:
                        continue  # given up on c for this window
                    return out  # c may still deliver a frame for this window
            out.append(self._take(t0, t_end))

    def _take(self, t0: int, t_end: int) -> MultiFrame:
        members: dict[str, Frame] = {}
        for c in self.cameras:
            q = self._pending[c]
            if q and q[0].timestamp_ns <= t_end:
                members[c] = q.popleft()
            while q and q[0].timestamp_ns <= t_end:  # a second frame in one window
                q.popleft()
                self.late[c] += 1
            self._done_until[c] = max(self._done_until[c], t_end)
        ts = sorted(f.timestamp_ns for f in members.values())
        stamp = ts[(len(ts) - 1) // 2]
        if stamp <= self._last_frame_ns:
            stamp = self._last_frame_ns + 1
        self._last_frame_ns = stamp
        missing = tuple(c for c in self.cameras if c not in members)
        return MultiFrame(timestamp_ns=stamp, frames=members, missing=missing, spread_ns=ts[-1] - ts[0])
