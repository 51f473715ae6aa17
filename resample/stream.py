"""A recorded session seen as a light field, resampled on the fly (``polycam motion SESSION``).

:class:`SessionLightField` offers what :func:`polycam.motion.estimate_trajectory`
reads from a light-field store — ``grid``, ``timestamps_ns``, ``frame(i)``,
``weights(i)``, ``groundtruth()`` — but computes each frame when asked: the
session's images of frame i are read and pushed through one
:class:`~resample.resampler.Resampler` whose splat geometry is built once. Only
the last resampled frame is kept (``frame(i)`` then ``weights(i)`` cost one
resampling), so memory does not grow with the session's length.

The first resampled frames also estimate the sensor noise of ``NOISE_CAMERAS_PER_FRAME`` of their
camera images each (:func:`polycam.image_noise.image_noise_sigma`, cycling through the cameras from
frame to frame, ``NOISE_IMAGES`` in all; not MJPG cameras': :data:`~resample.resampler.COMPRESSED_FORMATS`):
:attr:`SessionLightField.camera_noise_sigma`.
:meth:`SessionLightField.sample_noise_sigma` turns it into the std of the noise each resampled
sample carries (push-pull averages the cameras' pixels).

The result is the same light field that ``polycam resample`` writes (same grid,
same resampler), without the store in between.
"""

from __future__ import annotations

import logging
import math
import os
import time
from pathlib import Path

import numpy as np

from polycam.errors import InputError
from polycam.lightfield import LightFieldGrid
from polycam.session import Session, open_session

__all__ = ["SessionLightField", "models_at_capture", "NOISE_CAMERAS_PER_FRAME", "NOISE_IMAGES", "NOISE_PROBE",
           "NOISE_PROBE_SEED"]

log = logging.getLogger(__name__)

NOISE_CAMERAS_PER_FRAME = 1
"""Camera images per resampled frame whose sensor noise is estimated (the next one each frame: ~8 ms
per 640 x 480 grey image, against ~100 ms to resample an OAK-D Lite's frame) ..."""
NOISE_IMAGES = 12
"""... until this many images have been (the noise is the cameras', not the frames')."""
NOISE_PROBE = 1e-3
"""Smallest std (in [0, 1] units, 0.26 grey levels of 255) of the white noise added to a frame's images
to see what resampling does to noise (:meth:`SessionLightField.sample_noise_sigma`); the probe is
the cameras' own noise when that is larger."""
NOISE_PROBE_SEED = 20261206
"""Seed of that probe's noise (the same figure on every run of a session)."""


