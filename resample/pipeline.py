"""``polycam resample``: a recorded session → a light-field store, streaming, in parallel.

1. Open the session and its calibration (``SESSION/calib`` or ``calib_dir``: mrcal
   cameramodels, ``rt_cam_ref = T_cam_rig``).
2. Choose the grid (:func:`resample.grid.auto_grid`) unless one is given.
3. Build the splat geometry once (:class:`resample.resampler.Resampler`).
4. Create the store with every frame sized up front (:class:`resample.store.FrameStore`).
5. Resample the frames, each independently: read its images, resample, write its
   chunks. Memory stays constant (a bounded number of frames in flight).
   ``scheduler``:

   - ``"sync"``: in this process, one frame after the other (numba uses all cores
     inside each frame);
   - ``None`` (default): a local dask.distributed cluster with one single-threaded
     worker process per core (``workers``), or ``"sync"`` for tiny jobs;
   - ``"tcp://host:port"``: an existing dask.distributed scheduler. Its workers must
     see the session and the output folder at the same paths (a shared filesystem).

   The resampler (with its geometry) is sent once to every worker.
6. Add ``groundtruth.tum`` when the session has one, and publish the store.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from polycam.errors import InputError
from polycam.lightfield import LightFieldGrid
from polycam.lfstore import camera_positions_attr
from polycam.session import Session

__all__ = ["ResampleSummary", "resample_session", "open_calibration"]

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]

_TINY_JOB_RAYS = 50_000_000
"""Jobs with fewer rays than this (frames x pixels) run in-process by default: starting a
local cluster and shipping the geometry to it takes ~10 s, more than such a job gains."""


@dataclass(frozen=True)
class ResampleSummary:
    """What :func:`resample_session` did."""

    path: Path
    """The light-field store written."""
    grid: LightFieldGrid
    frames: int
    cameras: int
    rays_per_frame: int
    """Camera pixels per frame."""
    channels: int
    missing_images: int
    """Camera images absent from frames (resampled from the cameras present)."""
    empty_frames: int
    """Frames without any image (written as L = W = 0)."""
    scheduler: str
    """``sync``, ``local:N`` or the scheduler address."""
    seconds_geometry: float
    seconds_frames: float
    mean_W: float
    """Mean confidence over all written samples."""
    camera_noise_sigma: float = float("nan")
    """The cameras' sensor noise recorded in the store (its ``camera_noise`` attribute; NaN: none)."""
    compressed_cameras: int = 0
    """Cameras left out of that estimate: they record MJPG (:data:`resample.resampler.COMPRESSED_FORMATS`)."""
    sync_warning: str = ""
    """:func:`polycam.session.sync_warning` of the session ('' when its cameras are synchronised)."""
    cameras_moved_to_capture: bool = False
    """Each frame was resampled with every camera where it captured its image (``capture_motion``)."""


def open_calibration(session, calib_dir: str | os.PathLike | None) -> dict:
    """The session's camera models (``calib_dir`` or ``SESSION/calib``); an InputError when none."""
    models = session.calibration(calib_dir)
    if models is None:
        raise InputError(f"{session.path}: no calibration (no {session.path / 'calib'} folder); "
                         "pass --calib CALIB_DIR")
    return models


def _channels_of(session) -> int:
    """3 if the first images of any camera are RGB, else 1."""
    for cam in session.cameras:
        ts = session.image_timestamps(cam)
        if ts.size and np.ndim(session.read_image(cam, int(ts[0]))) == 3:
            return 3
    return 1


# ----------------------------------------------------------------------------- per-frame work

_SESSIONS: dict[tuple, object] = {}
"""Per-process cache of opened sessions (a worker serves many frames of one session)."""
_LOCKS: dict[int, threading.Lock] = {}
_GLOBAL_LOCK = threading.Lock()


def _session(path: str):
    try:   # a session rewritten at the same path (long-lived cluster) is opened afresh
        key = (path, os.stat(os.path.join(path, "frames.csv")).st_mtime_ns)
    except OSError:
        key = (path, None)
    s = _SESSIONS.get(key)
    if s is None:
        from polycam.session import open_session

        s = open_session(path)
        if len(_SESSIONS) > 4:
            _SESSIONS.clear()
        _SESSIONS[key] = s
    return s


