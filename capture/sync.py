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
median for an even count; with free-running cameras at several frame rates, of the members at
the multi-frames' rate), raised to one nanosecond after the previous
multi-frame's if needed so frame timestamps strictly increase.

**Free-running cameras** (``period_ns`` given; ``polycam capture --free-running``): cameras
without a common trigger have their phases anywhere in a frame period, which no tolerance
under a period groups, and their timestamps jitter (USB transfer, scheduling) by more than
the gaps between 20 cameras' phases, so the timestamps alone cannot say which frame an
image belongs to. Instead each camera's phase is tracked: the first multi-frame takes each
camera's first frame within one period of the earliest timestamp; its *reference time* is
the median of its members' timestamps, and a camera's phase is its timestamp minus the
reference time (then the median over its last :data:`PHASE_FRAMES` multi-frames). The next
multi-frame's reference time is the last one plus a period, and a camera's frame belongs to
it when its timestamp minus the camera's phase lies within half a period of it (earlier:
late, discarded; later: the camera is missing from this one). A camera seen for the first
time gets the phase, of those that keep the phases' span the narrowest, that puts its frame
nearest the reference time. The reference time then follows the cameras (the median of
their timestamps minus their phases), so a frame rate a little off the nominal one does not
drift out of the windows. Cameras' clocks differ too (crystals tens to hundreds of ppm
apart: over minutes their phases drift by a period or more): when the phases span more than
:data:`PHASE_WRAP` periods, the one furthest from the reference time moves by a whole
period, so each multi-frame's images stay within about a period of each other however long
the capture (a slower camera is then missing from one multi-frame, a faster one has one
image discarded as late). A camera at a slower nominal frame rate (``other_rate``: 25 fps
among 30) has no phase that stays put: its images go to the multi-frame whose span they are
nearest, centred on the middle of the tracked phases, and decide the multi-frames up to their
own timestamp only. Rule 3's waiting applies with each camera's window end.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .source import Frame

__all__ = ["MultiFrame", "Synchronizer", "default_tolerance_ns", "PHASE_FRAMES", "PHASE_WRAP"]

PHASE_FRAMES = 15
"""Free-running grouping: a camera's phase is the median over its last this many multi-frames."""

