"""The frame-source interface every capture driver implements (V4L2, DepthAI, mock, replay).

A :class:`FrameSource` delivers the frames of one or more cameras of a rig.
It is pull-based: the recorder calls :meth:`FrameSource.read` in one loop and
gets whatever frames became available, from any camera, in per-camera
timestamp order. A driver never blocks waiting for its consumer: like a
camera with a fixed number of kernel buffers, a source whose frames are not
read in time loses them, and the loss shows as a gap in that camera's
:attr:`Frame.sequence` numbers (which the recorder counts as drops).

Timestamps are int64 nanoseconds on one clock shared by all cameras of a
capture: the host's ``CLOCK_MONOTONIC`` for live drivers (V4L2 buffer
timestamps, DepthAI timestamps mapped to the host clock), the recorded
timestamps for replay, and a simulated clock for the mock driver in
as-fast-as-possible mode. docs/capture.md describes the drivers.
"""

from __future__ import annotations

import logging
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from polycam.errors import PolycamError

__all__ = ["Frame", "CameraLost", "Item", "FrameSource", "CompositeSource", "CaptureError"]

log = logging.getLogger(__name__)


class CaptureError(PolycamError):
    """A capture could not start or had to stop (device missing, format refused, ...)."""


@dataclass(frozen=True)
class Frame:
    """One image of one camera as a driver delivered it."""

    cam_id: str
    """Camera id (rig file)."""
    timestamp_ns: int
    """[ns] capture time on the capture's shared clock (see the module docstring)."""
    sequence: int
    """Driver frame counter; increases by one per frame the sensor produced, so a gap
    means frames were lost before they reached polycam."""
    image: np.ndarray
    """(H, W) grey or (H, W, 3) RGB, uint8 or uint16, in the rig's width x height."""


@dataclass(frozen=True)
class CameraLost:
    """A camera stopped delivering for good (unplugged, device error, end of its stream)."""

    cam_id: str
    reason: str
    """One line saying why (e.g. ``No such device``)."""
    timestamp_ns: int | None = None
    """[ns] time of the last frame it delivered, if any."""


Item = Frame | CameraLost
"""What :meth:`FrameSource.read` returns a list of."""


class FrameSource(ABC):
    """Frames of one or more cameras (see the module docstring).

    Life cycle: construct (cheap, no device access), :meth:`start` (open and
    configure the devices, start streaming; raises :class:`CaptureError` with
    one clear line when it cannot), :meth:`read` repeatedly, :meth:`stop`
    (idempotent; also on errors). Usable as a context manager.
    """

    cameras: tuple[str, ...]
    """Ids of the cameras this source delivers."""
    driver: str = "?"
    """Driver name (``v4l2``, ``depthai``, ``mock``, ``replay``)."""
    finished: bool = False
    """True once the source will deliver nothing more (end of a replay or of a
    mock run with a frame limit); :meth:`read` then returns ``[]`` at once."""
    realtime: bool = True
    """False for sources that run as fast as they are read (simulated clock)."""

    @abstractmethod
    def start(self) -> None:
        """Open and configure the devices and start streaming."""

    @abstractmethod
    def read(self, timeout: float) -> list[Item]:
        """Frames (and camera losses) available now, waiting up to ``timeout`` [s] for
        the first one; ``[]`` when none arrived in time or the source is finished."""

    @abstractmethod
    def stop(self) -> None:
        """Stop streaming and release the devices (idempotent)."""

    def info(self) -> dict[str, Any]:
        """Settings worth recording in the session's statistics (controls, sync mode, ...)."""
        return {}

    def __enter__(self) -> "FrameSource":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


@dataclass
class CompositeSource(FrameSource):
    """Several sources read as one (a rig that mixes drivers)."""

    sources: list[FrameSource] = field(default_factory=list)
    poll_s: float = 0.002
    """[s] sleep between polling rounds while nothing is available."""

    def __post_init__(self) -> None:
        self.cameras = tuple(c for s in self.sources for c in s.cameras)
        self.driver = "+".join(sorted({s.driver for s in self.sources}))
        self.realtime = any(s.realtime for s in self.sources)

    @property
    def finished(self) -> bool:  # type: ignore[override]
        return all(s.finished for s in self.sources)

    def start(self) -> None:
        started = []
        try:
            for s in self.sources:
                s.start()
                started.append(s)
        except BaseException:
            for s in started:
                s.stop()
            raise

    def read(self, timeout: float) -> list[Item]:
        deadline = time.monotonic() + max(timeout, 0.0)
        while True:
            out: list[Item] = []
            for s in self.sources:
                if not s.finished:
                    out.extend(s.read(0.0))
            if out or self.finished:
                return out
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return out
            time.sleep(min(self.poll_s, remaining))

    def stop(self) -> None:
        for s in self.sources:
            try:
                s.stop()
            except Exception:  # stop the rest whatever one of them does
                log.exception("stopping %s source", s.driver)

    def info(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for s in self.sources:
            out.update(s.info())
        return out