def _frame_task(resampler, session_path: str, t: int, partial: str, threads: int | None) -> tuple[int, int, float]:
    """Resample frame t of the session into the partial store: (t, cameras present, sum of W)."""
    from .store import write_frame

    if threads:
        import numba

        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    with _GLOBAL_LOCK:
        lock = _LOCKS.setdefault(id(resampler), threading.Lock())
    images = _session(session_path).read_frame(t)
    with lock:          # the resampler's buffers serve one frame at a time
        if not any(img is not None for img in images.values()):
            shape = resampler.grid.shape
            C = resampler.channels
            write_frame(partial, t, np.zeros((*shape, C) if C > 1 else shape, np.float32),
                        np.zeros(shape, np.float32))
            return t, 0, 0.0
        r = resampler.resample_into(images)
        write_frame(partial, t, r.L, r.W)
        return t, len(r.cameras), float(np.sum(r.W, dtype=np.float64))


def _moved_frame_task(models: dict, grid, channels: int, options, session_path: str, t: int, partial: str,
                      threads: int | None) -> tuple[int, int, float]:
    """:func:`_frame_task` with a resampler of frame t's own: ``models`` are the cameras where they
    captured its images (:func:`resample.stream.models_at_capture`)."""
    from .resampler import Resampler

    return _frame_task(Resampler(models, grid, channels=channels, options=options), session_path, t, partial,
                       threads)


# ----------------------------------------------------------------------------- the job


def _check_faces_reached(geometry, session_path) -> None:
    """:class:`~polycam.errors.InputError` when no camera ray reaches any face of the grid (the
    store would hold W = 0 everywhere: a grid whose faces the cameras do not look through); a
    warning naming the faces no ray reaches when others are reached (a six-face grid on a rig
    that looks one way)."""
    grid = geometry.grid
    per_face = geometry.w0.reshape(len(grid.faces), -1).sum(axis=1)
    empty = [face.name for face, w in zip(grid.faces, per_face) if not w > 0]
    if len(empty) == len(grid.faces):
        raise InputError(f"{session_path}: no camera ray reaches the grid's face(s) {' '.join(empty)}: "
                         "check the grid's faces against the directions the cameras look in")
    if empty:
        log.warning("%s: no camera ray reaches face(s) %s of the grid: their samples get W = 0",
                    session_path, " ".join(empty))


def _camera_noise_attr(sess, resampler) -> dict | None:
    """The store's ``camera_noise`` attribute: the median sensor noise of the calibrated cameras'
    images in the session's first frame (:func:`~resample.resampler.images_noise_sigma`, [0, 1]
    units; not MJPG cameras', :func:`~resample.resampler.noise_cameras`) and how many images gave an
    estimate; None when none did."""
    from .resampler import images_noise_sigma, median_noise, noise_cameras

    cams = noise_cameras(sess, resampler.cameras)
    sigma, n = median_noise(images_noise_sigma(sess.read_frame(0), cams).values()) if cams else (math.nan, 0)
    return {"sigma": sigma, "images": n} if n else None