PHASE_WRAP = 1.125
"""Free-running grouping: [periods] when the cameras' phases span more than this (their clocks ran apart),
the phase furthest from the reference time moves by a whole period (a period and a margin: the first
multi-frame's phases span less than one, and the jitter must not move a phase back and forth)."""

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
    period_ns: int | None = None
    """[ns] free-running cameras at this frame period: phase-tracked grouping (module docstring);
    None: the anchor rule with ``tolerance_ns``."""
    other_rate: frozenset[str] = frozenset()
    """Free-running grouping: the cameras at a slower frame rate than ``period_ns``
    (:func:`polycam.session.other_rate_cameras`): such a camera's phase against the multi-frames does
    not stay put, so its images go to the multi-frame nearest in time (module docstring)."""
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
        if self.period_ns is not None and self.period_ns <= 0:
            raise ValueError("period must be > 0")
        self._ref_ns: int | None = None          # [ns] free-running: the next multi-frame's reference time
        self._phases: dict[str, deque[int]] = {c: deque(maxlen=PHASE_FRAMES) for c in self.cameras}
        self._phase: dict[str, int | None] = {c: None for c in self.cameras}   # [ns] their medians (None: unseen)
        self._untracked = frozenset(self.other_rate) if self.period_ns is not None else frozenset()
        if self._untracked - set(self.cameras):
            raise KeyError(f"other_rate: unknown camera {sorted(self._untracked - set(self.cameras))[0]!r}")

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
            if self.period_ns is not None and self._ref_ns is not None:
                return out + self._emit_free_running(final)
            heads = [q[0].timestamp_ns for q in self._pending.values() if q]
            if not heads:
                return out
            t0 = min(heads)
            t_end = t0 + (self.tolerance_ns if self.period_ns is None else self.period_ns - 1)
            if not final:
                for c in self.cameras:
                    if self._pending[c] or c in self._lost:
                        continue
                    if self._watermark > t_end + self.wait_ns:
                        continue  # given up on c for this window
                    return out  # c may still deliver a frame for this window
            if self.period_ns is None:
                out.append(self._take(t0, t_end))
                continue
            # the first free-running multi-frame: each camera's first frame in the period; a camera's
            # next frame, jittered into it, stays for the next (judged by its phase)
            members = {c: q.popleft() for c, q in self._pending.items() if q and q[0].timestamp_ns <= t_end}
            for c, f in members.items():
                self._done_until[c] = int(f.timestamp_ns)
            self._track(members, {c: int(f.timestamp_ns) for c, f in members.items()})
            out.append(self._multiframe(members))

    # -- free-running cameras

    def _track(self, members: dict[str, Frame], shown: dict[str, int]) -> None:
        """After a multi-frame: its reference time (the median of members' timestamps minus their phases;
        ``shown``: those values), each member's phase, and the next reference time a period on; then
        :meth:`_wrap_phases`."""
        tracked = [v for c, v in shown.items() if c not in self._untracked]
        ref = int(np.median(tracked or list(shown.values())))
        for c, f in members.items():
            if c in self._untracked:
                continue
            self._phases[c].append(int(f.timestamp_ns) - ref)
            self._phase[c] = int(np.median(self._phases[c]))
        self._ref_ns = ref + int(self.period_ns)
        self._wrap_phases()

    def _first_phase(self, offset: int) -> int:
        """[ns] the phase of a camera seen for the first time after the first multi-frame, from its first
        timestamp's ``offset`` from the reference time: the value modulo the period that keeps the known
        phases' span the narrowest (so that :meth:`_wrap_phases` need not move it), of those the nearest
        the reference time."""
        P = int(self.period_ns)
        known = [p for p in self._phase.values() if p is not None]
        base = (offset + P // 2) % P - P // 2
        cands = (base - P, base, base + P)
        if not known:
            return base
        lo, hi = min(known), max(known)
        return min(cands, key=lambda p: (max(hi, p) - min(lo, p), abs(p)))

    def _wrap_phases(self) -> None:
        """Cameras whose clocks run apart: while the settled phases (over :data:`PHASE_FRAMES`
        multi-frames) span more than :data:`PHASE_WRAP` periods, the one furthest from the reference
        time moves by a whole period towards it. Its next image then belongs to the multi-frame after
        (a slower camera: missing from one) or before (a faster one: one image discarded as late)."""
        P = int(self.period_ns)
        while True:
            settled = {c: p for c, p in self._phase.items()
                       if p is not None and len(self._phases[c]) == PHASE_FRAMES}
            if len(settled) < 2 or max(settled.values()) - min(settled.values()) <= PHASE_WRAP * P:
                return
            c = max(settled, key=lambda k: abs(settled[k]))
            shift = -P if settled[c] > 0 else P
            self._phases[c] = deque((p + shift for p in self._phases[c]), maxlen=PHASE_FRAMES)
            self._phase[c] = settled[c] + shift
            log.info("%s: its phase drifted %.1f ms from the other cameras' reference; its images now go "
                     "with the %s multi-frame", c, settled[c] / 1e6, "next" if shift < 0 else "previous")

    def _emit_free_running(self, final: bool) -> list[MultiFrame]:
        out: list[MultiFrame] = []
        P = int(self.period_ns)
        while True:
            heads = {c: q[0] for c, q in self._pending.items() if q}
            if not heads:
                return out
            phase = dict(self._phase)
            ref = self._ref_ns
            for c, f in heads.items():                # a camera's first frame: see _first_phase
                if phase[c] is None and c not in self._untracked:
                    phase[c] = self._first_phase(int(f.timestamp_ns) - ref)
            known = [p for c, p in phase.items() if p is not None and c not in self._untracked]
            for c in self._untracked:                 # another frame rate: the frame nearest the middle of
                phase[c] = (min(known) + max(known)) // 2 if known else 0       # the others' phases
            # nothing for whole periods (every camera paused): skip to the earliest frame's period
            u_min = min(int(f.timestamp_ns) - phase[c] for c, f in heads.items())
            if u_min >= ref + P // 2:
                self._ref_ns = ref = ref + (u_min - ref + P // 2) // P * P
            if not final:
                for c in self.cameras:
                    if self._pending[c] or c in self._lost:
                        continue
                    end = ref + P // 2 + (phase[c] or 0)
                    if self._watermark > end + self.wait_ns:
                        continue  # given up on c for this multi-frame
                    return out
            members: dict[str, Frame] = {}
            shown: dict[str, int] = {}
            for c in self.cameras:
                q = self._pending[c]
                while q and int(q[0].timestamp_ns) - phase[c] < ref - P // 2:     # behind its window
                    if c in self._untracked and (len(q) < 2 or int(q[1].timestamp_ns) - phase[c] >= ref + P // 2):
                        break        # another frame rate: an image between two windows (the reference
                                     # times jitter) goes with the next
                    q.popleft()
                    self.late[c] += 1
                if q and int(q[0].timestamp_ns) - phase[c] < ref + P // 2:
                    members[c] = q.popleft()
                    shown[c] = int(members[c].timestamp_ns) - phase[c]
                if c in self._untracked:      # decided up to its image (a later one may go with the next)
                    if c in members:
                        self._done_until[c] = max(self._done_until[c], int(members[c].timestamp_ns))
                elif phase[c] is not None:
                    self._done_until[c] = max(self._done_until[c], ref + P // 2 + phase[c] - 1)
            if not members:                             # only stale frames were pending
                self._ref_ns = ref + P
                continue
            self._track(members, shown)
            out.append(self._multiframe(members))

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
        return self._multiframe(members)

    def _multiframe(self, members: dict[str, Frame]) -> MultiFrame:
        ts = sorted(f.timestamp_ns for f in members.values())
        # the stamp: the median over the cameras at the multi-frames' rate (a slower camera's offset saws)
        own = sorted(f.timestamp_ns for c, f in members.items() if c not in self._untracked) or ts
        stamp = own[(len(own) - 1) // 2]
        if stamp <= self._last_frame_ns:
            stamp = self._last_frame_ns + 1
        self._last_frame_ns = stamp
        missing = tuple(c for c in self.cameras if c not in members)
        return MultiFrame(timestamp_ns=stamp, frames=members, missing=missing, spread_ns=ts[-1] - ts[0])
