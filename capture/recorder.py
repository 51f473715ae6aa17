"""Recording: a frame source → synchroniser → bounded queue → background session writer.

:func:`record` runs one capture in the calling thread:

- the *capture loop* reads the source, counts drops (sequence gaps), groups
  frames into multi-frames (:class:`~capture.sync.Synchronizer`) and puts them
  on a bounded queue;
- a *writer thread* takes multi-frames off the queue and writes them through
  :class:`polycam.session.SessionWriter`, encoding the PNGs of one multi-frame
  on a small thread pool (PNG encoding runs outside the GIL), then appending
  its ``frames.csv`` row.

Nothing is lost silently. With a live source (``source.realtime``) a full
queue means the disk or CPU cannot keep up: the multi-frame is discarded and
every frame in it counted as ``overflow``; frames a driver lost show as
sequence gaps (``dropped``); frames that came too late for their multi-frame
are ``late``. A source on a simulated clock (mock as fast as possible, replay
not in real time) is simply throttled by a full queue instead.

Stopping: after ``frames`` multi-frames, after ``seconds`` of frame
timestamps, when ``stop_event`` is set (the CLI sets it on Ctrl-C / SIGTERM),
when the source ends, when every camera is lost, when a camera is lost and
``strict`` is set, or when writing fails (e.g. a full disk). In every case the
queue is drained, the statistics are written to ``capture_stats.toml`` and
the session is closed: ``complete``, or ``incomplete`` when writing failed.
A process killed outright leaves ``status = "incomplete"`` and every frame
written so far readable (SessionWriter flushes each row after its images).
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from polycam.rig import Rig
from polycam.session import other_rate_cameras

from .source import CameraLost, CaptureError, FrameSource
from .stats import STATS_FILE, CaptureStats
from .sync import MultiFrame, Synchronizer, default_tolerance_ns

__all__ = ["record", "CaptureResult"]

log = logging.getLogger(__name__)


@dataclass
class CaptureResult:
    """What :func:`record` did."""

    path: Path | None
    """The session folder (None when nothing was recorded)."""
    status: str
    """``complete`` or ``incomplete`` (session.toml); ``none`` without a session."""
    stats: CaptureStats
    stopped_by: str
    """``frames``, ``seconds``, ``interrupted``, ``end of source``, ``all cameras lost``,
    ``camera lost: <id>`` (strict), ``writer error`` or ``source error``."""


class _Writer(threading.Thread):
    """The background writer: multi-frames from a queue into a SessionWriter."""

    def __init__(self, session, q: queue.Queue, stats: CaptureStats, png_threads: int,
                 failed: threading.Event):
        super().__init__(name="polycam-writer", daemon=True)
        self.session = session
        self.q = q
        self.stats = stats
        self.failed = failed
        self.error: BaseException | None = None
        self.pool = ThreadPoolExecutor(png_threads, thread_name_prefix="polycam-png") if png_threads > 1 else None

    def run(self) -> None:
        try:
            while True:
                mf = self.q.get()
                if mf is None:
                    return
                if self.error is not None:
                    for c in mf.frames:
                        self.stats.per_camera[c].unwritten += 1
                    continue
                t0 = time.perf_counter()
                try:
                    self._write(mf)
                    self.stats.writer_busy_s += time.perf_counter() - t0
                except BaseException as e:  # noqa: BLE001 - reported by record()
                    self.error = e
                    self.failed.set()
                    for c in mf.frames:
                        self.stats.per_camera[c].unwritten += 1
        finally:
            if self.pool is not None:
                self.pool.shutdown(wait=True)

    def _write(self, mf: MultiFrame) -> None:
        s = self.session
        if s is None:  # not recording (statistics only)
            return
        if self.pool is not None and len(mf.frames) > 1:
            futures = [self.pool.submit(s.write_image, c, f.timestamp_ns, f.image) for c, f in mf.frames.items()]
            errors = [e for fu in futures if (e := fu.exception()) is not None]
            if errors:
                raise errors[0]
        else:
            for c, f in mf.frames.items():
                s.write_image(c, f.timestamp_ns, f.image)
        s.write_frame(mf.timestamp_ns, {c: f.timestamp_ns for c, f in mf.frames.items()})
        for c in mf.frames:
            self.stats.per_camera[c].recorded += 1
        self.stats.written += 1


def _describe(e: BaseException) -> str:
    if isinstance(e, OSError):
        what = e.strerror or str(e)
        return f"{what} ({e.filename})" if e.filename else what
    return str(e) or type(e).__name__


def record(source: FrameSource, rig: Rig, out: str | os.PathLike | None, *, frames: int | None = None,
           seconds: float | None = None, strict: bool = False, overwrite: bool = False,
           tolerance_ns: int | None = None, wait_ns: int | None = None, queue_frames: int = 32,
           png_threads: int = 3, stop_event: threading.Event | None = None,
           on_update: Callable[[CaptureStats], None] | None = None, update_interval: float = 0.5,
           writer_factory: Callable[..., Any] | None = None, free_running: bool = False) -> CaptureResult:
    """Capture from ``source`` into the session folder ``out`` (see the module docstring).

    rig: the rig (copied into the session); the source's cameras must be among its cameras.
    out: session folder, or None to run the capture without recording (statistics only).
    frames: stop after this many multi-frames; seconds: after this span of frame timestamps [s].
    tolerance_ns / wait_ns: synchroniser settings (defaults: half the shortest frame
        period; two of the longest frame periods).
    free_running: the cameras have no common trigger: one image per camera per frame period, each
        camera's phase tracked (:class:`Synchronizer`'s ``period_ns``, the shortest frame period;
        ``tolerance_ns`` is then not used; a slower camera's images go with the multi-frame nearest in
        time).
    queue_frames: capacity of the writer queue [multi-frames].
    writer_factory: ``factory(out, rig, overwrite=...)`` → a SessionWriter (tests inject
        failing writers); default :class:`polycam.session.SessionWriter`.
    on_update: called with the live :class:`CaptureStats` every ``update_interval`` [s] from a
        display thread (so a slow display never delays reading frames), and once at the end.

    Raises :class:`CaptureError` (after closing the session, with ``.result`` set) when
    writing failed or a camera was lost under ``strict``.
    """
    if frames is not None and frames < 1:
        raise ValueError("frames must be >= 1")
    if seconds is not None and not seconds > 0:
        raise ValueError("seconds must be > 0")
    ids = [c for c in rig.ids if c in set(source.cameras)]
    unknown = [c for c in source.cameras if c not in set(rig.ids)]
    if unknown:
        raise CaptureError(f"source camera {unknown[0]!r} is not in the rig {rig.name!r}")
    fps = [rig.camera(c).fps for c in ids]
    tol = default_tolerance_ns(fps) if tolerance_ns is None else int(tolerance_ns)
    period = int(round(1e9 / max(fps))) if free_running else None
    if period is not None:
        tol = period
    wait = int(round(2e9 / min(fps))) if wait_ns is None else int(wait_ns)
    stats = CaptureStats(ids, tol)
    stats.queue_size = queue_frames
    slower = frozenset(c for c, o in zip(ids, other_rate_cameras(fps)) if o) if free_running else frozenset()
    sync = Synchronizer(tuple(ids), tol, wait, period_ns=period, other_rate=slower)
    stop_event = stop_event or threading.Event()

    session = None
    if out is not None:
        if writer_factory is None:
            from polycam.session import SessionWriter

            writer_factory = SessionWriter
        session = writer_factory(out, rig, overwrite=overwrite)
    try:
        source.start()  # after the session exists: no frame is lost to setting it up
    except BaseException:
        if session is not None:  # nothing recorded: leave no empty session behind (and any replaced one back)
            session.discard()
        raise
    q: queue.Queue = queue.Queue(maxsize=queue_frames)
    failed = threading.Event()
    writer = _Writer(session, q, stats, png_threads, failed)
    writer.start()
    log.info("capture: %d cameras (%s) → %s; tolerance %.2f ms", len(ids), source.driver,
             out if out is not None else "(not recorded)", tol / 1e6)

    state = {"stop": ""}
    failure: Exception | None = None
    lost: set[str] = set()
    overflow_warned = [0.0]

    def deliver(mf: MultiFrame) -> None:
        if state["stop"] in ("frames", "seconds"):
            return  # a limit was reached: later multi-frames are not part of the capture
        if frames is not None and stats.multiframes >= frames:
            state["stop"] = state["stop"] or "frames"
            return
        if seconds is not None and stats.first_frame_ns is not None and \
                mf.timestamp_ns - stats.first_frame_ns >= seconds * 1e9:
            state["stop"] = state["stop"] or "seconds"
            return
        stats.multiframe(mf.timestamp_ns, mf.spread_ns, mf.missing)
        if source.realtime:
            try:
                q.put_nowait(mf)
            except queue.Full:
                for c in mf.frames:
                    stats.per_camera[c].overflow += 1
                now = time.monotonic()
                if now - overflow_warned[0] > 2.0:
                    overflow_warned[0] = now
                    log.warning("writer queue full (%d multi-frames): the disk or CPU cannot keep up; "
                                "frames are being dropped", queue_frames)
        else:
            while not failed.is_set():
                try:
                    q.put(mf, timeout=0.1)
                    break
                except queue.Full:
                    continue
            else:
                for c in mf.frames:
                    stats.per_camera[c].unwritten += 1
        stats.queue_max = max(stats.queue_max, q.qsize())
        if frames is not None and stats.multiframes >= frames:
            state["stop"] = state["stop"] or "frames"

    t_start = time.monotonic()
    done = threading.Event()
    ticker = None
    if on_update is not None:  # the display runs in its own thread: never delays reading frames
        def tick() -> None:
            while not done.wait(update_interval):
                try:
                    on_update(stats)
                except Exception:  # noqa: BLE001 - a display problem must not stop a capture
                    log.exception("live display update failed")

        ticker = threading.Thread(target=tick, name="polycam-display", daemon=True)
        ticker.start()
    try:
        while not state["stop"]:
            if stop_event.is_set():
                state["stop"] = "interrupted"
                break
            if failed.is_set():
                state["stop"] = "writer error"
                break
            if seconds is not None and source.realtime and time.monotonic() - t_start > seconds + 5.0:
                state["stop"] = "seconds"  # no frames at all: do not hang
                break
            try:
                items = source.read(0.05)
            except CaptureError:
                raise
            if not items and source.finished:
                state["stop"] = "end of source"
                break
            for it in items:
                if isinstance(it, CameraLost):
                    if it.cam_id in lost or it.cam_id not in stats.per_camera:
                        continue
                    lost.add(it.cam_id)
                    stats.lost(it.cam_id, it.reason)
                    log.warning("%s: camera lost (%s); recorded as missing from now on", it.cam_id, it.reason)
                    for mf in sync.lose(it.cam_id):
                        deliver(mf)
                    if strict:
                        state["stop"] = f"camera lost: {it.cam_id}"
                    elif len(lost) == len(ids):
                        state["stop"] = "all cameras lost"
                else:
                    gap = stats.frame(it.cam_id, it.timestamp_ns, it.sequence)
                    if gap:
                        log.info("%s: %d frame(s) dropped before sequence %d", it.cam_id, gap, it.sequence)
                    for mf in sync.add(it):
                        deliver(mf)
                if state["stop"] in ("frames", "seconds"):
                    break
    except KeyboardInterrupt:
        state["stop"] = "interrupted"
    except Exception as e:  # a driver failed: finish the session as incomplete, then report
        failure = e
        state["stop"] = "source error"
    finally:
        try:
            source.stop()
        finally:
            if state["stop"] not in ("frames", "seconds", "writer error"):
                for mf in sync.flush():
                    deliver(mf)
            for c, n in sync.late.items():
                stats.per_camera[c].late = n
            q.put(None)
            writer.join()
            stats.ended = time.monotonic()
            done.set()
            if ticker is not None:
                ticker.join()
    stopped_by = state["stop"] or "unknown"
    if writer.error is not None:
        stopped_by = "writer error"
        stats.error = _describe(writer.error)
    stats.stopped_by = stopped_by
    if on_update is not None:
        on_update(stats)

    if failure is not None:
        stats.error = _describe(failure)
    status = "none"
    if session is not None:
        status = "incomplete" if writer.error is not None or failure is not None else "complete"
        try:
            session.write_extra(STATS_FILE, stats.to_toml(source.info()))
        except OSError as e:
            log.warning("could not write %s: %s", STATS_FILE, _describe(e))
        try:
            session.close(status)
        except OSError as e:
            status = "incomplete"
            log.warning("closing the session failed: %s", _describe(e))
    result = CaptureResult(Path(out) if out is not None else None, status, stats, stopped_by)
    if failure is not None:
        raise failure
    if writer.error is not None:
        err = CaptureError(f"capture stopped: writing {out} failed: {stats.error}; the session is readable "
                           f"up to frame {stats.written} (status {status})")
        err.result = result  # type: ignore[attr-defined]
        raise err from writer.error
    if strict and stopped_by.startswith("camera lost"):
        cam = stopped_by.split(": ", 1)[1]
        err = CaptureError(f"capture stopped (--strict): {cam} was lost "
                           f"({stats.per_camera[cam].lost}); {stats.written} frames recorded in {out}")
        err.result = result  # type: ignore[attr-defined]
        raise err
    return result