def resample_session(session_path: str | os.PathLike | Session, out: str | os.PathLike, *,
                     calib_dir: str | os.PathLike | None = None, grid: LightFieldGrid | None = None,
                     options=None, uv_step_px: float = 1.0, xy_oversample: int = 2,
                     scheduler: str | None = None, workers: int | None = None, overwrite: bool = False,
                     capture_motion=None, progress: Progress | None = None) -> ResampleSummary:
    """Resample every frame of a session (a folder, or one already opened with
    :func:`polycam.session.open_session`) into the light-field store ``out`` (see the module
    docstring). ``scheduler``: ``"sync"``, ``"local"``, an address, or None (automatic:
    ``workers == 0`` → sync, ``workers`` given → local, else by job size). ``workers``:
    local worker processes (default: the number of cores). ``uv_step_px``, ``xy_oversample``: the
    automatic grid's direction step [camera pixels] and viewpoints per camera spacing
    (:func:`resample.grid.auto_grid`; not used with ``grid``, and recorded in the store's
    ``resample`` attribute when used). ``capture_motion``: (T - 1, 4, 4)
    ``T_prev_next`` per frame pair of a session whose cameras are not synchronised: each frame is
    resampled with every camera where it captured its image (:func:`resample.stream.models_at_capture`;
    a splat geometry per frame; the store's ``resample`` attribute says ``cameras_moved_to_capture``)."""
    from contextlib import ExitStack

    from polycam.session import open_session, sync_warning

    from .grid import auto_grid
    from .resampler import ResampleOptions, Resampler, noise_cameras
    from .store import FrameStore

    sess = session_path if isinstance(session_path, Session) else open_session(session_path)
    n = len(sess)
    if n == 0:
        raise InputError(f"{sess.path}: the session has no frames")
    models = open_calibration(sess, calib_dir)
    if capture_motion is not None:
        capture_motion = np.asarray(capture_motion, np.float64)
        if capture_motion.shape != (max(n - 1, 0), 4, 4):
            raise ValueError(f"capture_motion must be ({n - 1}, 4, 4), got {capture_motion.shape}")
    out = Path(out)
    if out.exists() and not overwrite:
        raise InputError(f"{out}: already exists (choose another name or allow overwriting)")
    options = options or ResampleOptions()
    grid_given = grid is not None
    if grid is None:
        grid = auto_grid(models, uv_step_px=uv_step_px, xy_oversample=xy_oversample)
    channels = _channels_of(sess)
    rays = sum(w * h for w, h in (sess.image_size(c) for c in sess.cameras))
    if scheduler is None:
        if workers == 0:
            scheduler = "sync"
        elif workers is not None:
            scheduler = "local"
        else:
            scheduler = "sync" if (n * rays < _TINY_JOB_RAYS or n == 1) else "local"

    with ExitStack() as stack:
        client, label, threads = (None, "sync", None) if scheduler == "sync" else \
            _dask_client(stack, scheduler, workers)        # connect first: fail before the long build
        t0 = time.perf_counter()
        resampler = Resampler(models, grid, channels=channels, options=options)
        t_geo = time.perf_counter() - t0
        _check_faces_reached(resampler.geometry, sess.path)      # before the store is created
        attrs = {"resample": {"session": str(Path(sess.path).resolve()),
                              "grid": "given" if grid_given else "auto",
                              "kernel": {"radius_xy": options.kernel.radius_xy,
                                         "radius_uv": options.kernel.radius_uv,
                                         "linear": options.kernel.linear},
                              "schedule": options.schedule, "attenuation": options.attenuation,
                              "full_weight": options.full_weight, "view_fill": options.view_fill}}
        if not grid_given:
            attrs["resample"].update(uv_step_px=float(uv_step_px), xy_oversample=int(xy_oversample))
        if capture_motion is not None:
            attrs["resample"]["cameras_moved_to_capture"] = True
        positions = resampler.camera_positions()
        if positions is not None:          # the depth refinement's sources (polycam.depth_refine)
            attrs["camera_positions"] = camera_positions_attr(positions)
        noise = _camera_noise_attr(sess, resampler)
        if noise is not None:
            attrs["camera_noise"] = noise
        store = FrameStore(out, grid, sess.timestamps_ns, channels=channels if channels > 1 else None,
                           overwrite=overwrite, extra_attrs=attrs)
        t1 = time.perf_counter()
        wsum = 0.0
        empty = 0
        try:
            moved = None
            if capture_motion is not None:
                from .stream import models_at_capture

                def moved(t: int) -> dict:
                    return models_at_capture(models, sess, t, capture_motion)
            if client is None:
                wsum, empty = _run_in_process(resampler, sess, n, str(store.partial), progress, moved)
            else:
                wsum, empty = _run_dask(client, resampler, str(sess.path), n, str(store.partial), threads,
                                        progress, moved)
            gt = sess.groundtruth()
            if gt is not None and not np.array_equal(gt.timestamps_ns, sess.timestamps_ns):
                log.warning("%s: groundtruth.tum does not have one pose per frame; not copied", sess.path)
                gt = None
            store.finish(groundtruth=gt)
        except BaseException:
            store.abort()
            raise
        t_frames = time.perf_counter() - t1
    if empty:
        log.warning("%s: %d frame(s) without any image were written as zeros", out, empty)
    summary = ResampleSummary(path=out, grid=grid, frames=n, cameras=len(sess.cameras), rays_per_frame=rays,
                              channels=channels, missing_images=int(np.sum(sess.cam_timestamps < 0)),
                              empty_frames=int(empty), scheduler=label, seconds_geometry=t_geo,
                              seconds_frames=t_frames, mean_W=wsum / (n * grid.num_rays),
                              camera_noise_sigma=noise["sigma"] if noise is not None else float("nan"),
                              compressed_cameras=len(sess.cameras) - len(noise_cameras(sess, sess.cameras)),
                              sync_warning=sync_warning(sess), cameras_moved_to_capture=capture_motion is not None)
    log.info("resampled %d frames of %d cameras into %s (%s): geometry %.1f s, frames %.1f s", n,
             summary.cameras, out, label, t_geo, t_frames)
    return summary


