"""The replay driver: a recorded session played back as a live frame source.

Every image listed in a camera's ``data.csv`` is delivered with its recorded
timestamp and its decoded pixels, so re-recording a replay gives the same
frames, timestamps and multi-frames bit for bit (the synchroniser depends on
timestamps only). Frames come in timestamp order across cameras, either as
fast as they are read (default) or in real time (``realtime=True``: the
recorded spacing, optionally scaled by ``speed``), paced on the host's
monotonic clock while keeping the recorded timestamps.

A session stores no driver sequence numbers, so replay rebuilds them from the
timestamps: ``round((t − t_first) · fps)`` with the camera's nominal ``fps``
(kept strictly increasing). A frame the original capture lost therefore
shows again as a sequence gap, provided timestamp jitter stays below half a
frame period.

A rig can use ``driver = "replay"`` with ``device = "SESSION"`` (the same
camera id in that session) or ``device = "SESSION#cam03"`` (another id);
relative paths are relative to the rig file.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import Any, Callable

from .source import CaptureError, Frame, FrameSource, Item

__all__ = ["ReplaySource", "parse_replay_device"]

log = logging.getLogger(__name__)


def parse_replay_device(device: str | None, cam_id: str, base: Path | None) -> tuple[Path, str]:
    """``"SESSION[#cam]"`` → (session folder, camera id in it)."""
    if not device:
        raise CaptureError(f"camera {cam_id}: driver replay needs device = \"SESSION\" or \"SESSION#cam\"")
    path, _, src = device.partition("#")
    p = Path(path)
    if not p.is_absolute() and base is not None:
        p = base / p
    return p, (src or cam_id)


class ReplaySource(FrameSource):
    """Frames of a recorded session (see the module docstring).

    session: a session folder or an open :class:`polycam.session.Session`.
    cameras: rig camera id → session camera id (default: every session camera as itself).
    realtime: pace frames like the recording (else as fast as read); speed scales real time.
    """

    driver = "replay"

    def __init__(self, session, cameras: dict[str, str] | None = None, *, realtime: bool = False,
                 speed: float = 1.0, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep, batch: int | None = None):
        self._session_arg = session
        self._map = dict(cameras) if cameras is not None else None
        self.realtime = bool(realtime)
        if not speed > 0:
            raise ValueError("speed must be > 0")
        self.speed = float(speed)
        self._clock = clock
        self._sleep = sleep
        self._batch = batch
        self.finished = False
        if isinstance(session, (str, os.PathLike)):
            from polycam.session import open_session

            session = open_session(session)  # validates the session (a file, not a device)
        self.session = session
        if self._map is None:
            self._map = {c: c for c in session.cameras}
        self.cameras = tuple(self._map)

    def start(self) -> None:
        events: list[tuple[int, int, str, str, int]] = []
        for k, (rig_cam, src_cam) in enumerate(self._map.items()):
            if src_cam not in self.session.cameras:
                raise CaptureError(f"{self.session.path}: no camera {src_cam!r} to replay as {rig_cam} "
                                   f"(session has {', '.join(self.session.cameras)})")
            fps = float(self.session.rig.camera(src_cam).fps)
            ts = self.session.image_timestamps(src_cam)
            prev = -1
            for t in ts.tolist():
                seq = max(int(round((t - int(ts[0])) * fps / 1e9)), prev + 1)
                prev = seq
                events.append((t, k, rig_cam, src_cam, seq))
        events.sort()
        self._events = events
        self._i = 0
        self._t_first = events[0][0] if events else 0
        self._wall0 = self._clock()
        self.finished = not events
        log.info("replay %s: %d images of %d cameras, %s", self.session.path, len(events), len(self._map),
                 "real time" if self.realtime else "as fast as possible")

    def _due_time(self, t_ns: int) -> float:
        return self._wall0 + (t_ns - self._t_first) / 1e9 / self.speed

    def read(self, timeout: float) -> list[Item]:
        if not hasattr(self, "_events"):
            raise RuntimeError("ReplaySource.read before start")
        if self._i >= len(self._events):
            self.finished = True
            return []
        n = self._batch or len(self._map)
        if self.realtime:
            wait = self._due_time(self._events[self._i][0]) - self._clock()
            if wait > timeout:
                if timeout > 0:
                    self._sleep(timeout)
                return []
            if wait > 0:
                self._sleep(wait)
            now = self._clock()
            j = self._i
            while j < len(self._events) and self._due_time(self._events[j][0]) <= now:
                j += 1
            j = max(j, self._i + 1)
        else:
            j = min(self._i + n, len(self._events))
        out: list[Item] = []
        for t, _, rig_cam, src_cam, seq in self._events[self._i:j]:
            out.append(Frame(rig_cam, t, seq, self.session.read_image(src_cam, t)))
        self._i = j
        if self._i >= len(self._events):
            self.finished = True
        return out

    def stop(self) -> None:
        pass

    def info(self) -> dict[str, Any]:
        return {"replay": {"session": str(self.session.path), "realtime": self.realtime, "speed": self.speed}}