class SessionLightField:
    """The light field of session ``session_path`` (a folder, or a session already opened with
    :func:`polycam.session.open_session`) with calibration ``calib_dir`` (default
    ``SESSION/calib``), frame by frame.

    grid: the two-plane grid (default :func:`resample.grid.auto_grid` of the models
        with ``uv_step_px`` and ``xy_oversample``); options: :class:`resample.resampler.ResampleOptions`;
        models: camera id → mrcal cameramodel, overriding ``calib_dir``; camera_noise: estimate the
        cameras' sensor noise as frames are resampled (off for re-solves that do not report it);
        capture_motion: (T - 1, 4, 4) ``T_prev_next`` per frame pair (a first estimate of the session's
        motion): each frame is then resampled with every camera moved to where it was when it captured
        its image, its share of the motion to the neighbouring frame (:func:`models_at_capture`), for
        cameras that are not synchronised (:func:`polycam.session.sync_warning`); a splat geometry per
        frame, so several times the resampling's cost; capture_offsets_ns: with ``capture_motion``, (F, C)
        [ns] added to each camera's capture time of each frame, or (C,) to every frame's (the session's
        camera order; a draw from the capture times' uncertainty,
        :meth:`polycam.session.Session.capture_time_draw_ns`, :mod:`polycam.sync_draws_cli`).
    Raises InputError for a session without frames or without a calibration.
    """

    def __init__(self, session_path: str | os.PathLike | Session, *, calib_dir: str | os.PathLike | None = None,
                 grid: LightFieldGrid | None = None, uv_step_px: float = 1.0, xy_oversample: int = 2,
                 options=None, models: dict | None = None, camera_noise: bool = True,
                 capture_motion=None, capture_offsets_ns=None):
        from .grid import auto_grid
        from .pipeline import _channels_of, open_calibration
        from .resampler import ResampleOptions, noise_cameras

        self.session = session_path if isinstance(session_path, Session) else open_session(session_path)
        if len(self.session) == 0:
            raise InputError(f"{self.session.path}: the session has no frames")
        self.models = dict(models) if models is not None else open_calibration(self.session, calib_dir)
        missing = [c for c in self.session.cameras if c not in self.models]
        if missing:
            log.warning("%s: no calibration for camera(s) %s; their images are ignored",
                        self.session.path, ", ".join(missing))
        self.grid = grid if grid is not None else auto_grid(self.models, uv_step_px=uv_step_px,
                                                            xy_oversample=xy_oversample)
        self.uv_step_px: float | None = uv_step_px if grid is None else None
        """Direction step of the grid [camera pixels] when known (the automatic grid's, or as set by
        whoever chose the grid: :func:`polycam.depth_cli.open_source`)."""
        self.uv_disparity = math.nan
        """Disparity per view step [grid samples] that chose ``uv_step_px`` (``--uv-step auto``,
        :func:`polycam.run.choose_uv_step`; NaN: not chosen that way)."""
        self.channels = _channels_of(self.session)
        self.options = options or ResampleOptions()
        """The :class:`~resample.resampler.ResampleOptions` every frame is resampled with."""
        self._resampler = None
        self.seconds_geometry = 0.0
        """[s] time spent building the session's splat geometry (with ``capture_motion`` only when
        :attr:`resampler` is asked for: each frame then builds its own)."""
        if capture_motion is None:
            _ = self.resampler              # built now: its cost and warnings come before the frames
        self.seconds_frames = 0.0
        """[s] time spent resampling frames so far."""
        self.frames_resampled = 0
        self.w_sums: dict[int, float] = {}
        """Frame index → mean confidence W of that frame (filled as frames are resampled)."""
        self.cameras_present: dict[int, int] = {}
        """Frame index → number of calibrated cameras that had an image."""
        self.camera_noise: dict[tuple[int, str], float] = {}
        """(frame index, camera id) → the sensor noise's std of that camera image, per channel, in [0, 1]
        units as the images are resampled (:func:`~resample.resampler.images_noise_sigma`; NaN: no estimate)."""
        self._noise_gain: float | None = None
        self._estimate_noise = bool(camera_noise)
        self.noise_cameras = set(noise_cameras(self.session, self.session.cameras))
        """The camera ids whose images give a noise estimate (:func:`~resample.resampler.noise_cameras`:
        not MJPG)."""
        self._cached: tuple[int, np.ndarray, np.ndarray] | None = None
        self._frame_resampler = None
        self.capture_motion = None if capture_motion is None else np.asarray(capture_motion, np.float64)
        if self.capture_motion is not None and self.capture_motion.shape != (len(self.session) - 1, 4, 4):
            raise ValueError(f"capture_motion must be ({len(self.session) - 1}, 4, 4), got {self.capture_motion.shape}")
        self.capture_offsets_ns = None
        if capture_offsets_ns is not None:
            offsets = np.asarray(capture_offsets_ns, np.float64)
            shape = (len(self.session), len(self.session.cameras))
            if offsets.shape not in (shape, shape[1:]):
                raise ValueError(f"capture_offsets_ns must be {shape} or {shape[1:]}, got {offsets.shape}")
            self.capture_offsets_ns = np.broadcast_to(offsets, shape)

    @property
    def resampler(self):
        """The :class:`~resample.resampler.Resampler` of the session's camera models (built on first use)."""
        if self._resampler is None:
            from .resampler import Resampler

            t0 = time.perf_counter()
            self._resampler = Resampler(self.models, self.grid, channels=self.channels, options=self.options)
            self.seconds_geometry += time.perf_counter() - t0
        return self._resampler

    @property
    def timestamps_ns(self) -> np.ndarray:
        """(T,) int64 frame timestamps [ns]."""
        return self.session.timestamps_ns

    @property
    def path(self) -> Path:
        return self.session.path

    def __len__(self) -> int:
        return len(self.session)

    @property
    def has_weights(self) -> bool:
        """Always: resampled frames come with their confidence W (as a store's ``has_weights``)."""
        return True

    def _resample(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        if self._cached is not None and self._cached[0] == t:
            return self._cached[1], self._cached[2]
        if not 0 <= t < len(self):
            raise IndexError(f"frame {t} out of range (0..{len(self) - 1})")
        t0 = time.perf_counter()
        images = {c: img for c, img in self.session.read_frame(t).items() if c in self.models}
        if not any(img is not None for img in images.values()):
            shape = self.grid.shape
            L = np.zeros((*shape, self.channels) if self.channels > 1 else shape, np.float32)
            W = np.zeros(shape, np.float32)
            self.cameras_present[t] = 0
        else:
            if self._estimate_noise:
                self._estimate_camera_noise(t, images)
            r = self._resampler_for(t).resample(images)
            L, W = r.L, r.W
            self.cameras_present[t] = len(r.cameras)
        self.seconds_frames += time.perf_counter() - t0
        self.frames_resampled += 1
        self.w_sums[t] = float(np.mean(W, dtype=np.float64))
        self._cached = (t, L, W)
        return L, W

    def _resampler_for(self, t: int):
        """The resampler of frame t: the session's, or with ``capture_motion`` one of its own, with the
        cameras where they captured that frame (the last one kept)."""
        if self.capture_motion is None:
            return self.resampler
        if self._frame_resampler is None or self._frame_resampler[0] != t:
            from .resampler import Resampler

            models = models_at_capture(self.models, self.session, t, self.capture_motion,
                                       None if self.capture_offsets_ns is None else self.capture_offsets_ns[t])
            self._frame_resampler = (t, Resampler(models, self.grid, channels=self.channels,
                                                  options=self.options))
        return self._frame_resampler[1]

    def _estimate_camera_noise(self, t: int, images: dict) -> None:
        """The sensor noise of the next ``NOISE_CAMERAS_PER_FRAME`` cameras (in the session's camera
        order, from frame t's position in that cycle) among frame t's images, until ``NOISE_IMAGES``
        images have been estimated."""
        from .resampler import images_noise_sigma

        cams = [c for c in self.models if c in self.noise_cameras and images.get(c) is not None]
        if not cams or len(self.camera_noise) >= NOISE_IMAGES:
            return
        k = min(NOISE_CAMERAS_PER_FRAME, len(cams))
        start = (t * k) % len(cams)
        chosen = [cams[(start + j) % len(cams)] for j in range(k)]
        if (t, chosen[0]) in self.camera_noise:       # a frame resampled again
            return
        for c, sigma in images_noise_sigma(images, chosen).items():
            self.camera_noise[(t, c)] = sigma

    @property
    def camera_noise_sigma(self) -> float:
        """Median over the camera images estimated so far of their sensor noise's std, in [0, 1] units
        (:attr:`camera_noise`; NaN before any estimate), as a store's
        :attr:`~polycam.lfstore.LightFieldStore.camera_noise_sigma`."""
        from .resampler import median_noise

        return median_noise(self.camera_noise.values())[0]

    @property
    def compressed_cameras(self) -> int:
        """How many of the session's cameras record a compressed format and give no noise estimate."""
        return len(self.session.cameras) - len(self.noise_cameras)

    @property
    def camera_noise_images(self) -> int:
        """How many camera images gave an estimate so far (as the store's attribute)."""
        from .resampler import median_noise

        return median_noise(self.camera_noise.values())[1]

    def sample_noise_sigma(self) -> float:
        """The std of the noise a resampled sample carries, in [0, 1] units: :attr:`camera_noise_sigma`
        times the RMS, over the samples with data (W > 0), of white noise of unit std in the cameras'
        images after resampling (push-pull averages pixels; colour channels averaged, as the motion
        solver takes them). That factor is measured once per session, on the last frame resampled:
        its images with white noise of the cameras' std (at least ``NOISE_PROBE``; the same in every
        channel of a grey camera) added are resampled again, and the difference from the frame,
        divided by that std, is the resampled unit noise (the resampling is linear in the images but
        for the view fill's choice of disparity, which such a probe moves as the images' own noise
        does). Costs one more frame's resampling; NaN before any frame, and without ``camera_noise``."""
        if not self._estimate_noise:
            return float("nan")
        if self._noise_gain is None:
            if not self.w_sums:
                return float("nan")
            from .resampler import normalise_image

            t = self._cached[0] if self._cached is not None else min(self.w_sums)   # no new resampling
            images = {c: img for c, img in self.session.read_frame(t).items()
                      if c in self.models and img is not None}
            L, W = self._resample(t)
            L, W = L.copy(), W.copy()
            if not images:                        # a frame without images: no probe
                return float("nan")
            # the images' own noise level: the view fill's plane sweep is not linear in the images, and
            # meets a probe of that size as it meets their noise (a much smaller one flips the sweep's
            # near ties between disparities, whose differences divided by the probe dominate the RMS)
            probe = self.camera_noise_sigma
            probe = max(probe, NOISE_PROBE) if math.isfinite(probe) else NOISE_PROBE
            rng = np.random.default_rng(NOISE_PROBE_SEED)
            probed = {}
            for c, img in images.items():
                a = normalise_image(img, self.channels)
                grey = np.ndim(img) == 2 or np.shape(img)[2] == 1   # its noise is the same in every channel
                a += rng.normal(0.0, probe, a.shape[:2] + (1 if grey else a.shape[2],)).astype(np.float32)
                probed[c] = a[:, :, 0] if self.channels == 1 else a
            r = self._resampler_for(t).resample(probed)
            N = (r.L - L) / np.float32(probe)
            if N.ndim == 6:                       # colour: the solver averages the channels
                N = N.mean(axis=-1)
            has = W > 0
            self._noise_gain = float(np.sqrt(np.mean(np.square(N[has], dtype=np.float64)))) if has.any() else math.nan
        return self.camera_noise_sigma * self._noise_gain

    def frame(self, t: int) -> np.ndarray:
        """(F, Ny, Nx, Nv, Nu) (or with a colour axis) float32 intensities of frame t."""
        return self._resample(t)[0]

    def weights(self, t: int) -> np.ndarray:
        """(F, Ny, Nx, Nv, Nu) float32 confidence in [0, 1] of frame t."""
        return self._resample(t)[1]

    def groundtruth(self):
        """The session's ``groundtruth.tum`` (:class:`~polycam.trajectory.Trajectory`) when it
        has one pose per frame, else None."""
        gt = self.session.groundtruth()
        if gt is not None and not np.array_equal(gt.timestamps_ns, self.timestamps_ns):
            log.warning("%s: groundtruth.tum does not have one pose per frame; ignored", self.session.path)
            return None
        return gt

    @property
    def camera_positions(self) -> np.ndarray | None:
        """As a store's :attr:`~polycam.lfstore.LightFieldStore.camera_positions`: the camera centres
        (iy, ix) in fractional grid indices at their views, (F, Ny, Nx, 2), or None."""
        return self.resampler.camera_positions()

    @property
    def mean_W(self) -> float:
        """Mean confidence over the frames resampled so far (NaN before any)."""
        return float(np.mean(list(self.w_sums.values()))) if self.w_sums else float("nan")


def models_at_capture(models: dict, session: Session, t: int, T_prev_next: np.ndarray,
                      capture_offsets_ns: np.ndarray | None = None) -> dict:
    """Camera id → its model in the rig frame at frame ``t``'s time, moved to where the camera was when
    it captured its image of that frame: by the share ``d / Δt`` of the motion to the next frame (``d``
    = its capture time minus the frame's time, both without their timestamps' jitter,
    :meth:`Session.capture_times_ns` and :meth:`Session.frame_times_ns`; ``Δt`` the frame interval), or back along the previous
    one for an image taken early: the poses :func:`polycam.trajectory.pose_at` interpolates. Beyond the
    first and last frames (an image taken before the first frame's time or after the last's) the step
    there is :func:`polycam.trajectory.step_beyond`'s, the velocity of the two end steps extrapolated
    (with three frames or more, neither of the two the identity a failed pair is given; else the end
    step held).
    ``T_prev_next``: (T - 1, 4, 4) rig motion per
    frame pair (frame i to i + 1, as :class:`polycam.motion.PairResult`); models: camera id → mrcal
    cameramodel (rig frame; the session's cameras without an image keep theirs); capture_offsets_ns:
    (C,) [ns] added to the cameras' capture times (session camera order), or None."""
    import mrcal

    from polycam.cameras import T_rig_cam_of
    from polycam.geometry import T_inverse, rt_from_T
    from polycam.trajectory import Trajectory, pose_at, step_beyond

    F = len(session)
    if F < 2:
        return dict(models)
    times = session.frame_times_ns().astype(np.int64)
    motion = np.asarray(T_prev_next, np.float64)
    # frame t and its neighbours (a capture lies within a frame of its frame); beyond the session's ends
    # a step of the motion going on (a failed pair's identity next to the end: the end step held)
    lo, hi = max(t - 1, 0), min(t + 1, F - 1)
    stamps, steps, here = list(times[lo:hi + 1]), list(motion[lo:hi]), t - lo

    def solved(*pairs: int) -> bool:
        return not any(np.array_equal(motion[p], np.eye(4)) for p in pairs)

    if F >= 3 and t == 0 and solved(0, 1):
        dt = times[1] - times[0]
        stamps.insert(0, times[0] - dt)
        steps.insert(0, step_beyond(motion[0], motion[1], dt, times[2] - times[1]))
        here += 1
    if F >= 3 and t == F - 1 and solved(F - 2, F - 3):
        dt = times[F - 1] - times[F - 2]
        stamps.append(times[F - 1] + dt)
        steps.append(step_beyond(motion[F - 2], motion[F - 3], dt, times[F - 2] - times[F - 3]))
    rel = Trajectory.from_relative(np.array(stamps), np.stack(steps))
    T_t_world = T_inverse(rel.T_world_rig[here])
    out = dict(models)
    captured = session.capture_times_ns()[t]
    for k, cam in enumerate(session.cameras):
        stamp = int(captured[k])
        if cam not in models or stamp < 0:
            continue
        if capture_offsets_ns is not None:
            stamp += int(round(capture_offsets_ns[k]))
        D = T_t_world @ pose_at(rel, stamp)                  # the rig at the capture, in the rig at frame t
        m = models[cam]
        out[cam] = mrcal.cameramodel(intrinsics=m.intrinsics(), imagersize=m.imagersize(),
                                     rt_cam_ref=rt_from_T(T_inverse(D @ T_rig_cam_of(m))))
    return out