def _run_in_process(resampler, sess, n: int, partial: str, progress: Progress | None,
                    moved=None) -> tuple[float, int]:
    """Frames one after the other in this process, with the reading of frame t+1 and the
    writing of frame t-1 overlapped with resampling frame t (two threads, two output
    buffers: PNG decoding and chunk compression release the GIL). ``moved``: frame t → its camera
    models where they captured it, resampled with a resampler of its own."""
    from concurrent.futures import ThreadPoolExecutor

    from .resampler import Resampler
    from .store import write_frame

    bufs = [resampler.new_output(), resampler.new_output()]
    C = resampler.channels
    wsum = 0.0
    empty = 0
    with ThreadPoolExecutor(2, thread_name_prefix="polycam-resample-io") as pool:
        reading = pool.submit(sess.read_frame, 0)
        writing = [None, None]
        for t in range(n):
            images = reading.result()
            if t + 1 < n:
                reading = pool.submit(sess.read_frame, t + 1)
            k = t % 2
            if writing[k] is not None:
                writing[k].result()                 # buffer k is free again
            L, W = bufs[k]
            if any(img is not None for img in images.values()):
                own = resampler if moved is None else Resampler(moved(t), resampler.grid, channels=C,
                                                                  options=resampler.options)
                r = own.resample_into(images, out=(L, W))
                wsum += float(np.sum(r.W, dtype=np.float64))
            else:
                L[...] = 0.0
                W[...] = 0.0
                empty += 1
            writing[k] = pool.submit(write_frame, partial, t, L if C > 1 else L[..., 0], W)
            if progress is not None:
                progress(t + 1, n)
        for f in writing:
            if f is not None:
                f.result()
    return wsum, empty


def _dask_client(stack, scheduler: str, workers: int | None):
    """(client, label, numba threads per task) for ``"local"`` or a scheduler address; the
    cluster and client close with ``stack``."""
    from distributed import Client, LocalCluster

    # distributed sets its loggers to INFO; keep them at the CLI's level (WARNING unless -v)
    dlog = logging.getLogger("distributed")
    old_level = dlog.level
    dlog.setLevel(max(logging.WARNING, logging.getLogger().getEffectiveLevel()))
    stack.callback(dlog.setLevel, old_level)
    if scheduler == "local":
        nw = workers or os.cpu_count() or 1
        cluster = stack.enter_context(LocalCluster(n_workers=nw, threads_per_worker=1, processes=True,
                                                   dashboard_address=":0", silence_logs=logging.ERROR))
        client = stack.enter_context(Client(cluster))
        log.info("dask: a local cluster of %d worker process(es)", nw)
        return client, f"local:{nw}", max(1, (os.cpu_count() or 1) // nw)
    try:
        client = stack.enter_context(Client(scheduler, timeout="10s"))
    except (OSError, TimeoutError, ValueError) as e:
        raise InputError(f"resample: cannot reach the dask scheduler at {scheduler!r} ({e})") from None
    log.info("dask: scheduler %s with %d worker(s)", scheduler, len(client.scheduler_info().get("workers", {})))
    return client, scheduler, None


def _run_dask(client, resampler, session_path: str, n: int, partial: str, threads: int | None,
              progress: Progress | None, moved=None) -> tuple[float, int]:
    """Frames as dask tasks, a bounded number in flight; returns (sum of W, empty frames). ``moved``:
    as :func:`_run_in_process`'s (each task then builds its frame's resampler)."""
    from distributed import as_completed

    nw = max(1, len(client.scheduler_info().get("workers", {})))
    if moved is None:
        remote = client.scatter(resampler, broadcast=True)

        def submit(t: int):
            return client.submit(_frame_task, remote, session_path, t, partial, threads, pure=False)
    else:
        def submit(t: int):
            return client.submit(_moved_frame_task, moved(t), resampler.grid, resampler.channels,
                                 resampler.options, session_path, t, partial, threads, pure=False)
    pending = iter(range(n))
    futures = as_completed()
    for _ in range(max(2, 2 * nw)):
        t = next(pending, None)
        if t is None:
            break
        futures.add(submit(t))
    done = 0
    wsum = 0.0
    empty = 0
    try:
        for fut in futures:
            _, k, ws = fut.result()
            fut.release()
            wsum += ws
            empty += k == 0
            done += 1
            if progress is not None:
                progress(done, n)
            t = next(pending, None)
            if t is not None:
                futures.add(submit(t))
    except BaseException:
        for f in list(futures.futures):
            f.cancel()
        raise
    return wsum, empty
